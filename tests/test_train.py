"""The training engine: determinism, resume, checkpoints and their refusals, DDP."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import write_cmu_file
from tiny_models import REGISTRY

import zoo.train as train_module
import zoo.train.loop as train_loop
from zoo.cli import main
from zoo.core.errors import TrainingError
from zoo.hub.checkpoints import CheckpointError, load_checkpoint, read_checkpoint, weights_digest
from zoo.models.registry import Registry
from zoo.train.loop import train
from zoo.train.options import RunOptions

HERE = Path(__file__).resolve().parent


def write_setup(folder: Path):
    """Three training files and one test file of CMU walking in ``folder / "cmu"``, and the
    tiny models' registry beside them: :func:`setup_in` of ``folder``."""
    for split, n in (("train", 3), ("test", 1)):
        for i in range(1, n + 1):
            write_cmu_file(
                folder / "cmu" / split / "walking" / f"walking_{i}.txt", 0.01 * i * np.arange(250)
            )
    (folder / "registry.yaml").write_text(REGISTRY)
    shutil.copy(HERE / "tiny_models.py", folder / "tiny_models.py")
    return setup_in(folder)


def setup_in(folder: Path):
    """The data root, registry and registry file :func:`write_setup` wrote in ``folder``."""
    reg_file = folder / "registry.yaml"
    registry = Registry.from_files(Path(__file__).resolve().parents[1] / "registry.yaml", reg_file)
    return folder / "cmu", registry, reg_file


@pytest.fixture
def setup(tmp_path):
    return write_setup(tmp_path)


def run(setup, out, *, epochs=None, recipe=None, overrides=None, **options):
    """``tiny`` trained on the setup's data into ``out`` (``recipe``: recipe overrides,
    ``epochs`` among them; ``options``: :class:`RunOptions`' fields)."""
    root, registry, _ = setup
    recipe = {**(recipe or {}), **({"epochs": epochs} if epochs is not None else {})}
    return train(
        "tiny",
        "cmu",
        RunOptions(data_root=root, out_dir=out, progress=False, **options),
        registry=registry,
        overrides=overrides,
        recipe_overrides=recipe,
    )


def digest(path):
    return weights_digest_of(read_checkpoint(path)["state_dict"])


def weights_digest_of(state):
    m = torch.nn.Module()
    for k, v in state.items():
        m.register_buffer(k.replace(".", "_"), v)
    return weights_digest(m)


def test_seeded_runs_match_and_checkpoint_carries_its_record(setup, tmp_path):
    a = run(setup, tmp_path / "a")
    b = run(setup, tmp_path / "b")
    assert digest(a) == digest(b)
    c = run(setup, tmp_path / "c", seed=1)
    assert digest(a) != digest(c)
    ckpt = read_checkpoint(a)
    assert ckpt["model"] == "tiny" and ckpt["hparams"]["hidden"] == 16
    assert ckpt["protocol"]["input_frames"] == 10 and ckpt["protocol"]["skeleton"] == "cmu38"
    assert [f["file"] for f in ckpt["training_data"]["files"]] == [
        f"train/walking/walking_{i}.txt" for i in (1, 2, 3)
    ]
    assert all(len(f["sha256"]) == 64 for f in ckpt["training_data"]["files"])
    assert ckpt["code_version"] and ckpt["recipe"]["lr"] == 0.001
    assert ckpt["training"]["best"]["val_mpjpe"] > 0
    assert ckpt["training"]["epochs_run"] >= 1


def test_bfloat16_precision_trains_under_autocast_with_float32_weights(
    setup, tmp_path, monkeypatch
):
    monkeypatch.setattr(train_loop, "cpu_has_native_bfloat16", lambda: True)
    plain = run(setup, tmp_path / "fp32")
    mixed = run(setup, tmp_path / "bf16", recipe={"precision": "bfloat16"})
    ckpt = read_checkpoint(mixed)
    assert ckpt["recipe"]["precision"] == "bfloat16"
    assert read_checkpoint(plain)["recipe"]["precision"] == "float32"
    assert all(v.dtype == torch.float32 for v in ckpt["state_dict"].values())
    # The same seed and data: only the forward's bfloat16 products differ.
    assert digest(mixed) != digest(plain)


@pytest.mark.parametrize("native, taken", [(True, "bfloat16"), (False, "float32")])
def test_precision_auto_trains_in_bfloat16_only_where_the_cpu_has_it(
    setup, tmp_path, monkeypatch, native, taken
):
    monkeypatch.setattr(train_loop, "cpu_has_native_bfloat16", lambda: native)
    run_dir = run(setup, tmp_path / "auto", epochs=1, recipe={"precision": "auto"})
    ckpt = read_checkpoint(run_dir)
    # the recipe stays auto (a resume elsewhere takes it again); the epoch says what it took
    assert ckpt["recipe"]["precision"] == "auto"
    assert [epoch["precision"] for epoch in ckpt["history"]] == [taken]
    if native:  # the step ran in it: bfloat16 products round as float32 ones do not
        plain = run(setup, tmp_path / "fp32", epochs=1)
        assert digest(run_dir) != digest(plain)


