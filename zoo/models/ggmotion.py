"""GGMotion: joints as groups of "virtual 3-D points" moved by forces: a spatial and a temporal
field, forces between body groups and within each group, a learned kinematic correction, then a
velocity and position update per block.

Wan, Sun. GGMotion: Group Graph Dynamics-Kinematics Networks for Human Motion Prediction. 2025.
The computation of its public code's CMU model (``cfg/cmu_long.yml``), written from reading it;
data flow, parameters and departures: docs/models/ggmotion.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import torch
import torch.nn.functional as F
from torch import nn

MM_PER_UNIT = 1000.0  # the code's scale: positions in mm divided by 1000
NORM_EPS = 1e-6


def hop_embedding(hops: torch.Tensor, dim: int, max_period: float = 10000.0) -> torch.Tensor:
    """Sinusoidal embedding ``(len(hops), dim)`` of integer hop distances: sines then cosines of
    ``dim // 2`` geometric frequencies from 1 to ``1 / max_period`` (zero-padded to odd ``dim``)."""
    half = dim // 2
    frequencies = torch.exp(-math.log(max_period) / (half - 1) * torch.arange(half))
    angles = hops.float()[:, None] * frequencies[None]
    return F.pad(torch.cat([angles.sin(), angles.cos()], dim=1), (0, dim % 2))


def _check_groups(groups, num_points: int) -> dict[str, list[tuple[int, int]]]:
    """``groups``: ``{name: [[parent, child], ...]}`` in joint indices, every joint a child in
    exactly one group; the first pair of the group holding the root is ``[root, root]``."""
    if not isinstance(groups, Mapping) or not groups:
        raise ValueError(
            f"GGMotion: groups must be a mapping {{name: [[parent, child], ...]}}, got {groups!r}"
        )
    children: dict[int, str] = {}
    out = {}
    for name, pairs in groups.items():
        if not isinstance(pairs, Sequence) or not pairs:
            raise ValueError(f"GGMotion: groups[{name!r}] must be a non-empty list of pairs")
        checked = []
        for pair in pairs:
            if (
                not isinstance(pair, Sequence)
                or len(pair) != 2
                or not all(isinstance(j, int) and 0 <= j < num_points for j in pair)
            ):
                raise ValueError(
                    f"GGMotion: groups[{name!r}] holds {pair!r}; expected [parent, child] joint "
                    f"indices in 0..{num_points - 1}"
                )
            if pair[1] in children:
                raise ValueError(
                    f"GGMotion: joint {pair[1]} is a child in groups[{children[pair[1]]!r}] and "
                    f"again in groups[{name!r}]"
                )
            children[pair[1]] = name
            checked.append((pair[0], pair[1]))
        out[str(name)] = checked
    if len(children) != num_points:
        missing = sorted(set(range(num_points)) - set(children))
        raise ValueError(f"GGMotion: joints {missing} are in no group (num_points {num_points})")
    return out


def hop_edges(bones: Sequence[tuple[int, int]], num_points: int) -> torch.Tensor:
    """Every ordered pair of distinct joints with its hop distance along ``bones`` (a tree):
    ``(P (P - 1), 3)`` rows ``[i, j, hops]`` in ``(i, j)`` order."""
    neighbours: dict[int, set[int]] = {j: set() for j in range(num_points)}
    for a, b in bones:
        neighbours[a].add(b)
        neighbours[b].add(a)
    rows = []
    for start in range(num_points):
        distance, queue = {start: 0}, [start]
        for joint in queue:  # breadth first: the queue grows while it is read
            for n in sorted(neighbours[joint] - set(distance)):
                distance[n] = distance[joint] + 1
                queue.append(n)
        rows += [[start, j, distance[j]] for j in sorted(distance) if j != start]
    if len(rows) != num_points * (num_points - 1):
        raise ValueError("GGMotion: the groups' bones do not connect every joint")
    return torch.tensor(rows, dtype=torch.long)


def _axis_norm(points: torch.Tensor) -> torch.Tensor:
    """``(..., 3, E)`` -> ``(..., E)``: each channel's length over x, y, z. Reduced along a
    contiguous last axis: torch's norm over the strided axis of 3 took 65% of a forward."""
    return torch.linalg.vector_norm(points.transpose(-1, -2).contiguous(), dim=-1)


def _mlp(width_in: int, hidden: int, width_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(width_in, hidden), nn.SiLU(), nn.Linear(hidden, width_out))


def _invariant_mix(
    items: torch.Tensor, maps: nn.ModuleList, mlp: nn.Module, out: nn.Linear, norm: bool
) -> torch.Tensor:
    """Items ``(..., G, 3, E)`` mixed through their rotation-invariant Gram matrix: per channel,
    query and key maps give a ``G x G`` matrix (row-normalised), an MLP turns it into mixing
    weights, which combine the value map's items; returns ``(..., G, 3, E)``."""
    key, query, value = (m(items).transpose(-1, -3) for m in maps)  # (..., E, 3, G)
    gram = query.transpose(-1, -2) @ key  # (..., E, G, G)
    if norm:
        gram = F.normalize(gram, dim=-1, eps=NORM_EPS)
    mixing = mlp(gram.flatten(-2)).unflatten(-1, gram.shape[-2:])
    return out((value @ mixing).transpose(-1, -3))


