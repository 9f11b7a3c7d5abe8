"""Mesh metrics with hand-computed values, and the mesh path of the evaluator."""

import math
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
import scipy.sparse as sp
import torch
import yaml
from conftest import use_toy_loader

import zoo
from zoo import create_model
from zoo.core.errors import BenchmarkError
from zoo.data.mesh import MeshDataset, MeshError, MeshSequence, MeshTopology, regress_joints
from zoo.data.spectral import SpectralBasis, SpectralError
from zoo.evaluation.evaluator import EvaluationError
from zoo.evaluation.markdown import markdown_tables
from zoo.models.repeat_last import RepeatLast
from zoo.protocol.benchmark import get_benchmark
from zoo.protocol.metrics import melv, mpjpe, vertex_rmse
from zoo.protocol.views import View

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
    torch.testing.assert_close(
        melv(moved[None, None], TRIANGLE[None], EDGES), torch.tensor([[expected]])
    )
    with pytest.raises(ValueError, match="melv: expected pred"):
        melv(pred[0], TRIANGLE[None], EDGES)


def test_vertex_rmse_by_hand():
    target = TRIANGLE[None, None].expand(2, 2, 3, 3)  # bounding-box diagonal |(3, 4, 0)| = 5
    pred = target.clone()
    pred[0, 0] += torch.tensor([1.0, 0, 0])  # every vertex off by 1 -> RMSE 1 -> 0.2
    pred[1, 1, 2, 2] = 3.0  # one vertex off by 3 -> sqrt(9 / 3) / 5
    out = vertex_rmse(pred, target)
    torch.testing.assert_close(out, torch.tensor([[0.2, 0.0], [0.0, math.sqrt(3) / 5]]))
    with pytest.raises(ValueError, match="vertex_rmse"):
        vertex_rmse(pred[:, :1], target)


def test_mpjpe_through_a_sparse_regressor_by_hand():
    # joint 0 = midpoint of vertices 0 and 1 = (1.5, 0, 0); joint 1 = vertex 2 = (0, 4, 0)
    regressor = sp.csr_matrix(np.array([[0.5, 0.5, 0.0], [0.0, 0.0, 1.0]]))
    target = TRIANGLE[None, None].repeat(1, 2, 1, 1)
    torch.testing.assert_close(
        regress_joints(target, regressor)[0, 0], torch.tensor([[1.5, 0, 0], [0, 4, 0]])
    )
    pred = target.clone()
    pred[0, 1, 0] += torch.tensor([0.0, 0, 4])  # joint 0 moves by 2, joint 1 stays: mean 1
    pred[0, 1, 2] += torch.tensor([0.0, 3, 4])  # joint 1 moves by 5: mean (2 + 5) / 2
    torch.testing.assert_close(
        mpjpe(regress_joints(pred, regressor), regress_joints(target, regressor)),
        torch.tensor([[0.0, 3.5]]),
    )
    with pytest.raises(ValueError, match=r"regressor \(2, 3\) does not fit"):
        regress_joints(torch.zeros(1, 4, 3), regressor)


# ---- the evaluator on mesh benchmarks ---------------------------------------------------------

# A 10 mm square of two triangles: 4 sides of 10 mm and a diagonal of 10 sqrt(2) mm.
SQUARE = np.array([[0.0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]])
SQUARE_FACES = np.array([[0, 1, 2], [0, 2, 3]])
MEAN_EDGE = (40 + 10 * math.sqrt(2)) / 5


def scaling(rate: float, frames: int = 5) -> np.ndarray:
    """The square scaled by ``1 + rate * t`` at frame t."""
    return np.stack([SQUARE * (1 + rate * t) for t in range(frames)]).astype(np.float32)


def toy_dataset() -> MeshDataset:
    topology = MeshTopology(SQUARE_FACES, 4, name="square")
    sequences = [
        MeshSequence("a0", "a", scaling(0.1), 25.0),
        MeshSequence("a1", "a", scaling(0.1), 25.0),
        MeshSequence("b0", "b", scaling(0.2), 25.0),
    ]
    centroid = sp.csr_matrix(np.full((1, 4), 0.25))
    return MeshDataset(
        "toy",
        "test",
        topology,
        sequences,
        recipe={"toy": 1},
        joint_regressor=centroid,
        joint_names=["centre"],
    )


