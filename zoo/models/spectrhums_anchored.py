"""SpecTrHuMS with anchored inference (a zoo change, not the paper's): the prediction is the last
observed frame plus the change the model predicts from it.

The paper decodes each predicted latent into a frame. Its transformer does not reproduce the
latents it observed (its output there is about twice a frame's real change away from them), so
the first predicted frame already carries that offset and loses to repeat-last at 80 ms. Here
frame ``t`` is ``x_last + R(D(o_t)) - R(D(o_last))``: the observed last frame, as given, plus the
difference between the decoded output at ``t`` and at the last observed position (``D`` the
decoder, ``R`` the spectral reconstruction, ``o`` the transformer's outputs). The offset both
decodes share cancels, and the frame keeps what the k coefficients cannot hold.

The weights are SpecTrHuMS's own (same parameters, same training loss): this class changes
inference only, so it runs the paper entry's shipped weights (registry ``weights_of``).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from zoo.models.spectrhums import SpecTrHuMS, SpecTrHuMSError


class AnchoredSpecTrHuMS(SpecTrHuMS):
    """:class:`zoo.models.spectrhums.SpecTrHuMS` (prediction only) whose frames are the last
    observed frame plus the decoded change from the last observed position."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        if self.task != "prediction":
            raise SpecTrHuMSError(
                f"anchored inference predicts from the last observed frame; task {self.task!r} "
                f"is not prediction"
            )

    # The paper's autoencoder floor (the true future through the autoencoder) is not this
    # model's: anchored inference with a perfect transformer keeps the last frame's detail. No
    # floor rows, then; the paper's entry of the same weights has them.
    autoencoder_floor = None

    def anchored_change(self, coeffs: Tensor) -> Tensor:
        """Observed coefficients ``(B, T_in, k, 3)`` -> the predicted change of each future
        frame from the last observed one, ``(B, T_out, k, 3)`` in mm."""
        if coeffs.ndim != 4 or coeffs.shape[1:] != (self.input_frames, self.k, 3):
            raise SpecTrHuMSError(
                f"coefficients: expected (B, {self.input_frames}, {self.k}, 3),"
                f" got {tuple(coeffs.shape)}"
            )
        z = self.standardise_latents(self.encode(coeffs))
        out = self.transformer(self.fill_window(z))[:, self.input_frames - 1 :]
        decoded = self.decode(self.destandardise_latents(out))
        return decoded[:, 1:] - decoded[:, :1]

    def forward(self, history: Tensor, final_frame: Tensor | None = None) -> Tensor:
        """``history (B, T_in, V, 3)`` in mm -> ``(B, T_out, V, 3)`` in mm."""
        self._check_vertices(history, "history", self.input_frames)
        self._check_final(final_frame is not None)
        change = self.anchored_change(self.project(history))
        return history[:, -1:] + self.reconstruct(change)

    @torch.no_grad()
    def rollout(self, history: Tensor, frames: int) -> Tensor:
        """Long-term prediction: the last ``input_frames`` frames (predicted ones included) fed
        back, each chunk anchored on the frame before it."""
        if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
            raise SpecTrHuMSError(f"frames: a positive integer, got {frames!r}")
        self._check_vertices(history, "history", None)
        if history.shape[1] < self.input_frames:
            raise SpecTrHuMSError(
                f"history: {history.shape[1]} frames, shorter than the "
                f"model's input_frames={self.input_frames}"
            )
        window, outputs, produced = history[:, -self.input_frames :], [], 0
        while produced < frames:
            chunk = self(window)
            outputs.append(chunk)
            produced += chunk.shape[1]
            window = torch.cat([window, chunk], dim=1)[:, -self.input_frames :]
        return torch.cat(outputs, dim=1)[:, :frames]
