"""Shipped weights: export from a checkpoint, sha256-checked loading, ``pretrained=True``, and
``zoo eval`` / ``zoo leaderboard`` computing a trained row from exactly the stored tensors."""

import json
import shutil
from dataclasses import asdict

import pandas as pd
import pytest
import torch
from conftest import Pristine
from test_train import run, setup_in, write_setup
from tiny_models import weights_record

import zoo
import zoo.hub.weights
from zoo.cli import main
from zoo.evaluation.results import EvalResult, read_table
from zoo.hub.checkpoints import export_weights, load_weights, read_checkpoint
from zoo.hub.records import RunRecord, WeightsRecord
from zoo.hub.weights import (
    WeightsError,
    available_weights,
    read_weights,
    read_weights_record,
    weights_file,
)
from zoo.leaderboard.rebuild import regenerate


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """test_train's CMU data and registry, and tiny trained there for two epochs (``run``),
    built once for the module."""
    folder = tmp_path_factory.mktemp("weights") / "trained"
    return Pristine(folder, lambda f: run(write_setup(f), f / "run", epochs=2))


@pytest.fixture
def setup(built):
    """test_train's ``setup``, in the built folder as it was built."""
    return setup_in(built.restore())


@pytest.fixture
def trained(setup, built):
    """A trained tiny model's run folder (best.pt, last.pt) on the setup's CMU data root."""
    return built.folder / "run"


@pytest.mark.parametrize("dtype", ["float32", "float16"])
def test_exported_weights_are_the_checkpoint_s_and_carry_its_record(trained, tmp_path, dtype):
    path = export_weights(trained / "last.pt", root=tmp_path / "weights", dtype=dtype)
    assert path == tmp_path / "weights" / "cmu" / "tiny@last.safetensors"
    state, record = read_weights(path)
    ckpt = read_checkpoint(trained / "last.pt")
    for name, tensor in ckpt["state_dict"].items():
        stored = tensor.to(getattr(torch, dtype)).float()  # exactly the stored values
        assert state[name].dtype == torch.float32 and torch.equal(state[name], stored)
    assert record.label == "tiny@last" and record.model == "tiny"
    assert record.dtype == dtype and len(record.sha256) == 64
    # what a reader needs to judge and reproduce the row: budget, device, data, code
    assert record.training["samples_seen"] > 0 and record.training["device_name"]
    assert record.recipe["epochs"] == 2 and record.seed == 0
    assert record.training_data["files"][0]["sha256"]
    assert record.hparams == ckpt["hparams"] and record.protocol == ckpt["protocol"]
    assert len(record.history) == 2 and record.init_from is None  # a first stage
    # every field of the checkpoint's run record, as the checkpoint holds it
    assert asdict(RunRecord.of_checkpoint(ckpt)).items() <= asdict(record).items()
    best = export_weights(trained / "best.pt", root=tmp_path / "weights")
    assert best.stem == "tiny"
    best_epoch = read_checkpoint(trained / "best.pt")["training"]["best"]["epoch"]
    assert [h["epoch"] for h in read_weights(best)[1].history] == list(range(1, best_epoch + 1))


def test_every_committed_record_reads_as_its_type_and_writes_back_the_same_fields():
    """The records written before the type existed (some without max_batches, recipe_changes,
    init_from or validation; four with upgrades) read into it, and it writes back each field
    they hold with the same value."""
    shipped = available_weights()
    assert len(shipped) >= 20
    for bench, label in shipped:
        path = weights_file(bench, label).with_suffix(".json")
        stored = json.loads(path.read_text())
        written = read_weights_record(weights_file(bench, label)).to_json()
        assert {k: written[k] for k in stored} == stored, path
        assert set(written) - set(stored) <= {
            "world_size", "max_batches", "recipe_changes", "init_from", "validation",
        }  # fmt: skip


@pytest.mark.parametrize(
    "change, message",
    [
        ({"format": "other/1"}, r"w\.json: format 'other/1', expected 'motion-zoo-weights/1'"),
        ({"sha256": None}, r"w\.json: field sha256 is NoneType None, expected str"),
        ({"parameters": "12"}, r"field parameters is str '12', expected int"),
        ({"seed": True}, r"field seed is bool True, expected NoneType or int"),
        ({"epochs": 3}, r"w\.json: unknown field\(s\) epochs \(a record of motion-zoo-weights/1 "),
        ({"label": ...}, r"w\.json: field\(s\) label missing"),
    ],
)
def test_a_weights_record_names_the_field_it_cannot_take(change, message):
    record = weights_record().to_json()
    assert WeightsRecord.from_json(record, "w.json") == WeightsRecord.from_json(
        json.loads(json.dumps(record)), "w.json"
    )
    record.update(change)
    record = {k: v for k, v in record.items() if v is not ...}
    with pytest.raises(WeightsError, match=message):
        WeightsRecord.from_json(record, "w.json")