@pytest.fixture
def toy_bench(tmp_path, monkeypatch):
    """A mesh benchmark on the toy dataset: 2 frames in, 3 out, one window per sequence."""
    monkeypatch.setenv("ZOO_CACHE_DIR", str(tmp_path / "cache"))
    use_toy_loader(monkeypatch, lambda root, split: toy_dataset())

    def write(**fields):
        spec = {
            "name": "toy",
            "representation": "mesh",
            "dataset": "toy",
            "loader": "toy.py:toy_dataset",
            "split": "test",
            "input_frames": 2,
            "output_frames": 3,
            "sampler": "all",
            **fields,
        }
        path = tmp_path / f"toy{len(list(tmp_path.glob('*.yaml')))}.yaml"
        path.write_text(yaml.safe_dump(spec))
        return get_benchmark(path)

    return write


def rows(frame, model, metric, averaging="frame"):
    sel = frame[(frame.model == model) & (frame.metric == metric) & (frame.averaging == averaging)]
    return {a: g.sort_values("frame")["value"].to_numpy() for a, g in sel.groupby("action")}


def test_mesh_evaluation_by_hand(toy_bench, tmp_path):
    bench = toy_bench(spectral_k=2, ground_truths=["raw", "spectral"], melv_frames="raw")
    model = create_model("repeat_last", benchmark=bench)
    assert model.num_points == 4
    result = zoo.evaluate(model, bench, label="repeat_last")
    frame, k = result.frame, np.arange(1, 4)
    # Reference = frame 1 (last observed), predicted frame k is frame 1 + k; the square scales.
    expected = {}
    for action, rate in (("a", 0.1), ("b", 0.2)):
        scale = 1 + rate * (1 + k)
        expected[action] = {
            "melv_gt": MEAN_EDGE * rate * k,  # every edge scales
            "rmse": rate * k * 10 / (scale * 10 * math.sqrt(2)),  # RMS |x0| = 10
            "mpjpe": 5 * math.sqrt(2) * rate * k,  # centroid (5, 5, 0)
        }
    for action in ("a", "b"):
        np.testing.assert_allclose(
            rows(frame, "ground_truth", "melv")[action], expected[action]["melv_gt"], rtol=1e-5
        )
        np.testing.assert_allclose(rows(frame, "repeat_last", "melv")[action], 0, atol=1e-6)
        np.testing.assert_allclose(
            rows(frame, "repeat_last", "rmse")[action], expected[action]["rmse"], rtol=1e-5
        )
        np.testing.assert_allclose(
            rows(frame, "repeat_last", "mpjpe")[action], expected[action]["mpjpe"], rtol=1e-5
        )
    # Actions: unweighted mean (2 windows of a, 1 of b); cumulative: running mean over frames.
    average = (expected["a"]["rmse"] + expected["b"]["rmse"]) / 2
    np.testing.assert_allclose(rows(frame, "repeat_last", "rmse")["average"], average, rtol=1e-5)
    np.testing.assert_allclose(
        rows(frame, "repeat_last", "rmse", "cumulative")["average"],
        np.cumsum(average) / k,
        rtol=1e-5,
    )
    assert set(frame.joints) == {"vertices", "regressor1"}
    assert set(frame[frame.metric == "mpjpe"].joints) == {"regressor1"}
    assert sorted(frame.horizon_ms.unique()) == [40, 80, 120]
    assert dict(frame[frame.action == "a"].groupby("action").windows.first()) == {"a": 2}
    record = result.protocol
    assert record["ground_truth"] == "raw" and record["spectral_basis"] is None
    assert record["topology_hash"] == toy_dataset().topology.hash
    assert record["recipe_hash"] == toy_dataset().recipe_hash
    assert record["windows_per_action"] == {"a": 2, "b": 1}
    assert "regressor1" in record["joint_protocols"]
    out = result.write(tmp_path / "out")
    assert (out / "tables.md").read_text().count("## ") == 6  # melv, rmse, mpjpe x 2 averagings


