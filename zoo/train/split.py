"""Which frames train and which validate (the ``val_split`` rules), the windows of each, and a
model's training view of every sequence, computed once and cached."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import torch

from zoo.core.errors import TrainingError
from zoo.core.io import progress_bar
from zoo.data.windows import window_sampler
from zoo.models.recipe import Recipe


def sequence_frames(sequence) -> np.ndarray:
    """The ``(T, P, 3)`` array of a skeleton (joint positions) or mesh (vertices) sequence."""
    return sequence.positions if hasattr(sequence, "positions") else sequence.vertices


def held_out_recordings(names: list[str], val_fraction: float) -> list[int]:
    """The recordings ``val_split: recordings`` holds out: every k-th in name order (k = round(1
    / val_fraction)), starting half a step in, so they spread over subjects and takes."""
    step = max(2, round(1 / val_fraction))
    order = sorted(range(len(names)), key=lambda i: names[i])
    return sorted(order[step // 2 :: step])


def held_out_frames(
    dataset, lengths: list[int], val_fraction: float, window: int, rule: str = "auto"
) -> dict[int, int]:
    """Which frames of the training recordings validate: ``{recording index: first held-out
    frame}`` for every recording that gives frames to validation (0: the whole recording).

    ``rule`` ``tails``: the last ``val_fraction`` of every recording long enough to spare a
    window (at least ``window / val_fraction`` frames); shorter ones are trained on whole.
    ``actions``: ``tails``, and for an action none of whose recordings is that long, the last
    ``val_fraction`` of the action's frames (at least one window) from the end of its longest
    recording: every action validates, none is held out whole.
    ``auto``: the same where every recording is long enough (H3.6M), otherwise the last
    ``val_fraction`` of the recordings, whole (cloth: one window per sequence; on CMU this is
    the last three recordings, all walking). ``recordings``: whole recordings, every k-th by
    name (:func:`held_out_recordings`).
    """
    count = len(lengths)
    if rule == "recordings":
        held = held_out_recordings([s.name for s in dataset.sequences], val_fraction)
        if len(held) >= count:
            raise TrainingError(
                f"{dataset.name}/{dataset.split}: {count} recordings are too few to "
                f"hold {val_fraction:.0%} of them out for validation"
            )
        return {i: 0 for i in held}
    long_enough = [i for i, n in enumerate(lengths) if n * val_fraction >= window]
    if rule == "actions":
        return _held_out_per_action(dataset, lengths, val_fraction, window)
    if rule == "tails" or len(long_enough) == count:
        if not long_enough:
            raise TrainingError(
                f"{dataset.name}/{dataset.split}: no recording is long enough to spare "
                f"{val_fraction:.0%} of its frames for a validation window of {window} (the "
                f"longest has {max(lengths, default=0)} frames, at least "
                f"{math.ceil(window / val_fraction)} needed); choose "
                f"the recipe's val_split 'recordings'"
            )
        return {i: int(round(lengths[i] * (1 - val_fraction))) for i in long_enough}
    held = max(1, int(round(count * val_fraction)))
    if held >= count:
        raise TrainingError(
            f"{dataset.name}/{dataset.split}: {count} sequences are too few "
            f"to hold {val_fraction:.0%} out for validation"
        )
    return {i: 0 for i in range(count - held, count)}


def _held_out_per_action(
    dataset, lengths: list[int], val_fraction: float, window: int
) -> dict[int, int]:
    """The ``actions`` rule of :func:`held_out_frames`."""
    by_action: dict[str, list[int]] = {}
    for i, sequence in enumerate(dataset.sequences[: len(lengths)]):
        by_action.setdefault(getattr(sequence, "action", ""), []).append(i)
    plan: dict[int, int] = {}
    for action, indices in by_action.items():
        tails = [i for i in indices if lengths[i] * val_fraction >= window]
        if tails:
            plan.update({i: int(round(lengths[i] * (1 - val_fraction))) for i in tails})
            continue
        longest = max(indices, key=lambda i: lengths[i])
        held = max(window, int(round(val_fraction * sum(lengths[i] for i in indices))))
        if lengths[longest] - held < window:  # the recording would train on no window
            raise TrainingError(
                f"{dataset.name}/{dataset.split}: action {action!r}: its longest recording "
                f"({lengths[longest]} frames) cannot spare {held} frames for validation and "
                f"keep a training window of {window}; choose the recipe's val_split 'tails'"
            )
        plan[longest] = lengths[longest] - held
    return plan


def split_train_val(
    dataset, val_fraction: float, window: int, arrays: list | None = None, rule: str = "auto"
) -> tuple[list, list]:
    """Training and validation arrays ``(T, P, 3)``, never overlapping, as
    :func:`held_out_frames` divides the recordings. ``arrays``: other per-frame arrays of the
    dataset's sequences (a training view), split exactly as the frames are."""
    if arrays is None:
        arrays = [sequence_frames(s) for s in dataset.sequences]
    plan = held_out_frames(dataset, [len(a) for a in arrays], val_fraction, window, rule)
    kept = [a[: plan[i]] if i in plan else a for i, a in enumerate(arrays) if plan.get(i) != 0]
    return kept, [arrays[i][plan[i] :] for i in sorted(plan)]


