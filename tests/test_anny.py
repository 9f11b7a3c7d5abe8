"""CMU BVH motion on the Anny body (zoo.data.anny).

The tests that need the ``anny`` package share one low-resolution model (session fixture) and
use the shortest trials (09_03: 128 motion frames at 120 fps, 27 frames at 25 Hz). The low
model loads in seconds from the build the tests ship (tests/conftest.py); the full one is built
by anny on its first load on a machine (minutes) and cached there.
"""

import importlib.util
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from zoo.data import anny
from zoo.data.anny import regressor as anny_regressor
from zoo.data.bvh import CMU_BVH_JOINTS, read_bvh
from zoo.data.expmap import DataFormatError
from zoo.data.mesh import MeshDataset, MeshTopology
from zoo.paths import REPO_ROOT

CMU_BVH = REPO_ROOT.parent / "shared" / "data" / "cmu_bvh"
SHORT = "09_03"  # train split, 27 frames at 25 Hz
SHORT_TEST = "09_05"  # test split

needs_data = pytest.mark.skipif(not CMU_BVH.is_dir(), reason=f"CMU BVH data not found at {CMU_BVH}")
needs_anny = pytest.mark.skipif(
    importlib.util.find_spec("anny") is None,
    reason="the anny package is not installed (pip install anny==0.6.2); CI installs it",
)


def bvh_path(key):
    return CMU_BVH / "data" / f"0{key[:2]}" / f"{key}.bvh"


# ---- rotations and resampling (no anny needed) -------------------------------------------------


def test_rotation_between_is_the_smallest_rotation():
    rng = np.random.default_rng(1)
    for _ in range(20):
        a, b = rng.normal(size=3), rng.normal(size=3)
        r = anny.rotation_between(a, b)
        np.testing.assert_allclose(r @ (a / np.linalg.norm(a)), b / np.linalg.norm(b), atol=1e-12)
        axis = Rotation.from_matrix(r).as_rotvec()
        assert abs(axis @ a) < 1e-9 and abs(axis @ b) < 1e-9  # about a x b: smallest angle
    np.testing.assert_allclose(
        anny.rotation_between([1, 0, 0], [-1, 0, 0]) @ [1, 0, 0], [-1, 0, 0], atol=1e-12
    )
    np.testing.assert_allclose(anny.rotation_between([0, 2, 0], [0, 1, 0]), np.eye(3))


def test_remove_heading_keeps_the_tilt():
    rng = np.random.default_rng(2)
    for _ in range(20):
        heading = Rotation.from_rotvec([0, rng.uniform(-3, 3), 0])
        axis = rng.normal(size=3)
        axis[1] = 0
        tilt = Rotation.from_rotvec(axis / np.linalg.norm(axis) * rng.uniform(0, 1.2))
        q = (heading * tilt).as_matrix()
        np.testing.assert_allclose(anny.remove_heading(q), tilt.as_matrix(), atol=1e-9)
    # A pure heading leaves nothing; a rotation about a horizontal axis is kept as is.
    np.testing.assert_allclose(
        anny.remove_heading(Rotation.from_rotvec([0, 1, 0]).as_matrix()), np.eye(3), atol=1e-12
    )


def test_resampling_to_25_hz_is_exact_on_shared_instants_and_slerps_between():
    rng = np.random.default_rng(3)
    n = 241  # 2 s at 120 fps
    rots = Rotation.random(n * 2, random_state=4).as_matrix().reshape(n, 2, 3, 3)
    out = anny.resample_rotations(rots, 120.0)
    assert out.shape == (51, 2, 3, 3)  # k / 25 for k = 0..50
    # 25 Hz frame 5k is 120 fps frame 24k.
    np.testing.assert_allclose(out[::5], rots[::24], atol=1e-9)
    # 25 Hz frame 1 (t = 40 ms) lies 4.8 frames in: slerp 80 % of the way from frame 4 to 5.
    r4, r5 = Rotation.from_matrix(rots[4, 0]), Rotation.from_matrix(rots[5, 0])
    expected = r4 * Rotation.from_rotvec(0.8 * (r4.inv() * r5).as_rotvec())
    np.testing.assert_allclose(out[1, 0], expected.as_matrix(), atol=1e-9)
    assert len(anny.resample_times(129 - 1, 120.0)) == 27
    assert anny.snapped_fps(0.0083333) == 120.0 and anny.snapped_fps(0.01) == 100.0
    del rng


