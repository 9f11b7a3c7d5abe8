"""The registry API, its errors, and a user's own baseline added from outside zoo/."""

import textwrap

import pandas as pd
import pytest

import zoo
from zoo.cli import main
from zoo.models.registry import Registry, RegistryError


def test_list_and_create():
    assert "repeat_last" in zoo.list_models()
    model = zoo.create_model("repeat_last", benchmark="cmu")
    assert model.output_frames == 25 and model.num_points == 25


def test_unknown_model_lists_valid_names():
    with pytest.raises(
        RegistryError, match=r"unknown model 'nope'; registered models: .*repeat_last"
    ):
        zoo.create_model("nope", benchmark="cmu")
    with pytest.raises(RegistryError, match=r"unknown model 'spgns'; did you mean spgsn\b"):
        zoo.create_model("spgns", benchmark="cmu")


def test_unknown_hparam_lists_valid_ones():
    """The model's own hyper-parameters, the benchmark's shape arguments apart (a --set of one
    of those is refused as fixed by the benchmark)."""
    with pytest.raises(
        RegistryError,
        match=r"no hyper-parameter 'depth'; its hyper-parameters: none \(input_frames, "
        r"output_frames, num_points come from the benchmark\)",
    ):
        zoo.create_model("repeat_last", benchmark="cmu", depth=3)
    with pytest.raises(
        RegistryError,
        match=r"its hyper-parameters: blocks, dct_n, dropout, hidden \(input_frames, ",
    ):
        zoo.create_model("ltd", benchmark="cmu", hiden=3)


def test_missing_shape_args_say_benchmark_supplies_them():
    with pytest.raises(RegistryError, match="needs input_frames, output_frames, num_points"):
        zoo.create_model("repeat_last")


def test_bad_registry_entry_names_file_and_field(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("models:\n  x:\n    class: a.B\n    representation: pointcloud\n")
    with pytest.raises(RegistryError, match=r"bad.yaml, line 4: model 'x': field 'representation'"):
        Registry.from_files(path)


def test_a_misspelt_field_gets_a_did_you_mean(tmp_path):
    path = tmp_path / "typo.yaml"
    path.write_text("models:\n  x:\n    class: a.B\n    representation: joints\n    hparam: {}\n")
    with pytest.raises(
        RegistryError,
        match=r"typo.yaml, line 5: model 'x': unknown field 'hparam' \(did you mean 'hparams'\?\)",
    ):
        Registry.from_files(path)
    # a field that is missing is placed at its model's line
    path.write_text("models:\n  y:\n    representation: joints\n")
    with pytest.raises(RegistryError, match=r"typo.yaml, line 2: model 'y': field 'class'"):
        Registry.from_files(path)


def test_a_class_the_file_lacks_is_named_with_the_file_and_its_classes(tmp_path):
    (tmp_path / "mine.py").write_text(BASELINE)
    path = tmp_path / "mine.yaml"
    path.write_text(
        "models:\n  mine:\n    class: mine.py:DampedVelocty\n    representation: joints\n"
    )
    registry = Registry.from_files(path)
    with pytest.raises(RegistryError) as error:
        registry.get("mine").load_class()
    text = str(error.value)
    assert f"{tmp_path / 'mine.py'} defines no class 'DampedVelocty'" in text
    assert "it defines DampedVelocity" in text and "zoo_user_" not in text


def test_a_class_file_that_fails_on_import_is_named_and_not_kept_half_loaded(tmp_path):
    (tmp_path / "broken.py").write_text("import torch\nBROKEN = torch.no_such_thing\n")
    path = tmp_path / "broken.yaml"
    path.write_text("models:\n  b:\n    class: broken.py:Model\n    representation: joints\n")
    entry = Registry.from_files(path).get("b")
    for _ in range(2):  # the second try runs the file again, not a half-run module
        with pytest.raises(RegistryError, match=r"cannot load class 'broken.py:Model' .*no_such"):
            entry.load_class()


BASELINE = '''
import torch


class DampedVelocity(torch.nn.Module):
    """Extrapolates the last observed velocity: a user's own baseline."""

    def __init__(self, input_frames, output_frames, num_points, damping=1.0):
        super().__init__()
        self.output_frames, self.damping = output_frames, damping

    def forward(self, history):
        velocity = history[:, -1] - history[:, -2]
        steps = torch.arange(1, self.output_frames + 1, dtype=history.dtype)
        return history[:, -1:] + self.damping * steps.view(1, -1, 1, 1) * velocity[:, None]
'''


def test_user_baseline_from_outside_zoo(tmp_path, swinging_cmu, capsys):
    root, _ = swinging_cmu
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "my_baselines.py").write_text(BASELINE)
    registry = tmp_path / "mine" / "registry.yaml"
    registry.write_text(
        textwrap.dedent("""\
        models:
          damped_velocity:
            class: my_baselines.py:DampedVelocity
            representation: joints
            hparams: {damping: 1.0}
            reference: a user's baseline
        """)
    )
    assert main(["list", "--registry", str(registry)]) == 0
    assert "damped_velocity" in capsys.readouterr().out
    outs = {}
    for model in ("damped_velocity", "repeat_last"):
        outs[model] = tmp_path / model
        assert (
            main(
                [
                    "eval",
                    "--registry",
                    str(registry),
                    "--model",
                    model,
                    "--benchmark",
                    "cmu",
                    "--sampler",
                    "all",
                    "--data-root",
                    str(root),
                    "--out",
                    str(outs[model]),
                ]
            )
            == 0
        )
    cv = pd.read_csv(outs["damped_velocity"] / "results.csv")
    rl = pd.read_csv(outs["repeat_last"] / "results.csv")
    assert set(cv.model) == {"damped_velocity"}
    pick = lambda df: (
        df[(df.action == "average") & (df.joints == "all38") & (df.averaging == "frame")]
        .sort_values("frame")["value"]
        .to_numpy()
    )
    # The swinging joint turns at constant angular speed: extrapolating its velocity beats
    # repeating its last position at every horizon.
    assert (pick(cv) < pick(rl)).all()
    # Overrides reach the user's class through the same validation as built-in models.
    assert (
        main(
            [
                "eval",
                "--registry",
                str(registry),
                "--model",
                "damped_velocity",
                "--set",
                "damping=0.5",
                "--sampler",
                "ltd8",
                "--data-root",
                str(root),
                "--out",
                str(tmp_path / "half"),
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "eval",
                "--registry",
                str(registry),
                "--model",
                "damped_velocity",
                "--set",
                "dampng=0.5",
                "--data-root",
                str(root),
                "--out",
                str(tmp_path / "typo"),
            ]
        )
        == 2
    )
    assert "its hyper-parameters: damping" in capsys.readouterr().err


