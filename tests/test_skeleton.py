"""Forward kinematics and Rodrigues, checked against values computed by hand."""

import math

import numpy as np
import pytest
import torch

from zoo.data.skeleton import CMU, H36M, Skeleton, forward_kinematics, rodrigues


def chain() -> Skeleton:
    # root -> a (child of root: keeps its offset) -> b -> c
    return Skeleton(
        name="chain4",
        parents=(-1, 0, 1, 2),
        offsets=np.array([[0, 0, 0], [0, 1, 0], [10, 0, 0], [0, 5, 0]], float),
        ignored=(0,),
        copy_to=(),
        copy_from=(),
    )


def test_rodrigues_quarter_turn_about_z():
    r = rodrigues(torch.tensor([[0.0, 0.0, math.pi / 2]], dtype=torch.float64))[0]
    expected = torch.tensor([[0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=torch.float64)
    # Not exact: the unit axis is r / (theta + eps), eps = float32 epsilon, as in the reference.
    assert torch.allclose(r, expected, atol=1e-6)
    assert not torch.allclose(r, expected, atol=1e-9)


def test_rodrigues_zero_is_identity():
    assert torch.equal(rodrigues(torch.zeros(2, 5, 3)), torch.eye(3).expand(2, 5, 3, 3))


def test_fk_by_hand_row_vector_convention():
    sk = chain()
    e = torch.zeros(1, 4, 3, dtype=torch.float64)
    e[0, 0] = torch.tensor([0, 0, 1.0])  # root rotation: never applied
    e[0, 1] = torch.tensor([0, 0, math.pi / 2])  # a: +90 deg about z
    e[0, 2] = torch.tensor([0, 0, math.pi / 2])  # b: another +90 deg about z
    p = forward_kinematics(e, sk)[0]
    # a is a child of the root: p_a = offset_a, whatever its rotation.
    assert torch.allclose(p[1], torch.tensor([0, 1.0, 0], dtype=torch.float64))
    # b: offset_b R_a + p_a with row vectors; [10,0,0] @ Rz(90) = [0,-10,0].
    assert torch.allclose(p[2], torch.tensor([0, -9.0, 0], dtype=torch.float64), atol=1e-5)
    # c: R_b <- R_b R_a = Rz(180); [0,5,0] @ Rz(180) = [0,-5,0].
    assert torch.allclose(p[3], torch.tensor([0, -14.0, 0], dtype=torch.float64), atol=1e-5)


@pytest.mark.parametrize("skeleton", [CMU, H36M])
def test_rest_pose_is_sum_of_offsets(skeleton):
    p = forward_kinematics(torch.zeros(1, skeleton.num_joints, 3, dtype=torch.float64), skeleton)
    for j in range(1, skeleton.num_joints):
        parent = skeleton.parents[j]
        expected = skeleton.offsets[j] + (p[0, parent].numpy() if parent > 0 else 0)
        np.testing.assert_allclose(p[0, j].numpy(), expected, atol=1e-9)


def test_fk_rejects_wrong_shape():
    with pytest.raises(ValueError, match="cmu38.*38"):
        forward_kinematics(torch.zeros(2, 32, 3), CMU)


def test_skeleton_tables_match_spec():
    assert len(CMU.used) == 25 and len(H36M.used) == 22
    assert CMU.num_channels == 117 and H36M.num_channels == 99
