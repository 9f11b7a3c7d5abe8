"""The generated cloth dataset: reproducible, physically sane, cached by recipe."""

import json

import numpy as np
import pytest

import zoo
from zoo.data import cloth
from zoo.data.cloth import ClothConfig, cloth_dir, cloth_mesh, load_cloth, simulate_cloth
from zoo.data.mesh import MeshError

# A small cloth (100 vertices, 0.5 s) keeps the tests fast; the solver is the default one.
TINY = ClothConfig(grid=(10, 10), frames=13, substeps=10, train_sequences=2, test_sequences=3)


@pytest.fixture(scope="module")
def tiny():
    return simulate_cloth(TINY, "test", [0, 1, 2])


def test_topology_is_asymmetric_and_valid():
    topo, rest = cloth_mesh(ClothConfig())
    assert topo.num_vertices == 484 and rest.shape == (484, 3)
    np.testing.assert_allclose(rest.mean(axis=0), 0, atol=1e-12)
    assert np.all(rest[:, 2] == 0)
    # Diagonals in both directions: the mirror image of the triangulation is another one.
    row, col = np.divmod(topo.faces, 22)
    mirrored = np.sort(row * 22 + (21 - col), axis=1)
    assert {tuple(f) for f in np.sort(topo.faces, axis=1)} != {tuple(f) for f in mirrored}
    # Every triangle keeps its orientation: the jitter folds nothing over.
    e1, e2 = (
        rest[topo.faces[:, 1]] - rest[topo.faces[:, 0]],
        rest[topo.faces[:, 2]] - rest[topo.faces[:, 0]],
    )
    area = np.cross(e1, e2)[:, 2]
    assert (np.abs(area) > 0.2 * np.abs(area).mean()).all()


def test_same_seed_same_bytes_and_batch_independence(tiny):
    vertices, metas = tiny
    again, metas_again = simulate_cloth(TINY, "test", [0, 1, 2])
    assert vertices.tobytes() == again.tobytes() and metas == metas_again
    alone, _ = simulate_cloth(TINY, "test", [2])  # a sequence does not depend on its batch
    assert alone.tobytes() == vertices[2:].tobytes()
    other, _ = simulate_cloth(ClothConfig(**{**TINY.__dict__, "seed": 1}), "test", [0])
    assert not np.array_equal(other[0], vertices[0])
    train, _ = simulate_cloth(TINY, "train", [0])
    assert not np.array_equal(train[0], vertices[0])


def test_physics(tiny):
    vertices, metas = tiny
    assert vertices.shape == (3, TINY.frames, 100, 3) and vertices.dtype == np.float32
    assert np.isfinite(vertices).all()
    topo, rest = cloth_mesh(TINY)
    for s, meta in enumerate(metas):
        pins = meta["pinned"]
        assert len(set(pins)) == 2
        # pinned vertices never move, to the bit
        assert (vertices[s][:, pins] == vertices[s][:1, pins]).all()
        # frame 0 is the rest shape, rotated (edge lengths in mm)
        e = topo.edges
        rest_len = np.linalg.norm(rest[e[:, 1]] - rest[e[:, 0]], axis=1) * 1000
        first = np.linalg.norm(vertices[s, 0, e[:, 1]] - vertices[s, 0, e[:, 0]], axis=1)
        np.testing.assert_allclose(first, rest_len, rtol=1e-5)
        # stretch stays bounded over the whole sequence
        lengths = np.linalg.norm(vertices[s][:, e[:, 1]] - vertices[s][:, e[:, 0]], axis=-1)
        strain = np.abs(lengths / rest_len - 1)
        assert strain.mean() < 0.02 and np.quantile(strain, 0.99) < 0.15, strain.max()
        # the cloth falls: the free vertices end well below where they started
        free = np.setdiff1d(np.arange(100), pins)
        z = vertices[s][:, free, 2].mean(axis=1)
        assert z[-1] < z[0] - 100 and (np.diff(z[:4]) < 0).all()