# ---- trials and split (data, no anny) ---------------------------------------------------------


@needs_data
def test_trials_split_and_selection_errors():
    trials = anny.list_trials(CMU_BVH)
    assert len(trials) == 98
    test = [t.key for t in trials if t.split == "test"]
    assert len(test) == 17 and all(int(k[3:]) % 5 == 0 for k in test)
    assert {t.description for t in trials if t.key in ("02_01", "09_03")} == {"walk", "run"}
    assert [t.key for t in anny.select_trials(CMU_BVH, "train", [SHORT])] == [SHORT]
    with pytest.raises(ValueError, match=r"'09_03' belongs to the train split, not test"):
        anny.select_trials(CMU_BVH, "test", [SHORT])
    with pytest.raises(ValueError, match=r"'04_01' is not a trial under"):
        anny.select_trials(CMU_BVH, "train", ["04_01"])


@needs_data
def test_a_bvh_with_an_unexpected_joint_is_named(tmp_path):
    text = bvh_path(SHORT).read_text().replace("JOINT LThumb", "JOINT LPinky", 1)
    (tmp_path / "odd.bvh").write_text(text)
    with pytest.raises(
        DataFormatError,
        match=r"odd\.bvh: unexpected joint 'LPinky'; expected "
        r"the joint set \{Hips, LHipJoint, .*RThumb\}",
    ):
        read_bvh(tmp_path / "odd.bvh", CMU_BVH_JOINTS)


# ---- on the Anny body -------------------------------------------------------------------------


@pytest.fixture(scope="session")
def low_model():
    if importlib.util.find_spec("anny") is None:
        pytest.skip("the anny package is not installed (pip install anny==0.6.2); CI installs it")
    return anny.shared_model("low")  # the one the zoo's own calls load, loaded once


@needs_anny
def test_the_shipped_low_body_is_what_anny_loads_without_building(tmp_path, monkeypatch):
    """The low body's build that the tests ship (conftest.ANNY_SHIPPED, put in anny's cache) is
    the file anny looks for: from a cache holding only it, the body loads and nothing is built.
    If another anny names or builds it otherwise, this fails: ship that anny's build instead."""
    from conftest import anny_cache_folder, seed_anny_cache

    paths = importlib.import_module("anny.paths")  # the package's, not zoo.data.anny
    assert anny_cache_folder() == paths.get_anny_cache_path()
    monkeypatch.setattr(paths, "_ANNY_CACHE_DIR", [paths.get_anny_cache_path()])

    def no_build(*args, **kwargs):
        raise AssertionError("anny built the body: the shipped build was not used")

    monkeypatch.setattr(importlib.import_module("anny.models"), "build_model_data", no_build)
    seed_anny_cache(tmp_path)
    model = anny.load_anny_model("low", anny_cache_dir=tmp_path)
    assert model.template_vertices.shape == (1229, 3)


