"""Where a model comes from: a registry name (with overridden hyper-parameters), a training
checkpoint, or shipped weights. One place builds or loads it for a benchmark, with its label,
provenance, recipe and the model part of its results' identity; the command line, the Python
API, the leaderboard, training and rendering all go through it.

    source = ModelSource.of(checkpoint="checkpoints/cmu/mlp/last.pt")
    loaded = source.load(registry, bench, dataset)     # loaded.model, loaded.label == "mlp@last"
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from torch import nn

from zoo.core.errors import ZooError
from zoo.hub.build import model_args_for
from zoo.hub.records import RunRecord
from zoo.models.registry import ModelEntry, Registry
from zoo.protocol.views import View


class SourceError(ZooError, ValueError):
    pass


@dataclass(frozen=True)
class ModelSource:
    """One of: ``name`` (a registry model, ``overrides`` replacing hyper-parameters),
    ``checkpoint`` (a ``best.pt`` / ``last.pt`` of ``zoo train``) or ``weights`` (shipped
    ``.safetensors``). ``label`` names its rows (default: see :meth:`default_label`)."""

    name: str | None = None
    checkpoint: Path | None = None
    weights: Path | None = None
    overrides: dict[str, Any] = field(default_factory=dict)
    label: str | None = None

    @classmethod
    def of(
        cls,
        model: str | None = None,
        checkpoint: str | Path | None = None,
        weights: str | Path | None = None,
        overrides: dict[str, Any] | None = None,
        label: str | None = None,
    ) -> ModelSource:
        """A source from command-line style arguments, refusing combinations that mean
        nothing (weights and a checkpoint; overrides of trained hyper-parameters)."""
        overrides = dict(overrides or {})
        if weights and checkpoint:
            raise SourceError("give --weights or --checkpoint, not both")
        if (weights or checkpoint) and overrides:
            kind = "shipped weights'" if weights else "a trained checkpoint's"
            raise SourceError(f"--set cannot change {kind} hyper-parameters")
        if not (model or weights or checkpoint):
            raise SourceError("give --model NAME, --checkpoint PATH or --weights PATH")
        if label is not None:
            from zoo.store.layout import check_label

            check_label(label)
        return cls(
            name=model,
            checkpoint=Path(checkpoint) if checkpoint else None,
            weights=Path(weights) if weights else None,
            overrides=overrides,
            label=label,
        )

    @property
    def kind(self) -> str:
        return "weights" if self.weights else "checkpoint" if self.checkpoint else "registry"

    def record(self) -> RunRecord | None:
        """The checkpoint's or weights' own record (model, hparams, protocol, ...)."""
        if self.weights:
            from zoo.hub.weights import read_weights_record

            return read_weights_record(self.weights)
        if self.checkpoint:
            from zoo.hub.checkpoints import read_checkpoint

            return RunRecord.of_checkpoint(read_checkpoint(self.checkpoint))
        return None

    def benchmark(self) -> str | None:
        """The benchmark a trained model was trained for (its default benchmark), if any."""
        record = self.record()
        return record.protocol["benchmark"] if record else None

    def default_label(self, model_name: str) -> str:
        """The row label: ``--label``; else a shipped file's label (its name), a checkpoint's
        (``<model>`` or ``<model>@last``), or for overridden hyper-parameters
        ``<model>+key=value`` (never the plain model's label)."""
        if self.label:
            return self.label
        if self.weights:
            # the file's label, or for an entry that runs these weights (weights_of) its own
            # name with the file's @suffix: never the row of the model the file holds
            recorded = self.record().model
            if model_name != recorded:
                _, at, suffix = self.weights.stem.partition("@")
                return f"{model_name}{at}{suffix}"
            return self.weights.stem
        if self.checkpoint:
            from zoo.hub.weights import checkpoint_label

            return checkpoint_label(self.checkpoint, model_name)
        from zoo.store.layout import variant_label

        return variant_label(model_name, self.overrides)

    def _entry_named_by_file(self, registry: Registry) -> str | None:
        """The entry a weights file's name names where it is not the model it holds: a link
        ``<entry>[@last].safetensors`` to the weights of the model that entry runs (registry
        ``weights_of``), so the file scores as that entry, never as the model it holds."""
        named = self.weights.stem.partition("@")[0]
        entry = registry.entries.get(named)
        if entry is not None and entry.weights_of == self.record().model:
            return named
        return None

    def load(self, registry: Registry, bench, dataset=None, data_root=None) -> LoadedModel:
        """The model, built or loaded for ``bench`` (checked against what it was trained for),
        in eval mode, with what its results record."""
        from zoo.core.io import sha256_file
        from zoo.hub.checkpoints import (
            checkpoint_provenance,
            load_checkpoint,
            load_weights,
            stored_hparams,
        )
        from zoo.hub.weights import weights_provenance

        if self.kind == "registry":
            entry = registry.get(self.name)
            view, hparams = model_args_for(
                registry,
                self.name,
                bench,
                data_root=data_root,
                dataset=dataset,
                overrides=self.overrides,
            )
            model = registry.create_model(self.name, **hparams)
            plain, hashes = stored_hparams(hparams)
            return LoadedModel(
                model=model,
                entry=entry,
                view=view,
                label=self.default_label(entry.name),
                provenance={**entry.provenance(), "hparams": plain},
                recipe=entry.train or None if entry.trainable else None,
                hparams={**plain, **({"context_hashes": hashes} if hashes else {})},
                trained=None,
            )
        name = self.name
        if self.kind == "weights" and name is None:
            name = self._entry_named_by_file(registry)
        if self.kind == "weights":
            model, record = load_weights(
                self.weights,
                registry=registry,
                benchmark=bench,
                data_root=data_root,
                dataset=dataset,
                model_name=name,
            )
            provenance = weights_provenance(self.weights, record)
            trained = {"kind": "weights", "sha256": record.sha256}
        else:
            model, payload = load_checkpoint(
                self.checkpoint,
                registry=registry,
                benchmark=bench,
                data_root=data_root,
                dataset=dataset,
                model_name=name,
            )
            provenance = checkpoint_provenance(self.checkpoint, payload)
            trained = {"kind": "checkpoint", "sha256": sha256_file(self.checkpoint)}
            record = RunRecord.of_checkpoint(payload)
        # the recorded model, or an entry that runs its weights (registry weights_of)
        entry = registry.get(name or record.model)
        hashes = record.context_hashes
        return LoadedModel(
            model=model,
            entry=entry,
            view=bench.view_for(entry.representation),
            label=self.default_label(entry.name),
            provenance={**entry.provenance(), **provenance},
            recipe=record.recipe,
            hparams={**record.hparams, **({"context_hashes": hashes} if hashes else {})},
            trained=trained,
        )


@dataclass
class LoadedModel:
    """A model ready to evaluate, and what its results record about it."""

    model: nn.Module
    entry: ModelEntry
    view: View
    label: str
    provenance: dict[str, Any]
    recipe: dict[str, Any] | None
    hparams: dict[str, Any]
    trained: dict[str, Any] | None

    @property
    def frames_read(self) -> int | None:
        """The observed frames it was built to read, the last of those a benchmark gives
        (fewer where it was trained on the benchmark this one takes weights from)."""
        return self.hparams.get("input_frames")

    def model_identity(self) -> dict[str, Any]:
        from zoo.core.io import registry_record
        from zoo.models.registry import files_read_while_built
        from zoo.store.identity import files_read_record

        reads = files_read_record(
            files_read_while_built(self.model), self.hparams, self.entry.source
        )
        return {
            "name": self.entry.name,
            "class": self.entry.class_name,
            "registry": registry_record(self.entry.source),
            **({"replaces": self.entry.replaces} if self.entry.replaces else {}),
            "hparams": self.hparams,
            # the data files it read while built, and those its hyper-parameters name
            **({"reads": reads} if reads else {}),
        }

    def identity(self, bench, protocol_id: str, code: dict[str, Any]) -> dict[str, Any]:
        """Its results' identity under ``protocol_id`` of ``bench``; ``code``: the code part, as
        the evaluation layer computes it (zoo.evaluation.pipeline.row_code)."""
        from zoo.store.identity import result_identity

        return result_identity(
            benchmark=bench.name,
            protocol_id=protocol_id,
            label=self.label,
            model=self.model_identity(),
            trained=self.trained,
            code=code,
        )

    def warn_if_untrained(self) -> None:
        if (self.entry.trainable or self.entry.weights_of) and self.trained is None:
            print(
                f"warning: {self.entry.name} is "
                + (f"{self.entry.weights_of}'s weights" if self.entry.weights_of else "trainable")
                + " and no --checkpoint or --weights was given: evaluating its untrained "
                "initialisation",
                file=sys.stderr,
            )


def object_identity(
    model: nn.Module, label: str, bench, protocol_id: str, code: dict[str, Any]
) -> dict[str, Any]:
    """The identity of results of a model object handed over directly (no registry): its
    class, its printed structure and plain attributes (what a constructor's hyper-parameters
    usually become) and a hash of its weights; ``code`` as for :meth:`LoadedModel.identity`."""
    from zoo.hub.checkpoints import weights_digest
    from zoo.store.identity import result_identity

    cls = type(model)
    settings = {
        f"{name}.{key}" if name else key: value
        for name, module in model.named_modules()
        for key, value in vars(module).items()
        if not key.startswith("_")
        and key != "training"
        and isinstance(value, (bool, int, float, str, type(None)))
    }
    return result_identity(
        benchmark=bench.name,
        protocol_id=protocol_id,
        label=label,
        model={
            "name": None,
            "class": cls.__qualname__,
            "registry": None,
            "hparams": {"repr": repr(model), "attributes": settings},
        },
        trained={"kind": "object", "sha256": weights_digest(model)},
        code=code,
    )
