"""Skeleton models (SPEC section 5): the DCT, the MLP baseline and SPGSN."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.fft
import torch

import zoo
from zoo.evaluate import evaluate
from zoo.models.dct import dct_matrix, idct_matrix
from zoo.models.mlp import SiMLPe
from zoo.registry import REPO_ROOT, RegistryError

CMU_ROOT = (REPO_ROOT / "../shared/data/cmu_mocap").resolve()
SKELETON_MODELS = ["mlp"]
# Small configurations for the tests that only need the wiring, not the paper's size.
SMALL = {"mlp": {"blocks": 4}}


def motion(batch: int, frames: int, points: int = 25, seed: int = 0) -> torch.Tensor:
    """Smooth random motion in mm: an offset per joint (up to ~1 m) plus a random walk, with
    some coordinates near zero so that absolute tolerances bite."""
    g = torch.Generator().manual_seed(seed)
    offsets = torch.randn(batch, 1, points, 3, generator=g) * 400
    offsets[:, :, :3] = torch.rand(batch, 1, 3, 3, generator=g)  # within 1 mm of the origin
    steps = torch.randn(batch, frames, points, 3, generator=g) * 5
    return offsets + steps.cumsum(dim=1)


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


# ---- MLP baseline (siMLPe) -----------------------------------------------------------------------

def test_untrained_mlp_is_repeat_last_to_a_micrometre_in_mm():
    model = zoo.create_model("mlp", benchmark="cmu").eval()
    history = motion(16, 10)
    with torch.no_grad():
        predicted = model(history)
    assert predicted.shape == (16, 25, 25, 3)
    deviation = (predicted - history[:, -1:]).abs().max().item()
    assert deviation <= 1e-6, deviation


def test_mlp_repeat_last_check_detects_a_non_tiny_gain():
    # The same check fails for a model that does not start near zero (the check can fail).
    model = SiMLPe(10, 25, 25, blocks=4, init_gain=1e-3).eval()
    history = motion(4, 10)
    with torch.no_grad():
        assert (model(history) - history[:, -1:]).abs().max().item() > 1e-6


def test_mlp_rolls_out_chunks_autoregressively():
    torch.manual_seed(0)
    model = SiMLPe(10, 25, 25, blocks=3, chunk=10, init_gain=1.0).eval()
    history = motion(3, 10)
    with torch.no_grad():
        predicted = model(history)
        first = model.step(history)
        second = model.step(first)  # the last 10 frames seen are exactly the first chunk
        third = model.step(second)
    assert torch.allclose(predicted, torch.cat([first, second, third[:, :5]], dim=1))
    assert (predicted[:, 10:] - predicted[:, 9:10]).abs().max() > 1.0  # a real, moving rollout


def test_mlp_chunk_is_at_most_the_observed_frames_and_sets_the_steps():
    model = SiMLPe(10, 25, 25, blocks=1, chunk=64)
    assert model.chunk == 10
    model = SiMLPe(10, 25, 25, blocks=1, chunk=5, init_gain=1.0).eval()
    calls = []
    original = model.step
    model.step = lambda window: calls.append(window.shape) or original(window)
    with torch.no_grad():
        assert model(motion(2, 10)).shape == (2, 25, 25, 3)
    assert len(calls) == 5


def test_mlp_training_loss_is_position_plus_velocity_l2_in_metres():
    torch.manual_seed(1)
    model = SiMLPe(10, 25, 25, blocks=2, init_gain=1.0)
    history, future = motion(4, 10, seed=1), motion(4, 25, seed=2)
    loss = model.training_loss(history, future)
    predicted = model.step(history) / 1000
    target = future[:, :10] / 1000
    position = (predicted - target).norm(dim=-1).mean()
    velocity = ((predicted[:, 1:] - predicted[:, :-1]) - (target[:, 1:] - target[:, :-1]))
    expected = position + velocity.norm(dim=-1).mean()
    assert loss.ndim == 0 and torch.allclose(loss, expected, rtol=1e-5)
    loss.backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in model.parameters())


def test_mlp_is_the_published_architecture():
    model = zoo.create_model("mlp", benchmark="cmu")
    assert len(model.blocks) == 48
    assert model.spatial_in.in_features == model.spatial_out.out_features == 75
    assert all(block.weight.shape == (10, 10) for block in model.blocks)  # T_in -> T_in
    assert all(block.norm.normalized_shape == (75,) for block in model.blocks)  # spatial axis
    assert not any(isinstance(m, (torch.nn.ReLU, torch.nn.GELU, torch.nn.Tanh))
                   for m in model.modules())


@pytest.mark.parametrize("kwargs, message", [
    ({"chunk": 0}, "chunk"), ({"blocks": -1}, "blocks"), ({"hidden_dim": 0}, "hidden_dim"),
    ({"init_gain": -1.0}, "init_gain")])
def test_mlp_rejects_bad_hyper_parameters(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SiMLPe(10, 25, 25, **kwargs)


def test_mlp_rejects_wrong_input_shape():
    with pytest.raises(ValueError, match=r"history must have shape \(B, 10, 25, 3\)"):
        SiMLPe(10, 25, 25, blocks=1)(torch.zeros(2, 9, 25, 3))


# ---- every skeleton model: registry, contract, evaluator ------------------------------------------

@pytest.mark.parametrize("name", SKELETON_MODELS)
def test_registered_model_follows_the_contract(name):
    entry = zoo.load_registry().get(name)
    assert entry.trainable and "joints" in entry.representation
    assert {"optimizer", "lr", "weight_decay", "batch_size", "epochs", "grad_clip", "schedule",
            "augment"} <= set(entry.train)
    model = zoo.create_model(name, benchmark="cmu", **SMALL[name])
    history, future = motion(3, 10), motion(3, 25, seed=5)
    predicted = model.eval()(history)
    assert predicted.shape == (3, 25, 25, 3) and predicted.dtype == torch.float32
    assert torch.isfinite(predicted).all()
    loss = model.train().training_loss(history, future)
    assert loss.ndim == 0 and torch.isfinite(loss)
    loss.backward()


@pytest.mark.parametrize("name", SKELETON_MODELS)
def test_unknown_hyper_parameter_is_an_error(name):
    with pytest.raises(RegistryError, match="no hyper-parameter 'hiden'"):
        zoo.create_model(name, benchmark="cmu", hiden=3)


@pytest.fixture(scope="module")
def cmu_test_data():
    if not (CMU_ROOT / "test").is_dir():
        pytest.skip(f"CMU Mocap test data not found at {CMU_ROOT}")
    from zoo.benchmark import get_benchmark
    return get_benchmark("cmu").load(CMU_ROOT)


@pytest.fixture(scope="module")
def repeat_last_result(cmu_test_data):
    return evaluate(zoo.create_model("repeat_last", benchmark="cmu"), "cmu",
                    model_name="repeat_last", dataset=cmu_test_data)


@pytest.mark.parametrize("name", SKELETON_MODELS)
def test_models_evaluate_on_real_cmu_test_data(name, cmu_test_data, repeat_last_result):
    torch.manual_seed(0)
    model = zoo.create_model(name, benchmark="cmu", **SMALL[name])
    result = evaluate(model, "cmu", model_name=name, dataset=cmu_test_data)
    frame, reference = result.frame, repeat_last_result.frame
    assert len(frame) == len(reference) > 0
    assert np.isfinite(frame["value"]).all() and (frame["value"] > 0).all()
    assert result.protocol["protocol_id"] == repeat_last_result.protocol["protocol_id"]
    if name == "mlp":  # untrained: repeat-last, so the same table to float rounding
        np.testing.assert_allclose(frame["value"], reference["value"], atol=1e-4)
