"""What a leaderboard writes and draws: a table's ``leaderboard.md`` (tables from
:mod:`zoo.report.tables`), ``protocol.json`` (listing its rows, whose folders beside it hold their
numbers: :func:`zoo.evaluation.results.read_table`), ``efficiency.csv`` and a ``<metric>.png`` per
metric; the shipped models' training curves; ``results/README.md``, the index of every table.
Nothing here evaluates."""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Iterable
from pathlib import Path

import pandas as pd

from zoo.core.io import (
    atomic_path,
    atomic_write_json,
    atomic_write_text,
    figure_drawn_from,
    save_figure,
)
from zoo.evaluation.markdown import markdown_tables, metric_unit
from zoo.evaluation.results import table_files
from zoo.hub.records import WeightsRecord
from zoo.protocol.comparable import check_comparable
from zoo.report.tables import headline_table, table_summary, table_views
from zoo.stats.comparison import table_comparisons


def write_leaderboard(
    results: list,
    out_dir: str | Path,
    horizons_ms: Iterable[int] | None = None,
    efficiency: dict[str, dict] | None = None,
    short_training: dict[str, tuple[str, str | None]] | None = None,
    previous: str | Path | None = None,
) -> Path:
    """Combine :class:`zoo.evaluation.results.EvalResult` objects of one protocol into ``out_dir``:
    ``leaderboard.md``, ``summary.json`` (the same table as data,
    :func:`zoo.report.tables.table_summary`, and :func:`zoo.stats.comparison.table_comparisons`),
    ``protocol.json`` and a ``<metric>.png`` per metric (each result's own folder, beside them,
    holds its ``results.csv``). ``efficiency`` (per row label, the costs ``zoo costs`` stored:
    :class:`zoo.leaderboard.efficiency.Costs`) fills the headline's cost columns and
    ``efficiency.csv`` (a dict without a row's label: its cost cells stay empty, and the table says
    how to fill them). ``short_training``: per row label trained short of its recipe, what its run
    saw and a link to its model's card, marked in the headline. ``previous``: the table's folder
    as stored, whose plots are copied where they were drawn from the same inputs."""
    out_dir = Path(out_dir)
    # Rows and runs in model order, whichever models were evaluated now and which were stored:
    # regenerating then rewrites no unchanged table.
    results = sorted(results, key=lambda r: str(r.frame["model"].iloc[0]))
    records = {r.protocol["protocol_id"]: r.protocol for r in results}
    check_comparable(records)
    frame = pd.concat([r.frame for r in results], ignore_index=True)
    views = table_views(results, horizons_ms, frame)
    headline = headline_table(
        results, horizons_ms, efficiency, short_training=short_training, views=views
    )
    tables = markdown_tables(frame, records, horizons_ms, headline=headline)
    protocol = dict(results[0].protocol)
    protocol["provenance"] = {"runs": [r.protocol.get("provenance", {}) for r in results]}
    atomic_write_text(out_dir / "leaderboard.md", tables)
    atomic_write_json(out_dir / "protocol.json", protocol)
    summary = table_summary(results, horizons_ms, views)
    summary["comparisons"] = table_comparisons(results)
    atomic_write_json(out_dir / "summary.json", summary)
    if efficiency:
        atomic_write_text(out_dir / "efficiency.csv", efficiency_csv(frame["model"], efficiency))
    plot_average(frame, out_dir, title=table_title(tables), previous=previous)
    return out_dir


def table_title(leaderboard: str) -> str:
    """A table's title, as its plots show it: the first line of its ``leaderboard.md``."""
    return leaderboard.splitlines()[0].lstrip("# ")


def efficiency_csv(models: Iterable[str], efficiency: dict[str, dict]) -> str:
    """``efficiency.csv``: the stored costs of a table's ``models``, one row each."""
    labels = sorted(set(models) & set(efficiency))
    costs = pd.DataFrame([{"model": m, **efficiency[m]} for m in labels])
    counts = {c: "Int64" for c in ("latency_repeats", "training_steps") if c in costs}
    return costs.astype(counts).to_csv(index=False)


