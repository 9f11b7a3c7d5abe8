"""A researcher's own model and weights from outside the repository: a row's identity covers
the files its model reads while built, its code fingerprint follows namespace packages and never
walks into an installed library."""

from __future__ import annotations

import sys
import textwrap
import time

import pytest
import torch
from test_store import board_args, cli, write_project

from zoo.evaluation.results import read_table

SCALED = """\
from pathlib import Path

import torch
from torch import nn


class Scaled(nn.Module):
    \"\"\"The last velocity, scaled by a factor from a file: read in the constructor from
    {where}.\"\"\"

    def __init__(self, input_frames, output_frames, num_points, factors="factors.pth"):
        super().__init__()
        self.output_frames = output_frames
        path = {path}
        self.scale = nn.Parameter(torch.load(path, weights_only=True)["scale"])

    def forward(self, history):
        last, velocity = history[:, -1:], history[:, -1:] - history[:, -2:-1]
        steps = torch.arange(1, self.output_frames + 1, dtype=history.dtype)
        return last + self.scale * velocity * steps.view(1, -1, 1, 1)
"""


def write_scaled(project, path_expression: str, where: str, hparams: str = "{}"):
    folder = project / "scaled"
    folder.mkdir()
    (folder / "scaled.py").write_text(SCALED.format(path=path_expression, where=where))
    (folder / "registry.yaml").write_text(
        textwrap.dedent(f"""\
        models:
          scaled:
            class: scaled.py:Scaled
            representation: joints
            hparams: {hparams}
        """)
    )
    return folder


def write_chain(package, name: str, files: int) -> None:
    """A package whose ``name`` reaches ``files`` modules, one calling the next (a library's
    depth, as torch's ``relu`` reaches much of torch)."""
    package.mkdir(parents=True)
    top = package.name
    (package / "__init__.py").write_text(f"from {top}.m0 import f as {name}\n")
    for i in range(files):
        call = f"from {top}.m{i + 1} import f as g\n" if i + 1 < files else "g = abs\n"
        (package / f"m{i}.py").write_text(f"{call}\n\ndef f(x):\n    return g(x) + {i}\n")


def save_factor(file, scale: float) -> None:
    torch.save({"scale": torch.tensor(scale)}, file)


def scaled_value(project) -> float:
    frame = read_table(project / "results" / "cmu" / "ltd8").frame
    return float(frame[frame.model == "scaled"]["value"].sum())


def test_a_weights_file_swapped_beside_an_outside_class_makes_its_row_stale(tmp_path, capsys):
    """The trial's swap: the wrapper loads its weights in its constructor; the file is replaced
    at the same path; a plain rebuild recomputes the row and names the file, and --check
    names it as the cause."""
    project = write_project(tmp_path)
    folder = write_scaled(project, 'Path(__file__).parent / "factors.pth"', "a file beside it")
    save_factor(folder / "factors.pth", 0.5)
    code, _, err = cli(capsys, "leaderboard", *board_args(project, "scaled"))
    assert code == 0, err
    before = scaled_value(project)

    save_factor(folder / "factors.pth", 0.9)  # another model's weights, the same path
    code, _, err = cli(capsys, "leaderboard", *board_args(project, "scaled"))
    assert code == 0, err
    assert "recomputing scaled: model.reads.factors.pth: stored" in err
    assert "scaled: reused" not in err
    assert scaled_value(project) != before

    save_factor(folder / "factors.pth", 0.5)
    check = [a for a in board_args(project, "scaled") if a != "--out"]
    check[check.index(project / "results")] = "--results"
    check.insert(check.index("--results") + 1, project / "results")
    code, _, err = cli(capsys, "leaderboard", "--check", *check)
    assert code == 1
    assert "scaled: a file its model reads changed: model.reads.factors.pth" in err


