"""Benchmarks of a skeleton's joints (``representation: joints``): recordings of ``(T, J, 3)``
positions on the skeleton the benchmark file names, models fed the joints the skeleton
predicts (or, where the data keeps them, every joint's exp-map angles: registry representation
``expmap``), rows of MPJPE under each joint protocol of the skeleton."""

from __future__ import annotations

from dataclasses import replace
from functools import partial
from typing import Any

import torch

from zoo.core.errors import BenchmarkError, EvaluationError, TrainingError
from zoo.data.motion import MotionDataset
from zoo.data.skeleton import Skeleton, forward_kinematics
from zoo.data.windows import gather_windows
from zoo.protocol.metrics import ACTION_AVERAGING, AVERAGING, joint_protocols, skeleton_errors
from zoo.protocol.representation import (
    JointsTruth,
    PlannedWindows,
    Representation,
    Scoring,
    TruthBatch,
)
from zoo.protocol.views import View


class JointsRepresentation(Representation):
    name = "joints"
    dataset_type = MotionDataset
    fields = ("skeleton",)
    model_kinds = ("expmap",)

    def check_fields(self, fields) -> None:
        if not fields.skeleton_def:
            raise ValueError(
                "a joints benchmark names the skeleton its recordings are on in field "
                "'skeleton', as package.module:NAME or file.py:NAME (e.g. zoo.data.skeleton:CMU)"
            )

    def check_dataset(self, bench, dataset: MotionDataset) -> None:
        """A loader's recordings are on the skeleton the file names, as ``(T, J, 3)`` positions
        at the dataset's one frame rate (windows count frames, horizons are milliseconds)."""
        where = f"{bench.source}: field 'loader': {bench.loader}"
        skeleton = bench.skeleton
        if not _same_skeleton(dataset.skeleton, skeleton):
            raise BenchmarkError(
                f"{bench.source}: field 'skeleton': {bench.loader} gave recordings on skeleton "
                f"{dataset.skeleton.name!r} ({dataset.skeleton.num_joints} joints), the file "
                f"names {bench.skeleton_def} ({skeleton.name!r}, {skeleton.num_joints} joints)"
            )
        shape = (skeleton.num_joints, 3)
        for seq in dataset.sequences:
            positions = getattr(seq.positions, "shape", ())
            if len(positions) != 3 or tuple(positions[1:]) != shape:
                raise BenchmarkError(
                    f"{where}: recording {seq.name!r} has positions of shape {positions}, "
                    f"expected (frames, {shape[0]}, 3)"
                )
            angles = getattr(seq.angles, "shape", None)
            if angles is not None and tuple(angles) != tuple(positions):
                raise BenchmarkError(
                    f"{where}: recording {seq.name!r} has angles of shape {angles}, expected "
                    f"its positions' {positions}"
                )
            if seq.fps != dataset.fps:
                raise BenchmarkError(
                    f"{where}: recording {seq.name!r} is at {seq.fps} Hz, the dataset at "
                    f"{dataset.fps} Hz; a benchmark's recordings share one frame rate"
                )

    def view_for(self, representations) -> View:
        """Joints, or a model of angles alone its exp-map angles."""
        if View.EXPMAP.value in representations and self.name not in representations:
            return View.EXPMAP
        return View.JOINTS

    def scored_kinds(self, dataset) -> tuple[str, ...]:
        """Models of exp-map angles join where every recording keeps its angles."""
        if all(s.angles is not None for s in dataset.sequences):
            return (self.name, View.EXPMAP.value)
        return (self.name,)

    def model_inputs(self, bench, context: tuple[str, ...], view: View, dataset) -> dict:
        skeleton = bench.skeleton
        inputs: dict[str, Any] = {
            "input_frames": bench.input_frames,
            "output_frames": bench.output_frames,
            "num_points": skeleton.num_joints if view is View.EXPMAP else len(skeleton.used),
        }
        if context and view is View.EXPMAP:
            raise BenchmarkError(
                f"benchmark {bench.name!r} supplies no context to a model of exp-map angles "
                f"(asked for {', '.join(context)})"
            )
        for name in context:
            if name == "parts":
                inputs["parts"] = {k: list(v) for k, v in skeleton.parts.items()}
            else:
                raise BenchmarkError(
                    f"benchmark {bench.name!r} cannot supply context {name!r}; it supplies: parts"
                )
        return inputs

    def plan(self, bench, dataset, sampler, t_out, ground_truth, melv_frames) -> PlannedWindows:
        for field, value in (("ground_truth", ground_truth), ("melv_frames", melv_frames)):
            if value is not None:
                raise EvaluationError(
                    f"benchmark {bench.name}: {field}={value!r} applies to mesh benchmarks only"
                )
        sequences = dataset.sequences
        index, actions = self.windows(
            bench, dataset, sampler, t_out, dataset.ltd_rule, [s.subaction for s in sequences]
        )
        if len(index) == 0:
            raise EvaluationError(
                f"benchmark {bench.name}: sampler {sampler} found no window of "
                f"{bench.input_frames + t_out} frames in {dataset.root}"
            )
        windows_per_action = {a: int((actions == a).sum()) for a in dataset.actions_present}
        return PlannedWindows(index, actions, _record(bench, dataset, sampler, windows_per_action))

    def scoring(self, protocol, device) -> Scoring:
        return _JointsScoring(protocol)

    def headline(self, record: dict[str, Any]) -> tuple[str, str]:
        """MPJPE under the first (official) joint protocol."""
        return "mpjpe", next(iter(record.get("joint_protocols") or {"all": ""}))

    def weights_fields(self, bench, view: View) -> dict[str, Any]:
        return {
            "skeleton": bench.skeleton.name,
            "used_joints": list(bench.skeleton.used),
            **({"view": view.value} if view is View.EXPMAP else {}),
        }

    def training_record(self, dataset: MotionDataset, view: View) -> dict[str, Any]:
        return {
            "dataset": dataset.name,
            "split": dataset.split,
            "files": [{"file": f["file"], "sha256": f["sha256"]} for f in dataset.files()],
            **({"view": view.value} if view is View.EXPMAP else {}),
        }

    def training_data(self, dataset: MotionDataset, view: View):
        """Joint positions, or for an angle model every joint's exp-map angles as the frames
        it trains on (:meth:`training_points` scores them as positions)."""
        if view is not View.EXPMAP:
            return dataset, list(dataset.skeleton.used)
        missing = [s.name for s in dataset.sequences if s.angles is None]
        if missing:
            raise TrainingError(
                f"dataset {dataset.name}: recording {missing[0]!r} keeps no exp-map angles to "
                f"train a model of view expmap on"
            )
        angles = [replace(s, positions=s.angles) for s in dataset.sequences]
        return replace(dataset, sequences=angles), list(range(dataset.skeleton.num_joints))

    def training_points(self, dataset: MotionDataset, view: View):
        """What validation scores a window of :meth:`training_data`'s frames as: the
        benchmark's predicted joints (of an angle model's frames, their positions)."""
        if view is not View.EXPMAP:
            return None
        return partial(_angles_to_joints, skeleton=dataset.skeleton)