@needs_anny
@pytest.mark.slow
def test_a_build_here_makes_the_shipped_low_body(tmp_path, monkeypatch):
    """What the shipped build stands for: anny's own build of the low body here, from an empty
    cache, has the shipped file's name and its tensors. The blend shapes and their projection
    come from an SVD, whose basis another CPU may sign or turn otherwise: they are compared as
    the products the body is computed from."""
    import torch
    from conftest import ANNY_SHIPPED
    from safetensors.torch import load_file

    paths = importlib.import_module("anny.paths")
    monkeypatch.setattr(paths, "_ANNY_CACHE_DIR", [paths.get_anny_cache_path()])
    anny.load_anny_model("low", anny_cache_dir=tmp_path)
    (shipped,) = ANNY_SHIPPED.rglob("*.safetensors")
    built = tmp_path / shipped.relative_to(ANNY_SHIPPED)
    assert built.is_file(), sorted(p.name for p in tmp_path.rglob("*"))  # anny's name for it
    here, there = load_file(built), load_file(shipped)
    assert here.keys() == there.keys()
    projection = "phenotype_blendshape_projection"
    fitted = ("blendshapes", "bone_heads_blendshapes", "bone_tails_blendshapes")
    for key in fitted:
        made = [t[projection] @ t[key].flatten(1) for t in (here, there)]
        torch.testing.assert_close(*made, rtol=0, atol=1e-9, msg=key)
    for key in here.keys() - {projection, *fitted}:
        torch.testing.assert_close(here[key], there[key], rtol=0, atol=1e-9, msg=key)


@pytest.fixture(scope="session")
def short_motion():
    if not CMU_BVH.is_dir():
        pytest.skip(f"CMU BVH data not found at {CMU_BVH}")
    bvh = read_bvh(bvh_path(SHORT), CMU_BVH_JOINTS)
    return bvh, anny.motion_rotations(bvh)


@pytest.fixture(scope="session")
def cache(tmp_path_factory):
    """One cache folder for the session: each dataset is built once."""
    return tmp_path_factory.mktemp("zoo-cache")


MI_BODY = {
    "gender": 0.9,
    "age": 0.85,
    "muscle": 0.2,
    "weight": 0.8,
    "height": 0.3,
    "proportions": 0.7,
}


@needs_anny
@pytest.mark.parametrize("phenotype", [None, MI_BODY], ids=["default", "mi"])
@pytest.mark.parametrize("root", anny.ROOT_MODES)
def test_skinned_bone_directions_match_the_bvh_forward_kinematics(
    low_model, short_motion, phenotype, root
):
    bvh, rots = short_motion
    frames = rots[[0, 9, 18, 26]]
    target = anny.retarget(low_model, bvh, phenotype)
    params = target.pose_parameters(frames, root)
    if root == "identity":
        np.testing.assert_array_equal(params[:, 0], np.eye(4)[None].repeat(4, 0))
    np.testing.assert_array_equal(params[..., :3, 3], 0)  # no translation anywhere
    out = anny.skin(low_model, params, phenotype, return_bone_ends=True)
    got = out["tails"] - out["heads"]
    expected = target.expected_directions(frames, root)
    angles = anny.angle_degrees(got[:, target.directed], expected[:, target.directed])
    assert target.directed.sum() == 17  # legs, feet, toes, back, neck, head, arms, forearms
    assert angles.max() < 0.01, f"max bone-direction error {angles.max():.4f} degrees"
    # The root (Hips) head sits at the origin: no global translation.
    np.testing.assert_allclose(out["heads"][:, 0], 0, atol=1e-3)
    # And the motion is not trivial: the legs swing by tens of degrees over the run.
    leg = low_model.bone_labels.index("LeftUpLeg")
    swing = anny.angle_degrees(got[:, None, leg], got[None, :, leg])
    assert swing.max() > 20, f"the thigh swings by {swing.max():.1f} degrees only"


