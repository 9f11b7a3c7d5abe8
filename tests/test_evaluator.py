"""The evaluator on motions whose errors are computed by hand, and its refusals."""

import json

import numpy as np
import pandas as pd
import pytest
from conftest import LEAF_OFFSET, write_cmu_file

import zoo
from zoo import create_model
from zoo.cli import main
from zoo.evaluation.evaluator import EvaluationError
from zoo.evaluation.markdown import markdown_tables
from zoo.protocol.benchmark import get_benchmark
from zoo.protocol.comparable import ProtocolMismatchError
from zoo.protocol.metrics import cumulative_mean


def expected_repeat_last(omega, t):
    # After halving, joint 5 turns 2*omega per frame; joint 6 sits LEAF_OFFSET from it, so after
    # t frames it has moved along a chord of 2 L sin(angle / 2). Only joint 6 moves.
    return 2 * LEAF_OFFSET * np.sin(2 * omega * t / 2)


@pytest.mark.parametrize("sampler", ["ltd8", "all"])
def test_repeat_last_by_hand(swinging_cmu, sampler):
    root, omega = swinging_cmu
    bench = get_benchmark("cmu")
    df = zoo.evaluate(
        create_model("repeat_last", benchmark=bench),
        bench,
        label="repeat_last",
        sampler=sampler,
        data_root=root,
    ).frame
    t = np.arange(1, 26)
    chord = expected_repeat_last(omega, t)
    for joints, count in (("all38", 38), ("used25", 25)):
        for averaging, values in (
            ("frame", chord / count),
            ("cumulative", np.cumsum(chord / count) / t),
        ):
            for action in ("walking", "average"):
                got = (
                    df[(df.joints == joints) & (df.averaging == averaging) & (df.action == action)]
                    .sort_values("frame")["value"]
                    .to_numpy()
                )
                np.testing.assert_allclose(got, values, rtol=1e-5)
    assert sorted(df.horizon_ms.unique())[:3] == [40, 80, 120]


def test_cumulative_is_running_mean_of_frame_values():
    per_frame = np.array([[1.0, 3.0, 8.0], [2.0, 2.0, 2.0]])
    np.testing.assert_allclose(cumulative_mean(per_frame), [[1, 2, 4], [2, 2, 2]])


def test_ltd8_windows_do_not_depend_on_t_in(swinging_cmu):
    from zoo.data.windows import window_sampler

    a = window_sampler("ltd8", [100], 10, 25)
    b = window_sampler("ltd8", [100], 50, 25)
    np.testing.assert_array_equal(a[:, 1] + 10, b[:, 1] + 50)  # same first predicted frame


def test_action_average_is_unweighted_over_actions(tmp_path):
    root = tmp_path / "cmu"
    write_cmu_file(root / "test" / "walking" / "walking_1.txt", 0.01 * np.arange(200))
    write_cmu_file(root / "test" / "running" / "running_1.txt", 0.03 * np.arange(400))
    bench = get_benchmark("cmu")
    result = zoo.evaluate(
        create_model("repeat_last", benchmark=bench),
        bench,
        label="rl",
        sampler="all",
        data_root=root,
    )
    df = result.frame[(result.frame.joints == "all38") & (result.frame.averaging == "frame")]
    walk, run, avg = (
        df[df.action == a].sort_values("frame")["value"].to_numpy()
        for a in ("walking", "running", "average")
    )
    np.testing.assert_allclose(avg, (walk + run) / 2)
    assert result.protocol["windows_per_action"] == {
        "running": 200 - 35 + 1,
        "walking": 100 - 35 + 1,
    }
    assert result.protocol["actions_present"] == ["running", "walking"]


def test_rows_of_different_protocols_refuse_to_share_a_table(swinging_cmu):
    root, _ = swinging_cmu
    bench = get_benchmark("cmu")
    model = create_model("repeat_last", benchmark=bench)
    a = zoo.evaluate(model, bench, label="a", sampler="ltd8", data_root=root)
    b = zoo.evaluate(model, bench, label="b", sampler="all", data_root=root)
    frame = pd.concat([a.frame, b.frame])
    records = {r.protocol["protocol_id"]: r.protocol for r in (a, b)}
    with pytest.raises(
        ProtocolMismatchError, match=r"differ in sampler \('(ltd8|all)' vs '(all|ltd8)'\)"
    ):
        markdown_tables(frame, records)
    # Same protocol, different models: one table.
    c = zoo.evaluate(model, bench, label="c", sampler="ltd8", data_root=root)
    text = markdown_tables(
        pd.concat([a.frame, c.frame]), {r.protocol["protocol_id"]: r.protocol for r in (a, c)}
    )
    assert "| a " in text and "| c " in text


def test_model_breaking_the_contract_is_named(swinging_cmu):
    import torch

    class Wrong(torch.nn.Module):
        def forward(self, history):
            return history  # T_in frames instead of T_out

    root, _ = swinging_cmu
    with pytest.raises(EvaluationError, match=r"model 'wrong' returned \(.*10, 25, 3\).*25, 25, 3"):
        zoo.evaluate(Wrong(), "cmu", label="wrong", data_root=root)


