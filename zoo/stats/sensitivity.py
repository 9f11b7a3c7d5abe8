"""How much the protocol moves a ranking: every model's headline numbers under every protocol a
benchmark's tables measure (window sampler and ground truth, frame or cumulative averaging, joint
set), each model's rank within each protocol, and every rank that differs from the reference
protocol (the benchmark's first table, frame averaging, headline joints) marked.

Published figures sit in the column of the protocol they were measured in, unranked.

    from zoo.stats.sensitivity import protocol_sensitivity
    table = protocol_sensitivity("results/cmu")   # a DataFrame; .markdown() and .plot() below
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from tabulate import tabulate

from zoo.core.io import atomic_write_text, figure_drawn_from, save_figure
from zoo.evaluation.markdown import headline_key, metric_unit
from zoo.stats.ranking import is_floor

HORIZONS_MS = (80, 400, 1000)


@dataclass
class Sensitivity:
    """``values``: one row per model, columns ``(protocol, horizon_ms)``; ``ranks`` the same
    shape (1 = lowest error among the models measured under that protocol); ``reported``:
    published figures as ``(label, protocol) -> {horizon_ms: value}``."""

    benchmark: str
    metric: str
    protocols: list[str]
    horizons: list[int]
    values: pd.DataFrame
    ranks: pd.DataFrame
    reported: dict[tuple[str, str], dict[int, float]]

    def changes(self) -> int:
        """How many (model, protocol, horizon) ranks differ from the reference protocol's."""
        ref = self.protocols[0]
        return int(
            sum(
                (
                    self.ranks[(p, h)].notna()
                    & self.ranks[(ref, h)].notna()
                    & (self.ranks[(p, h)] != self.ranks[(ref, h)])
                ).sum()
                for p in self.protocols[1:]
                for h in self.horizons
            )
        )

    def markdown(self) -> str:
        fmt = metric_unit(self.metric)[1]
        unit = metric_unit(self.metric)[0]
        ref = self.protocols[0]
        out = [
            f"# {self.benchmark}: how much the protocol moves the ranking",
            "",
            f"{self.metric.upper()} ({unit}) of every model under every protocol the tables "
            f"measure, mean over actions, with its rank among the models of that protocol in "
            f"brackets. Reference protocol: `{ref}`; a rank that differs from its rank there is "
            f"marked ↑ (better) or ↓ (worse). {self.changes()} rank(s) of "
            f"{self.ranks.notna().to_numpy().sum() - self.ranks[ref].notna().to_numpy().sum()} "
            f"differ. Published figures (reported) stand in the column of the protocol they "
            f"were measured in and are not ranked. Protocols: "
            + "; ".join(f"`{p}`" for p in self.protocols)
            + ".",
            "",
        ]
        for h in self.horizons:
            rows = []
            for model in self.values.index:
                cells = []
                for p in self.protocols:
                    v, r = self.values.loc[model, (p, h)], self.ranks.loc[model, (p, h)]
                    if pd.isna(v):
                        cells.append("–")
                        continue
                    base = self.ranks.loc[model, (ref, h)]
                    mark = ""
                    if p != ref and not pd.isna(base) and r != base:
                        mark = " ↑" if r < base else " ↓"
                    cells.append(f"{v:{fmt}} ({int(r)}){mark}")
                rows.append([model, *cells])
            for (label, p), values in self.reported.items():
                if h in values:
                    rows.append(
                        [
                            label if "reported" in label else f"{label} (reported)",
                            *[f"{values[h]:{fmt}}" if q == p else "–" for q in self.protocols],
                        ]
                    )
            out += [
                f"## {h} ms",
                "",
                tabulate(
                    rows,
                    headers=["model", *self.protocols],
                    tablefmt="github",
                    disable_numparse=True,
                ),
                "",
            ]
        return "\n".join(out)

    def plot(self, path: str | Path, digest: str | None = None) -> None:
        """``sensitivity.png``: each model's rank under each protocol, keeping ``digest``
        (:meth:`plot_digest`, computed here where not given)."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(
            1, len(self.horizons), figsize=(4.2 * len(self.horizons), 4.2), squeeze=False
        )
        x = np.arange(len(self.protocols))
        for ax, h in zip(axes[0], self.horizons):
            for model in self.values.index:
                ax.plot(x, [self.ranks.loc[model, (p, h)] for p in self.protocols], marker="o")
                last = self.ranks.loc[model, (self.protocols[-1], h)]
                if not pd.isna(last):
                    ax.annotate(
                        model,
                        (x[-1], last),
                        fontsize=7,
                        xytext=(4, 0),
                        textcoords="offset points",
                        va="center",
                    )
            ax.set_xticks(x, self.protocols, rotation=60, ha="right", fontsize=7)
            ax.invert_yaxis()
            ax.set_title(f"{h} ms", fontsize=9)
            ax.set_ylabel("rank (1 = lowest error)")
            ax.grid(alpha=0.3)
        fig.suptitle(f"{self.benchmark}: rank of each model under each protocol", fontsize=10)
        save_figure(fig, path, drawn_from=digest or self.plot_digest())

    def plot_digest(self) -> str:
        """A digest of what :meth:`plot` draws (ranks, protocols, horizons, benchmark), with
        matplotlib's version and the code that draws: a plot that keeps it is not drawn again."""
        import hashlib
        import inspect
        import json

        import matplotlib

        from zoo.core import io

        drawing = (Sensitivity.plot, Sensitivity.plot_digest, io.save_figure)
        inputs = [
            self.benchmark,
            self.protocols,
            [int(h) for h in self.horizons],
            self.ranks.to_csv(float_format="%.17g"),
            matplotlib.__version__,
            [inspect.getsource(f) for f in drawing],
        ]
        return hashlib.sha256(json.dumps(inputs, sort_keys=True).encode()).hexdigest()

    def write(self, folder: str | Path) -> list[Path]:
        """``sensitivity.md`` and ``sensitivity.png`` in ``folder``, each rewritten only when
        what it shows changed: the plot shows ranks only, so new values with the same ranks
        leave it. The plot first: a failed drawing leaves the table as it was, to be tried
        again. The files written."""
        folder = Path(folder)
        text, md, png = self.markdown(), folder / "sensitivity.md", folder / "sensitivity.png"
        digest = self.plot_digest()
        written = []
        if figure_drawn_from(png) != digest:
            self.plot(png, digest)
            written.append(png)
        if not (md.is_file() and md.read_text() == text):
            atomic_write_text(md, text)
            written.insert(0, md)
        return written