def test_a_file_named_by_a_hyper_parameter_is_part_of_the_identity(tmp_path, capsys):
    """A file a hyper-parameter names is covered even where the constructor opens it in a way
    Python's audit hook does not see (here: it is read at the first forward, lazily)."""
    project = write_project(tmp_path)
    folder = write_scaled(
        project,
        "Path(__file__).parent / factors",
        "the file its hyper-parameter names",
        hparams="{factors: " + str(tmp_path / "scaled" / "mine.pth") + "}",
    )
    save_factor(folder / "mine.pth", 0.5)
    assert cli(capsys, "leaderboard", *board_args(project, "scaled"))[0] == 0
    protocol = (project / "results" / "cmu" / "ltd8" / "scaled" / "protocol.json").read_text()
    assert '"mine.pth"' in protocol

    save_factor(folder / "mine.pth", 0.7)
    code, _, err = cli(capsys, "leaderboard", *board_args(project, "scaled"))
    assert code == 0 and "recomputing scaled: model.reads.mine.pth: stored" in err


def test_an_edit_inside_a_namespace_package_beside_the_class_moves_its_fingerprint(
    tmp_path, monkeypatch
):
    """``from parts import layers`` where ``parts/`` has no ``__init__.py``, as many research
    checkouts have: an edit in ``parts/layers.py`` makes the model's rows stale."""
    from zoo.models.registry import Registry
    from zoo.store.fingerprint import model_fingerprint

    monkeypatch.setattr(sys, "path", list(sys.path))

    def fingerprint(folder, activation: str, import_line: str) -> str:
        (folder / "parts").mkdir(parents=True)
        (folder / "parts" / "layers.py").write_text(
            f"from torch import nn\n\n\ndef block():\n    return nn.{activation}()\n"
        )
        (folder / "wrapper.py").write_text(
            f"from torch import nn\n{import_line}\n\n\nclass Wrapper(nn.Module):\n"
            "    def __init__(self, **_):\n        super().__init__()\n"
            "        self.act = layers.block()\n\n"
            "    def forward(self, history):\n        return self.act(history)\n"
        )
        (folder / "my.yaml").write_text(
            "models:\n  mine:\n    class: wrapper.py:Wrapper\n    representation: joints\n"
        )
        for name in ("parts", "parts.layers"):
            sys.modules.pop(name, None)
        return model_fingerprint(Registry.from_files(folder / "my.yaml").get("mine").load_class())

    for i, line in enumerate(("from parts import layers", "import parts.layers as layers")):
        tanh = fingerprint(tmp_path / f"a{i}", "Tanh", line)
        assert fingerprint(tmp_path / f"b{i}", "Tanh", line) == tanh  # another folder
        assert fingerprint(tmp_path / f"c{i}", "ReLU", line) != tanh


def test_another_environments_site_packages_is_a_library_not_researcher_code(tmp_path, monkeypatch):
    """The trial's layered environment: a second environment's site-packages added with
    ``site.addsitedir`` (torch among them) is not walked as researcher code; the fingerprint
    finishes in seconds and covers no file there."""
    import site

    from zoo.models.registry import Registry
    from zoo.store.fingerprint import reachable_code

    monkeypatch.setattr(sys, "path", list(sys.path))
    other = tmp_path / "other-env" / "site-packages"
    (other / "einops_like").mkdir(parents=True)
    (other / "einops_like" / "__init__.py").write_text("def rearrange(x):\n    return x\n")
    (other / "einops_like-0.8.dist-info").mkdir()
    # torch as the other environment has it: a large package by the same name
    write_chain(other / "torch", "relu", 300)
    (other / "extra.pth").write_text(str(tmp_path / "other-env" / "lib-extra") + "\n")
    site.addsitedir(str(other))
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "wrapper.py").write_text(
        "import torch\nfrom einops_like import rearrange\nfrom torch import nn\n\n\n"
        "class Wrapper(nn.Module):\n    def forward(self, history):\n"
        "        return rearrange(torch.relu(history))\n"
    )
    (folder / "my.yaml").write_text(
        "models:\n  mine:\n    class: wrapper.py:Wrapper\n    representation: joints\n"
    )
    cls = Registry.from_files(folder / "my.yaml").get("mine").load_class()
    started = time.monotonic()
    pieces = reachable_code(cls)
    assert time.monotonic() - started < 30
    assert pieces and all(not p.startswith(("torch/", "m1.py", "__init__.py")) for p in pieces)
    assert any(p.endswith("import::from einops_like import rearrange") for p in pieces)