def test_weights_beyond_float16_are_refused_in_float16_and_nothing_is_written(trained, tmp_path):
    # a BatchNorm running variance of positions in mm (PGBIG's reach 4e9) overflows float16
    ckpt = read_checkpoint(trained / "best.pt")
    name = next(n for n, t in ckpt["state_dict"].items() if t.is_floating_point())
    ckpt["state_dict"][name] = ckpt["state_dict"][name].clone().fill_(1e6)
    torch.save(ckpt, tmp_path / "big.pt")
    with pytest.raises(WeightsError, match=rf"1 tensor\(s\) exceed float16's range: {name} "
                       r"\(largest magnitude 1e\+06\); export with --dtype float32"):  # fmt: skip
        export_weights(tmp_path / "big.pt", root=tmp_path / "w", label="tiny")
    assert not (tmp_path / "w").exists()
    state, _ = read_weights(export_weights(tmp_path / "big.pt", root=tmp_path / "w",
                                           label="tiny", dtype="float32"))  # fmt: skip
    assert torch.equal(state[name], ckpt["state_dict"][name])


def test_a_changed_weights_file_is_refused_naming_it(trained, tmp_path):
    path = export_weights(trained / "best.pt", root=tmp_path / "w")
    data = bytearray(path.read_bytes())
    data[-1] ^= 1  # one bit of one weight
    path.write_bytes(bytes(data))
    with pytest.raises(
        WeightsError,
        match=r"tiny\.safetensors: sha256 .* differs from its "
        r"record",
    ):
        read_weights(path)
    path.with_suffix(".json").unlink()
    with pytest.raises(WeightsError, match=r"tiny\.json does not exist"):
        read_weights(path)


def test_foreign_weights_are_refused_naming_what_differs(trained, tmp_path, setup):
    from safetensors.torch import save_file

    from zoo.core.io import sha256_file

    path = export_weights(trained / "best.pt", root=tmp_path / "w")
    # another model's tensors under this record, the record's checksum brought up to date
    save_file({"encoder.weight": torch.zeros(4, 4)}, str(path))
    record = json.loads(path.with_suffix(".json").read_text())
    record["sha256"] = sha256_file(path)
    path.with_suffix(".json").write_text(json.dumps(record))
    with pytest.raises(
        zoo.hub.checkpoints.CheckpointError,
        match=r"tiny\.safetensors: weights do not fit model 'tiny': 4 of the model's 4 keys "
        r"missing \(net\.0\.weight, .*\); 1 unexpected \(encoder\.weight\)$",
    ):
        load_weights(path, registry=setup[1], data_root=setup[0])
    path.write_bytes(b"not safetensors")
    record["sha256"] = sha256_file(path)
    path.with_suffix(".json").write_text(json.dumps(record))
    with pytest.raises(WeightsError, match=r"tiny\.safetensors is not a readable safetensors"):
        read_weights(path)


def test_weights_for_another_protocol_are_refused(trained, tmp_path, setup):
    path = export_weights(trained / "best.pt", root=tmp_path / "w")
    record = json.loads(path.with_suffix(".json").read_text())
    record["protocol"]["output_frames"] = 10
    path.with_suffix(".json").write_text(json.dumps(record))
    with pytest.raises(
        zoo.hub.checkpoints.CheckpointError, match="weights .* another protocol.*output_frames"
    ):
        load_weights(path, registry=setup[1], benchmark="cmu")


def test_pretrained_model_comes_from_the_shipped_weights(
    trained,
    tmp_path,
    setup,
    monkeypatch,
):
    monkeypatch.setattr(zoo.hub.weights, "WEIGHTS_DIR", tmp_path / "weights")
    export_weights(trained / "last.pt")
    model = zoo.create_model("tiny@last", benchmark="cmu", registry=setup[1], pretrained=True)
    expected = read_checkpoint(trained / "last.pt")["state_dict"]
    assert not model.training
    for name, tensor in model.state_dict().items():
        torch.testing.assert_close(tensor, expected[name].half().float(), rtol=0, atol=0)
    with pytest.raises(
        WeightsError,
        match=r"no shipped weights for 'tiny' on benchmark 'cmu'.*"
        r"shipped: cmu/tiny@last",
    ):
        zoo.create_model("tiny", benchmark="cmu", registry=setup[1], pretrained=True)
    with pytest.raises(zoo.models.registry.RegistryError, match="needs benchmark"):
        zoo.create_model("tiny@last", registry=setup[1], pretrained=True)


