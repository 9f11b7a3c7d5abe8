"""A table's plots drawn against copied from the stored table, side by side in one run.

A rebuild draws each table's ``<metric>.png`` only when what it shows changed: the stored PNG
keeps a digest of its rows, title, styles and plotting code (its ``Drawn-From`` text), and a
plot with the same digest is copied (:func:`zoo.report.outputs.plot_average`). For each table
given, this times ``plot_average`` drawing into an empty folder (``drawn``: what every rebuild
paid before) and with the drawn folder as the stored one (``copied``), as medians of
``--repeats`` runs taken in turn, and says whether the copies are the drawn files byte for byte
and how many plots the copying runs drew (they must be, and none). ``tight`` times the drawing
laid out by matplotlib's ``tight_layout``, as plots were before their margins were fixed
(:func:`zoo.report.outputs.place_panels`), beside the drawing as it is.

Run: python benchmarks/speed/speed_plots.py [--table results/cmu/all ...] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path
from unittest import mock

from zoo.evaluation.results import read_table
from zoo.paths import REPO_ROOT
from zoo.report import outputs
from zoo.report.outputs import plot_average, table_title


def measure(table: Path, repeats: int) -> dict:
    frame = read_table(table).frame
    title = table_title((table / "leaderboard.md").read_text())
    drawn_s, copied_s, tight_s, same, redrawn = [], [], [], True, 0
    draw = outputs.save_figure

    def counted(*args, **kwargs):
        nonlocal redrawn
        redrawn += 1
        draw(*args, **kwargs)

    def laid_out_tight(fig, path, drawn_from=None, **_):
        draw(fig, path, drawn_from, tight=True)

    with tempfile.TemporaryDirectory() as tmp:

        def timed(save, folder, previous=None):
            """plot_average's seconds and files, each figure saved through ``save``."""
            with mock.patch.object(outputs, "save_figure", save):
                started = time.perf_counter()
                files = plot_average(frame, Path(tmp) / folder, title, previous)
                return time.perf_counter() - started, files

        for i in range(repeats):
            tight_s.append(timed(laid_out_tight, f"tight{i}")[0])
            seconds, drawn = timed(draw, f"drawn{i}")
            drawn_s.append(seconds)
            # a copy draws nothing: counted, not assumed
            seconds, copied = timed(counted, f"copied{i}", drawn[0].parent)
            copied_s.append(seconds)
            same &= all(a.read_bytes() == b.read_bytes() for a, b in zip(drawn, copied))
    drawn_m, copied_m = statistics.median(drawn_s), statistics.median(copied_s)
    tight_m = statistics.median(tight_s)
    return {
        "table": str(table),
        "plots": len(drawn),
        "drawn": drawn_m,
        "copied": copied_m,
        "ratio": drawn_m / copied_m,
        "tight": tight_m,
        "tight_ratio": tight_m / drawn_m,
        "same": same,
        "redrawn": redrawn,
    }


def over_tables(
    argv, description: str, default: list[Path], header: str, measure, line
) -> list[dict]:
    """A speed script over committed tables: ``--table`` folders (``default``) and
    ``--repeats``; ``measure(table, repeats)`` each, printed under ``header`` as
    ``line(name, row)``. Returns the rows."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--table", nargs="+", type=Path, default=default)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    print(header)
    rows = []
    for table in args.table:
        rows.append(measure(table, args.repeats))
        print(line(f"{table.parent.name}/{table.name}", rows[-1]))
    return rows


def _line(name: str, r: dict) -> str:
    same = "the same bytes" if r["same"] else "DIFFER"
    return (
        f"{name:<21} {r['plots']:5d}  {r['drawn']:9.3f}  {r['copied']:10.4f}  "
        f"{r['ratio']:11.0f}x  {same}, {r['redrawn']} redrawn  {r['tight']:9.3f}  "
        f"{r['tight_ratio']:10.2f}x"
    )


def main(argv=None) -> list[dict]:
    return over_tables(
        argv,
        __doc__.split("\n\n")[0],
        [REPO_ROOT / "results" / "cmu" / "all", REPO_ROOT / "results" / "cloth" / "all"],
        "table                 plots  drawn (s)  copied (s)  drawn/copied  files, redrawn"
        "  tight (s)  tight/drawn",
        measure,
        _line,
    )


if __name__ == "__main__":
    main()
