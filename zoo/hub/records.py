"""What a trained model's files say about the run that trained it, typed, written from these
classes and read back into them, so each field is named once.

:class:`RunRecord` is in every training checkpoint (``best.pt``, ``last.pt``): the model and
where its class comes from, its hyper-parameters, the protocol and data it trained for, the
recipe, seed, budget changes, the stage it started from and what validated it.
:class:`WeightsRecord` is the JSON file beside shipped weights: the run's record, and what export
adds (the file, its sha256 and storage dtype, the parameter count, the training summary and
validation curve, the checkpoint it came from, and any later upgrade of the record itself).
"""

from __future__ import annotations

import types
import typing
from dataclasses import MISSING, asdict, dataclass, field, fields
from typing import Any

from zoo.core.errors import ZooError

RECORD_FORMAT = "motion-zoo-weights/1"


class WeightsError(ZooError, ValueError):
    """Shipped weights or their record that cannot be used; the message names the file and, for
    a record, the field."""


@dataclass
class RunRecord:
    """The record of a training run, the same in each of its checkpoints (and in the weights
    exported from them)."""

    model: str
    hparams: dict[str, Any]
    protocol: dict[str, Any]
    origin: dict[str, Any] | None = None
    context_hashes: dict[str, str] = field(default_factory=dict)
    training_data: dict[str, Any] | None = None
    recipe: dict[str, Any] | None = None
    seed: int | None = None
    code_version: str | None = None
    torch: str | None = None
    # data-parallel processes (None: not recorded, as in weights exported before the record
    # was typed)
    world_size: int | None = None
    max_batches: int | None = None
    recipe_changes: list[dict[str, Any]] = field(default_factory=list)
    init_from: dict[str, Any] | None = None
    validation: dict[str, Any] | None = None

    @classmethod
    def of_checkpoint(cls, payload: dict[str, Any]) -> RunRecord:
        """The run record a checkpoint's contents hold (``RunRecord``'s fields; the weights,
        optimiser and history beside them are not part of it)."""
        names = {f.name for f in fields(RunRecord)}
        return cls(**{k: v for k, v in payload.items() if k in names})


@dataclass(kw_only=True)
class WeightsRecord(RunRecord):
    """The record beside shipped weights (``<label>.json``): the run's record and the export's."""

    label: str
    benchmark: str
    file: str
    sha256: str
    dtype: str
    parameters: int
    # budget (epochs, samples, seconds), device and precision of the run
    training: dict[str, Any] = field(default_factory=dict)
    # the validation curve (exported from a last.pt; None from a best.pt of older exports)
    history: list[dict[str, Any]] | None = None
    checkpoint: str | None = None
    # later changes to the record itself (no trained tensor changed), oldest first
    upgrades: list[dict[str, Any]] = field(default_factory=list)
    # weights made elsewhere (an authors' .pth) and imported: whose, each source file's name and
    # sha256, where they came from, the key map, the licence (zoo.hub.foreign)
    imported: dict[str, Any] | None = None

    @classmethod
    def from_json(cls, data: Any, source: str) -> WeightsRecord:
        """The record in ``data`` (a parsed JSON file), checked field by field; ``source`` names
        the file in the one-line error."""
        if not isinstance(data, dict) or data.get("format") != RECORD_FORMAT:
            found = data.get("format") if isinstance(data, dict) else None
            raise WeightsError(
                f"weights record {source}: format {found!r}, expected {RECORD_FORMAT!r}"
            )
        values = {k: v for k, v in data.items() if k != "format"}
        hints = typing.get_type_hints(cls)
        unknown = sorted(set(values) - set(hints))
        if unknown:
            raise WeightsError(
                f"weights record {source}: unknown field(s) {', '.join(unknown)} (a record of "
                f"{RECORD_FORMAT} has {', '.join(hints)})"
            )
        required = [f.name for f in fields(cls) if _required(f)]
        missing = [name for name in required if name not in values]
        if missing:
            raise WeightsError(f"weights record {source}: field(s) {', '.join(missing)} missing")
        for name, value in values.items():
            allowed = _runtime_types(hints[name])
            if not isinstance(value, allowed) or (isinstance(value, bool) and int in allowed):
                expected = " or ".join(sorted(t.__name__ for t in allowed))
                raise WeightsError(
                    f"weights record {source}: field {name} is {type(value).__name__} "
                    f"{value!r:.60}, expected {expected}"
                )
        return cls(**values)

    def to_json(self) -> dict[str, Any]:
        """The record as its JSON file holds it: what identifies the file first, then the
        run's record (``world_size`` where recorded, ``upgrades`` where there are some)."""
        values = asdict(self)
        data = {"format": RECORD_FORMAT, **{name: values.pop(name) for name in _HEAD}, **values}
        for name in ("world_size", "upgrades", "imported"):
            if not data[name]:
                del data[name]
        return data

    @property
    def epochs_by_steps(self) -> list[tuple[int, dict[str, Any]]]:
        """``(optimizer steps at its end, epoch record)`` of each epoch of the training history
        (empty where the record holds none, or no batch size to count steps by)."""
        batch = (self.recipe or {}).get("batch_size")
        out, steps = [], 0
        for epoch in (self.history or []) if batch else []:
            steps += epoch["samples"] // batch
            out.append((steps, epoch))
        return out


# the fields a weights record's file begins with, after its format
_HEAD = ("label", "model", "benchmark", "file", "sha256", "dtype", "parameters")


def _required(f) -> bool:
    return f.default is MISSING and f.default_factory is MISSING


def _runtime_types(hint) -> tuple[type, ...]:
    """The classes a JSON value of type ``hint`` may be: ``dict[str, Any] | None`` gives
    ``(dict, NoneType)``; ``float`` admits an ``int`` (JSON writes 2.0 as 2)."""
    if hint is Any:
        return (object,)
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return tuple(t for arg in typing.get_args(hint) for t in _runtime_types(arg))
    if hint is type(None):
        return (type(None),)
    base = typing.get_origin(hint) or hint
    return (int, float) if base is float else (base,)
