"""Leaderboards: bring every table of a benchmark up to date (``regenerate``: stored rows
reused while their identity holds, new and stale rows recomputed through
:mod:`zoo.evaluation.pipeline`),
or recompute the committed ones without writing (``Plan(check=...)``, compared by
:mod:`zoo.leaderboard.check`). What a table's folder holds is written by
:mod:`zoo.report.outputs`."""

from __future__ import annotations

import json
import os
import shutil
import sys
import time
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any

from zoo.core.io import atomic_path, atomic_write_json, replace_folder, repo_relative
from zoo.evaluation.pipeline import Subject, compute_all
from zoo.evaluation.results import TABLE_FILE, table_files
from zoo.evaluation.tolerance import agreement, sample_agreement
from zoo.hub.model_source import ModelSource
from zoo.leaderboard.check import (
    CHECK_WINDOWS,
    CheckReport,
    check_identity,
    check_table,
    draw_sample,
    fresh_seed,
    generated_data_hash,
    self_consistent,
    verification_record,
)
from zoo.leaderboard.efficiency import COSTS_FILE, Costs, architecture, cost_key
from zoo.leaderboard.rounding import rounding_margins
from zoo.paths import REPO_ROOT
from zoo.protocol.comparable import protocol_differences
from zoo.protocol.plan import plan_protocol
from zoo.report.outputs import plot_training_curves, training_curves, write_leaderboard
from zoo.store.identity import (
    identity_differences,
    only_code_changed,
    restamp_record,
    stored_identity,
)
from zoo.store.layout import RESULTS_DIR, StoreError, table_folder
from zoo.store.ownership import recorded_registry, refuse_foreign_registry, stored_provenance


@dataclass
class Plan:
    """What one ``zoo leaderboard`` run does on a benchmark. ``recompute``: every row anew;
    ``models``: (re)compute only these models' rows, keep every other stored row as it is;
    ``drop``: labels whose result folders are removed (deliberately) from the tables;
    ``check``: write nothing, recompute every committed row (on the report's sample of windows)
    and compare. ``windows`` and ``seed``: a row stale only because code changed is verified on
    that many windows (:func:`zoo.leaderboard.check.draw_sample`) and re-stamped if they agree, else
    recomputed; None: recomputed on every window."""

    recompute: bool = False
    models: frozenset = frozenset()
    drop: frozenset = frozenset()
    check: CheckReport | None = None
    windows: int | None = CHECK_WINDOWS
    seed: int = field(default_factory=fresh_seed)


@dataclass
class Row:
    """One planned row of a table: a label and where its model comes from."""

    label: str
    name: str
    source: ModelSource


@dataclass
class RowPlan:
    """What a run does with one row of a table, decided before anything is computed:
    ``reuse`` (its stored identity holds), ``keep`` (stored, other models asked for), ``skip``
    (not stored, other models asked for), ``verify`` (stale only because code changed: a sample
    decides), ``compute`` (new, stale, asked for, or any row of a check) or ``failed`` (its
    model cannot be loaded: a check reports it)."""

    row: Row
    action: str
    loaded: Any = None
    identity: dict | None = None
    stored: Path | None = None
    why: str | None = None
    error: Exception | None = None


@dataclass
class TablePlan:
    """One table's plan: its folder, protocol, the check's sample (None: every window), each
    planned row's :class:`RowPlan`, the stored rows this run does not plan (kept as stored)
    and those it drops."""

    where: str
    path: Path
    task: str
    protocol: Any
    sample: Any
    rows: list[RowPlan]
    foreign: list[Path]
    dropped: list[Path]


def regenerate(benchmark, *, plan: Plan | None = None, **options) -> list[Path]:
    """Bring ``<out_root>/<benchmark>/<table>/`` up to date for every sampler, task and (mesh
    benchmarks) ground truth of ``benchmark``: reuse each stored row whose identity
    (:mod:`zoo.store.identity`) still holds, recompute rows that are new or stale (saying why), keep
    every result folder it did not plan (a row of a registry not loaded now stays as stored),
    and rewrite a table only when one of its rows changed. ``options``: ``registry``,
    ``data_root``, ``out_root``, ``checkpoints``, ``weights`` and ``device``, as
    :meth:`Leaderboard.of` takes them.

    Rows: every registered model that needs no training; a trainable one from its shipped
    weights ``<weights>/<benchmark>/<label>.safetensors`` (a published row is always computed
    from the published weights), else from its checkpoint ``<checkpoints>/<benchmark>/<model>/
    best.pt`` (and ``last.pt`` as ``<model>@last`` when it trained past its best epoch).
    """
    return Leaderboard.of(benchmark, plan=plan, **options).run()