def test_load_cloth_caches_by_recipe(tmp_path, monkeypatch):
    first = load_cloth("test", TINY, cache_dir=tmp_path)
    folder = cloth_dir("test", TINY, tmp_path)
    assert folder.name == f"cloth-{first.recipe_hash}" and (folder / "meshes.npz").is_file()
    assert first.fps == 25.0 and len(first.sequences) == 3 and first.split == "test"
    assert first.actions_present == ("fall",) and first.recipe["sequences"] == 3

    def no_generate(*args, **kwargs):
        raise AssertionError("regenerated although cached")

    monkeypatch.setattr(cloth, "generate_cloth", no_generate)
    again = load_cloth("test", TINY, cache_dir=tmp_path)
    assert again.content_hash() == first.content_hash()
    assert again.sequences[1].meta == first.sequences[1].meta
    monkeypatch.undo()

    # Another recipe: another folder, never the cached one.
    other = ClothConfig(**{**TINY.__dict__, "test_sequences": 2})
    assert cloth_dir("test", other, tmp_path) != folder
    two = load_cloth("test", other, cache_dir=tmp_path)
    assert len(two.sequences) == 2
    # ... and a sequence does not depend on how many were generated.
    assert np.array_equal(two.sequences[1].vertices, first.sequences[1].vertices)

    # A folder whose recorded recipe is not the one its name says: an error.
    meta = json.loads((folder / "dataset.json").read_text())
    meta["recipe"]["seed"] = 99
    (folder / "dataset.json").write_text(json.dumps(meta))
    with pytest.raises(MeshError, match="another recipe"):
        load_cloth("test", TINY, cache_dir=tmp_path)


def test_default_cache_location_follows_env(tmp_path, monkeypatch):
    monkeypatch.setenv("ZOO_CACHE_DIR", str(tmp_path))
    assert cloth_dir("test", TINY).parent == tmp_path / "datasets"


def test_bad_arguments_are_named():
    with pytest.raises(MeshError, match="unknown split 'dev'"):
        TINY.recipe("dev")
    with pytest.raises(MeshError, match="grid must be at least 2 x 2"):
        cloth_mesh(ClothConfig(grid=(1, 5)))
    with pytest.raises(MeshError, match="split 'val' has 0 sequences"):
        cloth.generate_cloth("val", TINY)


def test_cloth_benchmark_on_a_small_cloth(tmp_path):
    from zoo.models.repeat_last import RepeatLast

    small = ClothConfig(grid=(10, 10), substeps=5, test_sequences=2)  # 50 frames, like the default
    dataset = load_cloth("test", small, cache_dir=tmp_path)
    # MELV on the raw frames: this 100-vertex cloth has no room for the benchmark's k = 256
    result = zoo.evaluate(
        RepeatLast(25, 25, 100),
        "cloth",
        dataset=dataset,
        label="repeat_last",
        melv_frames="raw",
    )
    frame = result.frame[(result.frame.action == "average") & (result.frame.averaging == "frame")]
    value = {
        (m, metric): g.sort_values("frame").value.to_numpy()
        for (m, metric), g in frame.groupby(["model", "metric"])
    }
    assert set(value) == {
        ("repeat_last", "melv"),
        ("repeat_last", "rmse"),
        ("ground_truth", "melv"),
    }
    assert (value["repeat_last", "melv"] == 0).all()  # the last observed frame, unchanged
    assert (value["ground_truth", "melv"] > 0).all()
    assert value["repeat_last", "rmse"][0] < value["repeat_last", "rmse"][9]
    assert result.protocol["windows_per_action"] == {"fall": 2}  # one window per sequence
    assert result.protocol["recipe_hash"] == dataset.recipe_hash


@pytest.mark.slow
def test_default_cloth_benchmark_end_to_end(tmp_path, monkeypatch):
    """Builds the default test split (100 sequences) and evaluates repeat_last on it."""
    from zoo import create_model

    monkeypatch.setenv("ZOO_CACHE_DIR", str(tmp_path))
    model = create_model("repeat_last", benchmark="cloth")
    result = zoo.evaluate(model, "cloth", label="repeat_last")
    assert result.protocol["windows_per_action"] == {"fall": 100}
    assert result.protocol["num_vertices"] == 484
    assert (tmp_path / "datasets" / f"cloth-{result.protocol['recipe_hash']}").is_dir()


def test_only_the_pins_are_random_by_default(tiny):
    """As in the paper: the cloth starts flat and level; heading and tilt are options."""
    vertices, metas = tiny
    assert all(m["heading_deg"] == 0 and m["tilt_deg"] == 0 for m in metas)
    np.testing.assert_allclose(vertices[:, 0, :, 2], 0, atol=1e-3)  # flat and level at rest
    posed = ClothConfig(**{**TINY.__dict__, "max_tilt_deg": 30.0, "random_heading": True})
    posed_vertices, posed_metas = simulate_cloth(posed, "test", [0, 1, 2])
    assert [m["pinned"] for m in posed_metas] == [m["pinned"] for m in metas]  # same pins
    assert all(m["heading_deg"] != 0 and m["tilt_deg"] != 0 for m in posed_metas)
    assert np.abs(posed_vertices[:, 0, :, 2]).max() > 10  # tilted: not flat in z
    assert TINY.recipe("test")["random_heading"] is False
    assert cloth_dir("test", posed) != cloth_dir("test", TINY)


