"""The public SPGSN code's CMU model and training step, re-implemented for timing only.

What this is: an independent re-implementation of the *computation* of the authors' public code
(github.com/MediaBrain-SJTU/SPGSN: ``utils/model.py`` ``GCN``, ``utils/attentions.py``, the
``train()`` loop of ``main_cmu_3d.py``), written here from reading that code, not copied from it.
It exists so that ``benchmarks/speed/speed_spgsn.py`` can time the public design next to ours on the
same CPU in the same run. It is not a model of this zoo and is not meant for training.

Configuration reproduced: the README's CMU command (``--input_n 10 --output_n 25 --dct_n 30``)
on the defaults of ``utils/opt.py`` (hidden 256, dropout 0.5, J = 1 wavelet filter, edge
keep-probability 0.4, part fusion on, Adam lr 1e-3, batch 32, gradient-norm clip 1), 75 nodes
(25 joints x 3 coordinates), upper part = used joints 10..24, lower part = 0..9, coordinate
nodes ordered as ``main_cmu_3d.py`` orders them (all x, then all y, then all z of a part).

Number of blocks: ``utils/opt.py`` defaults to ``num_stage=9`` (5.82 M parameters) and the CMU
command does not override it; the paper uses 10 blocks, and 10 gives the 6.46 M parameters
recorded for the public code's CMU run, so ``num_stage=10`` is the default here. Pass
``num_stage=9`` for the bare opt.py default.

Same as the public code, on purpose (each is part of its cost): per block, one scattering
module whose weights are shared by the whole body and both parts; three Bernoulli edge masks
drawn on every forward (training and evaluation alike); the diffusion-wavelet filter and the
normalised graph Laplacian rebuilt on every call (the Laplacian is computed and never used);
the same einsum contractions, reshapes, batch norms (one of them over a ``(N, C, 1)`` view),
channel attention, part fusion, scatter of the parts into a zero tensor, and dropout; parameters
that the forward never reads (a 48 x 48 ``att`` in every graph operator, left at zero here, it
is uninitialised memory there); the training loss, the mean L2 over all 35 frames after the
inverse DCT of the output, with the inverse DCT matrix rebuilt on every step.

Differences: CPU instead of ``.cuda()`` (no host-device copies; there too the masks are drawn
on the CPU, then copied); the debugging ``print`` in the scattering forward is left out; the DCT
matrix is the zoo's (same matrix, built without their Python double loop: 1.6 ms less per step
here, under 0.1 % of a step); ``clip_grad_norm_`` for the deprecated
``clip_grad_norm``; the input is float32 from the start (their loader yields float64, cast
with ``.float()`` on the GPU); a (V, V) graph is unsqueezed inside ``GraphOperator`` rather than
by its caller, so that ``FlopCounterMode`` under ``no_grad`` works (same operation).

    python benchmarks/speed/public_spgsn.py  # parameters, forward GFLOP/sample, training step time

From a script in ``benchmarks/speed/`` (its folder is on ``sys.path``)::

    from public_spgsn import make_public_step, forward_gflop_per_sample
    step, model = make_public_step(history_mm=history, future_mm=future)  # or batch_size=32
    step()                                # one full public training step, returns the loss
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from collections.abc import Callable

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from zoo.models.dct import dct_matrix

INPUT_N, OUTPUT_N, DCT_N = 10, 25, 30
CMU_JOINTS = 38
# Joints the public CMU loader drops (constant, or duplicates of a neighbour): 25 remain.
CMU_IGNORED = (0, 1, 2, 7, 8, 13, 16, 20, 24, 27, 29, 33, 36)
UPPER_JOINTS = tuple(range(10, 25))  # indices into the 25 used joints, as main_cmu_3d.py
LOWER_JOINTS = tuple(range(0, 10))


def coordinate_nodes(joints: tuple[int, ...]) -> np.ndarray:
    """Node indices of a part: every x, then every y, then every z (the public ordering)."""
    j = np.asarray(joints)
    return np.concatenate((3 * j, 3 * j + 1, 3 * j + 2))


# ---------------------------------------------------------------------------------------------
# Layers


class NodeLinear(nn.Module):
    """Public ``GraphConvolution``: ``A (X W) + b`` with a dense learned ``A``."""

    def __init__(self, d_in: int, d_out: int, nodes: int):
        super().__init__()
        bound = 1 / math.sqrt(d_out)
        self.weight = nn.Parameter(torch.empty(d_in, d_out).uniform_(-bound, bound))
        self.adjacency = nn.Parameter(torch.empty(nodes, nodes).uniform_(-bound, bound))
        self.bias = nn.Parameter(torch.empty(d_out).uniform_(-bound, bound))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.matmul(self.adjacency, torch.matmul(x, self.weight)) + self.bias


class GraphOperator(nn.Module):
    """Public ``GraphOperate``: per-filter feature transform, then per-filter graph mixing.

    x (N, K, V, d_in), graphs (F, V, V) or one graph (V, V) -> (N, K * F, V, d_out).
    """

    def __init__(self, d_in: int, d_out: int, filters: int = 1):
        super().__init__()
        self.weight = nn.Parameter(nn.init.xavier_normal_(torch.empty(filters, d_in, d_out)))
        bound = 1 / math.sqrt(d_in * d_out)
        self.bias = nn.Parameter(torch.empty(filters, d_out).uniform_(-bound, bound))
        # Never read by the forward; kept because it is a parameter of the public model
        # (48 x 48: the class's default node count, the CMU model does not pass its own).
        self.unused_att = nn.Parameter(torch.zeros(48, 48))

    def forward(self, x: torch.Tensor, graphs: torch.Tensor) -> torch.Tensor:
        if graphs.dim() == 2:
            # Unsqueezed here, not by the caller: a view of a parameter made under no_grad and
            # passed to a module breaks FlopCounterMode's module tracker.
            graphs = graphs.unsqueeze(0)
        h = torch.einsum("nkvi,fio->nkvfo", x, self.weight) + self.bias
        h = h.transpose(2, 3)  # (N, K, F, V, d_out)
        n, _, _, v, d = h.shape
        out = torch.einsum("fuv,nkfvo->nkfuo", graphs, h)
        return out.contiguous().view(n, -1, v, d)


class ScatteringUnit(nn.Module):
    """Public ``GraphConvScatter`` with J = 1: a graph convolution branch and a two-layer
    diffusion-wavelet branch on the masked graph; returns (N, 2, V, d)."""

    def __init__(self, d_in: int, d_out: int):
        super().__init__()
        self.conv = GraphOperator(d_in, d_out)
        self.wavelet1 = GraphOperator(d_in, d_out)
        self.wavelet2 = GraphOperator(d_out, d_out)
        self.filter_coef = nn.Parameter(torch.rand(2) * 1e-4)

    def wavelet(self, a: torch.Tensor) -> torch.Tensor:
        eye = torch.eye(a.shape[0])
        lazy_walk = 0.5 * (eye + a / (torch.linalg.matrix_norm(a) + 1e-3).detach())
        c = self.filter_coef
        return ((1 + c[0]) * eye - (1 - c[1]) * lazy_walk).unsqueeze(0)

    @staticmethod
    def normalised_laplacian(a: torch.Tensor) -> torch.Tensor:
        degree = a.sum(dim=-1)
        inv_sqrt = torch.diag(1 / torch.sqrt(degree + 1e-4))
        return inv_sqrt @ ((torch.diag(degree) - a) @ inv_sqrt)

    def forward(self, x: torch.Tensor, adjacency: torch.Tensor, mask: torch.Tensor):
        a = adjacency * mask
        wavelet = self.wavelet(a)
        self.normalised_laplacian(a)  # the public forward builds it and discards it: its cost
        x = x.unsqueeze(1)
        y_conv = self.conv(x, a.unsqueeze(0))
        y_wave = self.wavelet2(torch.tanh(self.wavelet1(x, wavelet)), wavelet)
        return torch.cat((y_conv, y_wave), dim=1)


class PartFusion(nn.Module):
    """Public ``PartFuse``: softmax affinities between upper and lower nodes from two bias-free
    layers per part; returns (upper -> lower, lower -> upper) weights."""

    def __init__(self, d: int, width: int = 64):
        super().__init__()
        self.up1, self.up2 = _bias_free(d, width), _bias_free(width, width)
        self.down1, self.down2 = _bias_free(d, width), _bias_free(width, width)

    def forward(self, y_up: torch.Tensor, y_down: torch.Tensor):
        f_up = self.up2(F.relu(self.up1(y_up.mean(1))))
        f_down = self.down2(F.relu(self.down1(y_down.mean(1))))
        down_to_up = torch.softmax(f_up @ f_down.transpose(-1, -2), dim=-1)
        up_to_down = torch.softmax(f_down @ f_up.transpose(-1, -2), dim=-1)
        return up_to_down, down_to_up


class ChannelAttention(nn.Module):
    """Public ``KernelAttention_Sigmoid`` (a softmax over the channel axis despite its name)."""

    def __init__(self, d: int):
        super().__init__()
        self.fc1, self.fc2 = _bias_free(d, d), nn.Linear(d, 1)
        nn.init.xavier_normal_(self.fc2.weight)
        nn.init.uniform_(self.fc2.bias, -1 / math.sqrt(d), 1 / math.sqrt(d))
        self.w_h = nn.Parameter(nn.init.xavier_normal_(torch.empty(d, d)))
        self.w_q = nn.Parameter(nn.init.xavier_normal_(torch.empty(d, d)))
        self.b = nn.Parameter(torch.empty(d).uniform_(-1 / math.sqrt(d), 1 / math.sqrt(d)))

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        x = self.fc1(y)  # (N, C, V, d)
        query = F.relu(x.mean(1))
        h = torch.tanh(x @ self.w_h + (query @ self.w_q).unsqueeze(1) + self.b)
        return torch.softmax(self.fc2(h), dim=1)  # (N, C, V, 1)


def _bias_free(d_in: int, d_out: int) -> nn.Linear:
    layer = nn.Linear(d_in, d_out, bias=False)
    nn.init.xavier_normal_(layer.weight)
    return layer


class PartedScattering(nn.Module):
    """Public ``GraphConvScatter_Forest``: one scattering unit run on the whole body and on each
    part, each with its own learned graph and a fresh Bernoulli edge mask, then part fusion and
    the parts added back at their body positions."""

    def __init__(self, d: int, nodes: int, up: np.ndarray, down: np.ndarray, keep_prob: float):
        super().__init__()
        self.up, self.down = torch.as_tensor(up), torch.as_tensor(down)
        bound = 1 / math.sqrt(d)
        self.graphs = nn.ParameterList(
            nn.Parameter(torch.empty(n, n).uniform_(-bound, bound))
            for n in (nodes, len(up), len(down))
        )
        self.keep_probs = [torch.full((n, n), keep_prob) for n in (nodes, len(up), len(down))]
        self.unit = ScatteringUnit(d, d)
        self.fusion = PartFusion(d)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            masks = [torch.bernoulli(p) for p in self.keep_probs]
        g_body, g_up, g_down = self.graphs
        y = self.unit(x, g_body, masks[0])
        y_up = self.unit(x[:, self.up], g_up, masks[1])
        y_down = self.unit(x[:, self.down], g_down, masks[2])
        up_to_down, down_to_up = self.fusion(y_up, y_down)
        y_down = y_down + torch.einsum("nwv,ncvd->ncwd", up_to_down, y_up)
        y_up = y_up + torch.einsum("nvw,ncwd->ncvd", down_to_up, y_down)
        parts = torch.zeros_like(y)
        parts[:, :, self.up] = y_up
        parts[:, :, self.down] = y_down
        return y + parts


class Block(nn.Module):
    """Public ``GC_Block``: parted scattering, batch norms, tanh, channel attention, mean over
    channels, dropout, then a plain graph layer, batch norm, ReLU, dropout, residual."""

    def __init__(self, d: int, nodes: int, up, down, dropout: float, keep_prob: float):
        super().__init__()
        self.scatter = PartedScattering(d, nodes, up, down, keep_prob)
        self.bn_conv = nn.BatchNorm1d(nodes * d)
        self.bn_wave = nn.BatchNorm1d(nodes * d)
        self.attention = ChannelAttention(d)
        self.graph = nn.Parameter(
            torch.empty(nodes, nodes).uniform_(-1 / math.sqrt(d), 1 / math.sqrt(d))
        )
        self.mix = GraphOperator(d, d)
        self.bn_mix = nn.BatchNorm1d(nodes * d)
        self.drop = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.scatter(x)
        n, _, v, d = y.shape
        y_conv = self.bn_conv(y[:, 0].contiguous().view(n, -1)).view(n, 1, v, d)
        # The public code normalises this branch through a (N, V*d, 1) view: same statistics.
        y_wave = self.bn_wave(y[:, 1:].contiguous().view(n, 1, -1).transpose(1, 2))
        y_wave = y_wave.transpose(1, 2).view(n, 1, v, d)
        y = torch.tanh(torch.cat((y_conv, y_wave), dim=1))
        y = y + 0.1 * y * self.attention(y)
        y = self.drop(y.mean(1))
        y = self.mix(y.unsqueeze(1), self.graph)
        y = self.drop(F.relu(self.bn_mix(y.contiguous().view(n, -1)).view(n, v, d)))
        return y + x


class PublicSPGSN(nn.Module):
    """Public ``GCN`` for CMU: DCT coefficients (N, 75, dct_n) -> (N, 75, dct_n)."""

    def __init__(
        self,
        *,
        dct_n: int = DCT_N,
        hidden: int = 256,
        num_stage: int = 10,
        nodes: int = 75,
        upper_joints=UPPER_JOINTS,
        lower_joints=LOWER_JOINTS,
        dropout: float = 0.5,
        edge_prob: float = 0.4,
    ):
        super().__init__()
        up, down = coordinate_nodes(upper_joints), coordinate_nodes(lower_joints)
        self.embed = NodeLinear(dct_n, hidden, nodes)
        self.bn = nn.BatchNorm1d(nodes * hidden)
        self.blocks = nn.ModuleList(
            Block(hidden, nodes, up, down, dropout, edge_prob) for _ in range(num_stage)
        )
        self.readout = NodeLinear(hidden, dct_n, nodes)
        self.drop = nn.Dropout(dropout)

    def forward(self, dct_input: torch.Tensor) -> torch.Tensor:
        y = self.embed(dct_input)
        n, v, d = y.shape
        y = self.drop(torch.tanh(self.bn(y.view(n, -1)).view(n, v, d)))
        for block in self.blocks:
            y = block(y)
        return self.readout(y) + dct_input


# ---------------------------------------------------------------------------------------------
# Data and training step, as the public CMU loader and train() do them


def public_batch(history_mm: torch.Tensor, future_mm: torch.Tensor, dct_n: int = DCT_N):
    """The public loader's tensors from (N, T_in, 25, 3) and (N, T_out, 25, 3) used joints.

    Returns ``dct_input`` (N, 75, dct_n): DCT of the input padded with its last frame;
    ``all_seq`` (N, T, 114): every frame with all 38 joints (dropped ones at zero); ``dim_used``.
    """
    seq = torch.cat((history_mm, future_mm), dim=1).float()
    n, t_in, t = seq.shape[0], history_mm.shape[1], seq.shape[1]
    used = [j for j in range(CMU_JOINTS) if j not in CMU_IGNORED]
    all_seq = seq.new_zeros(n, t, CMU_JOINTS, 3)
    all_seq[:, :, used] = seq
    all_seq = all_seq.view(n, t, -1)
    dim_used = torch.tensor([3 * j + c for j in used for c in range(3)])  # x, y, z per joint
    padded = torch.cat((torch.arange(t_in), torch.full((t - t_in,), t_in - 1)))
    dct = dct_matrix(t)[:dct_n]  # the zoo's orthonormal DCT-II (the public get_dct_matrix)
    dct_input = torch.einsum("kt,ntc->nck", dct, all_seq[:, padded][:, :, dim_used])
    return dct_input.contiguous(), all_seq, dim_used


def public_training_step(
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    dct_input: torch.Tensor,
    all_seq: torch.Tensor,
    dim_used: torch.Tensor,
    dct_n: int = DCT_N,
) -> float:
    """One iteration of the public ``train()``; returns the loss (mean L2 over all frames)."""
    out = model(dct_input)
    t, nodes = all_seq.shape[1], len(dim_used)
    # rebuilt and inverted per step there too
    idct = torch.linalg.inv(dct_matrix(t, torch.float64)).float()
    frames = torch.matmul(idct[:, :dct_n], out.view(-1, dct_n).transpose(0, 1))
    frames = frames.transpose(0, 1).contiguous().view(-1, nodes, t)
    frames = frames.transpose(1, 2).contiguous().view(-1, 3)
    target = all_seq[:, :, dim_used].clone().contiguous().view(-1, 3)
    loss = torch.mean(torch.norm(target - frames, 2, 1))
    optimizer.zero_grad()
    loss.backward()
    nn.utils.clip_grad_norm_(model.parameters(), max_norm=1)
    optimizer.step()
    return loss.item()


def smooth_motion(batch: int, frames: int, joints: int, seed: int) -> torch.Tensor:
    """Random smooth motion in mm: offsets plus a random walk (only the shapes matter here)."""
    g = torch.Generator().manual_seed(seed)
    offsets = torch.randn(batch, 1, joints, 3, generator=g) * 400
    return offsets + (torch.randn(batch, frames, joints, 3, generator=g) * 5).cumsum(dim=1)


def make_public_step(
    batch_size: int = 32,
    seed: int = 0,
    history_mm: torch.Tensor | None = None,
    future_mm: torch.Tensor | None = None,
    **model_kwargs,
) -> tuple[Callable[[], float], PublicSPGSN]:
    """A zero-argument callable doing one public training step (returns the loss), and the model.

    The batch is built once, outside the step, as the public data loader delivers it; pass
    ``history_mm`` (N, 10, 25, 3) and ``future_mm`` (N, 25, 25, 3) to use your own motion.
    """
    torch.manual_seed(seed)
    model = PublicSPGSN(**model_kwargs).train()
    dct_n = model.readout.weight.shape[1]
    if history_mm is None or future_mm is None:
        history_mm = smooth_motion(batch_size, INPUT_N, 25, seed + 1)
        future_mm = smooth_motion(batch_size, OUTPUT_N, 25, seed + 2)
        future_mm = future_mm - future_mm[:, :1] + history_mm[:, -1:]  # continue the history
    dct_input, all_seq, dim_used = public_batch(history_mm, future_mm, dct_n)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    return (
        lambda: public_training_step(model, optimizer, dct_input, all_seq, dim_used, dct_n),
        model,
    )


def forward_gflop_per_sample(model: PublicSPGSN) -> float:
    """Forward FLOPs at batch 1 (evaluation mode: batch norm needs two samples to train)."""
    from torch.utils.flop_counter import FlopCounterMode

    was_training = model.training
    model.eval()
    x = torch.randn(1, model.embed.adjacency.shape[0], model.readout.weight.shape[1])
    with torch.no_grad(), FlopCounterMode(display=False) as counter:
        model(x)
    model.train(was_training)
    return counter.get_total_flops() / 1e9


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--steps", type=int, default=5, help="timed training steps (median)")
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--num-stage", type=int, default=10, help="blocks (opt.py default: 9)")
    parser.add_argument("--hidden", type=int, default=256)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    step, model = make_public_step(
        batch_size=args.batch_size, num_stage=args.num_stage, hidden=args.hidden
    )
    params = sum(p.numel() for p in model.parameters())
    print(f"total params: {params / 1e6:.2f}M ({params})")
    print(f"forward GFLOP per sample: {forward_gflop_per_sample(model):.3f}")
    losses, times = [step()], []  # the first step (warm-up) is not timed
    for _ in range(args.steps):
        start = time.perf_counter()
        losses.append(step())
        times.append(time.perf_counter() - start)
    print("losses:", " ".join(f"{x:.2f}" for x in losses))
    print(
        f"training step, batch {args.batch_size}, {torch.get_num_threads()} thread(s): median "
        f"{statistics.median(times):.3f} s over {len(times)} steps after a warm-up"
    )


if __name__ == "__main__":
    main()
