"""SPGSN, the design of its paper, not that of its public code: multi-part adaptive graph
scattering blocks on the DCT coefficients of the padded input.

Li, Chen, Zhang, Xie, Tian, Zhang. Skeleton-Parted Graph Scattering Networks for 3D Human Motion
Prediction. ECCV 2022. Data flow, blocks, the zoo's own options and how the code is batched:
docs/models/spgsn.md ("Architecture").
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import torch
from torch import nn

from zoo.models.dct import dct_matrix

PART_NAMES = ("upper", "lower")
MM_PER_M = 1000.0


class _Tanh(torch.autograd.Function):
    """``tanh(x)`` computed as ``2 sigmoid(2x) - 1``: the same function (to ~1e-7 absolute), but
    ATen's float sigmoid is the faster of the two on a CPU (docs/models/spgsn.md, Architecture)."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        y = torch.mul(x, 2.0).sigmoid_().mul_(2.0).sub_(1.0)
        ctx.save_for_backward(y)
        return y

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (y,) = ctx.saved_tensors
        return torch.ops.aten.tanh_backward(grad, y)  # grad * (1 - y^2)


def tanh(x: torch.Tensor) -> torch.Tensor:
    return _Tanh.apply(x)


def _integer(name: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(f"SPGSN: {name} must be an integer >= {low}, got {value!r}")
    return value


def _part_nodes(parts: Mapping[str, Sequence[int]] | None, num_points: int) -> dict[str, list[int]]:
    """Check the ``parts`` context and expand joints to their 3 coordinate nodes."""
    if not isinstance(parts, Mapping):
        raise ValueError(
            f"SPGSN: parts must be a mapping {{'upper': [...], 'lower': [...]}} of "
            f"joint indices (the benchmark's 'parts' context), got {parts!r}"
        )
    if set(parts) != set(PART_NAMES):
        raise ValueError(
            f"SPGSN: parts must have exactly the keys 'upper' and 'lower', got {sorted(parts)}"
        )
    seen: dict[int, str] = {}
    nodes = {}
    for name in PART_NAMES:
        joints = list(parts[name])
        if not joints:
            raise ValueError(f"SPGSN: parts[{name!r}] is empty; every part needs a joint")
        for j in joints:
            if isinstance(j, bool) or not isinstance(j, int) or not 0 <= j < num_points:
                raise ValueError(
                    f"SPGSN: parts[{name!r}] holds {j!r}; expected joint indices in "
                    f"0..{num_points - 1} (num_points = {num_points})"
                )
            if j in seen:
                raise ValueError(
                    f"SPGSN: joint {j} is listed in parts[{seen[j]!r}] and again in "
                    f"parts[{name!r}]; body parts must be disjoint"
                )
            seen[j] = name
        nodes[name] = [3 * j + c for j in joints for c in range(3)]
    return nodes


def filter_coefficient_mask(order: int) -> torch.Tensor:
    """Which basis matrices each filter may use: rows are ``h_0 .. h_K``, columns the basis
    ``[A, I, A~, A~^2, A~^4, ..., A~^(2^(K-1))]``."""
    mask = torch.zeros(order + 1, order + 2)
    mask[0, 0] = 1  # h_0 = a00 A
    if order >= 1:
        mask[1, 1:3] = 1  # h_1 = a10 I + a11 A~
    for k in range(2, order + 1):
        mask[k, 2 : k + 2] = 1  # h_k = sum_{j=1..k} a_kj A~^(2^(j-1))
    return mask


def initial_filter_coefficients(order: int) -> torch.Tensor:
    """Diffusion wavelets: ``h_0 = A``, ``h_1 = I - A~``, ``h_k = A~^(2^(k-2)) - A~^(2^(k-1))``."""
    coefficients = torch.zeros(order + 1, order + 2)
    coefficients[0, 0] = 1.0
    for k in range(1, order + 1):
        coefficients[k, k] = 1.0  # a_k,k-1 (column k holds I for k = 1, A~^(2^(k-2)) otherwise)
        coefficients[k, k + 1] = -1.0  # a_kk
    return coefficients


class ScatteringBlock(nn.Module):
    """One multi-part graph scattering block; its graphs' filter banks come from :class:`SPGSN`."""

    def __init__(
        self,
        hidden: int,
        layers: int,
        order: int,
        aggregation_dim: int,
        fusion_dim: int,
        dropout: float,
        fuse_parts: bool,
    ) -> None:
        super().__init__()
        filters = order + 1
        self.hidden, self.layers, self.filters = hidden, layers, filters
        # W_k of the first layer as one (C, (K+1) C) matrix: X @ it gives every X W_k at once.
        self.first_weight = nn.Parameter(torch.empty(hidden, filters, hidden))
        self.deeper_weights = nn.Parameter(torch.empty(layers - 1, filters, hidden, hidden))
        for k in range(filters):
            nn.init.xavier_uniform_(self.first_weight[:, k])
            for layer in range(layers - 1):
                nn.init.xavier_uniform_(self.deeper_weights[layer, k])
        self.spectrum = nn.Linear(hidden, hidden, bias=False)  # W_sp
        # f1 on the concatenation [H_sp, H_k] = f1_sp(H_sp) + f1_leaf(H_k): H_sp's half once.
        self.attention_sp = nn.Linear(hidden, aggregation_dim)
        self.attention_leaf = nn.Linear(hidden, aggregation_dim, bias=False)
        self.attention_out = nn.Linear(aggregation_dim, 1)  # f2
        self.fuse_parts = fuse_parts
        if fuse_parts:  # f_up, f_low: the authors' code's two bias-free layers
            self.embed_upper = nn.Sequential(
                nn.Linear(hidden, fusion_dim, bias=False),
                nn.ReLU(),
                nn.Linear(fusion_dim, fusion_dim, bias=False),
            )
            self.embed_lower = nn.Sequential(
                nn.Linear(hidden, fusion_dim, bias=False),
                nn.ReLU(),
                nn.Linear(fusion_dim, fusion_dim, bias=False),
            )
        self.mlp = nn.Sequential(nn.Linear(hidden, hidden), nn.ReLU())
        self.dropout = nn.Dropout(dropout)

    def forward(
        self, x: torch.Tensor, banks: dict[str, torch.Tensor], part_index: dict[str, torch.Tensor]
    ) -> torch.Tensor:
        """``x``: ``(N, B, C)``; ``banks[part]``: ``(K+1, N_p, N_p)``; returns ``(N, B, C)``."""
        nodes, batch, hidden = x.shape
        filters = self.filters
        # First layer, weights first: every X W_k once for all parts, as (K+1, N, B*C).
        projected = torch.matmul(
            x.reshape(nodes * batch, hidden), self.first_weight.reshape(hidden, filters * hidden)
        )
        projected = projected.reshape(nodes, batch, filters, hidden).permute(2, 0, 1, 3)
        projected = projected.contiguous().reshape(filters, nodes, batch * hidden)
        aggregated = {}
        for part, bank in banks.items():
            rows = projected if part == "whole" else projected.index_select(1, part_index[part])
            part_nodes = rows.shape[1]
            channels = tanh(torch.bmm(bank, rows))  # (K+1, N_p, B*C): tanh(h_k X W_k)
            # Tree channels as (filter, node, parent channel, batch, feature): the filter axis
            # first for the per-filter weights, the node axis before the parents for the graphs.
            channels = channels.reshape(filters, part_nodes, 1, batch, hidden)
            for layer in range(self.layers - 1):
                channels = self._scatter(channels, bank, self.deeper_weights[layer])
            aggregated[part] = self._aggregate(channels)
        whole = aggregated["whole"]
        if self.fuse_parts:
            upper, lower = self._fuse(aggregated["upper"], aggregated["lower"])
            # H_up' (+) H_low' at the body's node positions (a gather: index_add is slow on CPU);
            # nodes in no part read the appended zero row.
            placed = torch.cat([upper, lower, upper.new_zeros(1, batch, hidden)])
            whole = whole + placed.index_select(0, part_index["placement"])
        return self.dropout(self.mlp(whole))

    @staticmethod
    def _scatter(channels: torch.Tensor, bank: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
        """One deeper tree layer: every channel ``U`` to ``tanh(h_k U W_k)`` for every filter k.

        ``channels``: ``(F, N_p, M, B, C)`` (``F * M`` channels); returns
        ``(K+1, N_p, F * M, B, C)``.
        """
        _, nodes, _, batch, hidden = channels.shape
        filters = bank.shape[0]
        # Node-major: one product of all stacked filters ((K+1) N_p x N_p) with every channel.
        node_major = channels.transpose(0, 1).reshape(nodes, -1)
        parents = node_major.shape[1] // (batch * hidden)
        filtered = torch.matmul(bank.reshape(filters * nodes, nodes), node_major)
        # Then W_k per filter: one batched product, rows (node, parent, batch) contiguous.
        children = torch.bmm(filtered.reshape(filters, -1, hidden), weight)
        return tanh(children).reshape(filters, nodes, parents, batch, hidden)

    def _aggregate(self, leaves: torch.Tensor) -> torch.Tensor:
        """Spectrum aggregation of leaves ``(F, N_p, M, B, C)`` (``F * M`` channels): a softmax
        over the channels weighs them; returns ``(N_p, B, C)``."""
        channel_dims = (0, 2)
        count = leaves.shape[0] * leaves.shape[2]
        # sum(0).sum(1), not sum((0, 2)): one dim at a time is much faster (docs/models/spgsn.md).
        spectrum = torch.relu(self.spectrum(leaves.sum(0).sum(1) / count))
        scores = self.attention_out(
            tanh(self.attention_leaf(leaves) + self.attention_sp(spectrum)[:, None])
        )
        scores = scores - scores.amax(dim=channel_dims, keepdim=True)
        weights = scores.exp()
        weights = weights / weights.sum(dim=channel_dims, keepdim=True)
        return (weights * leaves).sum(0).sum(1)

    def _fuse(self, upper: torch.Tensor, lower: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Bipartite cross-part fusion; ``upper`` ``(N_up, B, C)``, ``lower`` ``(N_low, B, C)``."""
        affinity = torch.einsum("ubc,lbc->bul", self.embed_upper(upper), self.embed_lower(lower))
        lower_from_upper = torch.softmax(affinity, dim=1)  # each lower node: weights over upper
        upper_from_lower = torch.softmax(affinity, dim=2)  # each upper node: weights over lower
        new_lower = lower + torch.einsum("bul,ubc->lbc", lower_from_upper, upper)
        new_upper = upper + torch.einsum("bul,lbc->ubc", upper_from_lower, lower)
        return new_upper, new_lower


class SPGSN(nn.Module):
    def __init__(
        self,
        input_frames: int,
        output_frames: int,
        num_points: int,
        parts: Mapping[str, Sequence[int]] | None = None,
        body_parts: bool = True,
        blocks: int = 10,
        hidden: int = 256,
        scattering_layers: int = 2,
        filter_order: int = 2,
        dct_n: int = 30,
        aggregation_dim: int = 64,
        fusion_dim: int = 64,
        dropout: float = 0.5,
        metre_inputs: bool = True,
        zero_readout: bool = False,
    ) -> None:
        super().__init__()
        self.input_frames = _integer("input_frames", input_frames, 1)
        self.output_frames = _integer("output_frames", output_frames, 1)
        self.num_points = _integer("num_points", num_points, 1)
        _integer("blocks", blocks, 1)
        _integer("hidden", hidden, 1)
        _integer("scattering_layers", scattering_layers, 1)
        _integer("filter_order", filter_order, 0)
        _integer("aggregation_dim", aggregation_dim, 1)
        _integer("fusion_dim", fusion_dim, 1)
        frames = input_frames + output_frames
        if _integer("dct_n", dct_n, 1) > frames:
            raise ValueError(
                f"SPGSN: dct_n = {dct_n} exceeds the {frames} frames "
                f"(input_frames + output_frames) it keeps coefficients of"
            )
        if (
            isinstance(dropout, bool)
            or not isinstance(dropout, (int, float))
            or not 0 <= dropout < 1
        ):
            raise ValueError(f"SPGSN: dropout must be a probability in [0, 1), got {dropout!r}")
        for name, flag in (
            ("body_parts", body_parts),
            ("metre_inputs", metre_inputs),
            ("zero_readout", zero_readout),
        ):
            if not isinstance(flag, bool):
                raise ValueError(f"SPGSN: {name} must be true or false, got {flag!r}")
        # The network's coefficient unit: metres (inputs of order one) or the data's mm.
        self.unit = MM_PER_M if metre_inputs else 1.0
        self.dct_n = dct_n
        self.body_parts = body_parts
        nodes = 3 * num_points
        part_nodes = {"whole": list(range(nodes))}
        if body_parts:
            part_nodes.update(_part_nodes(parts, num_points))
        self.part_names = tuple(part_nodes)
        for name, index in part_nodes.items():
            self.register_buffer(
                f"{name}_nodes", torch.tensor(index, dtype=torch.long), persistent=False
            )
        if body_parts:
            # Row of node n in cat([upper, lower, zero row]): where fusion reads node n from.
            placement = torch.full((nodes,), len(part_nodes["upper"]) + len(part_nodes["lower"]))
            placement[part_nodes["upper"] + part_nodes["lower"]] = torch.arange(
                len(part_nodes["upper"]) + len(part_nodes["lower"])
            )
            self.register_buffer("placement_nodes", placement, persistent=False)
        dct = dct_matrix(frames)
        self.register_buffer("dct", dct[:dct_n].contiguous(), persistent=False)  # (dct_n, T)
        self.register_buffer("idct", dct[:dct_n].T.contiguous(), persistent=False)  # (T, dct_n)

        # One learned graph per block and part, stored per part so the filter banks of all
        # blocks come out of one batched computation.
        bound = 1.0 / math.sqrt(hidden)
        self.graphs = nn.ParameterDict(
            {
                name: nn.Parameter(
                    torch.empty(blocks, len(index), len(index)).uniform_(-bound, bound)
                )
                for name, index in part_nodes.items()
            }
        )
        self.register_buffer(
            "coefficient_mask", filter_coefficient_mask(filter_order), persistent=False
        )
        self.filter_coefficients = nn.Parameter(
            initial_filter_coefficients(filter_order).repeat(blocks, 1, 1)
        )
        self.filter_order = filter_order

        self.embed = nn.Linear(dct_n, hidden)
        self.embed_dropout = nn.Dropout(dropout)
        self.blocks = nn.ModuleList(
            ScatteringBlock(
                hidden,
                scattering_layers,
                filter_order,
                aggregation_dim,
                fusion_dim,
                dropout,
                fuse_parts=body_parts,
            )
            for _ in range(blocks)
        )
        self.readout = nn.Linear(hidden, dct_n)
        if zero_readout:
            # The untrained model returns the padded input's truncated DCT, i.e. nearly
            # repeat-last, and learns the departure from it.
            nn.init.zeros_(self.readout.weight)
            nn.init.zeros_(self.readout.bias)

    def filter_banks(self) -> dict[str, torch.Tensor]:
        """Every block's filters per part: ``{part: (blocks, K+1, N_p, N_p)}``."""
        coefficients = self.filter_coefficients * self.coefficient_mask
        banks = {}
        for name in self.part_names:
            graph = self.graphs[name]
            eye = torch.eye(graph.shape[-1], dtype=graph.dtype, device=graph.device)
            frobenius2 = graph.square().sum(dim=(-2, -1), keepdim=True)
            diffusion = 0.5 * (eye + graph / frobenius2)  # A~
            basis = [graph, eye.expand_as(graph), diffusion]
            power = diffusion
            for _ in range(2, self.filter_order + 1):
                power = power @ power  # A~^(2^(j-1)) by repeated squaring
                basis.append(power)
            basis = torch.stack(basis[: self.filter_order + 2], dim=1)  # (blocks, K+2, N, N)
            banks[name] = torch.einsum("ekj,ejnm->eknm", coefficients, basis)
        return banks

    def reconstruct(self, history: torch.Tensor) -> torch.Tensor:
        """All ``T_in + T_out`` frames ``(B, T, P, 3)`` in mm: the observed ones reconstructed,
        then the predicted ones."""
        if history.ndim != 4 or tuple(history.shape[1:]) != (self.input_frames, self.num_points, 3):
            raise ValueError(
                f"SPGSN: history must have shape (B, {self.input_frames}, "
                f"{self.num_points}, 3), got {tuple(history.shape)}"
            )
        batch = history.shape[0]
        frames = self.input_frames + self.output_frames
        padded = (
            torch.cat([history, history[:, -1:].expand(-1, self.output_frames, -1, -1)], dim=1)
            .reshape(batch, frames, -1)
            .to(self.dct.dtype)
        )
        # The DCT of positions in mm and the residual sum stay float32 even under a bf16
        # autocast (which would cost millimetres); the network in between may use it.
        with torch.autocast(history.device.type, enabled=False):
            coefficients = torch.einsum("kt,btn->nbk", self.dct, padded)  # (N, B, dct_n), mm
        h = self.embed_dropout(tanh(self.embed(coefficients / self.unit)))
        banks = self.filter_banks()
        index = {name: getattr(self, f"{name}_nodes") for name in self.part_names}
        if self.body_parts:
            index["placement"] = self.placement_nodes
        for i, block in enumerate(self.blocks):
            h = h + block(h, {name: bank[i] for name, bank in banks.items()}, index)
        # the model's own dtype: float32, or float64 where a test runs it so
        delta = self.readout(h).to(self.dct.dtype)
        with torch.autocast(history.device.type, enabled=False):
            sequence = torch.einsum("tk,nbk->btn", self.idct, coefficients + self.unit * delta)
        return sequence.reshape(batch, frames, self.num_points, 3)

    def forward(self, history: torch.Tensor) -> torch.Tensor:
        return self.reconstruct(history)[:, self.input_frames :]

    def training_loss(self, history: torch.Tensor, future: torch.Tensor) -> torch.Tensor:
        """Mean per-joint L2 error (mm) over all ``T_in + T_out`` frames: the authors' code's
        loss. The paper prints another (equation 9: a squared error over the future frames)."""
        expected = (self.output_frames, self.num_points, 3)
        if future.ndim != 4 or tuple(future.shape[1:]) != expected:
            raise ValueError(
                f"SPGSN: future must have shape (B, {self.output_frames}, "
                f"{self.num_points}, 3), got {tuple(future.shape)}"
            )
        target = torch.cat([history, future], dim=1)
        return torch.linalg.vector_norm(self.reconstruct(history) - target, dim=-1).mean()
