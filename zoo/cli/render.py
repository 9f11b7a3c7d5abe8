"""``zoo render``: ground truth and prediction side by side."""

from __future__ import annotations

from pathlib import Path

from zoo.cli.common import (
    UsageError,
    add_command,
    benchmark_of,
    common_options,
    model_source,
    model_source_options,
    registry_of,
    task_options,
)
from zoo.store.layout import RESULTS_DIR


def add(sub) -> None:
    p = add_command(sub, "render", "ground truth and prediction side by side (PNG, .glb)", run)
    common_options(p)
    model_source_options(p, "mesh benchmark (default: the checkpoint's or weights', else cloth)")
    p.add_argument(
        "--windows", type=int, nargs="+", default=[0, 1, 2], help="test windows to draw, by number"
    )
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="model hyper-parameter")
    task_options(p)
    p.add_argument("--out", help="folder (default: results/<benchmark>/renders)")


def run(args) -> int:
    from zoo.report.render import render_windows

    registry = registry_of(args)
    source = model_source(args)
    bench = benchmark_of(args, source, "cloth")
    if not bench.strategy.drawn:
        raise UsageError(
            f"zoo render draws meshes; benchmark {bench.name!r} is a {bench.representation} one"
        )
    dataset = bench.load(args.data_root)
    loaded = source.load(registry, bench, dataset, args.data_root)
    out = Path(args.out) if args.out else RESULTS_DIR / bench.name / "renders"
    written = render_windows(
        loaded.model,
        loaded.label,
        bench,
        dataset,
        args.windows,
        out,
        task=args.task,
        horizon=args.horizon_frames,
    )
    print("wrote " + ", ".join(str(p) for p in written))
    return 0
