"""How far a recomputed result may sit from a stored one and still be the same result.

``zoo leaderboard --check`` names a value beyond this tolerance, and a recomputation that agrees
with a stored result within it leaves the stored files byte for byte (:func:`agreement`). The
tolerance's error model (float32 rounding across CPUs) and its constants:
docs/reproducibility.md ("The tolerance and its error model").
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from zoo.evaluation.markdown import metric_unit
from zoo.protocol.metrics import METRICS

KEY_COLUMNS = ["model", "action", "metric", "averaging", "joints", "horizon_ms"]
RELATIVE_TOLERANCE = 2.0**-16


def _floor(metric: str) -> float:
    """The absolute floor of ``metric``'s tolerance (its declaration's; an unknown one: 0)."""
    declared = METRICS.get(metric)
    return declared.tolerance if declared else 0.0


def tolerance_text() -> str:
    return (
        f"|difference| <= {RELATIVE_TOLERANCE:.2g} x |value| + {_floor('mpjpe'):.2g} "
        f"mm ({_floor('rmse'):.2g} in RMSE; a std: of its mean; float32 rounding "
        f"across CPUs)"
    )


def tolerance_by_metric(metrics) -> str:
    """The tolerance of each of ``metrics``, in its own unit (metrics of one unit together)."""
    by_floor: dict[str, list[str]] = {}
    for m in sorted(set(metrics)):
        unit = metric_unit(m)[0]
        floor = (
            f"{_floor(m):.2g} mm"
            if unit == "mm"
            else f"{_floor(m):.2g}" + (f" ({unit})" if unit else "")
        )
        by_floor.setdefault(floor, []).append(m)
    return (
        "; ".join(
            f"{', '.join(names)}: |difference| <= {RELATIVE_TOLERANCE:.2g} x |value| + {floor}"
            for floor, names in by_floor.items()
        )
        + " (a std: the tolerance of its mean)"
    )


def allowed(metric, scale: np.ndarray) -> np.ndarray:
    """The largest difference tolerated for values of ``metric`` (a name or an array of names)
    of magnitude ``scale`` (the value itself, or a std's mean)."""
    return RELATIVE_TOLERANCE * np.abs(scale) + np.vectorize(_floor, otypes=[float])(
        np.asarray(metric)
    )


@dataclass
class Agreement:
    """Whether a recomputed result agrees with a stored one: ``same`` (every value of
    ``results.csv`` and every per-window error within the tolerance, on the same rows and
    windows), the largest difference as a share of its tolerance, and ``why`` not."""

    same: bool
    share: float
    why: str = ""


def agreement(result, folder: str | Path) -> Agreement:
    """Compare ``result`` (a :class:`zoo.evaluation.results.EvalResult`) with the result stored in
    ``folder``, value by value and window by window."""
    from zoo.core.errors import EvaluationError
    from zoo.evaluation.results import EvalResult

    try:
        stored = EvalResult.read(folder)
        return _compare(result, stored)
    except (EvaluationError, KeyError, ValueError, OSError) as e:
        # an unreadable, older or malformed stored result is rewritten, never kept
        return Agreement(False, float("inf"), f"stored result unreadable ({type(e).__name__}: {e})")


def _compare(result, stored) -> Agreement:
    if stored.protocol.get("protocol_id") != result.protocol.get("protocol_id"):
        return Agreement(False, float("inf"), "another protocol")
    new = result.frame.sort_values(KEY_COLUMNS).reset_index(drop=True)
    old = stored.frame.sort_values(KEY_COLUMNS).reset_index(drop=True)
    if len(new) != len(old) or not (new[KEY_COLUMNS] == old[KEY_COLUMNS]).all().all():
        return Agreement(False, float("inf"), "other rows (metrics, actions or horizons)")
    share = 0.0
    scale = old["value"].to_numpy(float)
    limit = allowed(old["metric"].to_numpy(), scale)
    for column in ("value", "std"):
        if column not in new or column not in old:
            return Agreement(False, float("inf"), f"no column {column!r}")
        a, b = new[column].to_numpy(float), old[column].to_numpy(float)
        nan = np.isnan(a) | np.isnan(b)
        if (np.isnan(a) != np.isnan(b)).any():
            return Agreement(False, float("inf"), f"{column}: a NaN on one side only")
        if (~nan).any():
            share = max(share, float((np.abs(a - b)[~nan] / limit[~nan]).max()))
    if (result.windows is None) != (stored.windows is None):
        return Agreement(False, float("inf"), "per-window errors on one side only")
    if result.windows is not None:
        try:
            gaps = window_gaps(result.windows, stored.windows)
        except Incomparable as e:
            return Agreement(False, float("inf"), str(e))
        share = max([share, *(g.share for g in gaps)])
    if share > 1:
        return Agreement(False, share, f"values differ by up to {share:.2f} of the tolerance")
    return Agreement(True, share)


def sample_agreement(fresh, stored, rows: np.ndarray) -> Agreement:
    """Whether per-window errors ``fresh`` (a :class:`zoo.evaluation.results.WindowErrors` of the
    windows at positions ``rows`` of ``stored``'s) agree with the stored ones there, series by
    series."""
    try:
        gaps = window_gaps(fresh, stored, rows)
    except Incomparable as e:
        return Agreement(False, float("inf"), str(e))
    share = max((g.share for g in gaps), default=0.0)
    if share > 1:
        worst = max(gaps, key=lambda g: g.share)
        return Agreement(
            False, share, f"{'/'.join(worst.key)} differs by up to {share:.2f} of the tolerance"
        )
    return Agreement(True, share)


class Incomparable(ValueError):
    """Per-window errors that cannot be compared: other windows, a series missing."""


@dataclass
class WindowGap:
    """The largest difference of one series of per-window errors from the stored one: as a share of
    what it is held to, relative, absolute, and at which window (its stored position);
    ``held_to_rounding``: how many of its values exceed the a-priori tolerance but not the margin
    their measured rounding sensitivity gives them (:mod:`zoo.leaderboard.rounding`), and the
    largest of those as a share of the a-priori tolerance (``a_priori``)."""

    key: tuple[str, str, str]
    share: float
    relative: float
    absolute: float
    window: int
    held_to_rounding: int = 0
    a_priori: float = 0.0
    # the stored positions of the windows beyond what they are held to, and beyond the a-priori
    # tolerance alone (what a sampled check would name, with and without rounding margins)
    beyond: tuple = ()
    beyond_a_priori: tuple = ()


def _window_shares(fresh, stored, rows: np.ndarray | None):
    """Each series: its key, the stored positions, the absolute differences and their shares
    of the a-priori tolerance (a NaN on one side only: infinite); :class:`Incomparable` where
    the windows are not the same ones or a series is missing from ``stored``."""
    rows = np.arange(len(stored.start)) if rows is None else np.asarray(rows)
    if len(rows) != len(fresh.start) or (len(rows) and rows.max() >= len(stored.start)):
        raise Incomparable(f"other windows ({len(stored.start)} stored)")
    if not (
        np.array_equal(stored.start[rows], fresh.start)
        and np.array_equal(stored.sequence[rows], fresh.sequence)
    ):
        raise Incomparable("other windows")
    if set(fresh.errors) != set(stored.errors):
        missing = sorted("/".join(k) for k in set(fresh.errors) ^ set(stored.errors))
        raise Incomparable(f"other per-window error series ({', '.join(missing)} on one side)")
    for key, values in fresh.errors.items():
        before = stored.errors[key][rows].astype(np.float64)
        if values.shape != before.shape:
            raise Incomparable(f"{'/'.join(key)}: another shape")
        after = values.astype(np.float64)
        gap = np.abs(after - before)
        limit = allowed(key[1], before)
        with np.errstate(invalid="ignore", divide="ignore"):
            share = np.nan_to_num(gap / limit, nan=0.0, posinf=np.inf)
        # a NaN on one side only is a difference; on both sides, the same value
        one, both = np.isnan(after) != np.isnan(before), np.isnan(after) & np.isnan(before)
        share = np.where(one, np.inf, np.where(both, 0.0, share))
        yield key, rows, before, np.where(both, 0.0, gap), limit, share


def windows_beyond(fresh, stored, rows: np.ndarray | None = None) -> np.ndarray:
    """The positions in ``fresh`` of the windows with any error beyond the a-priori tolerance
    (finite: a NaN on one side is a difference no rounding explains)."""
    beyond = np.zeros(len(fresh.start), bool)
    for *_, share in _window_shares(fresh, stored, rows):
        if share.size:
            finite = np.isfinite(share) & (share > 1)
            beyond |= finite.reshape(len(beyond), -1).any(axis=1)
    return np.flatnonzero(beyond)


def window_gaps(
    fresh, stored, rows: np.ndarray | None = None, margins: dict | None = None
) -> list[WindowGap]:
    """Each series of ``fresh`` per-window errors against ``stored``'s at its windows' positions
    ``rows`` (None: every window, in order); :class:`Incomparable` where the windows are not the
    same ones or a series is missing from ``stored``. ``margins`` (per series, an array shaped like
    its errors): what a value may differ by beyond the a-priori tolerance, where its rounding
    sensitivity was measured (:mod:`zoo.leaderboard.rounding`); each value is held to the larger of
    the two."""
    gaps = []
    for key, at, before, gap, limit, a_priori in _window_shares(fresh, stored, rows):
        if not before.size:
            continue
        margin = (margins or {}).get(key)
        share = a_priori
        if margin is not None:
            with np.errstate(invalid="ignore", divide="ignore"):
                widened = np.nan_to_num(gap / np.maximum(limit, margin), nan=0.0, posinf=np.inf)
            share = np.where(np.isfinite(a_priori), widened, a_priori)
        held = (a_priori > 1) & (share <= 1)
        i = int(np.argmax(share))

        gaps.append(
            WindowGap(
                key,
                float(share.flat[i]),
                float(gap.flat[i] / max(abs(before.flat[i]), 1e-12)),
                float(gap.flat[i]),
                int(at[i // before.shape[1]]) if before.ndim == 2 else int(at[i]),
                held_to_rounding=int(held.sum()),
                a_priori=float(a_priori[held].max()) if held.any() else 0.0,
                beyond=_positions(at, share > 1),
                beyond_a_priori=_positions(at, a_priori > 1),
            )
        )
    return gaps


def _positions(at: np.ndarray, flags: np.ndarray) -> tuple[int, ...]:
    """The stored positions ``at`` of the windows with any flagged value."""
    return tuple(int(p) for p in at[flags.reshape(len(at), -1).any(axis=1)])
