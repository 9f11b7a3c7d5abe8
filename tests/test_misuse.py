"""User mistakes end in one clear line and a non-zero exit, never a traceback, and nothing of
the user's is touched (issue: reliability). Each case was a traceback or worse before."""

import textwrap

import numpy as np
import pytest
from conftest import write_cmu_file

from zoo.cli import main


@pytest.fixture
def root(tmp_path):
    for split in ("train", "test"):
        write_cmu_file(
            tmp_path / "cmu" / split / "walking" / "walking_1.txt", 0.01 * np.arange(400)
        )
    return tmp_path / "cmu"


def run(capsys, *args):
    code = main(list(args))
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err.strip().splitlines()[-1] if err.strip() else ""


@pytest.mark.parametrize(
    "args, message",
    [
        (
            ["train", "--model", "mlp", "--max-batches", "0", "--epochs", "1"],
            "--max-batches: must be a positive integer, got 0",
        ),
        (
            ["train", "--model", "mlp", "--seed", "-1", "--epochs", "1"],
            "seed must be an integer in 0..2**32-1, got -1",
        ),
        (
            ["train", "--model", "spgsn", "--set", "dropout=1.5", "--epochs", "1"],
            "model 'spgsn': SPGSN: dropout must be a probability in [0, 1), got 1.5",
        ),
        (
            ["train", "--model", "mlp", "--train-set", "schedule={type:step}"],
            "field 'schedule': a schedule names its type",
        ),
        (
            ["train", "--model", "mlp", "--device", "banana"],
            "--device 'banana': not a torch device",
        ),
        (
            ["eval", "--model", "repeat_last", "--set", "input_frames=12"],
            "--set input_frames: fixed by the benchmark (cmu)",
        ),
        (
            ["eval", "--model", "spgsn", "--set", "blocks=0"],
            "model 'spgsn': SPGSN: blocks must be an integer >= 1, got 0",
        ),
        (["eval", "--model", "repeat_last", "--out", "/proc/zoo-denied/x"], "cannot be written"),
        (
            ["data", "describe", "cmu", "--split", "val"],
            "--split 'val': benchmark cmu has splits test (test) and train (train), or 'all'",
        ),
    ],
)
def test_mistakes_end_in_one_line(capsys, root, tmp_path, args, message):
    extra = ["--data-root", str(root)] if args[0] in ("train", "eval", "data") else []
    if args[0] == "train":
        extra += ["--out", str(tmp_path / "run")]
    code, last = run(capsys, *args, *extra)
    assert code == 2 and message in last


def test_cuda_on_a_machine_without_it_is_named(capsys, root):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    code, last = run(
        capsys, "eval", "--model", "repeat_last", "--device", "cuda:0", "--data-root", str(root)
    )
    assert code == 2 and "--device cuda:0: this machine has no CUDA device" in last


def test_out_never_replaces_what_is_not_a_zoo_result(capsys, root, tmp_path):
    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    code, last = run(
        capsys,
        "eval",
        "--model",
        "repeat_last",
        "--sampler",
        "ltd8",
        "--data-root",
        str(root),
        "--out",
        str(notes),
    )
    assert code == 2 and "exists and is not a folder" in last and notes.read_text() == "mine"
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("years of work")
    code, last = run(
        capsys,
        "eval",
        "--model",
        "repeat_last",
        "--sampler",
        "ltd8",
        "--data-root",
        str(root),
        "--out",
        str(mine),
    )
    assert code == 2 and "not one the zoo wrote" in last
    assert (mine / "thesis.tex").read_text() == "years of work"


def test_empty_checkpoint_names_the_file_and_the_fix(capsys, root, tmp_path):
    (tmp_path / "empty.pt").write_bytes(b"")
    code, last = run(
        capsys, "eval", "--checkpoint", str(tmp_path / "empty.pt"), "--data-root", str(root)
    )
    assert code == 2 and "empty.pt is empty, truncated or not a motion-zoo checkpoint" in last
    code, last = run(capsys, "weights", "export", str(tmp_path / "empty.pt"))
    assert code == 2 and "train again, or restore the file" in last


