"""Constant-velocity baseline: every future frame continues the last observed frame-to-frame
displacement, ``x[T + t] = x[T] + t (x[T] - x[T - 1])``."""

from __future__ import annotations

import torch
from torch import nn


class ConstantVelocity(nn.Module):
    def __init__(self, input_frames: int, output_frames: int, num_points: int) -> None:
        super().__init__()
        if input_frames < 2:
            raise ValueError(
                f"constant velocity needs at least 2 observed frames, got input_frames="
                f"{input_frames}"
            )
        self.input_frames = input_frames
        self.output_frames = output_frames
        self.num_points = num_points

    def forward(self, history: torch.Tensor) -> torch.Tensor:
        last = history[:, -1:]
        step = last - history[:, -2:-1]
        t = torch.arange(1, self.output_frames + 1, dtype=history.dtype, device=history.device)
        return last + t[None, :, None, None] * step
