"""``zoo leaderboard --check``: every committed row recomputed on the plan's sample of
windows and compared with its table (the verdict: :mod:`.verdict`); nothing is written.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from zoo.evaluation.results import table_files
from zoo.hub.weights import fetch_command
from zoo.leaderboard.plan import Leaderboard, TablePlan, why_not_planned
from zoo.leaderboard.rounding import rounding_margins
from zoo.leaderboard.verdict import (
    check_identity,
    check_table,
)
from zoo.store.identity import (
    stored_identity,
)


class Check(Leaderboard):
    """The committed tables of one benchmark recomputed and compared; nothing written."""

    def __init__(self, **options) -> None:
        if options.get("plan") is None or options["plan"].check is None:  # before any data
            raise ValueError("Check needs a plan with a CheckReport (Plan(check=...))")
        super().__init__(**options)

    def run(self) -> list[Path]:
        bench, check = self.bench, self.plan.check
        written = []
        self._refuse_models_without_rows()
        for sampler, task, truth, folder in self.tables():
            started = time.perf_counter()
            try:  # a check goes on to the next table whatever fails in this one
                table = self.plan_table(sampler, task, truth, folder)
                outcome = None if table is None else self._check_table(table)
            except Exception as e:  # noqa: BLE001
                check.start_table(f"{bench.name}/{folder}")
                check.problem(f"{bench.name}/{folder}: not checked: {e}")
                outcome = True
            if outcome:  # each table's verdict as soon as it is known, not only at the end
                print(f"{check.table_line(check.current)} ({time.perf_counter() - started:.0f} s)")
            if outcome is not None:
                written.append(self.root / bench.name / folder)
        produced = {p.name for p in written}
        for table in table_files(self.root / bench.name):
            if table.parent.name not in produced:
                check.current = ""
                check.problem(f"{table}: a committed table that the leaderboard no longer produces")
        return written

    def _check_table(self, table: TablePlan) -> bool | None:
        """Recompute every planned row on the check's sample and compare with the committed
        table; nothing written."""
        check, where = self.plan.check, table.where
        failed = set()
        for r in table.rows:
            if r.action == "skip":
                print(f"{where}: {r.row.label}: not checked (from {r.why})", file=sys.stderr)
                continue
            check.tables[where].rows.append(r.row.label)
            if r.action == "failed":
                check.problem(f"{where}: {r.row.label}: not recomputed: {r.error}")
                failed.add(r.row.label)
            elif r.stored is not None:
                check_identity(r.row.label, stored_identity(r.stored), r.identity, check)
        pending = [r for r in table.rows if r.action == "compute"]
        fresh, computed = [], []
        for r, result in zip(pending, self._compute(table, pending, "checking")):
            if isinstance(result, Exception):
                check.problem(f"{where}: {r.row.label}: not recomputed: {result}")
                failed.add(r.row.label)
            else:
                fresh.append(result)
                computed.append((r.row.label, r.loaded.model, r.loaded.view, result))
        for p in table.foreign:
            held = self.withheld(p.name)
            if held is not None:  # the weights' licence keeps them out: what makes them here
                check.needs_files(f"{p.name}: {fetch_command(*held)}")
            else:
                check.problem(f"{p}: cannot be recomputed ({why_not_planned(p, self)})")
        if fresh:
            # a row not recomputed is named once, above, not once per committed value
            unplanned = {p.name for p in table.foreign} | failed
            # windows beyond the a-priori tolerance: held to their rounding sensitivity too
            margins = rounding_margins(
                computed, table.path, table.sample, table.protocol, self.device
            )
            check_table(
                fresh, table.path, check, unplanned=unplanned, rows=table.sample, margins=margins
            )
        checked = [r for r in table.rows if r.action != "skip"]
        return True if fresh or table.foreign or checked else None
