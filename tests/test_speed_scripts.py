"""The speed scripts of ``benchmarks/speed/`` import without doing any work, and each one's
``main`` runs end to end at the smallest sizes (tiny models, one repeat): a smoke test of the
scripts, not of the figures they print. speed_anny needs the ``anny`` package and the CMU BVH
data, and a warm anny cache to take seconds rather than minutes: the tests ship the low body's
build (tests/conftest.py), and anny builds the full one on its first load on a machine."""

import importlib.util
import math
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[1]
SPEED = REPO / "benchmarks" / "speed"
CMU_BVH = REPO.parent / "shared" / "data" / "cmu_bvh"
SCRIPTS = [
    "public_auxformer",
    "public_dmgnn",
    "public_ggmotion",
    "public_msrgcn_training",
    "public_spgsn",
    "public_tfan",
    "speed_anny",
    "speed_baselines",
    "speed_check",
    "speed_compile",
    "speed_eval",
    "speed_expmap",
    "speed_identity",
    "speed_intervals",
    "speed_leaderboard_model",
    "speed_pass",
    "speed_plots",
    "speed_public_cmu",
    "speed_spectral",
    "speed_spectrhums",
    "speed_spgsn",
    "speed_spgsn_training",
    "speed_training_view",
]


def load(name: str):
    """The script ``benchmarks/speed/<name>.py`` imported by its path."""
    spec = importlib.util.spec_from_file_location(f"speed_script_{name}", SPEED / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def figures(out: str) -> list[float]:
    """Every number a script printed, NaN and infinity included, so that a test can refuse a
    timing that came out as NaN (a word printed beside it proves nothing)."""
    import re

    number = r"(?:nan|inf|-?\d+(?:\.\d+)?(?:e[-+]?\d+)?)"
    words = re.findall(rf"(?<![\w.]){number}(?=x?(?![\w.]))", out)  # 1.57x: a ratio
    return [float(w) for w in words]


def assert_finite(out: str, at_least: int) -> None:
    values = figures(out)
    assert len(values) >= at_least, out
    assert all(math.isfinite(v) for v in values), [v for v in values if not math.isfinite(v)]


@pytest.fixture(autouse=True)
def one_thread():
    """One torch thread (steady on a shared machine); the scripts' own thread settings and this
    one are undone afterwards."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def test_the_folder_holds_the_speed_scripts_and_benchmarks_the_protocols():
    assert sorted(p.stem for p in SPEED.glob("*.py")) == SCRIPTS
    assert list((REPO / "benchmarks").glob("*.py")) == []


@pytest.mark.parametrize("name", SCRIPTS)
def test_importing_does_no_work(name, capsys):
    assert callable(load(name).main)
    assert capsys.readouterr().out == ""


def test_public_spgsn(capsys):
    load("public_spgsn").main(
        ["--steps", "1", "--batch-size", "2", "--num-stage", "1", "--hidden", "16"]
    )
    out = capsys.readouterr().out
    assert "training step, batch 2" in out
    assert_finite(out, at_least=3)


def test_speed_baselines(capsys):
    load("speed_baselines").main(["--repeats", "1", "--tiny"])
    out = capsys.readouterr().out
    assert "ltd training step" in out and "pgbig training step" in out and "ratio" in out
    assert_finite(out, at_least=6)


def test_speed_compile_times_both_steps(capsys):
    args = ["--model", "mlp", "--set", "blocks=2", "--batch", "4", "--repeats", "1"]
    assert load("speed_compile").main([*args, "--backend", "eager"]) == 0
    out = capsys.readouterr().out
    assert "mlp training step, batch 4" in out and "compiled (eager)" in out
    assert_finite(out, at_least=3)


def test_public_auxformer_names_a_missing_checkout(tmp_path, capsys):
    assert load("public_auxformer").main(["--public", str(tmp_path), "--repeats", "1"]) == 0
    assert f"no public checkout at {tmp_path / 'AuxFormer'}" in capsys.readouterr().out


def test_public_dmgnn_names_a_missing_checkout_and_fails(tmp_path, capsys):
    assert load("public_dmgnn").main(["--public", str(tmp_path), "--repeats", "1"]) == 1
    assert f"no public checkout at {tmp_path / 'DMGNN'}" in capsys.readouterr().out


def test_public_ggmotion_names_a_missing_checkout(tmp_path, capsys):
    assert load("public_ggmotion").main(["--public", str(tmp_path), "--repeats", "1"]) == 0
    assert f"no public checkout at {tmp_path / 'GGMotion'}" in capsys.readouterr().out


def test_public_msrgcn_training_names_a_missing_checkout(tmp_path, capsys):
    assert load("public_msrgcn_training").main(["--public", str(tmp_path), "--steps", "1"]) == 0
    assert f"no public checkout at {tmp_path / 'MSRGCN'}" in capsys.readouterr().out


def test_public_tfan_names_a_missing_checkout(tmp_path, capsys):
    assert load("public_tfan").main(["--public", str(tmp_path), "--repeats", "1"]) == 0
    assert f"no public checkout at {tmp_path / 'TFAN'}" in capsys.readouterr().out


def test_speed_public_cmu_names_missing_checkouts_and_steps_the_zoo_models(tmp_path, capsys):
    script = load("speed_public_cmu")
    assert script.main(["--public", str(tmp_path), "--repeats", "1"]) == 0
    out = capsys.readouterr().out
    for name, folder in (("ltd", "LearnTrajDep"), ("pgbig", "PGBIG"), ("msrgcn", "MSRGCN")):
        assert f"{name}: no public checkout at {tmp_path / folder}" in out
        model, step = script.zoo_step(name, *script.batch())
        before = [p.detach().clone() for p in model.parameters()]
        step()
        assert any(not torch.equal(a, b) for a, b in zip(before, model.parameters()))


def test_speed_eval(swinging_cmu, capsys):
    root, _ = swinging_cmu
    load("speed_eval").main(["--data-root", str(root), "--repeats", "1"])
    out = capsys.readouterr().out
    assert "per-window loop" in out and "ratio" in out
    assert_finite(out, at_least=3)


def test_speed_expmap_reads_the_same_bits_both_ways_and_prints_a_finite_ratio(swinging_cmu, capsys):
    root, _ = swinging_cmu
    timed = load("speed_expmap").main(["--data-root", str(root), "--repeats", "1"])
    out = capsys.readouterr().out
    assert timed["same"] and "the same float64 bits for every file: yes" in out
    assert "1 files, 200 frames" in out
    assert_finite(out, at_least=6)


def test_speed_check(swinging_cmu, tmp_path, capsys):
    from zoo.cli import main

    root, _ = swinging_cmu
    paths = ["--data-root", str(root), "--weights", str(tmp_path / "none")]
    paths += ["--checkpoints", str(tmp_path / "none")]
    out = tmp_path / "results"
    assert main(["leaderboard", "--benchmark", "cmu", "--out", str(out), *paths]) == 0
    capsys.readouterr()
    load("speed_check").main(
        ["--results", str(out), "--benchmark", "cmu", "--seed", "1", "--against-full", *paths]
    )
    lines = capsys.readouterr().out.splitlines()
    assert "GFLOP/s" in lines[0] and lines[1] == "check: 32 windows a table, seed 1"
    assert "ratio" in lines[2] and "faster" in lines[2]
    assert lines[3].startswith("cmu") and lines[3].endswith("passed")
    check, floor, ratio, full, faster = figures(lines[3])
    assert all(math.isfinite(v) and v > 0 for v in (check, full, faster)), lines[3]
    # against a floor of no arithmetic (repeat_last alone) the ratio is infinite, never NaN
    assert ratio > 0 and (math.isfinite(ratio) or floor == 0), lines[3]


@pytest.mark.slow  # four zoo processes, each importing torch: "several processes"
def test_speed_leaderboard_model(swinging_cmu, tmp_path, capsys):
    from zoo.cli import main

    root, _ = swinging_cmu
    base = tmp_path / "results"
    paths = ["--data-root", str(root), "--weights", str(tmp_path / "none")]
    paths += ["--checkpoints", str(tmp_path / "none")]
    assert main(["leaderboard", "--benchmark", "cmu", "--out", str(base), *paths]) == 0
    capsys.readouterr()
    load("speed_leaderboard_model").main(
        ["--data-root", str(root), "--base", str(base), "--work", "1", "--repeats", "1"]
    )
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].startswith("cheap: zoo eval --sampler all ") and "ratio" in lines[1]
    assert lines[2].startswith("rollout: zoo eval --sampler all ")
    for line in lines[1:]:
        evaluated, board, ratio, repeats = figures(line.split(": ", 1)[1])
        assert evaluated > 0 and board > 0 and ratio == pytest.approx(board / evaluated, rel=0.1)


def test_speed_pass(swinging_cmu, tmp_path, capsys):
    root, _ = swinging_cmu
    args = ["--benchmark", "cmu", "--data-root", str(root), "--weights", str(tmp_path / "none")]
    load("speed_pass").main([*args, "--windows", "8", "--repeats", "1"])
    lines = capsys.readouterr().out.splitlines()
    assert "rows (" in lines[0] and "repeat_last" in lines[0]
    assert "ratio" in lines[1] and "per-window errors of both equal" in lines[1]
    ratio = float(lines[1].split("ratio ", 1)[1].split("x", 1)[0])
    assert math.isfinite(ratio) and ratio > 0, lines[1]  # a NaN timing would print nan here
    assert_finite(lines[1], at_least=4)


def test_speed_spectral(capsys):
    load("speed_spectral").main(
        ["--k", "16", "--repeats", "1", "--sphere", "8", "10", "--cloth-sequences", "2"]
    )
    out = capsys.readouterr().out
    assert "uv_sphere_82" in out and "batch of 2 sequences" in out and "ratio" in out
    assert_finite(out, at_least=6)


def test_speed_spectrhums(capsys):
    load("speed_spectrhums").main(["--repeats", "1", "--vertices", "64", "--k", "16", "--tiny"])
    out = capsys.readouterr().out
    assert "tiny configuration: k=16 coefficients on V=64" in out
    assert "layer-by-layer baseline, train step b32" in out
    assert_finite(out, at_least=6)


def test_speed_training_view(capsys):
    ratios = load("speed_training_view").main(["--repeats", "1", "--tiny", "--frames", "120"])
    out = capsys.readouterr().out
    assert "full, cached coefficients" in out and "full / low resolution" in out
    assert set(ratios) == {"full_over_low", "vertices_over_cached"}


def test_speed_spgsn(capsys):
    load("speed_spgsn").main(["--tiny", "--repeats", "1", "--bf16", "--models", "spgsn", "mlp"])
    out = capsys.readouterr().out
    assert "public code" in out and "== mlp ==" in out and "aim (>=" in out
    assert_finite(out, at_least=20)


def test_speed_spgsn_training_prints_a_finite_rate_for_every_configuration(capsys):
    load("speed_spgsn_training").main(["--tiny", "--repeats", "1", "--no-compile"])
    out = capsys.readouterr().out
    rows = {}
    for line in out.splitlines():
        label, _, cells = line.partition("  ")
        if label in ("float32 eager", "bfloat16 eager", "public code, float32 eager"):
            rows[label] = [float(c.rstrip("x")) for c in cells.split()[:3]]
    assert len(rows) == 3
    assert all(math.isfinite(v) and v > 0 for cells in rows.values() for v in cells)
    assert rows["public code, float32 eager"][2] == 1.0  # its own ratio
    assert "float32 eager: aten::" in out and "bfloat16 eager: aten::" in out


@pytest.mark.slow  # out of the README test command's 2 minutes; .ci/run runs it after
@pytest.mark.skipif(
    importlib.util.find_spec("anny") is None,
    reason="the anny package is not installed (pip install anny==0.6.2)",
)
@pytest.mark.skipif(not CMU_BVH.is_dir(), reason=f"CMU BVH data not found at {CMU_BVH}")
def test_speed_anny(capsys):
    load("speed_anny").main(["--trial", "09_03", "--frames", "8", "--batch", "4"])
    out = capsys.readouterr().out
    assert "cached load: full" in out and "end to end (09_03" in out


def test_speed_plots_copies_the_drawn_bytes_and_prints_a_finite_ratio(capsys):
    (row,) = load("speed_plots").main(["--table", str(REPO / "results" / "cmu" / "ltd8"),
                                       "--repeats", "1"])  # fmt: skip
    out = capsys.readouterr().out.splitlines()
    assert out[1].startswith("cmu/ltd8") and "the same bytes, 0 redrawn" in out[1]
    assert row["same"] and row["redrawn"] == 0
    for key in ("drawn", "copied", "ratio", "tight", "tight_ratio"):
        assert math.isfinite(row[key]) and row[key] > 0, key


def test_speed_intervals_gives_the_same_bits_kept_or_drawn_and_a_finite_ratio(capsys):
    (row,) = load("speed_intervals").main(["--table", str(REPO / "results" / "cmu" / "ltd8"),
                                           "--repeats", "1"])  # fmt: skip
    out = capsys.readouterr().out.splitlines()
    assert out[1].startswith("cmu/ltd8") and out[1].endswith("the same bits")
    assert row["same"] and row["rows"] > 1 and row["views"] > 0
    for key in ("kept", "drawn", "ratio"):
        assert math.isfinite(row[key]) and row[key] > 0, key


def test_speed_identity_prints_agreeing_fingerprints_and_a_finite_ratio(capsys):
    rows = load("speed_identity").main(["--benchmark", "cmu", "--model", "ltd", "--repeats", "1"])
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("benchmark") and out[1].startswith("cmu")
    assert out[2].startswith("model") and out[3].startswith("ltd")
    evaluator, model = rows
    assert evaluator["same"] and "agree" in out[1] and model["same"] and "agree" in out[3]
    for key in ("cold", "stored", "anew", "kept", "ratio"):
        assert math.isfinite(evaluator[key]) and evaluator[key] > 0, key
    for key in ("anew", "kept", "ratio"):
        assert math.isfinite(model[key]) and model[key] > 0, key
