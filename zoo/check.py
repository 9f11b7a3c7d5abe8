"""``zoo leaderboard --check``: freshly recomputed rows compared with the committed tables,
value by value and window by window, against :mod:`zoo.tolerance`; what was found, per table
and overall (:class:`CheckReport`). The leaderboard recomputes; this module compares and
reports, and writes nothing."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from zoo.tolerance import KEY_COLUMNS, tolerance_text
from zoo.tolerance import allowed as tolerated


@dataclass
class CheckReport:
    """What ``zoo leaderboard --check`` found: rows and tables recomputed, the largest
    difference from the committed values (and where), and every problem (a value outside its
    tolerance, a row or table missing on either side, a row that cannot be recomputed).

    Tolerances follow from the arithmetic (see :data:`TOLERANCES`): a value is named when it
    differs from the committed one by more than ``tolerance(metric) * max(|value|, scale)``."""

    rows: int = 0
    tables: int = 0
    models: set = field(default_factory=set)
    largest: tuple = (0.0, 0.0, 0.0, "")  # (share of its tolerance, relative, absolute, where)
    problems: list = field(default_factory=list)
    # per table ("<benchmark>/<table>"): rows checked, largest share of the tolerance, problems
    per_table: dict = field(default_factory=dict)
    current: str = ""

    def start_table(self, name: str) -> None:
        self.current = name
        self.per_table.setdefault(name, {"rows": 0, "share": 0.0, "problems": []})

    def problem(self, text: str) -> None:
        """A problem of the table being checked (or of the run, outside any table)."""
        self.problems.append(text)
        if self.current:
            self.per_table[self.current]["problems"].append(text)

    def table_lines(self) -> list[str]:
        """One line per table: rows checked and the largest difference as a share of the
        tolerance, or its problems (the first named: a refusal and its reason)."""
        return [self.table_line(name) for name in self.per_table]

    def table_line(self, name: str) -> str:
        t = self.per_table[name]
        verdict = (
            f"{len(t['problems'])} problem(s), first: {t['problems'][0]}"
            if t["problems"]
            else "passed"
        )
        return (
            f"{name}: {t['rows']} rows checked, largest difference {t['share']:.2f} of "
            f"the tolerance: {verdict}"
        )

    def note(self, gap: np.ndarray, old: np.ndarray, allowed: np.ndarray, where) -> None:
        """Keep the largest difference (measured as a share of its tolerance) and where
        (``where``: text, or a function of the position of that difference)."""
        if not gap.size:
            return
        share = gap / allowed
        i = int(np.argmax(share))
        if self.current:
            table = self.per_table[self.current]
            table["share"] = max(table["share"], float(share.flat[i]))
        if share.flat[i] > self.largest[0] or not self.largest[3]:
            relative = gap.flat[i] / max(abs(old.flat[i]), 1e-12)
            self.largest = (
                float(share.flat[i]),
                float(relative),
                float(gap.flat[i]),
                where(i) if callable(where) else where,
            )

    def summary(self) -> str:
        share, relative, absolute, where = self.largest
        return (
            f"checked {self.rows} rows of {len(self.models)} models in {self.tables} tables "
            f"against tolerance {tolerance_text()}: largest difference {absolute:.2g} "
            f"({relative:.2g} relative, {share:.2f} of its tolerance) at {where or '-'}"
        )


def check_table(
    results: list, folder: Path, check: CheckReport, unplanned: set = frozenset()
) -> None:
    """Compare freshly computed results with the committed table in ``folder`` (its rows'
    ``results.csv``, and each model's per-window errors with its ``windows.npz``)."""
    from zoo.results import TABLE_FILE, WINDOWS_FILE, WindowErrors, read_table

    check.tables += 1
    fresh = pd.concat([r.frame for r in results], ignore_index=True)
    if check.current:
        check.per_table[check.current]["rows"] += len(fresh)
    check.rows += len(fresh)
    check.models |= set(fresh["model"])
    if not (folder / TABLE_FILE).is_file():
        check.problem(f"{folder}/{TABLE_FILE}: missing; the leaderboard makes this table")
        return
    committed = read_table(folder).frame
    committed = committed[~committed["model"].isin(unplanned)]  # named once, as folders
    both = fresh.merge(
        committed, on=KEY_COLUMNS, how="outer", suffixes=("", "_committed"), indicator="side"
    )
    for row in both[both["side"] != "both"].itertuples():
        where = "committed only" if row.side == "right_only" else "recomputed only"
        check.problem(
            f"{folder}: {where}: " + ", ".join(f"{k}={getattr(row, k)}" for k in KEY_COLUMNS)
        )
    matched = both[both["side"] == "both"]
    for column in ("value", "std"):  # the mean and its standard deviation over windows
        if f"{column}_committed" not in matched:
            check.problem(
                f"{folder}: no column {column!r} (written by an older zoo); regenerate the table"
            )
            continue
        new, old = matched[column].to_numpy(float), matched[f"{column}_committed"].to_numpy(float)
        scale = matched["value_committed"].to_numpy(float)  # a std is held to its mean's
        difference = np.abs(new - old)
        relative = difference / np.maximum(np.abs(old), 1e-12)
        nan = np.isnan(new) | np.isnan(old)  # a NaN (one window's spread) matches only a NaN
        allowed = tolerated(matched["metric"].to_numpy(), scale)
        differs = np.where(nan, np.isnan(new) != np.isnan(old), difference > allowed)
        keep = ~nan
        rows = matched[keep]
        check.note(
            difference[keep],
            old[keep],
            allowed[keep],
            lambda i, rows=rows, column=column: (
                f"{folder.parent.name}/{folder.name} "
                + ", ".join(f"{k}={rows.iloc[i][k]}" for k in KEY_COLUMNS)
                + f" ({column})"
            ),
        )
        for row, rel in zip(matched[differs].itertuples(), relative[differs]):
            check.problem(
                f"{folder}: "
                + ", ".join(f"{k}={getattr(row, k)}" for k in KEY_COLUMNS)
                + f": {column} committed "
                f"{getattr(row, column + '_committed')!r}, recomputed {getattr(row, column)!r} "
                f"(relative {rel:.2g}; tolerance {tolerance_text()})"
            )
    for row in (
        matched[matched["protocol_id"] != matched["protocol_id_committed"]]
        .drop_duplicates("model")
        .itertuples()
    ):
        check.problem(
            f"{folder}: {row.model}: protocol "
            f"{row.protocol_id_committed} committed, {row.protocol_id} now"
        )
    for r in results:
        if r.windows is None:
            continue
        label = str(r.frame["model"].iloc[0])
        path = folder / label / WINDOWS_FILE
        if not path.is_file():
            check.problem(f"{path}: missing (per-window errors of {label})")
            continue
        stored = WindowErrors.read(path)
        same_windows = np.array_equal(stored.start, r.windows.start) and np.array_equal(
            stored.sequence, r.windows.sequence
        )
        for key, values in r.windows.errors.items():
            old = stored.errors.get(key)
            if old is None or not same_windows:
                check.problem(f"{path}: {'/'.join(key)}: missing or for other windows")
                continue
            old = old.astype(np.float64)
            gap = np.abs(old - values)
            relative = gap / np.maximum(np.abs(old), 1e-12)
            allowed = tolerated(key[1], old)
            check.note(
                gap,
                old,
                allowed,
                f"{folder.parent.name}/{folder.name}/{label}/{WINDOWS_FILE} {'/'.join(key)}",
            )
            if (gap > allowed).any():
                check.problem(
                    f"{path}: {'/'.join(key)}: per-window errors differ "
                    f"beyond tolerance (relative up to {relative.max():.2g}, "
                    f"absolute up to {gap.max():.2g}; tolerance "
                    f"{tolerance_text()})"
                )
