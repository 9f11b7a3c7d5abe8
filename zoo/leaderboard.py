"""Leaderboards: bring every table of a benchmark up to date (``regenerate``: stored rows
reused while their identity holds, new and stale rows recomputed), write
``results/<benchmark>/<table>/`` (tables from :mod:`zoo.tables`, plots), or check the committed
ones without writing (``CheckReport``)."""

from __future__ import annotations

import json
import os
import shutil
import sys
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from zoo.efficiency import COSTS_FILE, Costs, architecture, cost_key
from zoo.evaluate import evaluate
from zoo.io import atomic_write_json, atomic_write_text, replace_folder, save_figure
from zoo.model_source import ModelSource
from zoo.store import (
    RESULTS_DIR,
    StoreError,
    identity_differences,
    identity_id,
    stored_identity,
    table_folder,
)
from zoo.tables import (
    check_comparable,
    headline_table,
    markdown_tables,
    metric_unit,
    protocol_differences,
)
from zoo.tolerance import KEY_COLUMNS, agreement, tolerance_text
from zoo.tolerance import allowed as tolerated


def write_leaderboard(
    results: list,
    out_dir: str | Path,
    horizons_ms: Iterable[int] | None = None,
    efficiency: dict[str, dict] | None = None,
) -> Path:
    """Combine :class:`zoo.evaluate.EvalResult` objects of one protocol into ``out_dir``:
    ``results.csv``, ``leaderboard.md``, ``protocol.json`` and ``mpjpe.png``; ``efficiency``
    (per row label, the costs ``zoo costs`` stored: :class:`zoo.efficiency.Costs`) fills the
    headline's cost columns and ``efficiency.csv`` (a dict without a row's label: its cost
    cells stay empty, and the table says how to fill them)."""
    out_dir = Path(out_dir)
    # Rows and runs in model order, whichever models were evaluated now and which were stored:
    # regenerating then rewrites no unchanged table.
    results = sorted(results, key=lambda r: str(r.frame["model"].iloc[0]))
    records = {r.protocol["protocol_id"]: r.protocol for r in results}
    check_comparable(records)
    frame = pd.concat([r.frame for r in results], ignore_index=True)
    tables = markdown_tables(
        frame, records, horizons_ms, headline=headline_table(results, horizons_ms, efficiency)
    )
    protocol = dict(results[0].protocol)
    protocol["provenance"] = {"runs": [r.protocol.get("provenance", {}) for r in results]}
    atomic_write_text(out_dir / "results.csv", frame.to_csv(index=False))
    atomic_write_text(out_dir / "leaderboard.md", tables)
    atomic_write_json(out_dir / "protocol.json", protocol)
    if efficiency:
        atomic_write_text(out_dir / "efficiency.csv", efficiency_csv(frame["model"], efficiency))
    plot_average(frame, out_dir / "mpjpe.png", title=tables.splitlines()[0].lstrip("# "))
    return out_dir


def efficiency_csv(models: Iterable[str], efficiency: dict[str, dict]) -> str:
    """``efficiency.csv``: the stored costs of a table's ``models``, one row each."""
    labels = sorted(set(models) & set(efficiency))
    costs = pd.DataFrame([{"model": m, **efficiency[m]} for m in labels])
    counts = {c: "Int64" for c in ("latency_repeats", "training_steps") if c in costs}
    return costs.astype(counts).to_csv(index=False)


