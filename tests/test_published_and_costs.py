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


def test_ratio_to_a_published_figure_per_action_and_of_the_means():
    import pandas as pd

    from zoo.evaluation.results import EvalResult
    from zoo.protocol.published import Published
    from zoo.stats.published_ratio import PublishedRatioError, against_published

    measured = {"jumping": {80: 12.0, 1000: 110.0}, "walking": {80: 6.5, 1000: 44.0}}
    rows = [
        {"model": "mine", "action": a, "metric": m, "averaging": "frame", "joints": "all38",
         "horizon_ms": h, "value": v * (1 if m == "mpjpe" else 100)}
        for m in ("mpjpe", "other")
        for a, by_h in measured.items()
        for h, v in by_h.items()
    ]  # fmt: skip
    result = EvalResult(pd.DataFrame(rows), cmu_record(actions=("jumping", "walking")))
    entry = Published(
        label="paper", model="m", source="a table", benchmark="cmu", metric="mpjpe",
        averaging="frame", joints="all38",
        protocol={"dataset": "cmu_mocap", "sampler": "all", "input_frames": 10},
        per_action={"jumping": {80: 10.0, 1000: 100.0}, "walking": {80: 5.0, 1000: 40.0},
                    "soccer": {80: 1.0, 1000: 1.0}},
    )  # fmt: skip
    r = against_published(result, entry)
    assert r.actions == ["jumping", "walking"] and r.horizons_ms == [80, 1000]
    assert r.ratio("walking") == pytest.approx({80: 1.3, 1000: 1.1})
    # the mean divides the means, not the ratios' mean
    assert r.ratio() == pytest.approx({80: 18.5 / 15.0, 1000: 154.0 / 140.0})
    worst = r.worst()
    assert worst[80] == ("walking", pytest.approx(1.3)) and worst[1000][1] == pytest.approx(1.1)
    only = against_published(result, entry, actions=["jumping"])
    assert only.ratio() == pytest.approx({80: 1.2, 1000: 1.1})
    assert "| mean " in r.markdown() and "12.00 / 10.00" in r.markdown()
    with pytest.raises(PublishedRatioError, match=r"actions \['soccer'\]: expected actions"):
        against_published(result, entry, actions=["soccer"])
    ltd8 = EvalResult(result.frame, cmu_record("ltd8", actions=("jumping", "walking")))
    with pytest.raises(PublishedRatioError, match="sampler: 'all' published, 'ltd8' here"):
        against_published(ltd8, entry)
    h36m = EvalResult(result.frame, {**result.protocol, "benchmark": "h36m"})
    with pytest.raises(PublishedRatioError, match="benchmark cmu published, h36m here"):
        against_published(h36m, entry)
    # an action named twice counts once
    assert against_published(result, entry, actions=["walking", "walking"]).actions == ["walking"]
    # a row short of one figure is refused, not averaged over fewer actions
    short = EvalResult(result.frame.drop(index=[0]), result.protocol)
    with pytest.raises(PublishedRatioError, match="mine has no figure for jumping at 80 ms"):
        against_published(short, entry)
    other = EvalResult(result.frame[result.frame["metric"] == "other"], result.protocol)
    with pytest.raises(PublishedRatioError, match="no mpjpe rows with frame averaging"):
        against_published(other, entry)
    average = Published(**{**entry.__dict__, "per_action": None, "average": {80: 1.0}})
    with pytest.raises(PublishedRatioError, match="publishes an average only"):
        against_published(result, average)


def test_a_label_published_on_several_benchmarks_needs_the_benchmark():
    from zoo.stats.published_ratio import PublishedRatioError, published_entry

    with pytest.raises(PublishedRatioError, match=r"published for .*cloth.*: give --benchmark"):
        published_entry("spectrhums (reported)")
    assert published_entry("spectrhums (reported)", "cloth").benchmark == "cloth"
    assert published_entry("spectrhums (reported)", "cmu") is None
    assert published_entry("ltd (reported, all windows)").benchmark == "cmu"


def test_a_mistyped_published_label_is_named_with_the_closest_ones(capsys):
    """zoo compare A B, where B can be no row's label (it has a space) and is no published
    label, names the published labels closest to it, or those of the benchmark."""
    from zoo.cli import main

    assert main(["compare", "ltd", "ltd (reportd, all windows)", "--benchmark", "cmu"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is no published figure's label" in err[0]
    assert "did you mean 'ltd (reported, all windows)'" in err[0]
    assert main(["compare", "ltd", "no such (figure)", "--benchmark", "cmu50"]) == 2
    err = capsys.readouterr().err
    assert "published labels on cmu50: " in err and "'tfan (reported)'" in err