# One colour and marker per model, in registry order, the same in every table's plot (16
# colours far enough apart to tell; the site's script uses the same list).
PALETTE = (
    "#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf",
    "#7f7f7f", "#bcbd22", "#000080", "#00a087", "#f0027f", "#000000", "#6a3d9a", "#e6ab02",
)  # fmt: skip
MARKERS = ("o", "s", "^", "D", "x", "v")


def model_style(model: str, order: list[str]) -> dict:
    """Matplotlib style of a row: its model's colour and marker (``order``: the models in
    palette order), dashed for an ``@last`` variant or an autoencoder floor."""
    from zoo.protocol.metrics import FLOOR_SUFFIX

    base = model.partition("@")[0].removesuffix(FLOOR_SUFFIX)
    # a name outside the registry (ground_truth) by its letters alone, so that registering a
    # model moves no other colour; the site's script (site.js, style) does the same
    i = order.index(base) if base in order else sum(map(ord, base))
    variant = "@" in model or model.endswith(FLOOR_SUFFIX)
    return {
        "color": PALETTE[i % len(PALETTE)],
        "marker": MARKERS[i % len(MARKERS)],
        "markevery": 3,
        "markersize": 4,
        "linestyle": "--" if variant else "-",
        "linewidth": 1.0 if variant else 1.6,
    }


def plot_files(frame: pd.DataFrame) -> list[str]:
    """The plots a table draws: ``<metric>.png`` for each metric its rows hold."""
    return [f"{m}.png" for m in sorted(set(frame["metric"]))]


def plot_average(
    frame: pd.DataFrame, out_dir: str | Path, title: str = "", previous: str | Path | None = None
) -> list[Path]:
    """Error against horizon for the action average, one file per metric (:func:`plot_files`),
    one panel per averaging and joint set in it. A plot of ``previous`` (a folder) whose digest
    is the one :func:`plot_digests` gives now is copied, not drawn again."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from zoo.models.registry import load_registry

    order = load_registry().list_models()
    avg = frame[frame["action"] == "average"]
    digests = plot_digests(frame, title)
    written = []
    for metric, name in zip(sorted(set(frame["metric"])), plot_files(frame)):
        mine = avg[avg["metric"] == metric]
        unit = metric_unit(metric)[0]
        panels = sorted(mine.groupby(["averaging", "joints"]).groups)
        path, key = Path(out_dir) / name, digests[name]
        if previous is not None and figure_drawn_from(Path(previous) / name) == key:
            with atomic_path(path) as tmp:
                shutil.copyfile(Path(previous) / name, tmp)
            written.append(path)
            continue
        fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 4.0), squeeze=False)
        for ax, (averaging, joints) in zip(axes[0], panels):
            sub = mine[(mine["averaging"] == averaging) & (mine["joints"] == joints)]
            for model, rows in sub.groupby("model"):
                rows = rows.sort_values("horizon_ms")
                ax.plot(rows["horizon_ms"], rows["value"], label=model, **model_style(model, order))
            ax.set_title(f"{metric.upper()}, {averaging} averaging, joints {joints}", fontsize=9)
            ax.set_xlabel("horizon (ms)")
            ax.set_ylabel(metric.upper() + (f" ({unit})" if len(unit) < 16 else ""))
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
        fig.suptitle(f"{metric.upper()} ({unit}) against horizon: {title}", fontsize=9)
        place_panels(fig, len(panels))
        save_figure(fig, path, drawn_from=key, tight=False)
        written.append(path)
    return written


def place_panels(fig, panels: int) -> None:
    """Fixed margins (inches) for :func:`plot_average`'s row of ``panels``: wide enough for the
    y axis's tick labels and unit in every committed plot. tight_layout would measure each
    figure's text in a layout pass of its own before the figure is drawn."""
    left, right, bottom, top, between = 0.8, 0.15, 0.55, 0.65, 0.9
    width, height = fig.get_size_inches()
    axes_width = (width - left - right - (panels - 1) * between) / panels
    fig.subplots_adjust(
        left=left / width,
        right=1 - right / width,
        bottom=bottom / height,
        top=1 - top / height,
        wspace=between / axes_width,
    )