def plot_average(frame: pd.DataFrame, path: str | Path, title: str = "") -> None:
    """Error against horizon for the action average: one panel per (averaging, joints)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    avg = frame[frame["action"] == "average"]
    panels = sorted(avg.groupby(["metric", "averaging", "joints"]).groups)
    fig, axes = plt.subplots(1, len(panels), figsize=(4.5 * len(panels), 3.8), squeeze=False)
    for ax, key in zip(axes[0], panels):
        metric, averaging, joints = key
        sub = avg[
            (avg["metric"] == metric) & (avg["averaging"] == averaging) & (avg["joints"] == joints)
        ]
        for model, rows in sub.groupby("model"):
            rows = rows.sort_values("horizon_ms")
            ax.plot(rows["horizon_ms"], rows["value"], marker=".", label=model)
        ax.set_title(f"{metric} ({averaging}, {joints})", fontsize=9)
        ax.set_xlabel("horizon (ms)")
        ax.set_ylabel(metric_unit(metric)[0])
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title, fontsize=9)
    save_figure(fig, path)


def training_curves(
    weights_root: str | Path | None, benchmark: str
) -> dict[str, list[tuple[int, float]]]:
    """``{label: [(optimizer steps, validation MPJPE mm), ...]}`` of every shipped model of
    ``benchmark`` whose record holds its training history (exported from a ``last.pt``)."""
    from zoo.weights import available_weights, read_weights_record, training_points, weights_file

    curves = {}
    for bench, label in available_weights(weights_root):
        if bench != benchmark:
            continue
        points = training_points(read_weights_record(weights_file(bench, label, weights_root)))
        if points:
            curves[label] = points
    return curves


def plot_training_curves(
    curves: dict[str, list[tuple[int, float]]], path: str | Path, title: str = ""
) -> None:
    """Validation MPJPE against optimizer steps, one line per trained model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4))
    for label, points in sorted(curves.items()):
        steps, errors = zip(*points)
        ax.plot(steps, errors, marker=".", label=label)
    ax.set_xlabel("optimizer steps")
    ax.set_ylabel("validation MPJPE (mm)")
    ax.set_yscale("log")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=9)
    save_figure(fig, path)


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
        lines = []
        for name, t in self.per_table.items():
            verdict = (
                f"{len(t['problems'])} problem(s), first: {t['problems'][0]}"
                if t["problems"]
                else "passed"
            )
            lines.append(
                f"{name}: {t['rows']} rows checked, largest difference {t['share']:.2f} of "
                f"the tolerance: {verdict}"
            )
        return lines

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


@dataclass
class Plan:
    """What one ``zoo leaderboard`` run does on a benchmark. ``recompute``: every row anew;
    ``models``: (re)compute only these models' rows, keep every other stored row as it is;
    ``drop``: labels whose result folders are removed (deliberately) from the tables;
    ``check``: write nothing, recompute every committed row and compare."""

    recompute: bool = False
    models: frozenset = frozenset()
    drop: frozenset = frozenset()
    check: CheckReport | None = None


@dataclass
class Row:
    """One planned row of a table: a label and where its model comes from."""

    label: str
    name: str
    source: ModelSource


