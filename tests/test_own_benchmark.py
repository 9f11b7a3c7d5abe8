"""A benchmark of one's own from outside the repository: docs/adding-a-benchmark.md's
walk-through (docs/examples/my_mocap) on five of the CMU BVH recordings."""

import csv
import shutil

import pytest
import yaml

from zoo.cli import main
from zoo.core.errors import BenchmarkError
from zoo.paths import REPO_ROOT
from zoo.protocol.benchmark import get_benchmark

EXAMPLE = REPO_ROOT / "docs" / "examples" / "my_mocap"
CMU_BVH = REPO_ROOT.parent / "shared" / "data" / "cmu_bvh"
# subject 5: a walk and three dances to train on, a dance (trial 5) to test on
TRIALS = ("05_01", "05_02", "05_03", "05_04", "05_05")


@pytest.fixture
def own(tmp_path, monkeypatch):
    """The example's two files in a folder of one's own (the working folder), and a data folder
    of five recordings with their manifest."""
    if not (CMU_BVH / "MANIFEST.tsv").is_file():
        pytest.skip(f"{CMU_BVH} not present")
    data = tmp_path / "data"
    with open(CMU_BVH / "MANIFEST.tsv", newline="") as f:
        reader = csv.DictReader(f, delimiter="\t")
        rows = [r for r in reader if r["path"].rsplit("/", 1)[-1][:-4] in TRIALS]
        fields = reader.fieldnames
    for row in rows:
        (data / row["path"]).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(CMU_BVH / row["path"], data / row["path"])
    with open(data / "MANIFEST.tsv", "w", newline="") as f:
        writer = csv.DictWriter(f, fields, delimiter="\t")
        writer.writeheader()
        writer.writerows(rows)
    mine = tmp_path / "mine"
    mine.mkdir()
    for file in ("my_mocap.py", "my_mocap.yaml"):
        shutil.copy(EXAMPLE / file, mine / file)
    monkeypatch.chdir(mine)
    return mine, data


def test_the_walk_through_scores_trains_ranks_compares_and_builds_a_site(own, capsys):
    mine, data = own
    given = ["--benchmark", "my_mocap.yaml", "--data-root", str(data)]
    assert main(["eval", "--model", "repeat_last", *given, "--results", "results"]) == 0
    out = ["--out", "checkpoints/my_mocap/mlp", "--no-progress", "--max-batches", "2"]
    assert main(["train", "--model", "mlp", *given, "--epochs", "1", *out]) == 0
    assert (mine / "checkpoints" / "my_mocap" / "mlp" / "best.pt").is_file()
    capsys.readouterr()
    ranked = ["--results", "results", "--checkpoints", "checkpoints", "--weights-dir", "weights"]
    assert main(["leaderboard", *given, *ranked]) == 0
    board = (mine / "results" / "my_mocap" / "stride10" / "leaderboard.md").read_text()
    assert "mlp" in board and "repeat_last" in board
    compare = ["compare", "mlp", "repeat_last", "--benchmark", "my_mocap.yaml"]
    assert main([*compare, "--results", "results"]) == 0
    said = capsys.readouterr().out
    assert "window-sampling interval" in said
    # at the benchmark's own horizons (100-500 ms at 30 fps), not CMU's
    assert "at 100 ms" in said and "at 500 ms" in said and "at 80 ms" not in said
    assert main(["site", "--results", "results"]) == 0
    assert "my_mocap" in (mine / "results" / "site" / "index.html").read_text()
    # the protocol is the file's: its own windows and horizons, its loader's skeleton
    protocol = yaml.safe_load((mine / "results" / "my_mocap" / "stride10" / "protocol.json").open())
    assert protocol["input_frames"] == 15 and protocol["fps"] == 30.0
    # nothing of it was written in the repository
    for folder in ("results", "checkpoints", "weights"):
        assert not (REPO_ROOT / folder / "my_mocap").exists()


def test_a_loader_it_cannot_call_is_one_line_naming_the_field(own, tmp_path, capsys):
    mine, data = own
    spec = yaml.safe_load((mine / "my_mocap.yaml").read_text())
    cases = {
        "no_colon": ({"loader": "my_mocap.load"}, "field 'loader': expected"),
        "no_file": ({"loader": "nosuch.py:load"}, "field 'loader': function file"),
        "misspelt": ({"loader": "my_mocap.py:lod"}, "defines no function 'lod'; it defines"),
        "option": ({"loader_options": {"rate": 2}}, "cannot be called as loader(data_root"),
    }
    for name, (change, message) in cases.items():
        path = mine / f"{name}.yaml"
        path.write_text(yaml.safe_dump({**spec, **change}))
        argv = ["eval", "--model", "repeat_last", "--benchmark", str(path)]
        assert main([*argv, "--data-root", str(data), "--results", "results"]) == 2, name
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and message in err, (name, err)
        assert str(path) in err, (name, err)
    with pytest.raises(BenchmarkError, match="returned list, expected a MotionDataset"):
        (mine / "lists.py").write_text("def load(root, split, actions=()):\n    return []\n")
        path = mine / "lists.yaml"
        path.write_text(yaml.safe_dump({**spec, "loader": "lists.py:load"}))
        get_benchmark(path).load(data)


