"""``zoo leaderboard``: rebuild the tables of results/, or check them (``--check``)."""

from __future__ import annotations

import sys
from pathlib import Path

from zoo.cli.common import (
    Deprecated,
    UsageError,
    add_command,
    committed_benchmarks,
    common_options,
    default_benchmarks,
    registry_of,
    results_option,
    weights_dir_option,
)
from zoo.core.budgets import CHECK_WINDOWS
from zoo.paths import REPO_ROOT


def add(sub) -> None:
    p = add_command(sub, "leaderboard", "re-evaluate and rebuild results/<benchmark>/", run)
    common_options(p)
    p.add_argument(
        "--benchmark",
        action="append",
        help="benchmark(s); default cloth, and cmu where its data is present",
    )
    results_option(p)
    p.add_argument("--out", dest="results", action=Deprecated, new="--results")
    weights_dir_option(
        p, "folder of shipped weights <benchmark>/<label>.safetensors; a trained row with "
        "shipped weights is computed from them",
    )  # fmt: skip
    p.add_argument("--weights", dest="weights_dir", action=Deprecated, new="--weights-dir")
    p.add_argument(
        "--checkpoints",
        default=str(REPO_ROOT / "checkpoints"),
        help="folder of trained checkpoints <benchmark>/<model>/best.pt (where zoo train writes)",
    )
    p.add_argument(
        "--check",
        action="store_true",
        help="write nothing: recompute every row of every committed table (default: "
        "every benchmark under --results) on a sample of its windows (--windows, --full), "
        "recompute each row's averages from its stored per-window errors, and exit 1 "
        "naming each value that differs by more than float32 rounding across CPUs "
        "(tolerances in the summary) and each row whose weights are not the recorded ones",
    )
    p.add_argument(
        "--windows",
        type=int,
        metavar="N",
        help=f"windows a table's sample has (default {CHECK_WINDOWS}, every action among "
        "them): what --check recomputes, and what verifies a row stale only because code "
        "changed before it is re-stamped",
    )
    p.add_argument(
        "--seed", type=int, help="the sample's seed (default: drawn anew each run, and printed)"
    )
    p.add_argument(
        "--full",
        action="store_true",
        help="every window: --check recomputes every row in full, and a row stale only "
        "because code changed is recomputed instead of verified on a sample",
    )
    p.add_argument(
        "--model",
        action="append",
        metavar="NAME",
        help="add or refresh only this model's rows (repeatable); every other "
        "stored row is kept as it is",
    )
    p.add_argument(
        "--recompute",
        nargs="*",
        metavar="BENCHMARK",
        help="recompute every row (of these benchmarks; alone: of all) instead of "
        "reusing stored rows whose identity holds",
    )
    p.add_argument(
        "--base",
        metavar="RESULTS",
        help="a results folder to start from (e.g. the repository's results/): its tables of "
        "each benchmark are copied under --results where that has none, so the rebuild "
        "there shows their rows beside yours; RESULTS itself is never written",
    )
    p.add_argument(
        "--drop",
        action="append",
        metavar="LABEL",
        help="remove this row's result folder from the tables (repeatable): the way "
        "to delete a row the leaderboard did not make",
    )


def run(args) -> int:
    import time

    from zoo.leaderboard.check import Check
    from zoo.leaderboard.plan import Plan
    from zoo.leaderboard.rebuild import Rebuild
    from zoo.leaderboard.verdict import CheckReport, fresh_seed

    registry = registry_of(args)
    if args.windows is not None and args.windows < 1:
        raise UsageError(f"--windows {args.windows}: expected a positive number of windows")
    if args.seed is not None and not 0 <= args.seed < 2**32:
        raise UsageError(f"--seed {args.seed}: expected an integer in 0..2**32-1")
    if args.windows is not None and args.full:
        raise UsageError("--windows samples; --full checks every window: give one of them")
    windows = None if args.full else (args.windows or CHECK_WINDOWS)
    seed = args.seed if args.seed is not None else fresh_seed()
    check = CheckReport(windows=windows, seed=seed) if args.check else None
    if check and (args.recompute is not None or args.model or args.drop):
        raise UsageError(
            "--check recomputes every committed row and writes nothing; it takes "
            "no --recompute, --model or --drop"
        )
    if check:
        print(
            "zoo leaderboard --check: "
            + (
                "every window of every table (--full)"
                if windows is None
                else f"{windows} windows a table, every action among them (seed {seed}; "
                f"--seed {seed} draws them again; --full checks every window)"
            ),
            file=sys.stderr,
        )
    if not args.benchmark:
        args.benchmark = (
            committed_benchmarks(Path(args.results)) if check else list(default_benchmarks())
        )
    names = [Path(b).stem for b in args.benchmark]
    unknown = sorted(set(args.recompute or ()) - set(names))
    if unknown:
        raise UsageError(
            f"--recompute {' '.join(unknown)}: not among the benchmarks of this run "
            f"({', '.join(names)})"
        )
    if check:
        from zoo.evaluation.results import TABLE_FILE, table_files

        for name in names:
            if not table_files(Path(args.results) / name):
                raise UsageError(
                    f"--check: no committed table of {name} under {args.results} "
                    f"(expected {args.results}/{name}/<sampler>/{TABLE_FILE})"
                )
    for model in args.model or ():  # a misspelt name or a class that cannot load: before any data
        registry.get(model).load_class()
    if args.base is not None:
        if check:
            raise UsageError("--base starts a rebuild elsewhere; --check writes nothing")
        base = Path(args.base)
        if not base.is_dir():
            raise UsageError(f"--base {base}: no such results folder")
        if base.resolve() == Path(args.results).resolve():
            raise UsageError(f"--base {base} is --results itself: name another --results")
        from zoo.leaderboard.rebuild import copy_benchmark_tables

        for name in names:
            copied = copy_benchmark_tables(base, args.results, name)
            print(f"{name}: {len(copied)} table(s) copied from {base}", file=sys.stderr)
    started = time.perf_counter()
    for bench, name in zip(args.benchmark, names):
        plan = Plan(
            recompute=args.recompute is not None and (not args.recompute or name in args.recompute),
            models=frozenset(args.model or ()),
            drop=frozenset(args.drop or ()),
            check=check,
            windows=windows,
            seed=seed,
        )

        def tables(bench=bench, plan=plan):
            """This benchmark's tables under this run's plan, their data loaded."""
            return (Check if check else Rebuild).of(
                bench,
                registry=registry,
                data_root=args.data_root,
                out_root=Path(args.results),
                checkpoints=Path(args.checkpoints),
                weights=Path(args.weights_dir),
                device=args.device,
                plan=plan,
            )

        if check is None:
            tables().run()
            continue
        print(f"checking {name} ...", file=sys.stderr)
        try:  # a benchmark that cannot be loaded at all is reported; the others are checked
            tables().run()
        except Exception as e:  # noqa: BLE001
            check.start_table(f"{name} (not loaded, or a table not finished)")
            check.problem(f"{name}: not checked: {e}")
    if check is None:
        from zoo.report.outputs import write_index

        print(f"wrote {write_index(Path(args.results))} ({time.perf_counter() - started:.0f} s)")
        return 0
    for problem in check.problems:
        print(f"zoo leaderboard --check: {problem}", file=sys.stderr)
    first, *rest = check.summary()
    print(
        f"{first} ({', '.join(names)}; {time.perf_counter() - started:.0f} "
        f"s){'' if not check.problems else f'; {len(check.problems)} problem(s) above'}"
    )
    for line in rest:
        print(line)
    return 1 if check.problems else 0
