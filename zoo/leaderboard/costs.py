"""``zoo costs``: measure the cost columns of the rows of a benchmark's committed tables
(:func:`zoo.leaderboard.efficiency.measure`: float32, a time budget per model, progress on stderr),
store them in ``results/<benchmark>/costs.json`` (format: :mod:`zoo.leaderboard.efficiency`) with
the machine, thread count and date, and rewrite those tables' cost columns (the headline's cost
cells and the line under it in ``leaderboard.md``; ``efficiency.csv``): no row is recomputed, and no
other byte of a table, row folder or ``results.csv`` changes. The only command that measures
costs."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable
from pathlib import Path

from zoo.core.budgets import COST_SECONDS
from zoo.core.errors import ZooError
from zoo.core.io import atomic_write_text, folder_lock
from zoo.evaluation.results import TABLE_FILE, read_table, table_labels
from zoo.leaderboard.efficiency import architecture, cost_key, measure
from zoo.leaderboard.plan import Leaderboard, Plan
from zoo.report.outputs import efficiency_csv
from zoo.report.tables import with_costs

RENDERED = ("leaderboard.md", "efficiency.csv")  # the files of a table that show costs


class CostsError(ZooError, ValueError):
    pass


class NoRowsError(CostsError):
    """The benchmark's tables hold no row of the models asked for."""


def measure_costs(
    benchmark,
    *,
    registry=None,
    data_root=None,
    out_root: str | Path | None = None,
    weights: str | Path | None = None,
    checkpoints: str | Path | None = None,
    device: str = "cpu",
    models: Iterable[str] = (),
    seconds: float = COST_SECONDS,
) -> list[Path]:
    """Measure the costs of every row (``models``: of these registry models' rows only; the
    other stored costs are kept) of ``benchmark``'s tables under ``out_root``, write its
    ``costs.json`` and re-render the tables' cost columns; the tables rewritten."""
    models = frozenset(models)
    board = Leaderboard.of(
        benchmark,
        registry=registry,
        data_root=data_root,
        out_root=out_root,
        weights=weights,
        checkpoints=checkpoints,
        device=device,
        plan=Plan(models=models),
    )
    bench, store = board.bench, board.costs
    tables = committed_tables(board)
    if not tables:
        raise CostsError(
            f"{board.root / bench.name}: no committed table (zoo leaderboard --benchmark "
            f"{bench.name} makes them)"
        )
    rows: dict[str, tuple] = {}  # label: (row, task), the leaderboard's own rows
    for path, task, labels in tables:
        planned = {r.label: r for r in board.rows(task)}
        for label in sorted(labels - set(planned)):
            print(
                f"{bench.name}/{path.name}: {label}: not a row the leaderboard makes (here), "
                f"no cost measured",
                file=sys.stderr,
            )
        for label in sorted(labels & set(planned)):
            rows.setdefault(label, (planned[label], task))
    groups: dict[str, list] = {}  # one measurement per architecture (mlp and mlp@last)
    for label, (row, task) in rows.items():
        if models and row.name not in models:
            continue
        loaded = board.load(row)
        key = cost_key(loaded, bench, board.dataset, task)
        groups.setdefault(architecture(key), []).append((label, loaded, key, task))
    if not groups:
        raise NoRowsError(
            f"{bench.name}: no row of {', '.join(sorted(models)) or 'any model'} in its tables"
        )
    if store.old:
        print(f"{store.path}: older format, replaced whole", file=sys.stderr)
    measured = {} if not models else dict(store.rows)
    started = time.perf_counter()
    for i, (digest, members) in enumerate(groups.items(), 1):
        label, loaded, key, task = members[0]
        labels = ", ".join(m[0] for m in members)
        prefix = f"{bench.name} [{i}/{len(groups)}] {labels}"
        print(f"{prefix}: measuring in float32 (budget {seconds:g} s)", file=sys.stderr)
        began = time.perf_counter()
        costs = measure(
            loaded.model,
            input_frames=key["input_frames"],  # those it reads
            output_frames=bench.output_frames,
            points=key["points"],
            task=task,
            recipe=loaded.recipe,
            device=device,
            seconds=seconds,
            say=lambda text, prefix=prefix: print(f"{prefix}: {text}", file=sys.stderr),
        )
        print(f"{prefix}: done in {time.perf_counter() - began:.0f} s", file=sys.stderr)
        for member in members:
            measured[member[0]] = {"architecture": digest, **costs}
    if len({e["device"] for e in measured.values()}) > 1:  # only with --model
        print(
            f"{bench.name}: its stored costs now come from more than one machine (the table "
            f"names each); zoo costs --benchmark {bench.name} without --model measures every "
            f"row on one",
            file=sys.stderr,
        )
    store.rows = measured
    store.save()
    print(
        f"wrote {store.path} ({len(groups)} model(s), {sum(map(len, groups.values()))} row(s), "
        f"{time.perf_counter() - started:.0f} s)"
    )
    written = [path for path, task, labels in tables if render_costs(board, path, task, labels)]
    for path in written:
        print(f"wrote the cost columns of {path}/{' and '.join(RENDERED)}")
    return written


def committed_tables(board: Leaderboard) -> list[tuple[Path, str, set[str]]]:
    """``(folder, task, row labels)`` of each committed table the leaderboard makes for the
    board's benchmark (every sampler, task and ground truth)."""
    tables = []
    for _, task, _, folder in board.tables():
        path = board.root / board.bench.name / folder
        if (path / TABLE_FILE).is_file():
            tables.append((path, task, set(table_labels(path))))
    return tables


def render_costs(board: Leaderboard, path: Path, task: str, labels: set[str]) -> bool:
    """Rewrite the cost cells (and the line naming their machine) of the table in ``path``
    with the costs now stored, and its ``efficiency.csv``: nothing else of the table, and
    nothing of its rows. Whether a file changed."""
    efficiency: dict = {}
    for row in board.rows(task):
        if row.label in labels:
            board.stored_cost(efficiency, row.label, board.load(row), task)
    models = set(read_table(path, columns=["model"]).frame["model"])
    board_md = path / "leaderboard.md"
    new = {
        board_md: with_costs(board_md.read_text(), models, efficiency, board.bench.name),
        path / "efficiency.csv": efficiency_csv(models, efficiency) if efficiency else None,
    }
    changed = False
    with folder_lock(path):
        for file, text in new.items():
            if text is not None and (not file.is_file() or file.read_text() != text):
                atomic_write_text(file, text)
                changed = True
            elif text is None and file.is_file():
                file.unlink()
                changed = True
    return changed
