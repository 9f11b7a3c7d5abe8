"""A row's identity says what its code does, not where the code lives. In a copy of the tree
with a module of the evaluator renamed, a model's module renamed, a function moved to another
file and an evaluator module's definitions reordered, every committed row is still current and
every cost cell of CMU still filled; a real change to the code a row reaches makes it stale."""

from __future__ import annotations

import ast
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from zoo.paths import REPO_ROOT


def probe(results: str | Path, costs: bool = True) -> dict:
    """What the imported tree says of the committed rows in ``results``: the rows whose
    recorded code fingerprints are not those of this code, and (``costs``) the CMU rows whose
    cost cells ``costs.json`` keeps for their model as it is now (each model loaded)."""
    from zoo.evaluation.pipeline import row_code
    from zoo.leaderboard.costs import committed_tables
    from zoo.leaderboard.plan import Leaderboard
    from zoo.models.registry import load_registry
    from zoo.protocol.benchmark import get_benchmark
    from zoo.store.fingerprint import model_fingerprint

    registry = load_registry()
    evaluators: dict[str, str] = {}
    models: dict[str, str | None] = {}
    stale, rows = [], sorted(Path(results).glob("*/*/*/protocol.json"))
    for path in rows:
        identity = json.loads(path.read_text())["provenance"]["identity"]
        bench, model, code = path.parts[-4], identity["model"], identity["code"]
        if bench not in evaluators:
            evaluators[bench] = row_code(None, get_benchmark(bench))["evaluator"]
        if code["evaluator"] != evaluators[bench]:
            stale.append(f"{path}: evaluator {code['evaluator']}, now {evaluators[bench]}")
        entry = registry.entries.get(model["name"])
        if entry is not None and entry.class_name == model["class"]:
            if model["name"] not in models:
                models[model["name"]] = model_fingerprint(entry.load_class())
            if code.get("model") and code["model"] != models[model["name"]]:
                stale.append(f"{path}: model {code['model']}, now {models[model['name']]}")
    kept: list[str] = []
    if costs:
        board = Leaderboard.of("cmu", out_root=results, weights=Path(results).parent / "weights")
        for _, task, labels in committed_tables(board):
            efficiency: dict = {}
            for row in board.rows(task):
                if row.label in labels:
                    board.stored_cost(efficiency, row.label, board.load(row), task)
            kept += sorted(efficiency)
    return {"rows": len(rows), "stale": stale, "models": models, "costs": sorted(set(kept))}


