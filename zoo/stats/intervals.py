"""How sure a number is, and what it is sure about: a confidence interval over recordings where
every action has ``MIN_RECORDINGS`` of them (:func:`recording_interval`), else a
window-sampling interval from a studentised circular block bootstrap within recordings
(:func:`window_sampling_interval`); paired comparisons, the bold set (:func:`best_set`) and a
sign test over actions. docs/protocols.md ("How sure a number is") says what each means.
"""

# zoo: computes no number

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

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


MIN_RECORDINGS = 3  # independent recordings per action for a recording-level interval
# Blocks of two window lengths, widened by a t quantile on the blocks (Replicates.widened):
# longer blocks leave CMU's shorter recordings too few degrees of freedom (docs/protocols.md,
# "Why blocks of two window lengths").
BLOCK_WINDOWS = 2
# A recording whose windows' starts span fewer than this many window lengths holds too little of
# its own variance for any block to show: one of 48 windows (CMU's running) covered 0.68 with
# long memory, 70 windows 0.89, 100 windows 0.92. Tables name them.
MIN_SPAN_WINDOWS = 3


@dataclass
class Design:
    """Where a table's windows come from, and so what an interval over them can mean:
    ``recordings`` per action (independent recordings, each with its windows)."""

    recordings: dict[str, int]

    @property
    def recording_level(self) -> bool:
        """Every action has ``MIN_RECORDINGS`` or more recordings: an interval over recordings
        is a confidence interval of the benchmark's mean."""
        return min(self.recordings.values()) >= MIN_RECORDINGS

    def counts(self) -> str:
        counts = sorted(set(self.recordings.values()))
        if len(counts) == 1:
            n = counts[0]
            return (
                f"{n} recording{'s' if n > 1 else ''} per action, {len(self.recordings)} action(s)"
            )
        return ", ".join(f"{a} {n}" for a, n in self.recordings.items())


def coverage_record() -> dict:
    """The coverage measured for these intervals (``zoo/stats/coverage.yaml``, written by
    ``benchmarks/coverage/coverage.py``); empty if not measured."""
    from zoo.core.io import load_yaml

    path = Path(__file__).with_name("coverage.yaml")
    return load_yaml(path.read_text()) if path.is_file() else {}


def design(sequence: np.ndarray, actions: np.ndarray) -> Design:
    sequence, actions = np.asarray(sequence), np.asarray(actions)
    return Design({str(a): int(len(np.unique(sequence[actions == a]))) for a in np.unique(actions)})


def block_length(starts: np.ndarray, block_frames: int, window_frames: int) -> int:
    """A recording's block, in windows: ``block_frames`` long, at most half the recording so
    that it holds two blocks, but never shorter than one window (windows closer than that share
    frames, so a shorter block cuts through their dependence)."""
    n = len(starts)
    wanted = block_windows(starts, block_frames)
    overlap = block_windows(starts, window_frames)
    return max(1, min(wanted, max(math.ceil(n / 2), overlap), n))


def short_recordings(sequence: np.ndarray, start: np.ndarray, window_frames: int) -> list[int]:
    """Recordings of several windows whose starts span fewer than ``MIN_SPAN_WINDOWS`` window
    lengths: their intervals are known to be too narrow."""
    sequence, start = np.asarray(sequence), np.asarray(start)
    out = []
    for rec in np.unique(sequence):
        own = start[sequence == rec]
        if len(own) > 1 and own.max() - own.min() + 1 < MIN_SPAN_WINDOWS * window_frames:
            out.append(int(rec))
    return out


@dataclass
class _ActionBlocks:
    """One action's windows, sorted by (recording, start), with the blocks to draw from."""

    rows: np.ndarray  # window rows of the action by recording and start, each
    #                       recording followed by its first windows again (circular blocks)
    offsets: np.ndarray  # first position (into rows) of every candidate block
    lengths: np.ndarray  # its length in windows
    blocks: float  # how many blocks the action's windows make (for degrees of freedom)


