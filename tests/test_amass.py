"""AMASS on SMPL-H (zoo.data.amass), on small synthetic files in the exact key layout.

No SMPL-H or AMASS data is used or committed: every file here is written by the test.
"""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from zoo.data import amass
from zoo.data.expmap import DataFormatError
from zoo.data.mesh import MeshDataset
from zoo.data.skeleton import rodrigues

ROOT_PARENT = np.uint32(4294967295)  # how SMPL files mark the root's parent


def strip_faces(num_vertices):
    """A triangle strip over vertices 0..V-1 (every vertex in a face, manifold)."""
    return np.array(
        [[i, i + 1, i + 2] if i % 2 == 0 else [i + 1, i, i + 2] for i in range(num_vertices - 2)],
        dtype=np.int32,
    )


def model_arrays(num_joints=24, num_vertices=30, num_betas=4, seed=0):
    """SMPL-H-layout arrays of a random small body: a chain-like tree, random weights."""
    rng = np.random.default_rng(seed)
    parents = [0] + [int(rng.integers(0, j)) for j in range(1, num_joints)]
    weights = rng.dirichlet(np.ones(3), size=num_vertices)
    dense = np.zeros((num_vertices, num_joints))
    for v in range(num_vertices):
        dense[v, rng.choice(num_joints, 3, replace=False)] = weights[v]
    regressor = rng.random((num_joints, num_vertices))
    return {
        "v_template": rng.normal(size=(num_vertices, 3)),
        "shapedirs": rng.normal(scale=0.01, size=(num_vertices, 3, num_betas)),
        "posedirs": rng.normal(scale=0.001, size=(num_vertices, 3, 9 * (num_joints - 1))),
        "J_regressor": regressor / regressor.sum(axis=1, keepdims=True),
        "weights": dense,
        "kintree_table": np.array(
            [[ROOT_PARENT] + parents[1:], list(range(num_joints))], dtype=np.uint32
        ),
        "f": strip_faces(num_vertices),
    }


def write_npz(path, arrays):
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **arrays)
    return path


def motion_arrays(frames=12, num_joints=24, fps=120.0, num_betas=16, seed=1, gender="female"):
    rng = np.random.default_rng(seed)
    return {
        "poses": rng.normal(scale=0.3, size=(frames, 3 * num_joints)),
        "betas": rng.normal(size=num_betas),
        "trans": rng.normal(size=(frames, 3)),
        "gender": np.array(gender),
        "mocap_framerate": np.array(fps),
        "dmpls": np.zeros((frames, 8)),
    }  # AMASS files carry extra keys; they are ignored


# ---- the body model ---------------------------------------------------------------------------


def test_rodrigues_matches_scipy_including_zero():
    vecs = np.random.default_rng(0).normal(size=(50, 3))
    vecs[0] = 0
    vecs[1] = [1e-7, 0, 0]
    got = rodrigues(torch.as_tensor(vecs), exact=True).numpy()
    np.testing.assert_allclose(got, Rotation.from_rotvec(vecs).as_matrix(), atol=1e-12)


def test_skinning_of_a_known_pose_by_hand(tmp_path):
    # Three joints in a chain 0 -> 1 -> 2; four vertices bound to 0, 1, 2 and half 0 / half 1.
    v_template = np.array([[0, 0, 0], [2, 0, 0], [3, 1, 0], [1, 1, 0]], dtype=float)
    shapedirs = np.zeros((4, 3, 1))
    shapedirs[:, 0, 0] = 1.0  # beta 0 moves everything along +x
    posedirs = np.zeros((4, 3, 18))
    posedirs[1, 1, 0] = 0.5  # vertex 1's y follows (R_1 - I)[0, 0]
    regressor = np.array([[1, 0, 0, 0], [0, 0.5, 0, 0.5], [0, 0, 1, 0]], dtype=float)
    weights = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0]], dtype=float)
    arrays = {
        "v_template": v_template,
        "shapedirs": shapedirs,
        "posedirs": posedirs,
        "J_regressor": regressor,
        "weights": weights,
        "kintree_table": np.array([[ROOT_PARENT, 0, 1], [0, 1, 2]], dtype=np.uint32),
        "f": np.array([[0, 1, 3], [1, 2, 3]], dtype=np.int32),
    }
    model = amass.load_smplh(write_npz(tmp_path / "model.npz", arrays))
    assert model.parents == (-1, 0, 1) and model.num_betas == 1
    pose = np.zeros(9)
    pose[3:6] = [0, 0, np.pi / 2]  # joint 1: 90 degrees about z
    verts, joints = model.forward(torch.as_tensor(pose[None]), torch.tensor([0.5]))
    verts, joints = verts[0].numpy(), joints[0].numpy()
    shaped = v_template + [0.5, 0, 0]
    j1 = 0.5 * (shaped[1] + shaped[3])  # (2, 0.5, 0)
    rz = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=float)

    def about_j1(p):
        return rz @ (p - j1) + j1

    # Pose blend shape: (R_1 - I)[0, 0] = -1, so vertex 1 moves by -0.5 in y before skinning.
    expected = np.array(
        [
            shaped[0],
            about_j1(shaped[1] + [0, -0.5, 0]),
            about_j1(shaped[2]),
            0.5 * shaped[3] + 0.5 * about_j1(shaped[3]),
        ]
    )
    np.testing.assert_allclose(verts, expected, atol=1e-12)
    np.testing.assert_allclose(joints, [shaped[0], j1, about_j1(shaped[2])], atol=1e-12)