def update_sensitivity(benchmark_dir: str | Path) -> str | None:
    """``sensitivity.md`` and ``.png`` of a benchmark's results folder brought up to date with
    its tables: written where :func:`protocol_sensitivity` has a table, removed where it has
    none any more (a drop left one model, say); what was done, None where nothing changed."""
    folder = Path(benchmark_dir)
    sensitivity = protocol_sensitivity(folder)
    if sensitivity is not None:
        written = sensitivity.write(folder)
        return f"wrote {', '.join(str(p) for p in written)}" if written else None
    stale = [p for p in (folder / "sensitivity.md", folder / "sensitivity.png") if p.is_file()]
    for path in stale:
        path.unlink()
    if stale:
        return (
            f"removed {', '.join(str(p) for p in stale)}: its tables no longer rank two models "
            f"under two protocols"
        )
    return None


def protocol_sensitivity(benchmark_dir: str | Path, horizons_ms=HORIZONS_MS) -> Sensitivity | None:
    """The protocol-sensitivity table of one benchmark's results folder (``results/<name>``),
    prediction tables only; None when its tables measure a single protocol or rank a single
    model (whose rank is 1 under every protocol: nothing can move)."""
    from zoo.evaluation.results import read_table, table_files
    from zoo.protocol.published import place

    benchmark_dir = Path(benchmark_dir)
    frames, records = [], {}
    for table in table_files(benchmark_dir):
        result = read_table(table.parent)
        if result.protocol.get("task", "prediction") != "prediction":
            continue
        records[table.parent.name] = result.protocol
        frames.append(result.frame.assign(table=table.parent.name))
    if not frames:
        return None
    frame = pd.concat(frames, ignore_index=True)
    first = next(iter(records.values()))
    metric, headline_joints = headline_key(first)
    rows = frame[
        (frame["metric"] == metric)
        & (frame["action"] == "average")
        & ~frame["model"].map(is_floor)
        & (frame["model"] != "ground_truth")
    ]
    joints = [headline_joints, *sorted(set(rows["joints"]) - {headline_joints})]
    # the benchmark's own sampler first: the reference protocol
    try:
        from zoo.protocol.benchmark import get_benchmark

        default = get_benchmark(first["benchmark"]).sampler
    except Exception:  # a benchmark file not at hand: the first table's own
        default = first.get("sampler")
    tables = sorted(records, key=lambda t: (records[t].get("sampler") != default, t))
    protocols = [
        f"{t} {a} {j}" if len(joints) > 1 else f"{t} {a}"
        for t in tables
        for a in ("frame", "cumulative")
        for j in joints
    ]
    if len(protocols) < 2:
        return None
    horizons = [h for h in horizons_ms if h in set(rows["horizon_ms"])]
    columns = pd.MultiIndex.from_tuples([(p, h) for p in protocols for h in horizons])
    models = sorted(set(rows["model"]))
    if len(models) < 2:
        return None
    values = pd.DataFrame(np.nan, index=models, columns=columns)
    reported: dict[tuple[str, str], dict[int, float]] = {}
    for t in tables:
        for a in ("frame", "cumulative"):
            for j in joints:
                p = f"{t} {a} {j}" if len(joints) > 1 else f"{t} {a}"
                sel = rows[(rows["table"] == t) & (rows["averaging"] == a) & (rows["joints"] == j)]
                for r in sel.itertuples():
                    if r.horizon_ms in horizons:
                        values.loc[r.model, (p, r.horizon_ms)] = r.value
                for placed in place(records[t], metric, a, j):
                    if not placed.differences and placed.values:
                        reported[placed.entry.label, p] = dict(placed.values)
    ranks = values.rank(axis=0, method="min")
    return Sensitivity(
        benchmark=str(first.get("benchmark", benchmark_dir.name)),
        metric=metric,
        protocols=protocols,
        horizons=horizons,
        values=values,
        ranks=ranks,
        reported=reported,
    )