def test_command_line_overrides_read_numbers_as_numbers():
    from zoo.cli import UsageError, parse_overrides

    got = parse_overrides(
        [
            "lr=1e-3",
            "blocks=4",
            "schedule={type: cosine, min_lr: 1e-6}",
            "name=mlp",
            "lrs=[3e-4, 1.0e-5]",
        ]
    )
    assert got == {
        "lr": 1e-3,
        "blocks": 4,
        "schedule": {"type": "cosine", "min_lr": 1e-6},
        "name": "mlp",
        "lrs": [3e-4, 1e-5],
    }
    assert isinstance(got["blocks"], int)
    with pytest.raises(UsageError, match="expects key=value, got 'lr'"):
        parse_overrides(["lr"])


def test_entry_task_is_checked(tmp_path):
    from zoo.models.registry import Registry, RegistryError

    path = tmp_path / "r.yaml"
    path.write_text(
        "models:\n  m:\n    class: zoo.models.repeat_last.RepeatLast\n"
        "    representation: joints\n    task: forecasting\n"
    )
    with pytest.raises(
        RegistryError,
        match="line 5: model 'm': field 'task': input should be 'prediction' or 'completion', "
        "got 'forecasting'",
    ):
        Registry.from_files(path)
    path.write_text(
        "models:\n  m:\n    class: zoo.models.repeat_last.RepeatLast\n"
        "    representation: joints\n    hparams: {task: completion}\n"
    )
    with pytest.raises(
        RegistryError,
        match="field 'task': the entry's task is 'prediction' but hparams say task 'completion'",
    ):
        Registry.from_files(path)


def test_a_registry_file_rewritten_in_place_is_read_anew(tmp_path):
    """A file edited to the same size with its time put back (an editor, a copy that keeps
    times) is read as it is now, not as a kept parse of it."""
    import os

    path = tmp_path / "r.yaml"
    entry = "models:\n  m:\n    class: zoo.models.repeat_last.RepeatLast\n"
    path.write_text(entry + "    representation: joints\n    description: first\n")
    stat = path.stat()
    assert Registry.from_files(path).get("m").description == "first"
    path.write_text(entry + "    representation: joints\n    description: again\n")
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert path.stat().st_size == stat.st_size and path.stat().st_mtime_ns == stat.st_mtime_ns
    assert Registry.from_files(path).get("m").description == "again"


