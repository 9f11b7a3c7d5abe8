"""``zoo costs``: measure the tables' cost columns."""

from __future__ import annotations

import sys
from pathlib import Path

from zoo.cli.common import (
    Deprecated,
    UsageError,
    add_command,
    committed_benchmarks,
    common_options,
    registry_of,
    results_option,
    weights_dir_option,
)
from zoo.core.budgets import COST_SECONDS
from zoo.paths import REPO_ROOT


def add(sub) -> None:
    p = add_command(
        sub,
        "costs",
        "measure the tables' cost columns (float32, time-boxed) into "
        "results/<benchmark>/costs.json and re-render those columns",
        run,
    )
    common_options(p)
    p.add_argument(
        "--benchmark",
        action="append",
        help="benchmark(s); default every benchmark with tables under --results",
    )
    p.add_argument(
        "--model",
        action="append",
        metavar="NAME",
        help="measure only this registry model's rows (repeatable); the other stored costs "
        "are kept",
    )
    p.add_argument(
        "--seconds",
        type=float,
        default=COST_SECONDS,
        help="time budget per model; a slow model gets fewer latency calls and training "
        "steps, and says so",
    )
    results_option(p)
    p.add_argument("--out", dest="results", action=Deprecated, new="--results")
    weights_dir_option(p, "folder of shipped weights, as zoo leaderboard")
    p.add_argument("--weights", dest="weights_dir", action=Deprecated, new="--weights-dir")
    p.add_argument(
        "--checkpoints",
        default=str(REPO_ROOT / "checkpoints"),
        help="folder of trained checkpoints, as zoo leaderboard",
    )


def run(args) -> int:
    import time

    from zoo.leaderboard.costs import NoRowsError, measure_costs
    from zoo.report.outputs import write_index

    if not args.seconds > 0:
        raise UsageError(f"--seconds {args.seconds:g}: expected a positive time budget")
    registry = registry_of(args)
    benchmarks = args.benchmark or committed_benchmarks(Path(args.results))
    if not benchmarks:
        raise UsageError(f"{args.results}: no committed table; give --benchmark NAME")
    started, measured = time.perf_counter(), 0
    for bench in benchmarks:
        try:
            measure_costs(
                bench,
                registry=registry,
                data_root=args.data_root,
                out_root=Path(args.results),
                weights=Path(args.weights_dir),
                checkpoints=Path(args.checkpoints),
                device=args.device,
                models=args.model or (),
                seconds=args.seconds,
            )
            measured += 1
        except NoRowsError as e:
            if args.benchmark:  # named: its rows were expected
                raise
            print(f"{e}: skipped", file=sys.stderr)
    if not measured:
        raise UsageError(
            f"no table under {args.results} has a row of {', '.join(args.model or ['any model'])}"
        )
    print(f"wrote {write_index(Path(args.results))} ({time.perf_counter() - started:.0f} s)")
    return 0
