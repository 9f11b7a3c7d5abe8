"""Bad input gets a clear error naming the file and line, or the option and its valid values,
and leaves no partial result files behind."""

import numpy as np
import pytest
from conftest import write_cmu_file

from zoo.cli import main
from zoo.core.errors import DataNotFoundError
from zoo.data.expmap import DataFormatError
from zoo.data.motion import load_cmu


def run_eval(root, out, *extra):
    return main(
        [
            "eval",
            "--model",
            "repeat_last",
            "--benchmark",
            "cmu",
            "--data-root",
            str(root),
            "--out",
            str(out),
            *extra,
        ]
    )


def corrupt_line(path, lineno, fields_transform):
    lines = path.read_text().splitlines()
    lines[lineno - 1] = ",".join(fields_transform(lines[lineno - 1].split(",")))
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize(
    "transform, message",
    [
        (
            lambda f: f[:-1],
            r"walking_1.txt, line 7: expected 117 comma-separated values.*found 116",
        ),
        (
            lambda f: f[:4] + ["abc"] + f[5:],
            r"walking_1.txt, line 7, column 5: 'abc' is not a number",
        ),
        (
            lambda f: f[:9] + ["nan"] + f[10:],
            r"walking_1.txt, line 7, column 10: value nan is not fin",
        ),
    ],
)
def test_malformed_file_names_file_and_line(swinging_cmu, tmp_path, capsys, transform, message):
    root, _ = swinging_cmu
    corrupt_line(root / "test" / "walking" / "walking_1.txt", 7, transform)
    with pytest.raises(DataFormatError, match=message):
        load_cmu(root, "test")
    out = tmp_path / "out"
    assert run_eval(root, out) == 2
    assert "line 7" in capsys.readouterr().err
    assert not out.exists()  # nothing half-written


def test_exp_map_numbers_read_as_pythons_float_with_blank_and_spaced_lines(tmp_path):
    """The C reader gives the bits Python's float gives, and a file with blank lines (empty or
    spaces only) and a malformed line later reads as the line-by-line reader does."""
    from zoo.data.expmap import read_expmap_file
    from zoo.data.skeleton import CMU

    rng = np.random.default_rng(0)
    values = rng.standard_normal((5, CMU.num_channels)) * 10.0 ** rng.integers(-8, 8, (5, 1))
    texts = [[repr(float(v)) for v in row] for row in values]
    texts[0][:4] = ["-0", "1e-310", " 0.1 ", "123456789.123456789123"]  # subnormal, spaces
    path = tmp_path / "frames.txt"
    body = [",".join(row) for row in texts]
    expected = np.array([[float(v) for v in row] for row in texts])
    for blank in ("", "   "):  # numpy's reader skips the first; the second is read by line
        path.write_text("\n".join([body[0], "", body[1], blank, *body[2:]]) + "\n")
        assert read_expmap_file(path, CMU).tobytes() == expected.tobytes()
    path.write_text("\n".join([body[0], "   ", body[1], body[2][: body[2].rindex(",")]]))
    with pytest.raises(DataFormatError, match=r"frames.txt, line 4: expected 117 .*found 116"):
        read_expmap_file(path, CMU)
    path.write_text(" \n\n")
    with pytest.raises(DataFormatError, match=r"frames.txt: file holds no frames"):
        read_expmap_file(path, CMU)


def test_empty_action_folder_is_an_error(swinging_cmu, tmp_path, capsys):
    root, _ = swinging_cmu
    (root / "test" / "running").mkdir()
    assert run_eval(root, tmp_path / "out") == 2
    assert "test/running: action folder holds no running_<n>.txt file" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_missing_data_root_says_what_to_pass(tmp_path, capsys):
    assert run_eval(tmp_path / "nowhere", tmp_path / "out") == 2
    err = capsys.readouterr().err
    assert "nowhere for CMU Mocap (exp-map layout) does not exist" in err and "--data-root" in err
    with pytest.raises(DataNotFoundError):
        load_cmu(tmp_path / "nowhere")


def test_unknown_sampler_lists_valid_ones(swinging_cmu, tmp_path, capsys):
    root, _ = swinging_cmu
    assert run_eval(root, tmp_path / "out", "--sampler", "random9") == 2
    err = capsys.readouterr().err
    # the samplers of this benchmark: rand256 is Human3.6M's, not offered for CMU
    assert (
        "--sampler 'random9': unknown for benchmark cmu; valid: ltd8, all (its tables), allK" in err
    )
    assert "rand256" not in err
    assert not (tmp_path / "out").exists()
    assert run_eval(root, tmp_path / "out", "--sampler", "rand256") == 2
    assert "--sampler rand256: defined for Human3.6M" in capsys.readouterr().err


