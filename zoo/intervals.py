"""How sure a number is: block-bootstrap intervals over overlapping windows.

Windows of one recording overlap (CMU's ``all`` sampler: neighbouring windows share 34 of their 35
frames), so their errors are strongly correlated and a standard error over windows is far too
small. The circular block bootstrap keeps that dependence: it resamples runs of consecutive
windows of one recording (a block: the windows starting within ``block_frames`` of the block's
first; :func:`zoo.tables.block_frames_default` takes two window lengths), never pieces of two
recordings, a run past a recording's end continuing at its start. Each action's windows are rebuilt
from blocks drawn among all its recordings' blocks (with one recording per action, as on CMU,
that is the plain moving-block bootstrap of it; with one window per recording, as on cloth, it is
the ordinary bootstrap of independent recordings), to as many windows as the action has. Then
the protocol averages as always: mean over an action's windows, unweighted mean over the
actions, which are never resampled away (the protocol fixes them).

A paired comparison of two models scored on the same windows bootstraps the per-window
differences with the same blocks, which removes the variance the two models share.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

REPLICATES = 2000
CONFIDENCE = 0.95


def protocol_mean(errors: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """The protocol's average ``(T,)`` of per-window errors ``(W, T)``: the mean over each
    action's windows, then the unweighted mean over actions."""
    actions = np.asarray(actions)
    return np.mean([errors[actions == a].mean(axis=0) for a in np.unique(actions)], axis=0)


def block_windows(starts: np.ndarray, block_frames: int) -> int:
    """How many consecutive windows of a recording one block holds: those starting within
    ``block_frames`` frames of the first, at the recording's typical (median) stride."""
    if len(starts) < 2:
        return 1
    stride = float(np.median(np.diff(np.sort(starts))))
    return max(1, math.ceil(block_frames / max(stride, 1.0)))


def short_recordings(sequence: np.ndarray, start: np.ndarray, block_frames: int) -> list[int]:
    """Recordings with several windows but fewer than two blocks of them: the bootstrap sees
    too little of their variance (their intervals come out too narrow)."""
    sequence, start = np.asarray(sequence), np.asarray(start)
    out = []
    for rec in np.unique(sequence):
        own = start[sequence == rec]
        if 1 < len(own) < 2 * block_windows(own, block_frames):
            out.append(int(rec))
    return out


@dataclass
class _ActionBlocks:
    """One action's windows, sorted by (recording, start), with the blocks to draw from."""

    rows: np.ndarray  # window rows of the action by recording and start, each
    #                       recording followed by its first windows again (circular blocks)
    offsets: np.ndarray  # first position (into rows) of every candidate block
    lengths: np.ndarray  # its length in windows


def _action_blocks(
    sequence: np.ndarray, start: np.ndarray, rows: np.ndarray, block_frames: int
) -> _ActionBlocks:
    """Circular blocks: every window of a recording starts one, and a block running past the
    recording's last window continues at its first, so every window is drawn equally often
    (the plain moving blocks under-draw both ends and bias the variance down)."""
    order = rows[np.lexsort((start[rows], sequence[rows]))]
    extended, offsets, lengths, position = [], [], [], 0
    for rec in np.unique(sequence[order]):
        own = order[sequence[order] == rec]
        # At least two blocks per recording: one block the whole recording long would make
        # every replicate a rotation of it, and its variance zero.
        length = min(block_windows(start[own], block_frames), max(1, math.ceil(len(own) / 2)))
        offsets.append(position + np.arange(len(own)))
        lengths.append(np.full(len(own), length))
        extended.append(np.concatenate([own, own[: length - 1]]))
        position += len(extended[-1])
    return _ActionBlocks(np.concatenate(extended), np.concatenate(offsets), np.concatenate(lengths))


def block_bootstrap(
    errors: np.ndarray,
    sequence: np.ndarray,
    start: np.ndarray,
    actions: np.ndarray,
    block_frames: int,
    replicates: int = REPLICATES,
    seed: int = 0,
) -> np.ndarray:
    """Bootstrap replicates ``(replicates, T)`` of :func:`protocol_mean` of ``errors (W, T)``;
    ``sequence``, ``start`` and ``actions`` ``(W,)`` say where each window comes from."""
    errors = np.asarray(errors, dtype=np.float64)
    sequence, start, actions = (np.asarray(a) for a in (sequence, start, actions))
    if errors.ndim != 2 or not len(sequence) == len(start) == len(actions) == len(errors):
        raise ValueError(
            f"block_bootstrap: expected errors (W, T) and W sequences, starts and "
            f"actions, got {errors.shape}, {len(sequence)}, {len(start)}, "
            f"{len(actions)}"
        )
    if not isinstance(block_frames, int) or block_frames < 1:
        raise ValueError(
            f"block_bootstrap: block_frames must be a positive integer, got {block_frames!r}"
        )
    rng = np.random.default_rng(seed)
    per_action = []
    for action in np.unique(actions):
        rows = np.flatnonzero(actions == action)
        blocks = _action_blocks(sequence, start, rows, block_frames)
        n = len(rows)
        # Running sums over the action's windows: a block's sum is a difference of two rows.
        cumsum = np.concatenate(
            [np.zeros((1, errors.shape[1])), np.cumsum(errors[blocks.rows], axis=0)]
        )
        draws = math.ceil(n / blocks.lengths.min()) + 1
        chosen = rng.integers(0, len(blocks.offsets), size=(replicates, draws))
        first, length = blocks.offsets[chosen], blocks.lengths[chosen]
        before = np.cumsum(length, axis=1) - length
        take = np.clip(n - before, 0, length)  # the last block is cut to reach n windows
        sums = (cumsum[first + take] - cumsum[first]).sum(axis=1)
        per_action.append(sums / n)
    return np.mean(per_action, axis=0)


def percentile_interval(
    replicates: np.ndarray, confidence: float = CONFIDENCE
) -> tuple[np.ndarray, np.ndarray]:
    """The ``confidence`` percentile interval ``(lo, hi)`` of bootstrap replicates, per column."""
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence!r}")
    tail = 100 * (1 - confidence) / 2
    lo, hi = np.percentile(replicates, [tail, 100 - tail], axis=0)
    return lo, hi


def naive_interval(
    errors: np.ndarray, actions: np.ndarray, confidence: float = CONFIDENCE
) -> tuple[np.ndarray, np.ndarray]:
    """The interval that treats every window as independent (normal, per-window standard
    errors): what the overlap makes far too narrow. For validation only."""
    from scipy.stats import norm

    errors, actions = np.asarray(errors, dtype=np.float64), np.asarray(actions)
    groups = [errors[actions == a] for a in np.unique(actions)]
    variance = sum(g.var(axis=0, ddof=1) / len(g) for g in groups) / len(groups) ** 2
    z = norm.ppf(0.5 + confidence / 2)
    centre = protocol_mean(errors, actions)
    return centre - z * np.sqrt(variance), centre + z * np.sqrt(variance)