class GroupBlock(nn.Module):
    """One GGMotion block: forces on every joint's virtual points, then their update."""

    def __init__(
        self,
        num_points: int,
        groups: dict[str, list[tuple[int, int]]],
        edge_dim: int,
        hidden: int,
        norm: bool,
        kinematics: bool,
    ) -> None:
        super().__init__()
        self.norm, self.kinematics = norm, kinematics
        e, h = edge_dim, hidden
        self.spatio_mlp = nn.Linear(e, e, bias=False)
        self.temporal_mlp = nn.Linear(e, e, bias=False)
        # the fields start switched off: a block first passes velocities through
        self.spatio_scale = nn.Parameter(torch.zeros(num_points, 3))
        self.temporal_scale = nn.Parameter(torch.zeros(num_points, 3))
        self.spatio_att_mlp = nn.Sequential(nn.Linear(h, 1), nn.Sigmoid())
        self.spatio_h_mlp = _mlp(e, h, e)
        self.temporal_h_mlp = _mlp(e, h, e)
        count = len(groups)
        self.group_force_emb = nn.ModuleList(nn.Linear(e, e, bias=False) for _ in range(3))
        self.group_force_mlp = _mlp(count**2, h, count**2)
        self.group_force_out = nn.Linear(e, e, bias=False)
        self.part_force_emb = nn.ModuleList(nn.Linear(e, e, bias=False) for _ in range(3))
        self.part_force_mlp = nn.ModuleList(
            _mlp(len(pairs) ** 2, h, len(pairs) ** 2) for pairs in groups.values()
        )
        self.part_force_out = nn.Linear(e, e, bias=False)
        self.a_out_mlp = nn.Linear(e, e, bias=False)
        if kinematics:  # force, bone and bone velocity: 3 vectors, their 3 x 3 Gram matrix
            self.acc_emb = nn.ModuleList(nn.Linear(e, e, bias=False) for _ in range(3))
            self.acc_mlp = _mlp(9, h, 3)
            self.acc_out = nn.Linear(e, e, bias=False)

    def forward(self, x, v, centre, edges, gates, parents, children, members):
        """``x``, ``v``: ``(B, P, 3, E)``; ``centre`` ``(B, 1, 3, 1)``; ``edges`` ``(M, 3)`` and
        their ``gates`` ``(M, 1, 1)``; per group its joints' ``parents`` and ``children`` and
        ``members`` ``(G, P)`` (1 where a joint is a child of the group)."""
        source, target = edges[:, 0], edges[:, 1]
        difference = x[:, source] - x[:, target]  # (B, M, 3, E)
        spatial = gates * self.spatio_h_mlp(_axis_norm(difference)).unsqueeze(-2)
        spatial = spatial * self.spatio_mlp(difference)
        field = torch.zeros_like(x).index_add_(1, source, spatial)
        spatial_force = v + self.spatio_scale[..., None] * field
        about = x - centre
        temporal = self.temporal_h_mlp(_axis_norm(about)).unsqueeze(-2) * self.temporal_mlp(about)
        force = spatial_force + (v + self.temporal_scale[..., None] * temporal)

        # between groups: each group's summed force, mixed, given back to its joints
        group_sums = torch.einsum("gp,bpce->bgce", members, force)
        between = _invariant_mix(
            group_sums, self.group_force_emb, self.group_force_mlp, self.group_force_out, self.norm
        )
        force = force + torch.einsum("gp,bgce->bpce", members, between)

        new_x, new_v = torch.empty_like(x), torch.empty_like(v)
        for mlp, parent, child in zip(self.part_force_mlp, parents, children):
            own = force[:, child]
            within = _invariant_mix(own, self.part_force_emb, mlp, self.part_force_out, self.norm)
            pushed = own + within
            update = (
                pushed - self._correction(pushed, x, v, parent, child)
                if self.kinematics
                else pushed
            )
            new_v[:, child] = v[:, child] + self.a_out_mlp(update)
            new_x[:, child] = x[:, child] + new_v[:, child]
        return new_x, new_v

    def _correction(self, force, x, v, parent, child) -> torch.Tensor:
        """The learned kinematic term: per joint and channel, the Gram matrix of its force, bone
        and bone velocity weighs the three into a correction ``(B, G, 3, E)``."""
        basis = torch.stack([force, x[:, child] - x[:, parent], v[:, child] - v[:, parent]], -2)
        # (B, G, E, 3 coordinates, 3 vectors)
        key, query, value = (m(basis).permute(0, 1, 4, 2, 3) for m in self.acc_emb)
        gram = query.transpose(-1, -2) @ key
        if self.norm:
            gram = F.normalize(gram, dim=-1, eps=NORM_EPS)
        weights = self.acc_mlp(gram.flatten(-2)).unsqueeze(-1)  # (B, G, E, 3, 1)
        return self.acc_out((value @ weights).squeeze(-1).transpose(-1, -2))