@needs_anny
def test_identity_root_removes_heading_and_tilt(low_model, short_motion):
    bvh, rots = short_motion
    target = anny.retarget(low_model, bvh)
    turned = rots.copy()
    turned[:, 0] = Rotation.from_rotvec([0, 1.0, 0]).as_matrix() @ turned[:, 0]
    np.testing.assert_allclose(
        target.pose_parameters(turned, "no_heading"),
        target.pose_parameters(rots, "no_heading"),
        atol=1e-9,
    )
    tilted = rots.copy()
    tilted[:, 0] = Rotation.from_rotvec([0.3, 0, 0]).as_matrix() @ tilted[:, 0]
    np.testing.assert_array_equal(
        target.pose_parameters(tilted, "identity"), target.pose_parameters(rots, "identity")
    )
    assert not np.allclose(
        target.pose_parameters(tilted, "no_heading"), target.pose_parameters(rots, "no_heading")
    )


@needs_anny
def test_ground_truth_edge_length_changes_at_low_resolution(low_model, short_motion):
    # At full resolution the mean |edge change| vs the first frame is about 0.25 mm for 10 mm
    # edges (linear blend skinning). The low-resolution mesh has ~42 mm edges and, measured on
    # 09_03, 1.2 mm mean change (p99 18 mm, max 62 mm): the same ~3 % of an edge.
    bvh, rots = short_motion
    v = anny.skin(low_model, anny.retarget(low_model, bvh).pose_parameters(rots))["vertices"]
    edges = MeshTopology(anny.model_faces(low_model), v.shape[1]).edges
    lengths = np.linalg.norm(v[:, edges[:, 0]] - v[:, edges[:, 1]], axis=-1).astype(np.float64)
    change = np.abs(lengths[1:] - lengths[0])
    assert 38 < lengths[0].mean() < 46
    assert 0.6 < change.mean() < 2.0
    assert 10 < np.percentile(change, 99) < 30 and change.max() < 100


def test_built_meshes_do_not_depend_on_the_thread_count(low_model, tmp_path):
    import torch

    before = torch.get_num_threads()
    hashes = []
    try:
        for threads in (3, 1):
            torch.set_num_threads(threads)
            hashes.append(
                anny.build_cmu_anny(
                    CMU_BVH,
                    identities="one",
                    topology="low",
                    split="train",
                    trials=[SHORT],
                    progress=False,
                    cache_dir=tmp_path / f"threads{threads}",
                ).content_hash()
            )
            assert torch.get_num_threads() == threads  # the caller's setting is restored
    finally:
        torch.set_num_threads(before)
    assert hashes[0] == hashes[1]


@needs_anny
@needs_data
def test_meshes_skinned_in_float64_do_not_depend_on_the_cpus_kernels(tmp_path):
    """The short trial skinned here, under this CPU's own kernels, and in a process under the
    generic kernel set (torch's and MKL's; benchmarks/check/skinning_kernels.py, which measures
    more sets): float32 skinning gets other last bits, float64 skinning rounded once the same
    bytes."""
    import torch

    script = REPO_ROOT / "benchmarks" / "check" / "skinning_kernels.py"
    spec = importlib.util.spec_from_file_location("skinning_kernels", script)
    kernels = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(kernels)
    here = kernels.skinned("low", [bvh_path(SHORT)])
    ran = kernels.skin_under("generic", "low", [bvh_path(SHORT)], tmp_path / "generic.npz")
    generic = np.load(tmp_path / "generic.npz")
    assert here["float64"].dtype == np.float32 and here["float64"].shape == (27, 1229, 3)
    np.testing.assert_array_equal(here["float64"], generic["float64"])
    if ran == torch.backends.cpu.get_cpu_capability():
        pytest.skip(f"torch runs its {ran} kernels here and under the generic set: nothing to tell")
    assert (here["float32"] != generic["float32"]).any()  # can fail: float32 follows the kernels


def build_low(cache, identities="one", seed=0, split="train", trials=(SHORT,)):
    """A low-resolution CMU-on-Anny dataset of a few trials, in the session's cache."""
    return anny.build_cmu_anny(
        CMU_BVH,
        identities=identities,
        topology="low",
        split=split,
        trials=list(trials),
        seed=seed,
        cache_dir=cache,
        progress=False,
    )


