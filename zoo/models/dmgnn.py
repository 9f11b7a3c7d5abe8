"""DMGNN, as its public code runs on CMU: exp-map angles of 26 joints seen at three scales
(joints, 10 parts, 5 bodies), an encoder of spatio-temporal graph layers per scale with
attention between the scales, and a graph-based GRU decoding one frame at a time.

Li, Chen, Zhao, Zhang, Wang, Tian. Dynamic Multiscale Graph Neural Networks for 3D
Skeleton-Based Human Motion Prediction. CVPR 2020. The model reads and predicts exponential
maps (the benchmark's ``expmap`` view); its rows are scored on the joint positions the one FK
routine makes of them. Data flow, normalisation and where it departs from the code:
docs/models/dmgnn.md.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from types import SimpleNamespace

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from zoo.models.dropout import Dropout

_NORM_FLOOR = 1e-4  # the code's: a channel whose std is below it is not scaled


def _graph_kernels(nodes: int, edges: Sequence[Sequence[int]]) -> Tensor:
    """The code's ``distance`` adjacency at one hop: ``(2, V, V)``, each column of the
    self-and-neighbour matrix divided by its sum, split into the self and the neighbour part."""
    adjacency = np.eye(nodes)
    for i, j in edges:
        adjacency[i, j] = adjacency[j, i] = 1.0
    normalised = adjacency / adjacency.sum(0, keepdims=True)
    self_part = np.diag(np.diag(normalised))
    return torch.tensor(np.stack([self_part, normalised - self_part]), dtype=torch.float32)


def _frames_out(frames: int, stride: int) -> int:
    """Frames after a temporal convolution of kernel 5, padding 2 and ``stride``."""
    return (frames - 1) // stride + 1


class SpatialConv(nn.Module):
    """A 1x1 convolution to one feature set per adjacency kernel, summed over the kernels'
    graphs: ``sum_k A_k^T (W_k x)``."""

    def __init__(self, channels_in: int, channels_out: int, kernels: int) -> None:
        super().__init__()
        self.kernels = kernels
        self.conv = nn.Conv2d(channels_in, channels_out * kernels, kernel_size=(1, 1))

    def forward(self, x: Tensor, adjacency: Tensor) -> Tensor:
        x = self.conv(x)
        n, kc, t, v = x.shape
        x = x.view(n, self.kernels, kc // self.kernels, t, v)
        return torch.einsum("nkctv,kvw->nctw", x, adjacency).contiguous()


class GraphLayer(nn.Module):
    """The code's ``St_gcn``: a spatial graph convolution, then BatchNorm, ReLU, a temporal
    convolution (kernel 5, ``stride``), BatchNorm and dropout, a residual, ReLU."""

    def __init__(
        self, channels_in: int, channels_out: int, kernels: int, stride: int, dropout: float,
        residual: bool = True,
    ) -> None:  # fmt: skip
        super().__init__()
        self.gcn = SpatialConv(channels_in, channels_out, kernels)
        self.tcn = nn.Sequential(
            nn.BatchNorm2d(channels_out),
            nn.ReLU(),
            nn.Conv2d(channels_out, channels_out, (5, 1), (stride, 1), (2, 0)),
            nn.BatchNorm2d(channels_out),
            Dropout(dropout),
        )
        self.residual_kind = (
            "none" if not residual
            else "identity" if channels_in == channels_out and stride == 1
            else "conv"
        )  # fmt: skip
        if self.residual_kind == "conv":
            self.residual = nn.Sequential(
                nn.Conv2d(channels_in, channels_out, kernel_size=1, stride=(stride, 1)),
                nn.BatchNorm2d(channels_out),
            )

    def forward(self, x: Tensor, adjacency: Tensor) -> Tensor:
        y = self.tcn(self.gcn(x, adjacency))
        if self.residual_kind == "identity":
            y = y + x
        elif self.residual_kind == "conv":
            y = y + self.residual(x)
        return torch.relu(y)


class NodeMLP(nn.Module):
    """The code's ``Mlp_JpTrans``: two linear layers with a skip from the input into the
    second, BatchNorm over every node's output, LeakyReLU (0.01) unless last."""

    def __init__(self, size_in: int, hidden: int, size_out: int, dropout: float, act=True):
        super().__init__()
        self.fc1 = nn.Linear(size_in, hidden)
        self.fc2 = nn.Linear(hidden + size_in, size_out)
        self.bn = nn.BatchNorm1d(size_out)
        self.dropout = Dropout(dropout)
        self.act = act
        for layer in (self.fc1, self.fc2):
            nn.init.xavier_normal_(layer.weight)
            nn.init.constant_(layer.bias, 0.1)

    def forward(self, x: Tensor) -> Tensor:
        y = self.dropout(F.leaky_relu(self.fc1(x), 0.01))
        y = self.fc2(torch.cat((y, x), -1))
        y = self.bn(y.reshape(-1, y.shape[-1])).view(y.shape)
        return F.leaky_relu(y, 0.01) if self.act else y


