"""The history a row read: a benchmark that gives more observed frames than a model was trained
on (cmu50 takes cmu's weights) feeds it the last frames it reads, and every row says how many it
read, and whether its model padded them."""

from __future__ import annotations

import pytest
import torch
import yaml

import zoo
from zoo.core.errors import BenchmarkError, EvaluationError
from zoo.evaluation.evaluator import Scored
from zoo.paths import REPO_ROOT
from zoo.protocol.benchmark import get_benchmark
from zoo.report.tables import HISTORY_HEADER, headline_table, history_cells, table_summary

MLP = REPO_ROOT / "weights" / "cmu" / "mlp.safetensors"


def test_cmu50_scores_cmu_weights_on_the_last_ten_of_fifty_frames(swinging_cmu):
    root, _ = swinging_cmu
    ten = zoo.evaluate(MLP, "cmu", sampler="ltd8", data_root=root)
    fifty = zoo.evaluate(MLP, "cmu50", sampler="ltd8", data_root=root)
    # ltd8's windows end where cmu's do, and the model reads the same last 10 frames
    keys = ["action", "metric", "averaging", "joints", "horizon_ms"]
    both = ten.frame.merge(fifty.frame, on=keys)
    assert len(both) == len(ten.frame) > 0
    torch.testing.assert_close(
        torch.tensor(both["value_x"].to_numpy()), torch.tensor(both["value_y"].to_numpy())
    )
    assert fifty.protocol["input_frames"] == 50
    assert fifty.protocol["provenance"]["history"] == {"given": 50, "read": 10}
    assert "history" not in ten.protocol["provenance"]  # all it was given, as given
    assert fifty.protocol["protocol_id"] != ten.protocol["protocol_id"]

    # the table shows what each row read, beside a row that read all 50
    still = zoo.evaluate("repeat_last", "cmu50", sampler="ltd8", data_root=root)
    assert history_cells([fifty, still]) == {
        None: "all 50",
        "mlp": "last 10 of 50",
        "repeat_last": "all 50",
    }
    table = headline_table([fifty, still])
    assert HISTORY_HEADER in table and "last 10 of 50" in table
    # and the site reads it from the table's summary
    (view, *_) = table_summary([fifty, still])["views"]
    assert {row["model"]: row["history"] for row in view["models"]} == {
        "mlp": "last 10 of 50",
        "repeat_last": "all 50",
    }
    # a table whose rows all read every frame they were given has no such column
    assert HISTORY_HEADER not in headline_table([ten])


def test_a_model_reading_more_frames_than_given_is_refused_and_padding_is_recorded():
    model = torch.nn.Identity()
    with pytest.raises(EvaluationError, match="model 'long' reads 60 observed frames; .* gives 50"):
        Scored(model, "long", "joints", history_frames=60).history(torch.zeros(2, 50, 3, 3))
    observed = torch.arange(50.0).view(1, 50, 1, 1)
    assert Scored(model, "m", "joints", history_frames=10).history(observed)[0, 0, 0, 0] == 40
    padded = Scored(model, "tfan", "joints", history_frames=10, padded_to=50)
    assert padded.history_record(10) == {"history": {"given": 10, "read": 10, "padded_to": 50}}
    assert Scored(model, "m", "joints", history_frames=10).history_record(10) == {}


def test_weights_from_a_benchmark_with_a_longer_history_is_refused(tmp_path):
    assert get_benchmark("cmu50").weights_from == "cmu"
    spec = yaml.safe_load(get_benchmark("cmu50").source.read_text())
    path = tmp_path / "cmu5.yaml"
    path.write_text(yaml.safe_dump({**spec, "name": "cmu5", "input_frames": 5}))
    with pytest.raises(BenchmarkError, match="input_frames 5 here, 10 there"):
        get_benchmark(path)