def test_a_walk_into_thousands_of_files_stops_with_one_line(tmp_path, monkeypatch):
    """Past its bound the walk stops, naming the folder that brought the files in."""
    from zoo.store import fingerprint

    monkeypatch.setattr(sys, "path", list(sys.path))
    monkeypatch.setattr(fingerprint._Walk, "MAX_FILES", 20)
    checkout = tmp_path / "checkout"
    write_chain(checkout / "big", "relu", 40)
    (tmp_path / "wrapper.py").write_text(
        "import big\nfrom torch import nn\n\n\nclass Wrapper(nn.Module):\n"
        "    def forward(self, history):\n        return big.relu(history)\n"
    )
    sys.path.insert(0, str(checkout))
    monkeypatch.delitem(sys.modules, "big", raising=False)
    (tmp_path / "my.yaml").write_text(
        "models:\n  mine:\n    class: wrapper.py:Wrapper\n    representation: joints\n"
    )
    from zoo.models.registry import Registry

    cls = Registry.from_files(tmp_path / "my.yaml").get("mine").load_class()
    try:
        fingerprint.reachable_code(cls)
    except fingerprint.FingerprintError as e:
        message = str(e)
    else:
        raise AssertionError("the walk was not bounded")
    assert "more than 20 files outside the zoo" in message and str(checkout / "big") in message


def test_an_outside_models_rows_get_a_card_and_nothing_is_written_in_the_repository(
    tmp_path, capsys
):
    """With --results outside the repository, zoo cards and zoo site write only there; the
    outside model gets a card from its registry entry, its site row links to it, and its
    command to compute the row again names its registry and results folder."""
    from zoo.paths import REPO_ROOT

    project = write_project(tmp_path)
    folder = write_scaled(project, 'Path(__file__).parent / "factors.pth"', "a file beside it")
    save_factor(folder / "factors.pth", 0.5)
    registry = folder / "registry.yaml"
    registry.write_text(
        registry.read_text() + "    description: the last velocity, scaled by a factor\n"
    )

    def repository_files():
        watched = [REPO_ROOT / "README.md", *(REPO_ROOT / "docs" / "models").iterdir()]
        watched += [*(REPO_ROOT / "results").iterdir(), *(REPO_ROOT / "weights").iterdir()]
        return {p: p.stat().st_mtime_ns for p in watched} | {
            "site": (REPO_ROOT / "site").stat().st_mtime_ns
            if (REPO_ROOT / "site").exists()
            else None
        }

    before = repository_files()
    assert cli(capsys, "leaderboard", *board_args(project, "scaled"))[0] == 0
    results = project / "results"
    common = ["--registry", registry, "--results", results, "--weights-dir", project / "weights"]
    code, out, err = cli(capsys, "cards", *common)
    assert code == 0, err
    card = (results / "cards" / "scaled.md").read_text()
    assert "the last velocity, scaled by a factor" in card
    assert "(../cmu/ltd8/leaderboard.md)" in card
    code, out, err = cli(capsys, "site", *common)
    assert code == 0, err
    assert (
        f"wrote {len(list((results / 'site').glob('*.html')))} pages to {results / 'site'}" in out
    )
    assert "warning: " + str(results / "cards") not in err
    assert (results / "site" / "model-scaled.html").is_file()
    table = (results / "site" / "table-cmu-ltd8.html").read_text()
    assert "zoo eval --model scaled --registry registry.yaml --benchmark cmu" in table
    assert f"--out {(results / 'cmu' / 'ltd8' / 'scaled').resolve()}" in table
    assert repository_files() == before


