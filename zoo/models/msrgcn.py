"""MSR-GCN, as its public code runs on CMU: the body at four scales and a U-shaped graph network
down and back up them, a residual prediction on DCT coefficients supervised at every scale.

Dang, Nie, Long, Zhang, Li. MSR-GCN: Multi-Scale Residual Graph Convolution Networks for Human
Motion Prediction. ICCV 2021. Scales, data flow, normalisation and loss: docs/models/msrgcn.md
("As built, and where it departs from paper and code").
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence

import torch
from torch import Tensor, nn

from zoo.models.dct import dct_matrix
from zoo.models.dropout import Dropout
from zoo.models.ltd import GraphConvolution


def _integer(name: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(f"MSR-GCN: {name} must be an integer >= {low}, got {value!r}")
    return value


class _Activation(nn.Module):
    """BatchNorm over the flattened ``(nodes x features)`` vector, LeakyReLU, dropout."""

    def __init__(self, size: int, slope: float, dropout: float) -> None:
        super().__init__()
        self.norm = nn.BatchNorm1d(size)
        self.slope = slope
        self.dropout = Dropout(dropout)

    def forward(self, y: Tensor) -> Tensor:
        y = self.norm(y.reshape(y.shape[0], -1)).view(y.shape)
        return self.dropout(nn.functional.leaky_relu(y, self.slope))


class GraphLayer(nn.Module):
    def __init__(self, nodes: int, in_features: int, out_features: int, slope, dropout) -> None:
        super().__init__()
        self.conv = GraphConvolution(nodes, in_features, out_features)
        self.act = _Activation(nodes * out_features, slope, dropout)

    def forward(self, x: Tensor) -> Tensor:
        return self.act(self.conv(x))


class ResidualBlock(nn.Module):
    """Two graph layers with an identity skip."""

    def __init__(self, nodes: int, features: int, slope: float, dropout: float) -> None:
        super().__init__()
        self.first = GraphLayer(nodes, features, features, slope, dropout)
        self.second = GraphLayer(nodes, features, features, slope, dropout)

    def forward(self, x: Tensor) -> Tensor:
        return self.second(self.first(x)) + x


class Blocks(nn.Module):
    """``count`` residual blocks, with a skip over all of them."""

    def __init__(self, count: int, nodes: int, features: int, slope, dropout) -> None:
        super().__init__()
        self.blocks = nn.Sequential(
            *(ResidualBlock(nodes, features, slope, dropout) for _ in range(count))
        )

    def forward(self, x: Tensor) -> Tensor:
        return self.blocks(x) + x


class AxisMap(nn.Module):
    """A linear map over one axis of ``(B, N, F)``, then the activation: over the nodes
    (``(B, N_in, F) -> (B, N_out, F)``, ``other`` = F) or over the features
    (``(B, N, F_in) -> (B, N, F_out)``, ``other`` = N)."""

    def __init__(self, size_in: int, size_out: int, other: int, slope, dropout, nodes: bool):
        super().__init__()
        self.nodes = nodes
        self.linear = nn.Linear(size_in, size_out)
        self.act = _Activation(size_out * other, slope, dropout)

    def forward(self, x: Tensor) -> Tensor:
        if self.nodes:
            return self.act(self.linear(x.transpose(1, 2))).transpose(1, 2)
        return self.act(self.linear(x))


def NodeMap(nodes_in: int, nodes_out: int, features: int, slope, dropout) -> AxisMap:
    return AxisMap(nodes_in, nodes_out, features, slope, dropout, nodes=True)


def FeatureMap(nodes: int, features_in: int, features_out: int, slope, dropout) -> AxisMap:
    return AxisMap(features_in, features_out, nodes, slope, dropout, nodes=False)


class MSRGCN(nn.Module):
    def __init__(
        self,
        input_frames: int,
        output_frames: int,
        num_points: int,
        groups: Sequence[Sequence[Sequence[int]]],
        widths: Sequence[int] = (64, 128, 256, 512),
        blocks: int = 3,
        head_blocks: Sequence[int] = (6, 1, 1, 1),
        dct_n: int = 35,
        dropout: float = 0.1,
        negative_slope: float = 0.2,
    ) -> None:
        super().__init__()
        self.input_frames = _integer("input_frames", input_frames, 1)
        self.output_frames = _integer("output_frames", output_frames, 1)
        self.num_points = _integer("num_points", num_points, 1)
        frames = input_frames + output_frames
        if _integer("dct_n", dct_n, 1) > frames:
            raise ValueError(
                f"MSR-GCN: dct_n = {dct_n} exceeds the {frames} frames (input_frames + "
                f"output_frames) it keeps coefficients of"
            )
        if (
            isinstance(dropout, bool)
            or not isinstance(dropout, (int, float))
            or not 0 <= dropout < 1
        ):
            raise ValueError(f"MSR-GCN: dropout must be a probability in [0, 1), got {dropout!r}")
        points = [num_points]
        for i, scale in enumerate(groups):
            flat = [p for group in scale for p in group]
            if (
                not scale
                or any(not group for group in scale)
                or not all(isinstance(p, int) and 0 <= p < points[-1] for p in flat)
            ):
                raise ValueError(
                    f"MSR-GCN: groups[{i}] must be non-empty groups of point indices below "
                    f"{points[-1]} (the previous scale's points), got {scale!r}"
                )
            points.append(len(scale))
        if len(widths) != len(points) or len(head_blocks) != len(points):
            raise ValueError(
                f"MSR-GCN: {len(points)} scales (groups + 1) need as many widths and "
                f"head_blocks, got {len(widths)} and {len(head_blocks)}"
            )
        _integer("blocks", blocks, 0)
        for w in widths:
            _integer("widths[i]", w, 1)
        for h in head_blocks:
            _integer("head_blocks[i]", h, 0)
        self.dct_n = dct_n
        self.points = points
        # each coarser scale as a (points, finer points) averaging matrix
        for i, scale in enumerate(groups):
            mean = torch.zeros(len(scale), points[i])
            for row, group in enumerate(scale):
                mean[row, list(group)] = 1.0 / len(group)
            self.register_buffer(f"pool{i}", mean, persistent=False)
        dct = dct_matrix(frames)
        self.register_buffer("dct", dct[:dct_n].contiguous(), persistent=False)
        self.register_buffer("idct", dct[:dct_n].T.contiguous(), persistent=False)
        # the range that maps the inputs to [-1, 1] (set_range); stored with the weights
        self.register_buffer("low", torch.tensor(-1.0))
        self.register_buffer("high", torch.tensor(1.0))
        self.register_buffer("range_frames", torch.tensor(0, dtype=torch.long))
        nodes = [3 * p for p in points]
        a, d = negative_slope, dropout
        scales = range(len(points))
        self.enter = nn.ModuleList(
            GraphLayer(nodes[s], dct_n if s == 0 else widths[s - 1], widths[s], a, d)
            for s in scales
        )
        self.down = nn.ModuleList(
            NodeMap(nodes[s], nodes[s + 1], widths[s], a, d) for s in scales[:-1]
        )
        self.encode = nn.ModuleList(Blocks(blocks, nodes[s], widths[s], a, d) for s in scales)
        self.decode = nn.ModuleList(Blocks(blocks, nodes[s], widths[s], a, d) for s in scales)
        self.up = nn.ModuleList(
            nn.Sequential(
                NodeMap(nodes[s + 1], nodes[s], widths[s + 1], a, d),
                FeatureMap(nodes[s], widths[s + 1], widths[s], a, d),
            )
            for s in scales[:-1]
        )
        self.merge = nn.ModuleList(
            NodeMap(2 * nodes[s], nodes[s], widths[s], a, d) for s in scales[:-1]
        )
        self.heads = nn.ModuleList(
            Blocks(head_blocks[s], nodes[s], widths[s], a, d) for s in scales
        )
        self.readout = nn.ModuleList(GraphConvolution(nodes[s], widths[s], dct_n) for s in scales)

    def scales(self, frames: Tensor) -> list[Tensor]:
        """``frames (B, T, P, 3)`` at every scale, finest first."""
        out = [frames]
        for i in range(len(self.points) - 1):
            out.append(torch.einsum("qp,btpc->btqc", getattr(self, f"pool{i}"), out[-1]))
        return out

    def _coefficients(self, frames: Tensor) -> Tensor:
        """``(B, 3P, dct_n)``: node ``3p + c`` holds coordinate ``c`` of point ``p``."""
        flat = frames.reshape(frames.shape[0], frames.shape[1], -1)
        return torch.matmul(self.dct, flat).transpose(1, 2)

    def _normalised(self, x: Tensor) -> Tensor:
        return (x - self.low) / (self.high - self.low) * 2 - 1

    def reconstruct(self, history: Tensor) -> list[Tensor]:
        """All ``T`` frames ``(B, T, P_s, 3)`` of every scale, finest first, in mm."""
        if history.ndim != 4 or tuple(history.shape[1:]) != (self.input_frames, self.num_points, 3):
            raise ValueError(
                f"MSR-GCN: history must have shape (B, {self.input_frames}, "
                f"{self.num_points}, 3), got {tuple(history.shape)}"
            )
        padded = torch.cat([history, history[:, -1:].expand(-1, self.output_frames, -1, -1)], dim=1)
        inputs = [self._normalised(self._coefficients(f)) for f in self.scales(padded)]
        last = len(self.points) - 1
        down, h = [], inputs[0]
        for s in range(last + 1):
            h = self.encode[s](self.enter[s](h))
            down.append(h)
            if s < last:
                h = self.down[s](h)
        up = [None] * (last + 1)
        up[last] = self.decode[last](down[last])
        for s in range(last - 1, -1, -1):
            stacked = torch.cat([down[s], self.up[s](up[s + 1])], dim=1)
            up[s] = self.decode[s](self.merge[s](stacked))
        out = []
        for s in range(last + 1):
            coefficients = self.readout[s](self.heads[s](up[s])) + inputs[s]
            coefficients = (coefficients + 1) / 2 * (self.high - self.low) + self.low
            frames = torch.matmul(self.idct, coefficients.transpose(1, 2))
            out.append(frames.reshape(history.shape[0], -1, self.points[s], 3))
        return out

    def forward(self, history: Tensor) -> Tensor:
        return self.reconstruct(history)[0][:, self.input_frames :]

    def training_loss(self, history: Tensor, future: Tensor) -> Tensor:
        """Every scale supervised: the sum over scales of the mean point distance (mm, not
        squared) over all ``T_in + T_out`` frames."""
        expected = (self.output_frames, self.num_points, 3)
        if future.ndim != 4 or tuple(future.shape[1:]) != expected:
            raise ValueError(
                f"MSR-GCN: future must have shape (B, {self.output_frames}, "
                f"{self.num_points}, 3), got {tuple(future.shape)}"
            )
        targets = self.scales(torch.cat([history, future], dim=1))
        predictions = self.reconstruct(history)
        return sum(
            torch.linalg.vector_norm(p - t, dim=-1).mean() for p, t in zip(predictions, targets)
        )

    def start_epoch(self, epoch: int, frames: Callable[[], Iterable[tuple[Tensor, Tensor]]]):
        """Training-engine hook: in the first epoch (or while never set) the range that maps
        the network's inputs to [-1, 1] (:meth:`set_range`)."""
        if epoch == 0 or int(self.range_frames) == 0:
            self.set_range(frames())

    @torch.no_grad()
    def set_range(self, frames: Iterable[tuple[Tensor, Tensor]]) -> None:
        """The smallest and largest value over the training frames' positions at every scale
        and over the DCT coefficients of a window standing still at each of them (the public
        code takes both over its training windows; a still window's first coefficient,
        ``sqrt(T)`` times the position, bounds what a moving one reaches)."""
        low, high, count = math.inf, -math.inf, 0
        root = math.sqrt(self.input_frames + self.output_frames)
        for batch, _ in frames:
            for positions in self.scales(batch[:, None].to(self.low.dtype)):
                lo, hi = float(positions.min()), float(positions.max())
                low = min(low, lo, root * lo, 0.0)
                high = max(high, hi, root * hi, 0.0)
            count += batch.shape[0]
        if count == 0 or not high > low:
            raise ValueError("MSR-GCN: no training frames (or all equal) to take a range from")
        self.low.fill_(low)
        self.high.fill_(high)
        self.range_frames.fill_(count)


__all__ = ["MSRGCN"]