def regenerate(
    benchmark,
    *,
    registry=None,
    data_root=None,
    out_root: str | Path | None = None,
    checkpoints: str | Path | None = None,
    weights: str | Path | None = None,
    device: str = "cpu",
    plan: Plan | None = None,
) -> list[Path]:
    """Bring ``<out_root>/<benchmark>/<table>/`` up to date for every sampler, task and (mesh
    benchmarks) ground truth of ``benchmark``: reuse each stored row whose identity
    (:mod:`zoo.store`) still holds, recompute rows that are new or stale (saying why), keep
    every result folder it did not plan (a row of a registry not loaded now stays as stored),
    and rewrite a table only when one of its rows changed.

    Rows: every registered model that needs no training; a trainable one from its shipped
    weights ``<weights>/<benchmark>/<label>.safetensors`` (a published row is always computed
    from the published weights), else from its checkpoint ``<checkpoints>/<benchmark>/<model>/
    best.pt`` (and ``last.pt`` as ``<model>@last`` when it trained past its best epoch).
    """
    from zoo.benchmark import get_benchmark
    from zoo.registry import load_registry

    board = Leaderboard(
        bench=get_benchmark(benchmark) if isinstance(benchmark, (str, Path)) else benchmark,
        registry=registry or load_registry(),
        root=Path(out_root or RESULTS_DIR),
        weights=Path(weights) if weights else None,
        checkpoints=Path(checkpoints) if checkpoints else None,
        device=device,
        plan=plan or Plan(),
        data_root=data_root,
    )
    return board.run()


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
        self.counts = {"reused": 0, "recomputed": 0, "agreed": 0, "kept": 0, "dropped": 0}
        self.loaded: dict = {}
        unknown = sorted(set(plan.models) - set(registry.list_models()))
        if unknown:
            raise StoreError(
                f"--model {', '.join(unknown)}: not a registered model (add its "
                f"registry with --registry); registered: "
                f"{', '.join(registry.list_models())}"
            )

    def run(self) -> list[Path]:
        bench = self.bench
        truths = (
            (bench.ground_truths or (bench.ground_truth,))
            if bench.representation == "mesh"
            else (None,)
        )
        tasks = dict.fromkeys(
            ["prediction", *(self.registry.get(n).task for n in self.registry.list_models())]
        )
        written, changed = [], False
        if self.plan.check is None:
            self._preflight(truths, tasks)
        for sampler in bench.samplers:
            for task in tasks:
                for truth in truths:
                    folder = table_folder(sampler, task, truth)
                    started = time.perf_counter()
                    if self.plan.check is not None:
                        try:  # a check goes on to the next table whatever fails in this one
                            outcome = self._table(sampler, task, truth, folder)
                        except Exception as e:  # noqa: BLE001
                            self.plan.check.start_table(f"{bench.name}/{folder}")
                            self.plan.check.problem(f"{bench.name}/{folder}: not checked: {e}")
                            outcome = True
                    else:
                        outcome = self._table(sampler, task, truth, folder)
                    if outcome:
                        print(
                            f"{bench.name}/{folder}: {time.perf_counter() - started:.0f} s",
                            file=sys.stderr,
                        )
                    if outcome is not None:
                        written.append(self.root / bench.name / folder)
                        changed |= outcome
        check = self.plan.check
        if check is not None:
            produced = {p.name for p in written}
            for table in sorted((self.root / bench.name).glob("*/results.csv")):
                if table.parent.name not in produced:
                    check.current = ""
                    check.problem(
                        f"{table}: a committed table that the leaderboard no longer produces"
                    )
            return written
        from zoo.sensitivity import protocol_sensitivity

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
            f"{bench.name}: {c['reused']} row(s) reused, {c['recomputed']} recomputed, "
            f"{c['agreed']} recomputed in agreement with the stored row (files kept), "
            f"{c['kept']} kept as stored (not planned by this registry), {c['dropped']} "
            f"dropped",
            file=sys.stderr,
        )
        return written

    def _preflight(self, truths, tasks) -> None:
        """Before anything is evaluated or written: a stored row that this run would replace
        must be the leaderboard's own (same registry, made by a rebuild); a user's row stops
        the run, naming it and how to keep or drop it."""
        from zoo.evaluate import protocol_for

        found_drops = set()
        for sampler in self.bench.samplers:
            for task in tasks:
                for truth in truths:
                    folder = self.root / self.bench.name / table_folder(sampler, task, truth)
                    if not folder.is_dir():
                        continue
                    found_drops |= {p.name for p in folder.iterdir()} & set(self.plan.drop)
                    rows = [
                        r
                        for r in self._rows(task)
                        if r.label not in self.plan.drop
                        and (folder / r.label / "protocol.json").is_file()
                        and (not self.plan.models or r.name in self.plan.models)
                    ]
                    protocol = None
                    for row in rows:
                        loaded = self._load(row)
                        _refuse_foreign_registry(folder / row.label, loaded, row.label)
                        made_by = _provenance(folder / row.label).get("made_by", MADE_BY)
                        if made_by == MADE_BY:
                            continue
                        protocol = protocol or protocol_for(
                            self.bench,
                            self.dataset,
                            sampler=sampler,
                            task=task,
                            ground_truth=truth,
                        )
                        differences = identity_differences(
                            stored_identity(folder / row.label),
                            loaded.identity(self.bench, protocol["protocol_id"]),
                        )
                        if differences:
                            raise StoreError(
                                f"{folder / row.label}: row {row.label!r} was made by "
                                f"{made_by}, and the leaderboard's own {row.label!r} differs "
                                f"({'; '.join(differences[:3])}); nothing was changed: keep "
                                f"yours under another label (zoo eval --label NAME), or remove "
                                f"it deliberately with --drop {row.label}"
                            )
        missing = sorted(set(self.plan.drop) - found_drops)
        if missing:
            print(
                f"{self.bench.name}: --drop {', '.join(missing)}: no such row in its tables",
                file=sys.stderr,
            )

    def _evaluate(self, loaded, row: Row, sampler: str, truth: str | None, task: str):
        return evaluate(
            loaded.model,
            self.bench,
            model_name=row.label,
            sampler=sampler,
            dataset=self.dataset,
            device=self.device,
            provenance=loaded.provenance,
            ground_truth=truth,
            view=loaded.view,
            task=task,
        )

    def _load(self, row: Row):
        """A row's model, built once and used by every table."""
        if row.label not in self.loaded:
            self.loaded[row.label] = row.source.load(self.registry, self.bench, self.dataset)
        return self.loaded[row.label]

    # ---- rows -----------------------------------------------------------------------------

    def _rows(self, task: str) -> list[Row]:
        bench, registry = self.bench, self.registry
        # Skeleton models join a mesh benchmark with a joint regressor, fed its regressed joints.
        names = registry.list_models(bench.representation)
        if bench.representation == "mesh" and self.dataset.joint_regressor is not None:
            names += [n for n in registry.list_models("joints") if n not in names]
        rows = []
        planned = (n for n in names if registry.get(n).task == task)
        for name in (n for n in planned if registry.get(n).leaderboard):
            if not registry.get(name).trainable:
                rows.append(Row(name, name, ModelSource.of(name)))
                continue
            for label in (name, f"{name}@last"):
                shipped = self._shipped(label)
                checkpoint = (
                    self.checkpoints
                    / bench.name
                    / name
                    / ("last.pt" if label != name else "best.pt")
                    if self.checkpoints
                    else None
                )
                if shipped is not None:
                    rows.append(Row(label, name, ModelSource.of(weights=shipped, label=label)))
                    if checkpoint is not None and checkpoint.is_file():
                        print(
                            f"{bench.name}: {label}: the shipped weights {shipped}, not "
                            f"{checkpoint} (zoo weights export publishes a checkpoint)",
                            file=sys.stderr,
                        )
                elif checkpoint is not None and checkpoint.is_file():
                    if label != name and _no_further_than_best(checkpoint):
                        continue  # trained no further than its best epoch: best.pt's weights
                    rows.append(
                        Row(label, name, ModelSource.of(checkpoint=checkpoint, label=label))
                    )
        return rows

    def _shipped(self, label: str) -> Path | None:
        """Shipped weights of ``label``: this benchmark's own, else those of the benchmark it
        takes weights from (``weights_from``)."""
        if not self.weights:
            return None
        from zoo.weights import weights_file

        for name in (self.bench.name, self.bench.weights_from):
            path = weights_file(name, label, self.weights) if name else None
            if path is not None and path.is_file():
                return path
        return None

    # ---- one table ------------------------------------------------------------------------

    def _table(self, sampler: str, task: str, truth: str | None, folder: str) -> bool | None:
        """Check or bring one table up to date; None when there is no table to make, else
        whether it was (re)written."""
        from zoo.evaluate import EvalResult, protocol_for

        bench, plan, check = self.bench, self.plan, self.plan.check
        path = self.root / bench.name / folder
        where = f"{bench.name}/{folder}"
        stored = (
            {
                p.name: p
                for p in sorted(path.iterdir())
                if p.is_dir() and (p / "protocol.json").is_file()
            }
            if path.is_dir()
            else {}
        )
        rows = [r for r in self._rows(task) if r.label not in plan.drop]
        if (
            task != "prediction"
            and not any(self.registry.get(r.name).trainable for r in rows)
            and not any(label not in {r.label for r in rows} for label in stored)
        ):
            return None  # a table of baselines alone says nothing about this task
        protocol = protocol_for(bench, self.dataset, sampler=sampler, task=task, ground_truth=truth)
        if check is not None:
            check.start_table(where)
        fresh, reused, efficiency, reasons = [], [], {}, []
        refreshed: dict[str, dict] = {}  # rows that agree, whose stored identity is updated
        failed = set()  # rows of a check that could not be recomputed
        for number, row in enumerate(rows, 1):
            if check is not None:
                print(f"checking {where}: {row.label} ({number}/{len(rows)})", file=sys.stderr)
                try:  # a refusal (weights for another basis, a missing file) ends one row only
                    loaded = self._load(row)
                    result = self._evaluate(loaded, row, sampler, truth, task)
                except Exception as e:  # noqa: BLE001 - every failure is reported, none stops
                    check.problem(f"{where}: {row.label}: not recomputed: {e}")
                    failed.add(row.label)
                    continue
                stamp(result, loaded.identity(bench, protocol["protocol_id"]), made_by=MADE_BY)
                fresh.append(result)
                continue
            loaded = self._load(row)
            identity = loaded.identity(bench, protocol["protocol_id"])
            old = stored.get(row.label)
            if check is not None or plan.recompute:
                why = "asked (--recompute)" if check is None else None
            elif plan.models and row.name not in plan.models:
                if old is not None:
                    reused.append(old)
                    self.counts["reused"] += 1
                    self._cost(efficiency, row.label, loaded, task)
                    if identity_differences(stored_identity(old), identity):
                        print(
                            f"{where}: {row.label}: kept as stored although stale (only "
                            f"{', '.join(sorted(plan.models))} asked)",
                            file=sys.stderr,
                        )
                continue
            elif plan.models:
                why = "asked (--model)"
            elif old is None:
                why = "new"
            else:
                differences = identity_differences(stored_identity(old), identity)
                why = "; ".join(differences[:3]) + (" ..." if len(differences) > 3 else "")
                if not differences:
                    reused.append(old)
                    self.counts["reused"] += 1
                    self._cost(efficiency, row.label, loaded, task)
                    continue
            if why is not None:
                reasons.append(f"{row.label}: {why}")
            result = self._evaluate(loaded, row, sampler, truth, task)
            stamp(result, identity, made_by=MADE_BY)
            if old is not None:
                # A recomputation within the tolerance of the stored row leaves its files as
                # they are (only a stale identity is brought up to date): a rebuild on another
                # CPU rewrites nothing that merely rounded differently.
                agreed = agreement(result, old)
                if agreed.same:
                    stale = bool(identity_differences(stored_identity(old), identity))
                    if stale:
                        refreshed[row.label] = identity
                    reused.append(old)
                    self.counts["agreed"] += 1
                    self._cost(efficiency, row.label, loaded, task)
                    print(
                        f"{where}: {row.label}: recomputed ({why}); agrees with the stored row "
                        f"(largest difference {agreed.share:.2f} of the tolerance): "
                        + ("its files kept, its identity updated" if stale else "kept as stored"),
                        file=sys.stderr,
                    )
                    if reasons and why is not None:
                        reasons.pop()  # said above; nothing of this row is rewritten
                    continue
                reasons[-1:] = [f"{reasons[-1]}; rewritten: {agreed.why}"] if reasons else []
            fresh.append(result)
            self.counts["recomputed"] += 1
            self._cost(efficiency, row.label, loaded, task)
        planned = {r.label for r in rows}
        foreign = [
            p for label, p in stored.items() if label not in planned and label not in plan.drop
        ]
        dropped = [p for label, p in stored.items() if label in plan.drop]
        if check is not None:
            for p in foreign:
                check.problem(f"{p}: cannot be recomputed ({_why_not_planned(p, self)})")
            if fresh:
                # a row not recomputed is named once, above, not once per committed value
                _check_table(fresh, path, check, unplanned={p.name for p in foreign} | failed)
            return True if fresh or foreign or rows else None
        kept = []
        for p in [*reused, *foreign]:
            result = EvalResult.read(p)
            if p.name in refreshed:  # the table records the identity its row now has
                stamp_record(result.protocol, refreshed[p.name])
            differences = protocol_differences(protocol, result.protocol)
            if differences:
                print(
                    f"{where}: {p.name}: its stored result was measured under another "
                    f"protocol ({'; '.join(differences)}); left out of the leaderboard (kept "
                    f"on disk)",
                    file=sys.stderr,
                )
                continue
            if p in foreign:
                print(
                    f"{where}: {p.name}: kept as stored ({_why_not_planned(p, self)})",
                    file=sys.stderr,
                )
            kept.append(result)
        self.counts["kept"] += len(foreign)
        self.counts["dropped"] += len(dropped)
        results = fresh + kept
        if not results:
            return None
        for reason in reasons:
            print(f"{where}: recomputing {reason}", file=sys.stderr)
        try:
            return self._write(path, fresh, reused, dropped, results, efficiency, refreshed)
        except _Unchanged:
            return False

    def _write(self, path, fresh, reused, dropped, results, efficiency, refreshed=None) -> bool:
        bench = self.bench
        produced = {str(r.frame["model"].iloc[0]) for r in fresh} | {p.name for p in dropped}
        with replace_folder(path, checked=True) as tmp:
            # everything in the folder that this run does not produce again is carried over:
            # result folders reused or kept, and whatever else a user put there
            for entry in sorted(path.iterdir()) if path.is_dir() else ():
                if entry.name in produced or entry.name in TABLE_FILES:
                    continue
                if entry.is_dir() and not entry.is_symlink():
                    shutil.copytree(entry, tmp / entry.name, copy_function=os.link, symlinks=True)
                else:
                    os.link(entry, tmp / entry.name, follow_symlinks=False)
            for result in fresh:
                result.write(tmp / str(result.frame["model"].iloc[0]), replace=False)
            for label, identity in (refreshed or {}).items():
                # a new file in place of the hard link: the stored folder stays as it was
                record = json.loads((tmp / label / "protocol.json").read_text())
                stamp_record(record, identity)
                atomic_write_json(tmp / label / "protocol.json", record)
            write_leaderboard(results, tmp, bench.horizons_ms, efficiency)
            if not fresh and not dropped and not refreshed and _same_files(path, tmp):
                raise _Unchanged
        gone = f", dropped {', '.join(p.name for p in dropped)}" if dropped else ""
        print(
            f"wrote {path}/leaderboard.md ({len(results)} rows: {len(fresh)} evaluated now, "
            f"{len(reused)} reused, {len(results) - len(fresh) - len(reused)} kept{gone})"
        )
        return True

    def _cost(self, efficiency: dict, label: str, loaded, task: str) -> None:
        """A row's cost columns as ``zoo costs`` stored them (this measures nothing), while
        they are those of its model (:func:`zoo.efficiency.cost_key`); else none."""
        key = cost_key(loaded, self.bench, self.dataset, task)
        stored = self.costs.get(label, architecture(key))
        if stored is not None:
            efficiency[label] = stored


