"""State dicts and the models they are for: whether one fits a model, said in a line
(:func:`fit_summary`), and what a command told a state dict from outside the zoo where it reads
the zoo's own files says (:func:`foreign_pointer`). Below the checkpoint and weights readers and
the import of outside weights (:mod:`zoo.hub.foreign`), which all use them.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

# the suffixes of state dicts saved by torch.save in the field's code
FOREIGN_SUFFIXES = (".pth", ".pt", ".bin", ".ckpt", ".tar")


def foreign_pointer(path: str | Path, flag: str) -> str:
    """What a command given an outside state dict where it wants the zoo's own file says."""
    if flag == "--weights" and Path(path).name in ("best.pt", "last.pt"):
        return f"{path} is a training checkpoint: score it with --checkpoint {path}"
    return (
        f"{path} is a state dict from outside the zoo, not what {flag} reads; import it first: "
        f"zoo weights import {path} --model NAME --benchmark BENCH [--key-map MAP.yaml] "
        f"(docs/adding-a-model.md, 'Weights from elsewhere'), then pass the .safetensors it "
        f"writes as --weights"
    )


def fit_summary(model: nn.Module, state: dict[str, torch.Tensor], shown: int = 4) -> str | None:
    """None where ``state`` fits ``model`` key for key and shape for shape; else one short
    paragraph: how many keys are missing and unexpected, the first few of each, and the shapes
    that differ (never torch's list of every key)."""
    own = model.state_dict()
    missing = [k for k in own if k not in state]
    unexpected = [k for k in state if k not in own]
    shapes = [
        f"{k} {tuple(state[k].shape)} vs the model's {tuple(own[k].shape)}"
        for k in own
        if k in state and tuple(state[k].shape) != tuple(own[k].shape)
    ]
    if not (missing or unexpected or shapes):
        return None

    def few(items: list[str]) -> str:
        more = f", ... ({len(items) - shown} more)" if len(items) > shown else ""
        return ", ".join(items[:shown]) + more

    parts = []
    if missing:
        parts.append(f"{len(missing)} of the model's {len(own)} keys missing ({few(missing)})")
    if unexpected:
        parts.append(f"{len(unexpected)} unexpected ({few(unexpected)})")
    if shapes:
        parts.append(f"{len(shapes)} of other shapes ({few(shapes)})")
    hint = _prefix_hint(missing, unexpected)
    return "; ".join(parts) + (f"; {hint}" if hint else "")


def _prefix_hint(missing: list[str], unexpected: list[str]) -> str:
    """A key map line that renames the unexpected keys onto exactly the missing ones, where
    they differ by a prefix alone (``module.`` of DataParallel, say)."""
    if not missing or not unexpected:
        return ""
    first, wanted = unexpected[0], set(missing)

    def cuts(key: str) -> list[str]:
        return [""] + [key[: i + 1] for i, c in enumerate(key) if c == "."]

    for source in cuts(first):
        for target in cuts(missing[0]):
            renamed = [target + k[len(source) :] for k in unexpected if k.startswith(source)]
            if source != target and len(renamed) == len(unexpected) and set(renamed) == wanted:
                return f"a key map {{{source!r}: {target!r}}} would rename them"
    return ""
