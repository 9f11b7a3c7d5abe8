"""Joints and meshes, one object each (zoo.protocol.representation): the words a benchmark file
and a registry entry write are the objects', what depends on the kind of points is asked of the
benchmark's object, and no module outside the objects tests the word."""

import re
from pathlib import Path
from typing import get_args

import pytest

import zoo
from zoo import create_model
from zoo.core.errors import EvaluationError
from zoo.models.registry import ModelRepresentation
from zoo.protocol.benchmark import (
    MODEL_REPRESENTATIONS,
    REPRESENTATIONS,
    get_benchmark,
    representation_of,
)
from zoo.protocol.joints import JointsRepresentation
from zoo.protocol.mesh import MeshRepresentation
from zoo.protocol.views import View

ZOO = Path(__file__).resolve().parents[1] / "zoo"
OBJECTS = {ZOO / "protocol" / f"{name}.py" for name in ("representation", "joints", "mesh")}
# a representation's word or a view compared, or looked up in a record, in code
BRANCH = re.compile(
    r"""representation\s*(==|!=)|[=!]=\s*"(mesh|joints)"|"(mesh|joints)"\s+(not\s+)?in\b"""
    r"""|\b(is|is not|==|!=)\s+View\.|get\("representation"\)"""
)


def test_the_registry_writes_the_words_of_the_representations():
    assert tuple(REPRESENTATIONS) == ("joints", "mesh")
    assert get_args(ModelRepresentation) == MODEL_REPRESENTATIONS == ("joints", "expmap", "mesh")


def test_benchmarks_ask_their_representation():
    assert isinstance(get_benchmark("cmu").strategy, JointsRepresentation)
    assert isinstance(get_benchmark("cloth").strategy, MeshRepresentation)
    # a joints record predates the word: it names none
    assert representation_of({"joint_protocols": {"all38": ""}}).name == "joints"
    assert representation_of({"representation": "mesh"}).headline({}) == ("rmse", "vertices")


def test_no_module_outside_the_representations_tests_the_word():
    found = [
        f"{path.relative_to(ZOO.parent)}:{number}: {line.strip()}"
        for path in sorted(ZOO.rglob("*.py"))
        if path not in OBJECTS
        for number, line in enumerate(path.read_text().splitlines(), start=1)
        if BRANCH.search(line.split("#")[0])
    ]
    # zoo render and the site's clips draw surfaces: they ask the object whether it has any
    assert found == []


@pytest.mark.parametrize(
    "line",
    [
        'if bench.representation == "mesh":',
        'if protocol.get("representation") == "mesh":',
        "mesh=view is View.MESH,",
        'if "mesh" in representations:',
    ],
)
def test_the_branch_finder_finds_branches(line):
    assert BRANCH.search(line)


def test_a_joints_benchmark_refuses_a_model_fed_vertices(swinging_cmu):
    root, _ = swinging_cmu
    bench = get_benchmark("cmu")
    model = create_model("repeat_last", benchmark=bench)
    with pytest.raises(EvaluationError, match=r"joints benchmark: model 'still' must be fed"):
        zoo.evaluate(model, bench, label="still", data_root=root, view="mesh")
    joints = zoo.evaluate(model, bench, label="still", data_root=root, view=View.JOINTS)
    assert set(joints.frame["metric"]) == {"mpjpe"}


def test_a_model_given_no_view_is_fed_the_benchmarks_own(swinging_cmu):
    from zoo.evaluation.evaluator import Scored, evaluate_models
    from zoo.protocol.plan import plan_protocol

    root, _ = swinging_cmu
    bench = get_benchmark("cmu")
    protocol = plan_protocol(bench, bench.load(root), sampler="ltd8")
    scored = Scored(create_model("repeat_last", benchmark=bench), "still")
    (result,) = evaluate_models([scored], protocol)
    assert set(result.frame["joints"]) == {"all38", "used25"}
    assert scored.view is None  # the caller's model is left as it was given


def test_a_joints_run_records_the_files_it_trained_on(swinging_cmu):
    root, _ = swinging_cmu
    joints = get_benchmark("cmu")
    record = joints.strategy.training_record(joints.load(root, split="test"), View.JOINTS)
    assert record["files"] and set(record["files"][0]) == {"file", "sha256"}
