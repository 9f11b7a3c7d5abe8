"""Weights from outside the zoo (an authors' ``.pth``) imported as shipped weights of a
registered model through a key map, scored as theirs, and pointed to where a command is given
one in place of the zoo's own files."""

from __future__ import annotations

import json

import pandas as pd
import torch
from test_store import cli, write_project


def authors_state(project, prefix: str = "module.") -> dict:
    """The tiny model's weights as an authors' training script saves them: under DataParallel's
    prefix, inside a dictionary with the epoch."""
    from zoo.models.registry import Registry

    registry = Registry.from_files(project / "tiny" / "registry.yaml")
    torch.manual_seed(3)
    model = registry.create_model("tiny", input_frames=10, output_frames=25, num_points=25)
    return {f"{prefix}{k}": v for k, v in model.state_dict().items()}


def import_args(project, *more):
    return [
        "weights",
        "import",
        *more,
        "--model",
        "tiny",
        "--benchmark",
        "cmu",
        "--registry",
        project / "tiny" / "registry.yaml",
        "--weights-dir",
        project / "weights",
    ]


def test_an_authors_state_dict_imports_through_a_key_map_and_scores_as_their_weights(
    tmp_path, capsys
):
    from zoo.core.io import sha256_file

    project = write_project(tmp_path)
    pth = project / "authors" / "ckpt_best.pth"
    pth.parent.mkdir()
    torch.save({"epoch": 40, "state_dict": authors_state(project)}, pth)

    # the keys do not fit as they are: a short summary and the key map that would fix them
    code, _, err = cli(capsys, *import_args(project, pth))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "4 of the model's 4 keys missing" in err and "4 unexpected" in err
    assert "a key map {'module.': ''} would rename them" in err
    assert not (project / "weights").exists()  # nothing half-written

    key_map = project / "authors" / "map.yaml"
    key_map.write_text("'module.': ''\n")
    address = "github.com/someone/tiny/blob/abc123/ckpt_best.pth"
    code, out, err = cli(
        capsys,
        *import_args(project, pth, "--key-map", key_map, "--source", address, "--licence", "none"),
    )
    assert code == 0, err
    weights = project / "weights" / "cmu" / "tiny@authors.safetensors"
    assert f"wrote {weights}" in out
    record = json.loads(weights.with_suffix(".json").read_text())
    assert record["imported"] == {
        "whose": "authors",
        "files": [{"file": "ckpt_best.pth", "sha256": sha256_file(pth), "state_key": "state_dict"}],
        "source": address,
        "key_map": {"module.": ""},
        "licence": "none",
        "redistributable": False,
    }

    out_dir = project / "eval"
    code, _, err = cli(
        capsys,
        "eval",
        "--weights",
        weights,
        "--registry",
        project / "tiny" / "registry.yaml",
        "--data-root",
        project / "cmu",
        "--sampler",
        "ltd8",
        "--out",
        out_dir,
    )
    assert code == 0, err
    protocol = json.loads((out_dir / "protocol.json").read_text())
    assert protocol["provenance"]["imported"]["files"][0]["sha256"] == sha256_file(pth)
    assert protocol["provenance"]["identity"]["label"] == "tiny@authors"

    # the same numbers as the model holding those weights, built directly
    from zoo import evaluate
    from zoo.models.registry import Registry

    registry = Registry.from_files(project / "tiny" / "registry.yaml")
    model = registry.create_model("tiny", input_frames=10, output_frames=25, num_points=25)
    model.load_state_dict({k[len("module.") :]: v for k, v in authors_state(project).items()})
    direct = evaluate(model.eval(), "cmu", data_root=project / "cmu", sampler="ltd8")
    imported = pd.read_csv(out_dir / "results.csv")
    assert abs(imported["value"].sum() - direct.frame["value"].sum()) < 1e-3


def test_parts_saved_apart_import_under_their_prefixes(tmp_path, capsys):
    project = write_project(tmp_path)
    state = authors_state(project, prefix="")
    first = {k[len("net.0.") :]: v for k, v in state.items() if k.startswith("net.0.")}
    last = {k[len("net.3.") :]: v for k, v in state.items() if k.startswith("net.3.")}
    torch.save(first, tmp_path / "first.pth")
    torch.save(last, tmp_path / "last.pth")
    code, _, err = cli(
        capsys,
        *import_args(
            project, f"net.0.={tmp_path / 'first.pth'}", f"net.3.={tmp_path / 'last.pth'}"
        ),
    )
    assert code == 0, err