def test_a_known_name_needs_an_explicit_override_that_results_record(
    tmp_path, swinging_cmu, capsys
):
    import json

    root, _ = swinging_cmu
    (tmp_path / "my_baselines.py").write_text(BASELINE)
    registry = tmp_path / "registry.yaml"
    entry = """\
        models:
          repeat_last:
            class: my_baselines.py:DampedVelocity
            representation: joints
            hparams: {damping: 1.0}
            reference: not the zoo's repeat_last
        """
    registry.write_text(textwrap.dedent(entry))
    args = [
        "eval",
        "--registry",
        str(registry),
        "--model",
        "repeat_last",
        "--sampler",
        "ltd8",
        "--data-root",
        str(root),
        "--out",
        str(tmp_path / "out"),
    ]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert f"{registry}, line 2: model 'repeat_last' is already defined in " in err
    assert "registry.yaml; choose another name, or add 'override: true'" in err
    registry.write_text(textwrap.dedent(entry) + "    override: true\n")
    assert main(args) == 0
    provenance = json.loads((tmp_path / "out" / "protocol.json").read_text())["provenance"]
    assert provenance["class"] == "my_baselines.py:DampedVelocity"
    assert provenance["registry"] == f"outside:{registry.name}" and provenance["replaces"].endswith(
        "registry.yaml"
    )
    # the zoo's own entries record theirs too
    assert (
        main(
            [
                "eval",
                "--model",
                "repeat_last",
                "--sampler",
                "ltd8",
                "--data-root",
                str(root),
                "--out",
                str(tmp_path / "zoo"),
            ]
        )
        == 0
    )
    provenance = json.loads((tmp_path / "zoo" / "protocol.json").read_text())["provenance"]
    assert provenance["class"] == "zoo.models.repeat_last.RepeatLast"
    assert provenance["registry"] == "registry.yaml" and "replaces" not in provenance


def test_a_model_kept_out_of_the_leaderboards_is_still_a_zoo_model():
    import torch

    from zoo.models.registry import load_registry

    registry = load_registry()
    entry = registry.get("constant_velocity")
    assert entry.leaderboard is False and registry.get("repeat_last").leaderboard is True
    model = registry.create_model(
        "constant_velocity", input_frames=3, output_frames=2, num_points=1
    )
    history = torch.tensor([[[[0.0, 0, 0]], [[1.0, 0, 0]], [[2.0, 0, 0]]]])
    assert model(history)[0, :, 0, 0].tolist() == [3.0, 4.0]


STILL = """\
from torch import nn


class Still(nn.Module):
    def __init__(self, input_frames, output_frames, num_points):
        super().__init__()
        self.output_frames = output_frames

    def forward(self, history):
        return history[:, -1:].expand(-1, self.output_frames, -1, -1)
"""


def test_the_api_takes_a_registry_files_path(tmp_path):
    """zoo.evaluate and zoo.create_model take the path of one's registry file (or a list),
    as --registry does; anything else, or a missing file, is one clear error before any data
    is read."""
    import numpy as np
    from conftest import write_cmu_file

    import zoo
    from zoo.models.registry import RegistryError

    root = tmp_path / "cmu"
    write_cmu_file(root / "test" / "walking" / "walking_1.txt", 0.01 * np.arange(400))
    (tmp_path / "still.py").write_text(STILL)
    reg = tmp_path / "my_registry.yaml"
    reg.write_text("models:\n  still:\n    class: still.py:Still\n    representation: joints\n")
    result = zoo.evaluate("still", "cmu", registry=str(reg), data_root=root, sampler="all")
    assert len(result.frame) > 0
    assert type(zoo.create_model("still", "cmu", registry=reg)).__name__ == "Still"
    assert zoo.create_model("still", "cmu", registry=[reg]) is not None
    with pytest.raises(RegistryError, match="zoo.evaluate: registry must be a zoo.Registry"):
        zoo.evaluate("still", "cmu", registry=3, data_root=tmp_path / "no data")
    with pytest.raises(RegistryError, match="registry file .*nope.yaml does not exist"):
        zoo.evaluate("still", "cmu", registry=tmp_path / "nope.yaml", data_root=tmp_path / "x")


