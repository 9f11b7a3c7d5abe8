"""Leaderboards: re-evaluate every model a benchmark can show (``regenerate``), write
``results/<benchmark>/<sampler>/`` (tables from :mod:`zoo.tables`, plots), or check the
committed ones without writing (``CheckReport``)."""
from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np
import pandas as pd

from zoo.io import atomic_write_json, atomic_write_text, folder_lock, replace_folder, \
    save_figure
from zoo.tables import check_comparable, headline_table, markdown_tables, metric_unit, \
    protocol_differences


def write_leaderboard(results: list, out_dir: str | Path,
                      horizons_ms: Iterable[int] | None = None,
                      efficiency: dict[str, dict] | None = None) -> Path:
    """Combine :class:`zoo.evaluate.EvalResult` objects of one protocol into ``out_dir``:
    ``results.csv``, ``leaderboard.md``, ``protocol.json`` and ``mpjpe.png``; ``efficiency``
    (per model, :func:`zoo.efficiency.measure`) fills the headline's cost columns and
    ``efficiency.csv``."""
    out_dir = Path(out_dir)
    # Rows and runs in model order, whichever models were evaluated now and which were stored:
    # regenerating then rewrites no unchanged table.
    results = sorted(results, key=lambda r: str(r.frame["model"].iloc[0]))
    records = {r.protocol["protocol_id"]: r.protocol for r in results}
    check_comparable(records)
    frame = pd.concat([r.frame for r in results], ignore_index=True)
    tables = markdown_tables(frame, records, horizons_ms,
                             headline=headline_table(results, horizons_ms, efficiency))
    protocol = dict(results[0].protocol)
    protocol["provenance"] = {"runs": [r.protocol.get("provenance", {}) for r in results]}
    atomic_write_text(out_dir / "results.csv", frame.to_csv(index=False))
    atomic_write_text(out_dir / "leaderboard.md", tables)
    atomic_write_json(out_dir / "protocol.json", protocol)
    if efficiency:
        labels = sorted(set(frame["model"]) & set(efficiency))
        atomic_write_text(out_dir / "efficiency.csv", pd.DataFrame(
            [{"model": m, **efficiency[m]} for m in labels]).to_csv(index=False))
    plot_average(frame, out_dir / "mpjpe.png", title=tables.splitlines()[0].lstrip("# "))
    return out_dir


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
        sub = avg[(avg["metric"] == metric) & (avg["averaging"] == averaging) &
                  (avg["joints"] == joints)]
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


def training_curves(weights_root: str | Path | None, benchmark: str
                    ) -> dict[str, list[tuple[int, float]]]:
    """``{label: [(optimizer steps, validation MPJPE mm), ...]}`` of every shipped model of
    ``benchmark`` whose record holds its training history (exported from a ``last.pt``)."""
    from zoo.weights import available_weights, read_weights, weights_file

    curves = {}
    for bench, label in available_weights(weights_root):
        if bench != benchmark:
            continue
        record = read_weights(weights_file(bench, label, weights_root))[1]
        history, batch = record.get("history"), (record.get("recipe") or {}).get("batch_size")
        if not history or not batch:
            continue
        steps, points = 0, []
        for epoch in history:
            steps += epoch["samples"] // batch
            points.append((steps, epoch["val_mpjpe"]))
        curves[label] = points
    return curves