def test_a_misspelt_field_is_one_line_naming_the_file_line_and_field(own, capsys):
    mine, data = own
    text = (mine / "my_mocap.yaml").read_text()
    line = next(i for i, t in enumerate(text.splitlines(), 1) if t.startswith("horizons_ms:"))
    path = mine / "typo.yaml"
    path.write_text(text.replace("horizons_ms:", "horizon_ms:"))
    assert main(["eval", "--model", "repeat_last", "--benchmark", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert f"{path}, line {line}: unknown field 'horizon_ms' (did you mean 'horizons_ms'?)" in err


def test_a_field_written_twice_is_refused_at_its_second_line(own, capsys):
    mine, _ = own
    text = (mine / "my_mocap.yaml").read_text().rstrip("\n") + "\n"
    path = mine / "twice.yaml"
    path.write_text(text + "horizons_ms: [100]\n")  # YAML alone would read the last one
    assert main(["eval", "--model", "repeat_last", "--benchmark", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    line = len(text.splitlines()) + 1
    assert err.endswith(
        f"{path}: not valid YAML: line {line}, column 1: key 'horizons_ms' is written twice"
    )


@pytest.mark.parametrize(
    "added, message",
    [
        ("spectral_k: 8", "field 'spectral_k': belongs to mesh benchmarks"),
        ("val_split: tail", "field 'val_split': input should be 'auto', 'tails'"),
    ],
)
def test_a_field_the_benchmark_cannot_have_names_its_line(own, added, message):
    """A mesh field in a joints benchmark, or a validation rule no recipe knows, is refused
    when the file is read (not when a model trains), at the line that writes it."""
    mine, _ = own
    key = added.split(":")[0]
    lines = (mine / "my_mocap.yaml").read_text().splitlines()
    text = "".join(f"{t}\n" for t in lines if not t.startswith(f"{key}:"))
    path = mine / "added.yaml"
    path.write_text(text + added + "\n")
    with pytest.raises(BenchmarkError) as refused:
        get_benchmark(path)
    assert f"{path}, line {len(text.splitlines()) + 1}: {message}" in str(refused.value)


def test_recordings_the_file_does_not_describe_are_refused_when_loaded(own):
    """A loader's recordings must be some, of the shape the skeleton gives, at one rate."""
    mine, data = own
    spec = yaml.safe_load((mine / "my_mocap.yaml").read_text())
    loader = spec["loader"].split(":")[1]
    cases = {
        "none": ("ds.sequences = []", "returned no recordings for split"),
        "shape": (
            "ds.sequences[0].positions = ds.sequences[0].positions[:, :5]",
            "has positions of shape \\(",
        ),
        "rate": ("ds.sequences[0].fps = 2 * ds.fps", "a benchmark's recordings share one"),
    }
    for name, (change, message) in cases.items():
        (mine / f"{name}.py").write_text(
            f"from my_mocap import {loader} as base\n\n\ndef load(root, split, **options):\n"
            f"    ds = base(root, split, **options)\n    {change}\n    return ds\n"
        )
        path = mine / f"{name}.yaml"
        path.write_text(yaml.safe_dump({**spec, "loader": f"{name}.py:load"}))
        with pytest.raises(BenchmarkError, match=message):
            get_benchmark(path).load(data)


def test_a_row_depends_on_its_own_loader_the_modules_beside_it_and_its_options(own):
    import os

    from zoo.evaluation.pipeline import row_code

    mine, _ = own
    (mine / "lab.py").write_text(
        "from lab_units import scale\n\ndef load(root, split):\n    return scale\n"
    )
    units = mine / "lab_units.py"
    units.write_text("scale = 1.0\n")
    spec = yaml.safe_load((mine / "my_mocap.yaml").read_text())
    path = mine / "lab.yaml"

    def fingerprint(**change) -> str:
        path.write_text(yaml.safe_dump({**spec, "loader": "lab.py:load", **change}))
        return row_code(None, get_benchmark(path))["evaluator"]

    before = fingerprint()
    assert fingerprint() == before
    units.write_text("scale = 25.4\n")
    os.utime(units, ns=(units.stat().st_mtime_ns + 10**9,) * 2)
    after_helper = fingerprint()
    assert after_helper != before  # a module beside the loader changed
    assert fingerprint(loader_options={"rate": 2}) != after_helper
    assert fingerprint(skeleton="zoo.data.skeleton:CMU") != after_helper