def test_a_users_model_that_raises_in_its_forward_gets_a_short_headed_error(tmp_path, capsys):
    """The authors' .cuda() inside forward: one error line naming the exception, then only the
    frames of the researcher's own files; not a raw traceback through the zoo and torch."""
    import numpy as np
    from conftest import write_cmu_file

    root = tmp_path / "cmu"
    write_cmu_file(root / "test" / "walking" / "walking_1.txt", 0.01 * np.arange(400))
    (tmp_path / "still.py").write_text(
        STILL.replace("        return history", "        raise RuntimeError('no CUDA here')\n"
                      "        return history")
    )  # fmt: skip
    reg = tmp_path / "my_registry.yaml"
    reg.write_text("models:\n  still:\n    class: still.py:Still\n    representation: joints\n")
    code = main(
        ["eval", "--registry", str(reg), "--model", "still", "--data-root", str(root),
         "--sampler", "all", "--out", str(tmp_path / "out")]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert code == 1
    assert "zoo eval: error: your code raised RuntimeError: no CUDA here" in err
    assert "still.py" in err and "in forward" in err
    assert "zoo/evaluation/evaluator.py" not in err and "torch/nn" not in err
    assert "Traceback" not in err and len(err.strip().splitlines()) < 8


def test_an_unknown_model_defined_by_a_registry_file_here_suggests_that_file(
    tmp_path, capsys, monkeypatch
):
    (tmp_path / "still.py").write_text(STILL)
    (tmp_path / "my_registry.yaml").write_text(
        "models:\n  still:\n    class: still.py:Still\n    representation: joints\n"
    )
    (tmp_path / "other.yaml").write_text("not: [a registry\n")  # unreadable: passed over
    monkeypatch.chdir(tmp_path)
    assert main(["eval", "--model", "still", "--data-root", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "unknown model 'still'" in err
    assert "(my_registry.yaml here defines 'still': add --registry my_registry.yaml)" in err
    assert main(["eval", "--model", "nothing_defines_this", "--data-root", str(tmp_path)]) == 2
    assert "here defines" not in capsys.readouterr().err


def test_a_longer_history_is_padded_with_the_oldest_frame():
    import torch

    from zoo.models.history import pad_history

    history = torch.arange(2 * 3 * 2, dtype=torch.float32).reshape(2, 3, 2)
    padded = pad_history(history, 5)
    assert padded.shape == (2, 5, 2)
    assert torch.equal(padded[:, :3], history[:, :1].expand(-1, 3, -1))
    assert torch.equal(padded[:, 2:], history)
    assert torch.equal(pad_history(history, 2), history[:, 1:])
    with pytest.raises(ValueError, match="frames must be a positive integer"):
        pad_history(history, 0)


def test_a_class_that_cannot_load_fails_before_any_data_is_read(tmp_path, capsys):
    """zoo eval, zoo leaderboard --model and zoo train name the class file's fault at once: the
    data root given does not exist, and the error is about the class, not the data."""
    (tmp_path / "still.py").write_text(STILL)
    reg = tmp_path / "my_registry.yaml"
    reg.write_text(
        "models:\n  typo:\n    class: still.py:Stil\n    representation: joints\n"
        "    trainable: true\n"
    )
    nowhere = str(tmp_path / "no data here")
    for argv in (
        ["eval", "--model", "typo"],
        ["leaderboard", "--benchmark", "cmu", "--model", "typo"],
        ["train", "--model", "typo"],
    ):
        assert main([*argv, "--registry", str(reg), "--data-root", nowhere]) == 2, argv
        err = capsys.readouterr().err
        assert "defines no class 'Stil'; it defines Still" in err, (argv, err)


def test_a_misspelt_recipe_field_is_refused_where_the_registry_is_read(tmp_path, capsys):
    """A bad recipe fails at zoo list (any command reading the registry), not at zoo train."""
    from zoo.cli import main

    registry = tmp_path / "mine.yaml"
    registry.write_text(
        "models:\n  mine:\n    class: zoo.models.repeat_last.RepeatLast\n"
        "    representation: joints\n    trainable: true\n    train: {lr: 0.001, epoch: 5}\n"
    )
    assert main(["list", "--registry", str(registry)]) == 2
    err = capsys.readouterr().err
    assert (
        f"{registry}, line 6: model 'mine': training recipe: unknown field 'epoch' (did you mean "
        f"'epochs'?)" in err
    )
    assert len(err.strip().splitlines()) == 1


def test_a_class_file_that_raises_as_it_runs_is_one_line_with_its_line(tmp_path):
    (tmp_path / "typo.py").write_text("import torch\n\nSCALE = {'mm': 1.0}['m']\n")
    path = tmp_path / "typo.yaml"
    path.write_text("models:\n  t:\n    class: typo.py:Model\n    representation: joints\n")
    with pytest.raises(RegistryError, match=r"typo.py, line 3: running it raised KeyError: 'm'"):
        Registry.from_files(path).get("t").load_class()