class GGMotion(nn.Module):
    def __init__(
        self,
        input_frames: int,
        output_frames: int,
        num_points: int,
        groups: Mapping[str, Sequence[Sequence[int]]] | None = None,
        layers: int = 4,
        edge_dim: int = 112,
        hidden: int = 84,
        norm: bool = True,
        kinematics: bool = True,
        bone_loss: bool = True,
    ) -> None:
        super().__init__()
        for name, value in (
            ("input_frames", input_frames),
            ("output_frames", output_frames),
            ("num_points", num_points),
            ("layers", layers),
            ("edge_dim", edge_dim),
            ("hidden", hidden),
        ):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"GGMotion: {name} must be a positive integer, got {value!r}")
        if input_frames < 2:
            raise ValueError("GGMotion: input_frames must be at least 2 (velocities)")
        if hidden < 4:
            raise ValueError(f"GGMotion: hidden must be at least 4 (hop embedding), got {hidden}")
        for name, flag in (("norm", norm), ("kinematics", kinematics), ("bone_loss", bone_loss)):
            if not isinstance(flag, bool):
                raise ValueError(f"GGMotion: {name} must be true or false, got {flag!r}")
        checked = _check_groups(groups, num_points)
        self.input_frames, self.output_frames, self.num_points = (
            input_frames,
            output_frames,
            num_points,
        )
        self.bone_loss = bone_loss
        bones = [(p, c) for pairs in checked.values() for p, c in pairs if p != c]
        edges = hop_edges(bones, num_points)
        self.register_buffer("edges", edges, persistent=False)
        self.register_buffer("edge_embedding", hop_embedding(edges[:, 2], hidden), persistent=False)
        self.register_buffer("bones", torch.tensor(sorted(bones)), persistent=False)
        members = torch.zeros(len(checked), num_points)
        for g, pairs in enumerate(checked.values()):
            members[g, [c for _, c in pairs]] = 1.0
            self.register_buffer(
                f"parents_{g}", torch.tensor([p for p, _ in pairs]), persistent=False
            )
            self.register_buffer(
                f"children_{g}", torch.tensor([c for _, c in pairs]), persistent=False
            )
        self.register_buffer("members", members, persistent=False)
        self.group_count = len(checked)
        self.x_emb = nn.Linear(input_frames, edge_dim, bias=False)
        self.v_emb = nn.Linear(input_frames, edge_dim, bias=False)
        self.blocks = nn.ModuleList(
            GroupBlock(num_points, checked, edge_dim, hidden, norm, kinematics)
            for _ in range(layers)
        )
        self.center_mlp = nn.ModuleList(
            nn.Linear(edge_dim, output_frames, bias=False) for _ in range(layers)
        )
        self.pro = nn.Linear(edge_dim, output_frames, bias=False)

    def predict_units(self, points: torch.Tensor) -> torch.Tensor:
        """The code's own forward: ``(B, P, 3, T_in)`` in its units (mm / 1000) to
        ``(B, P, 3, T_out)``."""
        velocity = torch.cat([points[..., 1:2] - points[..., :1], points.diff(dim=-1)], dim=-1)
        centre = points.mean(dim=(1, 3), keepdim=True)
        x = self.x_emb(points - centre) + centre
        v = self.v_emb(velocity)
        parents = [getattr(self, f"parents_{g}") for g in range(self.group_count)]
        children = [getattr(self, f"children_{g}") for g in range(self.group_count)]
        for block, to_centre in zip(self.blocks, self.center_mlp):
            gates = block.spatio_att_mlp(self.edge_embedding)[:, :, None]
            x, v = block(x, v, centre, self.edges, gates, parents, children, self.members)
            centre = to_centre(x).mean(dim=(1, 3), keepdim=True)
        return self.pro(x - centre) + centre

    def forward(self, history: torch.Tensor) -> torch.Tensor:
        expected = (self.input_frames, self.num_points, 3)
        if history.ndim != 4 or tuple(history.shape[1:]) != expected:
            raise ValueError(
                f"GGMotion: history must have shape (B, {self.input_frames}, "
                f"{self.num_points}, 3), got {tuple(history.shape)}"
            )
        points = history.permute(0, 2, 3, 1) / MM_PER_UNIT
        return (self.predict_units(points) * MM_PER_UNIT).permute(0, 3, 1, 2)

    def training_loss(self, history: torch.Tensor, future: torch.Tensor) -> torch.Tensor:
        """The code's loss, in its units: the mean Euclidean error of the predicted frames plus,
        with ``bone_loss``, the mean L1 error of every bone vector (child minus parent)."""
        prediction = self(history) / MM_PER_UNIT
        target = future / MM_PER_UNIT
        loss = torch.linalg.vector_norm(prediction - target, dim=-1).mean()
        if self.bone_loss:
            parent, child = self.bones[:, 0], self.bones[:, 1]
            bones = prediction[:, :, child] - prediction[:, :, parent]
            true_bones = target[:, :, child] - target[:, :, parent]
            loss = loss + (bones - true_bones).abs().sum(dim=-1).mean()
        return loss