def test_ctrl_c_ends_in_one_line(capsys, monkeypatch, root, tmp_path):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("zoo.evaluation.pipeline.evaluate_models", interrupted)
    code, last = run(
        capsys,
        "eval",
        "--model",
        "repeat_last",
        "--data-root",
        str(root),
        "--out",
        str(tmp_path / "out"),
    )
    assert code == 130 and last.startswith("zoo eval: interrupted")


def test_a_user_model_raising_while_built_gets_one_line_then_its_own_frames(capsys, root, tmp_path):
    (tmp_path / "mine.py").write_text(
        textwrap.dedent("""\
        import torch

        class Broken(torch.nn.Module):
            def __init__(self, input_frames, output_frames, num_points):
                super().__init__()
                raise ValueError("my own bug")
        """)
    )
    registry = tmp_path / "registry.yaml"
    registry.write_text(
        "models:\n  broken: {class: mine.py:Broken, representation: joints, reference: mine}\n"
    )
    code = main(
        ["eval", "--registry", str(registry), "--model", "broken", "--data-root", str(root)]
    )
    err = capsys.readouterr().err
    assert code == 1
    assert (
        f"zoo: model 'broken' (mine.py:Broken, registry {registry}) raised while being "
        f"built:" in err
    )
    # then its own frames only, as for a raise in its forward
    assert "your code raised ValueError: my own bug" in err
    assert 'mine.py", line 6, in __init__' in err and "zoo/models/registry.py" not in err


def test_model_names_cannot_escape_the_results_folder(capsys, tmp_path):
    registry = tmp_path / "registry.yaml"
    registry.write_text("models:\n  ../../evil: {class: x.py:X, representation: joints}\n")
    code, last = run(capsys, "list", "--registry", str(registry))
    assert code == 2 and "model '../../evil': a model name is letters, digits" in last


def test_binary_data_skipped_files_and_damaged_caches_are_named(capsys, root, tmp_path):
    (root / "test" / "walking" / "README.md").write_text("about these files")
    (root / "test" / "dancing").mkdir()
    code, _ = run(
        capsys,
        "eval",
        "--model",
        "repeat_last",
        "--sampler",
        "all",
        "--data-root",
        str(root),
        "--out",
        str(tmp_path / "ok"),
    )
    assert code == 0
    code = main(
        [
            "eval",
            "--model",
            "repeat_last",
            "--sampler",
            "all",
            "--data-root",
            str(root),
            "--out",
            str(tmp_path / "ok"),
        ]
    )
    err = capsys.readouterr().err
    assert "skipped" not in err  # said once, by zoo data list and describe, not by every load
    assert main(["data", "list", "--data-root", str(root)]) == 0
    out = capsys.readouterr().out
    assert f"note: {root}/test/walking: skipped README.md (not walking_<n>.txt)" in out
    assert f"note: {root}/test: skipped dancing (not among the benchmark's actions" in out
    assert main(["data", "describe", "cmu", "--data-root", str(root)]) == 0
    assert "test/walking: skipped README.md" in capsys.readouterr().out
    (root / "test" / "walking" / "walking_2.txt").write_bytes(bytes(range(128, 256)) * 8)
    code, last = run(capsys, "eval", "--model", "repeat_last", "--data-root", str(root))
    assert code == 2 and "walking_2.txt: not a text file" in last

    from zoo.data.mesh import MeshDataset, MeshError, MeshSequence, MeshTopology

    mesh = MeshDataset(
        name="tiny",
        split="test",
        recipe={"builder": "test"},
        topology=MeshTopology(np.array([[0, 1, 2]]), 3),
        sequences=[MeshSequence("s", "a", np.zeros((4, 3, 3), np.float32), 25.0)],
    )
    mesh.save(tmp_path / "cache")
    (tmp_path / "cache" / "meshes.npz").write_bytes(
        (tmp_path / "cache" / "meshes.npz").read_bytes()[:100]
    )
    with pytest.raises(
        MeshError,
        match="cache: damaged or truncated dataset cache .*delete the "
        "folder and it is rebuilt on next use",
    ):
        MeshDataset.load(tmp_path / "cache")