def _action_blocks(
    sequence: np.ndarray,
    start: np.ndarray,
    rows: np.ndarray,
    block_frames: int,
    window_frames: int,
) -> _ActionBlocks:
    """Circular blocks: every window of a recording starts one, and a block running past the
    recording's last window continues at its first, so every window is drawn equally often
    (the plain moving blocks under-draw both ends and bias the variance down)."""
    order = rows[np.lexsort((start[rows], sequence[rows]))]
    extended, offsets, lengths, position, blocks = [], [], [], 0, 0.0
    for rec in np.unique(sequence[order]):
        own = order[sequence[order] == rec]
        length = block_length(start[own], block_frames, window_frames)
        offsets.append(position + np.arange(len(own)))
        lengths.append(np.full(len(own), length))
        extended.append(np.concatenate([own, own[: length - 1]]))
        position += len(extended[-1])
        blocks += len(own) / length
    return _ActionBlocks(
        np.concatenate(extended), np.concatenate(offsets), np.concatenate(lengths), blocks
    )


@dataclass
class Replicates:
    """Bootstrap replicates of each action's mean, ``per_action (A, R, T)``, and the degrees
    of freedom each action's variance has (``df (A,)``). Replicates of two models drawn with
    one seed over one set of windows use the same blocks: their differences are the paired
    bootstrap."""

    per_action: np.ndarray
    df: np.ndarray

    @property
    def mean(self) -> np.ndarray:
        """Replicates ``(R, T)`` of the protocol mean (unweighted over actions)."""
        return self.per_action.mean(axis=0)

    def __sub__(self, other: Replicates) -> Replicates:
        return Replicates(self.per_action - other.per_action, np.minimum(self.df, other.df))

    def widened(self, confidence: float = CONFIDENCE) -> np.ndarray:
        """Replicates ``(R, T)`` of the protocol mean whose spread pays for few blocks: each
        action's deviations from its centre scaled by ``t(df) / z`` at ``confidence`` before
        the actions are averaged, so that an action of two or three blocks (whose bootstrap
        variance is far too small) weighs as a t quantile would make it; a normal quantile of
        their spread is then the interval's half width."""
        from scipy.stats import norm, t

        q = 0.5 + confidence / 2
        scale = t.ppf(q, self.df) / norm.ppf(q)
        centre = self.per_action.mean(axis=1, keepdims=True)
        return (centre + (self.per_action - centre) * scale[:, None, None]).mean(axis=0)


def _check_windows(errors, sequence, start, actions, what: str):
    errors = np.asarray(errors, dtype=np.float64)
    sequence, start, actions = (np.asarray(a) for a in (sequence, start, actions))
    if errors.ndim != 2 or not len(sequence) == len(start) == len(actions) == len(errors):
        raise ValueError(
            f"{what}: expected errors (W, T) and W sequences, starts and actions, got "
            f"{errors.shape}, {len(sequence)}, {len(start)}, {len(actions)}"
        )
    return errors, sequence, start, actions


def block_replicates(
    errors: np.ndarray,
    sequence: np.ndarray,
    start: np.ndarray,
    actions: np.ndarray,
    block_frames: int,
    replicates: int = REPLICATES,
    seed: int = 0,
    window_frames: int = 1,
) -> Replicates:
    """Circular block bootstrap of each action's mean of ``errors (W, T)`` (blocks within a
    recording, :func:`block_length`); an action's variance has as many degrees of freedom as
    its windows make non-overlapping blocks, less one (as batch means), at least one."""
    errors, sequence, start, actions = _check_windows(
        errors, sequence, start, actions, "block_replicates"
    )
    for name, value in (("block_frames", block_frames), ("window_frames", window_frames)):
        if not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"block_replicates: {name} must be a positive integer, got {value!r}")
    draws = _block_draws(
        sequence, start, actions, int(block_frames), replicates, seed, int(window_frames)
    )
    per_action = []
    for drawn in draws:
        # Running sums over the action's windows: a block's sum is a difference of two rows.
        cumsum = np.concatenate(
            [np.zeros((1, errors.shape[1])), np.cumsum(errors[drawn.rows], axis=0)]
        )
        per_action.append(_drawn_sums(cumsum, drawn.first, drawn.take) / drawn.windows)
    return Replicates(np.stack(per_action), np.asarray([drawn.df for drawn in draws]))


@dataclass(frozen=True)
class _ActionDraws:
    """The blocks drawn for one action: its windows' rows in block order, and each
    replicate's drawn blocks, ``first (R, draws)`` positions into ``rows`` and ``take`` windows
    from each (the last block cut to reach the action's ``windows``)."""

    rows: np.ndarray
    first: np.ndarray
    take: np.ndarray
    windows: int
    df: float