def test_spectral_ground_truth(toy_bench):
    full = toy_bench(spectral_k=4, ground_truths=["raw", "spectral"], melv_frames="raw")
    raw = zoo.evaluate(RepeatLast(2, 3, 4), full, label="repeat_last")
    spectral = zoo.evaluate(RepeatLast(2, 3, 4), full, label="repeat_last", ground_truth="spectral")
    basis = SpectralBasis.load_or_compute(toy_dataset().topology, 4)
    assert spectral.protocol["ground_truth"] == "spectral4"
    assert spectral.protocol["spectral_basis"]["hash"] == basis.hash
    assert spectral.protocol["protocol_id"] != raw.protocol["protocol_id"]
    # k = V: the reconstruction is the data itself, so the numbers agree.
    np.testing.assert_allclose(spectral.frame.value, raw.frame.value, rtol=1e-4, atol=1e-5)
    # k = 1 keeps only the mean of each coordinate: nothing moves but the centroid.
    low = zoo.evaluate(
        RepeatLast(2, 3, 4),
        toy_bench(
            spectral_k=1, ground_truth="spectral", ground_truths=["spectral"], melv_frames="raw"
        ),
        label="repeat_last",
    )
    np.testing.assert_allclose(rows(low.frame, "ground_truth", "melv")["a"], 0, atol=1e-5)
    np.testing.assert_allclose(
        rows(low.frame, "repeat_last", "mpjpe")["a"],
        rows(raw.frame, "repeat_last", "mpjpe")["a"],
        rtol=1e-5,
    )
    with pytest.raises(SpectralError, match=r"k must be an integer in \[1, 4\]"):
        zoo.evaluate(
            RepeatLast(2, 3, 4),
            toy_bench(spectral_k=5, ground_truth="spectral", ground_truths=["spectral"]),
            label="x",
        )


def test_basis_context_and_model_contract(toy_bench):
    bench = toy_bench(spectral_k=2)  # k=3 would cut the square's repeated eigenvalue (a warning)
    inputs = bench.model_inputs(("basis",))
    assert inputs["num_points"] == 4 and inputs["basis"].k == 2
    inputs["basis"].check_topology(toy_dataset().topology)
    with pytest.raises(BenchmarkError, match="cannot supply context 'parts'.*basis"):
        bench.model_inputs(("parts",))

    class WithBasis(RepeatLast):
        def __init__(self, basis, **kwargs):
            super().__init__(**kwargs)
            self.basis = basis

    result = zoo.evaluate(WithBasis(**inputs), bench, label="with_basis")
    assert result.protocol["provenance"]["model_basis"]["hash"] == inputs["basis"].hash

    class Wrong(RepeatLast):
        def forward(self, history):
            return history[:, -1:]

    with pytest.raises(EvaluationError, match=r"returned \(3, 1, 4, 3\).*expects \(3, 3, 4, 3\)"):
        zoo.evaluate(Wrong(2, 3, 4), bench, label="wrong")
    with pytest.raises(EvaluationError, match="found no window of 6 frames"):
        zoo.evaluate(RepeatLast(3, 3, 4), toy_bench(input_frames=3), label="x")


