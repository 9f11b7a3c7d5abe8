"""Linear in-betweening baseline for completion: the unknown frames run in a straight line, at
constant speed, from the last observed frame to the given final frame."""

from __future__ import annotations

import torch
from torch import nn


class LinearInterpolation(nn.Module):
    def __init__(self, input_frames: int, output_frames: int, num_points: int) -> None:
        super().__init__()
        self.input_frames = input_frames
        self.output_frames = output_frames
        self.num_points = num_points

    def forward(self, history: torch.Tensor, final_frame: torch.Tensor) -> torch.Tensor:
        """``history (B, T_in, P, 3)`` and ``final_frame (B, P, 3)``, the last of the ``T_out``
        frames -> ``(B, T_out, P, 3)``, whose last frame is ``final_frame`` itself."""
        if final_frame is None or final_frame.shape != history.shape[:1] + history.shape[2:]:
            got = None if final_frame is None else tuple(final_frame.shape)
            raise ValueError(
                f"final_frame: expected (B, P, 3) = "
                f"{tuple(history.shape[:1] + history.shape[2:])}, got {got}"
            )
        alpha = (
            torch.arange(1, self.output_frames + 1, dtype=history.dtype, device=history.device)
            / self.output_frames
        )
        return torch.lerp(history[:, -1:], final_frame[:, None], alpha[None, :, None, None])
