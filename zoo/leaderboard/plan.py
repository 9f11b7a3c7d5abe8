"""A leaderboard's plan, shared by its rebuild (:mod:`.rebuild`) and its check
(:mod:`.check`): what one run does (:class:`Plan`), every table a benchmark can have, the rows
each table plans and where their models come from, and what a run does with each row
(:class:`RowPlan`), decided before anything is computed or written
(:meth:`Leaderboard.plan_table`).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

from zoo.core.io import repo_relative
from zoo.evaluation.pipeline import Subject, compute_all, row_identity
from zoo.hub.foreign import AUTHORS_SUFFIX
from zoo.hub.model_source import ModelSource
from zoo.leaderboard.efficiency import COSTS_FILE, Costs, architecture, cost_key
from zoo.leaderboard.verdict import (
    CHECK_WINDOWS,
    CheckReport,
    fresh_seed,
)
from zoo.protocol.plan import plan_protocol
from zoo.store.identity import (
    identity_differences,
    only_code_changed,
    stored_identity,
)
from zoo.store.layout import RESULTS_DIR, StoreError, table_folder
from zoo.store.ownership import recorded_registry, stored_provenance


@dataclass
class Plan:
    """What one ``zoo leaderboard`` run does on a benchmark. ``recompute``: every row anew;
    ``models``: (re)compute only these models' rows, keep every other stored row as it is;
    ``drop``: labels whose result folders are removed (deliberately) from the tables;
    ``check``: write nothing, recompute every committed row (on the report's sample of windows)
    and compare (run by :class:`zoo.leaderboard.check.Check`). ``windows`` and ``seed``: a row
    stale only because code changed is verified on that many windows
    (:func:`zoo.leaderboard.verdict.draw_sample`) and re-stamped if they agree, else
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


class Leaderboard:
    """The tables of one benchmark, planned: the base of :class:`zoo.leaderboard.rebuild.Rebuild`
    and :class:`zoo.leaderboard.check.Check`."""

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
        self.loaded: dict = {}
        self.said: set[str] = set()  # notes printed once a run, however many tables plan a row
        self.protocols: dict = {}  # each table's protocol, planned once: {(sampler, task, truth)}
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
        truths = bench.strategy.ground_truths(bench)
        tasks = dict.fromkeys(
            ["prediction", *(self.registry.get(n).task for n in self.registry.list_models())]
        )
        for sampler in bench.samplers:
            for task in tasks:
                for truth in truths:
                    yield sampler, task, truth, table_folder(sampler, task, truth)

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
        kinds = bench.strategy.scored_kinds(self.dataset)
        names = list(dict.fromkeys(n for kind in kinds for n in registry.list_models(kind)))
        rows = []
        planned = (n for n in names if registry.get(n).task == task)
        for name in planned:
            entry = registry.get(name)
            # its authors' weights, imported (zoo weights import): a row beside its own, also
            # for a model kept out of the tables otherwise (leaderboard: false, no recipe yet)
            authors = None if entry.weights_of else self._shipped(name + AUTHORS_SUFFIX)
            if authors is not None:
                label = name + AUTHORS_SUFFIX
                rows.append(Row(label, name, ModelSource.of(weights=authors, label=label)))
            if not entry.leaderboard:
                continue
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
                        self._say_once(
                            f"{bench.name}: {label}: the shipped weights {shipped}, not "
                            f"{checkpoint} (zoo weights export publishes a checkpoint)"
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

    def _say_once(self, note: str) -> None:
        if note not in self.said:
            self.said.add(note)
            print(note, file=sys.stderr)

    def withheld(self, label: str):
        """``(path, record)`` of ``label``'s weights where their record is here and their licence
        keeps the tensors out of the repository, and they have not been made here yet."""
        from zoo.hub.weights import read_weights_record, record_file, weights_file, withheld

        for name in (self.bench.name, self.bench.weights_from) if self.weights else ():
            path = weights_file(name, label, self.weights) if name else None
            if path is not None and not path.is_file() and record_file(path).is_file():
                record = read_weights_record(path)
                return (path, record) if withheld(record) else None
        return None

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
            if old is None and row.source.checkpoint is not None:
                # a training under way here, not a row of the table: nothing to check
                return RowPlan(row, "skip", why=f"{row.source.checkpoint}, not in the table")
            try:
                loaded = self.load(row)
                return RowPlan(
                    row, "compute", loaded, row_identity(loaded, self.bench, protocol.id), old
                )
            except Exception as e:  # noqa: BLE001 - every failure is reported, none stops
                return RowPlan(row, "failed", stored=old, error=e)
        if plan.models and row.name not in plan.models and not plan.recompute:
            # not asked for: a stored row is kept as it is, its model not even loaded (a plain
            # rebuild says which rows are stale); one not stored is skipped
            return RowPlan(row, "skip" if old is None else "keep", stored=old)
        loaded = self.load(row)
        identity = row_identity(loaded, self.bench, protocol.id)
        step = partial(RowPlan, row, loaded=loaded, identity=identity, stored=old)
        if plan.recompute:
            return step("compute", why="asked (--recompute)")
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

    def stored_cost(self, efficiency: dict, label: str, loaded, task: str) -> None:
        """A row's cost columns as ``zoo costs`` stored them (this measures nothing), while
        they are those of its model (:func:`zoo.leaderboard.efficiency.cost_key`); else none.
        A row kept as it is (``loaded`` None: its model not loaded) keeps its stored costs."""
        if loaded is None:
            stored = self.costs.as_stored(label)
        else:
            stored = self.costs.get(
                label, architecture(cost_key(loaded, self.bench, self.dataset, task))
            )
        if stored is not None:
            efficiency[label] = stored


MADE_BY = "zoo leaderboard"


def why_not_planned(folder: Path, board: Leaderboard) -> str:
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
    held = board.withheld(folder.name)
    if held is not None:
        from zoo.hub.weights import fetch_command

        return f"{fetch_command(*held)}; --drop {folder.name} removes it"
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