def test_mesh_benchmark_files_are_checked(toy_bench, tmp_path):
    with pytest.raises(BenchmarkError, match="ground truth 'spectral' needs field 'spectral_k'"):
        toy_bench(ground_truth="spectral", ground_truths=["spectral"])
    with pytest.raises(BenchmarkError, match="'ground_truth' .'spectral'. must be one of"):
        toy_bench(spectral_k=2, ground_truth="spectral", ground_truths=["raw"])
    with pytest.raises(
        BenchmarkError,
        match="field 'ground_truth': input should be 'raw' or 'spectral', got 'smooth'",
    ):
        toy_bench(ground_truth="smooth")
    with pytest.raises(
        BenchmarkError, match="field 'loader': expected package.module:NAME or file.py:NAME"
    ):
        toy_bench(loader="nope")
    with pytest.raises(BenchmarkError, match="field 'skeleton': belongs to joints benchmarks"):
        toy_bench(skeleton="zoo.data.skeleton:CMU")
    with pytest.raises(BenchmarkError, match="field .spectral_k.: belongs to mesh benchmarks"):
        toy_bench(representation="joints", dataset="cmu_mocap", spectral_k=8)
    cloth = get_benchmark("cloth")
    assert cloth.representation == "mesh" and cloth.spectral_k == 256
    assert (cloth.input_frames, cloth.output_frames) == (25, 25)
    with pytest.raises(EvaluationError, match="mesh benchmarks only"):
        zoo.evaluate(RepeatLast(10, 25, 25), "cmu", label="x", ground_truth="raw")


def test_skeleton_models_see_the_regressed_joints_of_the_same_windows(toy_bench):
    bench = toy_bench()
    dataset = toy_dataset()
    assert bench.view_for(("joints",)) == "joints" and bench.view_for(("joints", "mesh")) == "mesh"
    inputs = bench.model_inputs((), dataset=dataset, view="joints")
    assert inputs["num_points"] == 1  # one regressed joint, the centroid
    mesh = zoo.evaluate(RepeatLast(2, 3, 4), bench, label="repeat_last", dataset=dataset)
    seen = []

    class JointsRepeatLast(RepeatLast):
        def forward(self, history):
            seen.append(history.clone())
            return super().forward(history)

    joints = zoo.evaluate(
        JointsRepeatLast(**inputs), bench, label="joints_model", dataset=dataset, view="joints"
    )
    # The model got the centroids of the observed frames: (5, 5, 0) scaled by 1 + rate * t.
    first = seen[0][0, :, 0]
    np.testing.assert_allclose(first[:, :2], 5 * np.array([[1.0, 1.0], [1.1, 1.1]]), rtol=1e-6)
    # Same windows, same protocol: the MPJPE rows equal the mesh evaluation's (the regressor is
    # linear, so repeating the last regressed frame is regressing the repeated mesh).
    assert joints.protocol["protocol_id"] == mesh.protocol["protocol_id"]
    assert set(joints.frame.metric) == {"mpjpe"} and set(joints.frame.model) == {"joints_model"}
    np.testing.assert_allclose(
        rows(joints.frame, "joints_model", "mpjpe")["average"],
        rows(mesh.frame, "repeat_last", "mpjpe")["average"],
        rtol=1e-6,
    )
    assert joints.protocol["provenance"]["model_input"] == "regressed joints (regressor1)"

    bare = MeshDataset("bare", "test", dataset.topology, dataset.sequences, recipe={})
    with pytest.raises(EvaluationError, match="bare has no joint regressor"):
        zoo.evaluate(JointsRepeatLast(**inputs), bench, label="x", dataset=bare, view="joints")
    with pytest.raises(MeshError, match="no joint regressor"):
        bench.model_inputs((), dataset=bare, view="joints")
    with pytest.raises(MeshError, match="cannot tell upper from lower body"):
        bench.model_inputs(("parts",), dataset=dataset, view="joints")


def test_joints_view_body_parts_from_bvh_names():
    names = ["Hips", "LeftUpLeg", "Spine", "Head", "RightUpLeg", "LeftArm"]
    topology = MeshTopology(np.array([[0, 1, 2]]), 3)
    regressor = sp.csr_matrix(np.full((len(names), 3), 1 / 3))
    seq = MeshSequence("s", "a", np.arange(18, dtype=np.float32).reshape(2, 3, 3), 25.0)
    view = MeshDataset(
        "d", "test", topology, [seq], recipe={}, joint_regressor=regressor, joint_names=names
    ).joints_view()
    assert view.parts == {"upper": [2, 3, 5], "lower": [0, 1, 4]}
    assert view.sequences[0].positions.shape == (2, 6, 3)
    np.testing.assert_allclose(view.sequences[0].positions[1, 0], [12, 13, 14])  # the centroid