MADE_BY = "zoo leaderboard"
# The files of a table itself (the rows' folders are beside them).
TABLE_FILES = ("results.csv", "leaderboard.md", "protocol.json", "efficiency.csv", "mpjpe.png")


class _Unchanged(Exception):
    """A table rebuilt to the same bytes: the old folder stays."""


def stamp(result, identity: dict, made_by: str) -> None:
    """Record ``identity`` in a result's provenance (written to its ``protocol.json``), and
    what made it (``zoo leaderboard``, ``zoo eval``, ``zoo.evaluate``): a rebuild replaces only
    rows it made."""
    stamp_record(result.protocol, identity)
    result.protocol["provenance"]["made_by"] = made_by


def stamp_record(protocol: dict, identity: dict) -> None:
    """``identity`` into a protocol record's provenance (its ``made_by`` unchanged)."""
    protocol["provenance"]["identity"] = identity
    protocol["provenance"]["identity_id"] = identity_id(identity)


def _same_files(old: Path, new: Path) -> bool:
    """Whether a rebuilt table's own files equal the stored ones, byte for byte."""
    return all(
        (old / name).is_file() == (new / name).is_file()
        and (not (new / name).is_file() or (old / name).read_bytes() == (new / name).read_bytes())
        for name in TABLE_FILES
    )