def test_cli_contract_writes_results_and_protocol(swinging_cmu, tmp_path):
    root, _ = swinging_cmu
    out = tmp_path / "out"
    assert (
        main(
            [
                "eval",
                "--model",
                "repeat_last",
                "--benchmark",
                "cmu",
                "--sampler",
                "ltd8",
                "--data-root",
                str(root),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    df = pd.read_csv(out / "results.csv")
    for column in [
        "model",
        "benchmark",
        "action",
        "metric",
        "averaging",
        "joints",
        "horizon_ms",
        "value",
    ]:
        assert column in df.columns
    protocol = json.loads((out / "protocol.json").read_text())
    assert protocol["sampler"] == "ltd8" and protocol["input_frames"] == 10
    assert protocol["output_frames"] == 25 and protocol["fps"] == 25
    assert protocol["files"][0]["file"] == "test/walking/walking_1.txt"
    assert len(protocol["files"][0]["sha256"]) == 64
    assert protocol["provenance"]["code_version"]
    assert set(df.protocol_id) == {protocol["protocol_id"]}


@pytest.mark.slow  # out of the README test command's 2 minutes; .ci/run runs it after
def test_two_process_evaluation_equals_one_to_the_last_digit(tmp_path):
    """torchrun splits the windows (every other batch) and gathers every process's errors; the
    sums are then added in one order, so the files are the single process's, byte for byte."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from zoo.evaluation.results import EvalResult

    root = tmp_path / "cmu"
    for action, speed in (("walking", 0.01), ("running", 0.03)):
        write_cmu_file(
            root / "test" / action / f"{action}_1.txt", speed * np.sin(np.arange(500) / 15.0)
        )
    args = [
        "eval",
        "--model",
        "repeat_last",
        "--data-root",
        str(root),
        "--sampler",
        "all",
        "--batch-size",
        "16",
    ]
    assert main([*args, "--out", str(tmp_path / "one")]) == 0
    torchrun = Path(sys.executable).parent / "torchrun"
    proc = subprocess.run(
        [
            str(torchrun),
            "--standalone",
            "--nproc_per_node",
            "2",
            "-m",
            "zoo.cli",
            *args,
            "--out",
            str(tmp_path / "two"),
        ],
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.count("wrote ") == 1  # the first process writes, the other does not
    one, two = (tmp_path / "one" / "results.csv"), (tmp_path / "two" / "results.csv")
    assert one.read_bytes() == two.read_bytes()
    a, b = EvalResult.read(tmp_path / "one").windows, EvalResult.read(tmp_path / "two").windows
    assert a.errors.keys() == b.errors.keys()
    assert all(np.array_equal(a.errors[k], b.errors[k]) for k in a.errors)
    assert np.array_equal(a.start, b.start) and len(a.start) > 3 * 16  # several batches each


def test_processes_score_disjoint_batches_that_cover_every_window():
    from zoo.core.distributed import DistInfo
    from zoo.evaluation.evaluator import _my_batches

    shares = [list(_my_batches(100, 16, DistInfo(rank, 3))) for rank in range(3)]
    assert shares == [[0, 48, 96], [16, 64], [32, 80]]
    assert list(_my_batches(100, 16, DistInfo())) == sorted(sum(shares, []))


def test_result_folders_are_replaced_whole_and_refuse_a_second_writer(
    swinging_cmu, tmp_path, monkeypatch
):
    from zoo.core.io import FolderBusyError, folder_lock
    from zoo.evaluation.results import EvalResult

    root, _ = swinging_cmu
    bench = get_benchmark("cmu")
    result = zoo.evaluate(
        create_model("repeat_last", benchmark=bench),
        bench,
        label="repeat_last",
        sampler="ltd8",
        data_root=root,
    )
    out = tmp_path / "run"
    result.write(out)
    (out / "stale.txt").write_text("from an older run")
    result.write(out)
    assert sorted(p.name for p in out.iterdir()) == [
        "protocol.json",
        "results.csv",
        "tables.md",
        "windows.npz",
    ]
    with folder_lock(out):
        with pytest.raises(FolderBusyError, match="run: another zoo process is writing"):
            result.write(out)
    # interrupted while writing: the old folder stays whole, nothing half-written is left
    before = (out / "results.csv").read_bytes()

    def broken(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("zoo.evaluation.results.atomic_write_json", broken)
    with pytest.raises(KeyboardInterrupt):
        result.write(out)
    assert (out / "results.csv").read_bytes() == before
    assert EvalResult.read(out).windows is not None
    assert [
        p.name
        for p in tmp_path.iterdir()
        if p.name.startswith(".run.") and not p.name.endswith(".lock")
    ] == []


@pytest.mark.parametrize("sampler", ["all", "stride5", "stride5_strict", "ltd8"])
def test_frame_counts_count_the_windows_holding_each_frame(sampler):
    from zoo.data.windows import frame_counts, gather_windows, window_sampler

    lengths = [100, 80, 130]
    index = window_sampler(sampler, lengths, 10, 25)
    frame_ids = [np.arange(n) for n in lengths]
    held = gather_windows([f[:, None] for f in frame_ids], index, 35)  # (W, 35, 1) frame ids
    counts = frame_counts(index, lengths, 35)
    for i, n in enumerate(lengths):
        ids = held[index[:, 0] == i].ravel()
        np.testing.assert_array_equal(counts[i], np.bincount(ids, minlength=n))


def test_frame_counts_name_a_window_past_its_sequence():
    from zoo.data.windows import SamplerError, frame_counts

    with pytest.raises(
        SamplerError,
        match=r"window 1 of sequence 0: frames \[8, 13\) run past "
        r"its 12 frames",
    ):
        frame_counts(np.array([[0, 0], [0, 8]]), [12], 5)
