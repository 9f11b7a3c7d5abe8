"""DMGNN and the view it is fed: every joint's exp-map angles of a joints benchmark, predicted
angles scored on the joints the one FK routine makes of them."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import write_cmu_file
from tiny_models import REGISTRY as TINY
from torch import nn

import zoo
from zoo.core.errors import EvaluationError
from zoo.models.dmgnn import DMGNN, _graph_kernels
from zoo.models.registry import Registry, load_registry
from zoo.protocol.benchmark import get_benchmark
from zoo.train.loop import train
from zoo.train.options import RunOptions

REPO = Path(__file__).resolve().parents[1]

ANGLE_MODELS = """\
models:
  last_angles:
    class: angle_models.py:LastAngles
    representation: expmap
    trainable: true
    hparams: {}
    reference: test model
    train: {lr: 0.01, batch_size: 8, epochs: 1}
"""

ANGLE_MODEL_CODE = '''
import torch
from torch import nn


class LastAngles(nn.Module):
    """The last observed angles, plus a learned offset that starts at zero."""

    def __init__(self, input_frames, output_frames, num_points):
        super().__init__()
        self.output_frames = output_frames
        self.offset = nn.Parameter(torch.zeros(num_points, 3))

    def forward(self, history):
        return history[:, -1:].expand(-1, self.output_frames, -1, -1) + self.offset
'''


class LastAngles(nn.Module):
    def __init__(self, input_frames, output_frames, num_points):
        super().__init__()
        self.output_frames = output_frames

    def forward(self, history):
        return history[:, -1:].expand(-1, self.output_frames, -1, -1)


def test_an_angle_model_is_scored_on_the_joints_its_angles_make(swinging_cmu):
    root, _ = swinging_cmu
    bench = get_benchmark("cmu")
    angles = zoo.evaluate(LastAngles(10, 25, 38), bench, label="a", data_root=root, view="expmap")
    joints = zoo.evaluate(zoo.create_model("repeat_last", benchmark=bench), bench, label="a",
                          data_root=root)  # fmt: skip
    # the last frame's angles are the last frame's joints: repeat-last, scored the same way
    assert angles.frame[["joints", "frame"]].equals(joints.frame[["joints", "frame"]])
    assert joints.frame["value"].max() > 1.0
    np.testing.assert_allclose(angles.frame["value"], joints.frame["value"], atol=1e-3)


def test_data_without_angles_feeds_no_angle_model(swinging_cmu):
    root, _ = swinging_cmu
    bench = get_benchmark("cmu")
    dataset = bench.load(root)
    assert bench.strategy.scored_kinds(dataset) == ("joints", "expmap")
    for sequence in dataset.sequences:
        sequence.angles = None
    assert bench.strategy.scored_kinds(dataset) == ("joints",)
    from zoo.evaluation.evaluator import Scored, evaluate_models
    from zoo.protocol.plan import plan_protocol

    protocol = plan_protocol(bench, dataset, sampler="ltd8")
    scored = Scored(LastAngles(10, 25, 38), "angles", view="expmap")
    (refused,) = evaluate_models([scored], protocol)
    assert isinstance(refused, EvaluationError)
    assert "must be fed view joints, got 'expmap'" in str(refused)


def test_an_angle_model_trains_on_angles_and_validates_in_mm(tmp_path):
    for i in (1, 2, 3):
        write_cmu_file(tmp_path / "cmu" / "train" / "walking" / f"walking_{i}.txt",
                       0.05 * i * np.arange(500))  # fmt: skip
    (tmp_path / "registry.yaml").write_text(TINY + ANGLE_MODELS.split("models:\n", 1)[1])
    (tmp_path / "angle_models.py").write_text(ANGLE_MODEL_CODE)
    shutil.copy(Path(__file__).parent / "tiny_models.py", tmp_path / "tiny_models.py")
    registry = Registry.from_files(REPO / "registry.yaml", tmp_path / "registry.yaml")
    assert registry.list_models("expmap") == ["dmgnn", "last_angles"]
    runs = {}
    for model in ("last_angles", "tiny"):
        out = tmp_path / model
        options = RunOptions(data_root=tmp_path / "cmu", out_dir=out, progress=False, max_batches=2)
        train(model, "cmu", options, registry=registry)
        runs[model] = torch.load(out / "last.pt", weights_only=False)
    state = runs["last_angles"]
    assert state["training_data"]["view"] == state["protocol"]["view"] == "expmap"
    angles, joints = state["history"][0], runs["tiny"]["history"][0]
    # validation scores the angles as the joints they make: repeat-last's errors are a joints
    # model's on the same held-out windows, in mm
    np.testing.assert_allclose(
        angles["val_horizons"]["repeat_last"], joints["val_horizons"]["repeat_last"], atol=1e-3
    )
    # two steps moved the offset off zero: the model is no longer repeat-last
    assert angles["val_horizons"]["model"] != angles["val_horizons"]["repeat_last"]


def _small_dmgnn(**changes) -> DMGNN:
    hparams = dict(load_registry().get("dmgnn").hparams)
    hparams.update(widths=[8, 8, 8, 8], hidden=8, cross_width=8, **changes)
    return DMGNN(input_frames=12, output_frames=4, num_points=38, **hparams)


def test_dmgnn_has_the_public_codes_parameters():
    # 62,643,859: the public code's Model(config/CMU/long/train.yaml), counted by
    # benchmarks/speed/public_dmgnn.py from a copy outside this repository
    model = zoo.create_model("dmgnn", benchmark="cmu50")
    assert sum(p.numel() for p in model.parameters()) == 62_643_859
    assert (model.input_frames, model.output_frames, model.num_points) == (50, 25, 38)


def test_dmgnn_graph_kernels_split_the_column_normalised_adjacency():
    self_part, neighbours = _graph_kernels(3, [(0, 1), (1, 2)]).numpy()
    np.testing.assert_allclose(np.diag(self_part), [1 / 2, 1 / 3, 1 / 2])
    expected = np.array([[0, 1 / 3, 0], [1 / 2, 0, 1 / 2], [0, 1 / 3, 0]])
    np.testing.assert_allclose(neighbours, expected)
    np.testing.assert_allclose((self_part + neighbours).sum(0), 1.0)


def test_dmgnn_predicts_its_joints_and_leaves_the_rest_at_the_training_mean():
    torch.manual_seed(0)
    model = _small_dmgnn()
    frames = torch.randn(40, 38, 3) * torch.linspace(0, 1, 38)[:, None]
    frames[:, 7] = 0.25  # a still joint: its std is below the floor and set to 1
    model.set_statistics([(frames[:25], None), (frames[25:], None)])
    flat = frames.reshape(40, -1).double()
    np.testing.assert_allclose(model.mean, flat.mean(0), atol=1e-6)
    expected_std = flat.std(0, unbiased=False)
    expected_std[expected_std < 1e-4] = 1.0
    np.testing.assert_allclose(model.std, expected_std, atol=1e-6)
    model.eval()
    pred = model(frames[None, :12].expand(2, -1, -1, -1))
    assert pred.shape == (2, 4, 38, 3)
    mean = model.mean.view(38, 3)
    unpredicted = [j for j in range(38) if j not in model.channels[::3] // 3]
    assert torch.equal(pred[:, :, unpredicted], mean[unpredicted].expand(2, 4, -1, -1))
    static = torch.nonzero(model.mask == 0)  # (joint of the 26, coordinate)
    joints = model.channels.view(-1, 3)[:, 0] // 3
    for j, c in static.tolist():
        assert torch.equal(pred[:, :, joints[j], c], mean[joints[j], c].expand(2, 4))


def test_dmgnn_trains_from_its_loss_and_reads_accelerations_as_the_code_does():
    torch.manual_seed(0)
    model = _small_dmgnn()
    frames = torch.randn(3, 16, 38, 3).cumsum(1) * 0.05
    model.set_statistics([(frames.reshape(-1, 38, 3), None)])
    loss = model.training_loss(frames[:, :12], frames[:, 12:])
    loss.backward()
    assert torch.isfinite(loss) and model.linear.weight.grad.abs().sum() > 0
    # the code's loss: each future frame's mean error, the later frames counted twice
    model.eval()
    with torch.no_grad():
        error = model.network(model.standardised(frames[:, :12]), 4) - model.standardised(
            frames[:, 12:]
        ).view(3, 4, -1, 3)
        per_frame = error.abs().mean(dim=(0, 2, 3))
        model.late_from = 2  # of the 4 frames here, as 10 of the code's 25
        weights = torch.tensor([1.0, 1.0, 2.0, 2.0])
        expected = (per_frame * weights).mean()
        assert torch.allclose(model.training_loss(frames[:, :12], frames[:, 12:]), expected)
    # the code's training loop aligns an acceleration with the frame before the change, its
    # test loop with the frame after it
    history = model.standardised(frames[:, :12])
    seen = history[:, :-1]
    v = torch.zeros_like(seen)
    v[:, 1:] = seen[:, 1:] - seen[:, :-1]
    for training, at in ((True, slice(0, -1)), (False, slice(1, None))):
        model.train(training)
        position, velocity, acceleration = model.motion_features(history)
        assert torch.equal(position, seen) and torch.equal(velocity, v)
        expected = torch.zeros_like(v)
        expected[:, at] = v[:, 1:] - v[:, :-1]
        assert torch.equal(acceleration, expected)


def test_dmgnn_refuses_groups_that_do_not_fit_its_joints():
    with pytest.raises(ValueError, match="part_back must name a group for each of the 26"):
        _small_dmgnn(part_back=[0] * 25)
    with pytest.raises(ValueError, match=r"joints must hold integers in \[0, 38\)"):
        _small_dmgnn(joints=[40] * 26)
