"""Is model A better than model B, and by how much? Paired comparisons with block-bootstrap
intervals (:mod:`zoo.intervals`) on the per-window errors the evaluator keeps.

(Called, ``zoo.compare(a, b, benchmark=None, **options)`` runs :func:`zoo.api.compare`: results,
result folders or stored labels in, a :class:`Comparison` out.)

Both results must come from one protocol record (the same windows): the difference A - B is
taken window by window, so the variance the two models share (hard windows are hard for both)
cancels, and the interval is that of the difference itself.

    from zoo.compare import compare
    c = compare("results/cmu/all/spgsn", "results/cmu/all/mlp")
    print("\\n".join(c.sentences()))
    c.write("some/folder")      # comparison.md and comparison.png
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from tabulate import tabulate

from zoo.errors import ZooError
from zoo.evaluate import EvalResult
from zoo.intervals import (
    CONFIDENCE,
    REPLICATES,
    block_bootstrap,
    percentile_interval,
    protocol_mean,
)
from zoo.metrics import AVERAGING, cumulative_mean
from zoo.tables import (
    ProtocolMismatchError,
    block_frames_default,
    default_horizons,
    headline_key,
    metric_unit,
    protocol_differences,
)


class ComparisonError(ZooError, ValueError):
    pass


def window_errors(
    result: EvalResult, model: str, metric: str, joints: str, averaging: str = "frame"
) -> np.ndarray:
    """Per-window errors ``(W, T)`` of one model under ``averaging`` (cumulative: the running
    mean over predicted frames, window by window, which averages to the table's figure)."""
    if result.windows is None:
        raise ComparisonError(
            f"result of {model!r} holds no per-window errors (windows.npz); "
            f"re-evaluate it (zoo eval / zoo leaderboard) to get them"
        )
    if averaging not in AVERAGING:
        raise ComparisonError(f"averaging must be one of {', '.join(AVERAGING)}, got {averaging!r}")
    errors = result.windows.get(model, metric, joints).astype(np.float64)
    return cumulative_mean(errors, axis=1) if averaging == "cumulative" else errors


def _label(result: EvalResult) -> str:
    return str(result.frame["model"].iloc[0])


def _load(source) -> EvalResult:
    if isinstance(source, EvalResult):
        return source
    path = Path(source)
    if not (path / "results.csv").is_file():
        raise ComparisonError(
            f"{path}: no evaluation here (results.csv missing); run zoo eval "
            f"or zoo leaderboard first"
        )
    return EvalResult.read(path)


@dataclass
class Comparison:
    """A - B per horizon: ``table`` has ``horizon_ms``, ``a``, ``b``, ``difference``, ``lo``,
    ``hi`` (the interval of A - B) and ``verdict`` (``a``, ``b`` or ``none``)."""

    a: str
    b: str
    metric: str
    joints: str
    averaging: str
    block_frames: int
    confidence: float
    replicates: int
    seed: int
    protocol: dict[str, Any]
    table: pd.DataFrame = field(repr=False)

    def sentences(self) -> list[str]:
        unit = metric_unit(self.metric)[0]
        unit = f" {unit}" if unit == "mm" else ""  # rmse's unit is a definition, not a unit
        fmt = metric_unit(self.metric)[1]
        pct = f"{100 * self.confidence:g}%"
        out = []
        for row in self.table.itertuples():
            if row.verdict == "none":
                out.append(
                    f"no difference detectable at {row.horizon_ms} ms ({self.a} - "
                    f"{self.b} = {row.difference:{fmt}}{unit}, {pct} interval "
                    f"{row.lo:{fmt}} to {row.hi:{fmt}})"
                )
                continue
            better, worse, lo, hi = (
                (self.a, self.b, -row.hi, -row.lo)
                if row.verdict == "a"
                else (self.b, self.a, row.lo, row.hi)
            )
            out.append(
                f"{better} is better than {worse} at {row.horizon_ms} ms by "
                f"{abs(row.difference):{fmt}}{unit}, {pct} interval {lo:{fmt}} to "
                f"{hi:{fmt}}"
            )
        return out

    def heading(self) -> str:
        p = self.protocol
        return (
            f"{self.a} against {self.b} on {p['benchmark']} ({p['dataset']} {p['split']}, "
            f"sampler {p['sampler']}, protocol {p['protocol_id']}): {self.metric} "
            f"({metric_unit(self.metric)[0]}), averaging `{self.averaging}`, joints "
            f"`{self.joints}`, action average; paired differences, "
            f"{100 * self.confidence:g}% block-bootstrap intervals (circular blocks of "
            f"{self.block_frames} frames within each recording, {self.replicates} "
            f"replicates, seed {self.seed})"
        )

    def markdown(self) -> str:
        fmt = metric_unit(self.metric)[1]
        rows = [
            [
                r.horizon_ms,
                r.a,
                r.b,
                r.difference,
                f"{r.lo:{fmt}} to {r.hi:{fmt}}",
                {"a": self.a, "b": self.b, "none": "-"}[r.verdict],
            ]
            for r in self.table.itertuples()
        ]
        table = tabulate(
            rows,
            headers=["horizon (ms)", self.a, self.b, f"{self.a} - {self.b}", "interval", "better"],
            tablefmt="github",
            floatfmt=fmt,
        )
        return "\n".join(
            [
                f"# {self.a} against {self.b}",
                "",
                self.heading() + ".",
                "",
                table,
                "",
                *[f"- {s}." for s in self.sentences()],
                "",
            ]
        )

    def plot(self, path: str | Path) -> None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from zoo.io import save_figure

        t = self.table
        fig, ax = plt.subplots(figsize=(6.5, 3.8))
        ax.fill_between(
            t["horizon_ms"],
            t["lo"],
            t["hi"],
            alpha=0.25,
            label=f"{100 * self.confidence:g}% interval",
        )
        ax.plot(t["horizon_ms"], t["difference"], marker=".", label=f"{self.a} - {self.b}")
        ax.axhline(0.0, color="black", linewidth=0.8)
        ax.set_xlabel("horizon (ms)")
        ax.set_ylabel(f"difference in {self.metric} ({metric_unit(self.metric)[0]})")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        ax.set_title(
            f"{self.a} - {self.b}: {self.protocol['benchmark']}, sampler "
            f"{self.protocol['sampler']} (below zero: {self.a} better)",
            fontsize=9,
        )
        save_figure(fig, path)

    def write(self, out_dir: str | Path) -> Path:
        """``comparison.md`` and ``comparison.png`` in ``out_dir``."""
        from zoo.io import atomic_write_text

        out_dir = Path(out_dir)
        atomic_write_text(out_dir / "comparison.md", self.markdown())
        self.plot(out_dir / "comparison.png")
        return out_dir


def compare(
    a,
    b,
    *,
    metric: str | None = None,
    joints: str | None = None,
    averaging: str = "frame",
    horizons_ms: Iterable[int] | None = None,
    block_frames: int | None = None,
    confidence: float = CONFIDENCE,
    replicates: int = REPLICATES,
    seed: int = 0,
) -> Comparison:
    """Compare two evaluation results (:class:`EvalResult` or their folders) of one protocol."""
    if not 0 < confidence < 1:
        raise ComparisonError(f"confidence must lie strictly between 0 and 1, got {confidence!r}")
    ra, rb = _load(a), _load(b)
    la, lb = _label(ra), _label(rb)
    diff = protocol_differences(ra.protocol, rb.protocol)
    if diff:
        raise ProtocolMismatchError(
            f"refusing to compare {la} and {lb}: their protocol records "
            f"differ in " + "; ".join(diff)
        )
    if la == lb:
        raise ComparisonError(f"both results are of model {la!r}; compare two models")
    default_metric, default_joints = headline_key(ra.protocol)
    metric, joints = metric or default_metric, joints or default_joints
    ea = window_errors(ra, la, metric, joints, averaging)
    eb = window_errors(rb, lb, metric, joints, averaging)
    wa, wb = ra.windows, rb.windows
    if not (np.array_equal(wa.sequence, wb.sequence) and np.array_equal(wa.start, wb.start)):
        raise ComparisonError(
            f"{la} and {lb} were scored on different windows although their "
            f"protocol records agree; re-evaluate both"
        )
    block_frames = block_frames or block_frames_default(wa)
    replicates_ = block_bootstrap(
        ea - eb, wa.sequence, wa.start, wa.action, block_frames, replicates, seed
    )
    lo, hi = percentile_interval(replicates_, confidence)
    mean_a, mean_b = protocol_mean(ea, wa.action), protocol_mean(eb, wb.action)
    frame_ms = 1000.0 / ra.protocol["fps"]
    horizon = np.rint(np.arange(1, ea.shape[1] + 1) * frame_ms).astype(int)
    wanted = list(horizons_ms) if horizons_ms is not None else default_horizons(ra.frame)
    missing = [h for h in wanted if h not in horizon]
    if missing:
        raise ComparisonError(
            f"horizons {missing} ms are not predicted frames of this protocol "
            f"(frames every {frame_ms:g} ms up to {horizon[-1]} ms)"
        )
    rows = []
    for h in wanted:
        t = int(np.flatnonzero(horizon == h)[0])
        verdict = "a" if hi[t] < 0 else "b" if lo[t] > 0 else "none"
        rows.append(
            {
                "horizon_ms": int(h),
                "a": mean_a[t],
                "b": mean_b[t],
                "difference": mean_a[t] - mean_b[t],
                "lo": lo[t],
                "hi": hi[t],
                "verdict": verdict,
            }
        )
    return Comparison(
        a=la,
        b=lb,
        metric=metric,
        joints=joints,
        averaging=averaging,
        block_frames=block_frames,
        confidence=confidence,
        replicates=replicates,
        seed=seed,
        protocol=ra.protocol,
        table=pd.DataFrame(rows),
    )