def plot_training_curves(curves: dict[str, list[tuple[int, float]]], path: str | Path,
                         title: str = "") -> None:
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
    difference from the committed values, and every problem (a row that differs, a row or
    table missing on either side, a row that cannot be recomputed)."""
    tolerance: float = 1e-6
    rows: int = 0
    tables: int = 0
    models: set = field(default_factory=set)
    max_difference: float = 0.0
    problems: list = field(default_factory=list)

    def summary(self) -> str:
        return (f"checked {self.rows} rows of {len(self.models)} models in {self.tables} tables: "
                f"max |difference| {self.max_difference:.3g}")


def regenerate(benchmark, *, registry=None, data_root=None, out_root: str | Path = "results",
               checkpoints: str | Path | None = None, weights: str | Path | None = None,
               device: str = "cpu", check: CheckReport | None = None) -> list[Path]:
    """Re-evaluate every model that can be evaluated on ``benchmark`` under each of its samplers
    (and, for mesh benchmarks, each ground truth: ``<sampler>-gt_spectral`` beside ``<sampler>``)
    and rebuild ``<out_root>/<benchmark>/<sampler>/``.

    A model is evaluated if it needs no training, if shipped weights
    ``<weights>/<benchmark>/<label>.safetensors`` exist (they take precedence: a published row
    is always computed from the published weights), or if its checkpoint
    ``<checkpoints>/<benchmark>/<model>/best.pt`` (where ``zoo train`` writes it) exists;
    otherwise a result folder already under ``out_root`` (from an earlier ``zoo eval
    --checkpoint``) is kept if its protocol still matches, and skipped with a warning naming the
    difference if not.

    ``check``: write nothing; recompute every row and compare it with the committed tables
    under ``out_root``, recording every difference in the report (a row that cannot be
    recomputed is a problem, never kept).
    """
    from zoo.benchmark import get_benchmark
    from zoo.registry import load_registry

    registry = registry or load_registry()
    bench = get_benchmark(benchmark) if isinstance(benchmark, (str, Path)) else benchmark
    dataset = bench.load(data_root)
    out_root = Path(out_root)
    written = []
    costs: dict = {}  # one measurement per architecture and benchmark, shared by its tables
    truths = (bench.ground_truths or (bench.ground_truth,)) if bench.representation == "mesh" \
        else (None,)
    tasks = dict.fromkeys(["prediction", *(registry.get(n).task for n in registry.list_models())])
    for sampler in bench.samplers:
        for task in tasks:
            for truth in truths:
                folder = results_folder(sampler, task, truth)
                path = _regenerate_one(bench, registry, dataset, sampler, truth, folder,
                                       out_root, checkpoints, device, task, weights, check,
                                       costs)
                if path is not None:
                    written.append(path)
    if check is not None:
        produced = {p.name for p in written}
        for table in sorted((out_root / bench.name).glob("*/results.csv")):
            if table.parent.name not in produced:
                check.problems.append(f"{table}: a committed table that the leaderboard no "
                                      f"longer produces")
        return written
    curves = training_curves(weights, bench.name) if weights else {}
    if curves:
        plot_training_curves(curves, out_root / bench.name / "training.png",
                             title=f"{bench.name}: validation MPJPE while training "
                                   f"(shipped models)")
    return written


INDEX_PREAMBLE = """# Results

Every table here is regenerated by `zoo leaderboard` (the README's first command does cloth and
CMU; `--benchmark NAME` any other) and re-checked without writing by `zoo leaderboard --check`,
which recomputes every row (baselines, and trained models from the weights shipped in
`weights/`) and names any that differs from the committed value by more than 1e-6 relative.

How each number is made:

- Each row is one model evaluated by `zoo.evaluate` under the protocol recorded in the folder's
  `protocol.json` (data files and hashes, window sampler, frame rate, joints, averaging); its
  `protocol_id` is in every row of `results.csv`, and rows of different protocols never share a
  table. Trained rows name the shipped weights (and their sha256) they were computed from.
- Headline tables: the benchmark's first metric, frame averaging, mean over actions; `±` is half
  the 95% block-bootstrap interval over windows (README, "How sure a number is"), bold marks the
  best model and those not distinguishable from it; `zoo compare A B --benchmark NAME` says by
  how much one model beats another.
