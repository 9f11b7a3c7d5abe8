"""A paused training committed compactly (float16 weights, Adam moments in 8 bits and
bfloat16) and resumed from it on another machine; precision recorded per epoch and changeable
on resume."""

import importlib.util
import json
import shutil
import time
from pathlib import Path

import pytest
import test_train
import torch
from test_train import run

import zoo
import zoo.hub.weights
from zoo.cli import main
from zoo.core.errors import TrainingError
from zoo.hub.checkpoints import CheckpointError, pause_run, read_checkpoint

setup = test_train.setup  # the tiny CMU data and registry of the training tests


@pytest.fixture
def weights_root(tmp_path, monkeypatch):
    root = tmp_path / "weights"
    monkeypatch.setattr(zoo.hub.weights, "WEIGHTS_DIR", root)
    return root


def test_a_paused_state_is_compact_and_resumes_on_a_new_machine(setup, tmp_path, weights_root):
    run(setup, tmp_path / "full", epochs=3)
    run(setup, tmp_path / "first", epochs=3, stop_after_epoch=2)
    dest = pause_run(tmp_path / "first", root=weights_root)
    assert dest == weights_root / "in_progress" / "cmu" / "tiny"
    last = read_checkpoint(dest / "last.pt")
    assert {t.dtype for t in last["state_dict"].values() if t.is_floating_point()} == {
        torch.float16
    }
    states = list(last["optimizer"]["state"].values())
    assert states and {s["exp_avg_sq"].dtype for s in states} == {torch.bfloat16}
    # the first moments travel as 8-bit blocks; read back, each within its block's step
    stored = torch.load(dest / "last.pt", weights_only=True)["optimizer"]["state"]
    assert {s["exp_avg"]["int8"].dtype for s in stored.values()} == {torch.int8}
    full_state = read_checkpoint(tmp_path / "first" / "last.pt")["optimizer"]["state"]
    for index, state in full_state.items():
        read_back = last["optimizer"]["state"][index]["exp_avg"]
        assert read_back.dtype == torch.float32 and read_back.shape == state["exp_avg"].shape
        bound = state["exp_avg"].abs().max() / 254 + 1e-12
        assert (read_back - state["exp_avg"]).abs().max() <= bound
    summary = json.loads((dest / "state.json").read_text())
    # its best epoch is its last (the tiny model improves every epoch): stored once
    assert summary["best_is_last"] and not (dest / "best.pt").exists()
    assert (summary["epochs_run"], summary["epochs_planned"]) == (2, 3)
    assert [e["precision"] for e in summary["epochs"]] == ["float32", "float32"]
    assert "--resume" in summary["resume"]

    # a new machine: no checkpoints folder, only the committed paused state
    out = tmp_path / "second"
    run(setup, out, epochs=3, resume=True)
    resumed = read_checkpoint(out / "last.pt")
    full = read_checkpoint(tmp_path / "full" / "last.pt")
    assert [h["epoch"] for h in resumed["history"]] == [1, 2, 3]
    assert [h["val_mpjpe"] for h in resumed["history"][:2]] == [
        h["val_mpjpe"] for h in full["history"][:2]
    ]
    # the rounding of the paused weights and moments moves the next epoch by little, not nothing
    for name, weight in full["state_dict"].items():
        assert torch.allclose(resumed["state_dict"][name], weight, rtol=0.05, atol=1e-3), name


def test_pausing_again_replaces_the_state_and_a_tensor_past_float16_stays_float32(
    setup, tmp_path, weights_root
):
    # lr 0: epoch 1 stays the best while epoch 2 is the last, so best.pt is stored
    run(setup, tmp_path / "r", epochs=3, stop_after_epoch=2, max_batches=1, recipe={"lr": 0.0})
    dest = pause_run(tmp_path / "r", root=weights_root)
    first = (dest / "best.pt").read_bytes()
    (dest / "stray.pt").write_bytes(b"from an older pause")
    last = read_checkpoint(tmp_path / "r" / "last.pt")
    name = next(k for k, t in last["state_dict"].items() if t.is_floating_point())
    last["state_dict"][name] = last["state_dict"][name] + 1e5
    torch.save(last, tmp_path / "r" / "last.pt")
    pause_run(tmp_path / "r", root=weights_root)
    assert sorted(p.name for p in dest.iterdir()) == ["best.pt", "last.pt", "state.json"]
    # an unchanged best.pt is stored byte for byte as before: a pause adds no copy to history
    assert (dest / "best.pt").read_bytes() == first
    paused = read_checkpoint(dest / "last.pt")
    assert paused["state_dict"][name].dtype == torch.float32
    assert paused["stored_as"]["weights_kept_float32"] == [name]
    assert zoo.hub.weights.paused_runs(weights_root)[("cmu", "tiny")]["epochs_run"] == 2