@needs_anny
@needs_data
def test_build_one_identity_low(low_model, cache):
    ds = build_low(cache)
    assert ds.name == "cmu_anny-oi-low-train" and ds.split == "train" and ds.fps == 25.0
    (seq,) = ds.sequences
    assert seq.vertices.shape == (27, 1229, 3) and seq.vertices.dtype == np.float32
    assert seq.action == "run" and seq.identity == "default"
    assert seq.meta["source_frames"] == 128 and seq.meta["source_fps"] == 120.0
    assert seq.meta["phenotype"] == anny.DEFAULT_PHENOTYPE
    assert seq.meta["skinning"] == anny.SKINNING == "float64, rounded once to float32"
    # Millimetres, Z up, about 1.6 m tall (the default body), root at the origin.
    height = np.ptp(seq.vertices[0, :, 2])
    assert 1400 < height < 1800
    assert ds.recipe["trials"][0]["trial"] == SHORT and len(ds.recipe["trials"][0]["sha256"]) == 64
    assert ds.recipe["anny_version"] == anny.anny_version() and ds.recipe["fps"] == 25.0
    # The joint regressor: 31 rows in BVH order summing to 1, close to the rig's bone heads.
    reg = ds.joint_regressor
    assert reg.shape == (31, 1229) and ds.joint_names == list(CMU_BVH_JOINTS)
    np.testing.assert_allclose(np.asarray(reg.sum(axis=1)).ravel(), 1.0, atol=1e-9)
    assert (reg.data > 0).all() and reg.nnz < 31 * 40
    folder = anny.dataset_folder(ds, cache)
    (rig,) = anny.load_rig_joints(folder)
    err = anny.regressor_error(reg, seq.vertices, rig)
    assert err.mean() < 10, f"regressed joints {err.mean():.1f} mm from the rig's bone heads"
    # Cached on disk under its recipe hash; a second call loads the same data.
    assert folder.name == f"{ds.name}-{ds.recipe_hash}"
    again = build_low(cache)
    assert again.content_hash() == ds.content_hash() and again.recipe_hash == ds.recipe_hash
    # The seed draws MI bodies only: an OI build of another seed is the same dataset.
    assert build_low(cache, seed=7).recipe_hash == ds.recipe_hash
    assert MeshDataset.load(folder).topology.hash == ds.topology.hash
    # The regressor is the shipped one, also for a dataset cached with another machine's fit.
    recipe, _ = anny.regressor_recipe(CMU_BVH, "low")
    shipped, _ = anny.load_regressor(anny.shipped_regressor_path("low", recipe))
    assert (abs(ds.joint_regressor - shipped) > 0).nnz == 0
    other = MeshDataset.load(folder)
    other.joint_regressor = other.joint_regressor.multiply(0.5).tocsr()
    other.save(folder)
    reloaded = build_low(cache)
    assert (abs(reloaded.joint_regressor - shipped) > 0).nnz == 0
    reloaded.save(folder)  # the session's cache as it was
    # A cache skinned otherwise (in float32, before SKINNING) is built again, not loaded.
    older = MeshDataset.load(folder)
    older.sequences[0].meta.pop("skinning")
    older.sequences[0].vertices[0, 0, 0] += 1.0
    older.save(folder)
    rebuilt = build_low(cache)
    assert rebuilt.content_hash() == ds.content_hash()
    assert MeshDataset.load(folder).sequences[0].meta["skinning"] == anny.SKINNING


