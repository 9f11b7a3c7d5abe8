"""The training recipe: a registry entry's ``train`` mapping, checked, and its learning-rate
schedule."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import torch

from zoo.core.errors import TrainingError


@dataclass(frozen=True)
class Recipe:
    """How a model trains: a registry entry's ``train`` mapping over these defaults, checked by
    :func:`training_recipe`. Checkpoints and weights records keep it as :meth:`as_dict`."""

    optimizer: str = "adam"
    lr: float = 1e-3
    weight_decay: float = 0.0
    batch_size: int = 32
    epochs: int = 10
    grad_clip: float | None = None
    schedule: dict[str, Any] = field(default_factory=lambda: {"type": "constant"})
    augment: list[str] = field(default_factory=list)
    val_fraction: float = 0.1
    # Which frames validate (held_out_frames): "auto", the last val_fraction of every sequence
    # where all are long enough (H3.6M), else the last val_fraction of the sequences (cloth; on
    # CMU the last 3 recordings, all of them walking); "tails", the last val_fraction of every
    # recording long enough to spare a window, the shorter ones trained on whole; "actions",
    # "tails" and, for an action none of whose recordings can spare a tail, the end of its
    # longest recording, so that every action validates and none is held out whole;
    # "recordings", whole recordings spread over the data (every k-th by name).
    val_split: str = "auto"
    train_sampler: str = "all"
    # Validation windows of the held-out frames: a sparser sampler (e.g. stride5_strict) cuts
    # the cost of validating large meshes every epoch.
    val_sampler: str = "all"
    # "bfloat16": the training loss (forward) under torch.autocast; weights, optimiser,
    # validation and evaluation stay float32.
    precision: str = "float32"
    # Early stopping: the run ends once this many epochs have passed without a new best
    # validation error (MSR-GCN's code trains until its loss stops improving); None: never.
    patience: int | None = None

    def as_dict(self) -> dict[str, Any]:
        """The recipe as records keep it (plain data, every field)."""
        return asdict(self)

    @classmethod
    def of(cls, recorded: dict[str, Any]) -> Recipe:
        """A recorded recipe (a checkpoint's or weights record's), fields it predates at their
        defaults; not checked (it ran)."""
        return cls(**{k: v for k, v in recorded.items() if k in _FIELDS})


DEFAULT_RECIPE: dict[str, Any] = Recipe().as_dict()
_FIELDS = frozenset(DEFAULT_RECIPE)
PRECISIONS = {"float32": None, "bfloat16": torch.bfloat16}
VAL_SPLITS = ("auto", "tails", "actions", "recordings")
SCHEDULES = ("constant", "step", "cosine", "multistep", "epoch_milestones")
AUGMENTATIONS = ("time_reversal",)


def training_recipe(entry_train: dict[str, Any], overrides: dict[str, Any] | None = None) -> Recipe:
    """A registry entry's recipe (``train``) with ``overrides``, over the defaults, checked."""
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
    patience = recipe["patience"]
    if patience is not None and (
        isinstance(patience, bool) or not isinstance(patience, int) or patience < 1
    ):
        raise TrainingError(
            f"training recipe: patience must be a positive integer (epochs without a new best "
            f"validation error before the run stops) or null, got {patience!r}"
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
    if schedule["type"] == "epoch_milestones":
        milestones = schedule.get("milestones")
        if not (
            isinstance(milestones, list)
            and milestones
            and all(isinstance(m, int) and not isinstance(m, bool) and m >= 1 for m in milestones)
            and milestones == sorted(milestones)
            and _positive_number(schedule.get("gamma"))
        ):
            raise TrainingError(
                f"training recipe: an epoch_milestones schedule needs milestones (increasing "
                f"epochs >= 1 after which the rate is multiplied by gamma) and gamma (a number "
                f"> 0); got {schedule!r}"
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
    return Recipe(**recipe)


def patience_spent(recipe: Recipe, epochs_done: int, best_epoch: int) -> bool:
    """Whether a run that has finished ``epochs_done`` epochs, its best validation at
    ``best_epoch`` (1-based), stops early under the recipe's ``patience``."""
    return recipe.patience is not None and epochs_done - max(best_epoch, 0) >= recipe.patience


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
    if kind == "epoch_milestones":  # GGMotion: x gamma after each milestone epoch (MultiStepLR)
        return base_lr * schedule["gamma"] ** sum(epoch >= m for m in schedule["milestones"])
    if kind == "multistep":  # siMLPe: lrs[i] from optimizer step milestones_steps[i-1] on
        lrs, milestones = schedule["lrs"], schedule["milestones_steps"]
        return lrs[sum(step >= m for m in milestones)]
    raise TrainingError(f"schedule type {kind!r} unknown")