def test_linear_interpolation_completes_a_uniform_scaling_exactly(toy_bench):
    bench = toy_bench()
    model = create_model("interpolate", benchmark=bench)
    result = zoo.evaluate(model, bench, label="interpolate", task="completion")
    frame = result.frame
    # The square scales linearly in time, so the straight line to the final frame is the truth.
    for metric in ("rmse", "mpjpe"):
        np.testing.assert_allclose(rows(frame, "interpolate", metric)["average"], 0, atol=1e-5)
    np.testing.assert_allclose(
        rows(frame, "interpolate", "melv")["average"],
        rows(frame, "ground_truth", "melv")["average"],
        rtol=1e-5,
    )
    assert result.protocol["task"] == "completion"
    with pytest.raises(ValueError, match=r"final_frame: expected \(B, P, 3\)"):
        model(torch.zeros(1, 2, 4, 3), None)


def test_melv_on_spectral_frames_by_default(toy_bench):
    """MELV measures edges of the k-coefficient reconstructions (reference and scored frames),
    as SpecTrHuMS does, wherever the benchmark has a basis; raw stays an option."""
    assert toy_bench().melv_on == "raw" and toy_bench(spectral_k=2).melv_on == "spectral"
    full = toy_bench(spectral_k=4)
    spectral = zoo.evaluate(RepeatLast(2, 3, 4), full, label="repeat_last")
    raw = zoo.evaluate(RepeatLast(2, 3, 4), full, label="repeat_last", melv_frames="raw")
    assert spectral.protocol["melv_frames"].startswith("spectral4")
    assert raw.protocol["melv_frames"].startswith("raw")
    assert spectral.protocol["protocol_id"] != raw.protocol["protocol_id"]
    # k = V: the reconstruction is the data itself
    np.testing.assert_allclose(spectral.frame.value, raw.frame.value, rtol=1e-4, atol=1e-5)
    # k = 1 keeps only each coordinate's mean: every edge collapses, the ground truth's MELV is
    # 0, while RMSE (scored against the raw ground truth) does not change.
    low = zoo.evaluate(RepeatLast(2, 3, 4), toy_bench(spectral_k=1), label="repeat_last")
    np.testing.assert_allclose(rows(low.frame, "ground_truth", "melv")["a"], 0, atol=1e-5)
    assert (rows(raw.frame, "ground_truth", "melv")["a"] > 0.5).all()
    np.testing.assert_allclose(
        rows(low.frame, "repeat_last", "rmse")["a"],
        rows(raw.frame, "repeat_last", "rmse")["a"],
        rtol=1e-6,
    )
    with pytest.raises(BenchmarkError, match="'melv_frames: spectral' needs field 'spectral_k'"):
        toy_bench(melv_frames="spectral")
    with pytest.raises(
        BenchmarkError, match="field 'melv_frames': input should be 'raw' or 'spectral'"
    ):
        toy_bench(spectral_k=2, melv_frames="smooth")
    with pytest.raises(EvaluationError, match="melv_frames must be one of raw, spectral"):
        zoo.evaluate(RepeatLast(2, 3, 4), full, label="x", melv_frames="smooth")


def test_every_row_carries_its_standard_deviation_over_windows(toy_bench):
    result = zoo.evaluate(RepeatLast(2, 3, 4), toy_bench(melv_frames="raw"), label="repeat_last")
    frame = result.frame
    rmse = frame[(frame.model == "repeat_last") & (frame.metric == "rmse")]
    by = {(r.action, r.averaging, r.frame): r for r in rmse.itertuples()}
    k = np.arange(1, 4)
    per_window = {
        a: rate * k / ((1 + rate * (1 + k)) * math.sqrt(2)) for a, rate in (("a", 0.1), ("b", 0.2))
    }
    for t in k:
        assert by["a", "frame", t].std == pytest.approx(0, abs=1e-7)  # two equal windows
        assert math.isnan(by["b", "frame", t].std)  # one window: no spread
        pooled = [per_window["a"][t - 1]] * 2 + [per_window["b"][t - 1]]
        assert by["average", "frame", t].std == pytest.approx(np.std(pooled, ddof=1), rel=1e-5)
        cumulative = [np.mean(per_window["a"][:t])] * 2 + [np.mean(per_window["b"][:t])]
        assert by["average", "cumulative", t].std == pytest.approx(
            np.std(cumulative, ddof=1), rel=1e-5
        )
    tables = markdown_tables(frame, {result.protocol["protocol_id"]: result.protocol})
    melv_table = tables[tables.index("## MELV (mm), averaging `frame`") :]
    assert "Each cell: mean (standard deviation over windows)." in melv_table
    assert "(0.000)" in melv_table.split("| ground_truth | a")[1].split("\n")[0]
    assert (
        "## RMSE (per vertex, normalised by the ground-truth frame's bounding-box diagonal)"
        in tables
    )


