"""A table's intervals and bold sets with the bootstrap's draws kept against drawn for every
model, side by side in one run.

Every model of a table is resampled with the same blocks (the paired bootstrap), and the draws
depend on the windows, block sizes and seed but not on a model's errors, so the zoo keeps the
last few sets of draws (:func:`zoo.stats.intervals._block_draws`) rather than draw them again
for each model's interval and again for the bold set. For each table given, this times
:func:`zoo.report.tables.table_views` (every interval and bold set a table shows) with the draws
kept (``kept``) and with nothing kept (``drawn``: each call draws its own, as before), as
medians of ``--repeats`` runs taken in turn, and says whether the two give the same intervals
and bold sets bit for bit (they must).

Run: python benchmarks/speed/speed_intervals.py [--table results/cmu/all ...] [--repeats 3]
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path
from unittest import mock

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from speed_plots import over_tables  # noqa: E402

from zoo.evaluation.results import EvalResult, table_labels  # noqa: E402
from zoo.paths import REPO_ROOT  # noqa: E402
from zoo.report.tables import table_views  # noqa: E402
from zoo.stats import intervals  # noqa: E402


def measure(table: Path, repeats: int) -> dict:
    results = [EvalResult.read(table / label) for label in table_labels(table)]

    def timed(keep: int):
        with (
            mock.patch.object(intervals, "_KEPT_DRAWS", keep),
            mock.patch.object(intervals, "_kept_draws", {}),
        ):
            started = time.perf_counter()
            views = table_views(results)
            return time.perf_counter() - started, views

    timed(0)  # imports and first-call costs, in neither column
    kept_s, drawn_s, same = [], [], True
    for _ in range(repeats):
        seconds, kept = timed(intervals._KEPT_DRAWS)
        kept_s.append(seconds)
        seconds, drawn = timed(0)
        drawn_s.append(seconds)
        same &= kept.keys() == drawn.keys() and all(
            kept[k].tied == drawn[k].tied
            and kept[k].half.keys() == drawn[k].half.keys()
            and all(np.array_equal(kept[k].half[m], drawn[k].half[m]) for m in kept[k].half)
            for k in kept
        )
    kept_m, drawn_m = statistics.median(kept_s), statistics.median(drawn_s)
    return {
        "table": str(table),
        "rows": len(results),
        "views": len(kept),
        "kept": kept_m,
        "drawn": drawn_m,
        "ratio": drawn_m / kept_m,
        "same": same,
    }


def _line(name: str, r: dict) -> str:
    same = "the same bits" if r["same"] else "DIFFER"
    return (
        f"{name:<31} {r['rows']:4d}  {r['views']:5d}  {r['kept']:8.3f}  {r['drawn']:9.3f}  "
        f"{r['ratio']:9.2f}x  {same}"
    )


def main(argv=None) -> list[dict]:
    return over_tables(
        argv,
        __doc__.split("\n\n")[0],
        [REPO_ROOT / "results" / "cmu" / "all", REPO_ROOT / "results" / "cmu" / "ltd8"],
        f"{'table':<31} rows  views  kept (s)  drawn (s)  drawn/kept  intervals, bold",
        measure,
        _line,
    )


if __name__ == "__main__":
    main()