def _probe_copy(tree: Path, costs: bool = True) -> dict:
    """:func:`probe` run by the zoo in ``tree`` (not the installed one, and none of its
    modules found through the editable install's finder) on the repository's results."""
    script = (
        "import json, sys\n"
        "sys.meta_path[:] = [f for f in sys.meta_path\n"
        "                    if 'Editable' not in getattr(f, '__name__', type(f).__name__)]\n"
        f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "import zoo\n"
        f"assert zoo.__file__.startswith({str(tree)!r}), zoo.__file__\n"
        "from test_identities_move import probe\n"
        f"print(json.dumps(probe({str(REPO_ROOT / 'results')!r}, costs={costs})))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=tree, env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.splitlines()[-1])


def _copy_tree(dest: Path) -> Path:
    # compiled files too: each copied module unchanged is loaded, not compiled, by the probe
    shutil.copytree(REPO_ROOT / "zoo", dest / "zoo")
    shutil.copy(REPO_ROOT / "registry.yaml", dest / "registry.yaml")
    (dest / "benchmarks").mkdir()
    for path in (REPO_ROOT / "benchmarks").iterdir():
        if path.suffix == ".yaml" or path.name in ("bases", "regressors"):
            (shutil.copytree if path.is_dir() else shutil.copy)(
                path, dest / "benchmarks" / path.name
            )
    (dest.parent / "shared").mkdir(exist_ok=True)
    if not (dest.parent / "shared" / "data").exists():
        (dest.parent / "shared" / "data").symlink_to(REPO_ROOT.parent / "shared" / "data")
    return dest


def _replace_everywhere(tree: Path, pattern: str, new: str) -> None:
    for path in [*tree.rglob("*.py"), tree / "registry.yaml"]:
        text = path.read_text()
        if re.search(pattern, text):
            path.write_text(re.sub(pattern, new, text))


def _rename_module(tree: Path, old: str, new: str) -> None:
    (tree / f"{old.replace('.', '/')}.py").rename(tree / f"{new.replace('.', '/')}.py")
    _replace_everywhere(tree, rf"\b{re.escape(old)}\b", new)


def _move_function(tree: Path, name: str, source: str, dest: str) -> None:
    """``name`` cut from module ``source`` and appended to ``dest`` with the imports it had;
    every import of it, and ``source`` itself, then import it from ``dest``."""
    src, dst = (tree / f"{m.replace('.', '/')}.py" for m in (source, dest))
    text = src.read_text()
    module = ast.parse(text)
    node = next(n for n in module.body if getattr(n, "name", None) == name)
    lines = text.splitlines(keepends=True)
    start = (node.decorator_list[0] if node.decorator_list else node).lineno - 1
    imports = [
        ast.get_source_segment(text, n)
        for n in module.body
        if isinstance(n, (ast.Import, ast.ImportFrom)) and getattr(n, "module", "") != "__future__"
    ]
    last_import = max(
        n.end_lineno for n in module.body if isinstance(n, (ast.Import, ast.ImportFrom))
    )
    kept = lines[:start] + lines[node.end_lineno :]
    kept.insert(last_import, f"from {dest} import {name}\n")
    src.write_text("".join(kept))
    dst.write_text(
        dst.read_text()
        + "\n"
        + "\n".join(imports)
        + "\n\n\n"
        + "".join(lines[start : node.end_lineno])
    )
    # an import of it beside other names keeps those from the source
    _replace_everywhere(
        tree,
        rf"(?m)^([ \t]*)from {re.escape(source)} import {name}, (.+)$",
        f"\\1from {dest} import {name}\n\\1from {source} import \\2",
    )
    _replace_everywhere(
        tree,
        rf"(?m)^([ \t]*)from {re.escape(source)} import {name}$",
        f"\\1from {dest} import {name}",
    )


def _reverse_functions(path: Path) -> None:
    """The module's top-level functions in reverse order, in the places they held."""
    text = path.read_text()
    lines = text.splitlines(keepends=True)
    spans = [
        ((n.decorator_list[0] if n.decorator_list else n).lineno - 1, n.end_lineno)
        for n in ast.parse(text).body
        if isinstance(n, ast.FunctionDef)
    ]
    pieces, out, at = ["".join(lines[a:b]) for a, b in spans][::-1], [], 0
    for (a, b), piece in zip(spans, pieces):
        out += [*lines[at:a], piece]
        at = b
    path.write_text("".join(out + lines[at:]))


@pytest.fixture(scope="module")
def committed():
    return probe(REPO_ROOT / "results")


def test_moving_code_re_stamps_no_row_and_empties_no_cost_cell(tmp_path, committed):
    tree = _copy_tree(tmp_path / "tree")
    _rename_module(tree, "zoo.protocol.metrics", "zoo.scores")  # reached by every row's evaluator
    # a trained model's own module: its shipped weights, which record the old path, still load
    _rename_module(tree, "zoo.models.ltd", "zoo.models.dct_gcn")
    _move_function(tree, "dct_matrix", "zoo.models.dct", "zoo.models.history")
    _reverse_functions(tree / "zoo" / "evaluation" / "evaluator.py")
    assert not (tree / "zoo" / "protocol" / "metrics.py").exists()
    assert "def dct_matrix" in (tree / "zoo" / "models" / "history.py").read_text()

    moved = _probe_copy(tree)
    assert committed["rows"] > 100 and not committed["stale"], committed["stale"][:5]
    assert len(committed["costs"]) >= 10
    assert moved["rows"] == committed["rows"]
    assert not moved["stale"], "\n".join(moved["stale"][:5])
    assert moved["costs"] == committed["costs"]


def test_a_real_change_to_the_code_a_row_reaches_makes_it_stale(tmp_path, committed):
    tree = _copy_tree(tmp_path / "tree")
    metrics = tree / "zoo" / "protocol" / "metrics.py"
    text = metrics.read_text()
    changed = text.replace("dim=-1).mean(dim=-1)", "dim=-1).mean(dim=-1) * 1.001")
    assert changed != text
    metrics.write_text(changed)
    dct = tree / "zoo" / "models" / "dct.py"
    dct.write_text(dct.read_text().replace("math.sqrt(0.5)", "math.sqrt(0.5001)"))

    changed = _probe_copy(tree, costs=False)  # what it asserts needs no model loaded
    # every row's evaluator, and each DCT model's own code
    assert sum("evaluator" in s for s in changed["stale"]) == committed["rows"]
    dct_models = {"ltd", "pgbig", "mlp", "msrgcn", "spgsn", "spgsn_1body", "tfan"}
    for name, fingerprint in changed["models"].items():
        assert (fingerprint != committed["models"][name]) == (name in dct_models), name
