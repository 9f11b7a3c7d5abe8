"""Every committed row's identity names the code that would compute it now: the evaluator's
fingerprint (with the code that generates its mesh dataset) and its model class's. A change
that moves either (an edit to code every model reaches, such as the error base) shows here
instead of as stale rows and emptied cost cells on the next rebuild."""

from __future__ import annotations

import json

from zoo.evaluation.pipeline import row_code
from zoo.models.registry import load_registry
from zoo.paths import REPO_ROOT
from zoo.protocol.benchmark import get_benchmark
from zoo.store.fingerprint import model_fingerprint


def test_committed_rows_carry_the_current_code_fingerprints():
    registry = load_registry()
    evaluators: dict[str, str] = {}
    models: dict[str, str | None] = {}
    stale = []
    rows = sorted((REPO_ROOT / "results").glob("*/*/*/protocol.json"))
    for path in rows:
        identity = (json.loads(path.read_text()).get("provenance") or {}).get("identity")
        bench = path.parts[-4]
        code, model = identity["code"], identity["model"]
        if bench not in evaluators:
            evaluators[bench] = row_code(None, get_benchmark(bench))["evaluator"]
        if code["evaluator"] != evaluators[bench]:
            stale.append(f"{path}: evaluator {code['evaluator']}, now {evaluators[bench]}")
        name = model["name"]
        if name in registry.entries and registry.get(name).class_path == model["class"]:
            if name not in models:
                models[name] = model_fingerprint(registry.get(name).load_class())
            if code.get("model") and code["model"] != models[name]:
                stale.append(f"{path}: model code {code['model']}, now {models[name]}")
    assert len(rows) > 100
    assert not stale, "\n".join(stale[:10])
