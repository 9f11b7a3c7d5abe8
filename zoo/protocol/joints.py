"""Benchmarks of a skeleton's joints (``representation: joints``): recordings of ``(T, J, 3)``
positions on the skeleton the benchmark file names, models fed the joints the skeleton
predicts, rows of MPJPE under each joint protocol of the skeleton."""

from __future__ import annotations

from functools import partial
from typing import Any

import torch

from zoo.core.errors import BenchmarkError, EvaluationError
from zoo.data.motion import MotionDataset
from zoo.data.skeleton import Skeleton
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
            if seq.fps != dataset.fps:
                raise BenchmarkError(
                    f"{where}: recording {seq.name!r} is at {seq.fps} Hz, the dataset at "
                    f"{dataset.fps} Hz; a benchmark's recordings share one frame rate"
                )

    def view_for(self, representations) -> View:
        return View.JOINTS

    def model_inputs(self, bench, context: tuple[str, ...], view: View, dataset) -> dict:
        skeleton = bench.skeleton
        inputs: dict[str, Any] = {
            "input_frames": bench.input_frames,
            "output_frames": bench.output_frames,
            "num_points": len(skeleton.used),
        }
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

    def weights_protocol(self, bench, view: View) -> dict[str, Any]:
        return {
            "benchmark": bench.name,
            "dataset": bench.dataset,
            "input_frames": bench.input_frames,
            "output_frames": bench.output_frames,
            "skeleton": bench.skeleton.name,
            "used_joints": list(bench.skeleton.used),
        }

    def training_record(self, dataset: MotionDataset, view: View) -> dict[str, Any]:
        return {
            "dataset": dataset.name,
            "split": dataset.split,
            "files": [{"file": f["file"], "sha256": f["sha256"]} for f in dataset.files()],
        }

    def training_data(self, dataset: MotionDataset, view: View):
        return dataset, list(dataset.skeleton.used)


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
        self.positions = [s.positions for s in protocol.dataset.sequences]
        self.benchmark = protocol.benchmark.name

    def check_view(self, view, name: str) -> None:
        if view is not View.JOINTS:
            raise EvaluationError(
                f"benchmark {self.benchmark} is a joints benchmark: model {name!r} must be fed "
                f"view joints, got {view!r}"
            )

    def truth(self, index, views) -> TruthBatch:
        windows = torch.from_numpy(gather_windows(self.positions, index, self.frames))
        return _JointsBatch(windows, self.used, self.t_in, self.skeleton)


class _JointsBatch(TruthBatch):
    def __init__(self, windows: torch.Tensor, used: list[int], t_in: int, skeleton) -> None:
        self.windows, self.used, self.t_in = windows, used, t_in
        self.truth = JointsTruth(windows[:, t_in:], partial(skeleton_errors, skeleton=skeleton))

    def observed(self, view: View):
        return self.windows[:, : self.t_in, self.used], self.windows[:, -1, self.used]

    def scored_as(self, view: View) -> JointsTruth:
        return self.truth
