"""The one training engine, shared by every trainable model.

A model's recipe is data: the ``train`` mapping of its registry entry (optimizer settings,
schedule, batch size, epochs, gradient clipping, augmentation), overridable from the command
line. The engine is seeded and deterministic on CPU; an interrupted run resumed with
``resume=True`` ends with the same weights as an uninterrupted one, because the data order of
every epoch derives from (seed, epoch) and the RNG states are saved with each epoch's state.

Validation: the last ``val_fraction`` of training recordings (by time), or whole recordings,
held out (``val_split``, :func:`held_out_frames`); its windows never overlap the training
windows. The checkpoint with the lowest mean validation MPJPE is kept as ``best.pt``;
``last.pt`` holds the full state for ``--resume``. Each epoch also records the error at the
first predicted frame and at 80, 400 and 1000 ms beside repeat-last's on the same windows
(:func:`validate`).

Model hooks (both optional): ``training_loss(history, future)`` replaces the default loss (mean
MPJPE over predicted frames); ``start_epoch(epoch, frames)`` runs before every epoch, with
``frames()`` yielding ``(frames (N, P, 3), counts (N,))``: every distinct frame of the training
windows once, in a fixed order, with the number of training windows that hold it (a statistic
over every frame of every window weights each frame by its count).

A model that learns in another representation of the frames than the one it is scored in
(SpecTrHuMS: spectral coefficients of the vertices) may define ``training_view(frames (N, P, 3))
-> (N, ...)`` with ``training_view_identity()`` (a dict naming everything the view depends on).
The engine then computes the view of every training sequence once, stores it beside the dataset
cache (``<cache>/views/<dataset>-<key>.npz``, keyed by the dataset's content hash and that
identity, so a changed basis or dataset is never read by mistake), and trains on windows of it:
``start_epoch``'s frames are in the view (``start_epoch(epoch, frames, view=True)``), and the
loss is ``training_loss_view(history, future)``. Validation still scores predictions in the
benchmark's own space (``val_sampler`` thins its windows where that is costly).

The engine's own steps are named functions, shared with whatever else needs them:
:func:`training_step` (one optimizer step; ``zoo costs`` times it too), :func:`validate` (the
mean and per-horizon validation errors) and :func:`save_epoch` (``best.pt`` and ``last.pt``).
:data:`MODEL_HOOKS` declares the model hooks above; a model that defines part of a group of
them is refused before training starts.

Distributed data-parallel: launched by ``torchrun``, each process takes its share of every
global batch (gloo on CPU, nccl on GPU), gradients are averaged, and rank 0 writes.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from zoo.benchmark import Benchmark, get_benchmark
from zoo.checkpoints import (
    CHECKPOINT_FORMAT,
    CheckpointError,
    model_origin,
    model_protocol,
    plain,
    read_checkpoint,
    save_checkpoint,
    stored_hparams,
    trained_model,
    weights_digest,
)
from zoo.data.windows import frame_counts, gather_windows, window_sampler
from zoo.distributed import DistInfo, init_distributed
from zoo.errors import EvaluationError, ZooError
from zoo.evaluation import checked_prediction, predict
from zoo.io import code_version, progress_bar, repo_relative, sha256_file
from zoo.metrics import mpjpe, vertex_rmse
from zoo.options import EVAL_BATCH
from zoo.paths import REPO_ROOT
from zoo.registry import Registry, load_registry
from zoo.weights import read_weights

DEFAULT_RECIPE: dict[str, Any] = {
    "optimizer": "adam",
    "lr": 1e-3,
    "weight_decay": 0.0,
    "batch_size": 32,
    "epochs": 10,
    "grad_clip": None,
    "schedule": {"type": "constant"},
    "augment": [],
    "val_fraction": 0.1,
    # Which frames validate (see held_out_frames): "auto", the last val_fraction of every
    # sequence where all are long enough (H3.6M), else the last val_fraction of the sequences
    # (cloth; on CMU the last 3 recordings, all of them walking); "tails", the last
    # val_fraction of every recording long enough to spare a window, the shorter ones trained
    # on whole (CMU: every action keeps its recordings); "actions", "tails" and, for an action
    # none of whose recordings can spare a tail, the end of its longest recording, so that every
    # action validates and none is held out whole; "recordings", whole recordings spread over
    # the data (every k-th by name, k = 1 / val_fraction), so that validation sees many
    # recordings and subjects.
    "val_split": "auto",
    "train_sampler": "all",
    # Validation windows of the held-out frames: every window by default; a sparser sampler
    # (e.g. stride5_strict) cuts the cost of validating large meshes every epoch.
    "val_sampler": "all",
    # "bfloat16": the training loss (forward) under torch.autocast; weights, optimiser,
    # validation and evaluation stay float32. Models keep their precision-critical sums (mm
    # positions, spectral products) in float32 themselves.
    "precision": "float32",
}
PRECISIONS = {"float32": None, "bfloat16": torch.bfloat16}
VAL_SPLITS = ("auto", "tails", "actions", "recordings")
SCHEDULES = ("constant", "step", "cosine", "multistep")
AUGMENTATIONS = ("time_reversal",)


class TrainingError(ZooError, RuntimeError):
    pass


# ---- recipe ----------------------------------------------------------------------------------


def training_recipe(
    entry_train: dict[str, Any], overrides: dict[str, Any] | None = None
) -> dict[str, Any]:
    recipe = {**DEFAULT_RECIPE, **entry_train, **(overrides or {})}
    unknown = sorted(set(recipe) - set(DEFAULT_RECIPE))
    if unknown:
        raise TrainingError(
            f"unknown training-recipe key(s) {', '.join(unknown)}; valid: "
            f"{', '.join(sorted(DEFAULT_RECIPE))}"
        )
    if recipe["optimizer"] != "adam":
        raise TrainingError(
            f"training recipe: optimizer {recipe['optimizer']!r} unknown; valid: adam"
        )
    schedule = recipe["schedule"] or {"type": "constant"}
    if not isinstance(schedule, dict) or schedule.get("type") not in SCHEDULES:
        raise TrainingError(
            f"training recipe: schedule {schedule!r} has no known type; valid: "
            f"{', '.join(SCHEDULES)} (YAML needs a space after each colon: "
            f"'{{type: step, every_epochs: 2, gamma: 0.96}}')"
        )
    warmup = schedule.get("warmup_steps", 0)
    if isinstance(warmup, bool) or not isinstance(warmup, int) or warmup < 0:
        raise TrainingError(
            f"training recipe: schedule warmup_steps must be a non-negative integer, got {warmup!r}"
        )
    bad = [a for a in recipe["augment"] or () if a not in AUGMENTATIONS]
    if bad:
        raise TrainingError(
            f"training recipe: augmentation {bad[0]!r} unknown; valid: {', '.join(AUGMENTATIONS)}"
        )
    if recipe["precision"] not in PRECISIONS:
        raise TrainingError(
            f"training recipe: precision {recipe['precision']!r} unknown; "
            f"valid: {', '.join(PRECISIONS)}"
        )
    for key in ("batch_size", "epochs"):
        if isinstance(recipe[key], bool) or not isinstance(recipe[key], int) or recipe[key] < 1:
            raise TrainingError(
                f"training recipe: {key} must be a positive integer, got {recipe[key]!r}"
            )
    # lr 0 is allowed: it runs the whole pipeline with frozen weights (tests use it).
    if not _positive_number(recipe["lr"], allow_zero=True):
        raise TrainingError(f"training recipe: lr must be a number >= 0, got {recipe['lr']!r}")
    if not _positive_number(recipe["weight_decay"], allow_zero=True):
        raise TrainingError(
            f"training recipe: weight_decay must be a number >= 0, got {recipe['weight_decay']!r}"
        )
    # A negative limit would flip the gradients' sign inside clip_grad_norm_.
    if recipe["grad_clip"] is not None and not _positive_number(recipe["grad_clip"]):
        raise TrainingError(
            f"training recipe: grad_clip must be a number > 0 or null (no "
            f"clipping), got {recipe['grad_clip']!r}"
        )
    if schedule["type"] == "step" and not (
        isinstance(schedule.get("every_epochs"), int)
        and schedule["every_epochs"] >= 1
        and _positive_number(schedule.get("gamma"))
        and isinstance(schedule.get("offset_epochs", 0), int)
        and not isinstance(schedule.get("offset_epochs", 0), bool)
        and schedule.get("offset_epochs", 0) >= 0
    ):
        raise TrainingError(
            f"training recipe: a step schedule needs every_epochs (an integer "
            f">= 1) and gamma (a number > 0), and offset_epochs, if given, an "
            f"integer >= 0; got {schedule!r}"
        )
    if schedule["type"] == "multistep":
        lrs, milestones = schedule.get("lrs"), schedule.get("milestones_steps")
        if (
            not isinstance(lrs, list)
            or not isinstance(milestones, list)
            or not lrs
            or len(lrs) != len(milestones) + 1
        ):
            raise TrainingError(
                f"training recipe: a multistep schedule needs milestones_steps "
                f"[s1, ...] and one more rate in lrs [lr0, lr1, ...], got "
                f"{schedule!r}"
            )
        # The schedule's own rates are what runs; a different lr would be recorded, not used.
        if recipe["lr"] != lrs[0]:
            raise TrainingError(
                f"training recipe: lr {recipe['lr']!r} is not what runs: the "
                f"multistep schedule sets its own rates lrs = {lrs}; change "
                f"the schedule instead (--train-set 'schedule={{type: "
                f"multistep, milestones_steps: [...], lrs: [...]}}') and give "
                f"lr equal to its first rate"
            )
    if not 0 < recipe["val_fraction"] < 0.5:
        raise TrainingError(
            f"training recipe: val_fraction must lie in (0, 0.5), got {recipe['val_fraction']}"
        )
    if recipe["val_split"] not in VAL_SPLITS:
        raise TrainingError(
            f"training recipe: val_split {recipe['val_split']!r} unknown; valid: "
            f"{', '.join(VAL_SPLITS)}"
        )
    return recipe


def _positive_number(value, allow_zero: bool = False) -> bool:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return False
    return value >= 0 if allow_zero else value > 0


def learning_rate(
    schedule: dict[str, Any], base_lr: float, epoch: int, epochs: int, step: int = 0
) -> float:
    """The learning rate at 0-based ``epoch`` and global optimizer ``step``.

    Any schedule may add ``warmup_steps: N``: the rate grows linearly from ``lr / N`` over the
    first N optimizer steps (a post-norm transformer trained at a high rate needs it). No
    schedule (``null``) is a constant rate, as the recipe check reads it."""
    schedule = schedule or {"type": "constant"}
    warmup = schedule.get("warmup_steps", 0)
    if warmup and step < warmup:
        rest = {k: v for k, v in schedule.items() if k != "warmup_steps"}
        return learning_rate(rest, base_lr, epoch, epochs, step) * (step + 1) / warmup
    kind = schedule.get("type", "constant")
    if kind == "constant":
        return base_lr
    if kind == "step":  # SPGSN: x gamma every `every_epochs`
        # offset_epochs: decays counted as if that many epochs had run before the first (LTD's
        # and PGBIG's code decay at the start of an epoch, the first one included for PGBIG)
        offset = schedule.get("offset_epochs", 0)
        return base_lr * schedule["gamma"] ** ((epoch + offset) // schedule["every_epochs"])
    if kind == "cosine":  # SpecTrHuMS: cosine from lr to min_lr over the run, per epoch
        lo = schedule.get("min_lr", 0.0)
        return lo + (base_lr - lo) * 0.5 * (1 + math.cos(math.pi * epoch / max(1, epochs)))
    if kind == "multistep":  # siMLPe: lrs[i] from optimizer step milestones_steps[i-1] on
        lrs, milestones = schedule["lrs"], schedule["milestones_steps"]
        return lrs[sum(step >= m for m in milestones)]
    raise TrainingError(f"schedule type {kind!r} unknown")


# ---- data ------------------------------------------------------------------------------------


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
                f"--train-set val_split=recordings"
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
                f"keep a training window of {window}; choose --train-set val_split=tails"
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

    from zoo.data.mesh import cache_root
    from zoo.io import atomic_path, canonical_json

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
    bar = _progress(progress, len(dataset.sequences), f"{dataset.name}: training view")
    with torch.no_grad():
        for sequence in dataset.sequences:
            frames = np.asarray(sequence_frames(sequence))[:, used]
            parts = [
                model.training_view(torch.from_numpy(np.ascontiguousarray(frames[i : i + 256])))
                for i in range(0, len(frames), 256)
            ]
            arrays.append(torch.cat(parts).to(torch.float32).numpy())
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(
            f,
            identity=np.asarray(canonical_json(identity)),
            **{f"s{i}": a for i, a in enumerate(arrays)},
        )
    return arrays


def _windows(arrays, length: int, sampler: str, t_in: int, t_out: int):
    usable = [a for a in arrays if len(a) >= length]
    index = window_sampler(sampler, [len(a) for a in usable], t_in, t_out)
    return usable, index


def cpu_info(path: str | Path = "/proc/cpuinfo") -> dict[str, str]:
    """The first processor's fields of ``path`` (Linux), or {} where it cannot be read."""
    try:
        text = Path(path).read_text()
    except OSError:
        return {}
    info: dict[str, str] = {}
    for line in text.splitlines():
        key, sep, value = line.partition(":")
        if not sep:
            if info:  # a blank line ends the first processor
                break
            continue
        info.setdefault(key.strip(), value.strip())
    return info