def _provenance(folder: Path) -> dict:
    import json

    return json.loads((folder / "protocol.json").read_text()).get("provenance", {})


def _recorded_registry(folder: Path) -> str | None:
    provenance = _provenance(folder)
    identity = provenance.get("identity") or {}
    return (identity.get("model") or {}).get("registry") or provenance.get("registry")


def _refuse_foreign_registry(folder: Path, loaded, label: str) -> None:
    """A stored row of this label made with another registry's model is the user's: never
    replaced by a rebuild that does not load that registry."""
    from zoo.io import repo_relative

    recorded = _recorded_registry(folder)
    if recorded is not None and recorded != repo_relative(loaded.entry.source):
        raise StoreError(
            f"{folder}: row {label!r} was evaluated with registry {recorded}, which "
            f"this run does not load (its {label!r} comes from "
            f"{repo_relative(loaded.entry.source)}); nothing was changed: pass "
            f"--registry {recorded}, or remove the row deliberately with --drop "
            f"{label}"
        )


def _why_not_planned(folder: Path, board: Leaderboard) -> str:
    from zoo.io import repo_relative

    recorded = _recorded_registry(folder)
    loaded = {repo_relative(e.source) for e in board.registry.entries.values()}
    if recorded is not None and recorded not in loaded:
        return (
            f"registry {recorded} not loaded: --registry {recorded} recomputes it, --drop "
            f"{folder.name} removes it"
        )
    provenance = _provenance(folder)
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
    from zoo.checkpoints import read_checkpoint

    try:
        training = read_checkpoint(checkpoint).get("training", {})
    except Exception:  # noqa: BLE001 - unreadable: shown as its own row, which then says why
        return False
    return training.get("best", {}).get("epoch") == training.get("epochs_run")


