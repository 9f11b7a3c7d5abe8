"""SpecTrHuMS's latent transformer: post-norm transformer encoder layers over a window of
per-frame latents, with sinusoidal positions.

Lemeunier, Denis, Lavoué, Dupont. SpecTrHuMS: Spectral Transformer for Human Mesh Sequence
learning. Computers & Graphics 2023. The model that uses it: :mod:`zoo.models.spectrhums`.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn


class EncoderLayer(nn.Module):
    """A post-norm transformer encoder layer (as ``nn.TransformerEncoderLayer`` with
    ``norm_first=False``, GELU): ``x = LN(x + MHA(x))``, ``x = LN(x + FF(x))``, on
    ``(B, T, E)``, with one fused projection for queries, keys and values."""

    def __init__(self, d_model: int, heads: int, ff: int, dropout: float) -> None:
        super().__init__()
        self.heads, self.dropout = heads, dropout
        self.qkv = nn.Linear(d_model, 3 * d_model)
        self.attn_out = nn.Linear(d_model, d_model)
        self.norm1 = nn.LayerNorm(d_model)
        self.ff1 = nn.Linear(d_model, ff)
        self.ff2 = nn.Linear(ff, d_model)
        self.norm2 = nn.LayerNorm(d_model)

    def forward(self, x: Tensor) -> Tensor:
        b, t, e = x.shape
        p = self.dropout if self.training else 0.0
        q, k, v = self.qkv(x).view(b, t, 3, self.heads, e // self.heads).permute(2, 0, 3, 1, 4)
        # Attention written out rather than torch's fused kernel, for CPU training speed
        # (measured: docs/models/spectrhums.md, "Implementation notes").
        weights = ((q * (e // self.heads) ** -0.5) @ k.transpose(-2, -1)).softmax(-1)
        a = F.dropout(weights, p, self.training) @ v
        a = self.attn_out(a.transpose(1, 2).reshape(b, t, e))
        x = self.norm1(x + F.dropout(a, p, self.training))
        h = self.ff2(F.dropout(F.gelu(self.ff1(x)), p, self.training))
        return self.norm2(x + F.dropout(h, p, self.training))


class LatentTransformer(nn.Module):
    """Linear, sinusoidal positions, dropout (``position_dropout``, 0.1 in the public code),
    post-norm transformer encoder layers, Linear."""

    def __init__(
        self,
        latent: int,
        d_model: int,
        layers: int,
        heads: int,
        ff: int,
        dropout: float,
        window: int,
        position_dropout: float = 0.0,
    ) -> None:
        super().__init__()
        self.position_dropout = position_dropout
        self.inp = nn.Linear(latent, d_model)
        self.layers = nn.ModuleList(
            EncoderLayer(d_model, heads, ff, dropout) for _ in range(layers)
        )
        self.out = nn.Linear(d_model, latent)
        self.register_buffer("positions", sinusoidal_positions(window, d_model), persistent=False)

    def forward(self, x: Tensor) -> Tensor:
        h = F.dropout(
            self.inp(x) + self.positions[: x.shape[1]], self.position_dropout, self.training
        )
        for layer in self.layers:
            h = layer(h)
        return self.out(h)


def sinusoidal_positions(length: int, dim: int) -> Tensor:
    """``pe[t, 2i] = sin(t / 10000^(2i/dim))``, ``pe[t, 2i+1] = cos(...)``: ``(length, dim)``."""
    t = torch.arange(length, dtype=torch.float64)[:, None]
    freq = torch.exp(torch.arange(0, dim, 2, dtype=torch.float64) * (-math.log(10000.0) / dim))
    pe = torch.zeros(length, dim, dtype=torch.float64)
    pe[:, 0::2] = torch.sin(t * freq)
    pe[:, 1::2] = torch.cos(t * freq)
    return pe.float()