def test_a_table_of_results_that_each_carry_the_ground_truths_rows_shows_them_once(toy_bench):
    """Every mesh result holds the ground truth's own MELV rows; a table of several (a
    leaderboard) shows that row once, with its value."""
    bench = toy_bench(melv_frames="raw")
    results = [zoo.evaluate(RepeatLast(2, 3, 4), bench, label=name) for name in ("a1", "a2")]
    frame = pd.concat([r.frame for r in results], ignore_index=True)
    records = {r.protocol["protocol_id"]: r.protocol for r in results}
    one = markdown_tables(results[0].frame, records)
    both = markdown_tables(frame, records)
    truth = [line for line in both.splitlines() if line.startswith("| ground_truth | a ")]
    assert truth and truth == [
        line for line in one.splitlines() if line.startswith("| ground_truth | a ")
    ]
    assert len(truth) == both.count("## MELV")
    # a model with no row for an action keeps its line in each table, blank
    cut = markdown_tables(frame[(frame.model != "a2") | (frame.action != "a")], records)
    rows = [line.split("|")[1:3] for line in both.splitlines() if line.startswith("| a2 ")]
    assert rows == [line.split("|")[1:3] for line in cut.splitlines() if line.startswith("| a2 ")]


def test_autoencoder_floor_rows_beside_the_model(toy_bench, tmp_path):
    """A model with ``autoencoder_floor`` gets ``<name>:autoencoder`` rows: the ground-truth
    future through it, scored like a prediction, shown in the headline but never the best."""
    from zoo.report.outputs import write_leaderboard

    class Blurred(RepeatLast):
        def autoencoder_floor(self, frames):
            return frames + 1.0  # every vertex 1 mm off along x, y and z

    bench = toy_bench(melv_frames="raw")
    result = zoo.evaluate(Blurred(2, 3, 4), bench, label="blurred")
    frame = result.frame
    assert set(frame.model) == {"blurred", "blurred:autoencoder", "ground_truth"}
    assert frame.model.iloc[0] == "blurred"  # the result folder is named after the model
    floor_rmse = rows(frame, "blurred:autoencoder", "rmse")
    for action, rate in (("a", 0.1), ("b", 0.2)):
        diagonal = 10 * math.sqrt(2) * (1 + rate * (1 + np.arange(1, 4)))
        np.testing.assert_allclose(floor_rmse[action], math.sqrt(3) / diagonal, rtol=1e-5)
    # a rigid shift keeps every edge: the floor's MELV is the ground truth's own
    np.testing.assert_allclose(
        rows(frame, "blurred:autoencoder", "melv")["a"],
        rows(frame, "ground_truth", "melv")["a"],
        rtol=1e-5,
    )
    assert "floor" in result.protocol["metrics"]
    out = write_leaderboard([result], tmp_path / "board")
    headline = (out / "leaderboard.md").read_text().split("## RMSE")[0]
    floor_line = next(line for line in headline.splitlines() if line.startswith("| blurred:"))
    model_line = next(line for line in headline.splitlines() if line.startswith("| blurred "))
    assert "*" not in floor_line.split("|", 2)[2] and "**" in model_line
    assert "±" in floor_line  # its own interval, from its per-window errors
    assert (
        "`blurred:autoencoder`: the ground-truth future through the model's autoencoder" in headline
    )
    plain = zoo.evaluate(RepeatLast(2, 3, 4), bench, label="repeat_last")
    assert not any(m.endswith(":autoencoder") for m in plain.frame.model)