- Cost columns (parameters, forward GFLOPs per window, latency of one window, training windows
  per second) are measured by the machine that wrote the table, named under it; they are not in
  `results.csv` and `--check` does not compare them.
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
        if (bench_dir / "training.png").is_file():
            lines += [f"Training curves of the shipped models: "
                      f"[{bench_dir.name}/training.png]({bench_dir.name}/training.png)", ""]
        for table in tables:
            folder = table.parent.relative_to(out_root).as_posix()
            text = table.read_text()
            start = text.find("## Headline")
            headline = text[start:] if start >= 0 else ""
            for marker in ("\n### ", "\n## "):
                cut = headline.find(marker, 1)
                headline = headline[:cut] if cut >= 0 else headline
            lines += [f"### {folder}", "",
                      f"[leaderboard]({folder}/leaderboard.md) · [results.csv]({folder}/results.csv)"
                      f" · [plot]({folder}/mpjpe.png)", ""]
            if headline:  # its heading and table; the leaderboard explains them
                rows = headline.strip().splitlines()
                lines += ["##" + rows[0], "", *[r for r in rows if r.startswith("|")], ""]
    path = out_root / "README.md"
    atomic_write_text(path, "\n".join(lines).rstrip() + "\n")
    return path


def results_folder(sampler: str, task: str = "prediction", truth: str | None = None,
                   horizon: int | None = None, melv: str | None = None) -> str:
    """The folder under ``results/<benchmark>/`` of one sampler, task, ground truth and (when
    not the benchmark's default) MELV frames: ``all``, ``all-completion``, ``all-longterm50``,
    ``all-gt_spectral``, ``all-melv_raw``, ..."""
    folder = sampler if task == "prediction" else f"{sampler}-{task}{horizon or ''}"
    folder = folder if truth in (None, "raw") else f"{folder}-gt_{truth}"
    return folder if melv is None else f"{folder}-melv_{melv}"


def _regenerate_one(bench, registry, dataset, sampler, truth, folder, out_root, checkpoints,
                    device, task="prediction", weights=None, check=None, costs=None):
    """One table: checked, or rebuilt under a lock and replaced as a whole (an interrupted
    regeneration leaves the old folder, never a half-written one)."""
    with folder_lock(out_root / bench.name / folder) if check is None else nullcontext():
        return _table(bench, registry, dataset, sampler, truth, folder, out_root, checkpoints,
                      device, task, weights, check, costs)


def _table(bench, registry, dataset, sampler, truth, folder, out_root, checkpoints, device,
           task, weights, check, costs):
    import shutil
    import sys

    from zoo.evaluate import EvalResult, evaluate

    results, stored, stored_dirs, efficiency = [], [], [], {}
    costs = {} if costs is None else costs
    # Skeleton models join a mesh benchmark with a joint regressor, fed its regressed joints.
    names = registry.list_models(bench.representation)
    if bench.representation == "mesh" and dataset.joint_regressor is not None:
        names += [n for n in registry.list_models("joints") if n not in names]
    names = [n for n in names if registry.get(n).task == task]
    if task != "prediction" and not any(registry.get(n).trainable and _has_run(
            out_root / bench.name / folder / n, checkpoints, bench, n, weights)
            for n in names):
        return None  # a table of baselines alone says nothing about this task
    for name in names:
        entry = registry.get(name)
        view = bench.view_for(entry.representation)
        for label, ckpt in _checkpoints_of(name, entry, bench, checkpoints):
            run_dir = out_root / bench.name / folder / label
            provenance = {}
            shipped = _shipped(weights, bench, label) if entry.trainable else None
            if shipped is not None:
                from zoo.train import load_weights
                from zoo.weights import weights_provenance

                model, record = load_weights(shipped, registry=registry, benchmark=bench,
                                             dataset=dataset)
                provenance = weights_provenance(shipped, record)
                recipe = record.get("recipe")
                if ckpt is not None and ckpt.is_file():
                    print(f"{bench.name}/{folder}: {label}: evaluating the shipped weights "
                          f"{shipped}, not {ckpt} (zoo weights export publishes a checkpoint)",
                          file=sys.stderr)
            elif ckpt is not None and ckpt.is_file():
                from zoo.train import checkpoint_provenance, load_checkpoint

                model, meta = load_checkpoint(ckpt, registry=registry, benchmark=bench,
                                              dataset=dataset)
                training = meta.get("training", {})
                if label != name and training.get("best", {}).get("epoch") == \
                        training.get("epochs_run"):
                    continue  # trained no further than its best epoch: best.pt's weights
                provenance = checkpoint_provenance(ckpt, meta)
                recipe = meta.get("recipe")
            elif not entry.trainable:
                model = registry.create_model(name, **bench.model_inputs(
                    entry.context, dataset=dataset, view=view))
                recipe = None
            elif (run_dir / "results.csv").is_file():
                if check is not None:
                    check.problems.append(f"{run_dir}: cannot be recomputed (no shipped weights "
                                          f"{bench.name}/{label}.safetensors, no checkpoint)")
                    continue
                stored.append(EvalResult.read(run_dir))
                stored_dirs.append(run_dir)
                print(f"{bench.name}/{folder}: {label}: no checkpoint here, keeping {run_dir}",
                      file=sys.stderr)
                continue
            else:
                if label == name:
                    print(f"{bench.name}/{folder}: {name}: skipped (trainable; no shipped "
                          f"weights, no checkpoint{f' at {ckpt}' if ckpt else ''})",
                          file=sys.stderr)
                continue
            provenance = {**entry.provenance(), **provenance}
            result = evaluate(model, bench, model_name=label, sampler=sampler, dataset=dataset,
                              device=device, provenance=provenance, ground_truth=truth,
                              view=view, task=task)
            if check is None:
                efficiency[label] = _cost(costs, name, provenance.get("hparams"), model, bench,
                                          dataset, view, task, recipe, device)
            results.append(result)
    # Freshly evaluated results come first: they define the protocol stored ones must match.
    kept = _drop_mismatched(results + stored, bench.name, folder)
    if not kept:
        return None
    if check is not None:
        _check_table(kept, out_root / bench.name / folder, check)
        return out_root / bench.name / folder
    path = out_root / bench.name / folder
    with replace_folder(path, lock=False) as tmp:
        for result in results:
            result.write(tmp / str(result.frame["model"].iloc[0]), replace=False)
        for source in stored_dirs:  # kept on disk even when left out of the table
            shutil.copytree(source, tmp / source.name)
        write_leaderboard(kept, tmp, bench.horizons_ms, efficiency)
    print(f"wrote {path}/leaderboard.md ({len(kept)} models, {len(results)} evaluated now)")
    return path


