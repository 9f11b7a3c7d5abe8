"""Issue 29's ablation script (``benchmarks/ablation/spectrhums.py``): its config is data, checked
on load, and a benchmark's own settings (``per_benchmark``) apply where the recipe moves to it."""

import copy
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


def load_with(tmp_path, script, **changes):
    """The shipped config with top-level fields replaced, loaded from a file of its own."""
    cfg = yaml.safe_load((ABLATION / "spectrhums_29.yaml").read_text())
    path = tmp_path / "ablation.yaml"
    path.write_text(yaml.safe_dump({**cfg, **changes}))
    return script.load_config(path)


def test_shipped_config_loads_and_every_budget_names_a_mesh_benchmark(script):
    from zoo.protocol.benchmark import get_benchmark

    cfg = script.load_config(ABLATION / "spectrhums_29.yaml")
    assert {"A", "B", "C", "D"} <= set(cfg["arms"])
    for name in cfg.get("per_benchmark") or {}:
        assert get_benchmark(name).representation == "mesh"


def test_cloth_full_runs_both_stages_with_its_own_settings(script, monkeypatch):
    """What ``train D`` runs on cloth_full: the shipped per_benchmark settings over D's own,
    in both stages, the second from the first's last weights; the config is left as it was."""
    cfg = script.load_config(ABLATION / "spectrhums_29.yaml")
    before = copy.deepcopy(cfg)
    runs = []
    monkeypatch.setattr(script, "_run", lambda *args: runs.append(args))
    moved = script.on_benchmark(cfg, "cloth_full")
    script.train(moved, "D", 0)
    assert cfg == before
    assert moved["out"] == f"{cfg['out']}/cloth_full"
    (_, model1, out1, seed1, recipe1, set1, init1), (_, model2, out2, _, recipe2, set2, init2) = (
        runs
    )
    assert (model1, model2, seed1) == ("spectrhums_residual", "spectrhums_residual", 0)
    assert out1.name == "D-seed0-pretrain" and out2.name == "D-seed0"
    assert out1.parent == script.ROOT / cfg["out"] / "cloth_full"
    shared = {"val_split": "recordings", "val_fraction": 0.125}
    assert recipe1 == {**shared, "epochs": 22, "train_sampler": "all", "val_sampler": "all"}
    assert set1 == {"autoencoder_epochs": 22} and init1 is None
    assert recipe2 == {**shared, "epochs": 6, "train_sampler": "all"}
    assert set2 == {} and init2 == out1 / "last.pt"


def test_without_settings_of_its_own_a_benchmark_gets_the_arms_recipes(script, monkeypatch):
    cfg = script.load_config(ABLATION / "spectrhums_29.yaml")
    runs = []
    monkeypatch.setattr(script, "_run", lambda *args: runs.append(args))
    script.train(script.on_benchmark(cfg, "cmu_anny_mi"), "D", 0)
    (*_, recipe1, set1, _), (*_, recipe2, _, _) = runs
    assert recipe1 == {**cfg["train_set"], **cfg["arms"]["D"]["pretrain"]["train_set"]}
    assert set1 == cfg["arms"]["D"]["pretrain"]["set"]
    assert recipe2 == cfg["train_set"]


@pytest.mark.parametrize(
    "per_benchmark, message",
    [
        ({"cloth_full": {"epochs": 4}}, r"per_benchmark\.cloth_full: expected a mapping of"),
        ({"cloth_full": {"train_set": 6}}, r"per_benchmark\.cloth_full\.train_set: expected"),
        (
            {"cloth_full": {"pretrain": {"train_set": {"epochs": 9}}}},
            r"per_benchmark\.cloth_full\.pretrain: expected train_set entries",
        ),
        ({"cmu_anny_oi_low": {"train_set": {"epochs": 4}}}, r"the config's own benchmark"),
        ({"cmu": {"train_set": {"epochs": 4}}}, r"per_benchmark\.cmu: not a mesh benchmark"),
        (
            {"cloth_full": {"pretrain": {"epochs": 30}}},
            r"arm C's pretrain on cloth_full: 30 epochs but autoencoder_epochs 22",
        ),
    ],
)
def test_a_malformed_per_benchmark_entry_is_refused_naming_it(
    script, tmp_path, per_benchmark, message
):
    with pytest.raises(SystemExit, match=message):
        load_with(tmp_path, script, per_benchmark=per_benchmark)