# The draws of the last few sets of windows. They depend on the windows, the block sizes, the
# replicates and the seed, not on the errors, and a table draws them for each of its models'
# intervals and again for its bold set. A set holds two (replicates, draws) index arrays per
# action.
_KEPT_DRAWS = 4
_kept_draws: dict[bytes, tuple[_ActionDraws, ...]] = {}


def _block_draws(
    sequence: np.ndarray,
    start: np.ndarray,
    actions: np.ndarray,
    block_frames: int,
    replicates: int,
    seed: int,
    window_frames: int,
) -> tuple[_ActionDraws, ...]:
    """Each action's circular blocks (:func:`_action_blocks`) drawn ``replicates`` times with
    one generator seeded ``seed``, action after action in sorted order; kept where the windows
    and the seed can be named by their bytes."""
    names, group = np.unique(actions, return_inverse=True)
    keep = isinstance(seed, (int, np.integer)) and not (
        sequence.dtype.hasobject or start.dtype.hasobject
    )
    if keep:
        # The actions enter as the group of each window, in sorted order: all a draw depends on.
        key = hashlib.blake2b(
            repr((block_frames, replicates, int(seed), window_frames)).encode(), digest_size=20
        )
        for values in (sequence, start, group.astype(np.int64)):
            key.update(f"{values.dtype}{values.shape}".encode())
            key.update(np.ascontiguousarray(values).tobytes())
        digest = key.digest()
        if digest in _kept_draws:
            drawn = _kept_draws[digest] = _kept_draws.pop(digest)  # most recent: kept longest
            return drawn
    rng = np.random.default_rng(seed)
    draws = []
    for index in range(len(names)):
        rows = np.flatnonzero(group == index)
        blocks = _action_blocks(sequence, start, rows, block_frames, window_frames)
        n = len(rows)
        count = math.ceil(n / blocks.lengths.min()) + 1
        chosen = rng.integers(0, len(blocks.offsets), size=(replicates, count))
        first, length = blocks.offsets[chosen], blocks.lengths[chosen]
        before = np.cumsum(length, axis=1) - length
        take = np.clip(n - before, 0, length)  # the last block is cut to reach n windows
        for array in (blocks.rows, first, take):
            array.flags.writeable = False
        # As many degrees of freedom as non-overlapping blocks, less one (batch means). The 1.5
        # times as many that overlapping blocks would have (Meketon and Schmeiser) measured
        # too few: long-memory coverage 0.83, the bold rule's family-wise error 0.07.
        draws.append(_ActionDraws(blocks.rows, first, take, n, max(1.0, blocks.blocks - 1)))
    drawn = tuple(draws)
    if keep:
        _kept_draws[digest] = drawn
        while len(_kept_draws) > _KEPT_DRAWS:
            del _kept_draws[next(iter(_kept_draws))]
    return drawn


def _drawn_sums(cumsum: np.ndarray, first: np.ndarray, take: np.ndarray) -> np.ndarray:
    """Each replicate's sum over its drawn blocks ``(R, T)``: the blocks' sums (differences of
    the running sums) added draw by draw, without the ``(R, draws, T)`` arrays a sum over the
    draws' axis gathers. In the order that sum adds them, so no interval moves: draw by draw
    where a window holds several columns; pairwise (numpy's order) where it holds one."""
    if cumsum.shape[1] == 1:
        return (cumsum[first + take] - cumsum[first]).sum(axis=1)
    sums = cumsum[first[:, 0] + take[:, 0]] - cumsum[first[:, 0]]
    for d in range(1, first.shape[1]):
        sums += cumsum[first[:, d] + take[:, d]] - cumsum[first[:, d]]
    return sums


def recording_replicates(
    errors: np.ndarray,
    sequence: np.ndarray,
    actions: np.ndarray,
    replicates: int = REPLICATES,
    seed: int = 0,
) -> Replicates:
    """Bootstrap of whole recordings within each action (each action's mean over the drawn
    recordings' windows): the replicates of a design with independent recordings."""
    errors = np.asarray(errors, dtype=np.float64)
    sequence, actions = np.asarray(sequence), np.asarray(actions)
    rng = np.random.default_rng(seed)
    per_action, df = [], []
    for action in np.unique(actions):
        rows = np.flatnonzero(actions == action)
        recs, index = np.unique(sequence[rows], return_inverse=True)
        sums = np.zeros((len(recs), errors.shape[1]))
        np.add.at(sums, index, errors[rows])
        counts = np.bincount(index, minlength=len(recs)).astype(np.float64)
        chosen = rng.integers(0, len(recs), size=(replicates, len(recs)))
        per_action.append(sums[chosen].sum(axis=1) / counts[chosen].sum(axis=1)[:, None])
        df.append(max(1.0, len(recs) - 1.0))
    return Replicates(np.stack(per_action), np.asarray(df))