def test_precision_may_change_on_resume_and_each_epoch_records_its_own(setup, tmp_path, capsys):
    out = tmp_path / "run"
    run(setup, out, epochs=3, max_batches=2, stop_after_epoch=1)
    run(
        setup, out, epochs=3, max_batches=2, resume=True, stop_after_epoch=2,
        recipe={"precision": "bfloat16"},
    )  # fmt: skip
    # a resume not given the precision keeps the run's, not the registry's, and says so
    capsys.readouterr()
    run(setup, out, epochs=3, max_batches=2, resume=True)
    assert (
        "resuming with the run's precision bfloat16, not the registry's float32 "
        "(--train-set precision=float32 takes it)" in capsys.readouterr().out
    )
    ckpt = read_checkpoint(out / "last.pt")
    assert [h["precision"] for h in ckpt["history"]] == ["float32", "bfloat16", "bfloat16"]
    assert ckpt["recipe_changes"] == [
        {"field": "precision", "from": "float32", "to": "bfloat16", "from_epoch": 2}
    ]


def test_zoo_weights_pause_names_a_missing_run_in_one_line(tmp_path, capsys):
    assert main(["weights", "pause", str(tmp_path / "nothing")]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nothing/last.pt does not exist" in err[0]


def test_a_paused_state_that_is_not_a_checkpoint_is_refused(tmp_path, weights_root):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "last.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="not a motion-zoo checkpoint|truncated"):
        pause_run(tmp_path / "run", root=weights_root)


def test_a_run_past_its_time_limit_begins_no_epoch(setup, tmp_path, capsys):
    run(setup, tmp_path / "late", epochs=2, stop_by=time.time() - 1)
    assert not (tmp_path / "late" / "last.pt").exists()
    assert "stopped before epoch 1: it would end past the time limit" in capsys.readouterr().out


def test_the_gpu_command_resumes_a_paused_state_and_brings_it_back(setup, tmp_path, weights_root):
    """The prepared GPU command, run on the CPU with a tiny budget: packed data, resume from
    the committed paused state, states back in parts, unpacked into weights/in_progress."""
    root, _, reg_file = setup
    script = _gpu_script()
    packed = tmp_path / "cmu_train.tar.xz"
    assert script.main(["pack", "--data-root", str(root), "--out", str(packed)]) == 0
    run(setup, tmp_path / "first", stop_after_epoch=1)
    pause_run(tmp_path / "first", root=weights_root)
    out = tmp_path / "OUT"
    assert (
        script.main(
            [
                "run",
                "--out",
                str(out),
                "--data",
                str(packed),
                "--models",
                "tiny",
                "--device",
                "cpu",
                "--max-batches",
                "2",
                "--minutes",
                "5",
                "--registry",
                str(reg_file),
            ]
        )  # fmt: skip
        == 0
    )
    log = (out / "log.txt").read_text()
    assert "tiny: 2 of 2 epochs" in log and "done in" in log
    parts = sorted((out / "tiny").iterdir())
    assert [p.name for p in parts] == ["state.tar.00", "state.tar.sha256"]
    assert script.main(["unpack", str(out), "--weights-dir", str(weights_root)]) == 0
    summary = zoo.hub.weights.paused_runs(weights_root)[("cmu", "tiny")]
    assert summary["epochs_run"] == 2 and len(summary["epochs"]) == 2
    # a finished model is passed over by the next run (named BENCHMARK/MODEL, as the queue's
    # cmu50 model is)
    out2 = tmp_path / "OUT2"
    script.main(
        ["run", "--out", str(out2), "--data", str(packed), "--models", "cmu/tiny", "--device",
         "cpu", "--registry", str(reg_file)]
    )  # fmt: skip
    assert "tiny: finished (2 epochs); nothing to do" in (out2 / "log.txt").read_text()


def test_unpack_of_a_folder_without_states_or_with_a_part_cut_short_says_so(tmp_path, capsys):
    script = _gpu_script()
    assert script.main(["unpack", str(tmp_path)]) == 1
    assert "no <model>/state.tar.00 to unpack" in capsys.readouterr().err
    state = tmp_path / "state"
    state.mkdir()
    (state / "last.pt").write_bytes(b"x" * 1000)
    parts = script._split_state(state, tmp_path / "OUT" / "tiny")
    assert [p.name for p in parts] == ["state.tar.00", "state.tar.sha256"]
    parts[0].write_bytes(parts[0].read_bytes()[:100])  # the device's time ran out mid-write
    assert script.main(["unpack", str(tmp_path / "OUT")]) == 1
    assert "cut short or missing; nothing unpacked" in capsys.readouterr().err


def _gpu_script():
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "gpu" / "train_pending.py"
    spec = importlib.util.spec_from_file_location("train_pending", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_patience_stops_a_run_that_no_longer_improves_and_its_state_says_finished(
    setup, tmp_path, capsys
):
    out = tmp_path / "run"
    # lr 0: the weights never change, so epoch 1 stays the best and patience 2 ends at 3
    run(setup, out, epochs=10, max_batches=1, recipe={"lr": 0.0, "patience": 2})
    ckpt = read_checkpoint(out / "last.pt")
    assert [h["epoch"] for h in ckpt["history"]] == [1, 2, 3]
    assert "stopped after epoch 3: no better validation error for 2 epochs" in (
        capsys.readouterr().out
    )
    from zoo.hub.checkpoints import paused_summary

    assert paused_summary(ckpt)["finished"] is True
    # a resume whose patience is already spent would train nothing: refused, naming the way on
    spent = r"cannot resume with patience 2: .* not improved in the 2 epochs since its best "
    spent += r"\(epoch 1\); --train-set patience=null, or one over 2, continues it"
    with pytest.raises(CheckpointError, match=spent):
        run(setup, out, epochs=10, max_batches=1, resume=True, recipe={"lr": 0.0, "patience": 2})
    assert read_checkpoint(out / "last.pt")["epoch"] == 2  # resuming adds no epoch
    # patience only says when to stop: a resume may lift it, and the run says from when
    # a resume not given the patience keeps the run's 2, not the registry's (none), and says so
    capsys.readouterr()
    with pytest.raises(CheckpointError, match=spent):
        run(setup, out, epochs=10, max_batches=1, resume=True, recipe={"lr": 0.0})
    assert read_checkpoint(out / "last.pt")["epoch"] == 2
    assert (
        "resuming with the run's patience 2, not the registry's null "
        "(--train-set patience=null takes it)" in capsys.readouterr().out
    )
    run(setup, out, epochs=5, max_batches=1, resume=True, recipe={"lr": 0.0, "patience": None})
    # the next resume not given it records no second change, and its command names none
    run(setup, out, epochs=6, max_batches=1, resume=True, recipe={"lr": 0.0})
    ckpt = read_checkpoint(out / "last.pt")
    assert [h["epoch"] for h in ckpt["history"]] == [1, 2, 3, 4, 5, 6]
    assert [c for c in ckpt["recipe_changes"] if c["field"] == "patience"] == [
        {"field": "patience", "from": 2, "to": None, "from_epoch": 4}
    ]
    assert "--train-set" not in paused_summary(ckpt)["resume"]
    with pytest.raises(
        TrainingError, match="field 'patience': input should be greater than or equal to 1, got 0"
    ):
        run(setup, tmp_path / "bad", recipe={"patience": 0})


def test_a_resumed_run_does_not_begin_an_epoch_its_history_here_says_cannot_finish(
    setup, tmp_path, capsys
):
    out = tmp_path / "run"
    run(setup, out, epochs=3, max_batches=2, stop_after_epoch=1)
    last = read_checkpoint(out / "last.pt")
    last["history"][0]["seconds"] = 3600.0  # an epoch of an hour on this very machine
    torch.save(last, out / "last.pt")
    run(setup, out, epochs=3, max_batches=2, resume=True, stop_by=time.time() + 60)
    assert read_checkpoint(out / "last.pt")["epoch"] == 0  # no epoch begun
    assert "stopped before epoch 2" in capsys.readouterr().out
    # the same hour recorded on another machine says nothing of this one
    last["history"][0]["device"] = "NVIDIA H200"
    torch.save(last, out / "last.pt")
    run(setup, out, epochs=2, max_batches=2, resume=True, stop_by=time.time() + 60)
    assert read_checkpoint(out / "last.pt")["epoch"] == 1


def test_the_paused_moments_are_restored_not_reset(setup, tmp_path, weights_root):
    """Resumed from the paused state, the run continues as from the full one, far closer to it
    than a resume whose Adam moments are thrown away."""
    run(setup, tmp_path / "a", epochs=3, stop_after_epoch=1)
    shutil.copytree(tmp_path / "a", tmp_path / "full")
    pause_run(tmp_path / "a", root=weights_root)
    run(setup, tmp_path / "paused", epochs=3, resume=True)  # from weights/in_progress
    fresh = read_checkpoint(tmp_path / "full" / "last.pt")
    fresh["optimizer"]["state"] = {}  # Adam starting again
    shutil.copytree(tmp_path / "full", tmp_path / "reset")
    torch.save(fresh, tmp_path / "reset" / "last.pt")
    run(setup, tmp_path / "reset", epochs=3, resume=True)
    run(setup, tmp_path / "full", epochs=3, resume=True)
    weights = {
        name: read_checkpoint(tmp_path / name / "last.pt")["state_dict"]
        for name in ("full", "paused", "reset")
    }

    def gap(other):
        return max((weights[other][k] - w).abs().max().item() for k, w in weights["full"].items())

    assert gap("paused") < gap("reset") / 5, (gap("paused"), gap("reset"))


def test_a_pilot_paused_with_a_larger_budget_resumes_to_it(setup, tmp_path, weights_root, capsys):
    run(setup, tmp_path / "pilot", epochs=1)  # a one-epoch pilot, finished as it was planned
    with pytest.raises(CheckpointError, match="its budget can only grow"):
        pause_run(tmp_path / "pilot", root=weights_root, epochs=0)
    dest = pause_run(tmp_path / "pilot", root=weights_root, epochs=3)
    summary = json.loads((dest / "state.json").read_text())
    assert (summary["epochs_run"], summary["epochs_planned"], summary["finished"]) == (1, 3, False)
    capsys.readouterr()
    run(setup, tmp_path / "long", resume=True)  # its 3 epochs, not the registry's 2
    assert (
        "resuming with the run's epochs 3, not the registry's 2 (--epochs 2 takes it)"
        in capsys.readouterr().out
    )
    ckpt = read_checkpoint(tmp_path / "long" / "last.pt")
    assert [h["epoch"] for h in ckpt["history"]] == [1, 2, 3]
    assert ckpt["recipe_changes"] == [{"field": "epochs", "from": 1, "to": 3, "from_epoch": 2}]


def test_a_study_run_pauses_under_its_own_name_beside_the_models_queue(
    setup, tmp_path, weights_root
):
    """A run of a study (the bfloat16 study's ltd_bf16_seed0) is paused under its own name, not
    as its model's one queued state, and resumes into the folder of that name."""
    run(setup, tmp_path / "queued", epochs=3, stop_after_epoch=1)
    queued = pause_run(tmp_path / "queued", root=weights_root)
    run(setup, tmp_path / "tiny_study", epochs=3, stop_after_epoch=2, seed=1)
    with pytest.raises(CheckpointError, match="expected a run name other than the model's"):
        pause_run(tmp_path / "tiny_study", root=weights_root, name="tiny")
    dest = pause_run(tmp_path / "tiny_study", root=weights_root, name="tiny_study")
    assert dest == weights_root / "in_progress" / "cmu" / "tiny_study"
    summary = json.loads((dest / "state.json").read_text())
    assert summary["run"] == "tiny_study" and summary["resume"].endswith(
        "--out checkpoints/cmu/tiny_study"
    )
    assert json.loads((queued / "state.json").read_text())["epochs_run"] == 1  # untouched

    out = tmp_path / "elsewhere" / "tiny_study"  # a new machine: resumed from its own state
    run(setup, out, epochs=3, resume=True, seed=1)
    history = read_checkpoint(out / "last.pt")["history"]
    study = read_checkpoint(tmp_path / "tiny_study" / "last.pt")["history"]
    assert [h["epoch"] for h in history] == [1, 2, 3]
    assert [h["val_mpjpe"] for h in history[:2]] == [h["val_mpjpe"] for h in study]


def test_a_best_epoch_that_is_the_last_is_stored_once(setup, tmp_path, weights_root):
    # lr 0 keeps epoch 1 the best: its best.pt differs from the last epoch's
    run(setup, tmp_path / "flat", epochs=3, max_batches=1, stop_after_epoch=2, recipe={"lr": 0.0})
    dest = pause_run(tmp_path / "flat", root=weights_root)
    assert sorted(p.name for p in dest.iterdir()) == ["best.pt", "last.pt", "state.json"]
    assert json.loads((dest / "state.json").read_text())["best_is_last"] is False

    out = tmp_path / "improving"
    run(setup, out, epochs=3, stop_after_epoch=2)
    last = read_checkpoint(out / "last.pt")
    assert last["best"]["epoch"] == 2  # the tiny model improves every epoch here
    dest = pause_run(out, root=weights_root)
    summary = json.loads((dest / "state.json").read_text())
    assert summary["best_is_last"] is True and set(summary["files"]) == {"last.pt"}
    assert sorted(p.name for p in dest.iterdir()) == ["last.pt", "state.json"]
    # a new machine: the resumed run gets both, the best the paused last epoch's weights
    fresh = tmp_path / "fresh"
    # its 2 epochs all run: the resume is refused, once the paused files are in place
    with pytest.raises(CheckpointError, match="already trained 2 epochs"):
        run(setup, fresh, epochs=2, resume=True)
    best = read_checkpoint(fresh / "best.pt")
    paused = read_checkpoint(dest / "last.pt")
    assert best["epoch"] == paused["epoch"] and all(
        torch.equal(best["state_dict"][k], paused["state_dict"][k]) for k in paused["state_dict"]
    )
