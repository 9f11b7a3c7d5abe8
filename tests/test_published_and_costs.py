"""Published figures beside measured rows (never mixed), and the cost columns."""

import pytest
import torch

from zoo.leaderboard.efficiency import forward_gflop, measure
from zoo.protocol.published import PublishedError, load_published, place


def cmu_record(
    sampler="all", actions=("basketball", "jumping", "running", "soccer", "walking", "washwindow")
):
    return {
        "benchmark": "cmu",
        "dataset": "cmu_mocap",
        "split": "test",
        "sampler": sampler,
        "input_frames": 10,
        "output_frames": 25,
        "fps": 25.0,
        "actions_present": list(actions),
    }


def test_reported_rows_only_where_the_protocol_matches():
    placed = {p.entry.label: p for p in place(cmu_record(), "mpjpe", "frame", "all38")}
    spgsn = placed["spgsn (reported)"]
    assert spgsn.differences == []
    # the paper's per-action figures, averaged over the 6 actions present here
    assert spgsn.values[80] == pytest.approx((10.24 + 14.93 + 10.75 + 10.86 + 6.32 + 4.86) / 6)
    assert sorted(spgsn.values) == [80, 160, 320, 400, 1000]
    assert "8 standard CMU test actions" in placed["spgsn (reported, 8 actions)"].differences[0]
    other = {p.entry.label: p for p in place(cmu_record("ltd8"), "mpjpe", "frame", "all38")}
    assert other["spgsn (reported)"].differences == ["sampler: 'all' published, 'ltd8' here"]
    cumulative = place(cmu_record(), "mpjpe", "cumulative", "all38")[0]
    assert cumulative.differences == ["averaging: frame published, cumulative here"]
    fewer = place(cmu_record(actions=("walking", "directing")), "mpjpe", "frame", "all38")[0]
    assert fewer.differences == ["no published figure for directing"] and fewer.values == {}
    assert place({"benchmark": "h36m"}, "mpjpe", "frame", "all32") == []


def test_published_file_errors_name_the_entry(tmp_path):
    bad = tmp_path / "published.yaml"
    bad.write_text(
        "- {label: x, model: m, source: s, benchmark: cmu, metric: mpjpe, "
        "averaging: frame, joints: all38, protocol: {}}\n"
    )
    with pytest.raises(PublishedError, match=r"entry 1 \(x\): give exactly one of per_action"):
        load_published(bad)
    bad.write_text(
        "- {label: y, model: m, source: s, benchmark: cmu, metric: mpjpe, "
        "averaging: frame, joints: all38, protocol: {}, average: {80: fast}}\n"
    )
    with pytest.raises(PublishedError, match=r"entry 1 \(y\): figures must map horizons"):
        load_published(bad)
    bad.write_text("- {label: z, metric: mpjpe}\n")
    with pytest.raises(PublishedError, match=r"entry 1 \(z\): missing \['model'"):
        load_published(bad)
    assert {e.benchmark for e in load_published()} == {"cmu", "cmu50", "cloth", "cloth_full"}


class Linear(torch.nn.Module):
    def __init__(self):
        super().__init__()
        self.layer = torch.nn.Linear(10 * 5 * 3, 25 * 5 * 3)

    def forward(self, history):
        return self.layer(history.flatten(1)).reshape(len(history), 25, 5, 3)


def test_costs_count_parameters_flops_and_time():
    model = Linear()
    history = torch.zeros(4, 10, 5, 3)
    assert forward_gflop(model, history) == pytest.approx(2 * 150 * 375 / 1e9)
    row = measure(
        model,
        input_frames=10,
        output_frames=25,
        points=5,
        recipe={"batch_size": 8, "grad_clip": 1.0, "precision": "float32"},
    )
    assert row["parameters"] == 150 * 375 + 375
    assert row["latency_ms"] > 0 and row["train_samples_per_s"] > 0
    assert row["device"].startswith("CPU") and "thread" in row["device"]
    # the measured model is left as it was
    before = {k: v.clone() for k, v in model.state_dict().items()}
    measure(model, input_frames=10, output_frames=25, points=5, recipe={"batch_size": 8})
    assert all(torch.equal(before[k], v) for k, v in model.state_dict().items())
    assert (
        measure(model, input_frames=10, output_frames=25, points=5)["train_samples_per_s"] is None
    )
