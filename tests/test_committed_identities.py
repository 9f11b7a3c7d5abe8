"""Every committed row's identity names the code that would compute it now: the evaluator's
fingerprint (with the code that generates its mesh dataset) and its model class's. A change
that moves either (an edit to code every model reaches, such as the error base) shows here
instead of as stale rows and emptied cost cells on the next rebuild. And every trained row
names weights the repository ships."""

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


def test_every_committed_trained_row_ships_its_weights():
    """A committed row computed from trained weights names a weights file of the repository,
    tracked, whose record's sha256 is the one the row was computed from: every committed
    number is re-checked from what a clone has. Weights whose licence keeps them out (an
    import without --redistributable) give rows of one's own tables only."""
    import subprocess

    tracked = set(
        subprocess.run(
            ["git", "ls-files", "weights"], cwd=REPO_ROOT, capture_output=True, text=True,
            check=True,
        ).stdout.split()
    )  # fmt: skip
    rows = sorted((REPO_ROOT / "results").glob("*/*/*/protocol.json"))
    unshipped = []
    for path in rows:
        provenance = json.loads(path.read_text()).get("provenance") or {}
        trained = provenance["identity"].get("trained")
        if trained is None:  # a baseline: nothing trained
            continue
        weights = provenance.get("weights")
        if trained.get("kind") != "weights" or weights not in tracked:
            unshipped.append(f"{path}: trained from {trained.get('kind')} {weights}, not shipped")
            continue
        record = json.loads((REPO_ROOT / weights).with_suffix(".json").read_text())
        if record["sha256"] != trained["sha256"]:
            unshipped.append(f"{path}: computed from {trained['sha256'][:12]}, shipped "
                             f"{record['sha256'][:12]}")  # fmt: skip
    assert len(rows) > 100
    assert not unshipped, "\n".join(unshipped[:10])
