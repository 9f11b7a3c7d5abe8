"""The optional hooks a model may define beyond ``forward``, as typed protocols.

The training engine and the evaluator look a model's hooks up once, through :func:`model_hooks`,
which refuses a model that defines part of a group (a training view without its loss, say) with
one line naming what is missing. A hook set to ``None`` on a class counts as absent (a subclass
turning off its parent's hook).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, fields
from typing import Any, Protocol

from torch import Tensor

from zoo.core.errors import ZooError

Frames = Callable[[], Iterable[tuple[Tensor, Tensor]]]


class ModelContractError(ZooError, TypeError):
    """A model that defines part of a group of hooks."""


class OwnLoss(Protocol):
    """The training loss in place of mean MPJPE over the predicted frames."""

    def training_loss(self, history: Tensor, future: Tensor) -> Tensor: ...


class EpochStart(Protocol):
    """Runs before every epoch; ``frames()`` yields ``(frames (N, P, 3), counts (N,))``: every
    distinct frame of the training windows once, with the number of windows holding it (in
    the model's training view, with ``view=True``, where it has one)."""

    def start_epoch(self, epoch: int, frames: Frames) -> None: ...


class TrainingView(Protocol):
    """A representation of the frames the model learns in, computed once and cached
    (SpecTrHuMS: spectral coefficients of the vertices), named by its identity; the loss then
    takes windows of it."""

    def training_view(self, frames: Tensor) -> Tensor: ...

    def training_view_identity(self) -> dict[str, Any]: ...

    def training_loss_view(self, history: Tensor, future: Tensor) -> Tensor: ...


class Rollout(Protocol):
    """Long-term prediction of ``frames`` frames by the model's own autoregression, in place of
    the evaluator's (feeding ``forward``'s predictions back)."""

    def rollout(self, history: Tensor, frames: int) -> Tensor: ...


class AutoencoderFloor(Protocol):
    """The ground truth passed through the model's own encoder and decoder: the evaluator scores
    it as the model's floor (rows ``<model>:autoencoder``)."""

    def autoencoder_floor(self, frames: Tensor) -> Tensor: ...


@dataclass(frozen=True)
class Hooks:
    """Which hooks a model defines (each field: its protocol)."""

    training_loss: bool = False
    start_epoch: bool = False
    training_view: bool = False
    rollout: bool = False
    autoencoder_floor: bool = False


PROTOCOLS: dict[str, type] = {
    "training_loss": OwnLoss,
    "start_epoch": EpochStart,
    "training_view": TrainingView,
    "rollout": Rollout,
    "autoencoder_floor": AutoencoderFloor,
}


def protocol_methods(protocol: type) -> tuple[str, ...]:
    """The methods a hook protocol declares, in declaration order."""
    return tuple(n for n, value in vars(protocol).items() if callable(value) and n[0] != "_")


def model_hooks(model: Any, name: str | None = None) -> Hooks:
    """The hooks ``model`` defines, checked: a model defining some but not all methods of a
    protocol is refused, naming the ones it lacks."""
    found = {}
    for field in fields(Hooks):
        methods = protocol_methods(PROTOCOLS[field.name])
        present = [m for m in methods if callable(getattr(model, m, None))]
        if present and len(present) != len(methods):
            missing = [m for m in methods if m not in present]
            who = f"{name} ({type(model).__name__})" if name else type(model).__name__
            protocol = PROTOCOLS[field.name].__name__
            raise ModelContractError(
                f"{who} defines {', '.join(present)} but not {', '.join(missing)}: the "
                f"{field.name} hooks go together (zoo.models.hooks.{protocol})"
            )
        found[field.name] = bool(present)
    return Hooks(**found)


__all__ = [
    "AutoencoderFloor",
    "EpochStart",
    "Hooks",
    "ModelContractError",
    "OwnLoss",
    "Rollout",
    "TrainingView",
    "model_hooks",
]
