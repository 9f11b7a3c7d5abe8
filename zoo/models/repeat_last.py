"""Repeat-last-frame (zero-velocity) baseline: every future frame equals the last observed one."""

from __future__ import annotations

import torch
from torch import nn


class RepeatLast(nn.Module):
    def __init__(self, input_frames: int, output_frames: int, num_points: int) -> None:
        super().__init__()
        self.input_frames = input_frames
        self.output_frames = output_frames
        self.num_points = num_points

    def forward(self, history: torch.Tensor) -> torch.Tensor:
        return history[:, -1:].expand(-1, self.output_frames, -1, -1).clone()
