"""Benchmarks of a mesh's vertices (``representation: mesh``): sequences of ``(T, V, 3)``
vertices on one triangulation, models fed the vertices (or, for a skeleton model, the joints
the dataset's regressor takes from them), rows of MELV, RMSE and, with a regressor, MPJPE.

The benchmark names the number ``spectral_k`` of Laplacian eigenvectors of its spectral basis
(what models with ``context: [basis]`` receive) and the ground truth its rows score against:
``raw`` vertices or ``spectral`` (the k-coefficient reconstruction, as SpecTrHuMS does)."""

from __future__ import annotations

from functools import partial
from typing import Any, Literal, get_args

import numpy as np
import torch

from zoo.core.errors import BenchmarkError, EvaluationError
from zoo.data.mesh import JointsView, MeshDataset, regress_joints
from zoo.data.spectral import SpectralBasis
from zoo.data.windows import gather_windows
from zoo.protocol.metrics import (
    ACTION_AVERAGING,
    AVERAGING,
    FLOOR_SUFFIX,
    STD_DESCRIPTION,
    edge_lengths,
    mpjpe,
    scored_errors,
)
from zoo.protocol.representation import (
    JointsTruth,
    PlannedWindows,
    Representation,
    Scoring,
    TruthBatch,
)
from zoo.protocol.views import View

MESH_BATCH_VALUES = 2**24  # float32 values of ground-truth windows held at once (64 MiB)
GroundTruth = Literal["raw", "spectral"]
GROUND_TRUTHS = get_args(GroundTruth)


class MeshRepresentation(Representation):
    name = "mesh"
    dataset_type = MeshDataset
    fields = ("spectral_k", "ground_truth", "ground_truths", "melv_frames")
    drawn = True

    def check_fields(self, fields) -> None:
        offered = fields.ground_truths or (fields.ground_truth,)
        if fields.ground_truth not in offered:
            raise ValueError(
                f"field 'ground_truth' ({fields.ground_truth!r}) must be one of field "
                f"'ground_truths' {list(offered)}"
            )
        if fields.spectral_k is None and "spectral" in offered:
            raise ValueError("ground truth 'spectral' needs field 'spectral_k'")
        if fields.spectral_k is None and fields.melv_frames == "spectral":
            raise ValueError("field 'melv_frames: spectral' needs field 'spectral_k'")

    def view_for(self, representations) -> View:
        """Its vertices, or for a skeleton-only model the joints its regressor takes from them
        (which the mesh models' MPJPE is scored on)."""
        if self.name in representations:
            return View.MESH
        if View.JOINTS.value in representations:
            return View.JOINTS
        raise BenchmarkError(
            f"a mesh benchmark feeds models of representation mesh or joints, not "
            f"{', '.join(representations)}"
        )

    def scored_kinds(self, dataset) -> tuple[str, ...]:
        """Skeleton models join a mesh benchmark with a joint regressor, fed its joints."""
        return (self.name, "joints") if dataset.joint_regressor is not None else (self.name,)

    def model_inputs(self, bench, context: tuple[str, ...], view: View, dataset) -> dict:
        """Read from ``dataset()`` (any split: they share the topology); ``view='joints'``: a
        skeleton model's keywords for the dataset's regressed joints."""
        data = dataset()
        if view == View.JOINTS:
            joints = data if isinstance(data, JointsView) else data.joints_view()
            inputs: dict[str, Any] = {"num_points": joints.num_joints}
            supplied = {"parts": lambda: joints.parts}
            whom = " to a model of its regressed joints"
        else:
            inputs = {"num_points": data.topology.num_vertices}
            supplied = {"basis": lambda: basis_of(bench, data)}
            whom = ""
        inputs = {
            "input_frames": bench.input_frames,
            "output_frames": bench.output_frames,
            **inputs,
        }
        for name in context:
            if name not in supplied:
                raise BenchmarkError(
                    f"benchmark {bench.name!r} cannot supply context {name!r}{whom}; it "
                    f"supplies: {', '.join(supplied)}"
                )
            inputs[name] = supplied[name]()
        return inputs

    def ground_truths(self, bench) -> tuple[str | None, ...]:
        return bench.ground_truths or (bench.ground_truth,)

    def plan(self, bench, dataset, sampler, t_out, ground_truth, melv_frames) -> PlannedWindows:
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
        basis = basis_of(bench, dataset) if "spectral" in (ground_truth, melv_frames) else None
        sequences = dataset.sequences
        index, actions = self.windows(bench, dataset, sampler, t_out, "per_file")
        if len(index) == 0:
            raise EvaluationError(
                f"benchmark {bench.name}: sampler {sampler} found no window of "
                f"{bench.input_frames + t_out} frames in {dataset.name}/{dataset.split} "
                f"(sequences of {min(len(s) for s in sequences)} to "
                f"{max(len(s) for s in sequences)} frames)"
            )
        windows_per_action = {
            a: int((actions == a).sum()) for a in dataset.actions_present if (actions == a).any()
        }
        record = _record(
            bench, dataset, sampler, windows_per_action, ground_truth, basis, melv_frames
        )
        return PlannedWindows(index, actions, record, ground_truth, melv_frames, basis)

    def scoring(self, protocol, device) -> Scoring:
        return _MeshScoring(protocol, device)

    def headline(self, record: dict[str, Any]) -> tuple[str, str]:
        """The normalised vertex RMSE."""
        return "rmse", "vertices"

    def weights_fields(self, bench, view: View) -> dict[str, Any]:
        """``view``: ``joints`` for a skeleton model trained on the regressed joints."""
        return {
            "representation": self.name,
            "spectral_k": bench.spectral_k,
            **({"points": "regressed joints"} if view == View.JOINTS else {}),
        }

    def training_record(self, dataset, view: View) -> dict[str, Any]:
        """The mesh's recipe and content; a skeleton model's (``dataset``: the mesh's
        :class:`JointsView`) names its regressed joints."""
        mesh = dataset.mesh if view is View.JOINTS else dataset
        return {
            "dataset": mesh.name,
            "split": mesh.split,
            "recipe_hash": mesh.recipe_hash,
            "content_hash": mesh.content_hash(),
            "topology_hash": mesh.topology.hash,
            **({"points": f"regressor{dataset.num_joints}"} if view is View.JOINTS else {}),
        }

    def validation_curve(self, view: View) -> str:
        return "rmse" if view is View.MESH else "mpjpe"

    def training_data(self, dataset: MeshDataset, view: View):
        """Every vertex, or a skeleton model's regressed joints (all of them)."""
        return (dataset.joints_view() if view is View.JOINTS else dataset), slice(None)