class ScaleEmbedding(nn.Module):
    """Each node's features at one scale for the attention between scales (the code's
    ``S{1,2,3}AttInform``): a temporal convolution (stride 2), the features flattened into one
    row per node (in the code's order) through an MLP, then one round of message passing over
    the fully connected graph of the scale's nodes (edges: receiver and receiver minus sender;
    nodes: the sum of their incoming edges divided by the number of nodes, as the code's
    ``edge2node_mean``)."""

    def __init__(self, channels: int, frames: int, width: int, nodes: int, dropout: float):
        super().__init__()
        self.time_conv = nn.Sequential(
            nn.Conv2d(channels, channels, (5, 1), (2, 1), (2, 0)),
            nn.BatchNorm2d(channels),
            Dropout(dropout),
        )
        self.mlp1 = NodeMLP(channels * _frames_out(frames, 2), width, width, dropout)
        self.mlp2 = NodeMLP(width * 2, width, width, dropout)
        self.mlp3 = NodeMLP(width * 2, width, width, dropout, act=False)
        send, receive = np.nonzero(1 - np.eye(nodes))  # the code's edge order
        self.register_buffer("send", torch.from_numpy(send), persistent=False)
        self.register_buffer("receive", torch.from_numpy(receive), persistent=False)

    def forward(self, x: Tensor) -> Tensor:
        n, _, _, v = x.shape
        # the code's view of (N, T, V, C) memory as V rows: a row holds T*C numbers of
        # consecutive frames and nodes, not one node's frames
        nodes = self.mlp1(self.time_conv(x).permute(0, 2, 3, 1).reshape(n, v, -1))
        receivers = nodes[:, self.receive]
        edges = self.mlp2(torch.cat((receivers, receivers - nodes[:, self.send]), -1))
        incoming = edges.new_zeros(n, v, edges.shape[-1]).index_add_(1, self.receive, edges)
        return self.mlp3(torch.cat((incoming / v, nodes), -1))


class CrossScale(nn.Module):
    """Features passed from scale ``source`` to scale ``target`` (the code's ``S1_to_S2`` and
    its three siblings): attention between the two scales' node embeddings, each target node
    mixing the source's features with weights summing to one over the source's nodes. Its
    embeddings are named as the code's (``embed_s1``...), so the code's state dicts load as
    they are."""

    def __init__(self, source: int, target: int, channels: int, frames: int, width: int,
                 nodes: dict[int, int], dropout: float) -> None:  # fmt: skip
        super().__init__()
        self.source, self.target = f"embed_s{source}", f"embed_s{target}"
        for scale in (source, target):
            embed = ScaleEmbedding(channels, frames, width, nodes[scale], dropout)
            self.add_module(f"embed_s{scale}", embed)

    def forward(self, x_source: Tensor, x_target: Tensor) -> Tensor:
        n, d, t, _ = x_source.shape
        w = x_target.shape[-1]
        source = getattr(self, self.source)(x_source)
        target = getattr(self, self.target)(x_target)
        attention = torch.softmax(target @ source.transpose(1, 2), dim=-1)
        flat = x_source.permute(0, 3, 2, 1).reshape(n, x_source.shape[-1], -1)
        return (attention @ flat).view(n, w, t, d).permute(0, 3, 2, 1)