def test_a_model_answering_in_metres_is_refused_naming_the_unit(tmp_path, capsys):
    """The trial's third mistake: a model predicting in metres where CMU gives millimetres
    scored about 474 mm at 1000 ms, exit 0. Now one line, naming the likely unit."""
    project = write_project(tmp_path)
    folder = project / "metres"
    folder.mkdir()
    (folder / "metres.py").write_text(
        "from torch import nn\n\n\nclass Metres(nn.Module):\n"
        "    def __init__(self, input_frames, output_frames, num_points):\n"
        "        super().__init__()\n        self.output_frames = output_frames\n\n"
        "    def forward(self, history):\n"
        "        return history[:, -1:].repeat(1, self.output_frames, 1, 1) / 1000\n"
    )
    (folder / "registry.yaml").write_text(
        "models:\n  metres:\n    class: metres.py:Metres\n    representation: joints\n"
    )
    code, _, err = cli(
        capsys,
        "eval",
        "--registry",
        folder / "registry.yaml",
        "--model",
        "metres",
        "--data-root",
        project / "cmu",
        "--sampler",
        "ltd8",
        "--out",
        tmp_path / "out",
    )
    errors = [line for line in err.splitlines() if not line.startswith("warning: ")]
    assert code == 2 and len(errors) == 1, err
    assert "predicted coordinates 0.001 times the scale of the history" in err
    assert "likely metres where the benchmark gives millimetres" in err
    assert not (tmp_path / "out").exists()


def test_refreshing_one_model_does_not_build_the_others(tmp_path, capsys):
    """``zoo leaderboard --model M`` keeps every other row as it is without building its model
    (what it costs beyond evaluating M): here another model that can no longer be built."""
    project = write_project(tmp_path)
    folder = write_scaled(project, 'Path(__file__).parent / "factors.pth"', "a file beside it")
    save_factor(folder / "factors.pth", 0.5)
    assert cli(capsys, "leaderboard", *board_args(project, "scaled"))[0] == 0
    before = scaled_value(project)
    (folder / "factors.pth").unlink()  # scaled cannot be built any more
    code, _, err = cli(
        capsys, "leaderboard", "--model", "repeat_last", *board_args(project, "scaled")
    )
    assert code == 0, err
    assert scaled_value(project) == before


def test_nested_recordings_each_see_their_files_and_leave_none_behind(tmp_path):
    """A wrapper whose constructor builds another registered model records inside a
    recording: each sees what was opened within it, and both end cleanly."""
    from zoo.core import files_read

    first, second = tmp_path / "a.npy", tmp_path / "b.npy"
    first.write_bytes(b"a")
    second.write_bytes(b"b")
    with files_read.recording_files_read() as outer:
        first.read_bytes()
        with files_read.recording_files_read() as inner:
            second.read_bytes()
    assert inner == {second.resolve()} and outer == {first.resolve(), second.resolve()}
    assert files_read._recorders == []


def test_a_weights_pth_beside_the_code_leaves_the_folder_researcher_code(tmp_path):
    """A folder is a library when it holds a site .pth, but a git-lfs pointer or a weights
    file named .pth beside the authors' code is neither."""
    from zoo.store.fingerprint import _holds_installed

    (tmp_path / "model.pth").write_text(
        "version https://git-lfs.github.com/spec/v1\noid sha256:abc\nsize 604729\n"
    )
    (tmp_path / "empty.pth").write_text("")
    assert not _holds_installed(str(tmp_path), 1)
    (tmp_path / "lib").mkdir()
    (tmp_path / "extra.pth").write_text("lib\n")
    assert _holds_installed(str(tmp_path), 2)


LAST = """\
import torch
from torch import nn


class Last(nn.Module):
    def __init__(self, input_frames, output_frames, num_points, gain=1.0):
        super().__init__()
        self.output_frames = output_frames
        self.gain = nn.Parameter(torch.tensor(gain))

    def forward(self, history):
        return self.gain * history[:, -1:].repeat(1, self.output_frames, 1, 1)


class Unchanged(Last):
    def forward(self, history):
        return history
"""

