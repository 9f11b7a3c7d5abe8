"""A model that attends over more observed frames than a protocol gives (HisRepItself: 50; CMU's
protocol: 10) pads the history on the left with its oldest frame, the zoo's convention, and
takes the length it pads to as a hyper-parameter, so that every row records it
(docs/adding-a-model.md, "A longer history than the protocol gives")."""

from __future__ import annotations

import torch


def pad_history(history: torch.Tensor, frames: int) -> torch.Tensor:
    """``history`` ``(B, T, ...)`` lengthened to ``frames`` frames by repeating its first
    (oldest) frame in front: a body that stood still before it was observed. A history already
    ``frames`` long or longer keeps its last ``frames`` frames."""
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise ValueError(f"pad_history: frames must be a positive integer, got {frames!r}")
    if history.ndim < 2 or history.shape[1] < 1:
        raise ValueError(
            f"pad_history: history must be (B, T, ...) with T >= 1, got {tuple(history.shape)}"
        )
    missing = frames - history.shape[1]
    if missing <= 0:
        return history[:, -frames:]
    oldest = history[:, :1].expand(-1, missing, *history.shape[2:])
    return torch.cat([oldest, history], dim=1)