class Encoder(nn.Module):
    """One motion feature (positions, velocities or accelerations) at three scales: four graph
    layers per scale with learned edge weights (``A * mul + add``), attention between the
    scales after the first ``fusion_layers`` layers, the coarse scales read back onto the joints
    (weight ``coarse_weight``), a fifth joint layer and the mean over time: ``(N, C, V)``."""

    def __init__(self, hp: SimpleNamespace) -> None:
        super().__init__()
        graphs = {1: hp.joint_graph, 2: hp.part_graph, 3: hp.body_graph}
        for scale, name in ((1, "A_j"), (2, "A_p"), (3, "A_b")):
            self.register_buffer(name, graphs[scale].clone())
        kernels = self.A_j.shape[0]
        widths = (hp.channels_in, *hp.widths)
        for scale in (1, 2, 3):
            for layer, stride in enumerate(hp.strides, start=1):
                block = GraphLayer(
                    widths[layer - 1], widths[layer], kernels, stride, hp.dropout,
                    residual=layer > 1,
                )  # fmt: skip
                self.add_module(f"s{scale}_l{layer}", block)
        self.s1_l5 = GraphLayer(widths[-1], widths[-1], kernels, 1, hp.dropout)
        nodes = {1: hp.joint_graph.shape[-1], 2: hp.part_graph.shape[-1], 3: len(hp.bodies)}
        frames = hp.frames_in - 1  # the encoders read all but the last observed frame
        for layer in range(1, hp.fusion_layers + 1):
            frames = _frames_out(frames, hp.strides[layer - 1])
            for name, (a, b) in (("j2p", (1, 2)), ("p2j", (2, 1)), ("p2b", (2, 3)),
                                 ("b2p", (3, 2))):  # fmt: skip
                cross = CrossScale(
                    a, b, widths[layer], frames, hp.cross_width, nodes, hp.cross_dropout
                )
                self.add_module(f"{name}_{layer}", cross)
        layers = {1: len(hp.strides) + 1, 2: len(hp.strides), 3: len(hp.strides)}
        for scale, graph in graphs.items():
            mul = [nn.Parameter(torch.ones(graph.shape)) for _ in range(layers[scale])]
            add = [nn.Parameter(torch.zeros(graph.shape)) for _ in range(layers[scale])]
            setattr(self, f"emul_s{scale}", nn.ParameterList(mul))
            setattr(self, f"eadd_s{scale}", nn.ParameterList(add))
        for name, groups in (("parts", hp.parts), ("bodies", hp.bodies)):
            members, sizes = _membership(groups, nodes[1])
            self.register_buffer(name, members, persistent=False)
            self.register_buffer(f"{name}_sizes", sizes, persistent=False)
        self.register_buffer("part_back", torch.tensor(hp.part_back), persistent=False)
        self.register_buffer("body_back", torch.tensor(hp.body_back), persistent=False)
        self.fusion_layers, self.cross_weight = hp.fusion_layers, hp.cross_weight
        self.coarse_weight, self.layers = hp.coarse_weight, len(hp.strides)

    def _adjacency(self, scale: int, layer: int) -> Tensor:
        graph = {1: self.A_j, 2: self.A_p, 3: self.A_b}[scale]
        mul = getattr(self, f"emul_s{scale}")[layer - 1]
        return graph * mul + getattr(self, f"eadd_s{scale}")[layer - 1]

    def forward(self, x: Tensor) -> Tensor:
        n, t, _ = x.shape
        x = x.view(n, t, self.A_j.shape[-1], -1).permute(0, 3, 1, 2)
        # group means, a sum divided by the count as the code's avg_pool2d (not times 1/3)
        s1, s2, s3 = x, x @ self.parts / self.parts_sizes, x @ self.bodies / self.bodies_sizes
        for layer in range(1, self.layers + 1):
            s1 = getattr(self, f"s1_l{layer}")(s1, self._adjacency(1, layer))
            s2 = getattr(self, f"s2_l{layer}")(s2, self._adjacency(2, layer))
            s3 = getattr(self, f"s3_l{layer}")(s3, self._adjacency(3, layer))
            if layer <= self.fusion_layers:
                j2p = getattr(self, f"j2p_{layer}")(s1, s2)
                p2j = getattr(self, f"p2j_{layer}")(s2, s1)
                p2b = getattr(self, f"p2b_{layer}")(s2, s3)
                b2p = getattr(self, f"b2p_{layer}")(s3, s2)
                w = self.cross_weight
                s1, s2, s3 = s1 + w * p2j, s2 + w * (j2p + b2p), s3 + w * p2b
        w = self.coarse_weight
        s1 = s1 + w * s2[..., self.part_back] + w * s3[..., self.body_back]
        return self.s1_l5(s1, self._adjacency(1, self.layers + 1)).mean(dim=2)


def _membership(groups: Sequence[Sequence[int]], nodes: int) -> tuple[Tensor, Tensor]:
    """``(V, G)`` with a one where node ``v`` is in group ``g``, and each group's size."""
    matrix = torch.zeros(nodes, len(groups))
    for g, members in enumerate(groups):
        matrix[list(members), g] = 1.0
    return matrix, matrix.sum(0)


