"""GGMotion as its public code computes it on CMU: parameters, the hop graph, rotation
equivariance, the loss, refusals. The layer-for-layer comparison with the public code is
benchmarks/speed/public_ggmotion.py (it needs a checkout)."""

import math

import pytest
import torch

import zoo
from zoo.models.ggmotion import GGMotion, hop_edges, hop_embedding
from zoo.models.registry import RegistryError


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return zoo.create_model("ggmotion", benchmark="cmu")


def test_cmu_model_has_the_codes_parameter_count(model):
    # the public code's long CMU model, counted from an instantiated model (SPEC section 5)
    assert sum(p.numel() for p in model.parameters()) == 1_032_076
    assert all(b.spatio_scale.abs().sum() == 0 for b in model.blocks)  # fields start off


def test_every_ordered_joint_pair_is_an_edge_labelled_by_its_hops(model):
    edges = model.edges
    assert edges.shape == (25 * 24, 3)
    hops = {(i, j): k for i, j, k in edges.tolist()}
    assert hops[8, 9] == hops[9, 8] == 1
    assert hops[3, 7] == 8  # left foot to right foot through the lower spine
    assert hops[17, 23] == 10  # hand to hand through the thorax
    assert min(hops.values()) == 1 and max(hops.values()) == 10
    assert all(hops[i, j] == hops[j, i] for i, j in hops)
    # the sinusoidal label: sines then cosines of geometric frequencies
    table = hop_embedding(torch.tensor([0, 3]), 84)
    assert table.shape == (2, 84) and torch.equal(table[0, :42], torch.zeros(42))
    assert table[1, 0].item() == pytest.approx(math.sin(3.0))


def test_a_rotated_motion_gives_the_rotated_prediction():
    """Gram matrices and norms over x, y, z, and channel maps that never mix them: the
    prediction turns with the body, as long as each field's (joint, axis) scale is the same on
    the three axes (the code learns one per axis, which training may make differ)."""
    torch.manual_seed(1)
    model = zoo.create_model("ggmotion", benchmark="cmu").eval()
    with torch.no_grad():
        for block in model.blocks:  # switch the fields on, so that they count
            block.spatio_scale.copy_(torch.randn(25, 1).expand(25, 3) * 0.05)
            block.temporal_scale.copy_(torch.randn(25, 1).expand(25, 3) * 0.05)
    history = torch.randn(3, 10, 25, 3).cumsum(1) * 20 + torch.randn(3, 1, 25, 3) * 300
    q, _ = torch.linalg.qr(torch.randn(3, 3))
    with torch.no_grad():
        turned = model(history @ q.T)
        expected = model(history) @ q.T
    assert (turned - expected).abs().max() < 1e-2  # mm
    assert (turned - model(history)).abs().max() > 10  # and the rotation did move it


def test_the_loss_is_the_codes_error_plus_the_bone_error(model):
    history = torch.randn(2, 10, 25, 3) * 100
    with torch.no_grad():
        future = model(history)
        assert model.training_loss(history, future).item() == pytest.approx(0.0, abs=1e-6)
        shifted = future + torch.tensor([3.0, 4.0, 0.0])  # every joint 5 mm off, bones intact
        assert model.training_loss(history, shifted).item() == pytest.approx(0.005, rel=1e-4)
        moved = future.clone()
        moved[:, :, 17] += torch.tensor([1.0, 0.0, 0.0])  # the left hand's tip 1 mm off
        loss = model.training_loss(history, moved).item()
    # mean error 1/25 mm, plus the one bone of 24 that changed, by 1 mm in L1
    assert loss == pytest.approx((1 / 25 + 1 / 24) / 1000, rel=1e-4)


def test_bad_groups_are_named():
    with pytest.raises(ValueError, match="joint 9 is a child in groups"):
        GGMotion(10, 25, 10, groups={"a": [[0, 0], [0, 9]], "b": [[0, 9]]})
    with pytest.raises(ValueError, match=r"joints \[2\] are in no group"):
        GGMotion(10, 25, 3, groups={"a": [[0, 0], [0, 1]]})
    with pytest.raises(ValueError, match="expected \\[parent, child\\] joint indices in 0..2"):
        GGMotion(10, 25, 3, groups={"a": [[0, 0], [0, 1], [1, 7]]})
    with pytest.raises(ValueError, match="do not connect every joint"):
        hop_edges([(0, 1)], 3)
    with pytest.raises(RegistryError, match="its hyper-parameters: bone_loss, edge_dim, groups"):
        zoo.create_model("ggmotion", benchmark="cmu", heads=4)