class Leaderboard:
    """The tables of one benchmark (see :func:`regenerate`)."""

    def __init__(
        self,
        *,
        bench,
        registry,
        root: Path,
        weights: Path | None,
        checkpoints: Path | None,
        device: str,
        plan: Plan,
        data_root=None,
    ) -> None:
        self.bench, self.registry, self.root = bench, registry, root
        self.weights, self.checkpoints, self.device, self.plan = weights, checkpoints, device, plan
        self.dataset = bench.load(data_root)
        self.costs = Costs(root / bench.name / COSTS_FILE)
        if self.costs.old:
            print(
                f"{self.costs.path}: an older format (timings in each recipe's precision), not "
                f"read: cost cells stay empty; zoo costs --benchmark {bench.name} replaces it",
                file=sys.stderr,
            )
        self.counts = {
            "reused": 0,
            "restamped": 0,
            "recomputed": 0,
            "agreed": 0,
            "kept": 0,
            "dropped": 0,
        }
        self.loaded: dict = {}
        self.protocols: dict = {}  # each table's protocol, planned once: {(sampler, task, truth)}
        self._short_training: dict | None = None  # read once: zoo.report.cards.short_training_notes
        unknown = sorted(set(plan.models) - set(registry.list_models()))
        if unknown:
            raise StoreError(
                f"--model {', '.join(unknown)}: not a registered model (add its "
                f"registry with --registry); registered: "
                f"{', '.join(registry.list_models())}"
            )

    @classmethod
    def of(
        cls,
        benchmark,
        *,
        registry=None,
        data_root=None,
        out_root: str | Path | None = None,
        checkpoints: str | Path | None = None,
        weights: str | Path | None = None,
        device: str = "cpu",
        plan: Plan | None = None,
    ) -> Leaderboard:
        """The tables of ``benchmark`` (a name, a YAML path or a Benchmark), its data loaded."""
        from zoo.models.registry import load_registry
        from zoo.protocol.benchmark import get_benchmark

        return cls(
            bench=get_benchmark(benchmark) if isinstance(benchmark, (str, Path)) else benchmark,
            registry=registry or load_registry(),
            root=Path(out_root or RESULTS_DIR),
            weights=Path(weights) if weights else None,
            checkpoints=Path(checkpoints) if checkpoints else None,
            device=device,
            plan=plan or Plan(),
            data_root=data_root,
        )

    def tables(self):
        """``(sampler, task, ground truth, folder)`` of every table the benchmark can have:
        each sampler, each task a registered model has, each ground truth of a mesh."""
        bench = self.bench
        truths = (
            (bench.ground_truths or (bench.ground_truth,))
            if bench.representation == "mesh"
            else (None,)
        )
        tasks = dict.fromkeys(
            ["prediction", *(self.registry.get(n).task for n in self.registry.list_models())]
        )
        for sampler in bench.samplers:
            for task in tasks:
                for truth in truths:
                    yield sampler, task, truth, table_folder(sampler, task, truth)

    def run(self) -> list[Path]:
        bench, check = self.bench, self.plan.check
        written, changed = [], False
        self._refuse_models_without_rows()
        if check is None:
            self._preflight()
        for sampler, task, truth, folder in self.tables():
            started = time.perf_counter()
            if check is not None:
                try:  # a check goes on to the next table whatever fails in this one
                    outcome = self._table(sampler, task, truth, folder)
                except Exception as e:  # noqa: BLE001
                    check.start_table(f"{bench.name}/{folder}")
                    check.problem(f"{bench.name}/{folder}: not checked: {e}")
                    outcome = True
            else:
                outcome = self._table(sampler, task, truth, folder)
            seconds = time.perf_counter() - started
            if outcome and check is not None:
                # each table's verdict as soon as it is known, not only at the end
                print(f"{check.table_line(check.current)} ({seconds:.0f} s)")
            elif outcome:
                print(f"{bench.name}/{folder}: {seconds:.0f} s", file=sys.stderr)
            if outcome is not None:
                written.append(self.root / bench.name / folder)
                changed |= outcome
        check = self.plan.check
        if check is not None:
            produced = {p.name for p in written}
            for table in table_files(self.root / bench.name):
                if table.parent.name not in produced:
                    check.current = ""
                    check.problem(
                        f"{table}: a committed table that the leaderboard no longer produces"
                    )
            return written
        from zoo.stats.sensitivity import protocol_sensitivity

        sensitivity = protocol_sensitivity(self.root / bench.name)
        if sensitivity is not None and sensitivity.write(self.root / bench.name):
            print(f"wrote {self.root / bench.name / 'sensitivity.md'}", file=sys.stderr)
        curves = training_curves(self.weights, bench.name) if self.weights else {}
        png = self.root / bench.name / "training.png"
        if curves and (changed or not png.is_file()):
            plot_training_curves(
                curves, png, title=f"{bench.name}: validation MPJPE while training (shipped models)"
            )
        c = self.counts
        print(
            f"{bench.name}: {c['reused']} row(s) reused, {c['restamped']} re-stamped after a "
            f"code change (a sample agreed), {c['recomputed']} recomputed, "
            f"{c['agreed']} recomputed in agreement with the stored row (files kept), "
            f"{c['kept']} kept as stored (not planned by this registry), {c['dropped']} "
            f"dropped",
            file=sys.stderr,
        )
        return written

    def _refuse_models_without_rows(self) -> None:
        """A model asked for by name (``--model``) that has nothing to be scored from: a
        trainable one with neither shipped weights nor a checkpoint here. Refused naming where
        the leaderboard looked, rather than reporting its other rows reused and exiting 0."""
        empty = []
        for name in self.plan.models:
            entry = self.registry.get(name)
            if entry.leaderboard and not any(r.name == name for r in self.rows(entry.task)):
                trained_as = entry.weights_of or name
                looked = [
                    repo_relative(self.weights / self.bench.name / f"{trained_as}.safetensors")
                    if self.weights
                    else None,
                    repo_relative(self.checkpoints / self.bench.name / trained_as / "best.pt")
                    if self.checkpoints
                    else None,
                ]
                empty.append(f"{name} (looked for {' and '.join(p for p in looked if p)})")
        if empty:
            raise StoreError(
                f"--model {', '.join(empty)}: no trained weights to score, so no row; train it "
                f"(zoo train --model {empty[0].split()[0]} --benchmark {self.bench.name}, with "
                f"--registry for your own) or export its weights (zoo weights export)"
            )

    def _preflight(self) -> None:
        """Before anything is evaluated or written: a stored row that this run would replace
        must be the leaderboard's own (same registry, made by a rebuild); a user's row stops
        the run, naming it and how to keep or drop it."""
        found_drops = set()
        for sampler, task, truth, name in self.tables():
            folder = self.root / self.bench.name / name
            if not folder.is_dir():
                continue
            found_drops |= {p.name for p in folder.iterdir()} & set(self.plan.drop)
            rows = [
                r
                for r in self.rows(task)
                if r.label not in self.plan.drop
                and (folder / r.label / "protocol.json").is_file()
                and (not self.plan.models or r.name in self.plan.models)
            ]
            for row in rows:
                loaded = self.load(row)
                refuse_foreign_registry(folder / row.label, loaded, row.label)
                made_by = stored_provenance(folder / row.label).get("made_by", MADE_BY)
                if made_by == MADE_BY:
                    continue
                differences = identity_differences(
                    stored_identity(folder / row.label),
                    loaded.identity(self.bench, self._protocol(sampler, task, truth).id),
                )
                if differences:
                    raise StoreError(
                        f"{folder / row.label}: row {row.label!r} was made by {made_by}, and "
                        f"the leaderboard's own {row.label!r} differs "
                        f"({'; '.join(differences[:3])}); nothing was changed: keep yours "
                        f"under another label (zoo eval --label NAME), or remove it "
                        f"deliberately with --drop {row.label}"
                    )
        missing = sorted(set(self.plan.drop) - found_drops)
        if missing:
            print(
                f"{self.bench.name}: --drop {', '.join(missing)}: no such row in its tables",
                file=sys.stderr,
            )

    def _protocol(self, sampler: str, task: str, truth: str | None):
        """A table's protocol, planned once for the preflight and the table alike."""
        key = (sampler, task, truth)
        if key not in self.protocols:
            self.protocols[key] = plan_protocol(
                self.bench, self.dataset, sampler=sampler, task=task, ground_truth=truth
            )
        return self.protocols[key]

    def load(self, row: Row):
        """A row's model, built once and used by every table."""
        if row.label not in self.loaded:
            self.loaded[row.label] = row.source.load(self.registry, self.bench, self.dataset)
        return self.loaded[row.label]

    # ---- rows -----------------------------------------------------------------------------

    def rows(self, task: str) -> list[Row]:
        bench, registry = self.bench, self.registry
        # Skeleton models join a mesh benchmark with a joint regressor, fed its regressed joints.
        names = registry.list_models(bench.representation)
        if bench.representation == "mesh" and self.dataset.joint_regressor is not None:
            names += [n for n in registry.list_models("joints") if n not in names]
        rows = []
        planned = (n for n in names if registry.get(n).task == task)
        for name in (n for n in planned if registry.get(n).leaderboard):
            entry = registry.get(name)
            # whose training gives this row its weights: its own, or (weights_of) another's
            trained_as = entry.weights_of or (name if entry.trainable else None)
            if trained_as is None:
                rows.append(Row(name, name, ModelSource.of(name)))
                continue
            variant = {"model": name} if entry.weights_of else {}
            for suffix in ("", "@last"):
                label = name + suffix
                shipped = self._shipped(trained_as + suffix)
                checkpoint = (
                    self.checkpoints
                    / bench.name
                    / trained_as
                    / ("last.pt" if suffix else "best.pt")
                    if self.checkpoints
                    else None
                )
                if shipped is not None:
                    rows.append(
                        Row(label, name, ModelSource.of(weights=shipped, label=label, **variant))
                    )
                    if checkpoint is not None and checkpoint.is_file():
                        print(
                            f"{bench.name}: {label}: the shipped weights {shipped}, not "
                            f"{checkpoint} (zoo weights export publishes a checkpoint)",
                            file=sys.stderr,
                        )
                elif checkpoint is not None and checkpoint.is_file():
                    if suffix and _no_further_than_best(checkpoint):
                        continue  # trained no further than its best epoch: best.pt's weights
                    rows.append(
                        Row(
                            label,
                            name,
                            ModelSource.of(checkpoint=checkpoint, label=label, **variant),
                        )
                    )
        return rows

    def _shipped(self, label: str) -> Path | None:
        """Shipped weights of ``label``: this benchmark's own, else those of the benchmark it
        takes weights from (``weights_from``)."""
        if not self.weights:
            return None
        from zoo.hub.weights import weights_file

        for name in (self.bench.name, self.bench.weights_from):
            path = weights_file(name, label, self.weights) if name else None
            if path is not None and path.is_file():
                return path
        return None

    # ---- one table ------------------------------------------------------------------------

    def _table(self, sampler: str, task: str, truth: str | None, folder: str) -> bool | None:
        """Check or bring one table up to date; None when there is no table to make, else
        whether it was (re)written (a check: whether it was checked)."""
        plan = self.plan_table(sampler, task, truth, folder)
        if plan is None:
            return None
        return self._check_table(plan) if self.plan.check is not None else self._rebuild(plan)

    def plan_table(
        self, sampler: str, task: str, truth: str | None, folder: str
    ) -> TablePlan | None:
        """What a run does with each row of one table, decided before anything is computed or
        written (None: no table to make). Loads the rows' models (once per run)."""
        bench, plan, check = self.bench, self.plan, self.plan.check
        path = self.root / bench.name / folder
        stored = (
            {
                p.name: p
                for p in sorted(path.iterdir())
                if p.is_dir() and (p / "protocol.json").is_file()
            }
            if path.is_dir()
            else {}
        )
        rows = [r for r in self.rows(task) if r.label not in plan.drop]
        if (
            task != "prediction"
            and not any(
                self.registry.get(r.name).trainable or self.registry.get(r.name).weights_of
                for r in rows
            )
            and not any(label not in {r.label for r in rows} for label in stored)
        ):
            return None  # a table of baselines alone says nothing about this task
        protocol = self._protocol(sampler, task, truth)
        where = f"{bench.name}/{folder}"
        sample = None  # the windows a check scores (positions; None: every one)
        if check is not None:
            check.start_table(where)
            sample = check.sample(protocol.actions)
        planned = {r.label for r in rows}
        return TablePlan(
            where=where,
            path=path,
            task=task,
            protocol=protocol,
            sample=sample,
            rows=[self._row_plan(row, stored.get(row.label), protocol) for row in rows],
            foreign=[p for label, p in stored.items() if label not in planned | plan.drop],
            dropped=[p for label, p in stored.items() if label in plan.drop],
        )

    def _row_plan(self, row: Row, old: Path | None, protocol) -> RowPlan:
        plan = self.plan
        if plan.check is not None:  # every row recomputed; one that cannot load is reported
            try:
                loaded = self.load(row)
                return RowPlan(
                    row, "compute", loaded, loaded.identity(self.bench, protocol.id), old
                )
            except Exception as e:  # noqa: BLE001 - every failure is reported, none stops
                return RowPlan(row, "failed", stored=old, error=e)
        if plan.models and row.name not in plan.models and old is None and not plan.recompute:
            return RowPlan(row, "skip")  # neither asked for nor stored: not even loaded
        loaded = self.load(row)
        identity = loaded.identity(self.bench, protocol.id)
        step = partial(RowPlan, row, loaded=loaded, identity=identity, stored=old)
        if plan.recompute:
            return step("compute", why="asked (--recompute)")
        if plan.models and row.name not in plan.models:
            return step("keep")
        if plan.models:
            return step("compute", why="asked (--model)")
        if old is None:
            return step("compute", why="new")
        differences = identity_differences(stored_identity(old), identity)
        if not differences:
            return step("reuse")
        why = "; ".join(differences[:3]) + (" ..." if len(differences) > 3 else "")
        if plan.windows is not None and only_code_changed(differences):
            return step("verify", why=why)
        return step("compute", why=why)

    def _check_table(self, table: TablePlan) -> bool | None:
        """Recompute every planned row on the check's sample and compare with the committed
        table; nothing written."""
        check, where = self.plan.check, table.where
        failed = set()
        for r in table.rows:
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
            check.problem(f"{p}: cannot be recomputed ({_why_not_planned(p, self)})")
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
        return True if fresh or table.foreign or table.rows else None

    def _compute(self, table: TablePlan, pending: list[RowPlan], verb: str) -> list:
        """The pending rows computed in one pass (on the check's sample, where it has one)."""
        if not pending:
            return []
        labels = ", ".join(r.row.label for r in pending)
        print(
            f"{verb} {table.where}: {labels} ({len(pending)} of {len(table.rows)} rows, one pass)",
            file=sys.stderr,
        )
        return compute_all(
            [(Subject.of_loaded(r.loaded), r.identity) for r in pending],
            table.protocol if table.sample is None else table.protocol.subset(table.sample),
            made_by=MADE_BY,
            device=self.device,
            keep_going=self.plan.check is not None,  # a rebuild stops at its first failure
        )

    def _rebuild(self, table: TablePlan) -> bool | None:
        """Carry out a table's plan: stored rows reused or re-stamped, the others computed,
        the table rewritten if any of its rows changed."""
        where, task = table.where, table.task
        reused, fresh, efficiency, reasons = [], [], {}, []
        # rows whose numbers stand and whose stored identity is updated: label -> (identity,
        # how the numbers were verified under it)
        refreshed: dict[str, tuple[dict, dict]] = {}
        for r in table.rows:
            if r.action in ("reuse", "keep"):
                reused.append(r.stored)
                self.counts["reused"] += 1
                self.stored_cost(efficiency, r.row.label, r.loaded, task)
                if r.action == "keep" and identity_differences(
                    stored_identity(r.stored), r.identity
                ):
                    print(
                        f"{where}: {r.row.label}: kept as stored although stale (only "
                        f"{', '.join(sorted(self.plan.models))} asked)",
                        file=sys.stderr,
                    )
        pending = [r for r in table.rows if r.action == "compute"]
        for r, verification in self._verify([r for r in table.rows if r.action == "verify"], table):
            if verification is None:  # the sample disagreed: recomputed on every window
                pending.append(replace(r, action="compute", why="code changed; a sample disagreed"))
                continue
            refreshed[r.row.label] = (r.identity, verification)
            reused.append(r.stored)
            self.counts["restamped"] += 1
            self.stored_cost(efficiency, r.row.label, r.loaded, task)
        for r, result in zip(pending, self._compute(table, pending, "evaluating")):
            reasons.append(f"{r.row.label}: {r.why}")
            if r.stored is not None:
                # A recomputation within the tolerance of the stored row leaves its files as
                # they are (only a stale identity is brought up to date): a rebuild on another
                # CPU rewrites nothing that merely rounded differently.
                agreed = agreement(result, r.stored)
                if agreed.same:
                    before = stored_identity(r.stored)
                    stale = bool(identity_differences(before, r.identity))
                    if stale:
                        refreshed[r.row.label] = (
                            r.identity,
                            verification_record(
                                before,
                                r.identity,
                                len(table.protocol.index),
                                None,
                                agreed,
                                generated_data_hash(result.protocol),
                            ),
                        )
                    reused.append(r.stored)
                    self.counts["agreed"] += 1
                    self.stored_cost(efficiency, r.row.label, r.loaded, task)
                    print(
                        f"{where}: {r.row.label}: recomputed ({r.why}); agrees with the stored "
                        f"row (largest difference {agreed.share:.2f} of the tolerance): "
                        + ("its files kept, its identity updated" if stale else "kept as stored"),
                        file=sys.stderr,
                    )
                    reasons.pop()  # said above; nothing of this row is rewritten
                    continue
                reasons[-1] = f"{reasons[-1]}; rewritten: {agreed.why}"
            fresh.append(result)
            self.counts["recomputed"] += 1
            self.stored_cost(efficiency, r.row.label, r.loaded, task)
        kept = self._kept(table, reused, refreshed)
        results = fresh + kept
        if not results:
            return None
        for reason in reasons:
            print(f"{where}: recomputing {reason}", file=sys.stderr)
        try:
            return self._write(
                table.path, fresh, reused, table.dropped, results, efficiency, refreshed
            )
        except _Unchanged:
            return False

    def _kept(self, table: TablePlan, reused: list[Path], refreshed) -> list:
        """The stored results a rebuild keeps (reused rows and rows it did not plan), each
        with the identity it now has; a row of another protocol is left out (kept on disk)."""
        from zoo.evaluation.results import EvalResult

        kept = []
        for p in [*reused, *table.foreign]:
            result = EvalResult.read(p)
            if p.name in refreshed:  # the table records the identity its row now has
                restamp_record(result.protocol, *refreshed[p.name])
            differences = protocol_differences(table.protocol.record, result.protocol)
            if differences:
                print(
                    f"{table.where}: {p.name}: its stored result was measured under another "
                    f"protocol ({'; '.join(differences)}); left out of the leaderboard (kept "
                    f"on disk)",
                    file=sys.stderr,
                )
                continue
            if p in table.foreign:
                print(
                    f"{table.where}: {p.name}: kept as stored ({_why_not_planned(p, self)})",
                    file=sys.stderr,
                )
            kept.append(result)
        self.counts["kept"] += len(table.foreign)
        self.counts["dropped"] += len(table.dropped)
        return kept

    def _write(self, path, fresh, reused, dropped, results, efficiency, refreshed=None) -> bool:
        bench = self.bench
        produced = {str(r.frame["model"].iloc[0]) for r in fresh} | {p.name for p in dropped}
        with replace_folder(path, checked=True) as tmp:
            # everything in the folder that this run does not produce again is carried over:
            # result folders reused or kept, and whatever else a user put there
            for entry in sorted(path.iterdir()) if path.is_dir() else ():
                if entry.name in produced or _table_owned(entry.name):
                    continue
                if entry.is_dir() and not entry.is_symlink():
                    shutil.copytree(entry, tmp / entry.name, copy_function=os.link, symlinks=True)
                else:
                    os.link(entry, tmp / entry.name, follow_symlinks=False)
            for result in fresh:
                result.write(tmp / str(result.frame["model"].iloc[0]), replace=False)
            for label, (identity, verification) in (refreshed or {}).items():
                # a new file in place of the hard link: the stored folder stays as it was
                record = json.loads((tmp / label / "protocol.json").read_text())
                restamp_record(record, identity, verification)
                atomic_write_json(tmp / label / "protocol.json", record)
            notes = self.short_training(path, results)
            write_leaderboard(results, tmp, bench.horizons_ms, efficiency, notes)
            if not fresh and not dropped and not refreshed and _same_files(path, tmp):
                raise _Unchanged
        gone = f", dropped {', '.join(p.name for p in dropped)}" if dropped else ""
        print(
            f"wrote {path}/leaderboard.md ({len(results)} rows: {len(fresh)} evaluated now, "
            f"{len(reused)} reused, {len(results) - len(fresh) - len(reused)} kept{gone})"
        )
        return True

    def _verify(self, rows: list[RowPlan], table: TablePlan):
        """Rows stale only because code changed, verified in one pass over a sample of the
        table's windows: each with its verification record if the sample agrees with its
        stored per-window errors, else with None (to be recomputed on every window)."""
        if not rows:
            return []
        from zoo.core.errors import EvaluationError
        from zoo.evaluation.results import EvalResult

        where, planned = table.where, table.protocol
        sample = draw_sample(planned.actions, self.plan.windows, self.plan.seed)
        print(
            f"verifying {where} after a code change: {', '.join(r.row.label for r in rows)} on "
            f"{len(sample)} of {len(planned.index)} windows (seed {self.plan.seed})",
            file=sys.stderr,
        )
        computed = compute_all(
            [(Subject.of_loaded(r.loaded), r.identity) for r in rows],
            planned.subset(sample),
            made_by=MADE_BY,
            device=self.device,
            keep_going=True,  # a row that fails here is recomputed in full, and fails there
        )
        out = []
        for r, result in zip(rows, computed):
            agreed = None  # not verifiable: no result, or a stored row that cannot be read
            if not isinstance(result, Exception):
                try:
                    stored = EvalResult.read(r.stored)
                except EvaluationError:
                    stored = None
                if stored is not None and stored.windows is not None:
                    agreed = sample_agreement(result.windows, stored.windows, sample)
                    if agreed.same:  # and its averages are its windows' own
                        agreed = self_consistent(stored, r.stored) or agreed
            if agreed is None or not agreed.same:
                print(
                    f"{where}: {r.row.label}: {r.why}; "
                    + (f"the sample disagrees ({agreed.why})" if agreed else "not verifiable")
                    + ": recomputed on every window",
                    file=sys.stderr,
                )
                out.append((r, None))
                continue
            before = stored_identity(r.stored)
            print(
                f"{where}: {r.row.label}: {r.why}; verified on {len(sample)} windows (largest "
                f"difference {agreed.share:.2f} of the tolerance): numbers kept, re-stamped",
                file=sys.stderr,
            )
            data = generated_data_hash(result.protocol)
            record = verification_record(
                before, r.identity, len(sample), self.plan.seed, agreed, data
            )
            out.append((r, record))
        return out

    def short_training(self, table: Path, results=()) -> dict[str, tuple[str, str | None]]:
        """Per row label of this benchmark trained short of its recipe, by its shipped weights
        (:func:`zoo.report.cards.short_training_notes`) or by the checkpoint it was scored from
        (what
        ``results``, the table's rows, record of their run): what its run saw and the path of
        its model's card from ``table``'s folder (None where it has none)."""
        from zoo.report.cards import checkpoint_budget_notes, shipped_weights, short_training_notes

        if self._short_training is None:
            shipped = (
                shipped_weights(self.weights)
                if self.weights is not None and self.weights.is_dir()
                else {}
            )
            self._short_training = short_training_notes(self.registry, shipped)
        notes = {
            label: n
            for (bench, label), n in self._short_training.items()
            if bench == self.bench.name
        }
        runs = {str(r.frame["model"].iloc[0]): r.protocol.get("provenance") or {} for r in results}
        notes.update(checkpoint_budget_notes(self.registry, runs))
        out = {}
        for label, note in notes.items():
            card = REPO_ROOT / "docs" / "models" / f"{label.partition('@')[0]}.md"
            link = os.path.relpath(card, table) if card.is_file() else None
            out[label] = (note, link)
        return out

    def stored_cost(self, efficiency: dict, label: str, loaded, task: str) -> None:
        """A row's cost columns as ``zoo costs`` stored them (this measures nothing), while
        they are those of its model (:func:`zoo.leaderboard.efficiency.cost_key`); else none."""
        key = cost_key(loaded, self.bench, self.dataset, task)
        stored = self.costs.get(label, architecture(key))
        if stored is not None:
            efficiency[label] = stored