class Decoder(nn.Module):
    """The code's graph-based GRU: each step reads the last frame's position, velocity and
    acceleration (9 numbers a joint), passes messages over the joint graph (first
    ``message_steps`` steps only), updates the hidden state and adds the predicted change to
    the position it read."""

    def __init__(self, hp: SimpleNamespace) -> None:
        super().__init__()
        self.register_buffer("A_j", hp.joint_graph.clone())
        kernels, hidden = self.A_j.shape[0], hp.hidden
        self.emul = nn.Parameter(torch.ones(self.A_j.shape))
        self.eadd = nn.Parameter(torch.ones(self.A_j.shape))  # the code's: ones, not zeros
        self.msg_in = _DecodeGcn(hidden, kernels, hp.message_dropout)
        for gate in ("r", "i", "n"):
            setattr(self, f"input_{gate}", nn.Linear(9, hidden))
        for gate in ("r", "i", "h"):
            setattr(self, f"hidden_{gate}", nn.Linear(hidden, hidden, bias=False))
        self.out_fc1 = nn.Linear(hidden, hidden)
        self.out_fc2 = nn.Linear(hidden, hidden)
        self.out_fc3 = nn.Linear(hidden, 3)
        self.dropout1, self.dropout2 = Dropout(hp.decoder_dropout), Dropout(hp.decoder_dropout)
        self.message_steps, self.noise = hp.message_steps, hp.noise

    def _step(self, x: Tensor, hidden: Tensor, step: int) -> tuple[Tensor, Tensor]:
        if step < self.message_steps:
            msg = self.msg_in(hidden, self.A_j * self.emul + self.eadd)
        else:
            msg = hidden
        msg, hidden = msg.transpose(1, 2), hidden.transpose(1, 2)
        r = torch.sigmoid(self.input_r(x) + self.hidden_r(msg))
        z = torch.sigmoid(self.input_i(x) + self.hidden_i(msg))
        n = torch.tanh(self.input_n(x) + r * self.hidden_h(msg))
        hidden = (1 - z) * n + z * hidden
        out = self.dropout1(F.leaky_relu(self.out_fc1(hidden), 0.1))
        out = self.dropout2(F.leaky_relu(self.out_fc2(out), 0.1))
        return x[..., :3] + self.out_fc3(out), hidden.transpose(1, 2)

    def forward(self, seen: list[Tensor], hidden: Tensor, frames: int) -> Tensor:
        """``seen``: the last three observed frames ``(N, V, 3)``, oldest first."""
        q = list(seen)
        for step in range(frames):
            position = q[-1]
            if self.training and self.noise:
                position = position + torch.randn_like(position) * self.noise
            velocity = q[-2] - q[-3]
            acceleration = q[-1] - q[-2] - velocity
            nxt, hidden = self._step(torch.cat((position, velocity, acceleration), -1),
                                     hidden, step)  # fmt: skip
            q.append(nxt)
        return torch.stack(q[3:], dim=1)