def test_a_pth_given_where_the_zoos_own_files_go_points_to_the_import(tmp_path, capsys):
    project = write_project(tmp_path)
    torch.save(authors_state(project), tmp_path / "model.pth")
    for flag in ("--weights", "--checkpoint"):
        code, _, err = cli(capsys, "eval", flag, tmp_path / "model.pth", "--out", tmp_path / "o")
        assert code == 2 and len(err.strip().splitlines()) == 1
        assert "is a state dict from outside the zoo" in err
        assert f"zoo weights import {tmp_path / 'model.pth'} --model NAME" in err
    torch.save({"a": object()}, tmp_path / "pickled.pth")
    code, _, err = cli(capsys, *import_args(project, tmp_path / "pickled.pth"))
    assert code == 2 and "not a state dict that loads without running code" in err


def test_a_file_whose_name_holds_an_equals_sign_imports_as_a_file(tmp_path, capsys):
    project = write_project(tmp_path)
    name = tmp_path / "epoch=49-step=9999.ckpt"  # Lightning's default name
    torch.save(authors_state(project, prefix=""), name)
    code, _, err = cli(capsys, *import_args(project, name))
    assert code == 0, err


def test_imported_weights_rank_beside_the_models_own_rows(tmp_path, capsys):
    """A leaderboard plans <model>@authors from the weights folder, beside the model's own
    rows; imported weights do not end the model's training (it still shows as pending)."""
    from test_store import board_args

    from zoo.evaluation.results import read_table
    from zoo.hub.weights import unshipped_models
    from zoo.models.registry import Registry

    project = write_project(tmp_path)
    torch.save(authors_state(project, prefix=""), tmp_path / "model.pth")
    assert cli(capsys, *import_args(project, tmp_path / "model.pth"))[0] == 0
    code, _, err = cli(capsys, "leaderboard", *board_args(project, "tiny"))
    assert code == 0, err
    assert "tiny@authors" in set(read_table(project / "results" / "cmu" / "ltd8").frame.model)
    registry = Registry.from_files(project / "tiny" / "registry.yaml")
    assert unshipped_models(registry, project / "weights")["tiny"].startswith(
        "training: no weights"
    )


def test_weights_their_licence_keeps_out_leave_their_row_and_say_how_to_make_them(tmp_path, capsys):
    """Not redistributable: the record ships, the tensors do not. Without them the row is kept
    and --check passes, saying which files and which import make them; made again, they are
    the recorded bytes and the row is checked."""
    from test_store import board_args

    from zoo.core.io import sha256_file
    from zoo.hub.records import WeightsError
    from zoo.hub.weights import read_weights, read_weights_record

    project = write_project(tmp_path)
    pth = tmp_path / "model.pth"
    torch.save(authors_state(project, prefix=""), pth)
    assert cli(capsys, *import_args(project, pth, "--licence", "none stated"))[0] == 0
    weights = project / "weights" / "cmu" / "tiny@authors.safetensors"
    digest = sha256_file(weights)
    assert cli(capsys, "leaderboard", *board_args(project, "tiny"))[0] == 0

    weights.unlink()  # a fresh clone: the record alone
    assert read_weights_record(weights).sha256 == digest
    try:
        read_weights(weights)
        raise AssertionError("withheld weights loaded")
    except WeightsError as e:
        said = str(e)
    assert "not shipped (licence: none stated)" in said and "model.pth (sha256 " in said
    assert "zoo weights import FOLDER/model.pth --model tiny --benchmark cmu" in said
    code, _, err = cli(capsys, "leaderboard", *board_args(project, "tiny"))
    assert code == 0, err
    assert "tiny@authors: kept as stored (its authors' weights are not shipped" in err
    code, out, err = cli(capsys, "leaderboard", "--check", *board_args(project, "tiny"))
    assert code == 0, err
    assert "passed; not checked here: tiny@authors: its authors' weights are not shipped" in out

    assert cli(capsys, *import_args(project, pth, "--licence", "none stated"))[0] == 0
    assert sha256_file(weights) == digest  # the very bytes its record and rows name
    code, out, err = cli(capsys, "leaderboard", "--check", *board_args(project, "tiny"))
    assert code == 0, err
    assert "not checked here" not in out


def test_the_same_tensors_write_the_same_bytes(tmp_path):
    """The library orders its metadata as a hash map does, differently from call to call; the
    zoo writes the header again in one order, so a record's sha256 can be made again."""
    from zoo.core.io import sha256_file
    from zoo.hub.weights import save_safetensors

    tensors = {"b": torch.arange(3.0), "a": torch.ones(2, 2)}
    metadata = {"model": "m", "format": "f", "label": "x", "benchmark": "cmu"}
    digests = set()
    for i in range(8):
        save_safetensors(tensors, tmp_path / f"{i}.safetensors", metadata)
        digests.add(sha256_file(tmp_path / f"{i}.safetensors"))
    assert len(digests) == 1
