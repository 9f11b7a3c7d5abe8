"""LTD, as its paper and its public CMU code describe it: graph convolutions over joint-coordinate
trajectories' DCT coefficients, a residual in DCT space.

Mao, Liu, Salzmann, Li. Learning Trajectory Dependencies for Human Motion Prediction. ICCV 2019.
Data flow, initialisation, loss and dropout: docs/models/ltd.md ("As built, and where it departs
from paper and code").
"""

from __future__ import annotations

import math

import torch
from torch import nn

from zoo.models.dct import dct_matrix
from zoo.models.dropout import Dropout


def _integer(name: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(f"LTD: {name} must be an integer >= {low}, got {value!r}")
    return value


class GraphConvolution(nn.Module):
    """``A (X W) + b`` on node features ``X (B, N, F_in)`` with a learnable dense ``A (N, N)``."""

    def __init__(self, nodes: int, in_features: int, out_features: int) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.empty(in_features, out_features))
        self.adjacency = nn.Parameter(torch.empty(nodes, nodes))
        self.bias = nn.Parameter(torch.empty(out_features))
        bound = 1.0 / math.sqrt(out_features)
        for parameter in (self.weight, self.adjacency, self.bias):
            nn.init.uniform_(parameter, -bound, bound)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        support = torch.matmul(x, self.weight)
        # the adjacency broadcast over the batch: a batched product that copies nothing
        adjacency = self.adjacency.expand(x.shape[0], -1, -1)
        return torch.matmul(adjacency, support) + self.bias


class GraphLayer(nn.Module):
    """Graph convolution, BatchNorm over the flattened ``N x F`` vector, tanh, dropout."""

    def __init__(self, nodes: int, in_features: int, out_features: int, dropout: float) -> None:
        super().__init__()
        self.conv = GraphConvolution(nodes, in_features, out_features)
        self.norm = nn.BatchNorm1d(nodes * out_features)
        self.dropout = Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.conv(x)
        y = self.norm(y.reshape(y.shape[0], -1)).view(y.shape)
        return self.dropout(torch.tanh(y))


class ResidualBlock(nn.Module):
    """Two graph layers with an identity skip."""

    def __init__(self, nodes: int, features: int, dropout: float) -> None:
        super().__init__()
        self.first = GraphLayer(nodes, features, features, dropout)
        self.second = GraphLayer(nodes, features, features, dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.second(self.first(x)) + x


class LTD(nn.Module):
    def __init__(
        self,
        input_frames: int,
        output_frames: int,
        num_points: int,
        hidden: int = 256,
        blocks: int = 12,
        dct_n: int = 35,
        dropout: float = 0.5,
    ) -> None:
        super().__init__()
        self.input_frames = _integer("input_frames", input_frames, 1)
        self.output_frames = _integer("output_frames", output_frames, 1)
        self.num_points = _integer("num_points", num_points, 1)
        _integer("hidden", hidden, 1)
        _integer("blocks", blocks, 0)
        frames = input_frames + output_frames
        if _integer("dct_n", dct_n, 1) > frames:
            raise ValueError(
                f"LTD: dct_n = {dct_n} exceeds the {frames} frames "
                f"(input_frames + output_frames) it keeps coefficients of"
            )
        if (
            isinstance(dropout, bool)
            or not isinstance(dropout, (int, float))
            or not 0 <= dropout < 1
        ):
            raise ValueError(f"LTD: dropout must be a probability in [0, 1), got {dropout!r}")
        nodes = 3 * num_points
        self.dct_n = dct_n
        dct = dct_matrix(frames)
        self.register_buffer("dct", dct[:dct_n].contiguous(), persistent=False)  # (dct_n, T)
        self.register_buffer("idct", dct[:dct_n].T.contiguous(), persistent=False)  # (T, dct_n)
        self.embed = GraphLayer(nodes, dct_n, hidden, dropout)
        self.blocks = nn.ModuleList(ResidualBlock(nodes, hidden, dropout) for _ in range(blocks))
        self.readout = GraphConvolution(nodes, hidden, dct_n)

    def coefficients(self, history: torch.Tensor) -> torch.Tensor:
        """The network's input ``(B, N, dct_n)``: DCT coefficients of the padded history, node
        ``3p + c`` being coordinate ``c`` of point ``p``."""
        if history.ndim != 4 or tuple(history.shape[1:]) != (self.input_frames, self.num_points, 3):
            raise ValueError(
                f"LTD: history must have shape (B, {self.input_frames}, "
                f"{self.num_points}, 3), got {tuple(history.shape)}"
            )
        batch = history.shape[0]
        padded = torch.cat(
            [history, history[:, -1:].expand(-1, self.output_frames, -1, -1)], dim=1
        ).reshape(batch, self.input_frames + self.output_frames, -1)
        return torch.matmul(self.dct, padded.to(self.dct.dtype)).transpose(1, 2)

    def reconstruct(self, history: torch.Tensor) -> torch.Tensor:
        """All ``T_in + T_out`` frames ``(B, T, P, 3)`` in mm."""
        x = self.coefficients(history)
        h = self.embed(x)
        for block in self.blocks:
            h = block(h)
        out = self.readout(h) + x
        frames = torch.matmul(self.idct, out.transpose(1, 2))
        return frames.reshape(history.shape[0], -1, self.num_points, 3)

    def forward(self, history: torch.Tensor) -> torch.Tensor:
        return self.reconstruct(history)[:, self.input_frames :]

    def training_loss(self, history: torch.Tensor, future: torch.Tensor) -> torch.Tensor:
        """Mean joint distance (mm, not squared) over all ``T_in + T_out`` frames."""
        expected = (self.output_frames, self.num_points, 3)
        if future.ndim != 4 or tuple(future.shape[1:]) != expected:
            raise ValueError(
                f"LTD: future must have shape (B, {self.output_frames}, "
                f"{self.num_points}, 3), got {tuple(future.shape)}"
            )
        target = torch.cat([history, future], dim=1)
        return torch.linalg.vector_norm(self.reconstruct(history) - target, dim=-1).mean()


__all__ = ["LTD", "GraphConvolution"]
