"""``zoo site``: the leaderboards as a static site."""

from __future__ import annotations

import sys
from pathlib import Path

from zoo.cli.common import (
    Deprecated,
    add_command,
    committed_benchmarks,
    registry_of,
    registry_option,
    results_option,
    weights_dir_option,
)
from zoo.paths import REPO_ROOT


def add(sub) -> None:
    p = add_command(
        sub,
        "site",
        "build the leaderboards as a static site (every table, curve, card and mesh clip; "
        "opens from file://, offline)",
        run,
    )
    p.add_argument(
        "--out",
        help="site folder, replaced whole (default: site/ for the repository's results, else "
        "<results>/site)",
    )
    results_option(p, "results root to read")
    weights_dir_option(p, "shipped weights folder")
    p.add_argument("--weights", dest="weights_dir", action=Deprecated, new="--weights-dir")
    p.add_argument(
        "--cards",
        help="model cards folder (default: where zoo cards writes them for --results: "
        "docs/models, or <results>/cards)",
    )
    p.add_argument(
        "--clips",
        action="store_true",
        help="first (re)write each mesh benchmark's clips.npz from its data and shipped weights "
        "(minutes; the site itself needs neither)",
    )
    p.add_argument(
        "--benchmark",
        action="append",
        default=[],
        help="with --clips: only this mesh benchmark (repeatable; default: every mesh benchmark "
        "with a table)",
    )
    p.add_argument("--data-root", help="with --clips: the benchmark's data folder")
    registry_option(p)


def run(args) -> int:
    import time

    started = time.perf_counter()  # the whole command: the build's imports load torch and pandas
    from zoo.site import build_site

    results = Path(args.results)
    if args.clips:
        from zoo.report.clips import CLIPS_FILE, write_benchmark_clips

        registry = registry_of(args)
        for name in args.benchmark or _mesh_benchmarks(results):
            path = write_benchmark_clips(
                name, registry, Path(args.weights_dir), results / name / CLIPS_FILE, args.data_root
            )
            print(f"wrote {path}")
    from zoo.store.layout import is_repository_results

    own = is_repository_results(results)
    out = Path(args.out) if args.out else REPO_ROOT / "site" if own else results / "site"
    build = build_site(
        out,
        results,
        weights_root=Path(args.weights_dir),
        cards_dir=Path(args.cards) if args.cards else _cards(results),
        registry=registry_of(args),
    )
    for line in build.warnings:
        print(f"warning: {line}", file=sys.stderr)
    print(
        f"wrote {len(build.pages)} pages to {build.out} ({build.bytes / 1e6:.1f} MB) in "
        f"{time.perf_counter() - started:.1f} s ({build.seconds:.1f} s writing them): open "
        f"{build.out / 'index.html'} in a browser (file://, offline)"
    )
    return 0


def _cards(results: Path) -> Path:
    """The cards ``zoo cards --results`` wrote for ``results``, else the repository's."""
    from zoo.report.cards import CARDS_DIR, cards_dir_for

    cards = cards_dir_for(results)
    return cards if cards.is_dir() else CARDS_DIR


def _mesh_benchmarks(results: Path) -> list[str]:
    from zoo.protocol.benchmark import get_benchmark

    return [name for name in committed_benchmarks(results) if get_benchmark(name).strategy.drawn]
