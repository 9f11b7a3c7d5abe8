"""The protocol-sensitivity table: every model under every protocol, ranks and rank changes."""

import shutil

import numpy as np
import pandas as pd

from zoo.evaluation.results import EvalResult
from zoo.report.outputs import write_leaderboard
from zoo.stats.sensitivity import protocol_sensitivity


def table(folder, sampler, values):
    """A prediction table of ``values {model: value at every horizon}``, frame and cumulative
    averaging (cumulative: half), under ``sampler``."""
    rows = []
    for model, v in values.items():
        for averaging, scale in (("frame", 1.0), ("cumulative", 0.5)):
            for h in (80, 400, 1000):
                rows.append(
                    {
                        "model": model,
                        "benchmark": "toy",
                        "action": "average",
                        "metric": "mpjpe",
                        "averaging": averaging,
                        "joints": "all",
                        "horizon_ms": h,
                        "frame": h // 40,
                        "value": v * scale * h / 1000,
                        "std": np.nan,
                        "protocol_id": sampler,
                    }
                )
    protocol = {
        "benchmark": "toy",
        "dataset": "toy",
        "split": "test",
        "input_frames": 10,
        "output_frames": 25,
        "fps": 25.0,
        "actions_present": ["walk"],
        "action_averaging": "unweighted",
        "sampler": sampler,
        "task": "prediction",
        "joint_protocols": {"all": "every joint"},
        "protocol_id": sampler,
    }
    frame = pd.DataFrame(rows)
    results = [
        EvalResult(
            frame=frame[frame.model == model].reset_index(drop=True),
            protocol={**protocol, "provenance": {"identity": {"label": model}}},
        )
        for model in values
    ]
    for result in results:  # a leaderboard's table: its rows' folders, then its own files
        result.write(folder / sampler / str(result.frame.model.iloc[0]))
    write_leaderboard(results, folder / sampler)


def test_ranks_under_every_protocol_and_the_changes_are_marked(tmp_path):
    table(tmp_path, "all", {"a": 10.0, "b": 12.0, "c": 30.0})
    table(tmp_path, "ltd8", {"a": 13.0, "b": 11.0, "c": 30.0})
    s = protocol_sensitivity(tmp_path)
    assert s.protocols == ["all frame", "all cumulative", "ltd8 frame", "ltd8 cumulative"]
    assert (
        s.ranks.loc["a", ("all frame", 1000)] == 1 and s.ranks.loc["a", ("ltd8 frame", 1000)] == 2
    )
    assert s.changes() == 2 * 2 * 3  # a and b swap under both ltd8 columns at three horizons
    text = s.markdown()
    assert "10.00 (1)" in text
    assert "13.00 (2) ↓" in text and "11.00 (1) ↑" in text and "30.00 (3) ↓" not in text
    assert s.write(tmp_path) and (tmp_path / "sensitivity.png").stat().st_size > 0
    assert not s.write(tmp_path)  # unchanged: not rewritten


def test_the_plot_is_drawn_again_only_when_a_rank_moves(tmp_path, monkeypatch):
    from zoo.stats import sensitivity

    drawn = []
    save = sensitivity.save_figure
    monkeypatch.setattr(
        sensitivity,
        "save_figure",
        lambda fig, path, **kw: drawn.append(path) or save(fig, path, **kw),
    )
    table(tmp_path, "all", {"a": 10.0, "b": 12.0})
    table(tmp_path, "ltd8", {"a": 13.0, "b": 11.0})
    assert protocol_sensitivity(tmp_path).write(tmp_path) and len(drawn) == 1
    png = (tmp_path / "sensitivity.png").read_bytes()
    table(tmp_path, "ltd8", {"a": 14.0, "b": 11.0})  # new values, the same ranks
    assert protocol_sensitivity(tmp_path).write(tmp_path) == [tmp_path / "sensitivity.md"]
    assert len(drawn) == 1
    assert "14.00 (2)" in (tmp_path / "sensitivity.md").read_text()
    assert (tmp_path / "sensitivity.png").read_bytes() == png
    assert not protocol_sensitivity(tmp_path).write(tmp_path) and len(drawn) == 1
    (tmp_path / "sensitivity.png").write_bytes(b"no digest")  # a plot drawn before: drawn again
    assert protocol_sensitivity(tmp_path).write(tmp_path) == [tmp_path / "sensitivity.png"]
    assert len(drawn) == 2
    table(tmp_path, "ltd8", {"a": 9.0, "b": 11.0})  # a rank moves
    assert protocol_sensitivity(tmp_path).write(tmp_path) and len(drawn) == 3
    assert (tmp_path / "sensitivity.png").read_bytes() != png


def test_one_protocol_has_no_sensitivity_table(tmp_path):
    assert protocol_sensitivity(tmp_path) is None


def test_one_model_has_no_sensitivity_table_and_a_stale_one_is_removed(tmp_path):
    """A single model ranks first under every protocol: no table. One left by a rebuild that
    ranked two (a model since dropped) describes rows no longer there: removed."""
    from zoo.stats.sensitivity import update_sensitivity

    table(tmp_path, "all", {"a": 10.0})
    table(tmp_path, "ltd8", {"a": 13.0})
    assert protocol_sensitivity(tmp_path) is None and update_sensitivity(tmp_path) is None
    table(tmp_path, "all", {"a": 10.0, "b": 12.0})
    table(tmp_path, "ltd8", {"a": 13.0, "b": 11.0})
    md, png = tmp_path / "sensitivity.md", tmp_path / "sensitivity.png"
    assert update_sensitivity(tmp_path) == f"wrote {md}, {png}"
    assert update_sensitivity(tmp_path) is None  # unchanged
    for sampler, value in (("all", 10.0), ("ltd8", 13.0)):
        shutil.rmtree(tmp_path / sampler / "b")
        table(tmp_path, sampler, {"a": value})
    said = update_sensitivity(tmp_path)
    assert said.startswith("removed ") and "no longer rank two models" in said
    assert not any((tmp_path / name).exists() for name in ("sensitivity.md", "sensitivity.png"))
