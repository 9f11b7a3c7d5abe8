"""Training a mesh model through the engine; its checkpoint carries the basis hash."""

import json
import shutil
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import use_toy_loader
from tiny_models import MESH_REGISTRY

import zoo
from zoo.core.io import sha256_file
from zoo.data.mesh import MeshDataset, MeshSequence, MeshTopology
from zoo.evaluation.results import read_table
from zoo.hub.checkpoints import CheckpointError, load_checkpoint, read_checkpoint
from zoo.models.registry import Registry
from zoo.protocol import benchmark as benchmark_module
from zoo.train.loop import train
from zoo.train.options import RunOptions

HERE = Path(__file__).resolve().parent


def grid(n):
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = (
        idx[:-1, :-1].ravel(),
        idx[:-1, 1:].ravel(),
        idx[1:, :-1].ravel(),
        idx[1:, 1:].ravel(),
    )
    return MeshTopology(np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]), n * n)


def waving(topology, split, count=8, frames=12):
    rng = np.random.default_rng(0 if split == "train" else 1)
    n = int(round(np.sqrt(topology.num_vertices)))
    xy = np.stack(np.meshgrid(np.arange(n), np.arange(n)), -1).reshape(-1, 2) * 10.0
    seqs = []
    for i in range(count):
        speed = rng.uniform(0.5, 2.0)
        t = np.arange(frames)[:, None]
        z = speed * t * np.sin(xy[:, 0] / 30.0)[None]  # a smooth mode moving at constant speed
        v = np.concatenate([np.broadcast_to(xy, (frames, len(xy), 2)), z[..., None]], -1)
        seqs.append(MeshSequence(f"{split}{i}", "wave", v.astype(np.float32), 25.0))
    return MeshDataset(f"toy-{split}", split, topology, seqs, recipe={"split": split})


@pytest.fixture
def toy_mesh(tmp_path, monkeypatch):
    sizes = {"n": 4}
    use_toy_loader(monkeypatch, lambda root, split: waving(grid(sizes["n"]), split))
    monkeypatch.setenv("ZOO_CACHE_DIR", str(tmp_path / "cache"))
    bench = tmp_path / "toy.yaml"
    bench.write_text(
        textwrap.dedent("""\
        name: toy
        representation: mesh
        dataset: toy_mesh
        loader: toy.py:waving
        split: test
        input_frames: 4
        output_frames: 4
        sampler: all
        spectral_k: 6
        """)
    )
    (tmp_path / "registry.yaml").write_text(MESH_REGISTRY)
    shutil.copy(HERE / "tiny_models.py", tmp_path / "tiny_models.py")
    registry = Registry.from_files(HERE.parent / "registry.yaml", tmp_path / "registry.yaml")
    return bench, registry, sizes


def test_mesh_model_trains_and_checkpoint_refuses_another_basis(toy_mesh, tmp_path):
    bench, registry, sizes = toy_mesh
    best = train(
        "tiny_spectral",
        bench,
        RunOptions(out_dir=tmp_path / "run", progress=False),
        registry=registry,
    )
    ckpt = read_checkpoint(best)
    assert ckpt["protocol"]["representation"] == "mesh" and ckpt["protocol"]["spectral_k"] == 6
    assert set(ckpt["context_hashes"]) == {"basis"} and "basis" not in ckpt["hparams"]
    assert len(ckpt["training_data"]["content_hash"]) == 64
    # Learning moved the gains off zero (the data move at constant speed).
    assert float(ckpt["state_dict"]["gain"].abs().max()) > 0.01
    model, _ = load_checkpoint(best, registry=registry, benchmark=bench)
    assert model.basis.hash == ckpt["context_hashes"]["basis"]
    sizes["n"] = 5  # the benchmark's mesh changes: its basis hash differs
    with pytest.raises(CheckpointError, match="basis hash .* differs from benchmark 'toy'"):
        load_checkpoint(best, registry=registry, benchmark=bench)


def test_skeleton_model_trains_on_a_mesh_benchmarks_regressed_joints(
    toy_mesh, tmp_path, monkeypatch
):
    import scipy.sparse as sp

    bench, registry, _ = toy_mesh

    def with_joints(root, split):
        data = waving(grid(4), split)
        regressor = np.zeros((3, 16))
        regressor[0, 0] = regressor[1, 15] = 1.0
        regressor[2] = 1 / 16
        data.joint_regressor, data.joint_names = sp.csr_matrix(regressor), ["a", "b", "c"]
        return data

    use_toy_loader(monkeypatch, with_joints)
    best = train(
        "mlp",
        bench,
        RunOptions(out_dir=tmp_path / "mlp", progress=False),
        registry=registry,
        overrides={"blocks": 2},
        recipe_overrides={"batch_size": 4, "schedule": {"type": "constant"}, "epochs": 2},
    )
    ckpt = read_checkpoint(best)
    assert ckpt["protocol"]["points"] == "regressed joints"
    assert ckpt["hparams"]["num_points"] == 3
    assert ckpt["training_data"]["points"] == "regressor3"
    model, _ = load_checkpoint(best, registry=registry, benchmark=bench)
    result = zoo.evaluate(model, bench, label="mlp", view="joints")
    assert set(result.frame.metric) == {"mpjpe"} and set(result.frame.joints) == {"regressor3"}


