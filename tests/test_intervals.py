"""Per-window errors, block-bootstrap intervals, paired comparisons and the headline table."""

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import write_cmu_file

from zoo import create_model
from zoo.benchmark import get_benchmark
from zoo.cli import main
from zoo.compare import ComparisonError, compare
from zoo.evaluate import EvalResult, EvaluationError, WindowErrors, evaluate
from zoo.intervals import (
    block_bootstrap,
    naive_interval,
    percentile_interval,
    protocol_mean,
    short_recordings,
)
from zoo.tables import ProtocolMismatchError, headline_table

WINDOW = 35  # CMU: 10 observed + 25 predicted frames


def overlapping_errors(rng, windows_per_action, frames=3, window=WINDOW):
    """Errors of windows that overlap as CMU's ``all`` sampler makes them (stride 1, 35-frame
    windows): each is a moving sum over the window's frames of independent noise, so windows
    ``k`` apart share ``35 - k`` of them. The true protocol mean is known: ``mean(mu)``."""
    errors, sequence, start, action, mu = [], [], [], [], []
    for a, n in enumerate(windows_per_action):
        mu.append(20.0 + 10 * a)
        noise = rng.standard_normal(n + window + frames)
        smooth = np.convolve(noise, np.ones(window) / np.sqrt(window), mode="valid")
        errors.append(
            np.stack([mu[-1] + 5 * smooth[np.arange(n) + t] for t in range(frames)], axis=1)
        )
        sequence += [a] * n
        start += list(range(n))
        action += [f"action{a}"] * n
    return (
        np.concatenate(errors),
        np.array(sequence),
        np.array(start),
        np.array(action),
        float(np.mean(mu)),
    )


def test_block_intervals_cover_the_truth_where_naive_ones_do_not():
    rng = np.random.default_rng(0)
    repetitions, block_covered, naive_covered = 200, [], []
    for r in range(repetitions):
        errors, sequence, start, action, truth = overlapping_errors(rng, [1000] * 5)
        lo, hi = percentile_interval(
            block_bootstrap(errors, sequence, start, action, 2 * WINDOW, 500, seed=r)
        )
        block_covered.append(np.mean((lo <= truth) & (truth <= hi)))
        lo, hi = naive_interval(errors, action)
        naive_covered.append(np.mean((lo <= truth) & (truth <= hi)))
    block, naive = np.mean(block_covered), np.mean(naive_covered)
    print(
        f"95% intervals, {repetitions} repetitions: block bootstrap covers {block:.3f}, "
        f"naive per-window {naive:.3f}"
    )
    assert 0.87 <= block <= 0.99
    assert naive < 0.4


def test_short_recordings_make_intervals_too_narrow():
    """CMU's own test recordings under ``all`` (running: 48 windows, fewer than two blocks):
    coverage falls well short of 95%, which is why tables name such recordings."""
    rng = np.random.default_rng(0)
    covered = []
    for r in range(200):
        errors, sequence, start, action, truth = overlapping_errors(
            rng, [255, 1009, 48, 265, 146, 1343]
        )
        lo, hi = percentile_interval(
            block_bootstrap(errors, sequence, start, action, 2 * WINDOW, 500, seed=r)
        )
        covered.append(np.mean((lo <= truth) & (truth <= hi)))
    print(f"95% block intervals on CMU's window counts cover {np.mean(covered):.3f}")
    assert 0.4 < np.mean(covered) < 0.85
    assert short_recordings(sequence, start, 2 * WINDOW) == [2]


def test_bootstrap_is_seeded_and_averages_as_the_protocol():
    rng = np.random.default_rng(1)
    errors, sequence, start, action, _ = overlapping_errors(rng, [300, 80])
    a = block_bootstrap(errors, sequence, start, action, WINDOW, 200, seed=3)
    assert np.array_equal(a, block_bootstrap(errors, sequence, start, action, WINDOW, 200, seed=3))
    assert not np.array_equal(
        a, block_bootstrap(errors, sequence, start, action, WINDOW, 200, seed=4)
    )
    # unweighted over actions: the short action counts as much as the long one
    expected = (errors[action == "action0"].mean(0) + errors[action == "action1"].mean(0)) / 2
    assert np.allclose(protocol_mean(errors, action), expected)
    # the replicates centre on it
    assert np.allclose(a.mean(0), expected, atol=3 * a.std(0).max() / np.sqrt(200))