def test_joints_are_regressed_in_float64_and_rounded_once():
    """Every CPU gives the same float32 joints: the weighted sum over thousands of vertices is
    summed in float64 (in float32 its last bits follow the CPU's summation order)."""
    import scipy.sparse

    rng = np.random.default_rng(0)
    vertices = torch.from_numpy(rng.normal(0, 800, (2, 5, 6000, 3)).astype(np.float32))
    dense = rng.random((7, 6000)) * (rng.random((7, 6000)) < 0.2)
    dense /= dense.sum(1, keepdims=True)
    exact = np.einsum("jv,btvc->btjc", dense, vertices.double().numpy()).astype(np.float32)
    for regressor in (dense, scipy.sparse.csr_matrix(dense)):
        joints = regress_joints(vertices, regressor)
        assert joints.dtype == torch.float32
        assert np.array_equal(joints.numpy(), exact)


def test_one_pass_scores_every_model_as_alone_and_a_failure_leaves_only_its_model(toy_bench):
    """zoo leaderboard scores a table's rows in one pass (the ground truth prepared once): each
    model's result equals its evaluation alone, to the last bit, and a model that fails mid-way
    leaves the pass with its error while the others are scored to the end."""
    from zoo.evaluation.evaluator import Scored, evaluate_models
    from zoo.protocol.plan import plan_protocol

    bench = toy_bench(spectral_k=2, ground_truths=["raw", "spectral"])
    dataset = toy_dataset()
    joint_inputs = bench.model_inputs((), dataset=dataset, view="joints")

    class FailsLast(RepeatLast):
        """Repeats the last frame, then predicts NaN on its third batch (the last window)."""

        calls = 0

        def forward(self, history):
            self.calls += 1
            out = super().forward(history)
            return torch.full_like(out, float("nan")) if self.calls == 3 else out

    for truth in ("raw", "spectral"):
        protocol = plan_protocol(bench, dataset, ground_truth=truth)
        models = [
            Scored(RepeatLast(2, 3, 4), "repeat_last"),
            Scored(FailsLast(2, 3, 4), "fails"),
            Scored(RepeatLast(**joint_inputs), "joints_model", view="joints"),
            Scored(RepeatLast(2, 3, 4), "bad_view", view="pixels"),
        ]
        together = evaluate_models(models, protocol, batch_size=1)
        assert isinstance(together[1], EvaluationError) and "non-finite" in str(together[1])
        assert isinstance(together[3], EvaluationError) and "pixels" in str(together[3])
        for scored, result in zip(models, together):
            if isinstance(result, Exception):
                continue
            (alone,) = evaluate_models([scored], protocol, batch_size=1, keep_going=False)
            assert result.windows.errors.keys() == alone.windows.errors.keys()
            for key, errors in alone.windows.errors.items():
                np.testing.assert_array_equal(result.windows.errors[key], errors)
            pd.testing.assert_frame_equal(result.frame, alone.frame)
        with pytest.raises(EvaluationError, match="non-finite"):
            evaluate_models(
                [Scored(FailsLast(2, 3, 4), "fails")], protocol, batch_size=1, keep_going=False
            )


def test_a_model_failing_on_another_process_fails_on_every_process(toy_bench, monkeypatch):
    """Under torchrun each process scores its share of the batches; a model that failed on
    another process must not give this one a result missing that process's windows."""
    import zoo.evaluation.evaluator as evaluator
    from zoo.core.distributed import DistInfo
    from zoo.protocol.plan import plan_protocol

    bench = toy_bench()
    protocol = plan_protocol(bench, toy_dataset())

    def gather_from_two(share, info):  # this process is 0; process 1 saw model 0 fail
        other = ({1: {}}, {0: "ValueError: broke on process 1's batch"})
        return {**share, 1: other}

    monkeypatch.setattr(evaluator, "gather_shares", gather_from_two)
    monkeypatch.setattr(evaluator, "init_distributed", lambda device: DistInfo(rank=0, world=2))
    models = [
        evaluator.Scored(RepeatLast(2, 3, 4), "a"),
        evaluator.Scored(RepeatLast(2, 3, 4), "b"),
    ]
    first, second = evaluator.evaluate_models(models, protocol, batch_size=1)
    assert isinstance(first, EvaluationError)
    assert "model 'a' failed on process 1: ValueError: broke" in str(first)
    assert not isinstance(second, Exception) and set(second.frame.model) == {"b", "ground_truth"}


