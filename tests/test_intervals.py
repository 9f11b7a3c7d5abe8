"""Per-window errors, block-bootstrap intervals, paired comparisons and the headline table."""

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import write_cmu_file

import zoo
from zoo import create_model
from zoo.cli import main
from zoo.evaluation.evaluator import EvaluationError
from zoo.evaluation.results import EvalResult, WindowErrors
from zoo.protocol.benchmark import get_benchmark
from zoo.protocol.comparable import ProtocolMismatchError
from zoo.report.tables import headline_table
from zoo.stats.comparison import ComparisonError, compare
from zoo.stats.intervals import (
    block_replicates,
    coverage_record,
    design,
    naive_interval,
    protocol_mean,
    recording_interval,
    short_recordings,
    sign_test,
    window_sampling_interval,
)

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


@pytest.mark.parametrize("columns", [1, 2, 25])
def test_drawn_blocks_are_summed_in_the_order_a_sum_over_the_draws_adds_them(columns):
    """Block bootstrap sums, added draw by draw, have the bits of numpy's sum over the draws'
    axis, which the committed intervals were computed with: a numpy that adds in another order
    would move their last digits, and fails here first."""
    from zoo.stats.intervals import _drawn_sums

    rng = np.random.default_rng(columns)
    cumsum = np.concatenate([np.zeros((1, columns)), np.cumsum(rng.random((500, columns)), 0)])
    for draws in (2, 9, 40):
        first = rng.integers(0, 440, size=(300, draws))
        take = rng.integers(0, 60, size=(300, draws))
        gathered = (cumsum[first + take] - cumsum[first]).sum(axis=1)
        assert np.array_equal(_drawn_sums(cumsum, first, take), gathered), draws


def test_kept_draws_serve_only_the_windows_and_seed_they_were_drawn_for(monkeypatch):
    """The blocks drawn for a set of windows serve the next model's errors over them; windows
    split into other recordings or started further apart, actions that sort in another order,
    or another seed draw their own, and actions named otherwise but grouped alike share them."""
    from zoo.stats import intervals

    rng = np.random.default_rng(4)
    errors, sequence, start, action, _ = overlapping_errors(rng, [120, 90])
    other = rng.standard_normal(errors.shape) + errors
    split = sequence.copy()
    split[:60] += 10  # the first action's windows in two recordings
    numbers = np.where(action == "action0", 2, 10)  # sorts as the names do
    cases = {
        "base": (sequence, start, action, 0),
        "split": (split, start, action, 0),
        "spaced": (sequence, 3 * start, action, 0),  # a third as many windows to a block
        "text": (sequence, start, numbers.astype(str), 0),  # "10" sorts before "2"
        "seed": (sequence, start, action, 1),
        "numbers": (sequence, start, numbers, 0),  # grouped as base: base's draws
    }

    def replicates(e, windows):
        *arrays, seed = windows
        return block_replicates(e, *arrays, 2 * WINDOW, 200, seed, WINDOW).per_action

    fresh = {}
    for name, windows in cases.items():  # each computed with nothing kept
        monkeypatch.setattr(intervals, "_kept_draws", {})
        fresh[name] = [replicates(e, windows) for e in (errors, other)]
    for name in ("split", "spaced", "text", "seed"):
        assert not np.array_equal(fresh[name][0], fresh["base"][0]), name
    assert all(np.array_equal(a, b) for a, b in zip(fresh["numbers"], fresh["base"]))

    drawn = []
    action_blocks = intervals._action_blocks
    monkeypatch.setattr(
        intervals, "_action_blocks", lambda *a: drawn.append(1) or action_blocks(*a)
    )
    monkeypatch.setattr(intervals, "_kept_draws", {})
    monkeypatch.setattr(intervals, "_KEPT_DRAWS", 5)  # every distinct set of draws here
    for rounds in range(2):  # drawn once (the second model reuses them), then all kept
        for name, windows in cases.items():
            before = len(drawn)
            for e, want in zip((errors, other), fresh[name]):
                assert np.array_equal(replicates(e, windows), want), name
            first_time = rounds == 0 and name != "numbers"
            assert len(drawn) - before == (2 if first_time else 0), (rounds, name)
    assert len(intervals._kept_draws) == intervals._KEPT_DRAWS
    unseeded = [replicates(errors, (sequence, start, action, None)) for _ in range(2)]
    assert not np.array_equal(*unseeded)  # no seed: fresh draws each time, none kept
    # each of the two actions: once per distinct set of windows, and in both unseeded calls
    assert len(drawn) == 2 * (len(cases) - 1) + 2 * 2
    for kept in intervals._kept_draws.values():
        for action in kept:
            assert not any(a.flags.writeable for a in (action.rows, action.first, action.take))


