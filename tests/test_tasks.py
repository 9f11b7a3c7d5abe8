"""The evaluator's tasks (prediction, completion, long-term) as protocol elements."""

import numpy as np
import pytest
import torch
from test_evaluator import expected_repeat_last

import zoo
from zoo import create_model
from zoo.cli import main
from zoo.evaluation.evaluator import EvaluationError, predict
from zoo.models.hooks import ModelContractError
from zoo.protocol.benchmark import get_benchmark


class LastTwoFramesModel(torch.nn.Module):
    """Predicts 2 frames at a time: how the generic long-term loop feeds predictions back."""

    def forward(self, history):
        return history[:, -1:].repeat(1, 2, 1, 1) + 1.0


def test_generic_longterm_loop_feeds_predictions_back():
    history = torch.zeros(1, 3, 2, 3)
    out = predict(LastTwoFramesModel(), history, "longterm", 5)
    assert out.shape == (1, 5, 2, 3)
    np.testing.assert_allclose(out[0, :, 0, 0].numpy(), [1, 1, 2, 2, 3])


class OwnRolloutModel(LastTwoFramesModel):
    """Long horizons by its own rollout (the ``rollout`` hook): the evaluator must use it."""

    def rollout(self, history, frames):
        return torch.full((history.shape[0], frames, *history.shape[2:]), 7.0)


def test_longterm_uses_a_models_own_rollout():
    out = predict(OwnRolloutModel(), torch.zeros(1, 3, 2, 3), "longterm", 5)
    assert out.shape == (1, 5, 2, 3) and bool((out == 7.0).all())


class HalfTrainingViewModel(torch.nn.Module):
    """Defines one method of the training-view hook group only."""

    def forward(self, history):
        return history[:, -1:].repeat(1, 25, 1, 1)

    def training_view(self, frames):
        return frames


def test_evaluator_refuses_half_a_hook_group_once_naming_what_is_missing(swinging_cmu):
    root, _ = swinging_cmu
    with pytest.raises(ModelContractError, match="half.*defines training_view but not"):
        zoo.evaluate(HalfTrainingViewModel(), get_benchmark("cmu"), label="half", data_root=root)


def test_longterm_repeat_last_by_hand(swinging_cmu):
    root, omega = swinging_cmu
    bench = get_benchmark("cmu")
    result = zoo.evaluate(
        create_model("repeat_last", benchmark=bench),
        bench,
        label="rl",
        sampler="all",
        data_root=root,
        task="longterm",
        horizon=40,
    )
    df = result.frame[
        (result.frame.joints == "all38")
        & (result.frame.averaging == "frame")
        & (result.frame.action == "average")
    ].sort_values("frame")
    assert df.horizon_ms.max() == 1600 and set(result.frame.task) == {"longterm"}
    np.testing.assert_allclose(
        df.value, expected_repeat_last(omega, np.arange(1, 41)) / 38, rtol=1e-5
    )
    assert result.protocol["predicted_frames"] == 40
    short = zoo.evaluate(
        create_model("repeat_last", benchmark=bench),
        bench,
        label="rl",
        sampler="all",
        data_root=root,
    )
    assert short.protocol["protocol_id"] != result.protocol["protocol_id"]


def test_task_errors_are_named(swinging_cmu, capsys):
    root, _ = swinging_cmu
    bench = get_benchmark("cmu")
    model = create_model("repeat_last", benchmark=bench)
    with pytest.raises(EvaluationError, match="RepeatLast does no completion"):
        zoo.evaluate(model, bench, label="rl", data_root=root, task="completion")
    with pytest.raises(EvaluationError, match="longterm needs a horizon of more than"):
        zoo.evaluate(model, bench, label="rl", data_root=root, task="longterm")
    assert (
        main(
            [
                "eval",
                "--model",
                "repeat_last",
                "--data-root",
                str(root),
                "--task",
                "longterm",
                "--horizon-frames",
                "20",
            ]
        )
        == 2
    )
    assert "got 20" in capsys.readouterr().err


def test_longterm_tables_and_console_show_every_horizon_and_the_real_output_length(
    swinging_cmu, tmp_path, capsys
):
    root, _ = swinging_cmu
    out = tmp_path / "lt"
    argv = ["eval", "--model", "repeat_last", "--sampler", "all", "--data-root", str(root)]
    assert main([*argv, "--task", "longterm", "--horizon-frames", "50", "--out", str(out)]) == 0
    console = capsys.readouterr().out
    assert all(f"{h} ms" in console for h in (1000, 1200, 1400, 1600, 1800, 2000))
    tables = (out / "tables.md").read_text()
    assert "10 in / 50 out (25 per step, autoregressive)" in tables.splitlines()[0]
    assert "1600 ms" in tables and "2000 ms" in tables
    plain = tmp_path / "plain"
    assert main([*argv, "--out", str(plain)]) == 0
    assert "10 in / 25 out at 25 fps" in (plain / "tables.md").read_text().splitlines()[0]
    assert "1200 ms" not in capsys.readouterr().out