@dataclass
class Interval:
    """A ``confidence`` interval ``(lo, hi)`` per column of the protocol mean ``centre``, of
    ``kind`` ``confidence`` (over independent recordings: where the benchmark mean could lie)
    or ``window-sampling`` (over windows of these recordings: where the number could lie had
    other windows of the same recordings been drawn; not a confidence interval of the actions)."""

    centre: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    kind: str
    df: np.ndarray

    @property
    def half(self) -> np.ndarray:
        return (self.hi - self.lo) / 2


def _z(confidence: float) -> float:
    from scipy.stats import norm

    return float(norm.ppf(0.5 + confidence / 2))


def _t(confidence: float, df) -> np.ndarray:
    from scipy.stats import t

    return t.ppf(0.5 + confidence / 2, np.asarray(df, dtype=np.float64))


def window_sampling_interval(
    errors: np.ndarray,
    sequence: np.ndarray,
    start: np.ndarray,
    actions: np.ndarray,
    block_frames: int,
    window_frames: int,
    confidence: float = CONFIDENCE,
    replicates: int = REPLICATES,
    seed: int = 0,
) -> Interval:
    """Studentised block bootstrap: the protocol mean +- a t quantile (Satterthwaite degrees of
    freedom over the actions' blocks) times the replicates' standard deviation. A percentile
    interval of a recording that holds two or three blocks is far too narrow (a handful of
    blocks cannot show the tails); the t quantile pays for the few blocks."""
    reps = block_replicates(
        errors, sequence, start, actions, block_frames, replicates, seed, window_frames
    )
    centre = protocol_mean(np.asarray(errors, dtype=np.float64), actions)
    width = _z(confidence) * reps.widened(confidence).std(axis=0)
    return Interval(centre, centre - width, centre + width, "window-sampling", reps.df.min())


def recording_interval(
    errors: np.ndarray,
    sequence: np.ndarray,
    actions: np.ndarray,
    confidence: float = CONFIDENCE,
) -> Interval:
    """A t interval over independent recordings: each action's mean is a window-weighted mean
    of its recordings' means, whose variance is estimated over recordings (cluster-robust, k /
    (k - 1) corrected, k - 1 degrees of freedom); the protocol mean's variance is the actions'
    sum over the squared number of actions, on Satterthwaite degrees of freedom."""
    errors = np.asarray(errors, dtype=np.float64)
    sequence, actions = np.asarray(sequence), np.asarray(actions)
    variances, dfs = [], []
    for action in np.unique(actions):
        rows = np.flatnonzero(actions == action)
        recs, index = np.unique(sequence[rows], return_inverse=True)
        k = len(recs)
        if k < 2:
            raise ValueError(
                f"recording_interval: action {action!r} has one recording; an interval over "
                f"recordings needs at least two"
            )
        sums = np.zeros((k, errors.shape[1]))
        np.add.at(sums, index, errors[rows])
        weights = np.bincount(index, minlength=k).astype(np.float64) / len(rows)
        mean = sums.sum(axis=0) / len(rows)
        residual = sums / len(rows) - weights[:, None] * mean  # n_r (x_r - m) / N
        variances.append(k / (k - 1) * (residual**2).sum(axis=0))
        dfs.append(k - 1.0)
    v, df_a = np.stack(variances), np.asarray(dfs)
    a = len(v)
    spread = (v**2 / df_a[:, None]).sum(axis=0)
    df = np.where(spread > 0, v.sum(axis=0) ** 2 / np.where(spread > 0, spread, 1), np.inf)
    centre = protocol_mean(errors, actions)
    width = _t(confidence, df) * np.sqrt(v.sum(axis=0)) / a
    return Interval(centre, centre - width, centre + width, "confidence", df)


