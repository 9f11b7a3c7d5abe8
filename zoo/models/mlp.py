"""The MLP baseline, siMLPe: DCT along time, linear maps over time and space, no activations, the
last observed frame added back; longer horizons rolled out ``chunk`` frames per step.

Guo, Du, Wang, Castillo, Alameda-Pineda, Horaud. Back to MLP: A simple baseline for human motion
prediction. WACV 2023. Data flow, initialisation and units: docs/models/mlp.md ("What it is, and
where it departs from the paper").
"""

from __future__ import annotations

import math

import torch
from torch import nn

from zoo.models.dct import dct_matrix

MM_PER_M = 1000.0


def _positive_int(name: str, value, allow_zero: bool = False) -> int:
    low = 0 if allow_zero else 1
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(f"SiMLPe: {name} must be an integer >= {low}, got {value!r}")
    return value


class TemporalBlock(nn.Module):
    """``x + LayerNorm(W x)`` with ``W`` acting along time; ``x`` is ``(B, T, hidden)``."""

    def __init__(self, frames: int, hidden: int, init_gain: float) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.empty(frames, frames))
        self.bias = nn.Parameter(torch.zeros(frames))
        self.norm = nn.LayerNorm(hidden)  # over the spatial axis, one affine pair per channel
        nn.init.xavier_uniform_(self.weight, gain=init_gain)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mixed = torch.matmul(self.weight, x) + self.bias[:, None]
        return x + self.norm(mixed)


class SiMLPe(nn.Module):
    def __init__(
        self,
        input_frames: int,
        output_frames: int,
        num_points: int,
        blocks: int = 48,
        hidden_dim: int | None = None,
        chunk: int = 10,
        init_gain: float = 1e-10,
    ) -> None:
        super().__init__()
        self.input_frames = _positive_int("input_frames", input_frames)
        self.output_frames = _positive_int("output_frames", output_frames)
        self.num_points = _positive_int("num_points", num_points)
        _positive_int("blocks", blocks, allow_zero=True)
        _positive_int("chunk", chunk)
        features = 3 * num_points
        hidden = features if hidden_dim is None else _positive_int("hidden_dim", hidden_dim)
        if (
            isinstance(init_gain, bool)
            or not isinstance(init_gain, (int, float))
            or not math.isfinite(init_gain)
            or init_gain < 0
        ):
            raise ValueError(f"SiMLPe: init_gain must be a finite number >= 0, got {init_gain!r}")
        # Temporal layers map T_in -> T_in frames, so one step can give at most T_in frames.
        self.chunk = min(chunk, input_frames)
        self.hidden_dim = hidden
        self.register_buffer("dct", dct_matrix(input_frames), persistent=False)
        self.spatial_in = nn.Linear(features, hidden)  # default init, as published
        self.blocks = nn.ModuleList(
            TemporalBlock(input_frames, hidden, init_gain) for _ in range(blocks)
        )
        self.spatial_out = nn.Linear(hidden, features)
        nn.init.xavier_uniform_(self.spatial_out.weight, gain=init_gain)
        nn.init.zeros_(self.spatial_out.bias)

    def step(self, window: torch.Tensor) -> torch.Tensor:
        """The ``chunk`` frames ``(B, chunk, P, 3)`` (mm) after ``window`` ``(B, T_in, P, 3)``."""
        batch = window.shape[0]
        x = window.reshape(batch, self.input_frames, -1) / MM_PER_M
        h = self.spatial_in(torch.matmul(self.dct, x))
        for block in self.blocks:
            h = block(h)
        coefficients = self.spatial_out(h)
        # Inverse DCT of the first `chunk` frames only: rows of D^T = columns of D.
        delta = torch.matmul(self.dct[:, : self.chunk].T, coefficients)
        delta = delta.reshape(batch, self.chunk, self.num_points, 3)
        return window[:, -1:] + MM_PER_M * delta

    def forward(self, history: torch.Tensor) -> torch.Tensor:
        self._check(history, "history", self.input_frames)
        window, predicted, count = history, [], 0
        while count < self.output_frames:
            frames = self.step(window)
            predicted.append(frames)
            count += self.chunk
            window = torch.cat([window, frames], dim=1)[:, -self.input_frames :]
        return torch.cat(predicted, dim=1)[:, : self.output_frames]

    def training_loss(self, history: torch.Tensor, future: torch.Tensor) -> torch.Tensor:
        """siMLPe's loss on one step: mean joint L2 error of positions plus that of frame-to-frame
        velocities, both in metres (the published scale of lr and weight decay)."""
        self._check(history, "history", self.input_frames)
        self._check(future, "future", self.output_frames)
        frames = min(self.chunk, self.output_frames)
        predicted = self.step(history)[:, :frames] / MM_PER_M
        target = future[:, :frames] / MM_PER_M
        loss = torch.linalg.vector_norm(predicted - target, dim=-1).mean()
        if frames > 1:
            velocity_error = predicted.diff(dim=1) - target.diff(dim=1)
            loss = loss + torch.linalg.vector_norm(velocity_error, dim=-1).mean()
        return loss

    def _check(self, motion: torch.Tensor, name: str, frames: int) -> None:
        expected = (frames, self.num_points, 3)
        if motion.ndim != 4 or tuple(motion.shape[1:]) != expected:
            raise ValueError(
                f"SiMLPe: {name} must have shape (B, {frames}, {self.num_points}, 3), "
                f"got {tuple(motion.shape)}"
            )
