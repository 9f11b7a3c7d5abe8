"""The results store: a result's identity is what was measured; nothing of another identity is
replaced silently; the leaderboard reuses what still holds, recomputes what is new or stale, and
never deletes a row it did not make."""

import contextlib
import copy
import io
import json
import os
import pickle
import re
import shutil
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import Pristine, write_cmu_file
from tiny_models import REGISTRY

from zoo.cli import main
from zoo.evaluation.results import read_table
from zoo.models.registry import Registry
from zoo.train.loop import train
from zoo.train.options import RunOptions

HERE = Path(__file__).resolve().parent

CONSTANT_VELOCITY = '''\
import torch
from torch import nn


class DampedVelocity(nn.Module):
    """The last observed velocity, carried on (multiplied by damping each frame)."""

    def __init__(self, input_frames, output_frames, num_points, damping=1.0):
        super().__init__()
        self.output_frames, self.damping = output_frames, damping

    def forward(self, history):
        velocity = history[:, -1] - history[:, -2]
        steps = torch.cumsum(self.damping ** torch.arange(1, self.output_frames + 1,
                                                          dtype=history.dtype), 0)
        return history[:, -1:] + steps.view(1, -1, 1, 1) * velocity[:, None]
'''


@pytest.fixture
def project(tmp_path):
    return write_project(tmp_path)


def write_project(tmp_path):
    """CMU data (two training files, one test file), the tiny models' registry and a user's
    registry with a constant-velocity baseline, each in its own folder."""
    root = tmp_path / "cmu"
    for split, n in (("train", 2), ("test", 1)):
        for i in range(1, n + 1):
            write_cmu_file(
                root / split / "walking" / f"walking_{i}.txt",
                0.01 * i * np.arange(800) + 0.002 * np.sin(np.arange(800) / 7),
            )
    (tmp_path / "tiny").mkdir()
    (tmp_path / "tiny" / "registry.yaml").write_text(REGISTRY)
    shutil.copy(HERE / "tiny_models.py", tmp_path / "tiny" / "tiny_models.py")
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "baselines.py").write_text(CONSTANT_VELOCITY)
    (tmp_path / "mine" / "registry.yaml").write_text(
        textwrap.dedent("""\
        models:
          damped_velocity:
            class: baselines.py:DampedVelocity
            representation: joints
            hparams: {damping: 1.0}
            reference: my own baseline
        """)
    )
    return tmp_path


