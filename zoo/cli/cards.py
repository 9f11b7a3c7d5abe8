"""``zoo cards``: the model cards from the registry, weights records and results."""

from __future__ import annotations

from pathlib import Path

from zoo.cli.common import (
    Deprecated,
    add_command,
    registry_of,
    registry_option,
    results_option,
    weights_dir_option,
)
from zoo.paths import REPO_ROOT


def add(sub) -> None:
    p = add_command(
        sub,
        "cards",
        "write the model cards (docs/models/<model>.md) from the registry, the shipped "
        "weights' records and results/; --check names the stale ones",
        run,
    )
    registry_option(p)
    p.add_argument("--check", action="store_true", help="write nothing; exit 1 if a card is stale")
    p.add_argument(
        "--out",
        help="cards folder (default: docs/models for the repository's results, else "
        "<results>/cards: nothing is written into the repository unless asked)",
    )
    weights_dir_option(p, "shipped weights folder")
    p.add_argument("--weights", dest="weights_dir", action=Deprecated, new="--weights-dir")
    results_option(p)
    p.add_argument(
        "--readme",
        help="a Markdown file whose headline tables (<!-- headline ... --> blocks) are "
        "rewritten from --results too (default: the repository's README.md for its own "
        "results, else none; '' for none)",
    )


def run(args) -> int:
    from zoo.report.cards import build_cards, cards_dir_for

    results = Path(args.results)
    from zoo.store.layout import is_repository_results

    own = is_repository_results(results)
    readme = args.readme if args.readme is not None else str(REPO_ROOT / "README.md") * own
    statuses = build_cards(
        Path(args.out) if args.out else cards_dir_for(results),
        registry=registry_of(args),
        weights_root=Path(args.weights_dir),
        results_root=results,
        write=not args.check,
        readme=Path(readme) if readme else None,
    )
    stale = [s for s in statuses if not s.fresh]
    for s in statuses:
        state = "up to date" if s.fresh else s.reason
        verb = "" if s.fresh or args.check else " (rewritten)"
        print(f"{s.path}: {state}{verb}")
        if args.check:
            for line in s.diff[:6]:
                print(f"    {line}")
    if args.check and stale:
        print(f"{len(stale)} of {len(statuses)} card(s) stale: run `zoo cards` to rewrite them")
        return 1
    return 0