def test_a_training_sampler_that_finds_no_window_is_named(toy_mesh, tmp_path):
    from zoo.core.errors import TrainingError

    bench, registry, _ = toy_mesh
    whole = tmp_path / "whole.yaml"  # the window is the whole 12-frame sequence, as on cloth
    whole.write_text(bench.read_text().replace("output_frames: 4", "output_frames: 8"))
    with pytest.raises(
        TrainingError,
        match="training sampler 'stride5_strict' finds no window "
        "of 12 frames.*longest: 12 frames.*train_sampler",
    ):
        train(
            "tiny_spectral",
            whole,
            RunOptions(out_dir=tmp_path / "run", progress=False),
            registry=registry,
            recipe_overrides={"train_sampler": "stride5_strict"},
        )
    assert not (tmp_path / "run").exists()  # nothing half-written


def test_start_epoch_gets_every_training_frame_once_with_its_window_count(
    toy_mesh, tmp_path, monkeypatch
):
    """Statistics over the counted frames equal those over every frame of every window."""
    from zoo.data.windows import gather_windows
    from zoo.train.split import split_train_val, usable_windows

    bench, registry, _ = toy_mesh
    use_toy_loader(monkeypatch, lambda root, split: waving(grid(4), split, frames=30))
    seen = []
    model_class = registry.get("tiny_spectral").load_class()
    monkeypatch.setattr(
        model_class,
        "start_epoch",
        lambda self, epoch, frames: seen.append(list(frames())),
        raising=False,
    )
    train(
        "tiny_spectral",
        bench,
        RunOptions(out_dir=tmp_path / "run", progress=False),
        registry=registry,
        recipe_overrides={"train_sampler": "all", "epochs": 1},
    )
    frames = torch.cat([f for f, _ in seen[0]]).double()
    counts = torch.cat([c for _, c in seen[0]])
    assert len(seen) == 1 and bool((counts > 0).all())

    train_seqs, _ = split_train_val(waving(grid(4), "train", frames=30), 0.25, 8)
    positions, index = usable_windows(train_seqs, 8, "all", 4, 4)
    windows = torch.from_numpy(gather_windows(positions, index, 8)).double().flatten(0, 1)
    assert int(counts.sum()) == len(windows) > 2 * len(frames)  # each frame in several windows
    weights = counts.double()[:, None, None]
    torch.testing.assert_close((weights * frames).sum(0) / counts.sum(), windows.mean(0))
    torch.testing.assert_close(
        (weights * frames.square()).sum(0) / counts.sum(), windows.square().mean(0)
    )


def test_a_training_view_is_computed_once_and_never_read_for_another_basis(toy_mesh, tmp_path):
    """Models with a training view (SpecTrHuMS: coefficients) train on it; it is stored under
    <cache>/views, read back while dataset and view identity hold, recomputed otherwise."""
    from zoo.train.split import training_view_arrays

    class Coefficients(torch.nn.Module):
        def __init__(self, basis, checksum):
            super().__init__()
            self.basis, self.checksum, self.calls = basis, checksum, 0

        def training_view(self, frames):
            self.calls += 1
            return self.basis.project(frames.double())

        def training_view_identity(self):
            return {"basis": self.basis.hash, "checksum": self.checksum}

    from zoo.data.spectral import SpectralBasis

    dataset = waving(grid(4), "train")
    basis = SpectralBasis.compute(dataset.topology, 6)
    first = Coefficients(basis, "a")
    arrays = training_view_arrays(first, dataset, slice(None), cache_dir=tmp_path / "c")
    assert first.calls > 0 and arrays[0].shape == (12, 6, 3) and arrays[0].dtype == np.float32
    np.testing.assert_allclose(arrays[1], basis.project(dataset.sequences[1].vertices), rtol=1e-5)
    again = Coefficients(basis, "a")
    assert all(
        np.array_equal(x, y)
        for x, y in zip(
            arrays, training_view_arrays(again, dataset, slice(None), cache_dir=tmp_path / "c")
        )
    )
    assert again.calls == 0  # read back
    other = Coefficients(basis, "b")  # another basis's bytes: never the stored file
    training_view_arrays(other, dataset, slice(None), cache_dir=tmp_path / "c")
    assert other.calls > 0 and len(list((tmp_path / "c" / "views").iterdir())) == 2


def test_spectrhums_trains_on_cached_coefficients(toy_mesh, tmp_path):
    bench, registry, _ = toy_mesh
    small = dict(latent=8, channels=[4, 8], pooling=[4, 2], d_model=16, layers=1, heads=2, ff=32)
    best = train(
        "spectrhums",
        bench,
        RunOptions(out_dir=tmp_path / "run", progress=False),
        registry=registry,
        overrides={**small, "autoencoder_epochs": 1, "static_frames": 8},
        recipe_overrides={"batch_size": 4, "train_sampler": "all", "epochs": 2},
    )
    views = list((tmp_path / "cache" / "views").iterdir())
    assert len(views) == 1 and views[0].name.startswith("toy-train-")
    history = read_checkpoint(tmp_path / "run" / "last.pt")["history"]
    assert len(history) == 2 and all(np.isfinite(h["train_loss"]) for h in history)
    assert best.is_file()