def _cost(costs, name, hparams, model, bench, dataset, view, task, recipe, device):
    """The efficiency columns of a model, measured once per architecture on a benchmark."""
    import json

    from zoo.efficiency import measure

    key = (name, json.dumps(hparams, sort_keys=True, default=str), view, task)
    if key not in costs:
        points = bench.model_inputs(dataset=dataset, view=view)["num_points"]
        costs[key] = measure(model, input_frames=bench.input_frames,
                             output_frames=bench.output_frames, points=points, task=task,
                             recipe=recipe, device=device)
    return costs[key]


KEY_COLUMNS = ["model", "action", "metric", "averaging", "joints", "horizon_ms"]


def _check_table(results: list, folder: Path, check: CheckReport) -> None:
    """Compare freshly computed results with the committed table in ``folder`` (and each
    model's per-window errors with its ``windows.npz``)."""
    from zoo.evaluate import WINDOWS_FILE, WindowErrors

    check.tables += 1
    fresh = pd.concat([r.frame for r in results], ignore_index=True)
    check.rows += len(fresh)
    check.models |= set(fresh["model"])
    if not (folder / "results.csv").is_file():
        check.problems.append(f"{folder}/results.csv: missing; the leaderboard makes this table")
        return
    committed = pd.read_csv(folder / "results.csv")
    both = fresh.merge(committed, on=KEY_COLUMNS, how="outer", suffixes=("", "_committed"),
                       indicator="side")
    for row in both[both["side"] != "both"].itertuples():
        where = "committed only" if row.side == "right_only" else "recomputed only"
        check.problems.append(f"{folder}/results.csv: {where}: " + ", ".join(
            f"{k}={getattr(row, k)}" for k in KEY_COLUMNS))
    matched = both[both["side"] == "both"]
    for column in ("value", "std"):  # the mean and its standard deviation over windows
        if f"{column}_committed" not in matched:
            check.problems.append(f"{folder}/results.csv: no column {column!r} (written by an "
                                  f"older zoo); regenerate the table")
            continue
        fresh_values, old_values = matched[column], matched[f"{column}_committed"]
        difference = (fresh_values - old_values).abs()
        relative = difference / old_values.abs().clip(lower=1e-12)
        # a NaN (the spread of a single window) matches only a NaN
        differs = (relative > check.tolerance) | (fresh_values.isna() != old_values.isna())
        if len(matched) and column == "value":
            check.max_difference = max(check.max_difference, float(difference.max()))
        for row, rel in zip(matched[differs].itertuples(), relative[differs]):
            check.problems.append(f"{folder}/results.csv: " + ", ".join(
                f"{k}={getattr(row, k)}" for k in KEY_COLUMNS) + f": {column} committed "
                f"{getattr(row, column + '_committed')!r}, recomputed {getattr(row, column)!r} "
                f"(relative {rel:.2g})")
    for row in matched[matched["protocol_id"] != matched["protocol_id_committed"]] \
            .drop_duplicates("model").itertuples():
        check.problems.append(f"{folder}/results.csv: {row.model}: protocol "
                              f"{row.protocol_id_committed} committed, {row.protocol_id} now")
    for r in results:
        if r.windows is None:
            continue
        label = str(r.frame["model"].iloc[0])
        path = folder / label / WINDOWS_FILE
        if not path.is_file():
            check.problems.append(f"{path}: missing (per-window errors of {label})")
            continue
        stored = WindowErrors.read(path)
        same_windows = np.array_equal(stored.start, r.windows.start) and \
            np.array_equal(stored.sequence, r.windows.sequence)
        for key, values in r.windows.errors.items():
            old = stored.errors.get(key)
            if old is None or not same_windows:
                check.problems.append(f"{path}: {'/'.join(key)}: missing or for other windows")
                continue
            gap = np.abs(old.astype(np.float64) - values) / np.maximum(np.abs(old), 1e-12)
            if gap.max() > check.tolerance:
                check.problems.append(f"{path}: {'/'.join(key)}: per-window errors differ "
                                      f"(relative up to {gap.max():.2g})")