def test_file_too_short_for_ltd8(tmp_path, capsys):
    write_cmu_file(tmp_path / "cmu" / "test" / "walking" / "walking_1.txt", np.zeros(100))
    assert run_eval(tmp_path / "cmu", tmp_path / "out", "--sampler", "ltd8") == 2
    assert "50 frames; ltd8 needs more than 75" in capsys.readouterr().err


def test_interrupted_write_leaves_no_partial_file(tmp_path, monkeypatch):
    from zoo.core import io

    target = tmp_path / "results.csv"
    with pytest.raises(RuntimeError):
        with io.atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("disk full")
    assert list(tmp_path.iterdir()) == []


def test_a_misnamed_action_folder_is_refused_before_anything_is_scored(tmp_path, capsys):
    """test/Walking where the benchmark expects test/walking: one line naming the folder
    expected and the folders found, never a table scored on the other action alone."""
    root = tmp_path / "cmu"
    write_cmu_file(root / "test" / "Walking" / "walking_1.txt", 0.01 * np.arange(200))
    write_cmu_file(root / "test" / "running" / "running_1.txt", 0.01 * np.arange(200))
    assert run_eval(root, tmp_path / "out") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert f"{root / 'test' / 'walking'}: no folder for action 'walking' of the benchmark" in err
    assert f"found in {root / 'test'}: Walking, running; is 'Walking' meant to be 'walking'?" in err
    assert not (tmp_path / "out").exists()


def test_an_absent_or_extra_action_folder_is_a_warning_and_a_declared_one_is_not(tmp_path, capsys):
    root = tmp_path / "cmu"
    write_cmu_file(root / "test" / "walking" / "walking_1.txt", 0.01 * np.arange(200))
    actions = ("walking", "running")
    load_cmu(root, "test", actions)
    load_cmu(root, "test", actions)
    (warning,) = capsys.readouterr().err.splitlines()  # once a process
    assert warning.startswith(f"warning: {root / 'test'}: no folder for action(s) running of ")
    assert "scored without them" in warning
    (root / "MISSING.txt").write_text("MISSING cmu/test/running/running_1.txt\n")
    write_cmu_file(root / "test" / "walking_extra" / "walking_extra_1.txt", np.zeros(200))
    assert load_cmu(root, "test", actions).actions_present == ("walking",)
    assert capsys.readouterr().err == ""  # the release's own extra folder: nothing to say
    write_cmu_file(root / "test" / "walking_old" / "walking_old_1.txt", np.zeros(200))
    assert load_cmu(root, "test", actions).actions_present == ("walking",)
    (only,) = capsys.readouterr().err.splitlines()
    assert only == (
        f"warning: {root / 'test'}: folder(s) walking_old are no action of the benchmark "
        "(walking, running); their files are not read"
    )


def test_a_bvh_root_that_is_missing_or_holds_no_trial_is_one_line(tmp_path, capsys):
    (tmp_path / "cmu_bvh_copy" / "trials").mkdir(parents=True)
    for root, said in (
        (tmp_path / "cmu_bvh", "CMU BVH folder not found"),
        (tmp_path / "cmu_bvh_copy", "no BVH trials (expected MANIFEST.tsv or data/NNN/NN_TT.bvh)"),
    ):
        args = ["eval", "--model", "repeat_last", "--benchmark", "cmu_anny_oi_low"]
        assert main([*args, "--data-root", str(root), "--out", str(tmp_path / "out")]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and f"{root}: {said}" in err
    assert "found in" in err and "trials" in err


@pytest.mark.parametrize(
    "text, refused",
    [
        ("a: 1\nb: {x: 1, x: 2}\n", "line 2, column 11: key 'x' is written twice"),
        ("base: &b {a: 1}\nmid: &m\n  <<: *b\n  a: 2\ntop:\n  <<: *m\n  c: 3\n", None),
        # an anchor written inside a merge: merging rewrites its keys before it is built
        ("base: &b {a: 1}\ntop:\n  <<: &m\n    <<: *b\n    a: 2\nlater: *m\n", None),
    ],
)
def test_a_key_written_twice_is_refused_and_a_merge_override_is_not(text, refused):
    import yaml

    from zoo.core.io import load_yaml, yaml_problem

    if refused is None:
        assert load_yaml(text) == yaml.safe_load(text)
        return
    with pytest.raises(yaml.YAMLError) as caught:
        load_yaml(text)
    assert yaml_problem(caught.value) == refused