@needs_anny
@needs_data
def test_many_identities_share_the_triangulation_differ_in_shape_and_are_seeded(low_model, cache):
    def build(seed, split="train", trials=(SHORT, "02_03")):
        return build_low(cache, "many", seed, split, trials)

    ds = build(0)
    oi = build_low(cache)
    assert ds.topology.hash == oi.topology.hash  # one triangulation for every identity
    a, b = ds.sequences
    assert a.identity != b.identity and a.meta["phenotype"] != b.meta["phenotype"]
    assert a.meta["phenotype"] == anny.mi_phenotype(0, SHORT)
    for key, (lo, hi) in anny.MI_PHENOTYPE_RANGES.items():
        assert lo <= a.meta["phenotype"][key] <= hi
    # Different bodies: same motion frame, different shapes (edge lengths differ).
    edges = ds.topology.edges

    def lengths(v):
        return np.linalg.norm(v[:, edges[:, 0]] - v[:, edges[:, 1]], axis=-1)

    diff = np.abs(lengths(a.vertices[:1]) - lengths(oi.sequences[0].vertices[:1]))
    assert diff.mean() > 0.5  # mm
    assert a.vertices.shape[0] == oi.sequences[0].vertices.shape[0] == 27
    # Reproducible: rebuilt from scratch with the same seed it is identical; another seed is not.
    shutil.rmtree(anny.dataset_folder(ds, cache))
    assert build(0).content_hash() == ds.content_hash()
    other = build(1)
    assert other.recipe_hash != ds.recipe_hash and other.content_hash() != ds.content_hash()
    # An identity depends on the seed and its trial only, not on the other trials built.
    alone = build(0, trials=(SHORT,))
    np.testing.assert_array_equal(alone.sequences[0].vertices, a.vertices)
    test = build(0, split="test", trials=(SHORT_TEST,))
    assert test.split == "test" and test.name == "cmu_anny-mi-low-test"


@needs_anny
@needs_data
def test_builder_argument_errors(cache):
    with pytest.raises(ValueError, match="identities must be one of"):
        anny.build_cmu_anny(
            CMU_BVH, identities="some", topology="low", split="train", cache_dir=cache
        )
    with pytest.raises(ValueError, match="topology must be one of"):
        anny.build_cmu_anny(
            CMU_BVH, identities="one", topology="mid", split="train", cache_dir=cache
        )
    with pytest.raises(ValueError, match="split must be one of"):
        anny.build_cmu_anny(CMU_BVH, identities="one", topology="low", split="val", cache_dir=cache)
    with pytest.raises(ValueError, match="root must be one of"):
        anny.build_cmu_anny(
            CMU_BVH, identities="one", topology="low", split="train", root="world", cache_dir=cache
        )


@needs_anny
@needs_data
@pytest.mark.slow
def test_full_resolution_directions_and_edge_lengths(short_motion):
    # Sanity figures at 13,718 vertices, measured on 09_03: mean edge 9.96 mm,
    # mean |edge change| 0.22 mm, p99 4.2 mm, max 30 mm.
    model = anny.load_anny_model("full")
    bvh, rots = short_motion
    target = anny.retarget(model, bvh)
    out = anny.skin(model, target.pose_parameters(rots), return_bone_ends=True)
    angles = anny.angle_degrees(
        (out["tails"] - out["heads"])[:, target.directed],
        target.expected_directions(rots)[:, target.directed],
    )
    assert angles.max() < 0.01
    v = out["vertices"]
    assert v.shape == (27, 13718, 3)
    topology = MeshTopology(anny.model_faces(model), v.shape[1])
    # The same faces on every CPU (the zoo splits anny's quads, ties along a fixed diagonal):
    # this hash is in every full-resolution protocol id.
    assert topology.hash == "7f172bf4f4c3b63ab89785c7169e4ecea18a640758fd85a31597c4dd2ac185da"
    edges = topology.edges
    lengths = np.linalg.norm(v[:, edges[:, 0]] - v[:, edges[:, 1]], axis=-1).astype(np.float64)
    change = np.abs(lengths[1:] - lengths[0])
    assert 9 < lengths[0].mean() < 11
    assert 0.1 < change.mean() < 0.4 and 2 < np.percentile(change, 99) < 8


# ---- the shipped joint regressors ----------------------------------------------------------------


