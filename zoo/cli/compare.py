"""``zoo compare``: is A better than B?"""

from __future__ import annotations

from pathlib import Path

from zoo.cli.common import (
    UsageError,
    add_command,
    checked_sampler,
    positive_int,
    results_option,
)


def add(sub) -> None:
    p = add_command(
        sub,
        "compare",
        "is A better than B? paired differences per horizon, intervals, sign test; or A's "
        "ratio to a published figure",
        run,
    )
    p.add_argument("a", help="model label (with --benchmark) or result folder")
    p.add_argument(
        "b",
        help="model label (with --benchmark) or result folder; or a published figure's label "
        "(zoo/protocol/published.yaml, e.g. 'ltd (reported)'): A's error over it per action",
    )
    p.add_argument("--benchmark", help="benchmark whose results/<benchmark>/<sampler>/ to read")
    p.add_argument("--sampler", help="window sampler (default: the benchmark's)")
    p.add_argument(
        "--ground-truth",
        choices=["raw", "spectral"],
        help="mesh benchmarks: the results scored against this ground truth",
    )
    results_option(p)
    p.add_argument("--metric", help="default: the benchmark's headline (mpjpe; rmse on meshes)")
    p.add_argument("--joints", help="joint protocol (default: the official one, e.g. all38)")
    p.add_argument(
        "--averaging",
        choices=["frame", "cumulative"],
        help="error at each frame, or the mean up to it (default: frame)",
    )
    p.add_argument(
        "--block-frames",
        type=positive_int,
        help="bootstrap block length in frames (default: 2 window lengths, BLOCK_WINDOWS in "
        "zoo/stats/intervals.py)",
    )
    p.add_argument("--confidence", type=float, default=0.95, help="level of the intervals")
    p.add_argument("--replicates", type=positive_int, default=2000, help="bootstrap replicates")
    p.add_argument("--seed", type=int, default=0, help="seed of the bootstrap")
    p.add_argument("--out", help="also write comparison.md and comparison.png in this folder")
    p.add_argument(
        "--actions",
        nargs="+",
        metavar="ACTION",
        help="against a published figure: the actions its mean and worst action cover "
        "(default: every action both have)",
    )


def run(args) -> int:
    from zoo.protocol.benchmark import get_benchmark
    from zoo.stats.comparison import compare
    from zoo.stats.published_ratio import against_published, published_entry

    if args.sampler is not None:
        checked_sampler(args.sampler, get_benchmark(args.benchmark) if args.benchmark else None)
    entry = None if Path(args.b).is_dir() else published_entry(args.b, args.benchmark)
    if (
        entry is None
        and not Path(args.a).is_dir()
        and published_entry(args.a, args.benchmark) is not None
    ):
        raise UsageError(f"{args.a!r} is a published figure: give it second (zoo compare A B)")
    if entry is None and not Path(args.b).is_dir():
        _check_row_or_published(args.b, args.benchmark)
    if args.actions and entry is None:
        raise UsageError(f"--actions: only against a published figure, and {args.b!r} is none")
    if entry is not None:
        if args.out:
            raise UsageError("--out: a ratio to a published figure is printed only")
        for option, mine in (("metric", args.metric), ("joints", args.joints)):
            if mine is not None and mine != getattr(entry, option):
                raise UsageError(
                    f"--{option} {mine}: {entry.label!r} publishes {getattr(entry, option)}"
                )
        if args.averaging is not None and args.averaging != entry.averaging:
            raise UsageError(
                f"--averaging {args.averaging}: {entry.label!r} publishes {entry.averaging}"
            )
        args.benchmark = args.benchmark or entry.benchmark
    # against a published figure, the table of its own sampler unless told otherwise
    sampler = args.sampler or (entry.protocol.get("sampler") if entry is not None else None)
    folders, bench = [], None
    for name in (args.a,) if entry is not None else (args.a, args.b):
        if Path(name).is_dir():
            folders.append(Path(name))
            continue
        if not args.benchmark:
            raise UsageError(
                f"{name!r} is not a result folder; give --benchmark to find "
                f"results/<benchmark>/<sampler>/{name}"
            )
        from zoo.protocol.benchmark import get_benchmark
        from zoo.store.layout import result_path, table_folder

        bench = get_benchmark(args.benchmark)
        folder = result_path(
            args.results,
            bench.name,
            table_folder(sampler or bench.sampler, truth=args.ground_truth),
            name,
        )
        if not (folder / "results.csv").is_file():
            raise UsageError(
                f"{folder}: no result of {name!r} there (zoo eval or zoo leaderboard writes it)"
                + ("; nor is it a published figure's label" if name == args.b else "")
            )
        folders.append(folder)
    if entry is not None:
        print(against_published(folders[0], entry, actions=args.actions).markdown())
        return 0
    comparison = compare(
        folders[0],
        folders[1],
        metric=args.metric,
        joints=args.joints,
        averaging=args.averaging or "frame",
        block_frames=args.block_frames,
        confidence=args.confidence,
        replicates=args.replicates,
        seed=args.seed,
        # the benchmark's own horizons (a benchmark of one's own at 30 fps has not CMU's)
        horizons_ms=bench.horizons_ms if bench is not None else None,
    )
    print(comparison.markdown())
    if args.out:
        comparison.write(args.out)
        print(f"wrote {args.out}/comparison.md, comparison.png")
    return 0


def _check_row_or_published(name: str, benchmark: str | None) -> None:
    """B that can name no row (a row label names a folder) is a published figure's label
    mistyped, or nothing: say which labels there are, the closest first."""
    import difflib

    from zoo.protocol.published import load_published
    from zoo.store.layout import StoreError, check_label

    try:
        check_label(name)
    except StoreError:
        labels = sorted({e.label for e in load_published() if benchmark in (None, e.benchmark)})
        close = difflib.get_close_matches(name, labels, n=3, cutoff=0.6)
        hint = (
            f"did you mean {', '.join(repr(c) for c in close)}?"
            if close
            else f"published labels{f' on {benchmark}' if benchmark else ''}: "
            + ", ".join(repr(label) for label in labels)
        )
        raise UsageError(
            f"{name!r} is no published figure's label (zoo/protocol/published.yaml) and cannot "
            f"be a row's (a row label is letters, digits and '_.@+=,-'): {hint}"
        ) from None
