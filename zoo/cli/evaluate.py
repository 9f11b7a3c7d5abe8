"""``zoo eval``: one model on one benchmark, its result stored."""

from __future__ import annotations

from zoo.cli.common import (
    UsageError,
    add_command,
    benchmark_of,
    checked_sampler,
    common_options,
    model_source,
    model_source_options,
    positive_int,
    print_average,
    registry_of,
    results_option,
    task_options,
)
from zoo.core.options import EVAL_BATCH


def add(sub) -> None:
    p = add_command(sub, "eval", "evaluate one model on one benchmark", run)
    common_options(p)
    model_source_options(p, "benchmark name or YAML path (default: the checkpoint's, else cmu)")
    p.add_argument(
        "--sampler",
        action="append",
        help="window sampler (ltd8, rand256, all, strideK, strideK_strict); "
        "repeatable; default the benchmark's",
    )
    p.add_argument(
        "--out", help="the result folder (default: <results>/<benchmark>/<sampler>/<label>)"
    )
    results_option(p)
    p.add_argument(
        "--label",
        help="the row's label and folder name (default: the model's name, "
        "<model>@last for a last.pt, <model>+key=value with --set)",
    )
    p.add_argument(
        "--replace",
        action="store_true",
        help="replace a stored result of another identity (other hyper-parameters, "
        "data, weights or code) in the same place",
    )
    p.add_argument(
        "--set", action="append", metavar="KEY=VALUE", help="override a hyper-parameter; repeatable"
    )
    p.add_argument(
        "--batch-size", type=positive_int, default=EVAL_BATCH, help="windows per forward pass"
    )
    task_options(p)
    p.add_argument(
        "--ground-truth",
        choices=["raw", "spectral"],
        help="mesh benchmarks: score against raw or k-coefficient vertices",
    )
    p.add_argument(
        "--melv-frames",
        choices=["raw", "spectral"],
        help="mesh benchmarks: MELV on the frames as they are (raw) or on their "
        "k-coefficient reconstructions (spectral, the default where the "
        "benchmark has a basis; as SpecTrHuMS measures)",
    )


def run(args) -> int:
    from zoo.core.distributed import init_distributed
    from zoo.evaluation.pipeline import Subject, evaluate_and_store
    from zoo.evaluation.tolerance import tolerance_text

    registry = registry_of(args)
    source = model_source(args)
    bench = benchmark_of(args, source, "cmu")
    # what can be refused without the data first: a model name, its class, a sampler's name
    if source.name is not None:
        registry.get(source.name).load_class()
    for sampler in args.sampler or ():
        checked_sampler(sampler, bench)
    dataset = bench.load(args.data_root)
    loaded = source.load(registry, bench, dataset, args.data_root)
    loaded.warn_if_untrained()
    subject = Subject.of_loaded(loaded)
    samplers = args.sampler or [bench.sampler]
    if args.out and len(samplers) > 1:
        raise UsageError(
            "--out takes one --sampler; omit --out to write "
            "results/<benchmark>/<sampler>/<label>/ for each"
        )
    # Under torchrun every process scores its share of the windows and all get the whole
    # result; the first writes it.
    writer = init_distributed(args.device).rank == 0
    for result, where, stored in evaluate_and_store(
        subject,
        bench,
        dataset,
        samplers,
        made_by="zoo eval",
        device=args.device,
        batch_size=args.batch_size,
        writes=writer,
        task=args.task,
        horizon=args.horizon_frames,
        ground_truth=args.ground_truth,
        melv_frames=args.melv_frames,
        out=args.out or None,
        results=args.results,
        replace=args.replace,
    ):
        if stored is None:
            continue
        if stored.action == "kept":
            print_average(result.frame, bench.horizons_ms)
            print(
                f"{where.folder}: agrees with the stored result of this identity (largest "
                f"difference {stored.agreed.share:.2f} of the tolerance, {tolerance_text()}); "
                f"left as stored"
            )
            continue
        if stored.action == "rewritten":
            print(
                f"{where.folder}: rewritten: the stored result of this identity {stored.agreed.why}"
            )
        print_average(result.frame, bench.horizons_ms)
        print(f"wrote {where.folder}/results.csv, protocol.json, tables.md, windows.npz")
    return 0