def test_validation_logs_each_horizon_beside_repeat_last_on_the_same_windows(toy_mesh, tmp_path):
    from zoo.data.windows import window_sampler
    from zoo.models.repeat_last import RepeatLast
    from zoo.protocol.metrics import vertex_rmse
    from zoo.train.validation import validate, validation_frames

    # 25 fps: frame t at 40 t ms; 80 ms is the 2nd predicted frame, 400 ms the 10th, 1000 ms
    # beyond a 4-frame future
    assert validation_frames(4, 25.0) == {"40 ms (first frame)": 0, "80 ms": 1}
    assert validation_frames(25, 25.0) == {
        "40 ms (first frame)": 0,
        "80 ms": 1,
        "400 ms": 9,
        "1000 ms": 24,
    }
    # at 30 fps no frame falls on 80 ms: the nearest (the 2nd) is named by its own time
    assert validation_frames(10, 30.0) == {"33 ms (first frame)": 0, "67 ms": 1}
    positions = [s.vertices for s in waving(grid(4), "test").sequences]
    index = window_sampler("all", [len(p) for p in positions], 4, 4)
    # repeat-last judged against itself: both lines are one
    model = RepeatLast(4, 4, 16)
    same = validate(model, positions, index, 4, 4, slice(None), "cpu", fps=25.0, curve="rmse")
    h = same["val_horizons"]
    assert h["metric"] == "rmse" and h["horizons"] == ["40 ms (first frame)", "80 ms"]
    assert h["model"] == h["repeat_last"]
    # the reference, computed here window by window
    expected = [
        np.mean(
            [
                float(
                    vertex_rmse(
                        torch.from_numpy(positions[s][b + 3 : b + 4][None]),
                        torch.from_numpy(positions[s][b + 4 + t : b + 5 + t][None]),
                    )
                )
                for s, b in index
            ]
        )
        for t in (0, 1)
    ]
    np.testing.assert_allclose(h["repeat_last"], expected, rtol=1e-6)
    assert expected[1] > expected[0] > 0  # the mesh moves: repeat-last falls behind


def test_each_epoch_records_its_horizons_and_the_log_prints_them(toy_mesh, tmp_path, capsys):
    bench, registry, _ = toy_mesh
    best = train(
        "tiny_spectral",
        bench,
        RunOptions(out_dir=tmp_path / "run", progress=False),
        registry=registry,
    )
    history = read_checkpoint(best)["history"]
    for epoch in history:
        h = epoch["val_horizons"]
        assert h["horizons"] == ["40 ms (first frame)", "80 ms"] and len(h["model"]) == 2
    assert history[0]["val_horizons"]["repeat_last"] == history[-1]["val_horizons"]["repeat_last"]
    assert "val rmse 40 ms (first frame) " in capsys.readouterr().out


def test_an_entry_with_weights_of_runs_that_models_weights_beside_its_rows(toy_mesh, tmp_path):
    from zoo.hub.model_source import ModelSource
    from zoo.leaderboard.rebuild import regenerate

    bench, registry, _ = toy_mesh
    checkpoints = tmp_path / "checkpoints"
    train(
        "tiny_spectral",
        bench,
        RunOptions(out_dir=checkpoints / "toy" / "tiny_spectral", progress=False),
        registry=registry,
    )
    best = checkpoints / "toy" / "tiny_spectral" / "best.pt"
    toy = benchmark_module.get_benchmark(bench)
    loaded = ModelSource.of(model="tiny_spectral_still", checkpoint=best).load(registry, toy)
    assert type(loaded.model).__name__ == "TinySpectralStill"
    assert loaded.entry.name == "tiny_spectral_still"
    torch.testing.assert_close(loaded.model.gain, read_checkpoint(best)["state_dict"]["gain"])
    with pytest.raises(CheckpointError, match="only where its registry entry says weights_of"):
        ModelSource.of(model="repeat_last", checkpoint=best).load(registry, toy)
    written = regenerate(
        bench, registry=registry, out_root=tmp_path / "out", checkpoints=checkpoints
    )
    rows = pd.concat(read_table(p).frame for p in written)
    assert {"tiny_spectral", "tiny_spectral_still"} <= set(rows.model)
    still = rows[(rows.model == "tiny_spectral_still") & (rows.metric == "rmse")]
    plain = rows[(rows.model == "tiny_spectral") & (rows.metric == "rmse")]
    assert len(still) == len(plain) and not np.allclose(still.value, plain.value)
    identity = json.loads((written[0] / "tiny_spectral_still" / "protocol.json").read_text())
    assert identity["provenance"]["identity"]["trained"]["sha256"] == sha256_file(best)
    assert identity["provenance"]["identity"]["model"]["name"] == "tiny_spectral_still"