def plot_digests(frame: pd.DataFrame, title: str) -> dict[str, str]:
    """``{file: digest}`` of what :func:`plot_average` draws of ``frame``: per metric, the
    action average's rows, the title and the metric's unit, each model's style, matplotlib's
    version and the source of the functions that draw (a change elsewhere redraws nothing)."""
    import inspect

    import matplotlib

    from zoo.core import io
    from zoo.models.registry import load_registry

    order = load_registry().list_models()
    drawing = (plot_average, place_panels, plot_digests, model_style, io.save_figure)
    code = [inspect.getsource(f) for f in drawing]
    avg = frame[frame["action"] == "average"]
    columns = ["metric", "averaging", "joints", "model", "horizon_ms", "value"]
    digests = {}
    for metric, name in zip(sorted(set(frame["metric"])), plot_files(frame)):
        rows = avg[avg["metric"] == metric][columns].sort_values(columns[:5])
        styles = sorted((m, model_style(m, order)) for m in set(rows["model"]))
        inputs = [
            rows.to_csv(index=False, float_format="%.17g"),
            title,
            metric_unit(metric),
            styles,
            matplotlib.__version__,
            code,
        ]
        digests[name] = hashlib.sha256(json.dumps(inputs, sort_keys=True).encode()).hexdigest()
    return digests


def training_curves(weights_root: str | Path | None, benchmark: str) -> dict[str, WeightsRecord]:
    """``{label: weights record}`` of every shipped model of ``benchmark`` whose record holds
    its training history (exported from a ``last.pt``), for :func:`plot_training_curves`."""
    from zoo.hub.weights import (
        available_weights,
        read_weights_record,
        training_points,
        weights_file,
    )

    records = {}
    for bench, label in available_weights(weights_root):
        if bench != benchmark:
            continue
        record = read_weights_record(weights_file(bench, label, weights_root))
        if training_points(record):  # by the record's label: a file linked twice counts once
            records[record.label] = record
    return records


# A benchmark's training curves of its shipped models, beside its tables.
TRAINING_PLOT = "training.png"


def training_plot_title(benchmark: str) -> str:
    return f"{benchmark}: validation MPJPE while training (shipped models)"


def training_curves_digest(records: dict[str, WeightsRecord], title: str) -> str:
    """What :func:`plot_training_curves` draws: each record's training history, the title,
    matplotlib's version and the drawing code (a table's change elsewhere redraws nothing)."""
    import inspect

    import matplotlib

    from zoo.core import io
    from zoo.hub.weights import training_horizons, training_points

    drawing = (plot_training_curves, training_curves_digest, io.save_figure)
    inputs = [
        sorted((label, training_points(r), training_horizons(r)) for label, r in records.items()),
        title,
        matplotlib.__version__,
        [inspect.getsource(f) for f in drawing],
    ]
    return hashlib.sha256(json.dumps(inputs, sort_keys=True).encode()).hexdigest()


