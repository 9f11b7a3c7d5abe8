"""The training recipe: a registry entry's ``train`` mapping, its schema (the :class:`Recipe`
dataclass, read through :mod:`zoo.core.schema`), and its learning-rate schedule."""

from __future__ import annotations

import math
from dataclasses import asdict, field
from typing import Annotated, Any, Literal, get_args

import pydantic
import torch
from pydantic import AfterValidator, BeforeValidator, ConfigDict, Field, StrictFloat, StrictInt
from typing_extensions import NotRequired, TypedDict, get_type_hints

from zoo.core.errors import TrainingError
from zoo.core.schema import validated
from zoo.protocol.benchmark import ValSplit

Count = Annotated[StrictInt, Field(ge=0)]
PositiveInt = Annotated[StrictInt, Field(ge=1)]
Rate = Annotated[StrictFloat, Field(ge=0, allow_inf_nan=False)]
# a factor or limit: a negative gradient limit would flip the gradients' sign in clip_grad_norm_
Positive = Annotated[StrictFloat, Field(gt=0, allow_inf_nan=False)]


def _increasing(values: list) -> list:
    if values != sorted(values):
        raise ValueError(f"expected increasing epochs, got {values}")
    return values


@pydantic.with_config(ConfigDict(extra="forbid"))
class _Warmup(TypedDict):
    # Any schedule may add warmup_steps: N: the rate grows linearly from lr / N over the first N
    # optimizer steps (a post-norm transformer trained at a high rate needs it).
    warmup_steps: NotRequired[Count]


class ConstantSchedule(_Warmup):
    type: Literal["constant"]


class StepSchedule(_Warmup):
    """SPGSN's: x ``gamma`` every ``every_epochs``; ``offset_epochs``: decays counted as if that
    many epochs had run before the first (LTD's and PGBIG's code decay at the start of an epoch,
    the first one included for PGBIG)."""

    type: Literal["step"]
    every_epochs: PositiveInt
    gamma: Positive
    offset_epochs: NotRequired[Count]


class CosineSchedule(_Warmup):
    """SpecTrHuMS's: cosine from lr to ``min_lr`` over the run, per epoch."""

    type: Literal["cosine"]
    min_lr: NotRequired[Rate]


class EpochMilestonesSchedule(_Warmup):
    """GGMotion's: x ``gamma`` after each milestone epoch (PyTorch's MultiStepLR)."""

    type: Literal["epoch_milestones"]
    milestones: Annotated[list[PositiveInt], Field(min_length=1), AfterValidator(_increasing)]
    gamma: Positive


class MultistepSchedule(_Warmup):
    """siMLPe's: ``lrs[i]`` from optimizer step ``milestones_steps[i-1]`` on."""

    type: Literal["multistep"]
    milestones_steps: list[Count]
    lrs: Annotated[list[Rate], Field(min_length=1)]


Schedule = Annotated[
    ConstantSchedule | StepSchedule | CosineSchedule | EpochMilestonesSchedule | MultistepSchedule,
    Field(discriminator="type"),
]


