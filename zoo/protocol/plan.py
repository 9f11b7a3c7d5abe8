"""A protocol, planned once: which windows of which dataset are scored, for which task and
against which ground truth, and the record every result row of it carries.

:func:`plan_protocol` is the one function that builds a :class:`Protocol` from (benchmark,
dataset, sampler, task, horizon, ground truth, MELV frames); the evaluator, the store, the tables
and ``--check`` read it and never plan again. Its record's comparable part (everything but
provenance) is hashed into ``protocol_id``, which every row carries, so rows measured
differently can never be mistaken for each other.
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from zoo.core.errors import EvaluationError
from zoo.core.io import canonical_json
from zoo.core.options import TASKS
from zoo.data import windows as window_rules
from zoo.data.motion import MotionDataset
from zoo.protocol.benchmark import GROUND_TRUTHS, Benchmark
from zoo.protocol.metrics import (
    ACTION_AVERAGING,
    AVERAGING,
    FLOOR_SUFFIX,
    STD_DESCRIPTION,
    joint_protocols,
)
from zoo.protocol.views import View


@dataclass(frozen=True, eq=False)
class Protocol:
    """One planned protocol: the dataset it reads (loaded once), its windows (``index``:
    sequence and first frame of each, in scoring order; ``actions``: each window's action), the
    frames a model sees and predicts, the spectral basis a mesh protocol needs (or None) and its
    record (``record["protocol_id"]`` included; provenance is added per result)."""

    benchmark: Benchmark
    dataset: Any
    sampler: str
    task: str
    input_frames: int
    predicted_frames: int
    index: np.ndarray
    actions: np.ndarray
    record: dict[str, Any]
    ground_truth: str | None = None
    melv_frames: str | None = None
    basis: Any = None

    @property
    def id(self) -> str:
        return self.record["protocol_id"]

    @property
    def window_frames(self) -> int:
        return self.input_frames + self.predicted_frames

    def subset(self, rows: np.ndarray) -> Protocol:
        """Only the windows at positions ``rows`` of this protocol's (a sampled check), its
        record and id kept: a pass over them gives the protocol's per-window errors of those
        windows, not its averages."""
        return dataclasses.replace(self, index=self.index[rows], actions=self.actions[rows])


def check_task(task: str, horizon: int | None, output_frames: int) -> int:
    """The number of predicted frames a task scores."""
    if task not in TASKS:
        raise EvaluationError(f"unknown task {task!r}; valid tasks: {', '.join(TASKS)}")
    if task == "longterm":
        if horizon is None or horizon <= output_frames:
            raise EvaluationError(
                f"task longterm needs a horizon of more than the model's "
                f"{output_frames} output frames (--horizon-frames), got "
                f"{horizon}"
            )
        return horizon
    if horizon is not None:
        raise EvaluationError(f"a horizon applies to task longterm, not {task}")
    return output_frames


def protocol_id(record: dict[str, Any]) -> str:
    comparable = {k: v for k, v in record.items() if k not in ("provenance", "protocol_id")}
    return hashlib.sha256(canonical_json(comparable).encode()).hexdigest()[:16]


def plan_protocol(
    bench: Benchmark,
    dataset,
    *,
    sampler: str | None = None,
    task: str = "prediction",
    horizon: int | None = None,
    ground_truth: str | None = None,
    melv_frames: str | None = None,
) -> Protocol:
    """The protocol these settings define on ``dataset`` (``bench.load()``), found without
    running any model. ``ground_truth`` and ``melv_frames`` (mesh benchmarks only): ``raw`` or
    ``spectral``, default the benchmark's; ``task``: see :data:`TASKS` (``longterm`` with
    ``horizon`` frames)."""
    if bench.representation == "mesh":
        return _mesh_plan(bench, dataset, sampler, task, horizon, ground_truth, melv_frames)
    for name, value in (("ground_truth", ground_truth), ("melv_frames", melv_frames)):
        if value is not None:
            raise EvaluationError(
                f"benchmark {bench.name}: {name}={value!r} applies to mesh benchmarks only"
            )
    return _skeleton_plan(bench, dataset, sampler, task, horizon)


def _task_record(task: str, frames: int) -> dict[str, Any]:
    return {"task": task, "task_rule": TASKS[task], "predicted_frames": frames}


def _windows(bench, dataset, sampler, t_out, rule, subactions=None):
    sequences = dataset.sequences
    index = window_rules.window_sampler(
        sampler,
        [len(s) for s in sequences],
        bench.input_frames,
        t_out,
        rule,
        groups=[s.action for s in sequences],
        **({"subactions": subactions} if subactions is not None else {}),
    )
    return index, np.asarray([sequences[i].action for i in index[:, 0]])


def _sealed(record: dict[str, Any]) -> dict[str, Any]:
    record["protocol_id"] = protocol_id(record)
    return record


def _skeleton_plan(
    bench: Benchmark, dataset: MotionDataset, sampler: str | None, task: str, horizon: int | None
) -> Protocol:
    sampler = window_rules.check_sampler(sampler or bench.sampler)
    t_in = bench.input_frames
    t_out = check_task(task, horizon, bench.output_frames)
    sequences = dataset.sequences
    index, actions = _windows(
        bench, dataset, sampler, t_out, dataset.ltd_rule, [s.subaction for s in sequences]
    )
    if len(index) == 0:
        raise EvaluationError(
            f"benchmark {bench.name}: sampler {sampler} found no window of "
            f"{t_in + t_out} frames in {dataset.root}"
        )
    windows_per_action = {a: int((actions == a).sum()) for a in dataset.actions_present}
    record = skeleton_record(bench, dataset, sampler, windows_per_action)
    record.update(_task_record(task, t_out))
    return Protocol(bench, dataset, sampler, task, t_in, t_out, index, actions, _sealed(record))


def skeleton_record(
    bench: Benchmark, dataset: MotionDataset, sampler: str, windows_per_action: dict[str, int]
) -> dict[str, Any]:
    skeleton = dataset.skeleton
    return {
        "benchmark": bench.name,
        "dataset": dataset.name,
        "split": dataset.split,
        "skeleton": skeleton.name,
        "units": "mm",
        "source_fps": dataset.source_fps,
        "subsample": dataset.subsample,
        "fps": dataset.fps,
        "input_frames": bench.input_frames,
        "output_frames": bench.output_frames,
        "horizon_rule": f"predicted frame t (1-based) is at t * {1000 / dataset.fps:g} ms",
        "sampler": sampler,
        "windows_per_action": windows_per_action,
        "actions_requested": list(dataset.actions_requested),
        "actions_present": list(dataset.actions_present),
        "files": [
            {"file": f["file"], "sha256": f["sha256"], "frames": f["frames"]}
            for f in dataset.files()
        ],
        "joint_protocols": joint_protocols(skeleton),
        "averaging": AVERAGING,
        "action_averaging": ACTION_AVERAGING,
        "global_motion": "root translation and rotation removed by FK (never applied)",
    }


def mesh_record(
    bench: Benchmark,
    dataset,
    sampler: str,
    windows_per_action: dict[str, int],
    ground_truth: str,
    basis=None,
    melv_frames: str = "raw",
) -> dict[str, Any]:
    """The record of a mesh protocol: the data, windows and frames, as for skeletons, plus the
    mesh's own elements (topology, ground truth, spectral basis, MELV frames)."""
    topology = dataset.topology
    joints = {
        "vertices": f"all {topology.num_vertices} vertices (MELV: their "
        f"{len(topology.edges)} unique undirected edges)"
    }
    if dataset.joint_regressor is not None:
        n = dataset.joint_regressor.shape[0]
        names = f" ({', '.join(dataset.joint_names)})" if dataset.joint_names else ""
        joints[f"regressor{n}"] = (
            f"{n} joints regressed from the vertices by the dataset's "
            f"sparse joint regressor{names}, mean L2 error over them"
        )
    if ground_truth == "spectral":
        truth = f"spectral{basis.k}"
        truth_rule = (
            f"every window (observed and future frames) replaced by its reconstruction "
            f"from the k={basis.k} lowest-frequency Laplacian coefficients, as "
            f"SpecTrHuMS scores"
        )
    else:
        truth, truth_rule = "raw", "the dataset's vertices as stored"
    fps = dataset.fps
    return {
        "benchmark": bench.name,
        "dataset": dataset.name,
        "split": dataset.split,
        "representation": "mesh",
        "units": "mm (rmse: none, normalised)",
        "fps": fps,
        "input_frames": bench.input_frames,
        "output_frames": bench.output_frames,
        "horizon_rule": f"predicted frame t (1-based) is at t * {1000 / fps:g} ms",
        "sampler": sampler,
        "windows_per_action": windows_per_action,
        "actions_present": [a for a in dataset.actions_present if a in windows_per_action],
        "topology_hash": topology.hash,
        "num_vertices": topology.num_vertices,
        "recipe_hash": dataset.recipe_hash,
        "ground_truth": truth,
        "ground_truth_rule": truth_rule,
        "spectral_basis": (
            {"k": basis.k, "hash": basis.hash, "topology_hash": basis.topology_hash}
            if basis is not None
            else None
        ),
        "melv_frames": (
            f"spectral{basis.k}: the reference frame and the scored frames "
            f"reconstructed from their k={basis.k} lowest-frequency Laplacian "
            f"coefficients (as SpecTrHuMS measures)"
            if melv_frames == "spectral"
            else "raw: the frames as scored"
        ),
        "joint_protocols": joints,
        "metrics": {
            **{metric.name: metric.description for metric in View.MESH.metrics},
            "std": STD_DESCRIPTION,
            "floor": f"model `<name>{FLOOR_SUFFIX}` rows: the ground-truth future through the "
            f"model's autoencoder alone (it sees the future: a bound, not a "
            f"prediction)",
        },
        "averaging": AVERAGING,
        "action_averaging": ACTION_AVERAGING,
        "global_motion": dataset.recipe.get("global_motion", "as stored in the dataset"),
    }


