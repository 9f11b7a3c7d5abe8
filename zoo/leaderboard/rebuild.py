"""A benchmark's tables brought up to date (:func:`regenerate`): stored rows reused while
their identity holds, rows stale only because code changed verified on a sample and re-stamped,
new and stale rows recomputed through :mod:`zoo.evaluation.pipeline`; a table rewritten, whole,
only when one of its rows changed. What a table's folder holds is :mod:`zoo.report.outputs`.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import time
from dataclasses import replace
from pathlib import Path

from zoo.core.io import atomic_path, atomic_write_json, replace_folder
from zoo.evaluation.pipeline import Subject, compute_all, row_identity
from zoo.evaluation.results import TABLE_FILE, table_files
from zoo.evaluation.tolerance import agreement, sample_agreement
from zoo.leaderboard.efficiency import COSTS_FILE
from zoo.leaderboard.plan import MADE_BY, Leaderboard, Plan, RowPlan, TablePlan, why_not_planned
from zoo.leaderboard.verdict import (
    draw_sample,
    generated_data_hash,
    self_consistent,
    verification_record,
)
from zoo.paths import REPO_ROOT
from zoo.protocol.comparable import protocol_differences
from zoo.report.outputs import (
    TRAINING_PLOT,
    plot_training_curves,
    training_curves,
    training_plot_title,
    write_leaderboard,
)
from zoo.store.identity import (
    identity_differences,
    restamp_record,
    stored_identity,
)
from zoo.store.layout import StoreError
from zoo.store.ownership import refuse_foreign_registry, stored_provenance


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

    A plan with a check (``Plan(check=...)``) is refused with ``ValueError``: a check writes
    nothing and runs as :class:`zoo.leaderboard.check.Check`.
    """
    return Rebuild.of(benchmark, plan=plan, **options).run()


class Rebuild(Leaderboard):
    """A benchmark's tables brought up to date (see :func:`regenerate`)."""

    def __init__(self, **options) -> None:
        # a check writes nothing: never a rebuild's plan (refused before any data is read)
        if options.get("plan") is not None and options["plan"].check is not None:
            raise ValueError("a plan with a check runs as zoo.leaderboard.check.Check")
        super().__init__(**options)
        self.counts = dict.fromkeys(
            ("reused", "restamped", "recomputed", "agreed", "kept", "dropped"), 0
        )
        self._short_training: dict | None = None  # read once: zoo.report.cards

    def run(self) -> list[Path]:
        bench = self.bench
        written = []
        self._refuse_models_without_rows()
        self._preflight()
        for sampler, task, truth, folder in self.tables():
            started = time.perf_counter()
            table = self.plan_table(sampler, task, truth, folder)
            outcome = None if table is None else self._rebuild(table)
            if outcome:
                print(
                    f"{bench.name}/{folder}: {time.perf_counter() - started:.0f} s", file=sys.stderr
                )
            if outcome is not None:
                written.append(self.root / bench.name / folder)
        from zoo.stats.sensitivity import update_sensitivity

        said = update_sensitivity(self.root / bench.name)
        if said:
            print(said, file=sys.stderr)
        curves = training_curves(self.weights, bench.name) if self.weights else {}
        if curves:  # drawn only where its records changed (the PNG keeps their digest)
            plot_training_curves(
                curves,
                self.root / bench.name / TRAINING_PLOT,
                title=training_plot_title(bench.name),
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
                    row_identity(loaded, self.bench, self._protocol(sampler, task, truth).id),
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
                    f"{table.where}: {p.name}: kept as stored ({why_not_planned(p, self)})",
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
            write_leaderboard(results, tmp, bench.horizons_ms, efficiency, notes, previous=path)
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
        (what ``results``, the table's rows, record of their run): what its run saw and the path of
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


def copy_benchmark_tables(base: str | Path, out: str | Path, benchmark: str) -> list[Path]:
    """The tables of ``benchmark`` under the results folder ``base`` (e.g. the repository's
    ``results/``) copied to ``out`` where ``out`` has none of its own, with the benchmark's cost
    cells and training curves: a rebuild under ``out`` then reuses their rows beside the user's
    and never writes ``base``. Returns the tables copied."""
    import shutil

    source, target = Path(base) / benchmark, Path(out) / benchmark
    copied = []
    for table in table_files(source):
        folder = target / table.parent.name
        if not folder.exists():  # whole or not at all: a copy cut short is never taken for one
            with replace_folder(folder) as tmp:
                shutil.copytree(table.parent, tmp, dirs_exist_ok=True)
            copied.append(folder)
    # its training curves too: drawn again only where the weights folder's records differ
    for name in (COSTS_FILE, TRAINING_PLOT):
        if (source / name).is_file() and not (target / name).exists():
            target.mkdir(parents=True, exist_ok=True)
            with atomic_path(target / name) as tmp:
                shutil.copy2(source / name, tmp)
    return copied
