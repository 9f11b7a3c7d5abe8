"""Issue 29's ablation script (``benchmarks/ablation/spectrhums.py``): its config is data, checked
on load, and a benchmark's own settings (``per_benchmark``) apply where the recipe moves to it."""

import importlib.util
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
ABLATION = REPO / "benchmarks" / "ablation"


@pytest.fixture(scope="module")
def script():
    spec = importlib.util.spec_from_file_location("ablation_spectrhums", ABLATION / "spectrhums.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_shipped_config_loads_and_every_budget_names_a_mesh_benchmark(script):
    from zoo.benchmark import get_benchmark

    cfg = script.load_config(ABLATION / "spectrhums_29.yaml")
    assert {"A", "B", "C", "D"} <= set(cfg["arms"])
    for name in cfg.get("per_benchmark") or {}:
        assert get_benchmark(name).representation == "mesh"


def test_a_benchmarks_budget_overrides_both_stages_and_only_there(script):
    cfg = script.load_config(ABLATION / "spectrhums_29.yaml")
    cfg["per_benchmark"] = {"cloth_full": {"train_set": {"epochs": 3}, "pretrain": {"epochs": 5}}}
    moved = script.on_benchmark(cfg, "cloth_full")
    assert moved["benchmark"] == "cloth_full"
    assert moved["out"] == f"{cfg['out']}/cloth_full"
    d = moved["arms"]["D"]
    assert d["train_set"]["epochs"] == 3
    assert d["pretrain"]["train_set"] == {**cfg["arms"]["D"]["pretrain"]["train_set"], "epochs": 5}
    assert moved["arms"]["A"]["train_set"] == {"epochs": 3}
    # no budget of its own: the arms' recipes as they are (the config's epochs)
    other = script.on_benchmark(cfg, "cmu_anny_mi")
    assert other["arms"]["D"]["pretrain"] == cfg["arms"]["D"]["pretrain"]
    assert not other["arms"]["B"].get("train_set")
    # the config itself is untouched
    assert "train_set" not in cfg["arms"]["D"]


def test_a_malformed_budget_is_refused_naming_it(script, tmp_path):
    cfg = yaml.safe_load((ABLATION / "spectrhums_29.yaml").read_text())
    cfg["per_benchmark"] = {"cloth_full": {"epochs": 4}}
    path = tmp_path / "ablation.yaml"
    path.write_text(yaml.safe_dump(cfg))
    with pytest.raises(
        SystemExit, match=r"per_benchmark: cloth_full: expected a mapping of train_set"
    ):
        script.load_config(path)
