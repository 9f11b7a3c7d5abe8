"""The Python API as timm and torchvision users expect it: ``zoo.create_model(name, benchmark=...,
pretrained=True)`` and ``zoo.list_models()``. The top of the library: it may import the registry,
the benchmarks and the shipped weights, and none of them imports it."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from zoo.registry import Registry, RegistryError, load_registry


def list_models(representation: str | None = None) -> list[str]:
    return load_registry().list_models(representation)


def create_model(name: str, benchmark: Any = None, registry: Registry | None = None,
                 pretrained: bool = False, **overrides: Any):
    """A registered model. ``benchmark`` (a name or a :class:`zoo.benchmark.Benchmark`) supplies
    the shape arguments and context; ``overrides`` replace any hyper-parameter by name.

    ``pretrained=True`` returns the model trained on ``benchmark`` from the weights shipped in
    ``weights/<benchmark>/<name>.safetensors`` (``name`` may be ``<model>@last``), in eval mode;
    the error lists the shipped ones when there are none."""
    registry = registry or load_registry()
    if pretrained:
        from zoo.train import load_weights
        from zoo.weights import pretrained_path

        if benchmark is None:
            raise RegistryError(f"create_model({name!r}, pretrained=True) needs benchmark=...: "
                                f"weights are trained for one benchmark")
        if overrides:
            raise RegistryError(f"pretrained weights fix the hyper-parameters; got overrides "
                                f"{', '.join(sorted(overrides))}")
        bench_name = benchmark if isinstance(benchmark, str) else benchmark.name
        return load_weights(pretrained_path(name, bench_name), registry=registry,
                            benchmark=benchmark)[0]
    if benchmark is not None:
        from zoo.benchmark import get_benchmark

        bench = get_benchmark(benchmark) if isinstance(benchmark, (str, Path)) else benchmark
        entry = registry.get(name)
        overrides = {**bench.model_inputs(entry.context,
                                          view=bench.view_for(entry.representation)),
                     **overrides}
    return registry.create_model(name, **overrides)