def test_precision_auto_is_taken_per_device_wherever_a_step_runs():
    """A step run outside zoo train (the speed scripts, the cost columns) takes ``auto`` as a
    run would: float32 on a GPU, bfloat16 only on a CPU that has it."""
    from zoo.train.host import cpu_has_native_bfloat16, precision_on
    from zoo.train.step import forward_precision

    assert precision_on("auto", "cuda") == "float32"
    assert precision_on("auto", "cpu", native=True) == "bfloat16"
    assert precision_on("auto", "cpu", native=False) == "float32"
    assert precision_on("bfloat16", "cpu", native=False) == "bfloat16"
    with forward_precision("auto", "cpu"):
        assert torch.is_autocast_enabled("cpu") is (cpu_has_native_bfloat16() is True)


def test_bfloat16_on_a_cpu_without_native_bfloat16_warns_that_float32_is_faster(
    setup, tmp_path, monkeypatch
):
    monkeypatch.setattr(train_loop, "cpu_has_native_bfloat16", lambda: False)
    with pytest.warns(
        RuntimeWarning,
        match=r"precision bfloat16 on a CPU without native "
        r"bfloat16 .* precision float32 is faster here",
    ):
        run(setup, tmp_path / "bf16", epochs=1, recipe={"precision": "bfloat16"})


def test_native_bfloat16_is_read_from_the_cpu_flags(tmp_path):
    from zoo.train.host import cpu_has_native_bfloat16

    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nflags\t\t: fpu sse avx2 fma\n")
    assert cpu_has_native_bfloat16(info) is False
    info.write_text("processor\t: 0\nflags\t\t: fpu avx2 avx512f avx512_bf16\n")
    assert cpu_has_native_bfloat16(info) is True
    assert cpu_has_native_bfloat16(tmp_path / "missing") is None


def test_the_training_device_names_the_cpu_model_and_its_kernels():
    from zoo.train.host import device_name

    name = device_name("cpu")
    assert name.startswith("CPU ") and torch.backends.cpu.get_cpu_capability() in name
    assert name.endswith(f"{os.cpu_count()} cores")


def test_checkpoint_provenance_names_repository_files_relative_to_it(tmp_path):
    from zoo.hub.checkpoints import checkpoint_provenance
    from zoo.paths import REPO_ROOT

    meta = {"hparams": {"hidden": 16}, "training": {"epochs_run": 3}}
    inside = checkpoint_provenance(REPO_ROOT / "checkpoints" / "cmu" / "mlp" / "best.pt", meta)
    assert inside == {
        "checkpoint": "checkpoints/cmu/mlp/best.pt",
        "hparams": {"hidden": 16},
        "training": {"epochs_run": 3},
    }
    outside = checkpoint_provenance(tmp_path / "best.pt", meta)
    assert outside["checkpoint"] == str((tmp_path / "best.pt").resolve())
    # with the run's budget, where the checkpoint records it (zoo.report.cards.budget_note reads it)
    budget = {"recipe": {"epochs": 50}, "validation": {"training_windows": 9}, "max_batches": 2}
    assert checkpoint_provenance(tmp_path / "best.pt", {**meta, **budget}).items() >= budget.items()


def test_resume_reaches_the_same_weights(setup, tmp_path):
    run(setup, tmp_path / "full", epochs=3)
    run(setup, tmp_path / "cut", epochs=3, stop_after_epoch=1)
    assert read_checkpoint(tmp_path / "cut" / "last.pt")["epoch"] == 0
    run(setup, tmp_path / "cut", epochs=3, resume=True)
    assert weights_digest_of(
        read_checkpoint(tmp_path / "full" / "last.pt")["state_dict"]
    ) == weights_digest_of(read_checkpoint(tmp_path / "cut" / "last.pt")["state_dict"])


def test_nan_loss_names_epoch_and_batch(setup, tmp_path):
    with pytest.raises(TrainingError, match="loss is nan at epoch 1, batch 1"):
        run(setup, tmp_path / "nan", overrides={"poison": True})