def test_one_window_per_recording_is_the_ordinary_bootstrap():
    rng = np.random.default_rng(2)
    n = 400
    errors = rng.normal(10.0, 2.0, size=(n, 1))
    replicates = block_bootstrap(
        errors, np.arange(n), np.zeros(n, int), np.array(["a"] * n), WINDOW, 4000, seed=0
    )
    assert replicates.std() == pytest.approx(errors.std() / np.sqrt(n), rel=0.08)
    assert short_recordings(np.arange(n), np.zeros(n, int), WINDOW) == []


def test_short_recordings_are_named_and_constant_errors_have_no_width():
    sequence = np.array([0] * 40 + [1] * 500)
    start = np.concatenate([np.arange(40), np.arange(500)])
    assert short_recordings(sequence, start, 2 * WINDOW) == [0]
    lo, hi = percentile_interval(
        block_bootstrap(np.ones((540, 2)), sequence, start, np.array(["a"] * 540), WINDOW, 100)
    )
    assert np.allclose(lo, 1.0) and np.allclose(hi, 1.0)


@pytest.fixture
def cmu_root(tmp_path):
    for action, speed in (("walking", 0.01), ("running", 0.03)):
        write_cmu_file(
            tmp_path / "cmu" / "test" / action / f"{action}_1.txt",
            speed * np.sin(np.arange(400) / 15.0),
        )
    return tmp_path / "cmu"


class Offset(torch.nn.Module):
    """Repeat-last plus a constant offset (mm) on every coordinate: a model strictly worse."""

    def __init__(self, offset):
        super().__init__()
        self.offset = offset

    def forward(self, history):
        return history[:, -1:].expand(-1, 25, -1, -1) + self.offset


def evaluated(root, model, label, sampler="all"):
    bench = get_benchmark("cmu")
    return evaluate(model, bench, model_name=label, sampler=sampler, data_root=root)


def test_per_window_errors_are_written_and_average_to_the_table(cmu_root, tmp_path):
    result = evaluated(cmu_root, create_model("repeat_last", benchmark="cmu"), "repeat_last")
    result.write(tmp_path / "out")
    back = EvalResult.read(tmp_path / "out")
    windows = back.windows
    assert windows.protocol_id == back.protocol["protocol_id"]
    assert windows.sequences == ["test/running/running_1.txt", "test/walking/walking_1.txt"]
    assert len(windows.start) == sum(back.protocol["windows_per_action"].values())
    frame = back.frame
    for joints in ("all38", "used25"):
        errors = windows.get("repeat_last", "mpjpe", joints)
        table = (
            frame[
                (frame.action == "average")
                & (frame.averaging == "frame")
                & (frame.joints == joints)
            ]
            .sort_values("frame")["value"]
            .to_numpy()
        )
        assert np.allclose(protocol_mean(errors, windows.action), table, rtol=1e-6)
    with pytest.raises(EvaluationError, match="no per-window errors for model 'x'"):
        windows.get("x", "mpjpe", "all38")
    (tmp_path / "out" / "windows.npz").write_bytes(b"not a zip")
    with pytest.raises(EvaluationError, match="windows.npz: not a readable per-window error"):
        EvalResult.read(tmp_path / "out")


def test_compare_finds_the_worse_model_and_refuses_other_protocols(cmu_root, tmp_path):
    base = evaluated(cmu_root, create_model("repeat_last", benchmark="cmu"), "repeat_last")
    worse = evaluated(cmu_root, Offset(torch.tensor(3.0)), "offset3")
    same = evaluated(cmu_root, Offset(torch.tensor(0.0)), "offset0")
    c = compare(worse, base)
    assert c.joints == "all38" and c.metric == "mpjpe" and c.block_frames == 70
    assert (c.table["verdict"] == "b").all() and (c.table["lo"] > 0).all()
    assert c.sentences()[0].startswith("repeat_last is better than offset3 at 80 ms by ")
    c = compare(same, base)
    assert (c.table["verdict"] == "none").all()
    assert c.sentences()[-1].startswith("no difference detectable at 1000 ms")
    c.write(tmp_path / "cmp")
    assert "horizon (ms) |" in (tmp_path / "cmp" / "comparison.md").read_text()
    assert (tmp_path / "cmp" / "comparison.png").stat().st_size > 0
    other = evaluated(
        cmu_root, create_model("repeat_last", benchmark="cmu"), "repeat_last", sampler="ltd8"
    )
    with pytest.raises(
        ProtocolMismatchError, match="refusing to compare offset3 and repeat_last: .*sampler"
    ):
        compare(worse, other)
    with pytest.raises(ComparisonError, match="both results are of model"):
        compare(base, base)
    with pytest.raises(ComparisonError, match="horizons \\[90\\] ms are not predicted frames"):
        compare(worse, base, horizons_ms=[90])


