"""The one DCT routine of the zoo: the orthonormal DCT-II along time, as a matrix.

``dct_matrix(n) @ x`` (``x`` with time on the first axis) gives the same coefficients as
``scipy.fft.dct(x, type=2, norm='ortho', axis=0)``. The matrix is orthogonal, so its inverse
(the orthonormal DCT-III) is its transpose. Both are built in float64 and cast once, so the round
trip is exact to float32 rounding.
"""

from __future__ import annotations

import math

import torch


def dct_matrix(
    n: int, dtype: torch.dtype = torch.float32, device: torch.device | str | None = None
) -> torch.Tensor:
    """The ``(n, n)`` orthonormal DCT-II matrix ``D``: coefficients ``c = D @ x``.

    ``D[k, t] = s_k * cos(pi * (2t + 1) * k / (2n))`` with ``s_0 = sqrt(1/n)`` and
    ``s_k = sqrt(2/n)`` otherwise.
    """
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise ValueError(
            f"dct_matrix: n (the number of frames) must be a positive integer, got {n!r}"
        )
    k = torch.arange(n, dtype=torch.float64)[:, None]
    t = torch.arange(n, dtype=torch.float64)[None, :]
    matrix = torch.cos(math.pi * (2 * t + 1) * k / (2 * n)) * math.sqrt(2.0 / n)
    matrix[0] *= math.sqrt(0.5)
    return matrix.to(dtype=dtype, device=device)


def idct_matrix(
    n: int, dtype: torch.dtype = torch.float32, device: torch.device | str | None = None
) -> torch.Tensor:
    """The inverse of :func:`dct_matrix`: its transpose (``x = D^T @ c``)."""
    return dct_matrix(n, torch.float64).T.contiguous().to(dtype=dtype, device=device)