@needs_anny
@needs_data
@pytest.mark.parametrize("topology", ["low", pytest.param("full", marks=pytest.mark.slow)])
def test_the_shipped_regressor_fits_the_frames_skinned_here_as_recorded(
    low_model, topology, fit_frames_once
):
    """What holds on every CPU: the shipped file passes its checksum (load_regressor) and
    misses the bone heads of the fit frames skinned here by what its record says. A fit here
    may land on other weights (the full body's fit is ill-conditioned), which is why it ships."""
    report = anny.check_joint_regressor(
        CMU_BVH, topology, model=low_model if topology == "low" else None
    )
    assert report["fits_here"], report
    for key, value in report["shipped_here"].items():
        assert abs(value - report["stats"][key][1]) <= anny.REGRESSOR_TOLERANCE_MM + 5e-4
    assert report["stats"]["fit_frames"] == (1280.0, 1280.0)


_FIT_FRAMES: dict[tuple, tuple] = {}


@pytest.fixture
def fit_frames_once(monkeypatch):
    """The regressor's fit frames skinned once per process, for the tests that fit, ship and
    check a regressor: what they test is the fit and the files, not the skinning (tested
    above), which takes each of them seconds."""
    skinned = anny_regressor.regressor_fit_frames

    def kept(model, bvh_files, **settings):
        settings = {"seed": 0, **settings}  # the default seed, given or not: one key
        key = (id(model), tuple(map(str, bvh_files)), tuple(sorted(settings.items())))
        if key not in _FIT_FRAMES:
            _FIT_FRAMES[key] = (model, skinned(model, bvh_files, **settings))
        return _FIT_FRAMES[key][1]  # the model kept beside its frames: its id stays its own

    monkeypatch.setattr(anny_regressor, "regressor_fit_frames", kept)


def forbid_refitting(monkeypatch) -> None:
    """Make any fit of a joint regressor fail the test: a shipped one must only be loaded."""

    def no_fit(*args, **kwargs):
        raise AssertionError("a shipped regressor was fitted again")

    monkeypatch.setattr(anny_regressor, "fit_joint_regressor", no_fit)


@needs_data
def test_the_regressor_is_loaded_from_the_shipped_file_not_fitted(tmp_path, monkeypatch):
    pytest.importorskip("anny")  # its version is part of the regressor's recipe

    forbid_refitting(monkeypatch)
    regressor = anny.joint_regressor(CMU_BVH, "low", cache_dir=tmp_path)
    assert regressor.source == str(
        anny.shipped_regressor_path("low", anny.regressor_recipe(CMU_BVH, "low")[0])
    )
    assert regressor.matrix.shape == (31, 1229) and regressor.recipe["fit_frames"] == 1280.0
    assert not (tmp_path / "anny").exists()  # nothing fitted, nothing cached


@needs_anny
@needs_data
def test_a_recipe_with_no_shipped_regressor_is_fitted_here_and_says_so(
    low_model, tmp_path, monkeypatch, capsys, fit_frames_once
):
    monkeypatch.setattr(anny_regressor, "SHIPPED_REGRESSORS", tmp_path / "none")
    fitted = anny.joint_regressor(CMU_BVH, "low", cache_dir=tmp_path, model=low_model)
    assert "fitting one here" in capsys.readouterr().err
    assert Path(fitted.source).parent == tmp_path / "anny"

    def no_fit(*args, **kwargs):
        raise AssertionError("a cached regressor was fitted again")

    monkeypatch.setattr(anny_regressor, "fit_joint_regressor", no_fit)
    again = anny.joint_regressor(CMU_BVH, "low", cache_dir=tmp_path)  # from the cache
    assert "using the one fitted here" in capsys.readouterr().err
    assert again.source == fitted.source and again.recipe == fitted.recipe
    assert (abs(again.matrix - fitted.matrix) > 0).nnz == 0