MADE_BY = "zoo leaderboard"
# The files of a table itself (the rows' folders are beside them).
TABLE_FILES = (TABLE_FILE, "summary.json", "protocol.json", "efficiency.csv")
# What older zoo versions wrote beside them and a rebuild removes: a table-wide copy of every
# row's results.csv (zoo.evaluation.results.read_table reads the rows themselves).
RETIRED_TABLE_FILES = ("results.csv",)


class _Unchanged(Exception):
    """A table rebuilt to the same bytes: the old folder stays."""


def _table_owned(name: str) -> bool:
    """A file a table rebuild writes (or retires), never carried over: its own files and its
    plots (``<metric>.png``, :func:`zoo.report.outputs.plot_files`)."""
    return name in TABLE_FILES + RETIRED_TABLE_FILES or name.endswith(".png")


def _same_files(old: Path, new: Path) -> bool:
    """Whether a rebuilt table's own files equal the stored ones, byte for byte (and the stored
    table holds no file a rebuild removes)."""
    names = set(TABLE_FILES) | {p.name for folder in (old, new) for p in folder.glob("*.png")}
    return not any((old / name).exists() for name in RETIRED_TABLE_FILES) and all(
        (old / name).is_file() == (new / name).is_file()
        and (not (new / name).is_file() or (old / name).read_bytes() == (new / name).read_bytes())
        for name in sorted(names)
    )