def test_parallel_generation_and_int16_storage(tmp_path):
    """Processes and batch sizes change nothing; int16 storage loads back what was generated,
    within 1/64 mm of the float32 simulation, in half the bytes."""
    compact = ClothConfig(**{**TINY.__dict__, "test_sequences": 5, "position_step_mm": 1 / 32})
    alone = cloth.generate_cloth("test", compact, batch=5, workers=1)
    spread = cloth.generate_cloth("test", compact, batch=2, workers=2)
    shared = cloth.generate_cloth("test", compact, workers=2)  # the default: 3 and 2 sequences
    assert all(
        np.array_equal(a.vertices, b.vertices) and np.array_equal(a.vertices, c.vertices)
        for a, b, c in zip(alone.sequences, spread.sequences, shared.sequences)
    )
    exact = cloth.generate_cloth("test", ClothConfig(**{**TINY.__dict__, "test_sequences": 5}))
    gap = max(
        np.abs(a.vertices - b.vertices).max() for a, b in zip(alone.sequences, exact.sequences)
    )
    assert 0 < gap <= 1 / 64 + 1e-4
    saved = load_cloth("test", compact, cache_dir=tmp_path, workers=2)
    loaded = load_cloth("test", compact, cache_dir=tmp_path)
    assert loaded.content_hash() == saved.content_hash() == alone.content_hash()
    plain = ClothConfig(**{**TINY.__dict__, "test_sequences": 5})
    load_cloth("test", plain, cache_dir=tmp_path)

    def stored_bytes(config):
        return (cloth_dir("test", config, tmp_path) / "meshes.npz").stat().st_size

    assert stored_bytes(compact) < 0.6 * stored_bytes(plain)
    with pytest.raises(MeshError, match="workers must be a positive integer"):
        cloth.generate_cloth("test", compact, workers=0)


def test_int16_storage_refuses_what_it_cannot_hold(tmp_path):
    from zoo.data.mesh import MeshDataset, MeshSequence, MeshTopology, quantise_vertices

    topology = MeshTopology(np.array([[0, 1, 2]]), 3, name="tri")
    wide = np.array([[[0, 0, 0], [5000, 0, 0], [0, 1, 0]]], np.float32)  # 5 m > 2 km / 1024
    off_grid = quantise_vertices(wide[:, :, :] / 10, 1 / 32) + 0.01
    for vertices, message in (
        (wide, "spans 5000 mm, more than int16 steps"),
        (off_grid, "not on the 0.03125 mm grid"),
    ):
        dataset = MeshDataset(
            "tri", "test", topology, [MeshSequence("s", "a", vertices, 25.0)], recipe={}
        )
        with pytest.raises(MeshError, match=message):
            dataset.save(tmp_path / "tri", step_mm=1 / 32)
        assert not (tmp_path / "tri" / "meshes.npz").exists()


def test_cloth_full_and_weights_from(monkeypatch):
    """cloth_full is the paper-sized cloth; cloth scores cloth_full's trained models."""
    from zoo.protocol.benchmark import get_benchmark

    full, small = get_benchmark("cloth_full"), get_benchmark("cloth")
    assert cloth.CLOTH_FULL.train_sequences == 16000 and cloth.CLOTH_FULL.test_sequences == 4000
    assert small.weights_from == "cloth_full" and full.weights_from is None
    # sequence i of a split is the same simulation in both, whatever their sizes
    assert {
        k: v
        for k, v in cloth.CLOTH_FULL.recipe("test").items()
        if k not in ("sequences", "position_step_mm")
    } == {
        k: v
        for k, v in ClothConfig().recipe("test").items()
        if k not in ("sequences", "position_step_mm")
    }
    monkeypatch.setenv("ZOO_WORKERS", "two")
    for loader in (cloth.cloth_full_dataset, cloth.cloth_dataset):
        with pytest.raises(MeshError, match="ZOO_WORKERS must be a positive integer, got 'two'"):
            loader(None, "test")


def test_weights_from_must_fit(tmp_path):
    import yaml

    from zoo.core.errors import BenchmarkError
    from zoo.protocol.benchmark import get_benchmark

    spec = yaml.safe_load(open(get_benchmark("cloth").source))
    for change, message in (
        ({"weights_from": "cloth"}, "must name another benchmark"),
        ({"weights_from": "nosuch"}, "field 'weights_from': unknown"),
        ({"output_frames": 20}, "output_frames 20 here, 25 there"),
    ):
        path = tmp_path / "b.yaml"
        path.write_text(yaml.safe_dump({**spec, **change}))
        with pytest.raises(BenchmarkError, match=message):
            get_benchmark(path)
