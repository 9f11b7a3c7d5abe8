"""Skeleton models (SPEC section 5): the DCT, the MLP baseline and SPGSN."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.fft
import torch

from zoo.models.dct import dct_matrix, idct_matrix


# ---- DCT -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("n", [1, 2, 10, 35, 50])
def test_dct_matches_scipy_orthonormal_dct2(n):
    x = np.random.default_rng(n).normal(size=(n, 7))
    expected = scipy.fft.dct(x, type=2, norm="ortho", axis=0)
    np.testing.assert_allclose(dct_matrix(n, torch.float64).numpy() @ x, expected, atol=1e-12)
    np.testing.assert_allclose(dct_matrix(n).numpy() @ x, expected, atol=1e-5)


@pytest.mark.parametrize("n", [10, 35])
def test_dct_round_trip_is_exact(n):
    x = torch.randn(n, 75, generator=torch.Generator().manual_seed(n))
    d, d_inv = dct_matrix(n), idct_matrix(n)
    assert torch.equal(d_inv, d.T)
    assert torch.allclose(d_inv @ (d @ x), x, atol=1e-6, rtol=0)
    assert torch.allclose(d @ d_inv, torch.eye(n), atol=1e-6, rtol=0)
    # the inverse is scipy's orthonormal DCT-III
    np.testing.assert_allclose(d_inv.double().numpy() @ x.double().numpy(),
                               scipy.fft.idct(x.double().numpy(), type=2, norm="ortho", axis=0),
                               atol=1e-5)


@pytest.mark.parametrize("n", [0, -3, 2.0, True])
def test_dct_rejects_bad_sizes(n):
    with pytest.raises(ValueError, match="positive integer"):
        dct_matrix(n)