# A researcher's slips with a model of their own: (files beside the registry, the registry's
# entry or text, the command after `zoo`, what the one line must say)
MISTAKES = {
    "registry not there": ({}, None, ["--registry", "{f}/nope.yaml"], "nope.yaml does not exist"),
    "registry not YAML": ({}, "models:\n  last: [\n", [], "not valid YAML: line 3, column 1"),
    "class file not there": ({}, "nothere.py:Last", [], "nothere.py does not exist"),
    "class misspelt": ({}, "last.py:Lats", [], "defines no class 'Lats'; it defines Last"),
    "a dependency missing": (
        {"needs.py": "import einops\n"},
        "needs.py:X",
        [],
        "No module named 'einops'",
    ),
    "a syntax error": ({"broken.py": "def f(:\n"}, "broken.py:X", [], "broken.py, line 1"),
    "a field misspelt": ({}, "last.py:Last\n    hparam: {gain: 2}", [], "did you mean 'hparams'?"),
    "a field written twice": (
        {},
        "last.py:Last\n    hparams: {gain: 2}\n    hparams: {gain: 3}",
        [],
        "key 'hparams' is written twice",
    ),
    "a hyper-parameter misspelt": (
        {},
        "last.py:Last\n    hparams: {gian: 2}",
        [],
        "does not accept gian",
    ),
    "the model misspelt": ({}, "last.py:Last", ["--model", "lats"], "did you mean last?"),
    "the wrong output shape": ({}, "last.py:Unchanged", [], "expects (8, 25, 25, 3)"),
    "the authors' .pth as --weights": (
        {},
        "last.py:Last",
        ["--weights", "{m}/model.pth"],
        "import it first: zoo weights import",
    ),
    "the authors' .pth as --checkpoint": (
        {},
        "last.py:Last",
        ["--checkpoint", "{m}/model.pth"],
        "import it first: zoo weights import",
    ),
    "a state dict that does not fit": (
        {},
        "last.py:Last",
        ["weights", "import", "{m}/model.pth", "--benchmark", "cmu", "--weights-dir", "{f}/w"],
        "gain (3,) vs the model's ()",
    ),
    "the sampler misspelt": ({}, "last.py:Last", ["--sampler", "ltd9"], "--sampler 'ltd9'"),
    "the data elsewhere": ({}, "last.py:Last", ["--data-root", "{f}/none"], "--data-root"),
}


@pytest.fixture(scope="module")
def mistakes_project(tmp_path_factory):
    project = write_project(tmp_path_factory.mktemp("mistakes"))
    (project / "m").mkdir()
    torch.save({"gain": torch.ones(3)}, project / "m" / "model.pth")
    return project


@pytest.mark.parametrize("mistake", list(MISTAKES))
def test_each_mistake_of_the_trial_gets_one_line_naming_what_to_mend(
    mistake, mistakes_project, capsys
):
    """The trial's 14 mistakes and kin: each ends the command with one line (no traceback, no
    torch key list), naming the file, field or argument."""
    project = mistakes_project
    m = project / "m"
    files, entry, command, expected = MISTAKES[mistake]
    folder = m / mistake.replace(" ", "_").replace("'", "").replace(".", "")
    folder.mkdir()
    for name, text in files.items():
        (folder / name).write_text(text)
    registry = folder / "registry.yaml"
    if entry is not None and entry.startswith("models:"):
        registry.write_text(entry)
    elif entry is not None:
        (folder / "last.py").write_text(LAST)
        registry.write_text(f"models:\n  last:\n    class: {entry}\n    representation: joints\n")
    command = [a.format(m=m, f=folder) for a in command]
    if command[:1] == ["weights"]:
        args = [*command, "--model", "last", "--registry", registry]
    else:  # zoo eval, the mistake's arguments taking the place of the defaults they name
        defaults = {"--registry": registry, "--model": "last", "--data-root": project / "cmu"}
        defaults |= {"--sampler": "ltd8", "--out": folder / "out"}
        args = [
            "eval",
            *command,
            *(x for k, v in defaults.items() if k not in command for x in (k, v)),
        ]
    code, _, err = cli(capsys, *args)
    errors = [line for line in err.splitlines() if line and not line.startswith("warning: ")]
    assert code == 2, err
    assert len(errors) == 1 and "Traceback" not in err, err
    assert expected in errors[0], err
    assert not (folder / "out").exists()
