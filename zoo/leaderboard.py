"""Leaderboard tables and plots from evaluator rows, refusing to mix protocols.

A table has one column per horizon and one row per (model, action); every number in it must
come from the same protocol record. Rows whose records differ raise
:class:`ProtocolMismatchError`, which names the fields that differ.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np
import pandas as pd
from tabulate import tabulate

from zoo.errors import ZooError
from zoo.io import atomic_path, atomic_write_json, atomic_write_text


class ProtocolMismatchError(ZooError, ValueError):
    pass


# Units and printed precision per metric: RMSE is normalised by the bounding-box diagonal.
METRIC_UNITS = {"mpjpe": ("mm", ".2f"), "melv": ("mm", ".3f"), "rmse": ("normalised", ".4f")}


def metric_unit(metric: str) -> tuple[str, str]:
    return METRIC_UNITS.get(metric, ("", ".4g"))


def _comparable(record: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in record.items() if k not in ("provenance", "protocol_id")}


def protocol_differences(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    """Human-readable differences between the comparable parts of two protocol records."""
    a, b = _comparable(a), _comparable(b)
    out = []
    for key in sorted(set(a) | set(b)):
        if a.get(key) == b.get(key):
            continue
        if key == "files" and isinstance(a.get(key), list) and isinstance(b.get(key), list):
            fa = {f["file"]: f.get("sha256") for f in a[key]}
            fb = {f["file"]: f.get("sha256") for f in b[key]}
            only_a, only_b = sorted(set(fa) - set(fb)), sorted(set(fb) - set(fa))
            changed = sorted(f for f in set(fa) & set(fb) if fa[f] != fb[f])
            parts = [f"only in first: {only_a}" if only_a else "",
                     f"only in second: {only_b}" if only_b else "",
                     f"different sha256: {changed}" if changed else ""]
            out.append("files (" + "; ".join(p for p in parts if p) + ")")
        else:
            out.append(f"{key} ({a.get(key)!r} vs {b.get(key)!r})")
    return out


def check_comparable(records: dict[str, dict[str, Any]]) -> None:
    """Raise unless every record has the same comparable part."""
    items = list(records.items())
    for pid, record in items[1:]:
        diff = protocol_differences(items[0][1], record)
        if diff:
            first = items[0][1].get("provenance", {}).get("model", items[0][0])
            second = record.get("provenance", {}).get("model", pid)
            raise ProtocolMismatchError(
                f"refusing to put rows of different protocols in one table: protocol "
                f"{items[0][0]} ({first}) and {pid} ({second}) differ in " + "; ".join(diff))


def markdown_tables(frame: pd.DataFrame, records: dict[str, dict[str, Any]],
                    horizons_ms: Iterable[int] | None = None, headline: str = "") -> str:
    """One Markdown table per (metric, averaging, joints), horizons as columns, after the
    ``headline`` table if given."""
    ids = sorted(frame["protocol_id"].unique())
    missing = [i for i in ids if i not in records]
    if missing:
        raise ProtocolMismatchError(f"rows carry protocol ids {missing} with no protocol record")
    check_comparable({i: records[i] for i in ids})
    record = records[ids[0]]
    horizons = list(horizons_ms or _default_horizons(frame))
    out = [f"# {record['benchmark']}: {record['dataset']} {record['split']}, "
           f"sampler {record['sampler']}, {record['input_frames']} in / "
           f"{record['output_frames']} out at {record['fps']:g} fps",
           "", f"Protocol {ids[0]}; actions present: {', '.join(record['actions_present'])}; "
           f"{record['action_averaging']}.", ""]
    if headline:
        out += [headline, ""]
    for (metric, averaging, joints), group in frame.groupby(["metric", "averaging", "joints"],
                                                            sort=True):
        table = (group[group["horizon_ms"].isin(horizons)]
                 .pivot_table(index=["model", "action"], columns="horizon_ms", values="value",
                              sort=False))
        table = table.reindex(columns=[h for h in horizons if h in table.columns])
        order = _action_order(record)
        table = table.sort_index(level=["model", "action"],
                                 key=lambda idx: idx.map(order) if idx.name == "action" else idx)
        description = record.get("joint_protocols", {}).get(joints, "")
        unit = metric_unit(metric)[0]
        out += [f"## {metric.upper()} ({unit}), averaging `{averaging}`, joints `{joints}`", "",
                f"{record.get('averaging', {}).get(averaging, '')}. {description}.", "",
                tabulate(table.reset_index(), headers=["model", "action"] +
                         [f"{h} ms" for h in table.columns], tablefmt="github",
                         floatfmt=metric_unit(metric)[1], showindex=False), ""]
    return "\n".join(out)


def _default_horizons(frame: pd.DataFrame) -> list[int]:
    standard = [80, 160, 320, 400, 560, 720, 880, 1000]
    present = set(frame["horizon_ms"])
    chosen = [h for h in standard if h in present]
    return chosen or sorted(present)


def _action_order(record: dict[str, Any]) -> dict[str, int]:
    order = {a: i for i, a in enumerate(record.get("actions_present", []))}
    order["average"] = len(order)
    return order


def write_leaderboard(results: list, out_dir: str | Path,
                      horizons_ms: Iterable[int] | None = None) -> Path:
    """Combine :class:`zoo.evaluate.EvalResult` objects of one protocol into ``out_dir``:
    ``results.csv``, ``leaderboard.md``, ``protocol.json`` and ``mpjpe.png``."""
    out_dir = Path(out_dir)
    # Rows and runs in model order, whichever models were evaluated now and which were stored:
    # regenerating then rewrites no unchanged table.
    results = sorted(results, key=lambda r: str(r.frame["model"].iloc[0]))
    records = {r.protocol["protocol_id"]: r.protocol for r in results}
    check_comparable(records)
    frame = pd.concat([r.frame for r in results], ignore_index=True)
    tables = markdown_tables(frame, records, horizons_ms,
                             headline=headline_table(results, horizons_ms))
    protocol = dict(results[0].protocol)
    protocol["provenance"] = {"runs": [r.protocol.get("provenance", {}) for r in results]}
    atomic_write_text(out_dir / "results.csv", frame.to_csv(index=False))
    atomic_write_text(out_dir / "leaderboard.md", tables)
    atomic_write_json(out_dir / "protocol.json", protocol)
    plot_average(frame, out_dir / "mpjpe.png", title=tables.splitlines()[0].lstrip("# "))
    return out_dir


def headline_table(results: list, horizons_ms: Iterable[int] | None = None) -> str:
    """Models as rows, horizons as columns: the benchmark's headline metric (frame averaging,
    action average) with half its 95% block-bootstrap interval, in bold where a model is the
    best at that horizon or not distinguishable from it (their paired interval holds zero)."""
    from zoo.compare import block_frames_default, headline_key, window_errors
    from zoo.intervals import REPLICATES, block_bootstrap, percentile_interval, \
        short_recordings

    record = results[0].protocol
    metric, joints = headline_key(record)
    frame = pd.concat([r.frame for r in results], ignore_index=True)
    rows = frame[(frame["metric"] == metric) & (frame["joints"] == joints) &
                 (frame["averaging"] == "frame") & (frame["action"] == "average")]
    if rows.empty:
        return ""
    horizons = [h for h in (horizons_ms or _default_horizons(frame)) if h in set(rows.horizon_ms)]
    values = rows.pivot_table(index="model", columns="horizon_ms", values="value")[horizons]
    frame_of = dict(zip(rows["horizon_ms"], rows["frame"]))
    columns = [int(frame_of[h]) - 1 for h in horizons]  # 0-based predicted frame of each
    errors = {str(r.frame["model"].iloc[0]): r for r in results if r.windows is not None
              and (str(r.frame["model"].iloc[0]), metric, joints) in r.windows.errors}
    errors = {m: window_errors(r, m, metric, joints)[:, columns] for m, r in errors.items()}
    windows = next((r.windows for r in results if r.windows is not None), None)
    block = block_frames_default(windows) if windows is not None else None

    def interval(values_: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return percentile_interval(block_bootstrap(values_, windows.sequence, windows.start,
                                                   windows.action, block, REPLICATES))

    half = {}
    for m, e in errors.items():
        lo, hi = interval(e)
        half[m] = (hi - lo) / 2
    fmt = metric_unit(metric)[1]
    best = values.idxmin()
    tied: dict[tuple[str, int], bool] = {}
    paired: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]] = {}
    for i, h in enumerate(horizons):
        for m in errors:
            if m != best[h] and best[h] in errors:
                if (m, best[h]) not in paired:
                    paired[m, best[h]] = interval(errors[m] - errors[best[h]])
                lo, hi = paired[m, best[h]]
                tied[m, h] = bool(lo[i] <= 0 <= hi[i])
    table = []
    for m in values.index:
        cells = []
        for i, h in enumerate(horizons):
            text = f"{values.loc[m, h]:{fmt}}" + (f" ±{half[m][i]:{fmt}}" if m in half else "")
            cells.append(f"**{text}**" if tied.get((m, h), m == best[h]) else text)
        table.append([m, *cells])
    unit = metric_unit(metric)[0]
    if windows is None:
        how = "no per-window errors stored, so no intervals"
    else:
        short = short_recordings(windows.sequence, windows.start, block)
        how = (f"± is half the 95% block-bootstrap interval (circular blocks of {block} frames "
               f"within each recording, {REPLICATES} replicates, seed 0); **bold**: the lowest "
               f"error at that horizon and every model whose paired 95% interval against it "
               f"holds zero (not distinguishable from the best)")
        if short:
            names = [windows.sequences[i] for i in short]
            how += (f". {len(names)} recording(s) hold fewer than two blocks of overlapping "
                    f"windows ({', '.join(names[:6])}{', ...' if len(names) > 6 else ''}): the "
                    f"bootstrap cannot see their full variance, so these intervals are too "
                    f"narrow")
    return "\n".join([f"## Headline: {metric.upper()} ({unit}), averaging `frame`, joints "
                      f"`{joints}`, mean over actions", "", how + ".", "",
                      tabulate(table, headers=["model"] + [f"{h} ms" for h in horizons],
                               tablefmt="github", disable_numparse=True)])


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
    _save_figure(fig, path)


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
    _save_figure(fig, path)


def _save_figure(fig, path: str | Path) -> None:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)


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
    truths = (bench.ground_truths or (bench.ground_truth,)) if bench.representation == "mesh" \
        else (None,)
    tasks = dict.fromkeys(["prediction", *(registry.get(n).task for n in registry.list_models())])
    for sampler in bench.samplers:
        for task in tasks:
            for truth in truths:
                folder = results_folder(sampler, task, truth)
                path = _regenerate_one(bench, registry, dataset, sampler, truth, folder,
                                       out_root, checkpoints, device, task, weights, check)
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


def results_folder(sampler: str, task: str = "prediction", truth: str | None = None,
                   horizon: int | None = None) -> str:
    """The folder under ``results/<benchmark>/`` of one sampler, task and ground truth:
    ``all``, ``all-completion``, ``all-longterm50``, ``all-gt_spectral``, ..."""
    folder = sampler if task == "prediction" else f"{sampler}-{task}{horizon or ''}"
    return folder if truth in (None, "raw") else f"{folder}-gt_{truth}"


def _regenerate_one(bench, registry, dataset, sampler, truth, folder, out_root, checkpoints,
                    device, task="prediction", weights=None, check=None):
    import sys

    from zoo.evaluate import EvalResult, evaluate

    results, stored = [], []
    # Skeleton models join a mesh benchmark with a joint regressor, fed its regressed joints.
    names = registry.list_models(bench.representation)
    if bench.representation == "mesh" and dataset.joint_regressor is not None:
        names += [n for n in registry.list_models("joints") if n not in names]
    names = [n for n in names if registry.get(n).task == task]
    if task != "prediction" and not any(registry.get(n).trainable and _has_run(
            out_root / bench.name / folder / n, checkpoints, bench.name, n, weights)
            for n in names):
        return None  # a table of baselines alone says nothing about this task
    for name in names:
        entry = registry.get(name)
        view = bench.view_for(entry.representation)
        for label, ckpt in _checkpoints_of(name, entry, bench, checkpoints):
            run_dir = out_root / bench.name / folder / label
            provenance = {}
            shipped = _shipped(weights, bench.name, label) if entry.trainable else None
            if shipped is not None:
                from zoo.weights import load_weights, weights_provenance

                model, record = load_weights(shipped, registry=registry, benchmark=bench,
                                             dataset=dataset)
                provenance = weights_provenance(shipped, record)
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
            elif not entry.trainable:
                model = registry.create_model(name, **bench.model_inputs(
                    entry.context, dataset=dataset, view=view))
            elif (run_dir / "results.csv").is_file():
                if check is not None:
                    check.problems.append(f"{run_dir}: cannot be recomputed (no shipped weights "
                                          f"{bench.name}/{label}.safetensors, no checkpoint)")
                    continue
                stored.append(EvalResult.read(run_dir))
                print(f"{bench.name}/{folder}: {label}: no checkpoint here, keeping {run_dir}",
                      file=sys.stderr)
                continue
            else:
                if label == name:
                    print(f"{bench.name}/{folder}: {name}: skipped (trainable; no shipped "
                          f"weights, no checkpoint{f' at {ckpt}' if ckpt else ''})",
                          file=sys.stderr)
                continue
            result = evaluate(model, bench, model_name=label, sampler=sampler, dataset=dataset,
                              device=device, provenance=provenance, ground_truth=truth,
                              view=view, task=task)
            if check is None:
                result.write(run_dir)
            results.append(result)
    # Freshly evaluated results come first: they define the protocol stored ones must match.
    kept = _drop_mismatched(results + stored, bench.name, folder)
    if not kept:
        return None
    if check is not None:
        _check_table(kept, out_root / bench.name / folder, check)
        return out_root / bench.name / folder
    path = write_leaderboard(kept, out_root / bench.name / folder, bench.horizons_ms)
    print(f"wrote {path}/leaderboard.md ({len(kept)} models, {len(results)} evaluated now)")
    return path


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
    difference = (matched["value"] - matched["value_committed"]).abs()
    relative = difference / matched["value_committed"].abs().clip(lower=1e-12)
    if len(matched):
        check.max_difference = max(check.max_difference, float(difference.max()))
    for row, rel in zip(matched[relative > check.tolerance].itertuples(),
                        relative[relative > check.tolerance]):
        check.problems.append(f"{folder}/results.csv: " + ", ".join(
            f"{k}={getattr(row, k)}" for k in KEY_COLUMNS) + f": committed "
            f"{row.value_committed!r}, recomputed {row.value!r} (relative {rel:.2g})")
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
        for key, values in r.windows.errors.items():
            old = stored.errors.get(key)
            if old is None or old.shape != values.shape or not (
                    np.array_equal(stored.start, r.windows.start)
                    and np.array_equal(stored.sequence, r.windows.sequence)):
                check.problems.append(f"{path}: {'/'.join(key)}: missing or for other windows")
                continue
            gap = np.abs(old.astype(np.float64) - values) / np.maximum(np.abs(old), 1e-12)
            if gap.max() > check.tolerance:
                check.problems.append(f"{path}: {'/'.join(key)}: per-window errors differ "
                                      f"(relative up to {gap.max():.2g})")


def _has_run(run_dir: Path, checkpoints, bench_name: str, name: str, weights=None) -> bool:
    """Whether a trained model has shipped weights, a checkpoint or a stored result to show."""
    return (run_dir / "results.csv").is_file() or bool(
        checkpoints and (Path(checkpoints) / bench_name / name / "best.pt").is_file()) or \
        _shipped(weights, bench_name, name) is not None


def _shipped(weights, bench_name: str, label: str) -> Path | None:
    """The shipped weights of ``label`` on a benchmark, if any."""
    if not weights:
        return None
    from zoo.weights import weights_file

    path = weights_file(bench_name, label, weights)
    return path if path.is_file() else None


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