def synthetic_result(label, errors, sequence, start, action):
    """An evaluation result of ``errors (W, 25)`` as the evaluator would write it."""
    protocol = {
        "benchmark": "synthetic",
        "dataset": "synthetic",
        "split": "test",
        "sampler": "all",
        "fps": 25.0,
        "input_frames": 10,
        "output_frames": 25,
        "joint_protocols": {"all38": "official"},
        "actions_present": sorted(set(action)),
        "action_averaging": "unweighted",
        "protocol_id": "p0",
    }
    mean = protocol_mean(errors, action)
    frame = pd.DataFrame(
        {
            "model": label,
            "benchmark": "synthetic",
            "action": "average",
            "metric": "mpjpe",
            "averaging": "frame",
            "joints": "all38",
            "horizon_ms": 40 * np.arange(1, 26),
            "frame": np.arange(1, 26),
            "value": mean,
            "protocol_id": "p0",
        }
    )
    windows = WindowErrors(
        sequences=[f"rec{i}" for i in range(sequence.max() + 1)],
        sequence=sequence,
        start=start,
        action=action,
        errors={(label, "mpjpe", "all38"): errors.astype(np.float32)},
        protocol_id="p0",
        window_frames=WINDOW,
    )
    return EvalResult(frame=frame, protocol=protocol, windows=windows)


def test_headline_table_marks_models_not_distinguishable_from_the_best():
    rng = np.random.default_rng(5)
    errors, sequence, start, action, _ = overlapping_errors(rng, [600, 600], frames=25)
    noise = overlapping_errors(rng, [600, 600], frames=25)[0] - 25.0  # zero-mean, overlapping
    results = [
        synthetic_result("best", errors, sequence, start, action),
        synthetic_result("noisy_twin", errors + 0.3 * noise, sequence, start, action),
        synthetic_result("worse", errors + 5.0, sequence, start, action),
    ]
    text = headline_table(results, [80, 400, 1000])
    rows = {
        line.split("|")[1].strip(): line
        for line in text.splitlines()
        if line.startswith("| ") and "model" not in line
    }
    assert rows["best"].count("**") == 6 and rows["noisy_twin"].count("**") == 6
    assert "**" not in rows["worse"] and " ±" in rows["worse"]
    assert "circular blocks of 70 frames" in text
    # without per-window errors: values only, the best in bold
    bare = [EvalResult(frame=r.frame, protocol=r.protocol) for r in results]
    text = headline_table(bare, [80])
    assert "no per-window errors stored" in text and "±" not in text.split("\n", 3)[-1]


def test_cli_compare_reads_result_folders(cmu_root, tmp_path, capsys):
    assert (
        main(
            [
                "eval",
                "--model",
                "repeat_last",
                "--data-root",
                str(cmu_root),
                "--sampler",
                "all",
                "--out",
                str(tmp_path / "res" / "cmu" / "all" / "repeat_last"),
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "eval",
                "--model",
                "mlp",
                "--data-root",
                str(cmu_root),
                "--sampler",
                "all",
                "--out",
                str(tmp_path / "res" / "cmu" / "all" / "mlp"),
            ]
        )
        == 0
    )
    capsys.readouterr()
    assert (
        main(
            [
                "compare",
                "mlp",
                "repeat_last",
                "--benchmark",
                "cmu",
                "--sampler",
                "all",
                "--results",
                str(tmp_path / "res"),
                "--replicates",
                "200",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "mlp against repeat_last on cmu" in out and "1000 ms" in out
    assert (
        main(
            [
                "compare",
                "mlp",
                "nobody",
                "--benchmark",
                "cmu",
                "--sampler",
                "all",
                "--results",
                str(tmp_path / "res"),
            ]
        )
        == 2
    )
    assert "no result of 'nobody' there" in capsys.readouterr().err
    assert main(["compare", "mlp", "repeat_last", "--results", str(tmp_path / "res")]) == 2
    assert "give --benchmark" in capsys.readouterr().err