def cpu_has_native_bfloat16(cpuinfo: str | Path = "/proc/cpuinfo") -> bool | None:
    """Whether this CPU multiplies bfloat16 natively (AVX512-BF16 or AMX), from the flags of
    ``cpuinfo``; None where they cannot be read (not Linux). Without them a bfloat16 autocast
    runs its products on a slow fallback."""
    flags = cpu_info(cpuinfo).get("flags")
    return None if flags is None else bool({"avx512_bf16", "amx_bf16"} & set(flags.split()))


def forward_precision(precision: str, device) -> torch.autocast:
    """The context a training loss runs in for recipe ``precision`` (``PRECISIONS``): an
    autocast to its dtype, or a disabled one for float32."""
    dtype = PRECISIONS[precision]
    return torch.autocast(torch.device(device).type, dtype=dtype, enabled=dtype is not None)


def _point_index(bench: Benchmark):
    """Which points of a frame models see: the predicted joints, or every vertex."""
    return slice(None) if bench.representation == "mesh" else list(bench.skeleton.used)


# ---- the loop --------------------------------------------------------------------------------


def train(
    model_name: str,
    benchmark: str | Benchmark,
    *,
    registry: Registry | None = None,
    epochs: int | None = None,
    out_dir: str | Path | None = None,
    data_root: str | Path | None = None,
    overrides: dict[str, Any] | None = None,
    train_overrides: dict[str, Any] | None = None,
    resume: bool = False,
    seed: int = 0,
    device: str = "cpu",
    max_batches: int | None = None,
    progress: bool = True,
    stop_after_epoch: int | None = None,
    init_from: str | Path | None = None,
    cuda_graph: bool = False,
) -> Path:
    """Train ``model_name`` on ``benchmark``'s training split; returns the best checkpoint path.

    With ``cuda_graph`` on one CUDA device (one process), each epoch's optimizer step is
    captured once as a CUDA graph and replayed (:class:`CudaGraphStep`).

    ``init_from`` (a checkpoint of the same model and protocol) starts from
    those weights with a fresh optimiser and schedule: a further stage of training (e.g. a longer
    autoencoder phase, then the joint one), recorded with the source's own budget.

    ``stop_after_epoch`` ends the run early as if interrupted (tests of ``resume``).
    """
    registry = registry or load_registry()
    bench = get_benchmark(benchmark) if isinstance(benchmark, (str, Path)) else benchmark
    entry = registry.get(model_name)
    if not entry.trainable:
        raise TrainingError(
            f"model {model_name!r} runs the weights of {entry.weights_of!r} (registry: "
            f"weights_of): train that one (zoo train --model {entry.weights_of})"
            if entry.weights_of
            else f"model {model_name!r} has nothing to train (registry: trainable: false)"
        )
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**32:
        raise TrainingError(f"seed must be an integer in 0..2**32-1, got {seed!r}")
    if max_batches is not None and (
        isinstance(max_batches, bool) or not isinstance(max_batches, int) or max_batches < 1
    ):
        raise TrainingError(
            f"max_batches (--max-batches) must be a positive integer, got {max_batches!r}"
        )
    recipe = training_recipe(
        {**({"val_split": bench.val_split} if bench.val_split else {}), **entry.train},
        {**(train_overrides or {}), **({"epochs": epochs} if epochs is not None else {})},
    )
    dist_info = init_distributed(device)
    if (
        recipe["precision"] == "bfloat16"
        and torch.device(device).type == "cpu"
        and cpu_has_native_bfloat16() is False
    ):
        warnings.warn(
            f"training {model_name} with precision bfloat16 on a CPU without native "
            f"bfloat16 products (no avx512_bf16 or amx_bf16 flag): torch falls back "
            f"to a slow path (SpecTrHuMS: a step 21x slower than float32 on an AVX2 "
            f"CPU); --train-set precision=float32 is faster here",
            RuntimeWarning,
            stacklevel=2,
        )
    view = bench.view_for(entry.representation)
    dataset = bench.load(data_root, split=bench.train_split)
    if bench.representation == "mesh" and view == "joints":
        dataset = dataset.joints_view()  # a skeleton model on a mesh benchmark's joints
    hparams = registry.model_args(
        model_name,
        **{**bench.model_inputs(entry.context, data_root, dataset, view), **(overrides or {})},
    )
    if init_from is not None and resume:
        raise TrainingError(
            "give --init-from (a new stage from other weights) or --resume (this "
            "run's last state), not both"
        )
    out_dir = Path(out_dir) if out_dir else REPO_ROOT / "checkpoints" / bench.name / model_name
    if init_from is not None and Path(init_from).resolve() in {
        (out_dir / f).resolve() for f in ("best.pt", "last.pt")
    }:
        raise TrainingError(
            f"--init-from {init_from}: this run would overwrite it; give the new "
            f"stage its own --out"
        )
    initial = (
        initial_weights(init_from, model_name, bench, registry, data_root, dataset)
        if init_from is not None
        else None
    )

    torch.manual_seed(seed)
    np.random.seed(seed)
    torch.use_deterministic_algorithms(True, warn_only=True)
    model = registry.create_model(model_name, **hparams).to(device)
    if initial is not None:
        try:
            model.load_state_dict(initial[0])
        except RuntimeError as e:
            raise TrainingError(
                f"--init-from {init_from}: its weights do not fit {model_name} "
                f"with these hyper-parameters: {e}"
            ) from None
    graphed = cuda_graph and torch.device(device).type == "cuda" and not dist_info.active
    optimizer = make_optimizer(model, recipe, device, graphed)
    t_in, t_out = bench.input_frames, bench.output_frames
    length = t_in + t_out
    train_seqs, val_seqs = split_train_val(
        dataset, recipe["val_fraction"], length, rule=recipe["val_split"]
    )
    train_pos, train_index = _windows(train_seqs, length, recipe["train_sampler"], t_in, t_out)
    val_pos, val_index = _windows(val_seqs, length, recipe["val_sampler"], t_in, t_out)
    if len(train_index) == 0:
        raise TrainingError(
            f"{dataset.name}/{dataset.split}: training sampler "
            f"{recipe['train_sampler']!r} finds no window of {length} frames in "
            f"the training sequences (longest: "
            f"{max((len(a) for a in train_seqs), default=0)} frames); choose "
            f"another with --train-set train_sampler=NAME (e.g. all)"
        )
    if len(val_index) == 0:
        raise TrainingError(
            f"{dataset.name}/{dataset.split}: validation sampler "
            f"{recipe['val_sampler']!r} finds no window of {length} frames in the held-out "
            f"sequences; choose another with --train-set val_sampler=NAME (e.g. all)"
        )
    used = _point_index(bench)
    check_hooks(model, model_name)
    # A model with a training view trains on windows of that view of every frame, computed once
    # (cached): train_src and src_points say where training windows come from.
    train_src, src_points = train_pos, used
    if hasattr(model, "training_view"):
        views = training_view_arrays(model, dataset, used, progress=progress)
        view_train, _ = split_train_val(
            dataset, recipe["val_fraction"], length, arrays=views, rule=recipe["val_split"]
        )
        train_src, view_index = _windows(view_train, length, recipe["train_sampler"], t_in, t_out)
        src_points = slice(None)
        if not np.array_equal(view_index, train_index):
            raise TrainingError(
                f"{model_name}: its training view changes the sequences' lengths "
                f"(training_view must map every frame to one)"
            )

    first_epoch, best, history = 0, {"val_mpjpe": math.inf, "epoch": -1}, []
    recipe_changes: list[dict[str, Any]] = []
    init_record = initial[1] if initial is not None else None
    last_path, best_path = out_dir / "last.pt", out_dir / "best.pt"
    if resume:
        state = read_checkpoint(last_path)
        init_record = state.get("init_from")
        if state["model"] != model_name or state["hparams"] != stored_hparams(hparams)[0]:
            raise CheckpointError(
                f"{last_path}: cannot resume: it holds {state['model']!r} with "
                f"other hyper-parameters"
            )
        recipe_changes = resume_changes(last_path, state, recipe, seed, max_batches)
        model.load_state_dict(state["state_dict"])
        optimizer.load_state_dict(state["optimizer"])
        # a run may resume on another device than the one that wrote it (GPU <-> CPU)
        optimizer_for_device(optimizer, device, graphed)
        torch.set_rng_state(state["rng"])
        if "cuda_rng" in state and torch.device(device).type == "cuda":
            torch.cuda.set_rng_state(state["cuda_rng"], torch.device(device))
        first_epoch, best, history = state["epoch"] + 1, state["best"], state["history"]
        for record in history:  # epochs written before they named their device
            record.setdefault("device", (state.get("training") or {}).get("device_name"))

    objective = TrainingObjective(model, entry.task, view=train_src is not train_pos)
    # Some phases leave parameters without gradients (SpecTrHuMS's transformer while the
    # autoencoder trains alone), which DDP must be told to expect.
    net = (
        torch.nn.parallel.DistributedDataParallel(objective, find_unused_parameters=True)
        if dist_info.active
        else objective
    )
    batch_size = recipe["batch_size"]
    if batch_size % dist_info.world:
        raise TrainingError(
            f"batch_size {batch_size} must divide evenly over {dist_info.world} processes"
        )
    # Incomplete last batches are dropped, so every process always gets an equal share.
    steps_per_epoch = max(1, len(train_index) // batch_size)
    if max_batches:
        steps_per_epoch = min(steps_per_epoch, max_batches)
    meta = {
        **_metadata(entry, hparams, bench, dataset, recipe, seed, device, dist_info, view),
        "max_batches": max_batches,
        "recipe_changes": recipe_changes,
        "init_from": init_record,
        "validation": validation_record(dataset, recipe, length, len(val_index)),
    }

    def training_frames():
        """``(frames (N, P, 3), counts (N,))``: every distinct frame of the training windows
        once, in a fixed order, with how many training windows hold it (statistics over every
        frame of every window at a fraction of the cost: sampler all puts each frame in
        ``length`` windows), in batches of at most 2**24 values (64 MiB) so big meshes fit."""
        counts = frame_counts(train_index, [len(a) for a in train_pos], length)
        flat = np.concatenate(counts)
        held = flat > 0
        # each held frame as a one-frame window (sequence, frame) for gather_windows
        frame_index = np.stack(
            [
                np.repeat(np.arange(len(counts)), [len(c) for c in counts]),
                np.concatenate([np.arange(len(c)) for c in counts]),
            ],
            1,
        )[held]
        weights = torch.from_numpy(flat[held])
        batch = max(1, 2**24 // int(np.prod(train_src[0][:1, src_points].shape)))
        for start in range(0, len(frame_index), batch):
            frames = gather_windows(train_src, frame_index[start : start + batch], 1)[
                :, 0, src_points
            ]
            yield (
                torch.from_numpy(np.ascontiguousarray(frames)).to(device),
                weights[start : start + batch].to(device),
            )

    if not objective.view and getattr(model, "training_loss", None) is None:
        check_output(model, model_name, val_pos, val_index, used, t_in, t_out, entry.task, device)
    if dist_info.rank == 0:
        schedule = recipe["schedule"] or {"type": "constant"}
        print(
            f"training {model_name} on {bench.name}: {len(train_index)} training windows "
            f"({recipe['train_sampler']}), {len(val_index)} validation windows; "
            f"{steps_per_epoch} steps of batch {batch_size} an epoch, epochs "
            f"{first_epoch + 1}..{recipe['epochs']}; adam lr {recipe['lr']:g}, schedule "
            f"{schedule}, weight decay {recipe['weight_decay']:g}, gradient clip "
            f"{recipe['grad_clip']}, {recipe['precision']}; seed {seed}; checkpoints in {out_dir}",
            flush=True,
        )
    for epoch in range(first_epoch, recipe["epochs"]):
        # captured anew every epoch: start_epoch may change what a step does (SpecTrHuMS's
        # autoencoder-only phase, then the joint one)
        step_graph = CudaGraphStep(net, model, optimizer, recipe, device) if graphed else None
        # e.g. warm-up phases, statistics over the data; frames in the model's training view
        # where it trains on one
        prepare_epoch(model, epoch, training_frames, view=train_src is not train_pos)
        order = torch.randperm(
            len(train_index), generator=torch.Generator().manual_seed(seed * 100003 + epoch)
        )
        augment_rng = np.random.default_rng([seed, epoch])
        model.train()
        bar = _progress(
            progress and dist_info.rank == 0,
            steps_per_epoch,
            f"{model_name} epoch {epoch + 1}/{recipe['epochs']}",
        )
        started, seen, loss_sum = time.perf_counter(), 0, 0.0
        for step in range(steps_per_epoch):
            lr = learning_rate(
                recipe["schedule"],
                recipe["lr"],
                epoch,
                recipe["epochs"],
                epoch * steps_per_epoch + step,
            )
            set_learning_rate(optimizer, lr)
            rows = order[step * batch_size : (step + 1) * batch_size].numpy()
            rows = rows[dist_info.rank :: dist_info.world]  # this process's share of the batch
            windows = gather_windows(train_src, train_index[rows], length)[:, :, src_points]
            if "time_reversal" in (recipe["augment"] or ()):
                flip = augment_rng.random(len(windows)) < 0.5
                windows[flip] = windows[flip, ::-1]
            windows = torch.from_numpy(np.ascontiguousarray(windows)).to(device)
            where = f"{model_name}: {{loss}} at epoch {epoch + 1}, batch {step + 1}"
            if step_graph is not None:
                loss = step_graph(windows[:, :t_in], windows[:, t_in:], where)
            else:
                loss = training_step(
                    net,
                    model,
                    optimizer,
                    windows[:, :t_in],
                    windows[:, t_in:],
                    recipe,
                    device,
                    where=where,
                )
            seen += len(rows) * dist_info.world
            loss_sum += loss.item()
            if bar is not None:
                bar.update(1)
                bar.set_postfix(
                    loss=f"{loss.item():.3f}",
                    samples_per_s=f"{seen / (time.perf_counter() - started):.0f}",
                )
        if bar is not None:
            bar.close()
        validation = validate(
            model,
            val_pos,
            val_index,
            t_in,
            t_out,
            used,
            device,
            task=entry.task,
            fps=getattr(dataset, "mesh", dataset).fps,  # a JointsView: its mesh's rate
            mesh=bench.representation == "mesh" and view == "mesh",
        )
        val = validation["val_mpjpe"]
        record = {
            "epoch": epoch + 1,
            "lr": lr,
            "train_loss": loss_sum / steps_per_epoch,
            **validation,
            "seconds": time.perf_counter() - started,
            "samples": seen,
            "device": device_name(device),  # a resumed run may move between machines
        }
        history.append(record)
        if dist_info.rank == 0:
            if val < best["val_mpjpe"]:
                best = {"val_mpjpe": val, "epoch": epoch + 1}
            save_epoch(out_dir, meta, model, optimizer, epoch, best, history, recipe, device)
            print(
                f"{model_name} epoch {epoch + 1}: train loss {record['train_loss']:.4f}, "
                f"val MPJPE {val:.2f} mm (best {best['val_mpjpe']:.2f} at epoch "
                f"{best['epoch']}), {record['seconds']:.1f} s; "
                + horizons_text(validation["val_horizons"]),
                flush=True,
            )
        if stop_after_epoch is not None and epoch + 1 >= stop_after_epoch:
            break
    if dist_info.active:
        _write_rank_digest(out_dir, model, dist_info)
    return best_path


def save_epoch(
    out_dir: Path,
    meta: dict[str, Any],
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    epoch: int,
    best: dict[str, Any],
    history: list[dict[str, Any]],
    recipe: dict[str, Any],
    device,
) -> None:
    """The checkpoints of a finished epoch (0-based ``epoch``): ``best.pt`` when it is the best
    so far, and ``last.pt``, the full state ``--resume`` continues from (optimiser, RNG)."""
    summary = _training_summary(recipe, history, best, device)
    if best["epoch"] == epoch + 1:
        # the curve up to this epoch travels too: a run whose best is its last epoch ships
        # one file, and its training plot with it
        save_checkpoint(
            out_dir / "best.pt",
            {
                **meta,
                "state_dict": model.state_dict(),
                "history": list(history),
                "training": summary,
            },
        )
    save_checkpoint(
        out_dir / "last.pt",
        {
            **meta,
            "state_dict": model.state_dict(),
            "optimizer": optimizer.state_dict(),
            "rng": torch.get_rng_state(),
            # dropout on a GPU draws from the device's generator
            **(
                {"cuda_rng": torch.cuda.get_rng_state(torch.device(device))}
                if torch.device(device).type == "cuda"
                else {}
            ),
            "epoch": epoch,
            "best": best,
            "history": history,
            "training": summary,
        },
    )


# The run's budget may grow when it is resumed (each change is recorded with the epoch it took
# effect); every other field of the recipe must stay what the checkpoint says was run.
BUDGET_FIELDS = ("epochs", "max_batches")


def resume_changes(
    path: Path, state: dict[str, Any], recipe: dict[str, Any], seed: int, max_batches: int | None
) -> list[dict[str, Any]]:
    """The checkpoint's recorded recipe changes plus this resume's; refuses any change that is
    not the budget, naming the fields."""
    stored = state.get("recipe") or {}
    given = plain(recipe)
    differ = [
        f"{key}: {stored.get(key, DEFAULT_RECIPE.get(key))!r} in the checkpoint, "
        f"{given.get(key)!r} now"
        for key in sorted(set(stored) | set(given))
        # a key the checkpoint predates held its default then
        if key not in BUDGET_FIELDS and stored.get(key, DEFAULT_RECIPE.get(key)) != given.get(key)
    ]
    if state.get("seed") != seed:
        differ.append(f"seed: {state.get('seed')!r} in the checkpoint, {seed!r} now")
    if differ:
        raise CheckpointError(
            f"{path}: cannot resume with another recipe ({'; '.join(differ)}); "
            f"only the budget (--epochs, --max-batches) may change on "
            f"resume. Resume with the checkpoint's values, or start a new "
            f"run with another --out"
        )
    done = state["epoch"] + 1
    if recipe["epochs"] < done:
        raise CheckpointError(
            f"{path}: cannot resume with --epochs {recipe['epochs']}: the run "
            f"has already trained {done} epochs"
        )
    changes = list(state.get("recipe_changes") or [])
    now = {"epochs": recipe["epochs"], "max_batches": max_batches}
    before = {"epochs": stored.get("epochs"), "max_batches": state.get("max_batches")}
    for field in BUDGET_FIELDS:
        # Checkpoints written before max_batches was recorded cannot say what it was.
        if field in stored or field in state:
            if before[field] != now[field]:
                changes.append(
                    {
                        "field": field,
                        "from": before[field],
                        "to": now[field],
                        "from_epoch": done + 1,
                    }
                )
    return changes


class TrainingObjective(nn.Module):
    """The training loss as a module, so DDP synchronises gradients of any model's own loss:
    with ``view``, the model's ``training_loss_view`` of windows of its training view; else its
    ``training_loss`` if it defines one, else mean MPJPE over predicted frames (a completion
    model is given the window's last frame)."""

    def __init__(self, model: nn.Module, task: str = "prediction", view: bool = False) -> None:
        super().__init__()
        self.model, self.task, self.view = model, task, view

    def forward(self, history: torch.Tensor, future: torch.Tensor) -> torch.Tensor:
        if self.view:  # windows of the model's own training view
            return self.model.training_loss_view(history, future)
        own = getattr(self.model, "training_loss", None)
        if own is not None:
            return own(history, future)
        pred = predict(self.model, history, self.task, future.shape[1], future[:, -1])
        return mpjpe(pred, future).mean()


def check_output(model, model_name, positions, index, used, t_in, t_out, task, device) -> None:
    """Before the first step: the model's prediction for one validation window has the
    contract's shape, or the one-line error ``zoo eval`` gives (else a wrong shape ends training
    in a traceback from inside the loss). Its values are not judged: a model may set itself up
    in its first epoch's hook, which has not run yet."""
    window = torch.from_numpy(gather_windows(positions, index[:1], t_in + t_out)[:, :, used])
    window = window.to(device)
    was_training = model.training
    model.eval()
    try:
        with torch.no_grad():
            pred = predict(model, window[:, :t_in], task, t_out, window[:, -1])
        shape_only = torch.nan_to_num(pred) if isinstance(pred, torch.Tensor) else pred
        checked_prediction(shape_only, (1, t_out, window.shape[2], 3), model_name, 0)
    except EvaluationError as e:
        raise TrainingError(f"{e}; nothing was trained") from None
    finally:
        model.train(was_training)


# Validation horizons logged every epoch beside the mean (the first predicted frame, then the
# short, middle and long horizons of the papers' tables), each with repeat-last's error on the
# same windows as the reference a prediction must beat.
VALIDATION_HORIZONS_MS = (80, 400, 1000)


def validation_frames(t_out: int, fps: float) -> dict[str, int]:
    """``{label: 0-based predicted frame}``: the first predicted frame and the frame nearest
    each of :data:`VALIDATION_HORIZONS_MS` that the window reaches, each labelled with its own
    time (frame ``t`` is at ``t * 1000 / fps`` ms: at 30 fps the frame nearest 80 ms is at 67)."""
    frames = {f"{1000 / fps:.0f} ms (first frame)": 0}
    for ms in VALIDATION_HORIZONS_MS:
        t = int(round(ms * fps / 1000))
        if 1 < t <= t_out:
            frames[f"{t * 1000 / fps:.0f} ms"] = t - 1
    return frames


# The optional model hooks the engine calls (see the module docstring), in groups a model
# defines whole or not at all.
MODEL_HOOKS = {
    "training_loss": ("training_loss",),
    "start_epoch": ("start_epoch",),
    "training_view": ("training_view", "training_view_identity", "training_loss_view"),
}


def check_hooks(model: nn.Module, model_name: str) -> None:
    """Refuse a model that defines part of a group of :data:`MODEL_HOOKS`, naming the rest."""
    for group, names in MODEL_HOOKS.items():
        present = [n for n in names if callable(getattr(model, n, None))]
        if present and len(present) != len(names):
            missing = [n for n in names if n not in present]
            raise TrainingError(
                f"{model_name} ({type(model).__name__}) defines {', '.join(present)} but not "
                f"{', '.join(missing)}: the {group} hooks go together (zoo.train.MODEL_HOOKS)"
            )


def prepare_epoch(model: nn.Module, epoch: int, frames, view: bool = False) -> None:
    """A model's ``start_epoch`` hook for ``epoch``, where it has one, as the engine runs it
    before each epoch: ``frames()`` yields ``(frames, counts)``, in the model's training view
    with ``view`` (only then is the hook given ``view=True``: a model without a view need not
    take it)."""
    if not hasattr(model, "start_epoch"):
        return
    if view:
        model.start_epoch(epoch, frames, view=True)
    else:
        model.start_epoch(epoch, frames)


def training_step(
    objective: nn.Module,
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    history: torch.Tensor,
    future: torch.Tensor,
    recipe: dict[str, Any],
    device,
    where: str = "{loss}",
    check_finite: bool = True,
) -> torch.Tensor:
    """One optimizer step, as the engine runs it and the cost columns time it: the loss
    (``objective``, in the recipe's precision), refused where it is not finite, its gradients,
    the recipe's gradient clip on ``model``'s parameters, and the step. Returns the loss.
    ``where`` says where a non-finite loss happened, ``{loss}`` standing for "loss is <value>".
    ``check_finite=False`` leaves that check to the caller (a CUDA graph cannot stop to look)."""
    with forward_precision(recipe["precision"], device):
        loss = objective(history, future)
    if check_finite:
        refuse_non_finite(loss, where)
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    if recipe.get("grad_clip"):
        nn.utils.clip_grad_norm_(model.parameters(), recipe["grad_clip"])
    optimizer.step()
    return loss


def refuse_non_finite(loss: torch.Tensor, where: str) -> None:
    if not torch.isfinite(loss):
        raise TrainingError(
            where.format(loss=f"loss is {loss.item()}")
            + ": training stopped (lower the lr or check the data)"
        )


def make_optimizer(
    model: nn.Module, recipe: dict[str, Any], device, graphed: bool = False
) -> torch.optim.Optimizer:
    """The recipe's Adam; for a CUDA graph, capturable, its learning rate a device tensor that
    :func:`set_learning_rate` changes in place (a float would be frozen into the graph)."""
    lr = torch.tensor(recipe["lr"], device=device) if graphed else recipe["lr"]
    return torch.optim.Adam(
        model.parameters(), lr=lr, weight_decay=recipe["weight_decay"], capturable=graphed
    )


def optimizer_for_device(optimizer: torch.optim.Optimizer, device, graphed: bool) -> None:
    """After ``load_state_dict``: the loaded groups' learning rate and ``capturable`` as
    :func:`make_optimizer` sets them for this run, the step counters where Adam expects them (on
    the device when capturable, else on the CPU), so a run written on a GPU resumes on a CPU and
    the other way round."""
    for group in optimizer.param_groups:
        lr = float(group["lr"])
        group["lr"] = torch.tensor(lr, device=device) if graphed else lr
        group["capturable"] = graphed
    for state in optimizer.state.values():
        if torch.is_tensor(state.get("step")):
            state["step"] = state["step"].to(device if graphed else "cpu", torch.float32)


def set_learning_rate(optimizer: torch.optim.Optimizer, lr: float) -> None:
    for group in optimizer.param_groups:
        if torch.is_tensor(group["lr"]):
            group["lr"].fill_(lr)
        else:
            group["lr"] = lr


class CudaGraphStep:
    """:func:`training_step` on a CUDA device, captured once as a CUDA graph and replayed.

    A small model's step is thousands of tiny kernels whose launches, not their arithmetic,
    take the time (PGBIG: about 2,000 a step at batch 16); a graph launches them all at once.
    The first :attr:`WARMUP` calls are ordinary steps on a side stream (they build Adam's state
    and let the libraries pick their kernels), the next one captures the step and every call
    from then on copies its batch into the graph's inputs and replays it: the same step, the
    same arithmetic. A non-finite loss is refused after its replay (the step is already taken;
    the checkpoints on disk are the last finished epoch's). The batch must keep its shape, and
    what the step does must not change while it is replayed (the engine captures one per
    epoch). A step that cannot be captured (one that reads a value back to decide what to do)
    is refused, naming why: the run stops there, its last finished epoch on disk."""

    WARMUP = 3

    def __init__(self, objective, model, optimizer, recipe, device) -> None:
        self.args = (objective, model, optimizer)
        self.recipe, self.device = recipe, device
        self.calls = 0
        self.graph: torch.cuda.CUDAGraph | None = None
        self.side = torch.cuda.Stream(device)

    def __call__(self, history: torch.Tensor, future: torch.Tensor, where: str) -> torch.Tensor:
        with torch.cuda.device(self.device):  # cuda:N: capture and replay there, not on cuda:0
            return self._step(history, future, where)

    def _step(self, history: torch.Tensor, future: torch.Tensor, where: str) -> torch.Tensor:
        self.calls += 1
        if self.calls <= self.WARMUP:
            self.side.wait_stream(torch.cuda.current_stream(self.device))
            with torch.cuda.stream(self.side):
                loss = training_step(*self.args, history, future, self.recipe, self.device, where)
            torch.cuda.current_stream(self.device).wait_stream(self.side)
            return loss
        if self.graph is None:
            self.history, self.future = history.clone(), future.clone()
            self.graph = torch.cuda.CUDAGraph()
            try:
                with torch.cuda.graph(self.graph):
                    self.loss = training_step(
                        *self.args,
                        self.history,
                        self.future,
                        self.recipe,
                        self.device,
                        check_finite=False,
                    )
            except RuntimeError as e:
                raise TrainingError(
                    f"{where.split(':')[0]}: its training step cannot be captured as a CUDA "
                    f"graph ({str(e).splitlines()[0][:200]}); train without --cuda-graph"
                ) from None
        else:
            self.history.copy_(history)
            self.future.copy_(future)
        self.graph.replay()
        refuse_non_finite(self.loss, where)
        return self.loss


@torch.no_grad()
def validate(
    model,
    positions,
    index,
    t_in,
    t_out,
    used,
    device,
    batch_size: int = EVAL_BATCH,
    task: str = "prediction",
    fps: float | None = None,
    mesh: bool = False,
) -> dict[str, Any]:
    """Validation errors: ``val_mpjpe``, the mean MPJPE (mm; mean vertex error on a mesh) over
    windows and predicted frames, which picks the best epoch; and, given ``fps``,
    ``val_horizons``: the error at each of :func:`validation_frames`, the model's and
    repeat-last's on the same windows (normalised vertex RMSE on a mesh, MPJPE on joints). A
    completion model (``task``) is given each window's last frame as its final frame."""
    model.eval()
    total, count = 0.0, 0
    per_frame = {who: torch.zeros(t_out, dtype=torch.float64) for who in ("model", "repeat_last")}
    error = vertex_rmse if mesh else mpjpe
    for start in range(0, len(index), batch_size):
        w = torch.from_numpy(
            gather_windows(positions, index[start : start + batch_size], t_in + t_out)[:, :, used]
        ).to(device)
        pred = predict(model, w[:, :t_in], task, t_out, w[:, -1])
        future = w[:, t_in:]
        err = mpjpe(pred, future)
        total += err.sum().item()
        count += err.numel()
        if fps is not None:
            same = w[:, t_in - 1 : t_in].expand_as(future)
            per_frame["model"] += (error(pred, future) if mesh else err).double().sum(0).cpu()
            per_frame["repeat_last"] += error(same, future).double().sum(0).cpu()
    result: dict[str, Any] = {"val_mpjpe": total / count}
    if fps is not None:
        frames = validation_frames(t_out, fps)
        result["val_horizons"] = {
            "metric": "rmse" if mesh else "mpjpe",
            "horizons": list(frames),
            **{
                who: [float(curve[t]) / len(index) for t in frames.values()]
                for who, curve in per_frame.items()
            },
        }
    return result


def horizons_text(horizons: dict[str, Any]) -> str:
    """One log line's worth of :func:`validate`'s ``val_horizons``."""
    digits = 4 if horizons["metric"] == "rmse" else 1
    return f"val {horizons['metric']} " + ", ".join(
        f"{h} {m:.{digits}f} (repeat-last {r:.{digits}f})"
        for h, m, r in zip(horizons["horizons"], horizons["model"], horizons["repeat_last"])
    )


def validation_record(dataset, recipe: dict[str, Any], window: int, windows: int) -> dict[str, Any]:
    """What a run validated on, as its checkpoint and shipped record say: the rule, the
    recordings held out whole and those whose last frames validate, and the number of
    windows."""
    names = [s.name for s in dataset.sequences]
    lengths = [len(sequence_frames(s)) for s in dataset.sequences]
    plan = held_out_frames(dataset, lengths, recipe["val_fraction"], window, recipe["val_split"])
    what: dict[str, Any] = {}
    if whole := [names[i] for i in sorted(plan) if plan[i] == 0]:
        what["recordings"] = whole
    if tails := [names[i] for i in sorted(plan) if plan[i] > 0]:
        what["tails"] = {"fraction": recipe["val_fraction"], "of": tails}
    return {
        "split": recipe["val_split"],
        "of": f"{dataset.name}/{dataset.split} ({len(names)} recordings)",
        **what,
        "windows": int(windows),
    }


def _training_data(dataset) -> dict[str, Any]:
    if hasattr(dataset, "files"):
        return {
            "dataset": dataset.name,
            "split": dataset.split,
            "files": [{"file": f["file"], "sha256": f["sha256"]} for f in dataset.files()],
        }
    mesh = getattr(dataset, "mesh", dataset)  # a JointsView trains on its mesh's regressed joints
    return {
        "dataset": mesh.name,
        "split": mesh.split,
        "recipe_hash": mesh.recipe_hash,
        "content_hash": mesh.content_hash(),
        "topology_hash": mesh.topology.hash,
        **({"points": f"regressor{dataset.num_joints}"} if mesh is not dataset else {}),
    }


def initial_weights(
    path: str | Path, model_name: str, bench: Benchmark, registry: Registry, data_root, dataset
) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """The state dict a new training stage starts from, and what the run records about it: the
    file, its kind and sha256, and the source's own recipe, budget and origin (so a chain of
    stages keeps every budget). The source is a training checkpoint (``.pt``) or shipped weights
    (``.safetensors``, checked against their record's sha256), so anyone can extend a published
    row's training from the repository alone; shipped weights may be float16, and the record
    says so. Refused, naming the file, if it holds another model or was trained for another
    protocol or data (the checks of ``trained_model``)."""
    path = Path(path)
    if path.suffix not in (".pt", ".safetensors"):
        raise TrainingError(
            f"--init-from {path}: expected a training checkpoint (best.pt or "
            f"last.pt) or shipped weights (.safetensors with their .json record)"
        )
    if not path.is_file():
        raise TrainingError(f"--init-from {path}: no such file")
    if path.suffix == ".safetensors":
        state_dict, meta = read_weights(path)
        kind, digest = "weights", meta["sha256"]
    else:
        meta = read_checkpoint(path)
        state_dict, kind, digest = meta["state_dict"], "checkpoint", sha256_file(path)
    if meta["model"] != model_name:
        raise TrainingError(f"--init-from {path}: it holds {meta['model']!r}, not {model_name!r}")
    source = trained_model(
        meta,
        state_dict,
        kind,
        path,
        registry=registry,
        benchmark=bench,
        data_root=data_root,
        dataset=dataset,
    )
    record = {
        "path": repo_relative(path),
        "kind": kind,
        "sha256": digest,
        **({"dtype": meta["dtype"]} if kind == "weights" else {}),
        "hparams": meta["hparams"],
        **{
            k: meta.get(k)
            for k in ("recipe", "max_batches", "recipe_changes", "training", "init_from")
        },
    }
    return source.state_dict(), record


def _metadata(entry, hparams, bench, dataset, recipe, seed, device, dist_info, view):
    stored, context_hashes = stored_hparams(hparams)
    return {
        "format": CHECKPOINT_FORMAT,
        "model": entry.name,
        "origin": model_origin(entry),
        "hparams": stored,
        "context_hashes": context_hashes,
        "protocol": model_protocol(bench, view),
        "training_data": _training_data(dataset),
        "recipe": plain(recipe),
        "seed": seed,
        "code_version": code_version(),
        "torch": str(torch.__version__),
        "world_size": dist_info.world,
    }


def _training_summary(recipe, history, best, device) -> dict[str, Any]:
    return {
        "epochs_run": len(history),
        "epochs_planned": recipe["epochs"],
        "samples_seen": int(sum(h["samples"] for h in history)),
        "seconds": float(sum(h["seconds"] for h in history)),
        "device": str(device),
        "device_name": devices_text(history, device_name(device)),
        "best": best,
        "final_val_mpjpe": history[-1]["val_mpjpe"] if history else None,
    }


def devices_text(history: list[dict[str, Any]], current: str) -> str:
    """The machines a run's epochs ran on: one name, or each with its epochs and minutes
    (``NVIDIA H200: epochs 1-7, 8.7 min; CPU ...: epochs 8-50, ...``). An epoch recorded
    before epochs named their device counts as ``current``'s."""
    spans: list[list] = []  # [name, first epoch, last epoch, seconds]
    for i, h in enumerate(history, 1):
        name = h.get("device") or current
        if spans and spans[-1][0] == name:
            spans[-1][2], spans[-1][3] = i, spans[-1][3] + h["seconds"]
        else:
            spans.append([name, i, i, h["seconds"]])
    if len({s[0] for s in spans}) <= 1:
        return spans[0][0] if spans else current
    return "; ".join(
        f"{name}: epoch{'s' if a != b else ''} {a}{f'-{b}' if a != b else ''}, "
        f"{seconds / 60:.1f} min"
        for name, a, b, seconds in spans
    )


def device_name(device) -> str:
    if str(device).startswith("cuda") and torch.cuda.is_available():
        return torch.cuda.get_device_name(torch.device(device))
    import platform

    # the model and the kernels torch picked (AVX2, AVX512, ...): a budget in minutes, and
    # whether mixed precision pays, depend on both
    model = cpu_info().get("model name") or platform.processor() or "CPU"
    return (
        f"CPU {model} ({platform.machine()}, {torch.backends.cpu.get_cpu_capability()}), "
        f"{os.cpu_count()} cores"
    )


def _write_rank_digest(out_dir: Path, model: nn.Module, dist_info: DistInfo) -> None:
    from zoo.io import atomic_write_text

    atomic_write_text(
        out_dir / "ranks" / f"rank{dist_info.rank}.sha256", weights_digest(model) + "\n"
    )


def _progress(enabled: bool, total: int, desc: str):
    if not enabled:
        return None
    return progress_bar(total=total, desc=desc, unit="batch", leave=False, dynamic_ncols=True)