def test_batched_forward_equals_one_frame_at_a_time(tmp_path):
    model = amass.load_smplh(write_npz(tmp_path / "m.npz", model_arrays()))
    poses = torch.as_tensor(np.random.default_rng(2).normal(scale=0.4, size=(5, 72)))
    betas = torch.tensor([0.3, -1.0])
    batch, _ = model.forward(poses, betas)
    for t in range(5):
        single, _ = model.forward(poses[t : t + 1], betas)
        np.testing.assert_allclose(batch[t].numpy(), single[0].numpy(), atol=1e-12)
    rest, joints = model.forward(torch.zeros(1, 72), torch.zeros(0))
    np.testing.assert_allclose(rest[0].numpy(), model.v_template.numpy(), atol=1e-12)


@pytest.mark.parametrize("key", amass.MODEL_KEYS)
def test_model_file_missing_key_is_named(tmp_path, key):
    arrays = model_arrays()
    del arrays[key]
    path = write_npz(tmp_path / "smplh.npz", arrays)
    with pytest.raises(DataFormatError, match=rf"smplh\.npz: SMPL-H model has no key '{key}'"):
        amass.load_smplh(path)


@pytest.mark.parametrize(
    "key, bad, message",
    [
        (
            "posedirs",
            np.zeros((30, 3, 10)),
            r"'posedirs' has shape \(30, 3, 10\), expected "
            r"\(30, 3, 207\)",
        ),
        (
            "J_regressor",
            np.zeros((24, 29)),
            r"'J_regressor' has shape \(24, 29\), expected "
            r"\(24, 30\)",
        ),
        ("weights", np.full((30, 24), 0.5), r"skinning weights of vertex 0 sum to 12"),
        ("f", np.array([[0, 1, 99]]), r"'f' must hold vertex indices in \[0, 30\)"),
        (
            "kintree_table",
            np.array([[ROOT_PARENT] + [5] * 23, list(range(24))], dtype=np.uint32),
            r"kintree_table gives joint 1 the parent 5",
        ),
    ],
)
def test_model_file_wrong_shapes_are_named(tmp_path, key, bad, message):
    arrays = model_arrays()
    arrays[key] = bad
    with pytest.raises(DataFormatError, match=r"smplh\.npz: .*" + message):
        amass.load_smplh(write_npz(tmp_path / "smplh.npz", arrays))


# ---- AMASS files and the frame-rate policy --------------------------------------------------


@pytest.mark.parametrize(
    "fps, stride, effective",
    [
        (120, 4, 30),
        (60, 2, 30),
        (100, 4, 25),
        (50, 2, 25),
        (30, 1, 30),
        (59.94, 2, 29.97),
        (24, 1, 24),
    ],
)
def test_frame_stride_policy(fps, stride, effective):
    assert amass.frame_stride(fps) == stride
    assert fps / stride == pytest.approx(effective)


@pytest.mark.parametrize("key", amass.AMASS_KEYS)
def test_amass_missing_key_is_named(tmp_path, key):
    arrays = motion_arrays()
    del arrays[key]
    path = write_npz(tmp_path / "seq_poses.npz", arrays)
    with pytest.raises(DataFormatError, match=rf"seq_poses\.npz: AMASS file has no key '{key}'"):
        amass.read_amass(path)


@pytest.mark.parametrize(
    "key, bad, message",
    [
        ("poses", np.zeros((12, 70)), r"'poses' has shape \(12, 70\), expected \(\*, 72\)"),
        ("trans", np.zeros((11, 3)), r"'trans' has shape \(11, 3\), expected \(12, 3\)"),
        ("betas", np.zeros((2, 16)), r"'betas' has shape \(2, 16\), expected \(\*\)"),
        ("mocap_framerate", np.array(-5.0), r"'mocap_framerate' must be positive"),
        ("gender", np.array(3), r"'gender' must be a string"),
    ],
)
def test_amass_wrong_shapes_are_named(tmp_path, key, bad, message):
    arrays = motion_arrays()
    arrays[key] = bad
    with pytest.raises(DataFormatError, match=r"seq_poses\.npz: key " + message):
        amass.read_amass(write_npz(tmp_path / "seq_poses.npz", arrays), num_joints=24)