def test_trained_checkpoint_evaluates_and_refuses_mismatches(setup, tmp_path, capsys):
    root, registry, reg_file = setup
    best = run(setup, tmp_path / "run")
    out = tmp_path / "eval"
    assert (
        main(
            [
                "eval",
                "--registry",
                str(reg_file),
                "--checkpoint",
                str(best),
                "--data-root",
                str(root),
                "--sampler",
                "all",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert (out / "results.csv").is_file()
    # the fully trained checkpoint gets its own label (and folder), never the early-stopped one's
    assert (
        main(
            [
                "eval",
                "--registry",
                str(reg_file),
                "--checkpoint",
                str(best.parent / "last.pt"),
                "--data-root",
                str(root),
                "--sampler",
                "all",
                "--out",
                str(tmp_path / "last"),
            ]
        )
        == 0
    )
    assert set(pd.read_csv(tmp_path / "last" / "results.csv").model) == {"tiny@last"}
    # another model
    assert (
        main(
            [
                "eval",
                "--registry",
                str(reg_file),
                "--checkpoint",
                str(best),
                "--model",
                "repeat_last",
                "--data-root",
                str(root),
                "--out",
                str(tmp_path / "x"),
            ]
        )
        == 2
    )
    assert "holds model 'tiny'" in capsys.readouterr().err
    # another protocol
    other = tmp_path / "cmu_short.yaml"
    text = (Path(__file__).resolve().parents[1] / "benchmarks" / "cmu.yaml").read_text()
    text = text.replace("data_root: ../../shared/data/cmu_mocap", f"data_root: {root}")
    other.write_text(text.replace("output_frames: 25", "output_frames: 10"))
    with pytest.raises(CheckpointError, match=r"output_frames \(checkpoint 25, benchmark 10\)"):
        load_checkpoint(best, registry=registry, benchmark=other)
    # another skeleton
    h36m = tmp_path / "h36m.yaml"
    h36m.write_text(text.replace("skeleton:CMU", "skeleton:H36M"))
    with pytest.raises(CheckpointError, match=r"skeleton \(checkpoint 'cmu38', benchmark 'h36m32'"):
        load_checkpoint(best, registry=registry, benchmark=h36m)
    # corrupted file
    broken = tmp_path / "broken.pt"
    broken.write_bytes(best.read_bytes()[:200])
    with pytest.raises(CheckpointError, match="broken.pt is empty, truncated or not a motion-zoo"):
        load_checkpoint(broken, registry=registry)
    assert not (tmp_path / "x").exists()


def test_recipe_errors_are_named(setup, tmp_path):
    with pytest.raises(TrainingError, match="unknown field 'lrr' .did you mean 'lr'.."):
        run(setup, tmp_path / "r", recipe={"lrr": 1})
    with pytest.raises(
        TrainingError,
        match="field 'schedule.warmup_steps': input should be greater than or equal to 0",
    ):
        run(
            setup,
            tmp_path / "r",
            recipe={"schedule": {"type": "constant", "warmup_steps": -1}},
        )
    with pytest.raises(
        TrainingError, match="field 'precision': input should be 'float32', 'bfloat16' or 'auto'"
    ):
        run(setup, tmp_path / "r", recipe={"precision": "float16"})
    with pytest.raises(TrainingError, match="nothing to train"):
        train(
            "repeat_last",
            "cmu",
            RunOptions(data_root=setup[0], out_dir=tmp_path),
            registry=setup[1],
        )


@pytest.mark.slow  # out of the README test command's 2 minutes; .ci/run runs it after
def test_two_process_ddp_ends_with_identical_weights(setup, tmp_path):
    root, _, reg_file = setup
    torchrun = Path(sys.executable).parent / "torchrun"
    env = {**os.environ, "ZOO_REGISTRY": str(reg_file), "OMP_NUM_THREADS": "1"}
    out = tmp_path / "ddp"
    proc = subprocess.run(
        [
            str(torchrun),
            "--standalone",
            "--nproc_per_node",
            "2",
            "-m",
            "zoo.cli",
            "train",
            "--model",
            "tiny",
            "--data-root",
            str(root),
            "--out",
            str(out),
            "--epochs",
            "1",
            "--no-progress",
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    digests = [(out / "ranks" / f"rank{r}.sha256").read_text() for r in (0, 1)]
    assert digests[0] == digests[1]
    assert read_checkpoint(out / "best.pt")["world_size"] == 2


def test_learning_rate_schedules():
    from zoo.models.recipe import learning_rate

    step = {"type": "step", "every_epochs": 2, "gamma": 0.96}
    assert [round(learning_rate(step, 1e-3, e, 50), 10) for e in range(5)] == [
        1e-3,
        1e-3,
        9.6e-4,
        9.6e-4,
        9.216e-4,
    ]
    cosine = {"type": "cosine", "min_lr": 1e-6}
    assert learning_rate(cosine, 1e-4, 0, 100) == 1e-4
    assert abs(learning_rate(cosine, 1e-4, 50, 100) - (1e-6 + 0.5 * (1e-4 - 1e-6))) < 1e-15
    multi = {"type": "multistep", "milestones_steps": [30000], "lrs": [3e-4, 1e-5]}
    assert learning_rate(multi, 3e-4, 0, 1, 29999) == 3e-4
    assert learning_rate(multi, 3e-4, 0, 1, 30000) == 1e-5
    # GGMotion's MultiStepLR stepped after each epoch: x 0.88 from the epoch after a milestone
    milestones = {"type": "epoch_milestones", "milestones": [5, 7], "gamma": 0.88}
    rates = [learning_rate(milestones, 3e-4, e, 50) for e in range(9)]
    assert rates == pytest.approx([3e-4] * 5 + [3e-4 * 0.88] * 2 + [3e-4 * 0.88**2] * 2)
    warm = {**cosine, "warmup_steps": 4}
    assert [learning_rate(warm, 1e-4, 0, 100, s) for s in range(5)] == pytest.approx(
        [2.5e-5, 5e-5, 7.5e-5, 1e-4, 1e-4], rel=1e-12
    )


def test_resume_refuses_another_recipe_and_records_a_larger_budget(setup, tmp_path):
    out = tmp_path / "run"
    run(setup, out, epochs=2, max_batches=2)
    for kw, field in (
        ({"seed": 1}, "seed"),
        ({"recipe": {"batch_size": 16}}, "batch_size"),
        ({"recipe": {"lr": 0.5}}, "lr"),
        (
            {"recipe": {"schedule": {"type": "step", "every_epochs": 1, "gamma": 0.9}}},
            "schedule",
        ),
    ):
        with pytest.raises(CheckpointError, match=f"cannot resume with another recipe .*{field}"):
            run(setup, out, epochs=3, max_batches=2, resume=True, **kw)
    with pytest.raises(CheckpointError, match="already trained 2 epochs"):
        run(setup, out, epochs=1, max_batches=2, resume=True)
    run(setup, out, epochs=4, max_batches=3, resume=True)
    # the run's own 4 epochs, not the registry's 2 (a resume keeps its budget): nothing left to
    # train, refused, not a no-op
    with pytest.raises(
        CheckpointError, match=r"with 4 epochs: the run has already trained 4 epochs \(--epochs"
    ):
        run(setup, out, max_batches=3, resume=True)
    ckpt = read_checkpoint(out / "last.pt")
    assert ckpt["recipe"]["epochs"] == 4 and ckpt["max_batches"] == 3
    assert ckpt["recipe_changes"] == [
        {"field": "epochs", "from": 2, "to": 4, "from_epoch": 3},
        {"field": "max_batches", "from": 2, "to": 3, "from_epoch": 3},
    ]
    assert [h["samples"] for h in ckpt["history"]][1:3] == [2 * 8, 3 * 8]
    # changes accumulate over resumes
    run(setup, out, epochs=5, max_batches=3, resume=True)
    assert read_checkpoint(out / "last.pt")["recipe_changes"][-1] == {
        "field": "epochs",
        "from": 4,
        "to": 5,
        "from_epoch": 5,
    }


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"grad_clip": -1}, "field 'grad_clip': input should be greater than 0, got -1"),
        ({"grad_clip": 0}, "field 'grad_clip': input should be greater than 0, got 0"),
        ({"lr": -0.1}, "field 'lr': input should be greater than or equal to 0"),
        ({"lr": "fast"}, "field 'lr': input should be a valid number, got 'fast'"),
        ({"weight_decay": -1e-4}, "field 'weight_decay': input should be greater than or equal"),
        ({"batch_size": 0}, "field 'batch_size': input should be greater than or equal to 1"),
        ({"schedule": {"type": "step", "gamma": 0.9}}, "field 'schedule.every_epochs' is required"),
        (
            {"schedule": {"type": "multistep", "lrs": [1e-3]}},
            "'schedule.milestones_steps' is required",
        ),
        (
            {
                "schedule": {"type": "multistep", "milestones_steps": [5], "lrs": [1e-3, 1e-4]},
                "lr": 0.5,
            },
            "lr 0.5 is not what runs",
        ),
    ],
)
def test_recipe_values_are_checked_before_training(setup, tmp_path, overrides, message):
    with pytest.raises(TrainingError, match=message):
        run(setup, tmp_path / "bad", recipe=overrides)
    assert not (tmp_path / "bad").exists()


def test_zero_epochs_is_an_error_not_the_full_recipe(setup, tmp_path):
    with pytest.raises(
        TrainingError, match="field 'epochs': input should be greater than or equal to 1, got 0"
    ):
        run(setup, tmp_path / "zero", epochs=0)


def test_init_from_starts_a_new_stage_from_those_weights_and_records_them(setup, tmp_path):
    first = run(setup, tmp_path / "a", epochs=1)
    source = read_checkpoint(first)
    # lr 0: the new stage changes nothing, so its weights are exactly the source's
    still = read_checkpoint(
        run(
            setup,
            tmp_path / "b",
            epochs=1,
            init_from=first,
            recipe={"lr": 0.0, "schedule": None},
        )
    )
    for name, tensor in source["state_dict"].items():
        assert torch.equal(still["state_dict"][name], tensor), name
    record = still["init_from"]
    assert record["path"].endswith("a/best.pt") and len(record["sha256"]) == 64
    assert record["training"]["epochs_run"] == 1 and record["recipe"]["lr"] == 0.001
    # a stage of a stage keeps the whole chain
    third = read_checkpoint(
        run(setup, tmp_path / "c", epochs=1, init_from=tmp_path / "b" / "last.pt")
    )
    assert third["init_from"]["init_from"]["sha256"] == record["sha256"]
    assert digest(tmp_path / "c" / "last.pt") != digest(first)


def test_init_from_shipped_weights_extends_a_published_row(setup, tmp_path):
    """Shipped weights (no checkpoint) start a new stage: anyone can extend a committed row's
    training from the repository alone; the record names the file, its kind and dtype."""
    from zoo.hub.checkpoints import export_weights

    first = run(setup, tmp_path / "a", epochs=1)
    shipped = export_weights(first, root=tmp_path / "weights", dtype="float32")
    still = read_checkpoint(
        run(
            setup,
            tmp_path / "b",
            epochs=1,
            init_from=shipped,
            recipe={"lr": 0.0, "schedule": None},
        )
    )
    for name, tensor in read_checkpoint(first)["state_dict"].items():
        assert torch.equal(still["state_dict"][name], tensor), name
    record = still["init_from"]
    assert record["kind"] == "weights" and record["dtype"] == "float32"
    assert record["path"].endswith("tiny.safetensors")
    assert record["training"]["epochs_run"] == 1
    # a damaged file is refused by its sha256 before any training
    data = bytearray(shipped.read_bytes())
    data[-1] ^= 1
    shipped.write_bytes(bytes(data))
    with pytest.raises(Exception, match=r"sha256 .* differs from its record"):
        run(setup, tmp_path / "c", epochs=1, init_from=shipped)
    assert not (tmp_path / "c").exists()


def test_init_from_refusals_name_the_file(setup, tmp_path):
    first = run(setup, tmp_path / "a", epochs=1)
    with pytest.raises(TrainingError, match=r"init_from: .*missing\.pt: no such file"):
        run(setup, tmp_path / "b", init_from=tmp_path / "missing.pt")
    with pytest.raises(TrainingError, match=r"init_from: .*tiny\.safetensors: no such file"):
        run(setup, tmp_path / "b", init_from=tmp_path / "tiny.safetensors")
    (tmp_path / "tiny.npz").write_bytes(b"")
    with pytest.raises(
        TrainingError,
        match=r"init_from: .*tiny\.npz: expected a training "
        r"checkpoint .* or shipped weights",
    ):
        run(setup, tmp_path / "b", init_from=tmp_path / "tiny.npz")
    with pytest.raises(TrainingError, match=r"would overwrite it; give the new stage its own"):
        run(setup, tmp_path / "a", init_from=first)
    with pytest.raises(TrainingError, match=r"not both"):
        run(setup, tmp_path / "b", init_from=first, resume=True)
    with pytest.raises(TrainingError, match=r"do not fit tiny with these hyper-parameters"):
        run(setup, tmp_path / "b", init_from=first, overrides={"hidden": 8})


def test_a_validation_sampler_thins_validation_and_old_checkpoints_resume(setup, tmp_path):
    out = tmp_path / "run"
    run(setup, out, epochs=1, max_batches=2, recipe={"val_sampler": "stride5_strict"})
    ckpt = read_checkpoint(out / "last.pt")
    assert ckpt["recipe"]["val_sampler"] == "stride5_strict"
    with pytest.raises(CheckpointError, match="val_sampler: 'stride5_strict' in the checkpoint"):
        run(setup, out, epochs=2, max_batches=2, resume=True)  # the default is 'all'
    # a checkpoint written before the key existed held the default then, and resumes
    plain_run = tmp_path / "plain"
    run(setup, plain_run, epochs=1, max_batches=2)
    state = read_checkpoint(plain_run / "last.pt")
    del state["recipe"]["val_sampler"]
    torch.save(state, plain_run / "last.pt")
    run(setup, plain_run, epochs=2, max_batches=2, resume=True)


def test_validation_by_recordings_holds_out_whole_recordings_and_records_them(tmp_path):
    root = tmp_path / "cmu"
    for i in range(1, 9):  # eight training recordings; with val_fraction 0.25, every 4th
        write_cmu_file(root / "train" / "walking" / f"walking_{i}.txt", 0.01 * i * np.arange(300))
    write_cmu_file(root / "test" / "walking" / "walking_1.txt", 0.01 * np.arange(300))
    reg_file = tmp_path / "registry.yaml"
    reg_file.write_text(REGISTRY)
    shutil.copy(HERE / "tiny_models.py", tmp_path / "tiny_models.py")
    registry = Registry.from_files(Path(__file__).resolve().parents[1] / "registry.yaml", reg_file)
    assert train_module.held_out_recordings([f"r{i}" for i in range(8)], 0.25) == [2, 6]
    best = train(
        "tiny",
        "cmu",
        RunOptions(data_root=root, out_dir=tmp_path / "run", progress=False),
        registry=registry,
        recipe_overrides={"val_split": "recordings", "val_fraction": 0.25, "epochs": 1},
    )
    validation = read_checkpoint(best)["validation"]
    # every 4th recording in name order, starting half a step in: the 3rd and the 7th
    assert [h.rsplit("/", 1)[-1].removesuffix(".txt") for h in validation["recordings"]] == [
        "walking_3",
        "walking_7",
    ]
    assert validation["split"] == "recordings" and validation["windows"] == 2 * (150 - 35 + 1)
    # auto: these 150-frame recordings cannot spare 10% for a 35-frame window, so the last
    # recording (10% of 8, rounded) is held out whole, and the record names it
    auto = read_checkpoint(run_default(registry, root, tmp_path / "auto", val_split="auto"))
    auto = auto["validation"]
    assert auto["split"] == "auto" and "tails" not in auto
    assert [h.rsplit("/", 1)[-1] for h in auto["recordings"]] == ["walking_8.txt"]
    with pytest.raises(
        TrainingError,
        match="field 'val_split': input should be 'auto', 'tails', 'actions' or 'recordings'",
    ):
        train(
            "tiny",
            "cmu",
            RunOptions(data_root=root, out_dir=tmp_path / "bad", progress=False),
            registry=registry,
            recipe_overrides={"val_split": "shuffled"},
        )


def test_validation_by_tails_takes_the_end_of_long_recordings_and_trains_on_short_ones(tmp_path):
    from zoo.protocol.benchmark import get_benchmark
    from zoo.train.split import held_out_frames, split_train_val

    root = tmp_path / "cmu"
    # frames after halving the rate: 400 (a 10% tail of 40 frames holds a 35-frame window)
    # and 150 (too short: trained on whole); two actions, as on CMU where short recordings of
    # one action (walking) sort last
    write_cmu_file(root / "train" / "basketball" / "basketball_1.txt", 0.01 * np.arange(800))
    for i in (1, 2):
        write_cmu_file(root / "train" / "walking" / f"walking_{i}.txt", 0.01 * np.arange(300))
    write_cmu_file(root / "test" / "walking" / "walking_1.txt", 0.01 * np.arange(300))
    bench = get_benchmark("cmu")
    dataset = bench.load(root, split=bench.train_split)
    lengths = [400, 150, 150]
    assert held_out_frames(dataset, lengths, 0.1, 35, "tails") == {0: 360}
    # auto holds out whole recordings here (some are short): the last one, a walk
    assert held_out_frames(dataset, lengths, 0.1, 35, "auto") == {2: 0}
    kept, held = split_train_val(dataset, 0.1, 35, rule="tails")
    assert [len(a) for a in kept] == [360, 150, 150] and [len(a) for a in held] == [40]
    np.testing.assert_array_equal(
        np.concatenate([kept[0], held[0]]), dataset.sequences[0].positions
    )
    reg_file = tmp_path / "registry.yaml"
    reg_file.write_text(REGISTRY)
    shutil.copy(HERE / "tiny_models.py", tmp_path / "tiny_models.py")
    registry = Registry.from_files(Path(__file__).resolve().parents[1] / "registry.yaml", reg_file)
    best = train(
        "tiny",
        "cmu",
        RunOptions(data_root=root, out_dir=tmp_path / "run", progress=False),
        registry=registry,
        recipe_overrides={"val_split": "tails", "epochs": 1},
    )
    validation = read_checkpoint(best)["validation"]
    assert validation["split"] == "tails" and "recordings" not in validation
    assert validation["tails"]["fraction"] == 0.1
    assert [h.rsplit("/", 1)[-1] for h in validation["tails"]["of"]] == ["basketball_1.txt"]
    assert validation["windows"] == 40 - 35 + 1
    with pytest.raises(TrainingError, match="no recording is long enough.*val_split 'recordings'"):
        held_out_frames(dataset, [150, 150, 150], 0.1, 35, "tails")


def test_validation_by_actions_gives_every_action_windows_and_holds_none_out_whole(tmp_path):
    """``actions``: tails where a recording can spare one; an action with no such recording
    (walking here, as on CMU) gives the last 10% of its frames, at least one window, from the
    end of its longest recording."""
    from zoo.protocol.benchmark import get_benchmark
    from zoo.train.split import held_out_frames

    root = tmp_path / "cmu"
    write_cmu_file(root / "train" / "basketball" / "basketball_1.txt", 0.01 * np.arange(800))
    write_cmu_file(root / "train" / "walking" / "walking_1.txt", 0.01 * np.arange(300))
    write_cmu_file(root / "train" / "walking" / "walking_2.txt", 0.01 * np.arange(300))
    write_cmu_file(root / "train" / "running" / "running_1.txt", 0.01 * np.arange(300))
    bench = get_benchmark("cmu")
    dataset = bench.load(root, split=bench.train_split)
    by_name = {s.name.rsplit("/", 1)[-1]: i for i, s in enumerate(dataset.sequences)}
    basketball, walking_1, walking_2, running = (
        by_name[n] for n in ("basketball_1.txt", "walking_1.txt", "walking_2.txt", "running_1.txt")
    )
    lengths = [0] * 4
    for i, n in ((basketball, 400), (walking_1, 150), (walking_2, 200), (running, 80)):
        lengths[i] = n
    plan = held_out_frames(dataset, lengths, 0.1, 35, "actions")
    # basketball: its 10% tail; walking: 10% of 350 frames is 35 (one window) from walking_2,
    # its longest; running: one recording of 80, which spares a window and keeps one
    assert plan == {basketball: 360, walking_2: 200 - 35, running: 80 - 35}
    assert all(start > 0 for start in plan.values())  # no recording held out whole
    with pytest.raises(TrainingError, match="action 'running'.*60 frames.*val_split 'tails'"):
        lengths[running] = 60
        held_out_frames(dataset, lengths, 0.1, 35, "actions")
    # CMU's own rule (benchmarks/cmu.yaml), for every model whose recipe names none
    (tmp_path / "registry.yaml").write_text(REGISTRY)
    shutil.copy(HERE / "tiny_models.py", tmp_path / "tiny_models.py")
    registry = Registry.from_files(HERE.parent / "registry.yaml", tmp_path / "registry.yaml")
    validation = read_checkpoint(run_default(registry, root, tmp_path / "run"))["validation"]
    assert validation["split"] == "actions" and "recordings" not in validation
    assert [h.rsplit("/", 1)[-1] for h in validation["tails"]["of"]] == [
        "basketball_1.txt",
        "running_1.txt",
        "walking_1.txt",  # as long as walking_2: the first of them
    ]


def run_default(registry, root, out, **recipe):
    return train(
        "tiny",
        "cmu",
        RunOptions(data_root=root, out_dir=out, progress=False),
        registry=registry,
        recipe_overrides={**recipe, "epochs": 1},
    )


def test_a_model_with_part_of_a_hook_group_is_refused_naming_the_rest(setup, tmp_path):
    from zoo.models.hooks import ModelContractError, model_hooks

    (tmp_path / "half.py").write_text(
        "import torch\n"
        "class HalfView(torch.nn.Module):\n"
        "    def __init__(self, input_frames, output_frames, num_points):\n"
        "        super().__init__()\n"
        "        self.w = torch.nn.Parameter(torch.zeros(1))\n"
        "        self.output_frames = output_frames\n"
        "    def forward(self, history):\n"
        "        return history[:, -1:].expand(-1, self.output_frames, -1, -1) + self.w\n"
        "    def training_view(self, frames):\n"
        "        return frames\n"
    )
    (tmp_path / "half.yaml").write_text(
        "models:\n  half:\n    class: half.py:HalfView\n    representation: joints\n"
        "    trainable: true\n"
    )
    root, registry, _ = setup
    registry.add_file(tmp_path / "half.yaml")
    with pytest.raises(
        ModelContractError, match="defines training_view but not training_view_identity"
    ):
        train(
            "half",
            "cmu",
            RunOptions(data_root=root, out_dir=tmp_path / "h", progress=False),
            registry=registry,
        )
    assert not (tmp_path / "h" / "last.pt").exists()  # refused before any training
    assert model_hooks(torch.nn.Linear(2, 2), "plain") == model_hooks(object())  # none at all


def test_a_run_written_with_a_capturable_optimizer_resumes_on_the_cpu(setup, tmp_path):
    """A GPU run replaying CUDA graphs saves Adam capturable, its learning rate a tensor; the
    same run resumed on a CPU continues as if it had been written there."""
    run(setup, tmp_path / "full", epochs=3)
    run(setup, tmp_path / "cut", epochs=3, stop_after_epoch=1)
    last = tmp_path / "cut" / "last.pt"
    state = torch.load(last, weights_only=True)
    for group in state["optimizer"]["param_groups"]:
        group["lr"], group["capturable"] = torch.tensor(group["lr"]), True
    torch.save(state, last)
    run(setup, tmp_path / "cut", epochs=3, resume=True)
    assert weights_digest_of(
        read_checkpoint(tmp_path / "full" / "last.pt")["state_dict"]
    ) == weights_digest_of(read_checkpoint(last)["state_dict"])


def test_learning_rate_is_set_in_place_where_it_is_a_tensor():
    model = torch.nn.Linear(2, 2)
    from zoo.models.recipe import Recipe

    recipe = Recipe(lr=0.01)
    graphed = train_module.make_optimizer(model, recipe, "cpu", graphed=True)
    lr = graphed.param_groups[0]["lr"]
    train_module.set_learning_rate(graphed, 0.5)
    assert graphed.param_groups[0]["lr"] is lr and float(lr) == 0.5
    plain_adam = train_module.make_optimizer(model, recipe, "cpu")
    train_module.set_learning_rate(plain_adam, 0.5)
    assert plain_adam.param_groups[0]["lr"] == 0.5


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_a_cuda_graph_trains_as_the_eager_step_and_resumes_on_the_cpu(setup, tmp_path):
    # capturable Adam computes its bias corrections on the device: on an H200 the weights after
    # 3 epochs differed from the eager step's by up to 1.2e-6 (5.7e-5 relative), losses equal
    # to the printed digits
    eager = run(setup, tmp_path / "eager", device="cuda", cuda_graph=False, epochs=3)
    graph = run(setup, tmp_path / "graph", device="cuda", cuda_graph=True, epochs=3)
    for key, value in read_checkpoint(eager)["state_dict"].items():
        torch.testing.assert_close(
            read_checkpoint(graph)["state_dict"][key], value, rtol=1e-4, atol=1e-5
        )
    assert read_checkpoint(graph)["training"]["epochs_run"] == 3
    # a graph run resumes on the GPU as it would have gone on, and on the CPU
    run(setup, tmp_path / "cut", device="cuda", cuda_graph=True, epochs=3, stop_after_epoch=1)
    shutil.copytree(tmp_path / "cut", tmp_path / "cut_cpu")
    run(setup, tmp_path / "cut", device="cuda", cuda_graph=True, epochs=3, resume=True)
    for key, value in read_checkpoint(tmp_path / "graph" / "last.pt")["state_dict"].items():
        torch.testing.assert_close(
            read_checkpoint(tmp_path / "cut" / "last.pt")["state_dict"][key],
            value,
            rtol=1e-4,
            atol=1e-5,
        )
    run(setup, tmp_path / "cut_cpu", epochs=3, resume=True)
    assert read_checkpoint(tmp_path / "cut_cpu" / "last.pt")["epoch"] == 2


def _compiling_with(monkeypatch, backend):
    """torch.compile, as the engine calls it, with ``backend`` (a name, or a callable) in place
    of inductor (whose options it then drops)."""
    compile_ = torch.compile
    monkeypatch.setattr(torch, "compile", lambda module, **_: compile_(module, backend=backend))


def test_a_compiled_run_trains_as_the_eager_one_and_each_epoch_says_so(
    setup, tmp_path, monkeypatch
):
    # dynamo's capture with the eager backend: the engine's compiled path, without the minutes
    # inductor takes to generate code (test_inductor_compiles_a_training_step runs that)
    _compiling_with(monkeypatch, "eager")
    eager = run(setup, tmp_path / "eager", epochs=2)
    compiled = run(setup, tmp_path / "compiled", epochs=2, compile=True)
    for key, value in read_checkpoint(eager)["state_dict"].items():
        torch.testing.assert_close(read_checkpoint(compiled)["state_dict"][key], value)
    history = read_checkpoint(compiled)["history"]
    assert [h.get("compiled") for h in history] == [True, True]
    from zoo.hub.checkpoints import paused_summary

    summary = paused_summary(read_checkpoint(compiled.parent / "last.pt"))
    assert summary["resume"].endswith(" --compile") and summary["epochs"][0]["compiled"]
    assert all("compiled" not in h for h in read_checkpoint(eager)["history"])


def test_a_compiler_that_fails_is_said_once_and_the_run_goes_on_eagerly(
    setup, tmp_path, monkeypatch, capsys
):
    calls = []

    def failing(graph, example_inputs):  # dynamo reports it as BackendCompilerFailed
        calls.append(1)
        raise RuntimeError("no C++ compiler found")

    _compiling_with(monkeypatch, failing)
    eager = run(setup, tmp_path / "eager", epochs=2)
    fallen = run(setup, tmp_path / "fallen", epochs=2, compile=True)
    assert digest(fallen) == digest(eager) and len(calls) == 1
    out = capsys.readouterr().out
    assert out.count("torch.compile failed") == 1 and "training on eagerly" in out
    assert all("compiled" not in h for h in read_checkpoint(fallen)["history"])


def test_a_backward_the_compiler_fails_on_is_taken_again_eagerly(
    setup, tmp_path, monkeypatch, capsys
):
    from torch._dynamo.backends.common import aot_autograd
    from torch._inductor.exc import InductorError

    def failing(graph, example_inputs):  # as inductor reports its own failures
        raise InductorError(RuntimeError("backward: out of registers"), None)

    _compiling_with(monkeypatch, aot_autograd(fw_compiler=lambda g, _: g, bw_compiler=failing))
    eager = run(setup, tmp_path / "eager", epochs=1)
    fallen = run(setup, tmp_path / "fallen", epochs=1, compile=True)
    assert digest(fallen) == digest(eager)
    assert capsys.readouterr().out.count("torch.compile failed") == 1


def test_compile_and_a_cuda_graph_are_refused_together():
    with pytest.raises(TrainingError, match="--compile or --cuda-graph, not both"):
        RunOptions(compile=True, cuda_graph=True)


@pytest.mark.slow
def test_inductor_compiles_a_training_step(setup, tmp_path):
    compiled = run(setup, tmp_path / "compiled", epochs=1, max_batches=2, compile=True)
    assert read_checkpoint(compiled)["history"][0]["compiled"] is True


WRONG_SHAPE = """\
models:
  wrong_shape:
    class: wrong_shape.py:DropsAFrame
    representation: joints
    trainable: true
    hparams: {}
    reference: test model
    train: {lr: 0.001, batch_size: 8, epochs: 1}
"""


def test_a_model_whose_output_has_the_wrong_shape_is_refused_before_the_first_step(
    setup, tmp_path, capsys
):
    """One line, as zoo eval gives it, and no checkpoint: not a traceback from the loss."""
    root, _, _ = setup
    (tmp_path / "wrong.yaml").write_text(WRONG_SHAPE)
    (tmp_path / "wrong_shape.py").write_text(
        "import torch\n\n\n"
        "class DropsAFrame(torch.nn.Module):\n"
        "    def __init__(self, input_frames, output_frames, num_points):\n"
        "        super().__init__()\n"
        "        self.scale = torch.nn.Parameter(torch.ones(()))\n"
        "        self.frames = output_frames - 1\n\n"
        "    def forward(self, history):\n"
        "        return self.scale * history[:, -1:].expand(-1, self.frames, -1, -1)\n"
    )
    common = ["--registry", str(tmp_path / "wrong.yaml"), "--data-root", str(root)]
    out = tmp_path / "run"
    assert main(["train", "--model", "wrong_shape", "--out", str(out), *common]) == 2
    err = capsys.readouterr().err.strip()
    lines = [line for line in err.splitlines() if not line.startswith("warning: ")]
    assert "Traceback" not in err and len(lines) == 1  # beside the data's (absent actions)
    assert err.endswith(
        "model 'wrong_shape' returned (1, 24, 25, 3); the contract (zoo.models) expects "
        "(1, 25, 25, 3); nothing was trained"
    )
    assert not (out / "last.pt").exists()
    assert main(["eval", "--model", "wrong_shape", "--out", str(tmp_path / "e"), *common]) == 2
    assert "model 'wrong_shape' returned (8, 24, 25, 3); the contract" in capsys.readouterr().err


def test_a_best_epoch_that_predicts_no_motion_is_warned_about(setup, tmp_path):
    """The MLP starts as repeat-last; with its weights frozen (lr 0) its best epoch is
    repeat-last at every horizon, which the engine says."""
    root, registry, _ = setup
    with pytest.warns(RuntimeWarning, match=r"mlp: its best epoch \(1\) cannot be told apart"):
        train(
            "mlp",
            "cmu",
            RunOptions(data_root=root, out_dir=tmp_path / "m", progress=False, max_batches=1),
            registry=registry,
            recipe_overrides={"lr": 0, "schedule": {"type": "constant"}, "epochs": 1},
        )


def test_like_repeat_last_needs_every_horizon_within_one_percent():
    from zoo.train.validation import like_repeat_last

    horizons = {"horizons": ["a", "b"], "repeat_last": [10.0, 100.0]}
    assert like_repeat_last({**horizons, "model": [10.05, 100.9]})
    assert not like_repeat_last({**horizons, "model": [10.05, 98.0]})
    assert not like_repeat_last(None)
