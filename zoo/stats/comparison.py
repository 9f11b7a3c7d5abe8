"""Is model A better than model B, and by how much? Paired comparisons with the intervals of
:mod:`zoo.stats.intervals` on the per-window errors the evaluator keeps, and a sign test over
actions.

(Called, ``zoo.compare(a, b, benchmark=None, **options)`` runs :func:`zoo.api.compare`: results,
result folders or stored labels in, a :class:`Comparison` out.)

Both results must come from one protocol record (the same windows): the difference A - B is
taken window by window, so the variance the two models share (hard windows are hard for both)
cancels, and the interval is that of the difference itself.

    from zoo.stats.comparison import compare
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

from zoo.core.errors import ZooError
from zoo.evaluation.markdown import default_horizons, headline_key, metric_unit
from zoo.evaluation.results import EvalResult
from zoo.protocol.comparable import ProtocolMismatchError, protocol_differences
from zoo.protocol.metrics import AVERAGING, cumulative_mean
from zoo.stats.intervals import (
    CONFIDENCE,
    REPLICATES,
    block_frames_default,
    design,
    interval,
    protocol_mean,
    sign_test,
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
    ``hi`` (the interval of A - B), per-unit counts ``a_lower``, ``ties``, ``units``, the sign
    test's ``sign_p``, and ``verdict``: ``a`` or ``b`` (better), ``these recordings`` (lower here,
    without evidence beyond), ``none``."""

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
    kind: str = "window-sampling"  # or "confidence": see zoo.stats.intervals.Interval
    units: str = "actions"  # what the sign test counts: actions, or recordings
    design: str = ""  # recordings per action, in words

    def sentences(self) -> list[str]:
        """One sentence per horizon. "A is better than B" only where the evidence reaches past
        these recordings: a confidence interval over recordings that excludes zero, or (one
        recording per action) a window-sampling interval that excludes zero together with a
        sign test over the actions at p <= 1 - confidence; otherwise what is true of these
        recordings."""
        unit = metric_unit(self.metric)[0]
        unit = f" {unit}" if unit == "mm" else ""  # rmse's unit is a definition, not a unit
        fmt = metric_unit(self.metric)[1]
        pct = f"{100 * self.confidence:g}%"
        what = "confidence interval" if self.kind == "confidence" else "window-sampling interval"
        out = []
        for row in self.table.itertuples():
            count = (
                f"{self.a} lower on {row.a_lower} of {row.units} {self.units}, "
                f"sign test p = {row.sign_p:.2g}"
            )
            if row.verdict == "none":
                out.append(
                    f"no difference detectable at {row.horizon_ms} ms ({self.a} - "
                    f"{self.b} = {row.difference:{fmt}}{unit}, {pct} {what} "
                    f"{row.lo:{fmt}} to {row.hi:{fmt}}; {count})"
                )
                continue
            a_lower = row.difference < 0
            better, worse, lo, hi = (
                (self.a, self.b, -row.hi, -row.lo) if a_lower else (self.b, self.a, row.lo, row.hi)
            )
            wins = row.a_lower if a_lower else row.units - row.a_lower - row.ties
            by = (
                f"by {abs(row.difference):{fmt}}{unit} ({pct} {what} {lo:{fmt}} to "
                f"{hi:{fmt}}; lower on {wins} of {row.units} {self.units}, sign test p = "
                f"{row.sign_p:.2g})"
            )
            if row.verdict in ("a", "b"):
                out.append(f"{better} is better than {worse} at {row.horizon_ms} ms {by}")
            else:
                out.append(
                    f"{better} is lower than {worse} at {row.horizon_ms} ms on these recordings "
                    f"{by}: too few {self.units} agree to say it is better on others"
                )
        return out

    def heading(self) -> str:
        p = self.protocol
        return (
            f"{self.a} against {self.b} on {p['benchmark']} ({p['dataset']} {p['split']}, "
            f"sampler {p['sampler']}, protocol {p['protocol_id']}): {self.metric} "
            f"({metric_unit(self.metric)[0]}), averaging `{self.averaging}`, joints "
            f"`{self.joints}`, action average ({self.design}); paired differences, "
            + (
                f"{100 * self.confidence:g}% confidence intervals over recordings (t)"
                if self.kind == "confidence"
                else f"{100 * self.confidence:g}% window-sampling intervals, conditional on "
                f"these recordings (studentised circular block bootstrap within each "
                f"recording, blocks of {self.block_frames} frames, {self.replicates} "
                f"replicates, seed {self.seed}), not confidence intervals for the actions"
            )
            + f"; per horizon, on how many {self.units} {self.a} is lower, with the exact "
            f"two-sided sign test"
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
                f"{r.a_lower} of {r.units}",
                f"{r.sign_p:.2g}",
                {"a": self.a, "b": self.b}.get(r.verdict, "-"),
            ]
            for r in self.table.itertuples()
        ]
        table = tabulate(
            rows,
            headers=[
                "horizon (ms)",
                self.a,
                self.b,
                f"{self.a} - {self.b}",
                "interval",
                f"{self.a} lower ({self.units})",
                "sign test p",
                "better",
            ],
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

        from zoo.core.io import save_figure

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
        from zoo.core.io import atomic_write_text

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
    shape = design(wa.sequence, wa.action)
    span = interval(ea - eb, wa, confidence, replicates, seed, block_frames)
    lo, hi = span.lo, span.hi
    # The sign test's units: recordings where they are independent replicates, else actions.
    unit_of = wa.sequence if shape.recording_level else wa.action
    units = np.unique(unit_of)
    unit_difference = np.stack([(ea - eb)[unit_of == u].mean(axis=0) for u in units])
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
        a_lower = int((unit_difference[:, t] < 0).sum())
        a_higher = int((unit_difference[:, t] > 0).sum())
        p = sign_test(a_lower, a_higher)
        excludes = hi[t] < 0 or lo[t] > 0
        supported = shape.recording_level or p <= 1 - confidence
        verdict = (
            "none"
            if not excludes
            else ("a" if hi[t] < 0 else "b")
            if supported
            else "these recordings"
        )
        rows.append(
            {
                "horizon_ms": int(h),
                "a": mean_a[t],
                "b": mean_b[t],
                "difference": mean_a[t] - mean_b[t],
                "lo": lo[t],
                "hi": hi[t],
                "a_lower": a_lower,
                "ties": len(units) - a_lower - a_higher,
                "units": len(units),
                "sign_p": p,
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
        kind=span.kind,
        units="recordings" if shape.recording_level else "actions",
        design=shape.counts(),
    )


def reader_pairs(results: list[EvalResult]) -> list[tuple[str, str]]:
    """The pairs of a table a reader asks about first: each trained predictor (its best
    validation row, not ``@last``) against ``repeat_last`` and against the best other
    predictor (lowest headline error summed over the table's horizons)."""
    from zoo.stats.ranking import is_floor

    by_label = {_label(r): r for r in results if r.windows is not None}
    if not by_label:  # no per-window errors stored: nothing to pair
        return []
    record = results[0].protocol
    metric, joints = headline_key(record)
    rows = pd.concat([r.frame for r in by_label.values()], ignore_index=True)
    rows = rows[
        (rows["metric"] == metric)
        & (rows["joints"] == joints)
        & (rows["averaging"] == "frame")
        & (rows["action"] == "average")
        & rows["horizon_ms"].isin(default_horizons(rows))
    ]
    total = rows.groupby("model")["value"].sum()
    trained = [
        m
        for m in by_label
        if m != "repeat_last" and "@" not in m and not is_floor(m) and m in total
    ]
    pairs = []
    for m in trained:
        if "repeat_last" in by_label:
            pairs.append((m, "repeat_last"))
        others = total[[o for o in trained if o != m]]
        best = str(others.idxmin()) if len(others) else None
        if best is not None and (best, m) not in pairs:  # one of a pair and its mirror
            pairs.append((m, best))
    return pairs


def table_comparisons(results: list[EvalResult]) -> list[dict[str, Any]]:
    """:func:`compare` of every pair of a table's predictions, as data (``summary.json``): the
    :func:`reader_pairs` first (``reader``: true), then every other pair once, in label order,
    so a reader can put any row against any other. Floors and the ground truth are no
    prediction and pair with nothing."""
    from zoo.stats.ranking import TRUTH_ROW, is_floor

    by_label = {_label(r): r for r in results}
    first = reader_pairs(results)
    rows = sorted(
        m
        for m, r in by_label.items()
        if r.windows is not None and not is_floor(m) and m != TRUTH_ROW
    )
    seen = {frozenset(p) for p in first}
    others = [(a, b) for i, a in enumerate(rows) for b in rows[i + 1 :]]
    out = []
    for a, b in first + [p for p in others if frozenset(p) not in seen]:
        c = compare(by_label[a], by_label[b])
        out.append(
            {
                "a": a,
                "b": b,
                "reader": (a, b) in first,
                "metric": c.metric,
                "joints": c.joints,
                "averaging": c.averaging,
                "kind": c.kind,
                "units": c.units,
                "design": c.design,
                "confidence": c.confidence,
                "rows": [
                    {k: _json_value(v) for k, v in row.items()}
                    for row in c.table.to_dict("records")
                ],
            }
        )
    return out


def _json_value(v):
    """A table cell as JSON (:func:`zoo.core.io.json_number` for a number)."""
    from zoo.core.io import json_number

    v = v.item() if hasattr(v, "item") else v
    return json_number(v) if isinstance(v, float) else v