def validation_record(
    dataset, recipe: Recipe, window: int, windows: int, training_windows: int | None = None
) -> dict[str, Any]:
    """What a run validated on, as its checkpoint and shipped record say: the rule, the
    recordings held out whole and those whose last frames validate, and the number of
    windows; with ``training_windows``, how many windows a full epoch draws from (what a
    record's budget is measured against)."""
    names = [s.name for s in dataset.sequences]
    lengths = [len(sequence_frames(s)) for s in dataset.sequences]
    plan = held_out_frames(dataset, lengths, recipe.val_fraction, window, recipe.val_split)
    what: dict[str, Any] = {}
    if whole := [names[i] for i in sorted(plan) if plan[i] == 0]:
        what["recordings"] = whole
    if tails := [names[i] for i in sorted(plan) if plan[i] > 0]:
        what["tails"] = {"fraction": recipe.val_fraction, "of": tails}
    return {
        "split": recipe.val_split,
        "of": f"{dataset.name}/{dataset.split} ({len(names)} recordings)",
        **what,
        "windows": int(windows),
        **({"training_windows": int(training_windows)} if training_windows is not None else {}),
    }


def usable_windows(arrays, length: int, sampler: str, t_in: int, t_out: int):
    """The arrays long enough for a window, and the sampler's windows ``(sequence, first
    frame)`` of them."""
    usable = [a for a in arrays if len(a) >= length]
    index = window_sampler(sampler, [len(a) for a in usable], t_in, t_out)
    return usable, index


VIEW_FORMAT = 1


def training_view_arrays(
    model, dataset, used, *, cache_dir: str | Path | None = None, progress: bool = False
) -> list[np.ndarray]:
    """The model's ``training_view`` of every sequence of ``dataset`` (frames ``[:, used]``),
    float32, computed once and kept in ``<cache>/views/`` under a key of the dataset's content
    and the view's identity; a stored file is read only if its recorded identity is exactly
    this one."""
    import hashlib
    import json

    from zoo.core.io import atomic_path, canonical_json
    from zoo.data.mesh import cache_root

    if not hasattr(dataset, "content_hash"):
        raise TrainingError(
            f"{dataset.name}: a training view is cached under the dataset's content hash, "
            f"which only mesh datasets have"
        )
    content = dataset.content_hash()
    identity = {
        "format": VIEW_FORMAT,
        "dataset": dataset.name,
        "split": dataset.split,
        "content_hash": content,
        "points": repr(used),
        "view": model.training_view_identity(),
    }
    key = hashlib.sha256(canonical_json(identity).encode()).hexdigest()[:16]
    path = cache_root(cache_dir) / "views" / f"{dataset.name}-{key}.npz"
    if path.is_file():
        with np.load(path, allow_pickle=False) as z:
            if json.loads(str(z["identity"])) == identity:
                return [z[f"s{i}"] for i in range(len(dataset.sequences))]
    arrays = []
    bar = progress_bar(
        total=len(dataset.sequences),
        desc=f"{dataset.name}: training view",
        unit="sequence",
        leave=False,
        disable=not progress,
    )
    with torch.no_grad():
        for sequence in dataset.sequences:
            frames = np.asarray(sequence_frames(sequence))[:, used]
            parts = [
                model.training_view(torch.from_numpy(np.ascontiguousarray(frames[i : i + 256])))
                for i in range(0, len(frames), 256)
            ]
            arrays.append(torch.cat(parts).to(torch.float32).numpy())
            bar.update(1)
    bar.close()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(
            f,
            identity=np.asarray(canonical_json(identity)),
            **{f"s{i}": a for i, a in enumerate(arrays)},
        )
    return arrays