def test_eval_and_leaderboard_compute_the_row_from_the_weights(
    trained,
    tmp_path,
    setup,
    capsys,
):
    root, registry, reg_file = setup
    weights = tmp_path / "weights"
    assert main(["weights", "export", str(trained / "last.pt"), "--root", str(weights)]) == 0
    assert main(["weights", "list", "--root", str(weights)]) == 0
    assert "tiny@last" in capsys.readouterr().out
    out = tmp_path / "eval"
    assert (
        main(
            [
                "eval",
                "--weights",
                str(weights / "cmu" / "tiny@last.safetensors"),
                "--registry",
                str(reg_file),
                "--data-root",
                str(root),
                "--sampler",
                "ltd8",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    evaluated = EvalResult.read(out)
    assert (
        evaluated.protocol["provenance"]["weights_sha256"]
        == read_weights(weights / "cmu" / "tiny@last.safetensors")[1].sha256
    )

    def rebuild(checkpoints):
        regenerate(
            "cmu",
            registry=registry,
            data_root=root,
            out_root=tmp_path / "results",
            checkpoints=checkpoints,
            weights=weights,
        )

    # No checkpoints at all: the leaderboard still computes the row, from the weights.
    rebuild(tmp_path / "no-checkpoints")
    board = read_table(tmp_path / "results" / "cmu" / "ltd8").frame
    row = board[board["model"] == "tiny@last"]
    assert len(row) > 0
    ltd8 = EvalResult.read(tmp_path / "results" / "cmu" / "ltd8" / "tiny@last")
    assert ltd8.protocol["provenance"]["weights"].endswith("tiny@last.safetensors")
    same = evaluated.frame.merge(
        row, on=["action", "metric", "averaging", "joints", "horizon_ms"], suffixes=("", "_board")
    )
    assert (tmp_path / "results" / "cmu" / "training.png").stat().st_size > 0  # its curve
    assert len(same) == len(row)  # the same sampler in both: the same numbers
    pd.testing.assert_series_equal(same["value"], same["value_board"], check_names=False)
    # A checkpoint beside the shipped weights: the weights are scored, and the note saying so
    # comes once a run, not once for each table that plans the row.
    beside = tmp_path / "checkpoints" / "cmu" / "tiny"
    beside.mkdir(parents=True)
    shutil.copy(trained / "last.pt", beside / "last.pt")
    capsys.readouterr()
    rebuild(tmp_path / "checkpoints")
    err = capsys.readouterr().err
    assert err.count("cmu: tiny@last: the shipped weights") == 1, err


def test_training_plot_draws_each_validation_horizon_beside_repeat_last(tmp_path, monkeypatch):
    from zoo.hub.weights import training_horizons
    from zoo.report import outputs
    from zoo.report.outputs import plot_training_curves

    horizons = lambda m: {  # noqa: E731
        "metric": "rmse",
        "horizons": ["40 ms (first frame)", "80 ms"],
        "model": [m, 2 * m],
        "repeat_last": [0.01, 0.02],
    }
    record = weights_record(
        recipe={"batch_size": 4},
        history=[
            {"samples": 40, "val_mpjpe": 3.0},  # an epoch logged before horizons were
            {"samples": 40, "val_mpjpe": 2.0, "val_horizons": horizons(0.03)},
            {"samples": 40, "val_mpjpe": 1.0, "val_horizons": horizons(0.005)},
        ],
    )
    assert training_horizons(record) == [(20, horizons(0.03)), (30, horizons(0.005))]
    drawn = []
    save = outputs.save_figure  # each figure drawn
    monkeypatch.setattr(
        outputs, "save_figure", lambda fig, *a, **k: (drawn.append(fig), save(fig, *a, **k))[1]
    )
    assert plot_training_curves({"m": record}, tmp_path / "training.png")
    axes = drawn[0].axes
    assert [a.get_title() for a in axes] == [
        "mean over predicted frames",
        "rmse at 40 ms (first frame)",
        "rmse at 80 ms",
    ]
    model, reference = axes[2].get_lines()
    assert list(model.get_ydata()) == [0.06, 0.01] and list(reference.get_ydata()) == [0.02, 0.02]
    assert (tmp_path / "training.png").stat().st_size > 0
    # the same records again: the file keeps their digest and is left as it is
    assert not plot_training_curves({"m": record}, tmp_path / "training.png")
    assert len(drawn) == 1
    record.history[-1]["val_mpjpe"] = 0.5  # another run's records: drawn again
    assert plot_training_curves({"m": record}, tmp_path / "training.png")
    assert len(drawn) == 2