def _record(
    bench, dataset: MotionDataset, sampler: str, windows_per_action: dict[str, int]
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


def _angles_to_joints(angles: torch.Tensor, skeleton: Skeleton, used=None) -> torch.Tensor:
    """Exp-map frames ``(B, T, J, 3)`` as the positions ``(B, T, J', 3)`` of the joints
    ``used`` (default: the skeleton's predicted ones), by the one FK routine."""
    b, t = angles.shape[:2]
    positions = forward_kinematics(angles.reshape(b * t, *angles.shape[2:]), skeleton)
    used = list(skeleton.used) if used is None else used
    return positions.view(b, t, *positions.shape[1:])[:, :, used]


def _same_skeleton(a: Skeleton, b: Skeleton) -> bool:
    """The same joints, tree, parts and scoring rule (offsets aside: positions come with the
    data)."""
    rule = ("name", "parents", "ignored", "copy_to", "copy_from", "parts", "official")
    return all(getattr(a, f) == getattr(b, f) for f in rule)


class _JointsScoring(Scoring):
    """Models fed the predicted joints of each window, scored on all of the skeleton's joints
    under each of its joint protocols."""

    def __init__(self, protocol) -> None:
        self.skeleton = protocol.dataset.skeleton
        self.used = list(self.skeleton.used)
        self.t_in, self.frames = protocol.input_frames, protocol.window_frames
        sequences = protocol.dataset.sequences
        self.positions = [s.positions for s in sequences]
        self.angles = [s.angles for s in sequences]
        self.benchmark = protocol.benchmark.name

    def check_view(self, view, name: str) -> None:
        kept = all(a is not None for a in self.angles)
        if view is not View.JOINTS and not (view is View.EXPMAP and kept):
            offered = "joints or expmap" if kept else "joints"
            raise EvaluationError(
                f"benchmark {self.benchmark} is a joints benchmark: model {name!r} must be fed "
                f"view {offered}, got {str(view)!r}"
            )

    def truth(self, index, views) -> TruthBatch:
        windows = torch.from_numpy(gather_windows(self.positions, index, self.frames))
        angles = None
        if View.EXPMAP in views:
            angles = torch.from_numpy(gather_windows(self.angles, index, self.frames))
        return _JointsBatch(windows, angles, self.used, self.t_in, self.skeleton)


class _JointsBatch(TruthBatch):
    def __init__(self, windows, angles, used: list[int], t_in: int, skeleton) -> None:
        self.windows, self.angles, self.used, self.t_in = windows, angles, used, t_in
        errors = partial(skeleton_errors, skeleton=skeleton)
        self.truth = JointsTruth(windows[:, t_in:], errors)
        # an angle model's prediction is scored as the joints FK makes of it
        self.angle_truth = JointsTruth(
            windows[:, t_in:],
            lambda pred, target: errors(_angles_to_joints(pred, skeleton, used), target),
        )

    def observed(self, view: View):
        if view is View.EXPMAP:
            return self.angles[:, : self.t_in], self.angles[:, -1]
        return self.windows[:, : self.t_in, self.used], self.windows[:, -1, self.used]

    def scored_as(self, view: View) -> JointsTruth:
        return self.angle_truth if view is View.EXPMAP else self.truth