def test_spectrhums_recipe_no_root_orientation_no_translation_and_stride(tmp_path):
    model = amass.load_smplh(write_npz(tmp_path / "m.npz", model_arrays()))
    motion = amass.read_amass(write_npz(tmp_path / "a_poses.npz", motion_arrays(frames=13)))
    assert motion.gender == "female" and motion.fps == 120.0
    verts, stride = amass.amass_vertices(model, motion)
    assert stride == 4 and verts.shape == (4, 30, 3) and verts.dtype == np.float32  # 0,4,8,12
    # Millimetres, frames 0, 4, 8, 12, root orientation zeroed, betas cut to the model's 4.
    poses = motion.poses[::4].copy()
    poses[:, :3] = 0
    expected, _ = model.forward(torch.as_tensor(poses), torch.as_tensor(motion.betas[:4]))
    np.testing.assert_allclose(verts, expected.numpy() * 1000, rtol=1e-6, atol=1e-3)
    # Another root orientation or translation changes nothing.
    other = motion_arrays(frames=13)
    other["poses"][:, :3] += 1.0
    other["trans"] += 5.0
    again, _ = amass.amass_vertices(model, amass.read_amass(write_npz(tmp_path / "b.npz", other)))
    np.testing.assert_array_equal(again, verts)
    wrong = amass.read_amass(write_npz(tmp_path / "c.npz", motion_arrays(num_joints=52)))
    with pytest.raises(
        DataFormatError,
        match=r"c\.npz: key 'poses' has 156 columns; the model "
        r"m\.npz has 24 joints \(72 columns\)",
    ):
        amass.amass_vertices(model, wrong)


def test_build_amass_dataset(tmp_path):
    root = tmp_path / "amass"
    write_npz(root / "BMLrub" / "s1" / "walk_poses.npz", motion_arrays(frames=20, fps=120))
    write_npz(root / "BMLrub" / "s1" / "run_poses.npz", motion_arrays(frames=9, fps=50, seed=3))
    write_npz(
        root / "BMLrub" / "s1" / "shape.npz", {"betas": np.zeros(16), "gender": np.array("female")}
    )
    female = write_npz(tmp_path / "female.npz", model_arrays())
    male = write_npz(tmp_path / "male.npz", model_arrays(seed=5))
    ds = amass.build_amass(
        root,
        {"female": female, "male": male},
        split="test",
        cache_dir=tmp_path / "cache",
        progress=False,
    )
    assert ds.name == "amass-test" and [s.name for s in ds.sequences] == [
        "BMLrub/s1/run_poses.npz",
        "BMLrub/s1/walk_poses.npz",
    ]
    run, walk = ds.sequences
    assert walk.vertices.shape == (5, 30, 3) and walk.fps == 30.0  # 20 frames, stride 4
    assert run.vertices.shape == (5, 30, 3) and run.fps == 25.0  # 9 frames, stride 2
    assert walk.meta["stride"] == 4 and walk.meta["effective_fps"] == 30.0
    assert walk.meta["source_fps"] == 120.0 and walk.action == "BMLrub"
    assert walk.identity.startswith("female-") and walk.identity != run.identity
    assert ds.joint_regressor.shape == (22, 30) and len(ds.joint_names) == 22
    assert ds.recipe["regressor"]["model"] == "female"  # no neutral: first gender in order
    folder = tmp_path / "cache" / "datasets" / f"amass-test-{ds.recipe_hash}"
    back = MeshDataset.load(folder)
    assert back.content_hash() == ds.content_hash()
    # A gender with no model is named.
    write_npz(root / "BMLrub" / "s2" / "jump_poses.npz", motion_arrays(gender="male"))
    with pytest.raises(DataFormatError, match=r"jump_poses\.npz: gender 'male' has no model"):
        amass.build_amass(
            root, {"female": female}, split="test", cache_dir=tmp_path / "c2", progress=False
        )
    # A model with fewer than the 22 body joints cannot give the SpecTrHuMS regressor.
    small = write_npz(tmp_path / "small.npz", model_arrays(num_joints=5))
    with pytest.raises(DataFormatError, match=r"small\.npz: 5 joints, fewer than the 22"):
        amass.build_amass(root, small, split="test", cache_dir=tmp_path / "c3", progress=False)
