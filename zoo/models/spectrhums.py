"""SpecTrHuMS: a spectral autoencoder and a transformer over its latents.

Lemeunier, Denis, Lavoué, Dupont. SpecTrHuMS: Spectral Transformer for Human Mesh Sequence
learning. Computers & Graphics 2023.

Data flow (every step on whole batches):

1. vertices ``(B, T, V, 3)`` in mm -> spectral coefficients ``C = Phi^T V`` ``(B, T, k, 3)``
   with the dataset's basis ``Phi (V, k)``, one matrix product for all frames;
2. coefficients standardised per (frequency, axis) with training-set mean and std;
3. the convolutional spectral autoencoder encodes every frame to a latent vector (256);
4. latents standardised with training-set mean and std (Welford, recomputed every epoch in
   which the transformer trains);
5. a window of ``T_in + T_out`` latents is filled in: the ``T_out`` unknown ones are the last
   observed latent repeated (prediction) or a linear interpolation from the last observed latent
   to the latent of a given final frame (completion, the final frame being the window's last);
6. a post-norm transformer encoder maps the window to a window of latents;
7. the ``T_out`` predicted latents are de-standardised, decoded to coefficients, de-standardised
   and turned back into vertices ``V = Phi C``, one matrix product for all frames.

Training (``training_loss``): a static loss, the MSE between de-standardised coefficients and
their autoencoder reconstruction on ``static_frames`` random frames of each window (default 1;
the public code draws one frame index per batch, here each window draws its own), which trains
the autoencoder alone; and a dynamic loss, the MSE between the transformer's
output and the standardised latents of the whole window (all ``T_in + T_out`` frames), computed
on latents encoded without gradient, so it trains the transformer alone. For the first
``autoencoder_epochs`` epochs (2) only the static loss is used. ``start_epoch`` computes the
coefficient statistics (first epoch) and the latent statistics (at the start of every epoch in
which the transformer trains, with the encoder as it is then) over all frames of all training
windows (each distinct frame encoded once, weighted by the number of windows holding it); both
are buffers, so they travel with the checkpoint.

The static loss is measured in metres (coefficients divided by ``loss_unit_mm`` = 1000), the
unit of the published SMPL data, while the model's inputs and outputs are in mm (zoo contract).

Long-term prediction (``rollout``) feeds the last ``T_in`` frames back: predicted coefficients
are re-encoded, which equals projecting their reconstructed vertices since ``Phi^T Phi = I``.

The autoencoder lives in :mod:`zoo.models.spectral_autoencoder`, the transformer in
:mod:`zoo.models.latent_transformer`; this module holds the model, its hyper-parameters
(:class:`SpecTrHuMSConfig`), the statistics and the basis checks.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from zoo.core.errors import ZooError
from zoo.data.spectral import probe_projections
from zoo.models.latent_transformer import LatentTransformer
from zoo.models.spectral_autoencoder import SpectralAutoencoder

TASKS = ("prediction", "completion")
# Largest |difference| of basis probe projections that counts as the same basis: above rounding
# (float16 storage, other machines' solvers), far below a flipped sign or a rotated eigenspace
# (the sizes: docs/models/spectrhums.md, "Implementation notes").
PROBE_TOLERANCE = 1e-2
_STD_FLOOR = 1e-6  # a feature whose std is below this is only centred (its std is set to 1)
_FRAMES_PER_CHUNK = 2048  # frames projected at once when computing statistics


class SpecTrHuMSError(ZooError, ValueError):
    """A SpecTrHuMS model was given inputs, a basis or settings it cannot work with."""


# ---- statistics ------------------------------------------------------------------------------


class Welford:
    """Running mean and sample variance over batches of feature vectors, in float64.

    Each batch is merged with Chan et al.'s parallel form of Welford's update, so the result
    equals the mean and the ``ddof=1`` standard deviation over all rows seen, whatever the
    batching.
    """

    def __init__(self, shape: Sequence[int], device: torch.device | str = "cpu") -> None:
        self.shape = tuple(shape)
        self.count = 0
        self.mean = torch.zeros(self.shape, dtype=torch.float64, device=device)
        self.m2 = torch.zeros(self.shape, dtype=torch.float64, device=device)

    def update(self, rows: Tensor, counts: Tensor | None = None) -> None:
        """Add ``rows (N, *shape)``, row ``i`` taken ``counts[i]`` times (default once)."""
        rows = rows.detach().to(self.mean.device, torch.float64).reshape(-1, *self.shape)
        if counts is None:
            counts = torch.ones(rows.shape[0], dtype=torch.int64)
        counts = counts.detach().to(self.mean.device, torch.int64).reshape(-1)
        if counts.shape[0] != rows.shape[0] or bool((counts < 0).any()):
            raise SpecTrHuMSError(
                f"statistics: {counts.shape[0]} counts for {rows.shape[0]} "
                f"rows (counts must be one non-negative integer per row)"
            )
        n_b = int(counts.sum())
        if n_b == 0:
            return
        weight = counts.to(torch.float64).reshape(-1, *([1] * len(self.shape)))
        mean_b = (weight * rows).sum(0) / n_b
        m2_b = (weight * (rows - mean_b).square()).sum(0)
        n = self.count + n_b
        delta = mean_b - self.mean
        self.mean = self.mean + delta * (n_b / n)
        self.m2 = self.m2 + m2_b + delta.square() * (self.count * n_b / n)
        self.count = n

    def finalize(self, what: str) -> tuple[Tensor, Tensor]:
        """``(mean, std)`` with the sample standard deviation (``ddof=1``)."""
        if self.count < 2:
            raise SpecTrHuMSError(f"{what}: statistics need at least 2 frames, got {self.count}")
        return self.mean, (self.m2 / (self.count - 1)).sqrt()


def _floored(std: Tensor) -> Tensor:
    return torch.where(std < _STD_FLOOR, torch.ones_like(std), std)


# ---- the hyper-parameters -------------------------------------------------------------------


def _positive(name: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise SpecTrHuMSError(f"{name}: a positive integer, got {value!r}")


@dataclass(frozen=True)
class SpecTrHuMSConfig:
    """SpecTrHuMS's hyper-parameters: :class:`SpecTrHuMS`'s arguments but the basis, with the
    same defaults. Checked on construction (a bad value raises :class:`SpecTrHuMSError` naming
    it); ``channels`` and ``pooling`` are kept as tuples."""

    input_frames: int
    output_frames: int
    num_points: int
    task: str = "prediction"
    latent: int = 256
    channels: Sequence[int] = (32, 64)
    pooling: Sequence[int] = (64, 32)
    kernel_size: int = 3
    d_model: int = 256
    layers: int = 6
    heads: int = 4
    ff: int = 1024
    dropout: float = 0.0
    position_dropout: float = 0.1
    autoencoder_epochs: int = 2
    static_frames: int = 1
    loss_unit_mm: float = 1000.0

    @property
    def window(self) -> int:
        """Frames the transformer sees: ``input_frames + output_frames``."""
        return int(self.input_frames) + int(self.output_frames)

    def __post_init__(self) -> None:
        for name in (
            "input_frames",
            "output_frames",
            "num_points",
            "latent",
            "kernel_size",
            "d_model",
            "layers",
            "heads",
            "ff",
            "static_frames",
        ):
            _positive(name, getattr(self, name))
        if self.task not in TASKS:
            raise SpecTrHuMSError(f"task: {self.task!r} unknown; valid: {', '.join(TASKS)}")
        self._check_levels()
        self._check_shapes()
        self._check_training()

    def _check_levels(self) -> None:
        """One channel count and one pooled size per encoder level; stored as tuples."""
        channels, pooling = list(self.channels), list(self.pooling)
        if not channels or len(channels) != len(pooling):
            raise SpecTrHuMSError(
                f"channels {channels} and pooling {pooling}: one channel count and "
                f"one pooled size per encoder level (published: [32, 64], [64, 32])"
            )
        for i, (c, p) in enumerate(zip(channels, pooling)):
            _positive(f"channels[{i}]", c)
            _positive(f"pooling[{i}]", p)
        object.__setattr__(self, "channels", tuple(channels))
        object.__setattr__(self, "pooling", tuple(pooling))

    def _check_shapes(self) -> None:
        if self.kernel_size % 2 == 0:
            raise SpecTrHuMSError(
                f"kernel_size: odd (the convolutions keep the frequency axis' "
                f"length), got {self.kernel_size}"
            )
        if self.d_model % 2 or self.d_model % self.heads:
            raise SpecTrHuMSError(
                f"d_model={self.d_model}: must be even (sinusoidal positions) and divisible by "
                f"heads={self.heads}"
            )

    def _check_training(self) -> None:
        for name in ("dropout", "position_dropout"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < 1:
                raise SpecTrHuMSError(f"{name}: a probability in [0, 1), got {value!r}")
        epochs = self.autoencoder_epochs
        if isinstance(epochs, bool) or not isinstance(epochs, int) or epochs < 0:
            raise SpecTrHuMSError(f"autoencoder_epochs: a non-negative integer, got {epochs!r}")
        if not self.loss_unit_mm > 0:
            raise SpecTrHuMSError(f"loss_unit_mm: positive, got {self.loss_unit_mm!r}")
        if self.static_frames > self.window:
            raise SpecTrHuMSError(
                f"static_frames={self.static_frames}: at most the window "
                f"(input_frames + output_frames = {self.window})"
            )


# ---- the model -------------------------------------------------------------------------------


class SpecTrHuMS(nn.Module):
    """SpecTrHuMS (Lemeunier et al., Computers & Graphics 2023), for prediction
    (``task='prediction'``) or completion (``'completion'``): a convolutional autoencoder of
    each frame's spectral coefficients and a transformer over the latents of a window.

    The hyper-parameters are checked and kept as ``config`` (:class:`SpecTrHuMSConfig`).
    ``basis``: the dataset's spectral basis (``vectors (V, k)`` with orthonormal columns ordered
    by frequency, ``hash``), supplied by the benchmark (registry ``context: [basis]``). Its
    ``V`` must equal ``num_points``; ``k`` comes from it and the window is
    ``input_frames + output_frames``.
    """

    def __init__(
        self,
        input_frames: int,
        output_frames: int,
        num_points: int,
        basis: Any,
        task: str = "prediction",
        latent: int = 256,
        channels: Sequence[int] = (32, 64),
        pooling: Sequence[int] = (64, 32),
        kernel_size: int = 3,
        d_model: int = 256,
        layers: int = 6,
        heads: int = 4,
        ff: int = 1024,
        dropout: float = 0.0,
        position_dropout: float = 0.1,
        autoencoder_epochs: int = 2,
        static_frames: int = 1,
        loss_unit_mm: float = 1000.0,
    ) -> None:
        given = locals()  # every argument by name: the config's fields are among them
        super().__init__()
        config = SpecTrHuMSConfig(**{f.name: given[f.name] for f in fields(SpecTrHuMSConfig)})
        phi = _basis_vectors(basis, config.num_points)
        self.config = config
        self.input_frames, self.output_frames = int(config.input_frames), int(config.output_frames)
        self.window = config.window
        self.num_points, self.k = int(config.num_points), phi.shape[1]
        self.task = config.task
        self.autoencoder_epochs = int(config.autoencoder_epochs)
        self.static_frames = int(config.static_frames)
        self.loss_unit_mm = float(config.loss_unit_mm)
        self.basis_hash = str(basis.hash)
        self.topology_hash = str(getattr(basis, "topology_hash", ""))
        self.phase = "autoencoder" if self.autoencoder_epochs > 0 else "joint"

        self.autoencoder = SpectralAutoencoder(
            self.k, config.channels, config.pooling, config.kernel_size, config.latent
        )
        self.transformer = LatentTransformer(
            config.latent,
            config.d_model,
            config.layers,
            config.heads,
            config.ff,
            config.dropout,
            self.window,
            config.position_dropout,
        )
        for m in self.modules():  # the published initialisation: xavier, zero bias
            if isinstance(m, (nn.Linear, nn.Conv1d)):
                nn.init.xavier_uniform_(m.weight)
                nn.init.zeros_(m.bias)

        self.basis = basis  # data, not parameters: it travels with the dataset, by hash
        self._register_buffers(phi, config.latent)

    def _register_buffers(self, phi: np.ndarray, latent: int) -> None:
        """What travels with the weights besides the parameters: the basis's identity and the
        standardisation statistics (empty until ``start_epoch`` computes them)."""
        self.register_buffer(
            "basis_id",
            torch.tensor(
                list(hashlib.sha256(self.basis_hash.encode()).digest()), dtype=torch.uint8
            ),
        )
        # The basis's own numbers, so weights are checked against the vectors they will meet,
        # not only against the name of the basis (see zoo.data.spectral: names agree across
        # machines, bytes do not).
        self.register_buffer("basis_probe", torch.from_numpy(probe_projections(phi)).float())
        self.register_buffer("coeff_mean", torch.zeros(self.k, 3))
        self.register_buffer("coeff_std", torch.ones(self.k, 3))
        self.register_buffer("coeff_frames", torch.zeros((), dtype=torch.int64))
        self.register_buffer("latent_mean", torch.zeros(latent))
        self.register_buffer("latent_std", torch.ones(latent))
        self.register_buffer("latent_frames", torch.zeros((), dtype=torch.int64))

    # ---- the basis: the dataset's own (one matrix product for all frames) ------------------------

    def project(self, vertices: Tensor) -> Tensor:
        """``(..., V, 3) -> (..., k, 3)``: ``Phi^T V``, by the basis itself."""
        return self.basis.project(vertices)

    def _project_frames(self, *parts: Tensor) -> Tensor:
        """Coefficients of ``parts (B, T_i, V, 3)`` joined along time: ``(B, sum T_i, k, 3)``."""
        return self.basis.project(torch.cat(parts, dim=1))

    def reconstruct(self, coeffs: Tensor) -> Tensor:
        """``(..., k, 3) -> (..., V, 3)``: ``Phi C``, by the basis itself."""
        return self.basis.reconstruct(coeffs)

    # ---- standardisation and the autoencoder ---------------------------------------------------

    def standardise_coefficients(self, coeffs: Tensor) -> Tensor:
        return (coeffs - self.coeff_mean) / self.coeff_std

    def destandardise_coefficients(self, coeffs: Tensor) -> Tensor:
        return coeffs * self.coeff_std + self.coeff_mean

    def standardise_latents(self, z: Tensor) -> Tensor:
        return (z - self.latent_mean) / self.latent_std

    def destandardise_latents(self, z: Tensor) -> Tensor:
        return z * self.latent_std + self.latent_mean

    def encode(self, coeffs: Tensor) -> Tensor:
        """Coefficients ``(..., k, 3)`` (mm) -> latents ``(..., latent)`` (not standardised)."""
        lead = coeffs.shape[:-2]
        x = self.standardise_coefficients(coeffs).reshape(-1, self.k, 3)
        return self.autoencoder.encode(x).view(*lead, -1)

    def decode(self, z: Tensor) -> Tensor:
        """Latents ``(..., latent)`` -> de-standardised coefficients ``(..., k, 3)`` (mm)."""
        lead = z.shape[:-1]
        x = self.autoencoder.decode(z.reshape(-1, z.shape[-1]))
        return self.destandardise_coefficients(x).view(*lead, self.k, 3)

    # ---- the window the transformer sees -------------------------------------------------------

    @property
    def known_frames(self) -> Tensor:
        """Which frames of the window the transformer's input is built from (bool ``(W,)``)."""
        known = torch.zeros(self.window, dtype=torch.bool)
        known[: self.input_frames] = True
        if self.task == "completion":
            known[-1] = True
        return known

    def fill_window(self, observed: Tensor, final: Tensor | None = None) -> Tensor:
        """The transformer's input ``(B, W, L)`` from standardised latents of the observed
        frames ``(B, T_in, L)`` and, for completion, of the final frame ``(B, L)``."""
        if observed.shape[1] != self.input_frames:
            raise SpecTrHuMSError(
                f"observed latents: {observed.shape[1]} frames, the model "
                f"observes input_frames={self.input_frames}"
            )
        self._check_final(final is not None)
        last = observed[:, -1:]
        if self.task == "prediction":
            unknown = last.expand(-1, self.output_frames, -1)
        else:
            alpha = (
                torch.arange(
                    1, self.output_frames + 1, device=observed.device, dtype=observed.dtype
                )
                / self.output_frames
            )
            # lerp is exact at both ends: the window's last latent is the final frame's
            unknown = torch.lerp(last, final[:, None], alpha[:, None])
        return torch.cat([observed, unknown], dim=1)

    def masked_window(self, latents: Tensor) -> Tensor:
        """The transformer's input for a full window of standardised latents ``(B, W, L)``:
        only the frames in ``known_frames`` are used, the others are filled in (training)."""
        if latents.shape[1] != self.window:
            raise SpecTrHuMSError(
                f"latent window: {latents.shape[1]} frames, the model's window "
                f"is {self.window} (input_frames {self.input_frames} + "
                f"output_frames {self.output_frames})"
            )
        final = latents[:, -1] if self.task == "completion" else None
        return self.fill_window(latents[:, : self.input_frames], final)

    def transform_window(self, latents: Tensor) -> Tensor:
        """The transformer on a full window of standardised latents, masked as in training."""
        return self.transformer(self.masked_window(latents))

    # ---- inference -----------------------------------------------------------------------------

    def predict_coefficients(self, coeffs: Tensor, final: Tensor | None = None) -> Tensor:
        """Observed coefficients ``(B, T_in, k, 3)`` (and, for completion, the final frame's
        ``(B, k, 3)``) -> predicted coefficients ``(B, T_out, k, 3)``, all in mm."""
        if coeffs.ndim != 4 or coeffs.shape[1:] != (self.input_frames, self.k, 3):
            raise SpecTrHuMSError(
                f"coefficients: expected (B, {self.input_frames}, {self.k}, 3),"
                f" got {tuple(coeffs.shape)}"
            )
        z = self.standardise_latents(self.encode(coeffs))
        z_final = None
        if final is not None:
            if final.shape != (coeffs.shape[0], self.k, 3):
                raise SpecTrHuMSError(
                    f"final coefficients: expected (B, k, 3) = "
                    f"({coeffs.shape[0]}, {self.k}, 3), got "
                    f"{tuple(final.shape)}"
                )
            z_final = self.standardise_latents(self.encode(final))
        out = self.transformer(self.fill_window(z, z_final))[:, self.input_frames :]
        return self.decode(self.destandardise_latents(out))

    def forward(self, history: Tensor, final_frame: Tensor | None = None) -> Tensor:
        """``history (B, T_in, V, 3)`` in mm -> ``(B, T_out, V, 3)`` in mm.

        Completion (``task='completion'``) also takes ``final_frame (B, V, 3)``, the frame the
        motion must reach at the end of the window (the last of the ``T_out`` frames).
        """
        self._check_vertices(history, "history", self.input_frames)
        final = None
        if final_frame is not None:
            if final_frame.ndim == 4 and final_frame.shape[1] == 1:
                final_frame = final_frame[:, 0]
            if final_frame.ndim != 3 or final_frame.shape != (history.shape[0], self.num_points, 3):
                raise SpecTrHuMSError(
                    f"final_frame: expected (B, V, 3) = ({history.shape[0]}, "
                    f"{self.num_points}, 3), got {tuple(final_frame.shape)}"
                )
            final = final_frame[:, None]
        self._check_final(final is not None)
        parts = (history,) if final is None else (history, final)
        coeffs = self._project_frames(*parts)  # one product for the observed and final frames
        final_coeffs = None if final is None else coeffs[:, -1]
        return self.reconstruct(
            self.predict_coefficients(coeffs[:, : self.input_frames], final_coeffs)
        )

    @torch.no_grad()
    def autoencoder_floor(self, frames: Tensor) -> Tensor:
        """``frames (B, T, V, 3)`` in mm through the autoencoder alone: projected, encoded,
        decoded and reconstructed. Scored against the ground truth, it is the error the model
        would keep with a perfect transformer (the evaluator's ``<name>:autoencoder`` rows)."""
        self._check_vertices(frames, "frames", None)
        return self.reconstruct(self.decode(self.encode(self.project(frames))))

    @torch.no_grad()
    def rollout(self, history: Tensor, frames: int) -> Tensor:
        """Long-term prediction: ``frames`` future frames ``(B, frames, V, 3)`` from a history of
        at least ``input_frames`` frames, feeding the last ``input_frames`` frames back.

        Fed-back frames are re-encoded from their predicted coefficients, which equals
        projecting their reconstructed vertices (``Phi^T Phi = I``) without the round trip.
        """
        if self.task != "prediction":
            raise SpecTrHuMSError(
                "rollout is long-term prediction; this model was trained for "
                "completion (task='completion')"
            )
        if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
            raise SpecTrHuMSError(f"frames: a positive integer, got {frames!r}")
        self._check_vertices(history, "history", None)
        if history.shape[1] < self.input_frames:
            raise SpecTrHuMSError(
                f"history: {history.shape[1]} frames, shorter than the "
                f"model's input_frames={self.input_frames}"
            )
        z = self.encode(self.project(history[:, -self.input_frames :]))
        frames, outputs, produced = int(frames), [], 0
        while produced < frames:
            out = self.transformer(self.fill_window(self.standardise_latents(z)))
            coeffs = self.decode(self.destandardise_latents(out[:, self.input_frames :]))
            outputs.append(coeffs)
            produced += self.output_frames
            if produced < frames:
                z = torch.cat([z, self.encode(coeffs)], dim=1)[:, -self.input_frames :]
        return self.reconstruct(torch.cat(outputs, dim=1)[:, :frames])

    # ---- training ------------------------------------------------------------------------------

    def start_epoch(
        self, epoch: int, frames: Callable[[], Iterable[tuple[Tensor, Tensor]]], view: bool = False
    ) -> None:
        """Training-engine hook: the phase of ``epoch`` and the statistics it needs.

        Coefficient statistics: in the first epoch (or whenever they were never computed);
        latent statistics: every epoch in which the transformer trains, with the current
        encoder. Both over every frame of every training window: ``frames()`` yields each
        distinct training frame ``(N, V, 3)`` once with the number of windows holding it
        ``(N,)``, which weights it; with ``view``, the frames' coefficients ``(N, k, 3)`` (the
        training view, computed once by the engine).
        """
        self.phase = "autoencoder" if epoch < self.autoencoder_epochs else "joint"
        if epoch == 0 or int(self.coeff_frames) == 0:
            self.compute_coefficient_statistics(frames(), view)
        if self.phase == "joint":
            self.compute_latent_statistics(frames(), view)

    @torch.no_grad()
    def compute_coefficient_statistics(
        self, frames: Iterable[tuple[Tensor, Tensor]], view: bool = False
    ) -> None:
        stats = Welford((self.k, 3), self.coeff_mean.device)
        for coeffs, counts in self._frame_coefficients(frames, view):
            stats.update(coeffs, counts)
        mean, std = stats.finalize("coefficient statistics over the training windows")
        self.coeff_mean.copy_(mean)
        self.coeff_std.copy_(_floored(std))
        self.coeff_frames.fill_(stats.count)

    @torch.no_grad()
    def compute_latent_statistics(
        self, frames: Iterable[tuple[Tensor, Tensor]], view: bool = False
    ) -> None:
        if int(self.coeff_frames) == 0:
            raise SpecTrHuMSError(
                "latent statistics need the coefficient statistics first "
                "(start_epoch computes both)"
            )
        stats = Welford((self.latent_mean.shape[0],), self.latent_mean.device)
        for coeffs, counts in self._frame_coefficients(frames, view):
            stats.update(self.encode(coeffs), counts)
        mean, std = stats.finalize("latent statistics over the training windows")
        self.latent_mean.copy_(mean)
        self.latent_std.copy_(_floored(std))
        self.latent_frames.fill_(stats.count)

    def _frame_coefficients(
        self, frames: Iterable[tuple[Tensor, Tensor]], view: bool = False
    ) -> Iterator[tuple[Tensor, Tensor]]:
        """Coefficients ``(N, k, 3)`` of the training frames with their counts, a few thousand
        frames at a time (``view``: the frames are coefficients already)."""
        seen = 0
        for batch, counts in frames:
            if view:
                self._check_coefficients(batch[None], "training frames (coefficients)")
            else:
                self._check_vertices(batch[None], "training frames", None)
            if counts.shape != batch.shape[:1]:
                raise SpecTrHuMSError(
                    f"training frames: {tuple(counts.shape)} counts for "
                    f"{batch.shape[0]} frames (one count per frame)"
                )
            batch = batch.to(self.coeff_mean.device, self.coeff_mean.dtype)
            for start in range(0, len(batch), _FRAMES_PER_CHUNK):
                part = slice(start, start + _FRAMES_PER_CHUNK)
                yield (batch[part] if view else self.project(batch[part])), counts[part]
            seen += len(batch)
        if seen == 0:
            raise SpecTrHuMSError("training frames: none given")

    def loss_terms(self, history: Tensor, future: Tensor) -> dict[str, Tensor | None]:
        """``{'static': ..., 'dynamic': ...}`` for a batch of windows (``dynamic`` is None in
        the autoencoder phase)."""
        self._check_vertices(history, "history", self.input_frames)
        self._check_vertices(future, "future", self.output_frames)
        return self.coefficient_loss_terms(self._project_frames(history, future))

    def coefficient_loss_terms(self, coeffs: Tensor) -> dict[str, Tensor | None]:
        """The loss terms for windows of coefficients ``(B, W, k, 3)`` in mm."""
        if coeffs.ndim != 4 or coeffs.shape[1:] != (self.window, self.k, 3):
            raise SpecTrHuMSError(
                f"coefficient windows: expected (B, {self.window}, {self.k}, "
                f"3), got {tuple(coeffs.shape)}"
            )
        if int(self.coeff_frames) == 0:
            raise SpecTrHuMSError(
                "training needs the coefficient statistics: call "
                "start_epoch(epoch, frames) first (the training engine does)"
            )
        b = coeffs.shape[0]
        if self.static_frames == self.window:
            picked = coeffs
        else:
            idx = torch.rand(b, self.window, device=coeffs.device).argsort(1)
            picked = coeffs[
                torch.arange(b, device=coeffs.device)[:, None], idx[:, : self.static_frames]
            ]
        rebuilt = self.decode(self.encode(picked))
        static = F.mse_loss(rebuilt / self.loss_unit_mm, picked / self.loss_unit_mm)
        if self.phase == "autoencoder":
            return {"static": static, "dynamic": None}
        if int(self.latent_frames) == 0:
            raise SpecTrHuMSError(
                "the joint phase needs the latent statistics: call "
                "start_epoch(epoch, frames) first (the training engine does)"
            )
        with torch.no_grad():  # the dynamic loss never updates the encoder
            target = self.standardise_latents(self.encode(coeffs))
        dynamic = F.mse_loss(self.transform_window(target), target)
        return {"static": static, "dynamic": dynamic}

    def training_loss(self, history: Tensor, future: Tensor) -> Tensor:
        return _total(self.loss_terms(history, future))

    # ---- the training view: coefficients, computed once per dataset and basis ----------------

    def training_view(self, frames: Tensor) -> Tensor:
        """Training-engine hook: a frame's training representation, its coefficients
        ``(N, V, 3) -> (N, k, 3)`` (projected in float64; the engine stores them in float32)."""
        self._check_vertices(frames[None], "frames", None)
        return self.basis.project(frames.double())

    def training_view_identity(self) -> dict[str, Any]:
        """What the coefficients depend on: the basis (its hash names what was computed, its
        checksum the vectors' bytes, which follow the machine's LAPACK kernels)."""
        return {
            "kind": "spectral coefficients",
            "basis_hash": self.basis_hash,
            "basis_checksum": str(getattr(self.basis, "checksum", "")),
            "k": self.k,
        }

    def training_loss_view(self, history: Tensor, future: Tensor) -> Tensor:
        """Training-engine hook: the loss of windows of coefficients ``(B, T, k, 3)``, whose cost
        does not grow with the number of vertices (measured: docs/models/spectrhums.md)."""
        return _total(self.coefficient_loss_terms(torch.cat([history, future], dim=1)))

    # ---- checks --------------------------------------------------------------------------------

    def _check_final(self, given: bool) -> None:
        if self.task == "prediction" and given:
            raise SpecTrHuMSError(
                "final_frame: this model was trained for prediction "
                "(task='prediction'); a final frame is for completion"
            )
        if self.task == "completion" and not given:
            raise SpecTrHuMSError(
                "final_frame is required: this model does completion "
                "(task='completion'), the unknown frames are interpolated "
                "towards the given final frame"
            )

    def _check_coefficients(self, x: Tensor, what: str) -> None:
        if not isinstance(x, Tensor) or x.ndim != 4 or x.shape[2:] != (self.k, 3):
            shape = tuple(x.shape) if isinstance(x, Tensor) else type(x).__name__
            raise SpecTrHuMSError(f"{what}: expected coefficients (B, T, {self.k}, 3), got {shape}")

    def _check_vertices(self, x: Tensor, what: str, frames: int | None) -> None:
        if not isinstance(x, Tensor) or x.ndim != 4 or x.shape[2:] != (self.num_points, 3):
            shape = tuple(x.shape) if isinstance(x, Tensor) else type(x).__name__
            raise SpecTrHuMSError(
                f"{what}: expected vertices (B, T, {self.num_points}, 3) in mm, got {shape}"
            )
        if frames is not None and x.shape[1] != frames:
            raise SpecTrHuMSError(
                f"{what}: {x.shape[1]} frames, expected {frames} (the model's window is "
                f"{self.window} = input_frames {self.input_frames} + output_frames "
                f"{self.output_frames})"
            )

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        saved = state_dict.get(prefix + "basis_id")
        if saved is not None and not torch.equal(saved.cpu(), self.basis_id.cpu()):
            raise SpecTrHuMSError(
                f"these weights were trained with another spectral basis than "
                f"this model's (hash {self.basis_hash[:12]}); a basis is never "
                f"interchangeable (eigenvector signs and order are arbitrary)"
            )
        probe = state_dict.get(prefix + "basis_probe")
        if saved is not None and probe is None:
            raise SpecTrHuMSError(
                "these weights carry no basis_probe (the numbers of the basis "
                "they were trained with), so they cannot be checked against "
                "this machine's basis; export them again from their checkpoint"
            )
        if probe is not None and probe.shape == self.basis_probe.shape:
            gap = (probe.float().cpu() - self.basis_probe.cpu()).abs().max().item()
            if not gap <= PROBE_TOLERANCE:
                raise SpecTrHuMSError(
                    f"these weights were trained with other numbers for spectral basis "
                    f"{self.basis_hash[:12]} than this machine computed: its probe projections "
                    f"differ by up to {gap:.3g} (rounding gives < {PROBE_TOLERANCE:g}), so some "
                    f"eigenvector has another sign or an eigenspace another rotation; the "
                    f"weights do not apply to this basis"
                )
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)