@pydantic.dataclasses.dataclass(frozen=True, config=ConfigDict(extra="forbid"))
class Recipe:
    """How a model trains: a registry entry's ``train`` mapping over these defaults, checked as
    :func:`training_recipe` reads it. Checkpoints and weights records keep it as
    :meth:`as_dict`."""

    optimizer: Literal["adam"] = "adam"
    # lr 0 is allowed: it runs the whole pipeline with frozen weights (tests use it).
    lr: Rate = 1e-3
    weight_decay: Rate = 0.0
    batch_size: PositiveInt = 32
    epochs: PositiveInt = 10
    grad_clip: Positive | None = None  # None: no clipping
    # no schedule (null) is a constant rate
    schedule: Schedule = field(default_factory=lambda: {"type": "constant"})
    augment: Annotated[
        list[Literal["time_reversal"]], BeforeValidator(lambda v: [] if v is None else v)
    ] = field(default_factory=list)
    val_fraction: Annotated[StrictFloat, Field(gt=0, lt=0.5)] = 0.1
    # Which frames validate (held_out_frames): "auto", the last val_fraction of every sequence
    # where all are long enough (H3.6M), else the last val_fraction of the sequences (cloth; on
    # CMU the last 3 recordings, all of them walking); "tails", the last val_fraction of every
    # recording long enough to spare a window, the shorter ones trained on whole; "actions",
    # "tails" and, for an action none of whose recordings can spare a tail, the end of its
    # longest recording, so that every action validates and none is held out whole;
    # "recordings", whole recordings spread over the data (every k-th by name).
    val_split: ValSplit = "auto"
    train_sampler: str = "all"
    # Validation windows of the held-out frames: a sparser sampler (e.g. stride5_strict) cuts
    # the cost of validating large meshes every epoch.
    val_sampler: str = "all"
    # "bfloat16": the training loss (forward) under torch.autocast; weights, optimiser,
    # validation and evaluation stay float32. "auto": bfloat16 on a CPU that multiplies it
    # natively, float32 elsewhere (docs/training.md's study); a run records which it took.
    precision: Literal["float32", "bfloat16", "auto"] = "float32"
    # Early stopping: the run ends once this many epochs have passed without a new best
    # validation error (MSR-GCN's code trains until its loss stops improving); None: never.
    patience: PositiveInt | None = None

    @pydantic.field_validator("schedule", mode="before")
    @classmethod
    def _schedule_type(cls, schedule: Any) -> Any:
        if schedule is None:
            return {"type": "constant"}
        if isinstance(schedule, dict) and "type" not in schedule:
            raise ValueError(
                f"a schedule names its type, one of {', '.join(SCHEDULES)} (YAML needs a space "
                f"after each colon: '{{type: step, every_epochs: 2, gamma: 0.96}}'), got "
                f"{schedule!r}"
            )
        return schedule

    @pydantic.model_validator(mode="after")
    def _multistep_rates(self) -> Recipe:
        schedule = self.schedule
        if schedule["type"] != "multistep":
            return self
        lrs, milestones = schedule["lrs"], schedule["milestones_steps"]
        if len(lrs) != len(milestones) + 1:
            raise ValueError(
                f"a multistep schedule needs milestones_steps [s1, ...] and one more rate in "
                f"lrs [lr0, lr1, ...], got {schedule!r}"
            )
        # The schedule's own rates are what runs; a different lr would be recorded, not used.
        if self.lr != lrs[0]:
            raise ValueError(
                f"lr {self.lr!r} is not what runs: the multistep schedule sets its own rates "
                f"lrs = {lrs}; change the schedule instead (--train-set 'schedule={{type: "
                f"multistep, milestones_steps: [...], lrs: [...]}}') and give lr equal to its "
                f"first rate"
            )
        return self

    def as_dict(self) -> dict[str, Any]:
        """The recipe as records keep it (plain data, every field)."""
        return asdict(self)

    @classmethod
    def of(cls, recorded: dict[str, Any]) -> Recipe:
        """A recorded recipe (a checkpoint's or weights record's), fields it predates at their
        defaults; not checked again (it ran, perhaps under rules since tightened)."""
        recipe = object.__new__(cls)
        for name, value in {**DEFAULT_RECIPE, **recorded}.items():
            if name in _FIELDS:
                object.__setattr__(recipe, name, value)
        return recipe


DEFAULT_RECIPE: dict[str, Any] = Recipe().as_dict()
_FIELDS = frozenset(DEFAULT_RECIPE)
PRECISIONS = {"float32": None, "bfloat16": torch.bfloat16}
VAL_SPLITS = get_args(ValSplit)
# each schedule's `type`, from the union the recipe reads them through
SCHEDULES = tuple(
    get_args(get_type_hints(member)["type"])[0] for member in get_args(get_args(Schedule)[0])
)


def training_recipe(
    entry_train: dict[str, Any],
    overrides: dict[str, Any] | None = None,
    path=None,
    at: tuple = (),
    what: str = "",
) -> Recipe:
    """A registry entry's recipe (``train``) with ``overrides``, over the defaults, checked; a
    refusal names the field, and the line of ``path`` (the registry file, the entry's recipe
    under the keys ``at``) where the recipe came from one; ``what`` starts the message."""
    recipe = {**DEFAULT_RECIPE, **entry_train, **(overrides or {})}
    return validated(Recipe, recipe, path, at, f"{what}training recipe: ", TrainingError)


def patience_spent(recipe: Recipe, epochs_done: int, best_epoch: int) -> bool:
    """Whether a run that has finished ``epochs_done`` epochs, its best validation at
    ``best_epoch`` (1-based), stops early under the recipe's ``patience``."""
    return recipe.patience is not None and epochs_done - max(best_epoch, 0) >= recipe.patience


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
