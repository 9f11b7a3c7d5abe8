"""Mesh metrics with hand-computed values, and the mesh path of the evaluator."""
import math

import numpy as np
import pytest
import scipy.sparse as sp
import torch

from zoo.data.mesh import MeshTopology
from zoo.metrics import melv, regress_joints, regressed_mpjpe, vertex_rmse

# One 3-4-5 right triangle: its edges (0,1), (0,2), (1,2) have lengths 3, 4 and 5.
TRIANGLE = torch.tensor([[0.0, 0, 0], [3, 0, 0], [0, 4, 0]])
EDGES = MeshTopology(np.array([[0, 1, 2]]), 3).edges


def test_melv_by_hand():
    pred = torch.stack([TRIANGLE, 2 * TRIANGLE, TRIANGLE + 7])[None]  # (1, 3, 3, 3)
    out = melv(pred, TRIANGLE[None], EDGES)
    # frame 1: unchanged; frame 2: lengths 6, 8, 10 -> |diff| 3, 4, 5 -> 4; frame 3: translated.
    torch.testing.assert_close(out, torch.tensor([[0.0, 4.0, 0.0]]))
    # one edge stretched by 3 (vertex 1 moved along x): mean over 3 edges of (3, 0, |sqrt(52)-5|)
    moved = TRIANGLE.clone()
    moved[1, 0] = 6
    expected = (3 + abs(math.sqrt(36 + 16) - 5)) / 3
    torch.testing.assert_close(melv(moved[None, None], TRIANGLE[None], EDGES),
                               torch.tensor([[expected]]))
    with pytest.raises(ValueError, match="melv: expected pred"):
        melv(pred[0], TRIANGLE[None], EDGES)


def test_vertex_rmse_by_hand():
    target = TRIANGLE[None, None].expand(2, 2, 3, 3)  # bounding-box diagonal |(3, 4, 0)| = 5
    pred = target.clone()
    pred[0, 0] += torch.tensor([1.0, 0, 0])   # every vertex off by 1 -> RMSE 1 -> 0.2
    pred[1, 1, 2, 2] = 3.0                     # one vertex off by 3 -> sqrt(9 / 3) / 5
    out = vertex_rmse(pred, target)
    torch.testing.assert_close(out, torch.tensor([[0.2, 0.0], [0.0, math.sqrt(3) / 5]]))
    with pytest.raises(ValueError, match="vertex_rmse"):
        vertex_rmse(pred[:, :1], target)


def test_mpjpe_through_a_sparse_regressor_by_hand():
    # joint 0 = midpoint of vertices 0 and 1 = (1.5, 0, 0); joint 1 = vertex 2 = (0, 4, 0)
    regressor = sp.csr_matrix(np.array([[0.5, 0.5, 0.0], [0.0, 0.0, 1.0]]))
    target = TRIANGLE[None, None].repeat(1, 2, 1, 1)
    torch.testing.assert_close(regress_joints(target, regressor)[0, 0],
                               torch.tensor([[1.5, 0, 0], [0, 4, 0]]))
    pred = target.clone()
    pred[0, 1, 0] += torch.tensor([0.0, 0, 4])   # joint 0 moves by 2, joint 1 stays: mean 1
    pred[0, 1, 2] += torch.tensor([0.0, 3, 4])   # joint 1 moves by 5: mean (2 + 5) / 2
    torch.testing.assert_close(regressed_mpjpe(pred, target, regressor),
                               torch.tensor([[0.0, 3.5]]))
    with pytest.raises(ValueError, match=r"regressor \(2, 3\) does not fit"):
        regress_joints(torch.zeros(1, 4, 3), regressor)
