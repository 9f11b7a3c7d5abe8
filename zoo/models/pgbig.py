"""PGBIG, as its paper describes it: stages of encoder-copy-decoder graph networks on DCT
coefficients, each learning a less smoothed future than the last and passing its guess on.

Ma, Nie, Long, Zhou, Yan, Liu. Progressively Generating Better Initial Guesses Towards Next
Stages for High-Quality Human Motion Prediction. CVPR 2022. Data flow, layers, targets and where
paper and code differ: docs/models/pgbig.md ("As built, and where it departs from paper and code").
"""

from __future__ import annotations

import math

import torch
from torch import nn

from zoo.models.dct import dct_matrix
from zoo.models.dropout import Dropout

STAGE_INPUTS = ("observed", "previous")


def _integer(name: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(f"PGBIG: {name} must be an integer >= {low}, got {value!r}")
    return value


class PlainLayer(nn.Module):
    """Joint, channel and coefficient mixing plus a bias over ``x (B, C_in, P, L)``."""

    def __init__(self, joints: int, length: int, in_channels: int, out_channels: int) -> None:
        super().__init__()
        self.joints = nn.Parameter(torch.empty(joints, joints))
        self.channels = nn.Parameter(torch.empty(in_channels, out_channels))
        self.coefficients = nn.Parameter(torch.empty(length, length))
        self.bias = nn.Parameter(torch.empty(length))
        bound = 1.0 / math.sqrt(joints)
        for parameter in (self.joints, self.channels, self.coefficients, self.bias):
            nn.init.uniform_(parameter, -bound, bound)

    def forward(self, x: torch.Tensor, copies: int = 1, keep: int | None = None) -> torch.Tensor:
        """The layer applied to ``x`` repeated ``copies`` times along the coefficient axis,
        its first ``keep`` output coefficients (default all)."""
        b, c, p, n = x.shape
        coefficients, bias = self.coefficients, self.bias
        if copies * n != len(coefficients):
            raise ValueError(
                f"PGBIG layer of {len(coefficients)} coefficients given {copies} x {n}"
            )
        if copies > 1:  # [x, x] W = x (W_top + W_bottom): no copy made, half the product
            coefficients = coefficients.view(copies, n, -1).sum(dim=0)
        if keep is not None:  # output coefficients nobody reads are not computed
            coefficients, bias = coefficients[:, :keep], bias[:keep]
        # The three mixings commute (one linear map per axis), so each is applied where its
        # tensor is smallest: a mixing that shrinks an axis first, one that grows it last.
        # None copies its input: the coefficient axis as one matrix product, joints and
        # channels as batched products with the weight broadcast over the batch.
        shrinks_channels = self.channels.shape[1] < c
        shrinks_length = coefficients.shape[1] <= n
        y = x
        if shrinks_channels:
            y = self._mix_channels(y)
        if shrinks_length:
            y = torch.matmul(y, coefficients)
        rows = y.shape[0] * y.shape[1]
        y = torch.matmul(self.joints.expand(rows, p, p), y.reshape(rows, p, y.shape[3]))
        y = y.view(b, -1, p, y.shape[2])
        if not shrinks_length:
            y = torch.matmul(y, coefficients)
        if not shrinks_channels:
            y = self._mix_channels(y)
        return y + bias

    def _mix_channels(self, x: torch.Tensor) -> torch.Tensor:
        b, c, p, length = x.shape
        y = torch.matmul(self.channels.t().expand(b, -1, -1), x.reshape(b, c, p * length))
        return y.view(b, -1, p, length)


class GraphLayer(nn.Module):
    """A plain layer, BatchNorm over the flattened ``C x P x L`` vector, tanh, dropout."""

    def __init__(
        self, joints: int, length: int, in_channels: int, out_channels: int, dropout: float
    ) -> None:
        super().__init__()
        self.layer = PlainLayer(joints, length, in_channels, out_channels)
        self.norm = nn.BatchNorm1d(out_channels * joints * length)
        self.dropout = Dropout(dropout)

    def forward(self, x: torch.Tensor, copies: int = 1) -> torch.Tensor:
        y = self.layer(x, copies).contiguous()
        y = self.norm(y.view(y.shape[0], -1)).view(y.shape)
        return self.dropout(torch.tanh(y))


class ResidualBlock(nn.Module):
    def __init__(self, joints: int, length: int, channels: int, dropout: float) -> None:
        super().__init__()
        self.first = GraphLayer(joints, length, channels, channels, dropout)
        self.second = GraphLayer(joints, length, channels, channels, dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.second(self.first(x)) + x


class Coder(nn.Module):
    """A graph layer, residual blocks and a plain layer, plus a 1x1 convolution of the input:
    PGBIG's encoder (``C -> d_model`` at length ``L``) and decoder (``d_model -> C`` at ``2L``)."""

    def __init__(
        self,
        joints: int,
        length: int,
        in_channels: int,
        hidden: int,
        out_channels: int,
        blocks: int,
        dropout: float,
    ) -> None:
        super().__init__()
        self.first = GraphLayer(joints, length, in_channels, hidden, dropout)
        self.blocks = nn.ModuleList(
            ResidualBlock(joints, length, hidden, dropout) for _ in range(blocks)
        )
        self.last = PlainLayer(joints, length, hidden, out_channels)
        self.skip = nn.Conv2d(in_channels, out_channels, kernel_size=1)

    def forward(self, x: torch.Tensor, copies: int = 1, keep: int | None = None) -> torch.Tensor:
        """The coder applied to ``x`` repeated ``copies`` times along the coefficient axis, its
        first ``keep`` output coefficients (default all)."""
        y = self.first(x, copies)
        for block in self.blocks:
            y = block(y)
        n = x.shape[3]
        keep = copies * n if keep is None else keep
        # The 1x1 convolution acts on each coefficient alone: of the copies, only those kept.
        skip = self.skip(x[..., : min(keep, n)])
        if keep > n:
            skip = skip.repeat(1, 1, 1, copies)[..., :keep]
        return self.last(y, keep=keep) + skip


class Stage(nn.Module):
    """Encoder, copy along the coefficient axis, decoder; the first ``L`` coefficients."""

    def __init__(
        self,
        joints: int,
        length: int,
        d_model: int,
        encoder_blocks: int,
        decoder_blocks: int,
        dropout: float,
    ) -> None:
        super().__init__()
        self.length = length
        self.encoder = Coder(joints, length, 3, d_model, d_model, encoder_blocks, dropout)
        self.decoder = Coder(joints, 2 * length, d_model, d_model, 3, decoder_blocks, dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.decoder(self.encoder(x), copies=2, keep=self.length)


def smooth(window: torch.Tensor, observed: int) -> torch.Tensor:
    """Accumulated-average smoothing of ``window (B, T, ...)``: future frame ``t`` becomes the
    mean of future frames ``1..t``; the ``observed`` first frames are unchanged."""
    future = window[:, observed:]
    counts = torch.arange(1, future.shape[1] + 1, dtype=window.dtype, device=window.device)
    means = future.cumsum(dim=1) / counts.view(-1, *([1] * (future.ndim - 2)))
    return torch.cat([window[:, :observed], means], dim=1)


class PGBIG(nn.Module):
    def __init__(
        self,
        input_frames: int,
        output_frames: int,
        num_points: int,
        stages: int = 4,
        d_model: int = 16,
        encoder_blocks: int = 1,
        decoder_blocks: int = 2,
        dct_n: int = 35,
        dropout: float = 0.3,
        stage_input: str = "observed",
    ) -> None:
        super().__init__()
        self.input_frames = _integer("input_frames", input_frames, 1)
        self.output_frames = _integer("output_frames", output_frames, 1)
        self.num_points = _integer("num_points", num_points, 1)
        _integer("stages", stages, 1)
        _integer("d_model", d_model, 1)
        _integer("encoder_blocks", encoder_blocks, 0)
        _integer("decoder_blocks", decoder_blocks, 0)
        frames = input_frames + output_frames
        if _integer("dct_n", dct_n, 1) > frames:
            raise ValueError(
                f"PGBIG: dct_n = {dct_n} exceeds the {frames} frames "
                f"(input_frames + output_frames) it keeps coefficients of"
            )
        if (
            isinstance(dropout, bool)
            or not isinstance(dropout, (int, float))
            or not 0 <= dropout < 1
        ):
            raise ValueError(f"PGBIG: dropout must be a probability in [0, 1), got {dropout!r}")
        if stage_input not in STAGE_INPUTS:
            raise ValueError(
                f"PGBIG: stage_input must be one of {', '.join(STAGE_INPUTS)} (observed: the "
                f"paper's Eq. 1; previous: the public code), got {stage_input!r}"
            )
        self.stage_input = stage_input
        self.dct_n = dct_n
        dct = dct_matrix(frames)
        self.register_buffer("dct", dct[:dct_n].contiguous(), persistent=False)  # (L, T)
        self.register_buffer("idct", dct[:dct_n].T.contiguous(), persistent=False)  # (T, L)
        self.stages = nn.ModuleList(
            Stage(num_points, dct_n, d_model, encoder_blocks, decoder_blocks, dropout)
            for _ in range(stages)
        )

    def _check(self, motion: torch.Tensor, name: str, frames: int) -> None:
        expected = (frames, self.num_points, 3)
        if motion.ndim != 4 or tuple(motion.shape[1:]) != expected:
            raise ValueError(
                f"PGBIG: {name} must have shape (B, {frames}, {self.num_points}, 3), "
                f"got {tuple(motion.shape)}"
            )

    def to_coefficients(self, frames: torch.Tensor) -> torch.Tensor:
        """``(B, T, P, 3)`` frames -> ``(B, 3, P, L)`` DCT coefficients."""
        return torch.einsum("lt,btpc->bcpl", self.dct, frames.to(self.dct.dtype))

    def to_frames(self, coefficients: torch.Tensor) -> torch.Tensor:
        """``(B, 3, P, L)`` coefficients -> ``(B, T, P, 3)`` frames (inverse DCT)."""
        return torch.einsum("tl,bcpl->btpc", self.idct, coefficients)

    def stage_outputs(self, history: torch.Tensor) -> list[torch.Tensor]:
        """Every stage's ``T_in + T_out`` frames ``(B, T, P, 3)`` in mm, first stage first."""
        self._check(history, "history", self.input_frames)
        padded = torch.cat([history, history[:, -1:].expand(-1, self.output_frames, -1, -1)], dim=1)
        x = self.to_coefficients(padded)
        outputs = []
        for i, stage in enumerate(self.stages):
            if i and self.stage_input == "observed":
                x = self.to_coefficients(
                    torch.cat([history, outputs[-1][:, self.input_frames :]], dim=1)
                )
            y = stage(x)
            outputs.append(self.to_frames(y))
            x = y
        return outputs

    def forward(self, history: torch.Tensor) -> torch.Tensor:
        return self.stage_outputs(history)[-1][:, self.input_frames :]

    def stage_targets(self, history: torch.Tensor, future: torch.Tensor) -> list[torch.Tensor]:
        """Each stage's target ``(B, T, P, 3)``: the ground truth smoothed ``S - s`` times."""
        target = torch.cat([history, future], dim=1)
        targets = [target]
        for _ in range(len(self.stages) - 1):
            targets.append(smooth(targets[-1], self.input_frames))
        return targets[::-1]

    def training_loss(self, history: torch.Tensor, future: torch.Tensor) -> torch.Tensor:
        """Mean over stages of the mean joint distance (mm) over all ``T`` frames, each stage
        against its own smoothed target."""
        self._check(future, "future", self.output_frames)
        losses = [
            torch.linalg.vector_norm(output - target, dim=-1).mean()
            for output, target in zip(
                self.stage_outputs(history), self.stage_targets(history, future)
            )
        ]
        return torch.stack(losses).mean()


__all__ = ["PGBIG", "smooth"]