def test_a_damaged_regressor_file_is_named(tmp_path):
    import scipy.sparse as sp

    matrix = sp.csr_matrix(np.array([[0.25, 0.75, 0.0], [0.0, 0.0, 1.0]]))
    path = anny.save_regressor(tmp_path / "r.npz", matrix, {k: 1.0 for k in anny.REGRESSOR_STATS})
    loaded, stats = anny.load_regressor(path)
    assert (abs(loaded - matrix) > 0).nnz == 0 and stats["fit_frames"] == 1.0
    with np.load(path) as z:
        fields = dict(z)
    fields["data"] = fields["data"] + 1e-9
    np.savez(tmp_path / "edited.npz", **fields)
    with pytest.raises(DataFormatError, match="edited.npz: its weights do not match"):
        anny.load_regressor(tmp_path / "edited.npz")
    (tmp_path / "text.npz").write_text("not a regressor")
    with pytest.raises(DataFormatError, match="text.npz: not a joint regressor file"):
        anny.load_regressor(tmp_path / "text.npz")
    (tmp_path / "cut.npz").write_bytes(path.read_bytes()[:2000])
    with pytest.raises(DataFormatError, match="cut.npz: not a joint regressor file"):
        anny.load_regressor(tmp_path / "cut.npz")
    del fields["checksum"]
    np.savez(tmp_path / "old.npz", **fields)  # a cache file from before checksums
    with pytest.raises(DataFormatError, match="old.npz: no checksum field"):
        anny.load_regressor(tmp_path / "old.npz")
    anny.load_regressor(tmp_path / "old.npz", checksum_required=False)


@needs_anny
@needs_data
def test_zoo_data_regressor_ships_a_fit_and_refuses_to_overwrite(
    low_model, tmp_path, monkeypatch, fit_frames_once
):
    from zoo.cli import main

    monkeypatch.setattr(anny_regressor, "SHIPPED_REGRESSORS", tmp_path / "regressors")
    args = ["data", "regressor", "cmu_anny_oi_low", "--data-root", str(CMU_BVH), "--ship"]
    assert main(args) == 0
    (written,) = (tmp_path / "regressors").iterdir()
    recipe, _ = anny.regressor_recipe(CMU_BVH, "low")
    assert written == anny.shipped_regressor_path("low", recipe)
    shipped, shipped_stats = anny.load_regressor(
        REPO_ROOT / "benchmarks" / "regressors" / written.name
    )
    fitted, stats = anny.load_regressor(written)  # its checksum holds
    assert fitted.shape == shipped.shape
    # a fit on another CPU may differ in its last bits, not in how well it fits
    for key in ("fit_mean_mm", "fit_p99_mm"):
        assert abs(stats[key] - shipped_stats[key]) <= anny.REGRESSOR_TOLERANCE_MM
    before = written.read_bytes()
    assert main(args) == 2  # shipped already: refused, nothing overwritten
    assert written.read_bytes() == before
    assert main(args[:-1]) == 0  # the shipped regressor fits the frames skinned here


@needs_data
def test_shipping_over_a_shipped_regressor_is_refused_before_any_fit(monkeypatch, capsys):
    pytest.importorskip("anny")  # its version is part of the regressor's recipe
    from zoo.cli import main

    forbid_refitting(monkeypatch)
    path = anny.shipped_regressor_path("low", anny.regressor_recipe(CMU_BVH, "low")[0])
    before = path.read_bytes()
    with pytest.raises(anny.RegressorShippedError, match="is shipped already"):
        anny.ship_joint_regressor(CMU_BVH, "low")
    args = ["data", "regressor", "cmu_anny_oi_low", "--data-root", str(CMU_BVH), "--ship"]
    assert main(args) == 2
    assert capsys.readouterr().err == (
        f"zoo data: error: {path} is shipped already (committed MPJPE rows depend on it); "
        "delete it deliberately to ship another\n"
    )
    assert path.read_bytes() == before
