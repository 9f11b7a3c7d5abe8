"""The one windowing routine: which windows of which sequences a protocol evaluates or trains on.

Samplers; a window is ``T_in + T_out`` consecutive frames:

- ``ltd8``: the LTD / convSeq2Seq test windows. Per CMU file, a fresh
  ``RandomState(1234567890)`` and 8 draws ``idx = randint(0, N - 75)``; per H3.6M action, one
  fresh generator and 4 rounds of ``randint(16, N1 - 150)``, ``randint(16, N2 - 150)`` over its
  two sub-actions. The window is ``[idx + 50 - T_in, idx + 50 + T_out)``, so the target frames
  never depend on ``T_in``.
- ``rand256``: the H3.6M rule with 128 rounds (256 windows per action).
- ``all``: every window, starting at every frame from 0 (SPGSN).
- ``strideK``: every K-th window from frame 0 (AMASS: ``stride5``); ``strideK_strict`` keeps a
  window only if ``start + T_in + T_out < N`` (strictly), as the SpecTrHuMS code does.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np

from zoo.core.errors import ZooError

LTD_SEED = 1234567890
# The LTD test windows are fixed by a 50-frame source and a 25-frame target whatever T_in/T_out.
LTD_SOURCE, LTD_TARGET = 50, 25

SAMPLERS = ("ltd8", "rand256", "all", "strideK", "strideK_strict")
_STRIDE = re.compile(r"^stride([1-9][0-9]*)(_strict)?$")
# allK: every window, cut as if K frames were observed (3DPW in LTD / SPGSN: all50), so the
# predicted frames of the windows do not depend on T_in.
_ALL_AS_IF = re.compile(r"^all([1-9][0-9]*)$")


class SamplerError(ZooError, ValueError):
    pass


def check_sampler(name: str) -> str:
    if name in ("ltd8", "rand256", "all") or _STRIDE.match(name) or _ALL_AS_IF.match(name):
        return name
    raise SamplerError(
        f"unknown sampler {name!r}; valid samplers: ltd8, rand256, all, allK, "
        f"strideK, strideK_strict (K a positive integer, e.g. stride5, all50)"
    )


def window_sampler(
    name: str,
    lengths: Sequence[int],
    input_frames: int,
    output_frames: int,
    ltd_rule: str = "per_file",
    groups: Sequence[str] | None = None,
    subactions: Sequence[int] | None = None,
) -> np.ndarray:
    """Window starts as an int64 array ``(W, 2)`` of ``(sequence index, first frame)``.

    ``groups`` (the action of each sequence) and ``subactions`` are needed by the H3.6M rule of
    ``ltd8`` / ``rand256``, which draws from one generator per action over its two recordings.
    """
    check_sampler(name)
    length = input_frames + output_frames
    if input_frames < 1 or output_frames < 1:
        raise SamplerError(
            f"input_frames and output_frames must be positive, got "
            f"{input_frames} and {output_frames}"
        )
    if name in ("ltd8", "rand256"):
        if input_frames > LTD_SOURCE or output_frames > LTD_TARGET:
            raise SamplerError(
                f"sampler {name} takes T_in <= {LTD_SOURCE} and T_out <= "
                f"{LTD_TARGET} (its windows are cut from 75-frame draws), got "
                f"{input_frames} and {output_frames}"
            )
        if name == "ltd8" and ltd_rule == "per_file":
            return _ltd_per_file(lengths, input_frames)
        if ltd_rule != "per_action_pair" and name == "rand256":
            raise SamplerError(
                "sampler rand256 is defined for Human3.6M (two sub-actions per "
                "action), not for this dataset"
            )
        rounds = 4 if name == "ltd8" else 128
        return _ltd_per_action_pair(lengths, groups, subactions, input_frames, rounds)
    as_if, match = _ALL_AS_IF.match(name), _STRIDE.match(name)
    first, stride, strict = 0, 1, False  # all
    if as_if:
        observed = int(as_if.group(1))
        if observed < input_frames:
            raise SamplerError(
                f"sampler {name} cuts windows as if {observed} frames were "
                f"observed; T_in = {input_frames} is more"
            )
        first = observed - input_frames
    elif match:
        stride, strict = int(match.group(1)), bool(match.group(2))
    out = []
    for i, n in enumerate(lengths):
        last = n - length - (1 if strict else 0)
        starts = np.arange(first, last + 1, stride)
        out.append(np.stack([np.full_like(starts, i), starts], axis=1))
    return np.concatenate(out).astype(np.int64) if out else np.zeros((0, 2), np.int64)


def _ltd_per_file(lengths: Sequence[int], input_frames: int) -> np.ndarray:
    out = []
    for i, n in enumerate(lengths):
        high = n - LTD_SOURCE - LTD_TARGET
        if high <= 0:
            raise SamplerError(
                f"sequence {i} has {n} frames; ltd8 needs more than {LTD_SOURCE + LTD_TARGET}"
            )
        rng = np.random.RandomState(LTD_SEED)  # fresh per file, as the reference loader does
        for _ in range(8):
            idx = rng.randint(0, high)
            out.append((i, idx + LTD_SOURCE - input_frames))
    return np.asarray(out, dtype=np.int64)


def _ltd_per_action_pair(lengths, groups, subactions, input_frames, rounds) -> np.ndarray:
    if groups is None or subactions is None:
        raise SamplerError(
            "the H3.6M window rule needs the action and sub-action of every sequence"
        )
    out = []
    for action in dict.fromkeys(groups):  # actions in first-seen order
        pair = {}
        for i, (g, s) in enumerate(zip(groups, subactions)):
            if g == action:
                pair[s] = i
        if sorted(pair) != [1, 2]:
            raise SamplerError(
                f"action {action!r}: the H3.6M window rule needs sub-actions 1 and "
                f"2, found {sorted(pair)}"
            )
        rng = np.random.RandomState(LTD_SEED)  # fresh per action
        first, second = [], []
        for _ in range(rounds):
            for sub, bucket in ((1, first), (2, second)):
                high = lengths[pair[sub]] - 150
                if high <= 16:
                    raise SamplerError(
                        f"action {action!r} sub-action {sub}: "
                        f"{lengths[pair[sub]]} frames is too short for the H3.6M "
                        f"window rule (needs more than 166)"
                    )
                idx = rng.randint(16, high)
                bucket.append((pair[sub], idx + LTD_SOURCE - input_frames))
        out += first + second
    return np.asarray(out, dtype=np.int64)


def gather_windows(sequences: Sequence[np.ndarray], index: np.ndarray, length: int) -> np.ndarray:
    """Stack the windows ``index`` (from :func:`window_sampler`) into ``(W, length, ...)``."""
    if len(index) == 0:
        return np.zeros((0, length) + sequences[0].shape[1:], sequences[0].dtype)
    offsets = np.arange(length)
    out = np.empty((len(index), length) + sequences[0].shape[1:], sequences[0].dtype)
    for i in np.unique(index[:, 0]):
        rows = np.nonzero(index[:, 0] == i)[0]
        out[rows] = sequences[i][index[rows, 1, None] + offsets]
    return out


def frame_counts(index: np.ndarray, lengths: Sequence[int], length: int) -> list[np.ndarray]:
    """How many windows of ``index`` hold each frame: one int64 array ``(n,)`` per sequence.

    Statistics "over every frame of every window" weight each frame by this count, so they can
    be computed over each distinct frame once (with sampler ``all`` a frame sits in ``length``
    windows).
    """
    lengths = np.asarray(lengths, np.int64)
    seq, starts = index[:, 0], index[:, 1]
    bad = np.nonzero((starts < 0) | (starts + length > lengths[seq]))[0]
    if len(bad):
        i = bad[0]
        raise SamplerError(
            f"window {i} of sequence {seq[i]}: frames [{starts[i]}, "
            f"{starts[i] + length}) run past its {lengths[seq[i]]} frames"
        )
    # +1 where a window starts, -1 one past its end; each sequence has n + 1 slots
    offsets = np.concatenate([[0], np.cumsum(lengths + 1)])
    edges = np.zeros(offsets[-1], np.int64)
    np.add.at(edges, offsets[seq] + starts, 1)
    np.add.at(edges, offsets[seq] + starts + length, -1)
    return [np.cumsum(edges[offsets[i] : offsets[i] + n]) for i, n in enumerate(lengths)]