def _why_not_planned(folder: Path, board: Leaderboard) -> str:
    from zoo.core.io import registry_record

    recorded = recorded_registry(folder)
    entries = board.registry.entries.values()
    loaded = {registry_record(e.source) for e in entries} | {
        repo_relative(e.source) for e in entries
    }
    if recorded is not None and recorded not in loaded:
        return (
            f"registry {recorded} not loaded: --registry with that file recomputes it, "
            f"--drop {folder.name} removes it"
        )
    provenance = stored_provenance(folder)
    if provenance.get("made_by", MADE_BY) != MADE_BY:
        return (
            f"made by {provenance['made_by']}, not a row the leaderboard plans: zoo eval "
            f"--label {folder.name} --replace refreshes it, --drop {folder.name} removes it"
        )
    return (
        f"no shipped weights {board.bench.name}/{folder.name}.safetensors and no checkpoint "
        f"to recompute it from; --drop {folder.name} removes it"
    )


def _no_further_than_best(checkpoint: Path) -> bool:
    from zoo.hub.checkpoints import read_checkpoint

    try:
        training = read_checkpoint(checkpoint).get("training", {})
    except Exception:  # noqa: BLE001 - unreadable: shown as its own row, which then says why
        return False
    return training.get("best", {}).get("epoch") == training.get("epochs_run")


def copy_benchmark_tables(base: str | Path, out: str | Path, benchmark: str) -> list[Path]:
    """The tables of ``benchmark`` under the results folder ``base`` (e.g. the repository's
    ``results/``) copied to ``out`` where ``out`` has none of its own, with the benchmark's cost
    cells: a rebuild under ``out`` then reuses their rows beside the user's and never writes
    ``base``. Returns the tables copied."""
    import shutil

    source, target = Path(base) / benchmark, Path(out) / benchmark
    copied = []
    for table in table_files(source):
        folder = target / table.parent.name
        if not folder.exists():  # whole or not at all: a copy cut short is never taken for one
            with replace_folder(folder) as tmp:
                shutil.copytree(table.parent, tmp, dirs_exist_ok=True)
            copied.append(folder)
    costs = source / COSTS_FILE
    if costs.is_file() and not (target / COSTS_FILE).exists():
        target.mkdir(parents=True, exist_ok=True)
        with atomic_path(target / COSTS_FILE) as tmp:
            shutil.copy2(costs, tmp)
    return copied
