import numpy as np
import pytest

from zoo.data.mesh import MeshDataset, MeshError, MeshSequence, MeshTopology


def square() -> MeshTopology:
    return MeshTopology(np.array([[0, 1, 2], [0, 2, 3]]), 4, name="square")


def test_edges_and_laplacian_of_two_triangles():
    t = square()
    assert t.edges.tolist() == [[0, 1], [0, 2], [0, 3], [1, 2], [2, 3]]
    lap = t.laplacian().toarray()
    assert lap.diagonal().tolist() == [3, 2, 3, 2]
    np.testing.assert_array_equal(lap.sum(axis=1), 0)


@pytest.mark.parametrize(
    "faces, n, message",
    [
        (np.zeros((0, 3), int), 0, "empty mesh"),
        (np.array([[0, 1, 5]]), 3, r"face indices must lie in \[0, 3\)"),
        (np.array([[0, 1, 1]]), 3, "repeats a vertex"),
        (np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4]]), 5, "non-manifold.*edge \\[0, 1\\]"),
        (np.array([[0, 1, 2]]), 4, "vertex 3 belongs to no face"),
    ],
)
def test_bad_meshes_are_named(faces, n, message):
    with pytest.raises(MeshError, match=message):
        MeshTopology(faces, n)


def test_dataset_round_trip_and_wrong_vertex_count(tmp_path):
    t = square()
    seq = MeshSequence(
        "s0", "fall", np.random.default_rng(0).normal(size=(5, 4, 3)).astype("f4"), 25.0
    )
    ds = MeshDataset("toy", "test", t, [seq], recipe={"seed": 0})
    back = MeshDataset.load(ds.save(tmp_path / "toy"))
    assert back.topology.hash == t.hash and back.content_hash() == ds.content_hash()
    with pytest.raises(MeshError, match="do not fit topology"):
        MeshDataset(
            "toy", "test", t, [MeshSequence("bad", "x", np.zeros((2, 5, 3)), 25.0)], recipe={}
        )


def test_triangulate_quads_takes_the_shorter_diagonal_and_breaks_ties_the_same_way():
    from zoo.data.mesh import QUAD_TIE, triangulate_quads

    quad = np.array([[0, 1, 2, 3]])
    # a-c shorter: (a, b, c), (c, d, a); b-d shorter: (a, b, d), (d, b, c).
    kite = np.array([[0, 0, 0], [2, -1, 0], [1, 0, 0], [2, 1, 0]], float)
    assert triangulate_quads(kite, quad).tolist() == [[0, 1, 2], [2, 3, 0]]
    wide = np.array([[-2, 0, 0], [0, -1, 0], [2, 0, 0], [0, 1, 0]], float)
    assert triangulate_quads(wide, quad).tolist() == [[0, 1, 3], [3, 1, 2]]
    # A square, exact or nudged either way by less than the tie tolerance (as another CPU's
    # rounding would), takes the fixed diagonal a-c.
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    for nudge in (0.0, QUAD_TIE / 10, -QUAD_TIE / 10):
        v = square.copy()
        v[2] *= 1 + nudge
        assert triangulate_quads(v, quad).tolist() == [[0, 1, 2], [2, 3, 0]]
    with pytest.raises(MeshError, match=r"quads must be an integer array \(F, 4\)"):
        triangulate_quads(square, np.array([[0, 1, 2]]))
