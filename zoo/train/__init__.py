"""The one training engine, shared by every trainable model.

A recipe (:mod:`zoo.models.recipe`, a registry entry's ``train`` mapping) says how to train;
the split (:mod:`.split`) which frames train and which validate; a step (:mod:`.step`) is what
the cost columns time too; validation (:mod:`.validation`) picks the best epoch; the state
(:mod:`.state`) is what ``best.pt`` and ``last.pt`` hold; the loop (:mod:`.loop`) runs them,
seeded, so that a resumed run ends with the weights of an uninterrupted one, carried out as
its options (:mod:`.options`: seed, device, folders, resume or a new stage, time limits) say.
The model hooks it calls: :mod:`zoo.models.hooks`. docs/training.md says how to train and what
each recipe ran. It imports the layers below it (evaluation, hub, store, models, protocol, data,
core).
"""

from __future__ import annotations

import importlib

# name -> the module that defines it (of this package unless dotted), loaded on first use (so
# that importing zoo.train.step, as the cost columns do, does not load the loop)
_EXPORTS = {
    "train": "loop",
    "RunOptions": "options",
    "DEFAULT_RECIPE": "zoo.models.recipe",
    "PRECISIONS": "zoo.models.recipe",
    "VAL_SPLITS": "zoo.models.recipe",
    "learning_rate": "zoo.models.recipe",
    "training_recipe": "zoo.models.recipe",
    "held_out_frames": "split",
    "held_out_recordings": "split",
    "split_train_val": "split",
    "training_view_arrays": "split",
    "cpu_has_native_bfloat16": "host",
    "cpu_info": "host",
    "device_name": "host",
    "CudaGraphStep": "step",
    "TrainingObjective": "step",
    "make_optimizer": "step",
    "prepare_epoch": "step",
    "set_learning_rate": "step",
    "training_step": "step",
    "validate": "validation",
    "save_epoch": "state",
}

__all__ = sorted([*_EXPORTS, "TrainingError"])


def __getattr__(name: str):
    if name == "TrainingError":
        from zoo.core.errors import TrainingError

        return TrainingError
    if name in _EXPORTS:
        module = _EXPORTS[name]
        module = module if "." in module else f"{__name__}.{module}"
        return getattr(importlib.import_module(module), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