def _total(terms: dict[str, Tensor | None]) -> Tensor:
    return terms["static"] if terms["dynamic"] is None else terms["static"] + terms["dynamic"]


def _basis_vectors(basis: Any, num_points: int) -> np.ndarray:
    if basis is None or not hasattr(basis, "vectors") or not hasattr(basis, "hash"):
        raise SpecTrHuMSError(
            f"basis: expected a spectral basis with 'vectors' (V, k) and "
            f"'hash' (the benchmark supplies it: registry context [basis]), "
            f"got {type(basis).__name__}"
        )
    phi = np.asarray(basis.vectors, dtype=np.float64)
    if phi.ndim != 2 or phi.shape[1] < 1:
        raise SpecTrHuMSError(f"basis: vectors must be a matrix (V, k), got shape {phi.shape}")
    if phi.shape[0] != num_points:
        raise SpecTrHuMSError(
            f"basis: {phi.shape[0]} vertices (basis {str(basis.hash)[:12]}), "
            f"but num_points={num_points}: the basis must belong to the "
            f"benchmark's mesh"
        )
    if phi.shape[1] > phi.shape[0]:
        raise SpecTrHuMSError(f"basis: k={phi.shape[1]} vectors exceed V={phi.shape[0]}")
    gram_error = np.abs(phi.T @ phi - np.eye(phi.shape[1])).max()
    if not gram_error < 1e-4:
        raise SpecTrHuMSError(
            f"basis: vectors are not orthonormal (max |Phi^T Phi - I| = "
            f"{gram_error:.2g}); reconstruction V = Phi C needs them to be"
        )
    return phi