def _mesh_plan(
    bench: Benchmark,
    dataset,
    sampler: str | None,
    task: str,
    horizon: int | None,
    ground_truth: str | None,
    melv_frames: str | None,
) -> Protocol:
    sampler = window_rules.check_sampler(sampler or bench.sampler)
    ground_truth = ground_truth or bench.ground_truth
    if ground_truth not in GROUND_TRUTHS:
        raise EvaluationError(
            f"ground_truth must be one of {', '.join(GROUND_TRUTHS)}, got {ground_truth!r}"
        )
    melv_frames = melv_frames or bench.melv_on
    if melv_frames not in GROUND_TRUTHS:
        raise EvaluationError(
            f"melv_frames must be one of {', '.join(GROUND_TRUTHS)}, got {melv_frames!r}"
        )
    if "spectral" in (ground_truth, melv_frames) and bench.spectral_k is None:
        raise EvaluationError(
            f"benchmark {bench.name}: spectral ground truth or MELV needs a "
            f"spectral basis (field spectral_k in {bench.source})"
        )
    basis = bench.spectral_basis(dataset) if "spectral" in (ground_truth, melv_frames) else None
    t_in = bench.input_frames
    t_out = check_task(task, horizon, bench.output_frames)
    sequences = dataset.sequences
    index, actions = _windows(bench, dataset, sampler, t_out, "per_file")
    if len(index) == 0:
        raise EvaluationError(
            f"benchmark {bench.name}: sampler {sampler} found no window of "
            f"{t_in + t_out} frames in {dataset.name}/{dataset.split} "
            f"(sequences of {min(len(s) for s in sequences)} to "
            f"{max(len(s) for s in sequences)} frames)"
        )
    windows_per_action = {
        a: int((actions == a).sum()) for a in dataset.actions_present if (actions == a).any()
    }
    record = {
        **mesh_record(
            bench, dataset, sampler, windows_per_action, ground_truth, basis, melv_frames
        ),
        **_task_record(task, t_out),
    }
    return Protocol(
        bench,
        dataset,
        sampler,
        task,
        t_in,
        t_out,
        index,
        actions,
        _sealed(record),
        ground_truth=ground_truth,
        melv_frames=melv_frames,
        basis=basis,
    )
