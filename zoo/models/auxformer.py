"""AuxFormer, as its public code's long-term CMU model runs: a transformer over one token per
joint and frame (the observed frames, then a mask token for each predicted one) that alternates
attention along time and across joints, trained with two auxiliary tasks beside prediction:
recovering randomly masked observed coordinates, and denoising partly noised ones.

Xu, Tan, Tan, Chen, Wang, Wang. Auxiliary Tasks Benefit 3D Skeleton-based Human Motion
Prediction. ICCV 2023. Public code: MediaBrain-SJTU/AuxFormer (``model/model.py``,
``main_cmu.py``, ``cfg/cmu_long.yml``), written from reading it; the parameter names are the
code's, so its state dicts load as they are. docs/models/auxformer.md says how the zoo scores
the frames the long model does not predict.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

ATTENTION_EPS = 1e-10  # the code's renormalisation of masked attention


def _integer(name: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(f"AuxFormer: {name} must be an integer >= {low}, got {value!r}")
    return value


def _fraction(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= 1:
        raise ValueError(f"AuxFormer: {name} must be a number in [0, 1], got {value!r}")
    return float(value)


class Attention(nn.Module):
    """Multi-head self-attention; a mask ``(B, L, L)`` of 0/1 multiplies the softmax, which is
    then renormalised (the code's rule: a token with nothing visible attends to nothing)."""

    def __init__(self, dim: int, heads: int, dim_per_head: int, dropout: float) -> None:
        super().__init__()
        self.heads = heads
        self.scale = dim_per_head**-0.5
        inner = heads * dim_per_head
        self.to_qkv = nn.Linear(dim, 3 * inner, bias=False)
        projects = not (heads == 1 and dim_per_head == dim)
        self.out = (
            nn.Sequential(nn.Linear(inner, dim), nn.Dropout(dropout)) if projects else nn.Identity()
        )

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        b, n, _ = x.shape
        qkv = self.to_qkv(x).view(b, n, 3, self.heads, -1).permute(2, 0, 3, 1, 4)
        q, k, v = qkv.contiguous()  # the products below run faster on contiguous heads
        attention = torch.softmax(q @ k.transpose(-1, -2) * self.scale, dim=-1)
        if mask is not None:
            attention = attention * mask[:, None]
            attention = attention / (attention.sum(dim=-1, keepdim=True) + ATTENTION_EPS)
        return self.out((attention @ v).transpose(1, 2).reshape(b, n, -1))


class PreNorm(nn.Module):
    def __init__(self, dim: int, net: nn.Module) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(dim)
        self.net = net

    def forward(self, x: torch.Tensor, **kwargs) -> torch.Tensor:
        return self.net(self.norm(x), **kwargs)


class FeedForward(nn.Module):
    def __init__(self, dim: int, hidden: int, dropout: float) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(dim, hidden),
            nn.GELU(),
            nn.Dropout(dropout),
            nn.Linear(hidden, dim),
            nn.Dropout(dropout),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class TransformerLayer(nn.Module):
    """One pre-norm attention and feed-forward layer. The two-deep lists hold the code's
    parameter names (``layers.0.0``: attention, ``layers.0.1``: feed-forward)."""

    def __init__(self, dim: int, hidden: int, heads: int, dim_per_head: int, dropout: float):
        super().__init__()
        attention = PreNorm(dim, Attention(dim, heads, dim_per_head, dropout))
        self.layers = nn.ModuleList(
            [nn.ModuleList([attention, PreNorm(dim, FeedForward(dim, hidden, dropout))])]
        )

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        attention, feed_forward = self.layers[0]
        x = x + attention(x, mask=mask)
        return x + feed_forward(x)


class SpaceTimeBlock(nn.Module):
    """Attention along each joint's frames, then across the joints of each frame, on tokens
    ``(B, N, T, D)`` (the code's ``STTrans`` of depth 1)."""

    def __init__(self, dim: int, hidden: int, heads: int, dim_per_head: int, dropout: float):
        super().__init__()
        self.transformer_t = nn.ModuleList(
            [TransformerLayer(dim, hidden, heads, dim_per_head, dropout)]
        )
        self.transformer_s = nn.ModuleList(
            [TransformerLayer(dim, hidden, heads, dim_per_head, dropout)]
        )

    def forward(self, x, mask_s=None, mask_t=None):
        b, n, t, d = x.shape
        x = self.transformer_t[0](x.reshape(b * n, t, d), mask_t)
        x = x.view(b, n, t, d).permute(0, 2, 1, 3).reshape(b * t, n, d)
        x = self.transformer_s[0](x, mask_s)
        return x.view(b, t, n, d).permute(0, 2, 1, 3)


class Head(nn.Module):
    """Linear, ReLU, linear: a token to a coordinate offset (the code's ``MLP``)."""

    def __init__(self, dim: int, hidden: int) -> None:
        super().__init__()
        self.layers = nn.ModuleList([nn.Linear(dim, hidden), nn.Linear(hidden, 3)])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.layers[1](torch.relu(self.layers[0](x)))


@dataclass(frozen=True)
class Corruption:
    """One batch's auxiliary corruptions, in the model's units: ``visible`` ``(B, N, T_obs)``,
    1 for an observed token the masking task keeps; ``noise`` ``(B, N, T, 3)`` added to every
    token before the denoising task's pass."""

    visible: torch.Tensor
    noise: torch.Tensor


class AuxFormer(nn.Module):
    """``forward(history (B, T_in, J, 3) in mm) -> (B, T_out, J, 3)``.

    The model predicts the future frames ``frame_stride``, ``2 * frame_stride``, ... and the last
    one (the long CMU model: every second frame and the 25th, 13 frames); the frames between are
    drawn on straight lines from their predicted neighbours (the first from the last observed
    frame). ``width``: the token size; ``depth``: encoder and decoder blocks, each with its own
    prediction head; ``mask_ratio``: the share of observed tokens the masking task hides;
    ``noise_ratio`` and ``noise_std`` (low, high): the share of tokens the denoising task noises,
    by a Gaussian whose deviation is drawn uniformly once a batch, in the code's units."""

    def __init__(
        self,
        input_frames: int,
        output_frames: int,
        num_points: int,
        width: int = 96,
        depth: int = 5,
        heads: int = 8,
        dim_per_head: int = 16,
        mlp_dim: int = 96,
        head_hidden: int = 128,
        aux_head_hidden: int = 96,
        frame_stride: int = 2,
        mask_ratio: float = 0.4,
        noise_ratio: float = 0.4,
        noise_std: tuple[float, float] = (0.1, 1.0),
        mm_per_unit: float = 100.0,
        dropout: float = 0.0,
    ) -> None:
        super().__init__()
        self.input_frames = _integer("input_frames", input_frames, 2)
        self.output_frames = _integer("output_frames", output_frames, 1)
        self.num_points = _integer("num_points", num_points, 1)
        stride = _integer("frame_stride", frame_stride, 1)
        predicted = list(range(stride, self.output_frames + 1, stride))
        if not predicted or predicted[-1] != self.output_frames:
            predicted.append(self.output_frames)
        self.predicted = predicted
        self.mask_ratio = _fraction("mask_ratio", mask_ratio)
        self.noise_ratio = _fraction("noise_ratio", noise_ratio)
        if (
            not isinstance(noise_std, (list, tuple))
            or len(noise_std) != 2
            or not all(isinstance(s, (int, float)) and s >= 0 for s in noise_std)
            or noise_std[0] > noise_std[1]
        ):
            raise ValueError(
                f"AuxFormer: noise_std must be [low, high] with 0 <= low <= high, got {noise_std!r}"
            )
        self.noise_std = (float(noise_std[0]), float(noise_std[1]))
        self.mm_per_unit = float(mm_per_unit)
        width, depth = _integer("width", width, 1), _integer("depth", depth, 1)
        tokens = self.input_frames + len(predicted)
        # the code's names and shapes; its decoder width equals its token width
        self.mask_embed = nn.Parameter(torch.randn(width))
        self.patch_embed = nn.Linear(9, width)  # position, velocity, acceleration
        self.decoder_pos_embed = nn.Embedding(tokens, width)
        self.decoder_agent_embed = nn.Embedding(self.num_points, width)
        self.agent_embed = nn.Parameter(torch.randn(1, self.num_points, 1, width))
        self.pos_embed = nn.Parameter(torch.randn(1, 1, tokens, width))
        self.head = nn.ModuleList([Head(width, head_hidden) for _ in range(depth)])
        self.aux_head = Head(width, aux_head_hidden)
        self.aux_head_2 = Head(width, aux_head_hidden)
        block = (width, mlp_dim, heads, dim_per_head, dropout)
        self.encoder = nn.ModuleList([SpaceTimeBlock(*block) for _ in range(depth)])
        self.decoder = nn.ModuleList([SpaceTimeBlock(*block) for _ in range(depth)])
        # each output frame as a mix of two known ones (0: the last observed, i: predicted i)
        known = [0, *predicted]
        left = [max(i for i, f in enumerate(known) if f <= t) for t in range(1, output_frames + 1)]
        right = [min(i for i, f in enumerate(known) if f >= t) for t in range(1, output_frames + 1)]
        weight = [
            0.0 if a == b else (t - known[a]) / (known[b] - known[a])
            for t, a, b in zip(range(1, output_frames + 1), left, right)
        ]
        self.register_buffer("left", torch.tensor(left), persistent=False)
        self.register_buffer("right", torch.tensor(right), persistent=False)
        self.register_buffer("weight", torch.tensor(weight)[:, None, None], persistent=False)

    def encode(
        self, trajectory: torch.Tensor, visible: torch.Tensor | None = None
    ) -> list[torch.Tensor]:
        """Every block's decoded tokens ``(B, N, T, D)`` for ``trajectory`` ``(B, N, T, 3)``, the
        code's ``mask_forward`` with the observed tokens where ``visible`` ``(B, N, T_in)`` is 1
        visible (None: all of them) and the predicted frames' tokens hidden.

        The code's encoder reads all T frames, but its masks hide every hidden token from every
        attention and its outputs there are dropped, so the predicted frames, hidden always,
        change nothing it gives: the encoder here reads the observed frames alone (10 of 23
        tokens on CMU), with no mask where all of them are visible (the same softmax over the
        same keys, but for the code's 1e-10 added to the visible weights' sum, which the hidden
        keys' share of the unmasked softmax scales). The decoder reads all T."""
        b, n, t, _ = trajectory.shape
        seen = self.input_frames
        velocity = torch.zeros_like(trajectory)
        velocity[:, :, 1:] = trajectory[:, :, 1:] - trajectory[:, :, :-1]
        acceleration = torch.zeros_like(velocity)
        acceleration[:, :, 1:] = velocity[:, :, 1:] - velocity[:, :, :-1]
        observed = torch.cat([trajectory, velocity, acceleration], dim=-1)[:, :, :seen]
        tokens = self.patch_embed(observed) + self.pos_embed[:, :, :seen] + self.agent_embed
        queries = self.mask_embed + self.decoder_pos_embed.weight[None, None]
        queries = (queries + self.decoder_agent_embed.weight[None, :, None]).expand(b, n, t, -1)
        hidden = queries[:, :, seen:]
        masks: dict[str, torch.Tensor] = {}
        if visible is not None:
            keep = visible[..., None]
            tokens = tokens * keep
            carried = queries[:, :, :seen] * (1 - keep)  # what a hidden observed token holds
            per_frame = visible.permute(0, 2, 1).reshape(b * seen, n)
            per_joint = visible.reshape(b * n, seen)
            masks = {
                "mask_s": per_frame[:, :, None] * per_frame[:, None, :],
                "mask_t": per_joint[:, :, None] * per_joint[:, None, :],
            }
        out = []
        for encoder, decoder in zip(self.encoder, self.decoder):
            encoded = encoder(tokens, **masks)
            if visible is not None:
                encoded = encoded * keep + carried
            decoded = decoder(torch.cat([encoded, hidden], dim=2))
            tokens, hidden = decoded[:, :, :seen], decoded[:, :, seen:]
            if visible is not None:
                tokens, carried = tokens * keep, tokens * (1 - keep)
            out.append(decoded)
        return out

    def observed_mask(self, trajectory: torch.Tensor) -> torch.Tensor:
        """The code's mask of the tokens the prediction sees ``(B, N, T)``: 1 for the observed
        frames, 0 for the predicted ones."""
        mask = trajectory.new_zeros(trajectory.shape[:3])
        mask[:, :, : self.input_frames] = 1.0
        return mask

    def _trajectory(self, history: torch.Tensor, future: torch.Tensor | None) -> torch.Tensor:
        """The tokens' coordinates ``(B, N, T_in + predicted, 3)`` in the code's units; the
        predicted frames are zeros without ``future`` (they are hidden either way)."""
        expected = (self.input_frames, self.num_points, 3)
        if history.ndim != 4 or tuple(history.shape[1:]) != expected:
            raise ValueError(
                f"AuxFormer: history must have shape (B, {self.input_frames}, "
                f"{self.num_points}, 3), got {tuple(history.shape)}"
            )
        past = history.permute(0, 2, 1, 3) / self.mm_per_unit
        if future is None:
            later = past.new_zeros(past.shape[0], self.num_points, len(self.predicted), 3)
        else:
            later = future[:, [f - 1 for f in self.predicted]].permute(0, 2, 1, 3)
            later = later / self.mm_per_unit
        return torch.cat([past, later], dim=2)

    def predict_units(self, trajectory: torch.Tensor) -> torch.Tensor:
        """The code's ``predict``: tokens ``(B, N, T, 3)`` in its units (the predicted frames'
        values unused) to the predicted frames ``(B, N, len(predicted), 3)``."""
        decoded = self.encode(trajectory)[-1]
        start = trajectory[:, :, self.input_frames - 1 : self.input_frames]
        return self.head[-1](decoded[:, :, self.input_frames :]) + start

    def forward(self, history: torch.Tensor) -> torch.Tensor:
        predicted = self.predict_units(self._trajectory(history, None)) * self.mm_per_unit
        known = torch.cat([history[:, -1:], predicted.permute(0, 2, 1, 3)], dim=1)
        left, right = known[:, self.left], known[:, self.right]
        return left + self.weight * (right - left)

    def draw_corruption(self, trajectory: torch.Tensor) -> Corruption:
        """The auxiliary tasks' random draws for one batch (the code's): ``mask_ratio`` of each
        window's observed tokens hidden, and a Gaussian of one deviation drawn in ``noise_std``
        on ``noise_ratio`` of its tokens."""
        b, n, t, _ = trajectory.shape
        count = n * self.input_frames
        order = torch.rand(b, count, device=trajectory.device).argsort(dim=-1)
        visible = trajectory.new_ones(b, count)
        visible.scatter_(1, order[:, : int(count * self.mask_ratio)], 0.0)
        low, high = self.noise_std
        std = low + (high - low) * torch.rand((), device=trajectory.device)
        kept = torch.rand(b, n, t, device=trajectory.device) < self.noise_ratio
        noise = torch.randn_like(trajectory) * std * kept[..., None]
        return Corruption(visible.view(b, n, self.input_frames), noise)

    def corrupted_loss(self, trajectory: torch.Tensor, corruption: Corruption) -> torch.Tensor:
        """The code's training loss for tokens ``trajectory`` (observed and true predicted
        frames, its units) under ``corruption``: each block head's mean prediction error over
        ``depth``, the masked tokens' mean error (the predicted frames count as masked), and the
        observed tokens' mean error after denoising."""
        observed = self.observed_mask(trajectory)
        masked = torch.cat([corruption.visible, observed[:, :, self.input_frames :]], dim=2)
        start = trajectory[:, :, self.input_frames - 1 : self.input_frames]
        target = trajectory[:, :, self.input_frames :]
        blocks = self.encode(trajectory)
        loss = 0
        for head, decoded in zip(self.head, blocks):
            prediction = head(decoded[:, :, self.input_frames :]) + start
            loss = loss + torch.linalg.vector_norm(prediction - target, dim=-1).mean() / len(blocks)
        hidden = (1 - masked)[..., None]
        recovered = self.aux_head(self.encode(trajectory, corruption.visible)[-1]) + start
        recovered = recovered * hidden
        error = torch.linalg.vector_norm(recovered - trajectory * hidden, dim=-1)
        loss = loss + error.sum() / hidden.sum()
        noisy = self.encode(trajectory + corruption.noise)[-1]
        denoised = self.aux_head_2(noisy[:, :, : self.input_frames]) + start
        past = trajectory[:, :, : self.input_frames]
        return loss + torch.linalg.vector_norm(denoised - past, dim=-1).mean()

    def training_loss(self, history: torch.Tensor, future: torch.Tensor) -> torch.Tensor:
        trajectory = self._trajectory(history, future)
        return self.corrupted_loss(trajectory, self.draw_corruption(trajectory))
