"""TFAN ("Twin-Flow Axis Normalization"), as its public CMU code runs it: two MLP predictors of
the same shape, one on joint positions and one on bones (three chain roots' positions and the
22 bone vectors), each over the DCT of 50 observed frames; a learned gate fuses their
predictions joint by joint down the kinematic tree; 10 frames a call, rolled out.

Public code: Deante-dx/TFAN (models/Predictor.py, models/FusionModel.py, exp/cmu/fusion). Its
CMU positions are in metres (mm / 1000), which its published weights expect. docs/models/tfan.md
says where this follows the code and where the paper.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from zoo.models.dct import dct_matrix, idct_matrix
from zoo.models.history import pad_history

MM_PER_UNIT = 1000.0  # the code's scale: positions in mm divided by 1000


class JointNorm(nn.Module):
    """Normalisation across the joints of each coordinate and time step (the code's ``LN_mid``
    over ``(B, J, 3, T)``), with one scale and shift per joint."""

    def __init__(self, joints: int, eps: float = 1e-5) -> None:
        super().__init__()
        self.eps = eps
        self.alpha = nn.Parameter(torch.ones(1, joints, 1, 1))
        self.beta = nn.Parameter(torch.zeros(1, joints, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        centred = x - x.mean(dim=1, keepdim=True)  # once, where the code subtracts twice
        var = (centred**2).mean(dim=1, keepdim=True)
        return centred / (var + self.eps).sqrt() * self.alpha + self.beta


class TemporalBlock(nn.Module):
    """``x + JointNorm(Linear_time(x))`` on ``(B, J * 3, T)``; the linear starts near zero
    (Xavier gain 1e-8), so every block starts as the identity (the code's ``MAN``)."""

    def __init__(self, frames: int, joints: int) -> None:
        super().__init__()
        self.joints = joints
        self.fc = nn.Linear(frames, frames)
        self.norm = JointNorm(joints)
        nn.init.xavier_uniform_(self.fc.weight, gain=1e-8)
        nn.init.zeros_(self.fc.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, d, t = x.shape
        y = self.fc(x).view(b, self.joints, d // self.joints, t)
        return x + self.norm(y).reshape(b, d, t)


class Predictor(nn.Module):
    """Spatial linear, ``blocks`` temporal blocks, spatial linear (initialised near zero): one
    stream's DCT coefficients ``(B, T, J * 3)`` to their residual."""

    def __init__(self, blocks: int, frames: int, joints: int) -> None:
        super().__init__()
        dim = 3 * joints
        self.fc_in = nn.Linear(dim, dim)
        self.fc = nn.Sequential(*[TemporalBlock(frames, joints) for _ in range(blocks)])
        self.fc_out = nn.Linear(dim, dim)
        nn.init.xavier_uniform_(self.fc_out.weight, gain=1e-8)
        nn.init.zeros_(self.fc_out.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.fc(self.fc_in(x).transpose(1, 2)).transpose(1, 2)
        return self.fc_out(y)


def _distance_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean point distance plus mean distance of the frame-to-frame changes, ``(B, T, J, 3)``."""
    velocity = (pred.diff(dim=1) - target.diff(dim=1)).norm(dim=-1).mean()
    return (pred - target).norm(dim=-1).mean() + velocity


def _integer(name: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(f"TFAN: {name} must be an integer >= {low}, got {value!r}")
    return value


class TFAN(nn.Module):
    """``forward(history (B, T_in, J, 3) in mm) -> (B, T_out, J, 3)``.

    ``roots``: the joints whose positions start the bone stream; ``bones``: ``[parent, child]``
    pairs, parents before children, every other joint a child once. The bone layout is the
    roots, then the bones' children in the order given; each fused joint is its bone added to
    a gated mix of its parent's predicted position and its parent's fused one, then gated
    against its own predicted position. ``history_frames``: the frames the predictors read (a
    shorter history is padded with its oldest frame, :func:`zoo.models.history.pad_history`);
    ``chunk``: frames predicted a call.

    Training follows the code's stages (``training_loss``, ``start_epoch``): for the first
    ``streams_epochs`` epochs each stream learns its own next ``chunk`` frames (positions; the
    roots and bone vectors), as ``exp/cmu/position`` and ``exp/cmu/bone`` train them; then the
    gate alone learns to fuse their predictions, the streams held fixed (``exp/cmu/fusion``)."""

    def __init__(
        self,
        input_frames: int,
        output_frames: int,
        num_points: int,
        roots: list[int],
        bones: list[list[int]],
        blocks: int = 48,
        history_frames: int = 50,
        chunk: int = 10,
        streams_epochs: int = 0,
    ) -> None:
        super().__init__()
        self.input_frames = _integer("input_frames", input_frames, 1)
        self.output_frames = _integer("output_frames", output_frames, 1)
        self.history_frames = _integer("history_frames", history_frames, 1)
        self.chunk = _integer("chunk", chunk, 1)
        self.streams_epochs = _integer("streams_epochs", streams_epochs, 0)
        self.phase = "streams" if self.streams_epochs else "gate"
        if self.chunk > self.history_frames:
            raise ValueError(
                f"TFAN: chunk ({chunk}) must not exceed history_frames ({history_frames})"
            )
        joints = _integer("num_points", num_points, 1)
        children = [child for _, child in bones]
        layout = [*roots, *children]
        if sorted(layout) != list(range(joints)):
            raise ValueError(
                f"TFAN: roots {roots} and the bones' children must name each of the "
                f"{joints} joints once, got {sorted(layout)}"
            )
        where = {joint: i for i, joint in enumerate(layout)}
        parents = [where[parent] for parent, _ in bones]
        late = [(p, c) for (p, c), i in zip(bones, parents) if i >= where[c]]
        if late:
            raise ValueError(f"TFAN: bones must list parents before children; {late} do not")
        self.register_buffer("layout", torch.tensor(layout), persistent=False)
        self.register_buffer("starts", torch.tensor([p for p, _ in bones]), persistent=False)
        self.register_buffer("ends", torch.tensor(children), persistent=False)
        self.roots = len(roots)
        self.parents = [None] * self.roots + parents  # in the layout
        self.position = Predictor(blocks, self.history_frames, joints)
        self.bone = Predictor(blocks, self.history_frames, joints)
        self.gate = nn.Linear(6 * joints, 2)
        self.register_buffer("dct", dct_matrix(self.history_frames), persistent=False)
        self.register_buffer("idct", idct_matrix(self.history_frames), persistent=False)

    def to_bones(self, joints: torch.Tensor) -> torch.Tensor:
        """``(B, T, J, 3)`` positions to the bone layout: the roots' positions, then each
        bone's vector from its parent to its child."""
        vectors = joints[:, :, self.ends] - joints[:, :, self.starts]
        return torch.cat([joints[:, :, self.layout[: self.roots]], vectors], dim=2)

    def _stream(self, predictor: Predictor, x: torch.Tensor) -> torch.Tensor:
        """The next ``chunk`` frames of one stream ``(B, T, D)``: its last frame plus the inverse
        DCT of the predicted coefficients (only the rows of those frames)."""
        coefficients = predictor(self.dct @ x)
        return self.idct[: self.chunk] @ coefficients + x[:, -1:]

    def fuse(self, bones: torch.Tensor, positions: torch.Tensor, gates: torch.Tensor):
        """Joint positions ``(B, T, J, 3)`` from both streams' predictions (``bones`` in the bone
        layout, ``positions`` in joint order) and the gates ``(B, T, 2)``."""
        placed = positions[:, :, self.layout]  # positions in the bone layout
        alpha, beta = gates[..., :1], gates[..., 1:]
        fused = [(placed[:, :, i] + bones[:, :, i]) / 2 for i in range(self.roots)]
        for i in range(self.roots, len(self.parents)):
            p = self.parents[i]
            chained = bones[:, :, i] + alpha * placed[:, :, p] + (1 - alpha) * fused[p]
            fused.append(chained * (1 - beta) + beta * placed[:, :, i])
        out = torch.stack(fused, dim=2)
        return out[:, :, torch.argsort(self.layout)]

    def start_epoch(self, epoch: int, frames) -> None:
        """Training-engine hook: the streams learn in the first ``streams_epochs`` epochs, the
        gate after them."""
        self.phase = "streams" if epoch < self.streams_epochs else "gate"

    def _inputs(self, history: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Both streams' inputs ``(B, history_frames, 3J)`` in metres: the positions (padded
        to the frames the model reads) and their bone layout."""
        positions = pad_history(history / MM_PER_UNIT, self.history_frames)
        b, _, j, _ = positions.shape
        return positions.reshape(b, -1, 3 * j), self.to_bones(positions).reshape(b, -1, 3 * j)

    def _next_chunk(self, positions: torch.Tensor, bones: torch.Tensor):
        """Each stream's next ``chunk`` frames ``(B, chunk, J, 3)`` from its inputs
        ``(B, T, 3J)``, in :meth:`fuse`'s order: the bone stream's, then the position stream's."""
        b, _, d = positions.shape
        shape = (b, -1, d // 3, 3)
        bone = self._stream(self.bone, bones).view(shape)
        return bone, self._stream(self.position, positions).view(shape)

    def _gated(self, bones: torch.Tensor, positions: torch.Tensor) -> torch.Tensor:
        """:meth:`fuse` of both streams' next frames under the gates the gate layer gives them."""
        gates = torch.sigmoid(self.gate(torch.cat([bones.flatten(2), positions.flatten(2)], -1)))
        return self.fuse(bones, positions, gates)

    def training_loss(self, history: torch.Tensor, future: torch.Tensor) -> torch.Tensor:
        """The code's loss on the next ``chunk`` frames, in metres: the mean distance of each
        predicted point from its target plus that of their frame-to-frame changes. The streams'
        phase sums it over both streams' own outputs (their parameters are apart, so each learns
        as alone); the gate's phase takes it on the fused joints, the streams held fixed."""
        target = future[:, : self.chunk] / MM_PER_UNIT
        with torch.set_grad_enabled(self.phase == "streams" and torch.is_grad_enabled()):
            bones, positions = self._next_chunk(*self._inputs(history))
        if self.phase == "streams":
            return _distance_loss(positions, target) + _distance_loss(bones, self.to_bones(target))
        return _distance_loss(self._gated(bones, positions), target)

    def forward(self, history: torch.Tensor) -> torch.Tensor:
        b, _, j, _ = history.shape
        positions, bones = self._inputs(history)
        out = []
        for _ in range(math.ceil(self.output_frames / self.chunk)):
            step = self._gated(*self._next_chunk(positions, bones))
            out.append(step)
            positions = torch.cat([positions[:, self.chunk :], step.reshape(b, -1, 3 * j)], 1)
            stepped = self.to_bones(step).reshape(b, -1, 3 * j)
            bones = torch.cat([bones[:, self.chunk :], stepped], 1)
        return torch.cat(out, dim=1)[:, : self.output_frames] * MM_PER_UNIT
