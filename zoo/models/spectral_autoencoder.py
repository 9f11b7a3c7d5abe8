"""SpecTrHuMS's spectral autoencoder: a per-frame convolutional autoencoder of spectral
coefficients ``(N, k, 3) <-> (N, latent)``, convolving and pooling along the frequency axis.

Lemeunier, Denis, Lavoué, Dupont. SpecTrHuMS: Spectral Transformer for Human Mesh Sequence
learning. Computers & Graphics 2023. The model that uses it: :mod:`zoo.models.spectrhums`.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn


class FrequencyPooling(nn.Module):
    """A learned matrix along the frequency axis: ``(N, C, n_in) -> (N, C, n_out)``."""

    def __init__(self, n_in: int, n_out: int) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.empty(n_in, n_out))
        nn.init.xavier_uniform_(self.weight)

    def forward(self, x: Tensor) -> Tensor:
        return x @ self.weight

    def extra_repr(self) -> str:
        return f"{self.weight.shape[0]} -> {self.weight.shape[1]}"


class SpectralAutoencoder(nn.Module):
    """Per-frame autoencoder of standardised coefficients ``(N, k, 3) <-> (N, latent)``.

    Encoder: for each level, ``Conv1d`` along the frequency axis (zero padding, same length),
    learned pooling of that axis, ELU; then flatten (channel-major) and a linear layer to the
    latent. Decoder: the mirror image (linear, then per level unpooling, ``Conv1d``, ELU), ending
    in a ``Conv1d`` to the 3 coordinates. Published sizes: channels (32, 64), pooling (64, 32),
    kernel 3, latent 256.

    The parameters are those of these layers (``nn.Conv1d`` weights, pooling matrices), but the
    arithmetic runs on a frequency-major layout ``(frequencies, frames, channels)`` where every
    step is one large matrix product over all frames. Convolution and (un)pooling are both
    linear with nothing between them, so the encoder computes ``pool(conv(x))`` as
    ``mix_channels(pool_shifted(x))`` and the decoder ``conv(unpool(x))`` as
    ``unpool_shifted(mix_channels(x))``: the same sums in another order, without the slow
    convolutions over all ``k`` frequencies (3 input channels in the encoder).
    """

    def __init__(
        self, k: int, channels: Sequence[int], pooling: Sequence[int], kernel_size: int, latent: int
    ) -> None:
        super().__init__()
        sizes = [k, *pooling]
        enc_ch = [3, *channels]
        self.encoder_convs = nn.ModuleList(
            nn.Conv1d(enc_ch[i], enc_ch[i + 1], kernel_size, padding=kernel_size // 2)
            for i in range(len(channels))
        )
        self.encoder_pools = nn.ModuleList(
            FrequencyPooling(sizes[i], sizes[i + 1]) for i in range(len(channels))
        )
        self.bottleneck = (channels[-1], pooling[-1])
        self.to_latent = nn.Linear(channels[-1] * pooling[-1], latent)
        self.from_latent = nn.Linear(latent, channels[-1] * pooling[-1])
        dec_ch = [*channels[::-1], channels[0]]  # (32, 64) -> 64 -> 32 -> 32, then 32 -> 3
        rev = sizes[::-1]
        self.decoder_pools = nn.ModuleList(
            FrequencyPooling(rev[i], rev[i + 1]) for i in range(len(channels))
        )
        self.decoder_convs = nn.ModuleList(
            nn.Conv1d(dec_ch[i], dec_ch[i + 1], kernel_size, padding=kernel_size // 2)
            for i in range(len(channels))
        )
        self.to_coordinates = nn.Conv1d(dec_ch[-1], 3, kernel_size, padding=kernel_size // 2)

    def encode(self, x: Tensor) -> Tensor:
        """``(N, k, 3) -> (N, latent)``."""
        h = x.transpose(0, 1)  # (k, N, 3): the coordinates are the input channels
        for conv, pool in zip(self.encoder_convs, self.encoder_pools):
            h = F.elu(_conv_then_pool(h, conv.weight, conv.bias, pool.weight))
        return self.to_latent(h.permute(1, 2, 0).flatten(1))  # channel-major flatten

    def decode(self, z: Tensor) -> Tensor:
        """``(N, latent) -> (N, k, 3)``."""
        h = self.from_latent(z).view(-1, *self.bottleneck).permute(2, 0, 1)  # (J, N, C)
        for pool, conv in zip(self.decoder_pools, self.decoder_convs):
            h = F.elu(_unpool_then_conv(h, pool.weight, conv.weight, conv.bias))
        # The last layer's outputs are scaled by the coefficients' std (up to metres once
        # de-standardised): float32 even under a bfloat16 autocast.
        with torch.autocast(h.device.type, enabled=False):
            out = _conv(
                h.to(self.to_coordinates.weight.dtype),
                self.to_coordinates.weight,
                self.to_coordinates.bias,
            )
        return out.transpose(0, 1)  # (N, k, 3)


def _conv_then_pool(x: Tensor, weight: Tensor, bias: Tensor, pool: Tensor) -> Tensor:
    """``Conv1d`` (zero padding, same length) then pooling, on ``x (L, N, C)`` -> ``(M, N, O)``.

    ``pool(conv(x))[j, o] = sum_{c,d} W[o,c,d] sum_g x[g,c] S_d[g,j] + b[o] sum_f P[f,j]`` with
    ``S_d[g, j] = P[g - d + pad, j]`` (zero outside): pool the shifted inputs, then mix channels.
    """
    length, n, c = x.shape
    o, _, kernel = weight.shape
    pad, m = kernel // 2, pool.shape[1]
    padded = F.pad(pool, (0, 0, pad, pad))  # padded[i] = P[i - pad]
    shifted = torch.stack([padded[2 * pad - d : 2 * pad - d + length] for d in range(kernel)])
    y = shifted.transpose(1, 2).reshape(kernel * m, length) @ x.reshape(length, n * c)
    y = y.view(kernel, m, n, c).permute(1, 2, 3, 0).reshape(m * n, c * kernel)
    out = (y @ weight.reshape(o, c * kernel).T).view(m, n, o)
    return out + (pool.sum(0)[:, None] * bias)[:, None, :]


def _unpool_then_conv(x: Tensor, pool: Tensor, weight: Tensor, bias: Tensor) -> Tensor:
    """Unpooling with ``pool (J, L)`` then ``Conv1d`` (zero padding, same length), on
    ``x (J, N, C)`` -> ``(L, N, O)``.

    ``conv(unpool(x))[f, o] = b[o] + sum_{d,j} U_d[j, f] sum_c W[o,c,d] x[j,c]`` with
    ``U_d[j, f] = U[j, f + d - pad]`` (zero outside): mix channels per tap, then one product
    with the shifted unpooling matrices.
    """
    j, n, c = x.shape
    o, _, kernel = weight.shape
    pad, length = kernel // 2, pool.shape[1]
    mixed = x.reshape(j * n, c) @ weight.permute(1, 2, 0).reshape(c, kernel * o)
    mixed = mixed.view(j, n, kernel, o).permute(2, 0, 1, 3).reshape(kernel * j, n * o)
    padded = F.pad(pool, (pad, pad))  # padded[:, i] = U[:, i - pad]
    shifted = torch.cat([padded[:, d : d + length] for d in range(kernel)])  # (K * J, L)
    return (shifted.T @ mixed).view(length, n, o) + bias


def _conv(x: Tensor, weight: Tensor, bias: Tensor) -> Tensor:
    """``Conv1d`` (zero padding, same length) on ``x (L, N, C)`` -> ``(L, N, O)``: one matrix
    product for every tap at once, then the taps' shifted sums."""
    length, n, c = x.shape
    o, _, kernel = weight.shape
    pad = kernel // 2
    taps = x.reshape(length * n, c) @ weight.permute(1, 2, 0).reshape(c, kernel * o)
    taps = taps.view(length, n, kernel, o)
    out = taps[:, :, pad] + bias
    for d in range(kernel):
        s = d - pad  # out[f] += taps[f + s, tap d]
        if s > 0:
            out[: length - s] += taps[s:, :, d]
        elif s < 0:
            out[-s:] += taps[: length + s, :, d]
    return out
