"""How far a recomputed result may sit from a stored one and still be the same result.

``zoo leaderboard --check`` names a value beyond this tolerance; ``zoo leaderboard``, ``zoo
eval`` and ``zoo.evaluate`` leave a stored result byte for byte when a recomputation agrees with
it within this tolerance (:func:`agreement`), so a rebuild on another CPU rewrites nothing that
only rounded differently.

The tolerance, from the arithmetic: every error is computed in float32, whose rounding follows
the CPU's kernels (summation order, fused multiply-adds, vector width), and generated meshes' own
bytes differ between CPUs in their last bits, so another machine reproduces a value to some
units in the last place, not bit for bit. ``RELATIVE_TOLERANCE`` is 2**-16, 128 float32 units
in the last place of the value (float32 carries 24 bits). The absolute floor is set by the
inputs, not by the error: an error is a small difference of coordinates around a metre (MELV:
of edge lengths), so its rounding is some units in the last place of a coordinate at one metre
(6.1e-5 mm each): ``ABSOLUTE_TOLERANCE['mm']`` = 2**-9 mm is 32 of them, and 2**-18 is the same
for RMSE, normalised by a bounding-box diagonal near 2 m. A standard deviation over windows
moves as much as the windows' errors do, so it is held to the tolerance of its mean. A real
change is far above all of these: a value moved by 0.01 mm is named (below 500 mm).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from zoo.tables import metric_unit

KEY_COLUMNS = ["model", "action", "metric", "averaging", "joints", "horizon_ms"]
RELATIVE_TOLERANCE = 2.0**-16
ABSOLUTE_TOLERANCE = {"mm": 2.0**-9, "rmse": 2.0**-18}


def tolerance_text() -> str:
    return (
        f"|difference| <= {RELATIVE_TOLERANCE:.2g} x |value| + {ABSOLUTE_TOLERANCE['mm']:.2g} "
        f"mm ({ABSOLUTE_TOLERANCE['rmse']:.2g} in RMSE; a std: of its mean; float32 rounding "
        f"across CPUs)"
    )


def allowed(metric, scale: np.ndarray) -> np.ndarray:
    """The largest difference tolerated for values of ``metric`` (a name or an array of names)
    of magnitude ``scale`` (the value itself, or a std's mean)."""

    def floor(m: str) -> float:
        return (
            ABSOLUTE_TOLERANCE["mm"]
            if metric_unit(m)[0] == "mm"
            else ABSOLUTE_TOLERANCE.get(m, 0.0)
        )

    return RELATIVE_TOLERANCE * np.abs(scale) + np.vectorize(floor, otypes=[float])(
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
    """Compare ``result`` (a :class:`zoo.results.EvalResult`) with the result stored in
    ``folder``, value by value and window by window."""
    from zoo.errors import EvaluationError
    from zoo.results import EvalResult

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
        w, s = result.windows, stored.windows
        if not (np.array_equal(w.start, s.start) and np.array_equal(w.sequence, s.sequence)):
            return Agreement(False, float("inf"), "other windows")
        if set(w.errors) != set(s.errors):
            return Agreement(False, float("inf"), "other per-window error series")
        for key, values in w.errors.items():
            before = s.errors[key].astype(np.float64)
            if values.shape != before.shape:
                return Agreement(False, float("inf"), f"{'/'.join(key)}: another shape")
            gap = np.abs(values.astype(np.float64) - before)
            if gap.size:
                share = max(share, float((gap / allowed(key[1], before)).max()))
    if share > 1:
        return Agreement(False, share, f"values differ by up to {share:.2f} of the tolerance")
    return Agreement(True, share)
