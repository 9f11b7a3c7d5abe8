"""zoo leaderboard --check on a sample of windows, and re-stamping after a code change: what
the check names (an edited value, raised per-window errors, other weights, a changed forward
pass), what it prints, and rows whose identity went stale because code changed."""

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import Pristine, write_cmu_file
from tiny_models import REGISTRY

from zoo.cli import main
from zoo.evaluation.results import WindowErrors
from zoo.leaderboard.verdict import data_hash_of, draw_sample, escape_sentence, verification_record
from zoo.models.registry import Registry
from zoo.train.loop import train
from zoo.train.options import RunOptions

HERE = Path(__file__).resolve().parent


def _train(tmp, root, out, seed=0):
    train(
        "tiny",
        "cmu",
        RunOptions(data_root=root, progress=False, seed=seed, out_dir=out),
        registry=Registry.from_files(HERE.parent / "registry.yaml", tmp / "registry.yaml"),
        recipe_overrides={"epochs": 1},
    )


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """Two actions of CMU (walking, running), a trained tiny model beside repeat_last, and the
    leaderboard built from them; each test works on it as built (:func:`board`)."""

    def build(tmp):
        root = tmp / "cmu"
        for split in ("train", "test"):
            write_cmu_file(root / split / "walking" / "walking_1.txt", 0.01 * np.arange(800))
            write_cmu_file(root / split / "running" / "running_1.txt", 0.03 * np.arange(300))
        (tmp / "registry.yaml").write_text(REGISTRY)
        shutil.copy(HERE / "tiny_models.py", tmp / "tiny_models.py")
        _train(tmp, root, tmp / "checkpoints" / "cmu" / "tiny")
        _train(tmp, root, tmp / "other", seed=1)  # another checkpoint of the same model
        assert main(["leaderboard", "--benchmark", "cmu", *_common(tmp)]) == 0

    return Pristine(tmp_path_factory.mktemp("check") / "board", build)


def _common(tmp):
    return [
        "--registry",
        str(tmp / "registry.yaml"),
        "--data-root",
        str(tmp / "cmu"),
        "--out",
        str(tmp / "results"),
        "--checkpoints",
        str(tmp / "checkpoints"),
        "--weights",
        str(tmp / "weights"),
    ]


@pytest.fixture
def board(built):
    """The built board as it was made."""
    return built.restore()