def test_a_metric_declared_once_is_scored_by_the_evaluator_in_every_view_that_lists_it(
    toy_bench, swinging_cmu, monkeypatch
):
    """The evaluator scores the metrics a view declares, each by its declaration's ``score``: a
    metric added to the declarations (here twice the MPJPE) gets its rows on a mesh model, on a
    skeleton model of the mesh benchmark's regressed joints and on a skeleton benchmark (under
    each of its joint protocols), with no edit to the evaluator."""
    import zoo.protocol.metrics as metrics
    import zoo.protocol.views as views
    from zoo.protocol.views import View

    assert [m.name for m in View.MESH.metrics] == ["melv", "rmse", "mpjpe"]
    assert [m.name for m in View.JOINTS.metrics] == ["mpjpe"]
    doubled = replace(
        metrics.METRICS["mpjpe"],
        name="mpjpe2",
        score=lambda pred, truth: {k: 2 * v for k, v in truth.joint_errors(pred).items()},
    )
    monkeypatch.setitem(metrics.METRICS, "mpjpe2", doubled)
    monkeypatch.setattr(
        views, "_VIEW_METRICS", {View.JOINTS: ("mpjpe", "mpjpe2"), View.MESH: ("mpjpe2",)}
    )
    bench, dataset = toy_bench(), toy_dataset()
    mesh = zoo.evaluate(RepeatLast(2, 3, 4), bench, label="repeat_last", dataset=dataset).frame
    # no MELV among the view's metrics: no ground_truth rows of the data's own MELV either
    assert set(mesh.metric) == {"mpjpe2"} and set(mesh.model) == {"repeat_last"}
    inputs = bench.model_inputs((), dataset=dataset, view="joints")
    joints = zoo.evaluate(
        RepeatLast(**inputs), bench, label="joints_model", dataset=dataset, view="joints"
    ).frame
    assert set(joints.metric) == {"mpjpe", "mpjpe2"}
    np.testing.assert_allclose(
        rows(joints, "joints_model", "mpjpe2")["average"],
        2 * rows(joints, "joints_model", "mpjpe")["average"],
        rtol=1e-6,
    )
    np.testing.assert_allclose(
        rows(mesh, "repeat_last", "mpjpe2")["average"],
        rows(joints, "joints_model", "mpjpe2")["average"],
        rtol=1e-6,
    )
    cmu = get_benchmark("cmu")
    skeleton = zoo.evaluate(
        zoo.create_model("repeat_last", benchmark=cmu), cmu, data_root=swinging_cmu[0]
    ).frame
    for protocol in ("all38", "used25"):
        one, two = (
            skeleton[(skeleton.joints == protocol) & (skeleton.metric == m)]
            for m in ("mpjpe", "mpjpe2")
        )
        assert len(one) == len(two) > 0
        np.testing.assert_allclose(two["value"].to_numpy(), 2 * one["value"].to_numpy(), rtol=1e-6)


def test_a_skeleton_model_trains_on_the_regressed_joints_and_its_record_says_so(toy_bench):
    bench, mesh = toy_bench(), toy_dataset()
    joints, points = bench.strategy.training_data(mesh, View.JOINTS)
    assert points == slice(None) and joints.fps == mesh.fps and joints.num_joints == 1
    assert bench.strategy.training_record(joints, View.JOINTS)["points"] == "regressor1"
    assert bench.strategy.training_data(mesh, View.MESH)[0] is mesh
    assert "points" not in bench.strategy.training_record(mesh, View.MESH)