def cli(capsys, *args):
    code = main([str(a) for a in args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def board_args(project, *registries):
    out = [
        "--benchmark",
        "cmu",
        "--data-root",
        project / "cmu",
        "--out",
        project / "results",
        "--weights",
        project / "weights",
        "--checkpoints",
        project / "no-checkpoints",
    ]
    for registry in registries:
        out += ["--registry", project / registry / "registry.yaml"]
    return out


def shipped_tiny(project, epochs=1, seed=0):
    """The tiny model trained and exported as shipped weights (weights/cmu/tiny.*)."""
    from zoo.hub.checkpoints import export_weights

    registry = Registry.from_files(
        HERE.parent / "registry.yaml", project / "tiny" / "registry.yaml"
    )
    run = project / "checkpoints" / f"seed{seed}"
    best = train(
        "tiny",
        "cmu",
        RunOptions(data_root=project / "cmu", seed=seed, progress=False, out_dir=run),
        registry=registry,
        recipe_overrides={"epochs": epochs},
    )
    return export_weights(best, root=project / "weights", dtype="float32")


@pytest.fixture(scope="module")
def _tiny_board(tmp_path_factory):
    def build(folder):
        write_project(folder)
        shipped_tiny(folder)
        with contextlib.redirect_stderr(io.StringIO()) as err:
            assert main([str(a) for a in ("leaderboard", *board_args(folder, "tiny"))]) == 0
        (folder / "leaderboard.err").write_text(err.getvalue())

    return Pristine(tmp_path_factory.mktemp("store") / "project", build)


@pytest.fixture
def tiny_board(_tiny_board):
    """A project with tiny trained and shipped (:func:`shipped_tiny`) and the leaderboard built
    with its registry, as built; what the build said on stderr in ``leaderboard.err``."""
    return _tiny_board.restore()


def test_a_users_row_survives_a_rebuild_without_its_registry(project, capsys):
    code, _, _ = cli(capsys, "leaderboard", *board_args(project, "mine"))
    assert code == 0
    table = project / "results" / "cmu" / "ltd8"
    assert set(read_table(table).frame.model) == {"damped_velocity", "repeat_last"}
    before = (table / "damped_velocity" / "results.csv").read_bytes()

    # The same rebuild without the user's registry: their row stays, on disk and in the table.
    code, _, err = cli(capsys, "leaderboard", "--recompute", *board_args(project))
    assert code == 0
    assert (table / "damped_velocity" / "results.csv").read_bytes() == before
    assert "damped_velocity" in set(read_table(table).frame.model)
    assert "damped_velocity: kept as stored (registry" in err and "not loaded" in err
    assert "--drop damped_velocity removes it" in err

    # Only a deliberate --drop removes it.
    code, _, _ = cli(capsys, "leaderboard", "--drop", "damped_velocity", *board_args(project))
    assert code == 0 and not (table / "damped_velocity").exists()
    assert set(read_table(table).frame.model) == {"repeat_last"}


def test_a_stored_row_of_another_registry_is_never_replaced(project, capsys):
    (project / "mine" / "registry.yaml").write_text(
        textwrap.dedent("""\
        models:
          repeat_last:
            class: baselines.py:DampedVelocity
            representation: joints
            override: true
            reference: a user's own row under a zoo name
        """)
    )
    assert cli(capsys, "leaderboard", *board_args(project, "mine"))[0] == 0
    stored = project / "results" / "cmu" / "all" / "repeat_last" / "results.csv"
    before = stored.read_bytes()
    code, _, err = cli(capsys, "leaderboard", *board_args(project))
    assert code == 2 and stored.read_bytes() == before
    assert "was evaluated with registry" in err and "--drop repeat_last" in err


def eval_args(project, *extra):
    return [
        "eval",
        "--registry",
        project / "mine" / "registry.yaml",
        "--model",
        "damped_velocity",
        "--sampler",
        "ltd8",
        "--results",
        project / "results",
        *extra,
    ]


def test_eval_never_replaces_a_result_of_another_identity(project, capsys, tmp_path):
    data = ["--data-root", project / "cmu"]
    assert cli(capsys, *eval_args(project, *data))[0] == 0
    place = project / "results" / "cmu" / "ltd8" / "damped_velocity"
    before = (place / "results.csv").read_bytes()
    # the same measurement again: same identity, allowed
    assert cli(capsys, *eval_args(project, *data))[0] == 0

    # other hyper-parameters: stored beside it under their own label, never in its place
    assert cli(capsys, *eval_args(project, *data, "--set", "damping=0.8"))[0] == 0
    assert (place.parent / "damped_velocity+damping=0.8" / "results.csv").is_file()
    code, out, _ = cli(
        capsys,
        "compare",
        "damped_velocity",
        "damped_velocity+damping=0.8",
        "--benchmark",
        "cmu",
        "--sampler",
        "ltd8",
        "--results",
        project / "results",
    )  # two configurations of one model, labelled
    assert code == 0 and "damped_velocity against damped_velocity+damping=0.8" in out
    code, _, err = cli(
        capsys, *eval_args(project, *data, "--set", "damping=0.8", "--label", "damped_velocity")
    )
    assert code == 2 and "model.hparams.damping: stored 1.0, now 0.8" in err

    # other data under the same benchmark name
    other = tmp_path / "other"
    write_cmu_file(other / "test" / "walking" / "walking_1.txt", 0.02 * np.arange(800))
    code, _, err = cli(capsys, *eval_args(project, "--data-root", other))
    assert code == 2 and "protocol_id: stored" in err
    assert "different sha256: ['test/walking/walking_1.txt']" in err

    # another benchmark file of the same name
    bench = yaml_text = (HERE.parent / "benchmarks" / "cmu.yaml").read_text()
    bench = tmp_path / "cmu.yaml"
    bench.write_text(yaml_text.replace("input_frames: 10", "input_frames: 12"))
    code, _, err = cli(capsys, *eval_args(project, *data, "--benchmark", bench))
    assert code == 2 and "input_frames (10 vs 12)" in err
    assert (place / "results.csv").read_bytes() == before

    # told to: replaced
    assert cli(capsys, *eval_args(project, *data, "--benchmark", bench, "--replace"))[0] == 0
    assert json.loads((place / "protocol.json").read_text())["input_frames"] == 12


def test_a_stale_row_is_recomputed_and_a_current_one_reused(tiny_board, capsys):
    project = tiny_board
    assert "recomputing tiny: new" in (project / "leaderboard.err").read_text()
    table = project / "results" / "cmu" / "all"
    written = {p: p.stat().st_mtime_ns for p in table.rglob("*") if p.is_file()}

    code, _, err = cli(capsys, "leaderboard", *board_args(project, "tiny"))
    assert code == 0 and "cmu: 4 row(s) reused, 0 re-stamped after a code change" in err
    assert {p: p.stat().st_mtime_ns for p in table.rglob("*") if p.is_file()} == written

    shipped_tiny(project, seed=1)  # retrained: other weights under the same label
    code, _, err = cli(capsys, "leaderboard", *board_args(project, "tiny"))
    assert code == 0 and "recomputing tiny: trained.sha256: stored" in err
    assert (
        "cmu: 2 row(s) reused, 0 re-stamped after a code change (a sample agreed), 2 recomputed"
        in err
    )  # repeat_last reused on both tables
    assert (table / "repeat_last" / "results.csv").stat().st_mtime_ns == written[
        table / "repeat_last" / "results.csv"
    ]


def test_a_user_checkpoint_names_its_registry(project, capsys):
    registry = Registry.from_files(
        HERE.parent / "registry.yaml", project / "tiny" / "registry.yaml"
    )
    best = train(
        "tiny",
        "cmu",
        RunOptions(
            data_root=project / "cmu", progress=False, out_dir=project / "checkpoints" / "tiny"
        ),
        registry=registry,
        recipe_overrides={"epochs": 1},
    )
    from zoo.hub.checkpoints import read_checkpoint

    origin = read_checkpoint(best)["origin"]
    assert origin["class"] == "tiny_models.py:TinyTemporal"
    assert origin["registry"] == str(project / "tiny" / "registry.yaml")
    code, _, err = cli(
        capsys,
        "eval",
        "--checkpoint",
        best,
        "--data-root",
        project / "cmu",
        "--out",
        project / "out",
    )
    assert code == 2
    assert (
        f"holds model 'tiny' (class tiny_models.py:TinyTemporal) from registry file "
        f"{project / 'tiny' / 'registry.yaml'}" in err
    )
    assert f"pass --registry {project / 'tiny' / 'registry.yaml'}" in err
    assert (
        cli(
            capsys,
            "eval",
            "--checkpoint",
            best,
            "--data-root",
            project / "cmu",
            "--out",
            project / "out",
            "--registry",
            project / "tiny" / "registry.yaml",
        )[0]
        == 0
    )


def test_readme_add_a_damped_velocity_baseline_to_the_cmu_ltd8_leaderboard(tiny_board, capsys):
    """The README's words: register a constant-velocity baseline from your own file and add it
    to the CMU leaderboard; no trained model is evaluated again."""
    project = tiny_board  # tiny shipped, and the leaderboard built with it
    table = project / "results" / "cmu" / "ltd8"
    tiny = (table / "tiny" / "protocol.json").read_bytes()

    code, out, err = cli(
        capsys, "leaderboard", "--model", "damped_velocity", *board_args(project, "tiny", "mine")
    )
    assert code == 0
    assert "recomputing damped_velocity: asked (--model)" in err
    assert "recomputing tiny" not in err and "recomputing repeat_last" not in err
    assert (table / "tiny" / "protocol.json").read_bytes() == tiny  # not re-evaluated
    board = (table / "leaderboard.md").read_text()
    assert "| damped_velocity " in board and "| tiny " in board
    record = json.loads((table / "damped_velocity" / "protocol.json").read_text())
    # a registry outside the repository is recorded by its file name: no machine's folders
    assert record["provenance"]["identity"]["model"]["registry"] == "outside:registry.yaml"
    assert str(project) not in json.dumps(record["provenance"]["identity"])


def test_python_results_carry_the_command_lines_identity(project, capsys):
    import zoo

    assert cli(capsys, *eval_args(project, "--data-root", project / "cmu"))[0] == 0
    stored = zoo.load_results("cmu", sampler="ltd8", root=project / "results")
    registry = Registry.from_files(
        HERE.parent / "registry.yaml", project / "mine" / "registry.yaml"
    )
    result = zoo.evaluate(
        "damped_velocity", "cmu", sampler="ltd8", registry=registry, data_root=project / "cmu"
    )
    assert result.identity == stored["damped_velocity"].identity
    assert result.summary().shape[1] == 25

    class Zero(torch.nn.Module):  # your own model object: no registry, nothing written
        def forward(self, history):
            return torch.zeros(history.shape[0], 25, *history.shape[2:])

    mine = zoo.evaluate(Zero(), "cmu", sampler="ltd8", data_root=project / "cmu", label="zero")
    assert mine.identity["model"]["class"].endswith("Zero")
    assert not (HERE.parent / "results" / "cmu" / "ltd8" / "zero").exists()
    comparison = zoo.compare(stored["damped_velocity"], mine)
    assert "damped_velocity against zero" in comparison.markdown()


def test_code_fingerprints_ignore_comments_and_docstrings(tmp_path):
    from zoo.store.fingerprint import code_fingerprint

    a, b, c = (tmp_path / f"{n}.py" for n in "abc")
    a.write_text('def f(x):\n    """Doc."""\n    return x + 1\n')
    b.write_text("def f(x):  # a comment\n\n    return (x\n            + 1)\n")
    c.write_text("def f(x):\n    return x + 2\n")
    assert code_fingerprint(a) == code_fingerprint(b) != code_fingerprint(c)


def test_a_rebuild_keeps_whatever_else_is_in_a_table_folder(project, capsys):
    # zoo eval first: the table folder holds only its row, and the rebuild builds on it
    assert cli(capsys, *eval_args(project, "--data-root", project / "cmu"))[0] == 0
    table = project / "results" / "cmu" / "ltd8"
    (table / "NOTES.md").write_text("my notes")
    (table / "my-comparison").mkdir()
    (table / "my-comparison" / "comparison.md").write_text("cv against rl")
    assert cli(capsys, "leaderboard", *board_args(project, "mine"))[0] == 0
    assert (table / "NOTES.md").read_text() == "my notes"
    assert (table / "my-comparison" / "comparison.md").is_file()
    assert set(read_table(table).frame.model) == {"damped_velocity", "repeat_last"}


def test_a_users_row_under_a_planned_label_stops_the_rebuild(project, capsys):
    registry = Registry.from_files(
        HERE.parent / "registry.yaml", project / "tiny" / "registry.yaml"
    )
    mine = train(
        "tiny",
        "cmu",
        RunOptions(
            data_root=project / "cmu", seed=3, progress=False, out_dir=project / "mine" / "run"
        ),
        registry=registry,
        recipe_overrides={"epochs": 1},
    )
    assert (
        cli(
            capsys,
            "eval",
            "--registry",
            project / "tiny" / "registry.yaml",
            "--checkpoint",
            mine,
            "--data-root",
            project / "cmu",
            "--sampler",
            "ltd8",
            "--results",
            project / "results",
        )[0]
        == 0
    )
    stored = project / "results" / "cmu" / "ltd8" / "tiny" / "results.csv"
    before = stored.read_bytes()
    shipped_tiny(project)  # the leaderboard's own tiny: other weights
    code, _, err = cli(capsys, "leaderboard", *board_args(project, "tiny"))
    assert code == 2 and stored.read_bytes() == before
    assert "row 'tiny' was made by zoo eval" in err and "--drop tiny" in err
    assert not (project / "results" / "cmu" / "all").exists()  # stopped before writing


def test_a_model_objects_identity_holds_its_settings(project):
    import zoo
    import zoo.store.identity

    spec = {}
    exec(CONSTANT_VELOCITY, spec)  # a class with no source file, as typed into a REPL
    run = dict(sampler="ltd8", data_root=project / "cmu", label="cv")
    a = zoo.evaluate(spec["DampedVelocity"](10, 25, 25, damping=1.0), "cmu", **run)
    b = zoo.evaluate(spec["DampedVelocity"](10, 25, 25, damping=0.8), "cmu", **run)
    assert a.identity["model"]["hparams"]["attributes"]["damping"] == 1.0
    assert a.identity != b.identity and a.identity["code"]["model"] is None
    out = project / "cv"
    zoo.evaluate(spec["DampedVelocity"](10, 25, 25), "cmu", out=out, **run)
    with pytest.raises(zoo.store.layout.StoreError, match="source cannot be read"):
        zoo.evaluate(spec["DampedVelocity"](10, 25, 25), "cmu", out=out, **run)


def test_a_rebuild_that_agrees_changes_no_file(project, capsys, monkeypatch):
    """A row recomputed within the tolerance of the stored one leaves its files byte for byte
    (a stale identity alone is brought up to date), and its table's plots are copied, not
    drawn; only a difference beyond the tolerance rewrites, and says why. zoo eval likewise."""
    from zoo.report import outputs

    code, _, _ = cli(capsys, "leaderboard", *board_args(project))
    table = project / "results" / "cmu" / "all"
    before = {p: p.read_bytes() for p in table.rglob("*") if p.is_file()}

    drawn = []
    draw = outputs.save_figure
    monkeypatch.setattr(outputs, "save_figure", lambda *a, **k: drawn.append(a[1]) or draw(*a, **k))
    code, _, err = cli(capsys, "leaderboard", *board_args(project), "--recompute")
    assert code == 0 and "repeat_last: recomputed (asked (--recompute)); agrees with the" in err
    assert "recomputing repeat_last" not in err  # nothing of it rewritten
    assert "kept as stored" in err
    assert {p: p.read_bytes() for p in table.rglob("*") if p.is_file()} == before
    assert drawn == []
    monkeypatch.undo()

    record_path = table / "repeat_last" / "protocol.json"
    record = json.loads(record_path.read_text())
    current = record["provenance"]["identity"]["code"]["evaluator"]
    record["provenance"]["identity"]["code"]["evaluator"] = "0" * 16  # as if the code changed
    record_path.write_text(json.dumps(record))
    code, _, err = cli(capsys, "leaderboard", *board_args(project), "--full")  # every window
    assert code == 0 and "its files kept, its identity updated" in err
    refreshed = json.loads(record_path.read_text())
    assert refreshed["provenance"]["identity"]["code"]["evaluator"] == current
    (verified,) = refreshed["provenance"]["verified"]
    assert verified["every_window"] and verified["code_before"]["evaluator"] == "0" * 16
    for name in ("results.csv", "windows.npz", "tables.md"):
        assert (table / "repeat_last" / name).read_bytes() == before[table / "repeat_last" / name]
    # the table's own record carries the updated identity: the next rebuild writes nothing
    table_record = json.loads((table / "protocol.json").read_text())
    assert '"every_window": true' in json.dumps(table_record)
    stamps = {p: p.stat().st_mtime_ns for p in table.rglob("*") if p.is_file()}
    code, _, err = cli(capsys, "leaderboard", *board_args(project))
    assert {p: p.stat().st_mtime_ns for p in table.rglob("*") if p.is_file()} == stamps

    results = table / "repeat_last" / "results.csv"
    frame = pd.read_csv(results)
    frame.loc[0, "value"] += 0.1  # far beyond float32 rounding
    frame.to_csv(results, index=False)
    code, _, err = cli(capsys, "leaderboard", *board_args(project), "--recompute")
    assert code == 0 and "rewritten: values differ by up to" in err
    assert results.read_bytes() == before[results]

    out = project / "mine_eval"
    args = ["eval", "--model", "repeat_last", "--sampler", "all", "--data-root"]
    code, _, _ = cli(capsys, *args, project / "cmu", "--out", out)
    stamps = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
    code, text, _ = cli(capsys, *args, project / "cmu", "--out", out)
    assert code == 0 and "left as stored" in text
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()} == stamps
    (out / "results.csv").write_text("")  # a damaged stored result is rewritten, not kept
    code, text, _ = cli(capsys, *args, project / "cmu", "--out", out)
    assert code == 0 and "rewritten: the stored result of this identity stored result " in text
    assert (out / "results.csv").read_text().startswith("model,")


MODEL_FILE = """\
import torch
from torch import nn

from zoo.models.dct import dct_matrix

SCALE = 2.0


def helper(x):
    return x * SCALE


class Model(nn.Module):
    def forward(self, x):
        return helper(x) + dct_matrix(3)[0, 0]
"""


def _model_class(folder: Path, text: str) -> type:
    import importlib.util

    folder.mkdir()
    (folder / "model.py").write_text(text)
    spec = importlib.util.spec_from_file_location(f"fingerprint_{folder.name}", folder / "model.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # as the registry loads a class from a file
    spec.loader.exec_module(module)
    return module.Model


@pytest.mark.parametrize(
    "change, stale",
    [
        ("a second class", False),
        ("a comment and a docstring", False),
        ("a helper's constant", True),
        ("the helper", True),
        ("an import from outside zoo", True),
        ("a statement run on import", True),
        ("an import under an alias", False),
        ("the module imported instead of the name", False),
        ("definitions reordered", False),
        ("another definition under the same name", True),
    ],
)
def test_a_model_fingerprint_covers_the_code_its_class_reaches(tmp_path, change, stale):
    from zoo.store.fingerprint import model_fingerprint, reachable_code

    changed = {
        "a second class": MODEL_FILE + "\n\nclass Other(nn.Module):\n    pass\n",
        "a comment and a docstring": MODEL_FILE.replace(
            "def helper(x):\n", 'def helper(x):\n    """Doubles."""  # why\n'
        ),
        "a helper's constant": MODEL_FILE.replace("SCALE = 2.0", "SCALE = 3.0"),
        "the helper": MODEL_FILE.replace("x * SCALE", "x * SCALE + 1"),
        "an import from outside zoo": MODEL_FILE.replace(
            "from torch import nn", "import torch.nn as nn"
        ),
        "a statement run on import": MODEL_FILE + "\ntorch.set_default_dtype(torch.float32)\n",
        "an import under an alias": MODEL_FILE.replace(
            "import dct_matrix\n", "import dct_matrix as basis\n"
        ).replace("dct_matrix(3)", "basis(3)"),
        "the module imported instead of the name": MODEL_FILE.replace(
            "from zoo.models.dct import dct_matrix", "from zoo.models import dct"
        ).replace("dct_matrix(3)", "dct.dct_matrix(3)"),
        "definitions reordered": MODEL_FILE.split("SCALE = 2.0")[0]
        + MODEL_FILE.split("\n\n\n", 2)[2]  # the class first
        + "\n\nSCALE = 2.0\n\n\ndef helper(x):\n    return x * SCALE\n",
        "another definition under the same name": MODEL_FILE.replace(
            "import dct_matrix\n", "import idct_matrix as dct_matrix\n"
        ),
    }[change]
    assert changed != MODEL_FILE
    before = model_fingerprint(_model_class(tmp_path / "before", MODEL_FILE))
    after = model_fingerprint(_model_class(tmp_path / "after", changed))
    assert (before != after) is stale
    code = reachable_code(_model_class(tmp_path / "again", MODEL_FILE))
    # what it reaches in zoo: dct_matrix and what dct_matrix itself uses, nothing else there
    assert {c.split("::")[1] for c in code if c.startswith("zoo/")} <= {"dct_matrix", "import"}
    assert any(c.startswith("zoo/models/dct.py::dct_matrix::") for c in code)


def test_a_model_reaches_its_base_class_in_another_zoo_module():
    from zoo.models.spectrhums_anchored import AnchoredSpecTrHuMS
    from zoo.store.fingerprint import reachable_code

    names = {c.split("::")[1] for c in reachable_code(AnchoredSpecTrHuMS)}
    assert {"AnchoredSpecTrHuMS", "SpecTrHuMS", "probe_projections"} <= names


def test_a_model_reaches_what_it_imports_inside_its_methods(tmp_path):
    from zoo.store.fingerprint import reachable_code

    local = MODEL_FILE.replace("from zoo.models.dct import dct_matrix\n", "").replace(
        "        return helper(x)",
        "        from zoo.models.dct import dct_matrix\n\n        return helper(x)",
    )
    code = reachable_code(_model_class(tmp_path / "local", local))
    assert any(c.startswith("zoo/models/dct.py::dct_matrix::") for c in code)


AUTHORS_FILE = """\
from torch import nn


class AuthorsNet(nn.Module):
    def __init__(self):
        super().__init__()
        self.act = nn.Tanh()

    def forward(self, x):
        return self.act(x)


class Unused(nn.Module):
    pass
"""

WRAPPER_FILE = """\
from torch import nn
{import_line}


class Wrapper(nn.Module):
    def __init__(self, **_):
        super().__init__()
        self.net = {use}

    def forward(self, history):
        return self.net(history)
"""


@pytest.mark.parametrize(
    "import_line, use",
    [
        ("from authors import AuthorsNet", "AuthorsNet()"),
        ("import authors", "authors.AuthorsNet()"),
        ("import authors as au", "au.AuthorsNet()"),
        ("import pkg.authors", "pkg.authors.AuthorsNet()"),
        ("from pkg import authors", "authors.AuthorsNet()"),
    ],
)
def test_a_wrapper_imports_the_file_beside_it_and_its_fingerprint_follows_that_file(
    tmp_path, import_line, use
):
    """A researcher's class file imports the authors' code from a file beside it (the
    registry puts its folder on sys.path), and the model's fingerprint covers what it reaches
    there: an activation changed in that file makes its rows stale, wherever the folder is."""
    from zoo.models.registry import Registry
    from zoo.store.fingerprint import model_fingerprint

    def fingerprint(folder: Path, authors: str) -> str:
        folder.mkdir()
        (folder / "authors.py").write_text(authors)
        (folder / "pkg").mkdir()  # the same file in a package beside the wrapper
        (folder / "pkg" / "__init__.py").write_text("")
        (folder / "pkg" / "authors.py").write_text(authors)
        (folder / "wrapper.py").write_text(WRAPPER_FILE.format(import_line=import_line, use=use))
        (folder / "my.yaml").write_text(
            "models:\n  mine:\n    class: wrapper.py:Wrapper\n    representation: joints\n"
        )
        for name in ("authors", "pkg", "pkg.authors"):
            sys.modules.pop(name, None)  # each folder's own files
        cls = Registry.from_files(folder / "my.yaml").get("mine").load_class()
        assert cls()(torch.zeros(2)).shape == (2,)
        return model_fingerprint(cls)

    before = fingerprint(tmp_path / "a", AUTHORS_FILE)
    assert fingerprint(tmp_path / "b", AUTHORS_FILE) == before  # another folder, same code
    relu = fingerprint(tmp_path / "c", AUTHORS_FILE.replace("nn.Tanh()", "nn.ReLU()"))
    unused = fingerprint(tmp_path / "d", AUTHORS_FILE.replace("    pass", "    x = 1"))
    assert relu != before
    # only what it reaches, however it is imported (a class unused is left out)
    assert unused == before


CHECKOUT_WRAPPER = """
import sys
from pathlib import Path

from torch import nn

sys.path.insert(0, str(Path(__file__).parent / "Checkout"))  # the authors' code, by its names
from module.model import AuthorsNet  # noqa: E402


class Wrapper(nn.Module):
    def __init__(self, **_):
        super().__init__()
        self.net = AuthorsNet()

    def forward(self, history):
        return self.net(history)
"""


def test_a_wrapper_that_puts_the_authors_checkout_on_sys_path_is_followed_into_it(
    tmp_path, monkeypatch
):
    """As docs/adding-a-model.md's GGMotion wrapper does: the authors' checkout in a folder
    beside the wrapper, put on sys.path by the wrapper, its packages imported by their names.
    A change in a file of the checkout that the model reaches makes its rows stale."""
    from zoo.models.registry import Registry
    from zoo.store.fingerprint import model_fingerprint, reachable_code

    monkeypatch.setattr(sys, "path", list(sys.path))

    def fingerprint(folder: Path, authors: str):
        (folder / "Checkout" / "module").mkdir(parents=True)
        (folder / "Checkout" / "module" / "__init__.py").write_text("")
        (folder / "Checkout" / "module" / "model.py").write_text(authors)
        (folder / "wrapper.py").write_text(CHECKOUT_WRAPPER)
        (folder / "my.yaml").write_text(
            "models:\n  mine:\n    class: wrapper.py:Wrapper\n    representation: joints\n"
        )
        for name in ("module", "module.model"):
            sys.modules.pop(name, None)
        cls = Registry.from_files(folder / "my.yaml").get("mine").load_class()
        return model_fingerprint(cls), {p.split("::")[0] for p in reachable_code(cls)}

    before, files = fingerprint(tmp_path / "a", AUTHORS_FILE)
    assert files == {"wrapper.py", "model.py"}
    assert fingerprint(tmp_path / "b", AUTHORS_FILE)[0] == before
    assert fingerprint(tmp_path / "c", AUTHORS_FILE.replace("nn.Tanh()", "nn.ReLU()"))[0] != before
    for name in ("module", "module.model"):
        sys.modules.pop(name, None)


def test_identity_differences_are_decided_on_by_field_not_by_their_words():
    from zoo.store.identity import Difference, identity_differences, only_code_changed

    code = identity_differences({"code": {"evaluator": "a"}}, {"code": {"evaluator": "b"}})
    assert only_code_changed(code) and code == ['code.evaluator: stored "a", now "b"']
    assert (code[0].field, code[0].stored, code[0].new, code[0].kind) == (
        "code.evaluator",
        "a",
        "b",
        "changed",
    )
    unreadable = identity_differences({"code": {}}, {"code": {"model": None}})
    assert not only_code_changed(unreadable) and "no result is its twin" in "; ".join(unreadable)
    assert unreadable[0].kind == "unreadable"
    assert identity_differences(None, {"code": {}})[0].kind == "unrecorded"
    # the kind decides, not the words: a code field whose values merely read alike is code
    assert only_code_changed([Difference("code.model", "no result is its twin", "x")])
    assert not only_code_changed([Difference("weights.sha256", "1", "2")])
    assert copy.deepcopy(code[0]).stored == "a" and pickle.loads(pickle.dumps(code[0])) == code[0]
    with pytest.raises(ValueError, match="kind 'odd'"):
        Difference("code.model", kind="odd")


def test_a_second_folder_whose_sibling_module_is_shadowed_is_refused(tmp_path):
    """Two registries' class files, each with its own authors.py: the second would import the
    first one's module (Python keeps one per name), so it is refused, naming both files."""
    from zoo.models.registry import Registry, RegistryError

    entries = {}
    for folder in ("first", "second"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "authors.py").write_text(AUTHORS_FILE)
        (tmp_path / folder / "wrapper.py").write_text(
            WRAPPER_FILE.format(import_line="from authors import AuthorsNet", use="AuthorsNet()")
        )
        (tmp_path / folder / "my.yaml").write_text(
            f"models:\n  {folder}:\n    class: wrapper.py:Wrapper\n    representation: joints\n"
        )
        entries[folder] = Registry.from_files(tmp_path / folder / "my.yaml").get(folder)
    sys.modules.pop("authors", None)
    try:
        entries["first"].load_class()
        with pytest.raises(RegistryError, match=r"second/authors.py would not be what its class"):
            entries["second"].load_class()
    finally:
        sys.modules.pop("authors", None)


KEPT_FINGERPRINTS = """
import json, sys, time
from pathlib import Path
sys.path.insert(0, sys.argv[1])
from zoo.store import fingerprint as fp

root = Path(sys.argv[1])


def now():
    closure = fp.code_closure("zoo/yy/user.py")
    from zoo.yy.user import User  # a model class: its reachable code is kept too

    closure = [str(p.relative_to(root)) for p in closure]
    return closure, fp.code_fingerprint(*closure), fp.model_fingerprint(User)


def changed(path, text):
    time.sleep(0.02)  # a new mtime even on a coarse clock
    path.write_text(text)


seen = [now()]
changed(root / "zoo" / "xx" / "foo.py", "def foo(x):\\n    return x + 2\\n")  # a module appears
seen.append(now())
changed(root / "zoo" / "xx" / "foo.py", "def foo(x):\\n    return x + 3\\n")  # and is edited
seen.append(now())
seen.append(now())  # nothing changed: the kept value
print(json.dumps(seen))
"""


def test_fingerprints_kept_in_a_process_follow_edits_and_new_modules(tmp_path):
    """A process keeps each module's fingerprint pieces and each model class's reachable code,
    and gives what a fresh process would after a module is added in another package (an import
    that named a function now names a module) and after that module is edited."""
    import subprocess

    shutil.copytree(
        HERE.parent / "zoo", tmp_path / "zoo", ignore=shutil.ignore_patterns("__pycache__")
    )
    (tmp_path / "zoo" / "xx").mkdir()
    (tmp_path / "zoo" / "xx" / "__init__.py").write_text("def foo(x):\n    return x + 1\n")
    (tmp_path / "zoo" / "yy").mkdir()
    (tmp_path / "zoo" / "yy" / "__init__.py").write_text("")
    (tmp_path / "zoo" / "yy" / "user.py").write_text(
        "from zoo.xx import foo\n\n\nclass User:\n    def use(self, x):\n        return foo(x)\n"
    )
    script = tmp_path / "kept.py"
    script.write_text(KEPT_FINGERPRINTS)

    def run(path: Path) -> list:
        out = subprocess.run(
            [sys.executable, str(path), str(tmp_path)], capture_output=True, text=True, check=True
        )
        return json.loads(out.stdout)

    kept = run(script)
    (closure_0, *first), (closure_1, *added), (closure_2, *edited), (_, *again) = kept
    assert "zoo/xx/foo.py" not in closure_0 and "zoo/xx/foo.py" in closure_1
    for module, model in (first, added, edited, again):
        assert module and model
    for i in (0, 1):  # the modules' fingerprint, the model's
        assert len({first[i], added[i], edited[i]}) == 3 and again[i] == edited[i]
    # a fresh process on the final tree agrees with the values the first one kept
    fresh = tmp_path / "fresh.py"
    fresh.write_text(KEPT_FINGERPRINTS.split("seen = [now()]")[0] + "print(json.dumps(now()))\n")
    assert run(fresh) == [closure_2, *edited]


STORED_FINGERPRINTS = """
import json, sys
sys.path.insert(0, sys.argv[1])
from zoo.store import fingerprint as fp

joints = fp.code_closure("zoo/protocol/joints.py", computing_only=True)
values = [fp.code_fingerprint(*joints), fp.definition_fingerprint(
    fp.zoo_module_file("zoo.models.ltd"), "LTD")]
print(json.dumps([values, fp._module_parts.cache_info().misses]))
"""


def test_fingerprints_of_the_zoos_code_are_stored_for_the_next_process(tmp_path):
    """A process finds the fingerprint pieces another stored under the cache folder and parses
    only what it must; after an edit, a store of garbage gives what the edited process (and a
    fresh one, as the first run was) computes."""
    import subprocess

    shutil.copytree(
        HERE.parent / "zoo", tmp_path / "zoo", ignore=shutil.ignore_patterns("__pycache__")
    )
    script = tmp_path / "stored.py"
    script.write_text(STORED_FINGERPRINTS)
    store = tmp_path / "cache" / "fingerprints"

    def run() -> tuple[list, int]:
        env = {k: v for k, v in os.environ.items() if k != "ZOO_CACHE_DIR"}
        done = subprocess.run(
            [sys.executable, "-B", str(script), str(tmp_path)],
            capture_output=True,
            text=True,
            check=True,
            env=env,
        )
        values, parsed = json.loads(done.stdout)
        return values, parsed

    first, parsed_first = run()
    stored = [json.loads(p.read_text()) for p in store.glob("*/*.json")]
    assert all(first) and len(stored) > 20
    zoo = str(tmp_path / "zoo")
    assert all(path.startswith(zoo) for entry in stored for path in entry["read"])
    again, parsed_again = run()
    assert again == first and parsed_again * 5 < parsed_first
    # a module added anywhere in the zoo may change what an import names: all read anew
    (tmp_path / "zoo" / "protocol" / "added.py").write_text("X = 1\n")
    added, parsed_added = run()
    assert added == first and parsed_added > parsed_first / 2

    metrics = tmp_path / "zoo" / "protocol" / "metrics.py"
    time.sleep(0.02)  # a new mtime even on a coarse clock
    metrics.write_text(metrics.read_text() + "\n\ndef added(x):\n    return x\n")
    edited, _ = run()
    assert edited[0] != first[0] and edited[1] == first[1]
    for stored in store.glob("*/*.json"):
        stored.write_text("{not json")
    assert run()[0] == edited


def test_a_module_that_says_it_computes_no_number_is_outside_the_evaluators_code(tmp_path):
    """A module that only presents, stores or moves results says so in a comment line of its
    own, so the evaluator's code leaves it out, with what only it reaches (no list of names
    above it in store.identity), and the line moves no fingerprint."""
    import time

    from zoo.store import identity
    from zoo.store.fingerprint import (
        COMPUTES_NO_NUMBER,
        code_closure,
        code_fingerprint,
        zoo_module_file,
    )

    evaluator = zoo_module_file("zoo.evaluation.evaluator")
    everything, computing = (
        code_closure(evaluator),
        set(code_closure(evaluator, computing_only=True)),
    )
    declared = {p for p in everything if COMPUTES_NO_NUMBER in p.read_text().splitlines()}
    assert {zoo_module_file("zoo.core.io"), zoo_module_file("zoo.evaluation.results")} <= declared
    assert {evaluator, zoo_module_file("zoo.protocol.metrics")} <= computing
    # zoo.core.version is reached only through zoo.core.io, which says it computes no number
    assert zoo_module_file("zoo.core.version") in set(everything) - computing - declared
    # the store names no module above it: the evaluation layer says which evaluator it runs
    assert not re.search(
        r"zoo\.(evaluation|report|stats|leaderboard)", Path(identity.__file__).read_text()
    )

    module = tmp_path / "module.py"
    module.write_text('"""A module."""\n\n\ndef f(x):\n    return x + 1\n')
    before = code_fingerprint(module)
    time.sleep(0.02)  # a new mtime even on a coarse clock
    module.write_text(f'"""A module."""\n\n{COMPUTES_NO_NUMBER}\n\n\ndef f(x):\n    return x + 1\n')
    assert code_fingerprint(module) == before
