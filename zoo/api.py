"""The Python API as timm and torchvision users expect it: ``zoo.create_model(name, benchmark=...,
pretrained=True)``, ``zoo.list_models()``, ``zoo.evaluate(model, benchmark)``,
``zoo.compare(a, b)`` and ``zoo.load_results(benchmark)``. The top of the library: it may import
everything else, and nothing imports it.

    import zoo
    result = zoo.evaluate(MyModel(...), "cmu", sampler="ltd8", label="mine")
    print(result.summary())                          # MPJPE per horizon, action average
    stored = zoo.load_results("cmu", sampler="ltd8")  # {label: EvalResult} from results/
    print(zoo.compare(result, stored["repeat_last"]).markdown())
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from zoo.hub.build import model_args_for
from zoo.models.registry import Registry, RegistryError, as_registry, load_registry


def list_models(representation: str | None = None) -> list[str]:
    return load_registry().list_models(representation)


def create_model(
    name: str,
    benchmark: Any = None,
    registry: Registry | str | Path | None = None,
    pretrained: bool = False,
    **overrides: Any,
):
    """A registered model. ``benchmark`` (a name or a :class:`zoo.protocol.benchmark.Benchmark`)
    supplies the shape arguments and context; ``overrides`` replace any hyper-parameter by name.

    ``pretrained=True`` returns the model trained on ``benchmark`` from the weights shipped in
    ``weights/<benchmark>/<name>.safetensors`` (``name`` may be ``<model>@last``; an entry with
    ``weights_of`` ships a link to that model's), in eval mode; the error lists the shipped ones
    when there are none. ``registry``: a :class:`zoo.models.registry.Registry`, or the path of your
    registry file (or a list of them), added to the project's."""
    registry = as_registry(registry, "zoo.create_model")
    if pretrained:
        from zoo.hub.checkpoints import load_weights
        from zoo.hub.weights import pretrained_path

        if benchmark is None:
            raise RegistryError(
                f"create_model({name!r}, pretrained=True) needs benchmark=...: "
                f"weights are trained for one benchmark"
            )
        if overrides:
            raise RegistryError(
                f"pretrained weights fix the hyper-parameters; got overrides "
                f"{', '.join(sorted(overrides))}"
            )
        bench_name = benchmark if isinstance(benchmark, str) else benchmark.name
        model = name.partition("@")[0]
        return load_weights(
            pretrained_path(name, bench_name),  # for a weights_of entry, its link to them
            registry=registry,
            benchmark=benchmark,
            model_name=model if registry.get(model).weights_of else None,
        )[0]
    if benchmark is not None:
        from zoo.protocol.benchmark import get_benchmark

        bench = get_benchmark(benchmark) if isinstance(benchmark, (str, Path)) else benchmark
        _, overrides = model_args_for(registry, name, bench, overrides=overrides)
    return registry.create_model(name, **overrides)


def evaluate(
    model: Any,
    benchmark: Any = "cmu",
    *,
    label: str | None = None,
    sampler: str | None = None,
    data_root: str | Path | None = None,
    dataset: Any = None,
    registry: Registry | str | Path | None = None,
    out: str | Path | None = None,
    store: bool = False,
    replace: bool = False,
    device: str = "cpu",
    **options: Any,
):
    """Evaluate a model on a benchmark; an :class:`zoo.evaluation.results.EvalResult` (``.frame``:
    every row; ``.summary()``: the action average per horizon) carrying the same identity as ``zoo
    eval`` records.

    ``model``: your own ``nn.Module`` (label: ``label``, default its class name), a registered
    model's name, or the path of a checkpoint (``.pt``) or shipped weights (``.safetensors``).
    Nothing is written unless asked: ``out=FOLDER``, or ``store=True`` for
    ``results/<benchmark>/<table>/<label>/``, which refuses a stored result of another identity
    unless ``replace=True``. ``dataset``: the benchmark's test data already loaded
    (``get_benchmark(b).load(root)``), instead of loading it from ``data_root``. ``registry``:
    a :class:`zoo.models.registry.Registry`, or the path of your registry file (or a list of them).
    ``options``: ``task`` (``prediction``, ``completion`` or ``longterm`` with ``horizon``
    frames), ``ground_truth`` and ``melv_frames`` (mesh benchmarks: ``raw`` or ``spectral``),
    ``view`` (``joints`` for a skeleton module on a mesh benchmark), ``batch_size``."""
    import torch

    from zoo.core.errors import EvaluationError
    from zoo.core.options import EVAL_BATCH
    from zoo.evaluation.pipeline import Subject, evaluate_and_store
    from zoo.hub.model_source import ModelSource
    from zoo.protocol.benchmark import get_benchmark
    from zoo.store.layout import check_label

    bench = get_benchmark(benchmark) if isinstance(benchmark, (str, Path)) else benchmark
    if dataset is not None and data_root is not None:
        raise EvaluationError("zoo.evaluate: give dataset (loaded data) or data_root, not both")
    registry = as_registry(registry, "zoo.evaluate")
    dataset = dataset if dataset is not None else bench.load(data_root)
    if isinstance(model, torch.nn.Module):
        default_view = bench.own_view  # a module of the benchmark's kind
        subject = Subject.of_module(
            model, check_label(label or type(model).__name__), options.pop("view", default_view)
        )
    else:
        path = Path(str(model))
        source = ModelSource.of(
            model=None if path.suffix in (".pt", ".safetensors") else str(model),
            checkpoint=path if path.suffix == ".pt" else None,
            weights=path if path.suffix == ".safetensors" else None,
            label=label,
        )
        subject = Subject.of_loaded(source.load(registry, bench, dataset, data_root))
    task = options.pop("task", "prediction")
    horizon = options.pop("horizon", None)
    ground_truth = options.pop("ground_truth", None)
    melv_frames = options.pop("melv_frames", None)
    batch_size = options.pop("batch_size", EVAL_BATCH)
    if options:
        raise RegistryError(
            f"zoo.evaluate: unknown option(s) {', '.join(sorted(options))}; valid: task, "
            f"horizon, ground_truth, melv_frames, batch_size, view"
        )
    [(result, _, _)] = evaluate_and_store(
        subject,
        bench,
        dataset,
        [sampler],
        made_by="zoo.evaluate",
        device=device,
        batch_size=batch_size,
        task=task,
        horizon=horizon,
        ground_truth=ground_truth,
        melv_frames=melv_frames,
        out=out,
        write=store,
        replace=replace,
    )
    return result


def compare(
    a: Any,
    b: Any,
    *,
    benchmark: Any = None,
    sampler: str | None = None,
    root: str | Path | None = None,
    **options: Any,
):
    """Is A better than B? ``a`` and ``b``: results (from :func:`evaluate` or
    :func:`load_results`), result folders, or labels of stored results of ``benchmark``;
    ``options`` as :func:`zoo.stats.comparison.compare` takes them. Returns a
    :class:`zoo.stats.comparison.Comparison` (``.markdown()``, ``.table``)."""
    from zoo.stats.comparison import compare as paired

    def resolve(x):
        if isinstance(x, str) and not Path(x).is_dir():
            if benchmark is None:
                raise RegistryError(f"compare({x!r}, ...): a label needs benchmark=...")
            results = load_results(benchmark, sampler=sampler, root=root)
            if x not in results:
                raise RegistryError(
                    f"no stored result labelled {x!r} for benchmark "
                    f"{benchmark!r}; stored: {', '.join(results) or 'none'}"
                )
            return results[x]
        return x

    return paired(resolve(a), resolve(b), **options)


def load_results(
    benchmark: Any,
    *,
    sampler: str | None = None,
    task: str = "prediction",
    ground_truth: str | None = None,
    root: str | Path | None = None,
) -> dict:
    """The stored results of one table, ``{label: EvalResult}`` (``results/<benchmark>/
    <table>/<label>/``), each with its protocol record and identity."""
    from zoo.evaluation.results import EvalResult
    from zoo.protocol.benchmark import get_benchmark
    from zoo.store.layout import RESULTS_DIR, table_folder

    bench = get_benchmark(benchmark) if isinstance(benchmark, (str, Path)) else benchmark
    folder = (
        Path(root or RESULTS_DIR)
        / bench.name
        / table_folder(sampler or bench.sampler, task, ground_truth)
    )
    return {
        p.name: EvalResult.read(p)
        for p in sorted(folder.glob("*/protocol.json"))
        for p in [p.parent]
    }