def plot_training_curves(
    records: dict[str, WeightsRecord], path: str | Path, title: str = ""
) -> bool:
    """Validation error against optimizer steps, one line per trained model (``{label: weights
    record}``); where the histories log them, one panel more per validation horizon, each
    model's line beside repeat-last's error on the same windows (dashed, same colour). A file
    already drawn from the same records is left as it is; returns whether it was drawn."""
    digest = training_curves_digest(records, title)
    if figure_drawn_from(path) == digest:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from zoo.hub.weights import training_horizons, training_points

    horizons = {label: training_horizons(r) for label, r in records.items()}
    # one panel per (metric, horizon): a joints-view model's MPJPE never shares a mesh model's RMSE
    panels = list(
        dict.fromkeys(
            (e["metric"], h) for runs in horizons.values() for _, e in runs for h in e["horizons"]
        )
    )
    fig, axes = plt.subplots(1, 1 + len(panels), figsize=(6.5 + 4 * len(panels), 4), squeeze=False)
    ax = axes[0, 0]
    colours = {}
    for label, record in sorted(records.items()):
        steps, errors = zip(*training_points(record))
        (line,) = ax.plot(steps, errors, marker=".", label=label)
        colours[label] = line.get_color()
    ax.set_xlabel("optimizer steps")
    ax.set_ylabel("validation MPJPE (mm)")
    ax.set_yscale("log")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    ax.set_title("mean over predicted frames", fontsize=9)
    for ax, (metric, name) in zip(axes[0, 1:], panels):
        for label, runs in sorted(horizons.items()):
            points = [(s, e) for s, e in runs if e["metric"] == metric and name in e["horizons"]]
            if not points:
                continue
            at = points[0][1]["horizons"].index(name)
            steps = [s for s, _ in points]
            ax.plot(steps, [e["model"][at] for _, e in points], marker=".", color=colours[label])
            ax.plot(
                steps,
                [e["repeat_last"][at] for _, e in points],
                linestyle="--",
                color=colours[label],
                label=f"repeat-last ({label}'s windows)",
            )
        ax.set_xlabel("optimizer steps")
        ax.set_ylabel(f"validation {metric}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        ax.set_title(f"{metric} at {name}", fontsize=9)
    fig.suptitle(title, fontsize=9)
    save_figure(fig, path, drawn_from=digest)
    return True


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
  numbers are in the row's own `<table>/<label>/results.csv`, each line carrying the
  `protocol_id`, and rows of different protocols never share a table
  (`zoo.evaluation.results.read_table` reads a table's rows as one frame). Trained rows name the
  shipped weights (and their sha256) they were computed from.
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
  are named under each table; they are not in the rows' `results.csv` and `--check` does not
  compare them.
- Mesh tables: RMSE is per vertex, normalised by the ground-truth frame's bounding-box
  diagonal; MELV is measured on the k-coefficient reconstructions of the reference and scored
  frames (as SpecTrHuMS measures it) and printed as mean (standard deviation over windows);
  `<model>:autoencoder` rows are a SpecTrHuMS model's floor, the ground-truth future through its
  autoencoder alone. `*-gt_spectral` tables score against the k-coefficient reconstruction.
- Rows marked `reported` are figures printed in papers (`zoo/protocol/published.yaml`), shown
  only where their protocol matches; the others are listed under each table with their
  differences.
"""


def write_index(out_root: str | Path) -> Path:
    """``<out_root>/README.md``: every benchmark's tables with their headline and plots."""
    path = Path(out_root) / "README.md"
    atomic_write_text(path, index_text(out_root))
    return path


def index_text(out_root: str | Path) -> str:
    """What :func:`write_index` writes for the tables under ``out_root``."""
    out_root = Path(out_root)
    lines = [INDEX_PREAMBLE]
    for bench_dir in sorted(p for p in out_root.iterdir() if p.is_dir()):
        tables = table_files(bench_dir)
        if not tables:
            continue
        lines += [f"## {bench_dir.name}", ""]
        if (bench_dir / "sensitivity.md").is_file():
            lines += [
                f"How much the protocol moves the ranking: "
                f"[{bench_dir.name}/sensitivity.md]({bench_dir.name}/sensitivity.md)",
                "",
            ]
        if (bench_dir / TRAINING_PLOT).is_file():
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
                f"[leaderboard]({folder}/leaderboard.md) · [rows]({folder}) (each row's "
                f"`results.csv` in its folder) · plots: "
                + ", ".join(
                    f"[{p.stem}]({folder}/{p.name})" for p in sorted(table.parent.glob("*.png"))
                ),
                "",
            ]
            if headline:  # its heading and table; the leaderboard explains them
                rows = headline.strip().splitlines()
                lines += ["##" + rows[0], "", *[r for r in rows if r.startswith("|")], ""]
    return "\n".join(lines).rstrip() + "\n"