def _files(folder):
    return {p: p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_draw_sample_gives_every_action_windows_in_proportion():
    actions = np.array(["walking"] * 1000 + ["running"] * 10 + ["jumping"])
    rows = draw_sample(actions, 20, seed=3)
    assert len(rows) == 20 and len(set(rows)) == 20 and (np.diff(rows) > 0).all()
    drawn = dict(zip(*np.unique(actions[rows], return_counts=True)))
    assert drawn == {"jumping": 1, "running": 1, "walking": 18}
    assert np.array_equal(draw_sample(actions, 20, seed=3), rows)  # the seed repeats it
    assert not np.array_equal(draw_sample(actions, 20, seed=4), rows)
    assert np.array_equal(draw_sample(actions, 5000, seed=3), np.arange(len(actions)))
    assert len(draw_sample(actions, 2, seed=0)) == 2  # fewer windows than actions
    assert "(1 - f)^n (f = 1%: 0.53, f = 5%: 0.038, f = 10%: 0.0012)" in escape_sentence(64)


def test_sampled_check_passes_prints_each_table_once_and_says_what_it_can_miss(board, capsys):
    before = _files(board / "results")
    assert main(["leaderboard", "--check", "--seed", "3", *_common(board)]) == 0
    captured = capsys.readouterr()
    out = captured.out.splitlines()
    assert "32 windows a table, every action among them (seed 3;" in captured.err
    ltd8 = [line for line in out if line.startswith("cmu/ltd8:")]
    every = [line for line in out if line.startswith("cmu/all:")]
    assert len(ltd8) == len(every) == 1  # each table once
    assert ltd8[0].startswith("cmu/ltd8: 2 rows on all 16 windows (running 8, walking 8)")
    assert every[0].startswith("cmu/all: 2 rows on 32 of 482 windows (running 8, walking 24)")
    assert ": passed (" in every[0]
    assert any(
        line.startswith(
            "checked 4 leaderboard rows (2 models: repeat_last, tiny) in 2 tables, on 48 of "
            "their 498 windows: largest difference"
        )
        for line in out
    )
    assert f"sample: seed 3 (--seed 3 draws it again); {escape_sentence(32)}" in out
    assert "tolerance: mpjpe: |difference| <= 1.5e-05 x |value| + 0.002 mm" in out[-1]
    assert _files(board / "results") == before  # a check writes nothing

    assert main(["leaderboard", "--check", "--full", *_common(board)]) == 0
    assert "cmu/all: 2 rows on all 482 windows" in capsys.readouterr().out
    assert main(["leaderboard", "--check", "--windows", "0", *_common(board)]) == 2
    assert "--windows 0: expected a positive number" in capsys.readouterr().err
    assert main(["leaderboard", "--check", "--seed", "-1", *_common(board)]) == 2
    assert "--seed -1: expected an integer in 0..2**32-1" in capsys.readouterr().err


def test_a_nan_a_missing_series_or_other_windows_never_agree():
    from zoo.evaluation.tolerance import sample_agreement

    def windows(values, series=("m", "mpjpe", "all")):
        errors = {series: np.array(values, np.float32).reshape(3, 1)}
        return WindowErrors(["a"], np.zeros(3, int), np.arange(3), np.array(["x"] * 3), errors,
                            "p", 2)  # fmt: skip

    rows = np.arange(3)
    assert sample_agreement(windows([1, 2, 3]), windows([1, 2, 3]), rows).same
    assert sample_agreement(windows([1, 2, np.nan]), windows([1, 2, np.nan]), rows).same
    assert not sample_agreement(windows([1, 2, np.nan]), windows([1, 2, 3]), rows).same
    assert not sample_agreement(windows([1, 2, 3]), windows([1, 2, np.nan]), rows).same
    other = windows([1, 2, 3], ("m", "melv", "vertices"))
    assert "other per-window error series" in sample_agreement(other, windows([1, 2, 3]), rows).why
    assert "other windows" in sample_agreement(windows([1, 2, 3]), windows([1, 2, 3]), rows + 2).why


def test_check_names_a_value_edited_in_results_csv(board, capsys):
    row = board / "results" / "cmu" / "all" / "tiny" / "results.csv"
    frame = pd.read_csv(row)
    at = (frame.horizon_ms == 400) & (frame.action == "walking") & (frame.averaging == "frame")
    frame.loc[at & (frame.joints == "all38"), "value"] += 0.01
    frame.to_csv(row, index=False)
    assert main(["leaderboard", "--check", "--seed", "3", *_common(board)]) == 1
    err = capsys.readouterr().err
    assert (
        f"{row}: model=tiny, action=walking, metric=mpjpe, averaging=frame, joints=all38, "
        "horizon_ms=400: value committed" in err
    )
    assert "its windows.npz gives" in err


def test_check_names_one_actions_per_window_errors_raised_by_one_percent(board, capsys):
    path = board / "results" / "cmu" / "all" / "repeat_last" / "windows.npz"
    stored = WindowErrors.read(path)
    walking = stored.action == "walking"  # stored after running's windows
    for key in stored.errors:
        stored.errors[key][walking] *= 1.01
    stored.write(path)
    assert main(["leaderboard", "--check", "--seed", "3", *_common(board)]) == 1
    err = capsys.readouterr().err
    said = f"{path}: repeat_last/mpjpe/used25: per-window errors differ beyond tolerance (window "
    assert said in err
    window = int(err.split(said)[1].split(",")[0])  # the stored position of the worst window
    assert window in draw_sample(stored.action, 32, seed=3) and walking[window]
    assert "action=walking" in err and "its windows.npz gives" in err  # results.csv disagrees


def test_check_names_weights_that_are_not_the_recorded_ones(board, capsys):
    shutil.copy(board / "other" / "best.pt", board / "checkpoints" / "cmu" / "tiny" / "best.pt")
    assert main(["leaderboard", "--check", "--seed", "3", *_common(board)]) == 1
    err = capsys.readouterr().err
    assert "cmu/all: tiny: weights are not the ones it records: trained.sha256" in err
    assert "tiny/mpjpe/used25: per-window errors differ beyond tolerance" in err


def test_check_names_a_forward_pass_changed_by_a_tenth_of_a_percent(board, capsys, monkeypatch):
    from zoo.models.repeat_last import RepeatLast

    forward = RepeatLast.forward
    monkeypatch.setattr(RepeatLast, "forward", lambda self, x: forward(self, x) * 1.001)
    assert main(["leaderboard", "--check", "--seed", "3", *_common(board)]) == 1
    err = capsys.readouterr().err
    assert "repeat_last/mpjpe/used25: per-window errors differ beyond tolerance" in err
    assert "tiny/mpjpe" not in err  # the other row still agrees


def _age_code(results: Path, labels=("repeat_last", "tiny")) -> dict:
    """Make rows look stamped by older code (another evaluator fingerprint), numbers kept."""
    old = {}
    for record in sorted(results.glob("cmu/*/*/protocol.json")):
        if record.parent.name not in labels:
            continue
        data = json.loads(record.read_text())
        identity = data["provenance"]["identity"]
        old[record] = dict(identity["code"])
        identity["code"]["evaluator"] = "0123456789abcdef"
        record.write_text(json.dumps(data))
    return old


def test_a_code_change_that_moves_no_number_re_stamps_rows_on_a_sample(board, capsys):
    results = board / "results"
    current = _age_code(results)
    numbers = {p: b for p, b in _files(results).items() if p.name != "protocol.json"}
    assert main(["leaderboard", "--check", "--seed", "3", *_common(board)]) == 0
    assert "4 rows were stamped by older code" in capsys.readouterr().out
    assert main(["leaderboard", "--benchmark", "cmu", "--seed", "5", *_common(board)]) == 0
    err = capsys.readouterr().err
    assert "verifying cmu/all after a code change: repeat_last, tiny on 32 of 482 windows" in err
    assert "verified on 32 windows" in err and "numbers kept, re-stamped" in err
    assert "cmu: 0 row(s) reused, 4 re-stamped after a code change" in err
    assert {p: b for p, b in _files(results).items() if p.name != "protocol.json"} == numbers
    for record, code in current.items():
        provenance = json.loads(record.read_text())["provenance"]
        assert provenance["identity"]["code"] == code
        (verified,) = provenance["verified"]
        assert verified["after"] == "code change" and verified["seed"] == 5
        assert verified["windows"] == (16 if "ltd8" in str(record) else 32)
        assert verified["code_before"]["evaluator"] == "0123456789abcdef"
        assert verified["code_after"] == code
    assert main(["leaderboard", "--benchmark", "cmu", *_common(board)]) == 0
    assert "cmu: 4 row(s) reused" in capsys.readouterr().err
    assert main(["leaderboard", "--check", "--full", *_common(board)]) == 0
    assert "stamped by older code" not in capsys.readouterr().out


def test_a_row_re_stamped_on_rebuilt_data_records_the_bytes_it_held_on():
    """A generated dataset rebuilt (CMU-on-Anny skinned in float64) re-stamps its rows on a
    sample: the verification records the new bytes, and the check compares the data it builds
    with those, not with the bytes the row was first computed on."""
    from zoo.evaluation.tolerance import Agreement

    code = {"evaluator": "0123456789abcdef", "model": "fedcba9876543210"}
    before = {"code": code}
    after = {"code": {**code, "evaluator": "1111111111111111"}}
    agreed = Agreement(True, 0.25, "")
    record = verification_record(before, after, 32, 5, agreed, data_hash="new")
    assert record["data_hash"] == "new" and record["after"] == "code change"
    assert "data_hash" not in verification_record(before, after, 32, 5, agreed)  # files' data
    row = {"provenance": {"data_hash": "first", "verified": [record]}}
    assert data_hash_of(row) == "new"
    row["provenance"]["verified"].append(verification_record(after, after, 32, 6, agreed))
    assert data_hash_of(row) == "new"  # a later verification on files records none
    assert data_hash_of({"provenance": {"data_hash": "first"}}) == "first"


def test_a_code_change_that_moves_numbers_recomputes_the_row_in_full(board, capsys):
    results = board / "results"
    _age_code(results, labels=("tiny",))
    path = results / "cmu" / "all" / "tiny" / "windows.npz"
    stored = WindowErrors.read(path)
    for key in stored.errors:
        stored.errors[key] *= 1.01  # what the old code computed, say
    stored.write(path)
    assert main(["leaderboard", "--benchmark", "cmu", "--seed", "5", *_common(board)]) == 0
    err = capsys.readouterr().err
    assert "cmu/all: tiny: " in err and "the sample disagrees" in err
    assert "recomputing tiny: code changed; a sample disagreed" in err
    record = json.loads((results / "cmu" / "all" / "tiny" / "protocol.json").read_text())
    assert "verified" not in record["provenance"]  # computed anew, not re-stamped
    assert main(["leaderboard", "--check", "--full", *_common(board)]) == 0


def test_full_recomputes_a_row_stale_because_of_code_instead_of_sampling(board, capsys):
    results = board / "results"
    _age_code(results, labels=("tiny",))
    assert main(["leaderboard", "--benchmark", "cmu", "--full", *_common(board)]) == 0
    err = capsys.readouterr().err
    assert "verifying" not in err
    assert "its files kept, its identity updated" in err
    record = json.loads((results / "cmu" / "all" / "tiny" / "protocol.json").read_text())
    (verified,) = record["provenance"]["verified"]
    assert verified["every_window"] is True and verified["windows"] == 482


def test_a_row_whose_results_csv_is_not_its_windows_is_recomputed_not_re_stamped(board, capsys):
    results = board / "results"
    _age_code(results, labels=("tiny",))
    row = results / "cmu" / "all" / "tiny" / "results.csv"
    frame = pd.read_csv(row)
    frame.loc[frame.action == "walking", "value"] += 0.01
    frame.to_csv(row, index=False)
    assert main(["leaderboard", "--benchmark", "cmu", "--seed", "5", *_common(board)]) == 0
    err = capsys.readouterr().err
    assert "its results.csv is not what its windows.npz gives" in err
    assert "recomputing tiny: code changed; a sample disagreed" in err
    assert main(["leaderboard", "--check", "--full", *_common(board)]) == 0


def _rippled(forward, moved_by: int | None = None):
    """repeat_last with a ripple of 1 mm at a period of 6 µm: a forward pass that turns the
    rounding of its inputs into differences far beyond the a-priori tolerance. ``moved_by``: its
    inputs first moved by that many units in the last place (another CPU's data)."""
    generator = torch.Generator().manual_seed(99)

    def rippled(self, x):
        if moved_by is not None:
            steps = torch.randint(-moved_by, moved_by + 1, x.shape, generator=generator)
            x = (x.double() * (1 + steps.double() * 2.0**-23)).float()
        y = forward(self, x)
        return y + torch.sin(1000.0 * y)

    return rippled


def test_windows_moved_by_rounding_alone_are_held_to_their_measured_sensitivity(
    board, capsys, monkeypatch
):
    """Rows written where the data's last bits differed (inputs moved by 2 units in the last
    place), by a model that amplifies rounding: the a-priori tolerance would name them, their
    measured rounding sensitivity does not; a change well beyond that sensitivity is named."""
    from zoo.models.repeat_last import RepeatLast

    forward = RepeatLast.forward
    monkeypatch.setattr(RepeatLast, "forward", _rippled(forward, moved_by=2))
    recompute = ["leaderboard", "--benchmark", "cmu", "--recompute", "cmu"]
    assert main([*recompute, *_common(board)]) == 0
    monkeypatch.setattr(RepeatLast, "forward", _rippled(forward))
    capsys.readouterr()
    assert main(["leaderboard", "--check", "--seed", "3", *_common(board)]) == 0
    out = capsys.readouterr().out
    said = out.split("per-window value(s) in ")[1]
    held, largest = (
        int(out.split(" per-window value(s)")[0].split()[-1]),
        float(said.split("(up to ")[1].split(" of it)")[0]),
    )
    assert held > 0 and largest > 1  # beyond the a-priori tolerance, within the measured one
    assert "within 8x their measured rounding sensitivity" in out

    # the ripple's rounding sensitivity is some 0.03 mm: 0.5 mm more is named
    _add_to_sampled_windows(board, 0.5)
    assert main(["leaderboard", "--check", "--seed", "3", *_common(board)]) == 1
    err = capsys.readouterr().err
    assert "repeat_last/mpjpe/used25: per-window errors differ beyond tolerance" in err
    assert "or of 8x its measured rounding sensitivity, whichever is larger" in err


def _add_to_sampled_windows(board, mm: float) -> None:
    path = board / "results" / "cmu" / "all" / "repeat_last" / "windows.npz"
    stored = WindowErrors.read(path)
    sample = draw_sample(stored.action, 32, seed=3)
    for key in stored.errors:
        stored.errors[key][sample] += mm
    stored.write(path)


def test_check_names_per_window_errors_moved_by_a_hundredth_of_a_millimetre(board, capsys):
    """A model of ordinary rounding: its measured sensitivity leaves 0.01 mm far outside."""
    _add_to_sampled_windows(board, 0.01)
    assert main(["leaderboard", "--check", "--seed", "3", *_common(board)]) == 1
    err = capsys.readouterr().err
    assert "repeat_last/mpjpe/used25: per-window errors differ beyond tolerance" in err


def test_a_full_check_says_how_often_a_sample_would_have_failed(board, capsys):
    """One window damaged: --full names it and works out, from its per-window differences, the
    share of 2,000 seeds whose sample of 32 holds that window."""
    path = board / "results" / "cmu" / "all" / "repeat_last" / "windows.npz"
    stored = WindowErrors.read(path)
    for key in stored.errors:
        stored.errors[key][100] *= 1.01
    stored.write(path)
    assert main(["leaderboard", "--check", "--full", *_common(board)]) == 1
    out = capsys.readouterr().out
    held = sum(100 in draw_sample(stored.action, 32, seed) for seed in range(2000))
    expected = f"would fail for {held / 2000:.1%} of seeds 0-1999 ({held / 2000:.1%} against"
    assert 0 < held < 2000 and expected in out


def test_check_names_an_edited_recording(board, capsys):
    """A test recording changed after the rows were made: its hash is in the protocol."""
    recording = board / "cmu" / "test" / "walking" / "walking_1.txt"
    lines = recording.read_text().splitlines()
    lines[5] = lines[5].replace("0", "1", 1)
    recording.write_text("\n".join(lines) + "\n")
    assert main(["leaderboard", "--check", "--seed", "3", *_common(board)]) == 1
    out = capsys.readouterr().out
    assert "cmu/all: repeat_last: recorded identity differs: protocol_id: stored" in out


def test_a_checkpoint_of_a_training_here_that_is_no_row_is_not_checked(board, capsys):
    # a model still training: its checkpoint is here, its rows are in no committed table (the
    # tables rebuilt without its rows and without its checkpoint)
    common = _common(board)
    elsewhere = common.index("--checkpoints") + 1
    common[elsewhere] = str(board / "no_checkpoints")
    assert main(["leaderboard", "--benchmark", "cmu", "--drop", "tiny", *common]) == 0
    assert main(["leaderboard", "--check", "--seed", "3", *_common(board)]) == 0
    captured = capsys.readouterr()
    checkpoint = board / "checkpoints" / "cmu" / "tiny" / "best.pt"
    assert f"cmu/ltd8: tiny: not checked (from {checkpoint}, not in the table)" in captured.err
    assert "checked 2 leaderboard rows (1 models: repeat_last)" in captured.out
