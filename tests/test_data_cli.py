"""zoo data: describe and export windows of a mesh dataset; errors name the argument."""

import numpy as np
import pytest
import trimesh

from zoo.cli import main
from zoo.data.catalog import describe, export_window
from zoo.data.mesh import MeshDataset, MeshError, MeshSequence, MeshTopology
from zoo.protocol.benchmark import get_benchmark


def toy_dataset(frames=60):
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    rng = np.random.default_rng(0)
    seqs = [
        MeshSequence(
            f"s{i}",
            "fall",
            rng.normal(size=(frames, 4, 3)).astype("f4") * 100,
            25.0,
            identity=f"id{i % 2}",
        )
        for i in range(3)
    ]
    return MeshDataset("toy", "test", MeshTopology(faces, 4), seqs, recipe={"seed": 0})


def test_describe_reports_sizes_identities_and_hashes():
    info = describe(toy_dataset())
    assert info["sequences"] == 3 and info["frames"] == 180 and info["identities"] == 2
    assert info["vertices"] == 4 and info["edges"] == 5 and info["fps"] == 25.0
    assert len(info["topology_hash"]) == 64 and len(info["content_hash"]) == 64


def test_export_glb_holds_every_frame_and_ply_one_file_per_frame(tmp_path):
    ds, bench = toy_dataset(), get_benchmark("cloth")
    glb = export_window(ds, bench, 2, tmp_path / "w.glb")[0]
    scene = trimesh.load(glb)
    assert len(scene.geometry) == bench.input_frames + bench.output_frames
    plys = export_window(ds, bench, 0, tmp_path / "w.ply")
    assert len(plys) == 50
    first = trimesh.load(plys[0], process=False)
    np.testing.assert_allclose(first.vertices, ds.sequences[0].vertices[0] / 1000, atol=1e-6)


def test_export_errors_name_the_argument(tmp_path):
    ds, bench = toy_dataset(), get_benchmark("cloth")
    with pytest.raises(MeshError, match=r"--window 99: .* has 33 windows .* \(valid: 0..32\)"):
        export_window(ds, bench, 99, tmp_path / "w.glb")
    with pytest.raises(MeshError, match=r"expected a file ending in .glb or .ply"):
        export_window(ds, bench, 0, tmp_path / "w.obj")


def test_data_list_and_missing_benchmark(capsys):
    assert main(["data", "list"]) == 0
    out = capsys.readouterr().out
    assert "cmu_anny_oi" in out and "cloth" in out
    with pytest.raises(SystemExit) as exit_:
        main(["data", "describe"])
    assert exit_.value.code == 2
    assert "required: benchmark" in capsys.readouterr().err


def test_render_writes_picture_and_meshes(tmp_path):
    from zoo import create_model
    from zoo.report.render import render_windows

    ds, bench = toy_dataset(), get_benchmark("cloth")
    model = create_model("repeat_last", input_frames=25, output_frames=25, num_points=4)
    written = render_windows(model, "repeat_last", bench, ds, [0, 5], tmp_path)
    assert [p.name for p in written] == [
        "repeat_last_windows.png",
        "repeat_last_window0.glb",
        "repeat_last_window5.glb",
    ]
    assert written[0].read_bytes()[:4] == b"\x89PNG"
    scene = trimesh.load(written[1])
    assert len(scene.geometry) == 2 * 3  # truth and prediction at 80, 400 and 1000 ms
    with pytest.raises(MeshError, match=r"--windows \[99\]"):
        render_windows(model, "repeat_last", bench, ds, [99], tmp_path)