def _check_table(
    results: list, folder: Path, check: CheckReport, unplanned: set = frozenset()
) -> None:
    """Compare freshly computed results with the committed table in ``folder`` (and each
    model's per-window errors with its ``windows.npz``)."""
    from zoo.evaluate import WINDOWS_FILE, WindowErrors

    check.tables += 1
    if check.current:
        check.per_table[check.current]["rows"] += len(
            pd.concat([r.frame for r in results], ignore_index=True)
        )
    fresh = pd.concat([r.frame for r in results], ignore_index=True)
    check.rows += len(fresh)
    check.models |= set(fresh["model"])
    if not (folder / "results.csv").is_file():
        check.problem(f"{folder}/results.csv: missing; the leaderboard makes this table")
        return
    committed = pd.read_csv(folder / "results.csv")
    committed = committed[~committed["model"].isin(unplanned)]  # named once, as folders
    both = fresh.merge(
        committed, on=KEY_COLUMNS, how="outer", suffixes=("", "_committed"), indicator="side"
    )
    for row in both[both["side"] != "both"].itertuples():
        where = "committed only" if row.side == "right_only" else "recomputed only"
        check.problem(
            f"{folder}/results.csv: {where}: "
            + ", ".join(f"{k}={getattr(row, k)}" for k in KEY_COLUMNS)
        )
    matched = both[both["side"] == "both"]
    for column in ("value", "std"):  # the mean and its standard deviation over windows
        if f"{column}_committed" not in matched:
            check.problem(
                f"{folder}/results.csv: no column {column!r} (written by an "
                f"older zoo); regenerate the table"
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
                f"{folder.parent.name}/{folder.name}/results.csv "
                + ", ".join(f"{k}={rows.iloc[i][k]}" for k in KEY_COLUMNS)
                + f" ({column})"
            ),
        )
        for row, rel in zip(matched[differs].itertuples(), relative[differs]):
            check.problem(
                f"{folder}/results.csv: "
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
            f"{folder}/results.csv: {row.model}: protocol "
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


INDEX_PREAMBLE = """# Results

Every table here is brought up to date by `zoo leaderboard` (the README's first command does
cloth and CMU; `--benchmark NAME` any other), which reuses a stored row while its identity
holds (benchmark and protocol, model class and hyper-parameters, weights' sha256, registry file
and evaluation code, in each row's `protocol.json`) and recomputes new or stale rows; and
re-checked without writing by `zoo leaderboard --check`, which recomputes every row (baselines,
and trained models from the weights shipped in `weights/`) and names any value that differs
from the committed one by more than float32 rounding across CPUs (the tolerance is printed in
its summary line).

How each number is made:

- Each row is one model evaluated by `zoo.evaluate` under the protocol recorded in the folder's
  `protocol.json` (data files and hashes, window sampler, frame rate, joints, averaging); its
  `protocol_id` is in every row of `results.csv`, and rows of different protocols never share a
  table. Trained rows name the shipped weights (and their sha256) they were computed from.
- Headline tables: the benchmark's first metric, frame averaging, mean over actions. `±` is half
  a 95% interval whose meaning each table states: with one recording per action (CMU,
  CMU-on-Anny), a window-sampling interval, conditional on these recordings and not a confidence
  interval for the actions; with three or more independent recordings per action (cloth), a
  confidence interval of the benchmark mean; each with its measured coverage
  ([docs/protocols.md](../docs/protocols.md)). Bold marks the best model and those not
  distinguishable from it by one simultaneous comparison of all the table's models;
  `zoo compare A B --benchmark NAME` says by how much one model beats another, and on how many
  actions (a model can stay bold beside one that `zoo compare` separates from it: bold guards
  against every pair at once).
- Cost columns (parameters, forward GFLOPs per window, latency of one window, training windows
  per second, every model in float32) are measured by `zoo costs`, never by `zoo leaderboard`,
  and kept in `<benchmark>/costs.json`; the machine (CPU, threads) and date that measured them
  are named under each table; they are not in `results.csv` and `--check` does not compare them.
- Mesh tables: RMSE is per vertex, normalised by the ground-truth frame's bounding-box
  diagonal; MELV is measured on the k-coefficient reconstructions of the reference and scored
  frames (as SpecTrHuMS measures it) and printed as mean (standard deviation over windows);
  `<model>:autoencoder` rows are a SpecTrHuMS model's floor, the ground-truth future through its
  autoencoder alone. `*-gt_spectral` tables score against the k-coefficient reconstruction.
- Rows marked `reported` are figures printed in papers (`zoo/published.yaml`), shown only where
  their protocol matches; the others are listed under each table with their differences.
"""


def write_index(out_root: str | Path) -> Path:
    """``<out_root>/README.md``: every benchmark's tables with their headline and plots."""
    out_root = Path(out_root)
    lines = [INDEX_PREAMBLE]
    for bench_dir in sorted(p for p in out_root.iterdir() if p.is_dir()):
        tables = sorted(bench_dir.glob("*/leaderboard.md"))
        if not tables:
            continue
        lines += [f"## {bench_dir.name}", ""]
        if (bench_dir / "sensitivity.md").is_file():
            lines += [
                f"How much the protocol moves the ranking: "
                f"[{bench_dir.name}/sensitivity.md]({bench_dir.name}/sensitivity.md)",
                "",
            ]
        if (bench_dir / "training.png").is_file():
            lines += [
                f"Training curves of the shipped models: "
                f"[{bench_dir.name}/training.png]({bench_dir.name}/training.png)",
                "",
            ]
        for table in tables:
            folder = table.parent.relative_to(out_root).as_posix()
            text = table.read_text()
            start = text.find("## Headline")
            headline = text[start:] if start >= 0 else ""
            for marker in ("\n### ", "\n## "):
                cut = headline.find(marker, 1)
                headline = headline[:cut] if cut >= 0 else headline
            lines += [
                f"### {folder}",
                "",
                f"[leaderboard]({folder}/leaderboard.md) · [results.csv]({folder}/results.csv)"
                f" · [plot]({folder}/mpjpe.png)",
                "",
            ]
            if headline:  # its heading and table; the leaderboard explains them
                rows = headline.strip().splitlines()
                lines += ["##" + rows[0], "", *[r for r in rows if r.startswith("|")], ""]
    path = out_root / "README.md"
    atomic_write_text(path, "\n".join(lines).rstrip() + "\n")
    return path