def test_window_sampling_intervals_cover_the_truth_where_naive_ones_do_not():
    rng = np.random.default_rng(0)
    repetitions, block_covered, naive_covered = 200, [], []
    for r in range(repetitions):
        errors, sequence, start, action, truth = overlapping_errors(rng, [1000] * 5)
        i = window_sampling_interval(
            errors, sequence, start, action, 2 * WINDOW, WINDOW, replicates=500, seed=r
        )
        block_covered.append(np.mean((i.lo <= truth) & (truth <= i.hi)))
        lo, hi = naive_interval(errors, action)
        naive_covered.append(np.mean((lo <= truth) & (truth <= hi)))
    block, naive = np.mean(block_covered), np.mean(naive_covered)
    print(
        f"95% intervals, {repetitions} repetitions: studentised block bootstrap covers "
        f"{block:.3f}, naive per-window {naive:.3f}"
    )
    assert 0.90 <= block <= 0.99
    assert naive < 0.4


def _coverage_script():
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "coverage" / "coverage.py"
    spec = importlib.util.spec_from_file_location("coverage_script", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look themselves up there
    spec.loader.exec_module(module)
    return module


def _agrees(measured: float, repetitions: int, recorded: float, recorded_repetitions: int):
    """Two coverage estimates within 3 Monte-Carlo standard errors of their difference."""
    p = (measured + recorded) / 2
    se = np.sqrt(max(p * (1 - p), 0.01) * (1 / repetitions + 1 / recorded_repetitions))
    return abs(measured - recorded) <= 3 * se


@pytest.mark.parametrize("memory", ["short_memory", "long_memory"])
def test_the_coverage_tables_print_is_the_coverage_measured(memory):
    """Tables quote zoo/stats/coverage.yaml; measured again here (fewer repetitions), single and
    paired, on CMU's window counts with short memory and with long memory and heavy tails."""
    script = _coverage_script()
    recorded = coverage_record()["window_sampling"]["synthetic"]
    measured = script.synthetic_coverage(120, memory.split("_")[0], seed=7)
    for kind in ("single", "paired"):
        assert _agrees(measured[kind], 120, recorded[memory][kind], recorded["repetitions"]), (
            memory,
            kind,
            measured,
            recorded[memory],
        )


def test_the_bold_rule_keeps_equally_good_models_bold_at_its_stated_rate():
    script = _coverage_script()
    recorded = coverage_record()["bold"]
    assert recorded["fwe"] <= 0.05 + 2 * np.sqrt(0.05 * 0.95 / recorded["repetitions"])
    measured = script.bold_error(80, seed=3)
    assert _agrees(measured["fwe"], 80, recorded["fwe"], recorded["repetitions"])
    assert measured["fwe_unadjusted"] > 0.2  # the uncorrected rule it replaces


def test_recording_level_intervals_are_t_intervals_over_recordings():
    rng = np.random.default_rng(3)
    # one window per recording: the textbook t interval of the mean
    x = rng.normal(10.0, 2.0, size=(12, 1))
    i = recording_interval(x, np.arange(12), np.array(["a"] * 12))
    from scipy import stats

    half = stats.t.ppf(0.975, 11) * x.std(ddof=1) / np.sqrt(12)
    assert i.kind == "confidence" and i.hi[0] - x.mean() == pytest.approx(half)
    assert design(np.arange(12), np.array(["a"] * 12)).recording_level
    assert not design(np.array([0, 0, 1]), np.array(["a", "a", "b"])).recording_level
    script = _coverage_script()
    recorded = coverage_record()["confidence"]["synthetic"]
    measured = script.recording_coverage(150, 3, seed=5)
    assert _agrees(measured, 150, recorded["3_per_action"], recorded["repetitions"])


def test_recordings_too_short_for_their_blocks_are_named():
    """CMU's running (48 windows, starts spanning 48 frames < 3 window lengths) is named; a
    recording of 1,000 windows, or one of eight windows spread over a long recording (ltd8),
    is not."""
    sequence = np.repeat([0, 1, 2], [48, 1000, 8])
    start = np.concatenate([np.arange(48), np.arange(1000), np.arange(8) * 300])
    assert short_recordings(sequence, start, WINDOW) == [0]


def test_sign_test_is_exact():
    assert sign_test(6, 0) == pytest.approx(2 / 64)
    assert sign_test(5, 1) == pytest.approx(14 / 64)
    assert sign_test(0, 0) == 1.0


def test_bootstrap_is_seeded_and_averages_as_the_protocol():
    rng = np.random.default_rng(1)
    errors, sequence, start, action, _ = overlapping_errors(rng, [300, 80])
    a = block_replicates(errors, sequence, start, action, WINDOW, 200, seed=3).mean
    assert np.array_equal(
        a, block_replicates(errors, sequence, start, action, WINDOW, 200, seed=3).mean
    )
    assert not np.array_equal(
        a, block_replicates(errors, sequence, start, action, WINDOW, 200, seed=4).mean
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
    replicates = block_replicates(
        errors, np.arange(n), np.zeros(n, int), np.array(["a"] * n), WINDOW, 4000, seed=0
    ).mean
    assert replicates.std() == pytest.approx(errors.std() / np.sqrt(n), rel=0.08)


def test_constant_errors_have_no_width():
    sequence = np.array([0] * 40 + [1] * 500)
    start = np.concatenate([np.arange(40), np.arange(500)])
    i = window_sampling_interval(
        np.ones((540, 2)), sequence, start, np.array(["a"] * 540), 2 * WINDOW, WINDOW, 0.95, 100
    )
    assert np.allclose(i.lo, 1.0) and np.allclose(i.hi, 1.0)


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
    return zoo.evaluate(model, bench, label=label, sampler=sampler, data_root=root)


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
    # two actions can never make a sign test significant: lower here, no claim beyond
    assert (c.table["verdict"] == "these recordings").all() and (c.table["lo"] > 0).all()
    assert c.sentences()[0].startswith(
        "repeat_last is lower than offset3 at 80 ms on these recordings by "
    )
    assert "lower on 2 of 2 actions, sign test p = 0.5" in c.sentences()[0]
    assert "too few actions agree" in c.sentences()[0]
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
    # the lowest in bold; not distinguishable from it in italics, a mark of its own
    cells = {m: [c.strip() for c in line.strip("|").split("|")][1:4] for m, line in rows.items()}
    lowest = [c.startswith("**") for c in cells["best"]]
    twin = [c.startswith("**") for c in cells["noisy_twin"]]
    assert [a != b for a, b in zip(lowest, twin)] == [True] * 3  # one of the two is the lowest
    for low, other in zip(cells["best"], cells["noisy_twin"]):
        tied = other if low.startswith("**") else low
        assert tied.startswith("*") and not tied.startswith("**") and tied.endswith("*")
    assert "*" not in rows["worse"] and " ±" in rows["worse"]
    assert "**Bold**: the lowest error at that horizon; *italic*: not distinguishable" in text
    # one recording per action: a window-sampling interval, said so, with its measured coverage
    recorded = coverage_record()["window_sampling"]["synthetic"]
    assert "95% window-sampling interval" in text and "blocks of 70 window(s)" in text
    assert "not a confidence interval for the actions" in text
    assert "confidence interval of" not in text
    assert f"{100 * recorded['short_memory']['single']:.0f}% of the time" in text
    assert "simultaneous comparison of the table's 3 models" in text
    # without per-window errors: values only, the best in bold
    bare = [EvalResult(frame=r.frame, protocol=r.protocol) for r in results]
    text = headline_table(bare, [80])
    assert "no per-window errors stored" in text and "±" not in text.split("\n", 3)[-1]


def test_a_table_of_independent_recordings_prints_confidence_intervals():
    rng = np.random.default_rng(6)
    n = 100  # cloth: one window per recording
    errors = rng.normal(30.0, 4.0, size=(n, 25))
    sequence, start, action = np.arange(n), np.zeros(n, int), np.array(["fall"] * n)
    results = [
        synthetic_result("a", errors, sequence, start, action),
        synthetic_result("b", errors + 3.0, sequence, start, action),
    ]
    text = headline_table(results, [80, 1000])
    recorded = coverage_record()["confidence"]["cloth_full"]
    assert "95% confidence interval of the benchmark mean" in text
    assert "100 recordings per action" in text and "window-sampling" not in text
    assert f"Measured coverage: {100 * recorded['single']:.0f}% for a model's mean" in text
    c = compare(results[1], results[0])
    assert (c.table["verdict"] == "b").all() and c.units == "recordings"
    assert c.sentences()[0].startswith("a is better than b at 80 ms by 3.0")
    assert "95% confidence interval" in c.sentences()[0]


def test_compare_claims_better_only_with_the_actions_behind_it():
    """Six actions, one recording each: B lower on all six (sign test p = 0.031) is better;
    lower on five of six by as much on average (p = 0.22) is lower on these recordings."""
    rng = np.random.default_rng(8)
    errors, sequence, start, action, _ = overlapping_errors(rng, [300] * 6, frames=25)
    shift = np.where(action == "action0", -2.0, 4.0)[:, None]
    a = synthetic_result("a", errors + 4.0, sequence, start, action)
    b = synthetic_result("b", errors, sequence, start, action)
    c = compare(a, b)
    assert (c.table["verdict"] == "b").all() and (c.table["a_lower"] == 0).all()
    assert "lower on 6 of 6 actions, sign test p = 0.031" in c.sentences()[0]
    five = synthetic_result("a", errors + shift, sequence, start, action)
    c = compare(five, b)
    assert (c.table["verdict"] == "these recordings").all()
    assert c.sentences()[0].startswith("b is lower than a at 80 ms on these recordings")
    assert "lower on 5 of 6 actions, sign test p = 0.22" in c.sentences()[0]


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
    # against a published figure: its own sampler's table, divided per action
    against = ["compare", "mlp", "ltd (reported, all windows)", "--benchmark", "cmu"]
    assert main([*against, "--results", str(tmp_path / "res")]) == 0
    assert "# mlp against ltd (reported, all windows)" in capsys.readouterr().out
    assert main(["compare", "mlp", "repeat_last", "--actions", "walking"]) == 2
    assert "--actions: only against a published figure" in capsys.readouterr().err


def test_the_coverage_script_runs_at_its_smallest(capsys, tmp_path):
    script = _coverage_script()
    for part in ("synthetic", "bold", "recordings"):
        assert script.main(["--only", part, "--repetitions", "3", "--root", str(tmp_path)]) == 0
    assert "synthetic: " in capsys.readouterr().out
    assert not (tmp_path / "zoo" / "coverage.yaml").exists()  # written only with --write


CMU_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "cmu_mocap"


@pytest.mark.skipif(not CMU_DATA.is_dir(), reason=f"CMU data not found at {CMU_DATA}")
def test_the_real_data_coverage_tables_print_is_measured_again():
    """repeat_last and constant_velocity on CMU's training recordings, pseudo test sets of one
    recording per action: the coverage of the held-out mean that the CMU tables print."""
    script = _coverage_script()
    recorded = coverage_record()["window_sampling"]["cmu_training"]
    measured = script.cmu_coverage(100, CMU_DATA, seed=11)
    assert measured["recordings_per_action"] == recorded["recordings_per_action"]
    for kind in ("repeat_last", "constant_velocity", "paired"):
        for m, r in zip(measured[kind], recorded[kind]):
            assert _agrees(m, 100, r, recorded["sets"]), (kind, measured[kind], recorded[kind])