def _has_run(run_dir: Path, checkpoints, bench, name: str, weights=None) -> bool:
    """Whether a trained model has shipped weights, a checkpoint or a stored result to show."""
    return (run_dir / "results.csv").is_file() or bool(
        checkpoints and (Path(checkpoints) / bench.name / name / "best.pt").is_file()) or \
        _shipped(weights, bench, name) is not None


def _shipped(weights, bench, label: str) -> Path | None:
    """The shipped weights of ``label`` on a benchmark, if any: its own, else those of the
    benchmark it takes weights from (``weights_from``)."""
    if not weights:
        return None
    from zoo.weights import weights_file

    for name in (bench.name, bench.weights_from):
        path = weights_file(name, label, weights) if name else None
        if path is not None and path.is_file():
            return path
    return None


def _checkpoints_of(name, entry, bench, checkpoints):
    """``(label, checkpoint path or None)`` to evaluate for a model: untrained models once;
    trained ones by their early-stopped checkpoint (``best.pt``, labelled with the model's name)
    and their fully trained one (``last.pt``, ``<name>@last``), which is shown only when training
    went on past the best epoch: the two can trade accuracy for smoothness (SpecTrHuMS reports
    both)."""
    if not entry.trainable:
        return [(name, None)]
    run = Path(checkpoints) / bench.name / name if checkpoints else None
    return [(name, run and run / "best.pt"), (f"{name}@last", run and run / "last.pt")]


def _drop_mismatched(results: list, bench: str, sampler: str) -> list:
    """Keep the results whose protocol matches the freshly evaluated reference."""
    import sys

    if not results:
        return []
    reference = results[0].protocol
    kept = [results[0]]
    for r in results[1:]:
        diff = protocol_differences(reference, r.protocol)
        if diff:
            model = r.protocol.get("provenance", {}).get("model", "?")
            print(f"{bench}/{sampler}: {model}: its stored result was measured under another "
                  f"protocol ({'; '.join(diff)}); left out of the leaderboard", file=sys.stderr)
        else:
            kept.append(r)
    return kept