def interval(
    errors: np.ndarray,
    windows,
    confidence: float = CONFIDENCE,
    replicates: int = REPLICATES,
    seed: int = 0,
    block_frames: int | None = None,
) -> Interval:
    """The interval a design allows for the protocol mean of ``errors (W, T)`` over ``windows`` (a
    :class:`zoo.evaluation.results.WindowErrors`): a confidence interval over recordings where every
    action has ``MIN_RECORDINGS`` or more, else a window-sampling interval."""
    if design(windows.sequence, windows.action).recording_level:
        return recording_interval(errors, windows.sequence, windows.action, confidence)
    return window_sampling_interval(
        errors,
        windows.sequence,
        windows.start,
        windows.action,
        block_frames or BLOCK_WINDOWS * windows.window_frames,
        windows.window_frames,
        confidence,
        replicates,
        seed,
    )


def joint_replicates(
    errors: dict[str, np.ndarray],
    windows,
    replicates: int = REPLICATES,
    seed: int = 0,
    block_frames: int | None = None,
) -> dict[str, Replicates]:
    """Replicates of several models' errors on one set of windows, drawn with the same blocks
    (or recordings): differences between them are paired."""
    if design(windows.sequence, windows.action).recording_level:
        return {
            m: recording_replicates(e, windows.sequence, windows.action, replicates, seed)
            for m, e in errors.items()
        }
    return {
        m: block_replicates(
            e,
            windows.sequence,
            windows.start,
            windows.action,
            block_frames or BLOCK_WINDOWS * windows.window_frames,
            replicates,
            seed,
            windows.window_frames,
        )
        for m, e in errors.items()
    }


def best_set(
    errors: dict[str, np.ndarray],
    windows,
    confidence: float = CONFIDENCE,
    replicates: int = REPLICATES,
    seed: int = 0,
    block_frames: int | None = None,
) -> dict[str, np.ndarray]:
    """Which models are not distinguishable from the best, per column: ``{model: bool (T,)}``.

    A simultaneous procedure (multiple comparisons with the best, max-t): model m stays in the
    set while no other model beats it by more than ``c`` paired standard errors, ``c`` the
    ``confidence`` quantile of the largest centred paired statistic over every ordered pair of
    models in the joint replicates, each replicate divided by an independent chi draw on the
    pairs' fewest degrees of freedom (so that few blocks or recordings widen it as a t
    quantile would). Among equally good models, all stay in with probability ``confidence``
    (simulated: benchmarks/coverage/coverage.py --bold).
    """
    names = list(errors)
    if len(names) < 2:
        return {m: np.ones(np.asarray(e).shape[1], bool) for m, e in errors.items()}
    reps = joint_replicates(errors, windows, replicates, seed, block_frames)
    centre = {
        m: protocol_mean(np.asarray(e, np.float64), windows.action) for m, e in errors.items()
    }
    widened = {m: r.widened(confidence) for m, r in reps.items()}
    stats, observed = [], {}
    for i, m in enumerate(names):
        for j in names[i + 1 :]:
            d = widened[m] - widened[j]
            se = d.std(axis=0)
            se = np.where(se > 0, se, np.inf)
            z = (d - d.mean(axis=0)) / se  # (R, T), centred
            stats.append(np.abs(z))  # both orders of the pair
            observed[m, j] = (centre[m] - centre[j]) / se
            observed[j, m] = -observed[m, j]
    critical = np.quantile(np.max(np.stack(stats), axis=0), confidence, axis=0)
    return {
        m: np.all(np.stack([observed[m, j] <= critical for j in names if j != m]), axis=0)
        for m in names
    }


def sign_test(wins: int, losses: int) -> float:
    """Exact two-sided sign test: the probability, were each unit equally likely to go
    either way, of a split at least as uneven as ``wins`` against ``losses`` (ties dropped)."""
    from scipy.stats import binomtest

    n = int(wins) + int(losses)
    return 1.0 if n == 0 else float(binomtest(int(wins), n, 0.5).pvalue)


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


def block_frames_default(windows) -> int:
    """Blocks of ``zoo.stats.intervals.BLOCK_WINDOWS`` window lengths
    (:func:`zoo.stats.intervals.block_length`
    keeps them at least one window long and at most half a recording)."""
    from zoo.stats.intervals import BLOCK_WINDOWS

    return BLOCK_WINDOWS * windows.window_frames