def basis_of(bench, dataset) -> SpectralBasis:
    """The :class:`SpectralBasis` of ``dataset``'s topology with ``bench.spectral_k`` vectors,
    from the basis cache (computed once, then never recomputed)."""
    if bench.spectral_k is None:
        raise BenchmarkError(
            f"benchmark {bench.name!r} ({bench.source}) sets no spectral_k: it has no "
            f"spectral basis"
        )
    return SpectralBasis.load_or_compute(dataset.topology, bench.spectral_k)


def _record(
    bench,
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


class _MeshScoring(Scoring):
    """How one mesh protocol scores a model on a batch of windows.

    ``melv_frames``: ``spectral`` (the default of benchmarks with a basis) measures MELV on the
    k-coefficient reconstruction of the reference frame and of the scored frames, as SpecTrHuMS
    does; ``raw`` on the frames as they are.

    ``view='joints'``: a skeleton model sees the regressed joints ``(B, T_in, J, 3)`` of the same
    windows and predicts ``(B, T_out, J, 3)``; it gets the ``mpjpe`` rows only, under the very
    protocol record of the mesh models, so both share one MPJPE table."""

    def __init__(self, protocol, device) -> None:
        self.protocol = protocol
        self.regressor = protocol.dataset.joint_regressor
        self.regress = partial(regress_joints, regressor=self.regressor)
        self.t_in, self.t_out = protocol.input_frames, protocol.predicted_frames
        self.num_vertices = protocol.dataset.topology.num_vertices
        self.joint_column = (
            f"regressor{self.regressor.shape[0]}" if self.regressor is not None else None
        )
        # once, not per call
        self.edges = torch.as_tensor(np.asarray(protocol.dataset.topology.edges), dtype=torch.long)
        self.vertices = [s.vertices for s in protocol.dataset.sequences]

    def batch_size(self, asked: int) -> int:
        """``asked``, or fewer windows where a batch would exceed ``MESH_BATCH_VALUES``."""
        window_values = (self.t_in + self.t_out) * self.num_vertices * 3
        return max(1, min(asked, MESH_BATCH_VALUES // window_values))

    def truth(self, index: np.ndarray, views) -> _MeshBatch:
        """The ground-truth windows of ``index`` (spectral truth: their reconstruction) and, for
        mesh models, the reference frame's edge lengths and the future's own MELV."""
        windows = torch.from_numpy(gather_windows(self.vertices, index, self.t_in + self.t_out))
        if self.protocol.ground_truth == "spectral":
            basis = self.protocol.basis
            windows = basis.reconstruct(basis.project(windows.double())).float()
        truth = _MeshBatch(windows, self.t_in, self.regress, self.joint_column, self.melv_lengths)
        if View.MESH in views:
            reference = windows[:, self.t_in - 1 : self.t_in]
            truth.reference_lengths = self.melv_lengths(reference)[:, 0]
            # the data's own figures (MELV's): the ground-truth rows of every mesh model
            own = [m for m in View.MESH.metrics if m.ground_truth_rows]
            truth.own = scored_errors({"ground_truth": truth.target}, own, truth)
        return truth

    def check_view(self, view, name: str) -> None:
        if not isinstance(view, View):
            raise EvaluationError(f"view must be mesh or joints, got {view!r}")
        if view is View.JOINTS and self.regressor is None:
            raise EvaluationError(
                f"benchmark {self.protocol.benchmark.name}: {self.protocol.dataset.name} has no "
                f"joint regressor, so skeleton model {name!r} cannot be evaluated on it"
            )

    def melv_lengths(self, frames: torch.Tensor) -> torch.Tensor:
        """Edge lengths of the frames MELV is measured on."""
        if self.protocol.melv_frames == "spectral":  # reconstructed from k coefficients
            basis = self.protocol.basis
            frames = basis.reconstruct(basis.project(frames.double())).float()
        return edge_lengths(frames, self.edges)

    def recorded(self, view: View, model) -> dict[str, Any]:
        basis, dataset = self.protocol.basis, self.protocol.dataset
        model_basis = getattr(model, "basis", None)
        return {
            # The data are named by their recipe in the protocol; the bytes of a generated mesh
            # follow the machine's float kernels (CMU-on-Anny's skinning: other bytes on another
            # CPU), so their hash is this build's provenance, not the protocol's.
            "data_hash": dataset.content_hash(),
            "data_exactness": "generated from its recipe on this machine: another CPU's build "
            "may differ in the last bits of its vertices (data_hash), and so may errors "
            "computed from them (MELV most: a difference of edge lengths)",
            **({"basis_checksum": basis.checksum} if isinstance(basis, SpectralBasis) else {}),
            **(
                {"model_basis": {"k": model_basis.k, "hash": model_basis.hash}}
                if isinstance(model_basis, SpectralBasis)
                else {}
            ),
            **(
                {"model_input": f"regressed joints ({self.joint_column})"}
                if view is View.JOINTS
                else {}
            ),
        }


class _MeshBatch(TruthBatch):
    """One batch of ground-truth windows and what is computed from them once for every model:
    the reference frame's edge lengths and the future's own errors (set by the scoring), the
    regressed joints (``regress(windows)``, on first use, scored as ``joint_column``; none
    without a regressor)."""

    def __init__(self, windows: torch.Tensor, t_in: int, regress, joint_column, melv_lengths):
        self.windows, self.t_in, self.regress = windows, t_in, regress
        self.joint_column, self.melv_lengths = joint_column, melv_lengths
        self.target = windows[:, t_in:]
        self.reference_lengths: torch.Tensor | None = None
        self.own: dict = {}
        self._joints: torch.Tensor | None = None

    def joints(self) -> torch.Tensor:
        if self._joints is None:
            self._joints = self.regress(self.windows)
        return self._joints

    def observed(self, view: View):
        windows = self.joints() if view is View.JOINTS else self.windows
        return windows[:, : self.t_in], windows[:, -1]

    def floor_target(self, view: View) -> torch.Tensor | None:
        """Mesh models' floor rows (the record's ``floor``), on the vertices' future."""
        return self.target if view is View.MESH else None

    def scored_as(self, view: View):
        """Itself for a mesh model; for a skeleton model, its regressed joints."""
        if view is View.MESH:
            return self
        column = self.joint_column
        return JointsTruth(
            self.joints()[:, self.t_in :], lambda pred, target: {column: mpjpe(pred, target)}
        )

    def own_errors(self, view: View) -> dict:
        return self.own if view is View.MESH else {}

    def joint_errors(self, pred: torch.Tensor) -> dict[str, torch.Tensor]:
        """MPJPE of the joints that predicted vertices ``pred`` regress to."""
        if self.joint_column is None:
            return {}
        return {self.joint_column: mpjpe(self.regress(pred), self.joints()[:, self.t_in :])}