class _DecodeGcn(nn.Module):
    def __init__(self, hidden: int, kernels: int, dropout: float) -> None:
        super().__init__()
        self.kernels = kernels
        self.conv = nn.Conv1d(hidden, hidden * kernels, kernel_size=1)
        self.dropout = Dropout(dropout)

    def forward(self, x: Tensor, adjacency: Tensor) -> Tensor:
        x = self.dropout(self.conv(x))
        n, kc, v = x.shape
        x = x.view(n, self.kernels, kc // self.kernels, v)
        return torch.einsum("nkcv,kvw->ncw", x, adjacency).contiguous()


def _int_list(name: str, value, low: int, high: int | None = None) -> list[int]:
    if not isinstance(value, (list, tuple)) or not value:
        raise ValueError(f"DMGNN: {name} must be a non-empty list of integers, got {value!r}")
    for v in value:
        if (
            isinstance(v, bool)
            or not isinstance(v, int)
            or not (low <= v and (high is None or v < high))
        ):
            bound = f"in [{low}, {high})" if high is not None else f">= {low}"
            raise ValueError(f"DMGNN: {name} must hold integers {bound}, got {v!r}")
    return list(value)


class DMGNN(nn.Module):
    """Exp-map frames ``(B, T_in, J, 3)`` in, ``(B, T_out, J, 3)`` out: the ``joints`` (26 of
    the skeleton's ``num_points``) predicted, standardised with the training frames' mean and
    std (set by :meth:`set_statistics`, stored with the weights), every other channel the
    training mean. Parameter names are the code's."""

    def __init__(
        self,
        input_frames: int,
        output_frames: int,
        num_points: int,
        joints: Sequence[int],
        edges: Sequence[Sequence[int]],
        parts: Sequence[Sequence[int]],
        part_edges: Sequence[Sequence[int]],
        bodies: Sequence[Sequence[int]],
        body_edges: Sequence[Sequence[int]],
        part_back: Sequence[int],
        body_back: Sequence[int],
        static_channels: Sequence[int] = (),
        widths: Sequence[int] = (32, 64, 128, 256),
        strides: Sequence[int] = (1, 2, 2, 2),
        hidden: int = 256,
        fusion_layers: int = 2,
        cross_width: int = 256,
        cross_weight: float = 0.3,
        coarse_weight: float = 0.6,
        message_steps: int = 10,
        dropout: float = 0.5,
        cross_dropout: float = 0.2,
        message_dropout: float = 0.5,
        decoder_dropout: float = 0.3,
        noise: float = 0.0005,
        late_from: int = 10,
        late_weight: float = 2.0,
    ) -> None:
        super().__init__()
        if isinstance(input_frames, bool) or not isinstance(input_frames, int) or input_frames < 3:
            raise ValueError(f"DMGNN: input_frames must be an integer >= 3, got {input_frames!r}")
        joints = _int_list("joints", joints, 0, num_points)
        v = len(joints)
        parts = [_int_list("parts", g, 0, v) for g in parts]
        bodies = [_int_list("bodies", g, 0, v) for g in bodies]
        part_back = _int_list("part_back", part_back, 0, len(parts))
        body_back = _int_list("body_back", body_back, 0, len(bodies))
        for name, back in (("part_back", part_back), ("body_back", body_back)):
            if len(back) != v:
                raise ValueError(f"DMGNN: {name} must name a group for each of the {v} joints")
        if len(widths) != len(strides) or hidden != widths[-1]:
            raise ValueError("DMGNN: widths and strides must pair up, the last width = hidden")
        if not 0 <= fusion_layers < len(strides):
            raise ValueError(f"DMGNN: fusion_layers must be in [0, {len(strides)})")
        hp = SimpleNamespace(  # the checked hyper-parameters the modules are built from
            channels_in=3, widths=tuple(widths), strides=tuple(strides), hidden=hidden,
            frames_in=input_frames, fusion_layers=fusion_layers, cross_width=cross_width,
            cross_weight=cross_weight, coarse_weight=coarse_weight, dropout=dropout,
            cross_dropout=cross_dropout, message_dropout=message_dropout,
            decoder_dropout=decoder_dropout, message_steps=message_steps, noise=noise,
            parts=parts, bodies=bodies, part_back=part_back, body_back=body_back,
            joint_graph=_graph_kernels(v, edges),
            part_graph=_graph_kernels(len(parts), part_edges),
            body_graph=_graph_kernels(len(bodies), body_edges),
        )  # fmt: skip
        self.input_frames, self.output_frames, self.num_points = (
            input_frames, output_frames, num_points,
        )  # fmt: skip
        self.encoder_pos, self.encoder_vel, self.encoder_acl = (Encoder(hp) for _ in range(3))
        self.decoder = Decoder(hp)
        self.linear = nn.Linear(hidden * 3, hidden)
        channels = torch.tensor([3 * j + c for j in joints for c in range(3)])
        self.register_buffer("channels", channels, persistent=False)
        mask = torch.ones(3 * v)
        if static_channels:
            mask[_int_list("static_channels", static_channels, 0, 3 * v)] = 0.0
        self.register_buffer("mask", mask.view(v, 3), persistent=False)
        self.register_buffer("mean", torch.zeros(num_points * 3))
        self.register_buffer("std", torch.ones(num_points * 3))
        self.late_from, self.late_weight = late_from, late_weight
        self._init_weights()

    def _init_weights(self) -> None:
        """The code's ``weights_init``: convolutions N(0, 0.02) with zero bias, BatchNorm
        weights N(1, 0.02) with zero bias (after the MLPs' Xavier initialisation)."""
        for m in self.modules():
            if isinstance(m, (nn.Conv1d, nn.Conv2d)):
                nn.init.normal_(m.weight, 0.0, 0.02)
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
            elif isinstance(m, (nn.BatchNorm1d, nn.BatchNorm2d)):
                nn.init.normal_(m.weight, 1.0, 0.02)
                nn.init.zeros_(m.bias)

    # ---- the network, on standardised channels ------------------------------------------------

    def network(self, frames: Tensor, output_frames: int) -> Tensor:
        """Standardised frames ``(N, T_in, 3V)`` of the predicted joints in, ``(N, T_out, V,
        3)`` out, the static channels zero. The encoders read all but the last frame (its
        velocity, and its acceleration aligned as the code's training or test loop aligns it);
        the decoder starts from the last three."""
        position, velocity, acceleration = self.motion_features(frames)
        encoded = torch.cat(
            (self.encoder_pos(position), self.encoder_vel(velocity),
             self.encoder_acl(acceleration)), dim=1,
        )  # fmt: skip
        hidden = torch.relu(self.linear(encoded.transpose(1, 2)).transpose(1, 2))
        n, t, _ = frames.shape
        seen = list(frames[:, -3:].reshape(n, 3, -1, 3).unbind(1))
        return self.decoder(seen, hidden, output_frames) * self.mask

    def motion_features(self, frames: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """The encoders' inputs, of all but the last frame: positions, velocities (the first
        zero) and accelerations, in training each frame's following change of velocity (the
        last zero), otherwise its preceding one (the first zero), as the code's two loops."""
        position = frames[:, :-1]
        velocity = F.pad(position[:, 1:] - position[:, :-1], (0, 0, 1, 0))
        change = velocity[:, 1:] - velocity[:, :-1]
        acceleration = F.pad(change, (0, 0, 0, 1) if self.training else (0, 0, 1, 0))
        return position, velocity, acceleration

    def standardised(self, angles: Tensor) -> Tensor:
        """Exp-map frames ``(N, T, J, 3)`` as the network's channels ``(N, T, 3V)``."""
        flat = angles.reshape(*angles.shape[:2], -1)
        return ((flat - self.mean) / self.std)[..., self.channels]

    def forward(self, history: Tensor) -> Tensor:
        predicted = self.network(self.standardised(history), self.output_frames)
        n, t = predicted.shape[:2]
        full = self.mean.expand(n, t, -1).clone()
        full[..., self.channels] += predicted.reshape(n, t, -1) * self.std[self.channels]
        return full.view(n, t, self.num_points, 3)

    def training_loss(self, history: Tensor, future: Tensor) -> Tensor:
        """The code's loss: each future frame's mean absolute error of the standardised
        channels of the predicted joints (static channels predicted as zero), weighted
        ``late_weight`` from frame ``late_from`` (0-based) on and 1 before, then averaged."""
        target = self.standardised(future).view(*future.shape[:2], -1, 3)
        predicted = self.network(self.standardised(history), future.shape[1])
        per_frame = (predicted - target).abs().mean(dim=(0, 2, 3))
        weights = torch.ones_like(per_frame)
        weights[self.late_from :] = self.late_weight
        return (per_frame * weights).mean()

    # ---- the standardisation --------------------------------------------------------------

    def start_epoch(self, epoch: int, frames: Callable[[], Iterable[tuple[Tensor, Tensor]]]):
        """Training-engine hook: the training frames' mean and std (:meth:`set_statistics`),
        every epoch, so that a run resumed from a paused state (which keeps buffers in
        float16) trains on the exact values; the same frames give the same values."""
        self.set_statistics(frames())

    @torch.no_grad()
    def set_statistics(self, frames: Iterable[tuple[Tensor, Tensor]]) -> None:
        """Mean and std of every exp-map channel over the training frames, each frame once (the
        code's ``normalization_stats`` over its training files); a std below 1e-4 is set to 1."""
        total = torch.zeros(self.num_points * 3, dtype=torch.float64)
        squares, count = torch.zeros_like(total), 0
        for batch, _ in frames:
            flat = batch.reshape(batch.shape[0], -1).double()
            total += flat.sum(0)
            squares += (flat * flat).sum(0)
            count += flat.shape[0]
        if count == 0:
            raise ValueError("DMGNN: no training frames to take a mean and std from")
        mean = total / count
        std = (squares / count - mean * mean).clamp_min(0.0).sqrt()
        std[std < _NORM_FLOOR] = 1.0
        self.mean.copy_(mean.to(self.mean.dtype))
        self.std.copy_(std.to(self.std.dtype))


__all__ = ["DMGNN"]
