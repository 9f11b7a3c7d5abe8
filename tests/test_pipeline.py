"""One pipeline (zoo.evaluation.pipeline) behind zoo eval, zoo.evaluate and zoo leaderboard: the
same result files from each, and one protocol planned per result whichever entry point."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import write_cmu_file
from test_mesh_eval import toy_bench  # noqa: F401 (a fixture)

import zoo
from zoo.cli import main
from zoo.data import windows as window_rules
from zoo.leaderboard.rebuild import regenerate
from zoo.models.registry import load_registry

FILES = ("results.csv", "tables.md", "windows.npz")


def cmu_root(tmp_path: Path) -> Path:
    root = tmp_path / "cmu"
    for action, rate in (("walking", 0.01), ("running", 0.02)):
        write_cmu_file(root / "test" / action / f"{action}_1.txt", rate * np.arange(300))
    return root


def _same_result(a: Path, b: Path) -> None:
    """Byte for byte, but for the two provenance fields that say when and by which command a
    result was made."""
    for name in FILES:
        assert (a / name).read_bytes() == (b / name).read_bytes(), f"{name} differs: {a} {b}"
    records = [json.loads((f / "protocol.json").read_text()) for f in (a, b)]
    for record in records:
        record["provenance"].pop("created")
        record["provenance"].pop("made_by")
    assert records[0] == records[1]


@pytest.mark.parametrize("kind", ["skeleton", "mesh"])
def test_the_three_entry_points_write_the_same_result(kind, tmp_path, request, capsys):
    if kind == "skeleton":
        bench, root, table = "cmu", cmu_root(tmp_path), "all"
        where = ["--benchmark", "cmu", "--sampler", "all", "--data-root", str(root)]
        api = {"sampler": "all", "data_root": root}
        board = {"data_root": root}
    else:
        path = request.getfixturevalue("toy_bench")().source
        bench, root, table = str(path), None, "all"
        where = ["--benchmark", str(path)]
        api, board = {}, {}
    by_cli, by_api = tmp_path / "cli", tmp_path / "api"
    assert main(["eval", "--model", "repeat_last", *where, "--out", str(by_cli)]) == 0
    zoo.evaluate("repeat_last", bench, out=by_api, **api)
    empty = tmp_path / "none"
    empty.mkdir()
    regenerate(
        bench,
        registry=load_registry(),
        out_root=tmp_path / "board",
        weights=empty,
        checkpoints=empty,
        **board,
    )
    name = "cmu" if kind == "skeleton" else "toy"
    by_board = tmp_path / "board" / name / table / "repeat_last"
    made_by = {
        json.loads((f / "protocol.json").read_text())["provenance"]["made_by"]
        for f in (by_cli, by_api, by_board)
    }
    assert made_by == {"zoo eval", "zoo.evaluate", "zoo leaderboard"}
    _same_result(by_cli, by_api)
    _same_result(by_cli, by_board)


def test_one_protocol_planned_per_result(tmp_path, monkeypatch):
    root = cmu_root(tmp_path)
    planned = []
    sampler = window_rules.window_sampler

    def counting(name, *args, **kwargs):
        planned.append(name)
        return sampler(name, *args, **kwargs)

    monkeypatch.setattr(window_rules, "window_sampler", counting)
    common = ["--model", "repeat_last", "--data-root", str(root)]
    assert main(["eval", *common, "--sampler", "all", "--out", str(tmp_path / "a")]) == 0
    assert planned == ["all"]
    planned.clear()
    assert main(["eval", *common, "--sampler", "all", "--sampler", "ltd8",
                 "--results", str(tmp_path / "r")]) == 0  # fmt: skip
    assert planned == ["all", "ltd8"]
    planned.clear()
    zoo.evaluate("constant_velocity", "cmu", sampler="all", data_root=root, out=tmp_path / "b")
    assert planned == ["all"]
    planned.clear()
    empty = tmp_path / "none"
    empty.mkdir()
    regenerate(
        "cmu",
        registry=load_registry(),
        data_root=root,
        out_root=tmp_path / "board",
        weights=empty,
        checkpoints=empty,
    )
    # one plan per table, shared by its rows (repeat_last and, were there more, every other)
    assert sorted(planned) == ["all", "ltd8"]
