"""The one implementation of every metric and its one declaration (:data:`METRICS`: unit,
printed precision, tolerance, text of the protocol records, and how a batch is scored), plus the
accumulator the evaluator streams into. The evaluator scores the metrics a view declares
(:class:`zoo.protocol.views.View`), each through its declaration's ``score``.

Per-frame errors are computed per window as ``(B, T_out)`` tensors; :class:`FrameErrorMean`
accumulates them per action (``update`` / ``compute``, as in torchmetrics); averaging over time
(``frame`` or ``cumulative``) and over actions happens once, at the end.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import torch

from zoo.data.skeleton import Skeleton

AVERAGING = {
    "frame": "error at predicted frame t alone (LTD, HisRep, SPGSN, siMLPe, SpecTrHuMS)",
    "cumulative": "mean of the per-frame errors over predicted frames 1..t (STS-GCN)",
}
ACTION_AVERAGING = "mean over windows inside an action, then unweighted mean over actions present"


# Rows of a model's autoencoder floor (the ground-truth future through its autoencoder alone: a
# bound, not a prediction) are labelled <model>:autoencoder.
FLOOR_SUFFIX = ":autoencoder"
# The ``std`` column of every row, as the mesh protocol records describe it.
STD_DESCRIPTION = (
    "standard deviation over windows (ddof 1) of the row's error; `average` rows "
    "pool the windows of every action"
)


def mpjpe(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean per-joint position error: ``(..., J, 3)`` -> ``(...)``, L2 norm averaged over J."""
    if pred.shape != target.shape:
        raise ValueError(
            f"mpjpe: prediction {tuple(pred.shape)} and target "
            f"{tuple(target.shape)} differ in shape"
        )
    return torch.linalg.vector_norm(pred - target, dim=-1).mean(dim=-1)


def cumulative_mean(per_frame: np.ndarray, axis: int = -1) -> np.ndarray:
    """Mean of the first t values for every t (the ``cumulative`` averaging protocol)."""
    steps = np.arange(1, per_frame.shape[axis] + 1)
    shape = [1] * per_frame.ndim
    shape[axis] = -1
    return np.cumsum(per_frame, axis=axis) / steps.reshape(shape)


# ---- joint protocols of the skeleton benchmarks ---------------------------------------------


def joint_protocols(skeleton: Skeleton) -> dict[str, str]:
    """Named joint protocols of a skeleton and what each means, the one the literature reports
    first (``skeleton.official``) first."""
    protocols = {
        f"all{skeleton.num_joints}": (
            f"{'official scoring: ' if skeleton.official == 'all' else ''}the "
            f"{len(skeleton.used)} predicted joints written into the "
            f"ground-truth {skeleton.num_joints}-joint pose, joints {list(skeleton.copy_to)} "
            f"overwritten by predicted joints {list(skeleton.copy_from)}, L2 error averaged over "
            f"all {skeleton.num_joints} joints (static joints count as zero)"
        ),
        f"used{len(skeleton.used)}": (
            f"plain mean L2 error over the {len(skeleton.used)} predicted joints"
        ),
    }
    if skeleton.official == "used":
        protocols = dict(reversed(list(protocols.items())))
    return protocols


def skeleton_errors(
    pred_used: torch.Tensor, target: torch.Tensor, skeleton: Skeleton
) -> dict[str, torch.Tensor]:
    """Per-frame MPJPE ``(B, T)`` under each joint protocol.

    ``pred_used``: ``(B, T, len(used), 3)``; ``target``: the full ground truth ``(B, T, J, 3)``.
    """
    used = list(skeleton.used)
    full = target.clone()
    full[:, :, used] = pred_used
    full[:, :, list(skeleton.copy_to)] = full[:, :, list(skeleton.copy_from)]
    errors = {
        f"all{skeleton.num_joints}": mpjpe(full, target),
        f"used{len(skeleton.used)}": mpjpe(pred_used, target[:, :, used]),
    }
    return {name: errors[name] for name in joint_protocols(skeleton)}


# ---- accumulation ------------------------------------------------------------------------------


class FrameErrorMean:
    """Running mean and standard deviation over windows of per-frame errors, per group (action).

    Sums in float64 so that thousands of windows add up without drift. The standard deviation is
    over windows (``ddof=1``), of each window's error at frame t (``frame`` averaging) or of its
    mean over frames 1..t (``cumulative``); for the ``average`` group it pools every window.
    """

    def __init__(self) -> None:
        self.sums: dict[str, np.ndarray] = {}
        self.squares: dict[str, dict[str, np.ndarray]] = {}
        self.counts: dict[str, int] = defaultdict(int)

    def update(self, errors: torch.Tensor | np.ndarray, groups: Sequence[str]) -> None:
        errors = (
            errors.detach().to("cpu", torch.float64).numpy()
            if isinstance(errors, torch.Tensor)
            else np.asarray(errors, dtype=np.float64)
        )
        if errors.ndim != 2 or len(errors) != len(groups):
            raise ValueError(
                f"FrameErrorMean.update: expected errors (B, T) with one group per "
                f"window, got {errors.shape} and {len(groups)} groups"
            )
        groups = np.asarray(groups)
        for g in np.unique(groups):
            rows = errors[groups == g]
            squares = {
                "frame": np.square(rows).sum(axis=0),
                "cumulative": np.square(cumulative_mean(rows, axis=1)).sum(axis=0),
            }
            if g in self.sums:
                self.sums[g] += rows.sum(axis=0)
                for averaging, value in squares.items():
                    self.squares[g][averaging] += value
            else:
                self.sums[g] = rows.sum(axis=0)
                self.squares[g] = squares
            self.counts[g] += len(rows)

    def compute(self) -> dict[str, np.ndarray]:
        """Per-group mean per-frame error ``(T,)``; the group ``average`` is their unweighted
        mean."""
        means = {g: self.sums[g] / self.counts[g] for g in self.sums}
        if means:
            means["average"] = np.mean(np.stack(list(means.values())), axis=0)
        return means

    def std(self, averaging: str) -> dict[str, np.ndarray]:
        """Per-group standard deviation over windows ``(T,)`` under ``averaging`` (NaN for a
        group of one window); ``average`` pools the windows of every group."""
        if averaging not in AVERAGING:
            raise ValueError(f"averaging must be one of {', '.join(AVERAGING)}, got {averaging!r}")

        def spread(total, squares, count):
            if count < 2:
                return np.full_like(total, np.nan)
            mean = total / count
            if averaging == "cumulative":
                mean = cumulative_mean(mean)
            with np.errstate(invalid="ignore"):  # an infinite error has no finite spread
                return np.sqrt(np.maximum(squares - count * mean**2, 0.0) / (count - 1))

        out = {
            g: spread(self.sums[g], self.squares[g][averaging], self.counts[g]) for g in self.sums
        }
        if out:
            out["average"] = spread(
                sum(self.sums.values()),
                sum(sq[averaging] for sq in self.squares.values()),
                sum(self.counts.values()),
            )
        return out


# ---- mesh metrics ------------------------------------------------------------------------------


def edge_lengths(vertices: torch.Tensor, edges: np.ndarray | torch.Tensor) -> torch.Tensor:
    """Lengths of ``edges (E, 2)`` in ``vertices (..., V, 3)``: ``(..., E)``."""
    if not isinstance(edges, torch.Tensor):
        edges = torch.as_tensor(np.asarray(edges))
    edges = edges.to(device=vertices.device, dtype=torch.long)
    if edges.ndim != 2 or edges.shape[1] != 2:
        raise ValueError(f"edge_lengths: edges must be (E, 2), got {tuple(edges.shape)}")
    # index_select on the vertex axis of one (N, V, 3) view: 1.4 times faster than indexing
    # vertices[..., edges[:, 0], :], the same numbers
    flat = vertices.reshape(-1, *vertices.shape[-2:])
    ends = flat.index_select(1, edges[:, 0]) - flat.index_select(1, edges[:, 1])
    return torch.linalg.vector_norm(ends, dim=-1).view(*vertices.shape[:-2], len(edges))


def melv(
    pred: torch.Tensor, reference: torch.Tensor, edges: np.ndarray | torch.Tensor
) -> torch.Tensor:
    """Mean edge length variation ``(B, T)``: for every frame of ``pred (B, T, V, 3)``, the mean
    over the unique undirected ``edges (E, 2)`` of ``|len_t - len_ref|``, with ``reference
    (B, V, 3)`` the last observed ground-truth frame. In the vertices' units (mm).
    Scored on the ground-truth future it gives the data's own figure (the baseline)."""
    if pred.ndim != 4 or reference.shape != pred.shape[:1] + pred.shape[2:]:
        raise ValueError(
            f"melv: expected pred (B, T, V, 3) and reference (B, V, 3), got "
            f"{tuple(pred.shape)} and {tuple(reference.shape)}"
        )
    return length_variation(edge_lengths(pred, edges), edge_lengths(reference, edges))


def length_variation(lengths: torch.Tensor, reference_lengths: torch.Tensor) -> torch.Tensor:
    """MELV from edge lengths: ``lengths (B, T, E)`` of the scored frames against
    ``reference_lengths (B, E)``, the mean over edges of ``|len_t - len_ref|``: ``(B, T)``
    (:func:`melv` from lengths already measured, as the evaluator shares the reference's)."""
    return (lengths - reference_lengths.unsqueeze(1)).abs().mean(dim=-1)


def vertex_rmse(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Normalised per-frame vertex RMSE ``(B, T)`` of ``(B, T, V, 3)`` meshes.

    ``RMSE_t = sqrt(mean_v |v_hat - v|^2) / |max_v v - min_v v|``: the root mean squared vertex
    error divided by the length of the diagonal of the ground-truth frame's axis-aligned bounding
    box, so it has no unit. SpecTrHuMS reports an RMSE normalised by the bounding-box diagonal but
    publishes no code for it: this definition is the zoo's own.
    """
    if pred.shape != target.shape or pred.ndim != 4:
        raise ValueError(
            f"vertex_rmse: expected prediction and target (B, T, V, 3) of one "
            f"shape, got {tuple(pred.shape)} and {tuple(target.shape)}"
        )
    rmse = (pred - target).pow(2).sum(dim=-1).mean(dim=-1).sqrt()
    diagonal = torch.linalg.vector_norm(target.amax(dim=-2) - target.amin(dim=-2), dim=-1)
    return rmse / diagonal


# ---- declarations ------------------------------------------------------------------------------


class BatchTruth(Protocol):
    """What a metric reads from one batch of ground truth, as the evaluator gives it for a
    view: the future frames (``target``), the per-frame joint errors of a prediction in the
    view's own points under each joint protocol of the benchmark (``joint_errors``: predicted
    vertices are regressed to joints first; none where the benchmark has no joints to score),
    and for mesh rows the edge lengths MELV compares (``melv_lengths``, ``reference_lengths``)."""

    target: torch.Tensor
    reference_lengths: torch.Tensor | None

    def joint_errors(self, pred: torch.Tensor) -> dict[str, torch.Tensor]: ...

    def melv_lengths(self, frames: torch.Tensor) -> torch.Tensor: ...


@dataclass(frozen=True)
class Metric:
    """A metric, declared once: what the tables and the protocol records say of it, how far a
    recomputation may stray, and how a batch is scored.

    ``unit`` heads its tables, ``fmt`` prints its values; ``with_std``: its tables print the
    standard deviation over windows beside the mean; ``description``: its entry in the mesh
    protocol records' ``metrics`` (hashed into ``protocol_id``: change it and every stored mesh
    result stops matching new ones); ``tolerance``: the absolute floor of the tolerance of a
    recomputed value, in its unit (:mod:`zoo.evaluation.tolerance`); ``score(pred, truth)``: the
    per-frame errors ``(B, T)`` of a batch's predictions, by joint protocol (``vertices`` for
    the mesh's own); ``ground_truth_rows``: the ground-truth future is scored too, as model
    ``ground_truth`` (the data's own figure, a baseline)."""

    name: str
    unit: str
    fmt: str
    with_std: bool
    description: str
    tolerance: float
    score: Callable[[torch.Tensor, BatchTruth], dict[str, torch.Tensor]] = field(compare=False)
    ground_truth_rows: bool = False


# The floor of a tolerance in mm: 32 float32 units in the last place of a coordinate at one
# metre (docs/reproducibility.md, "The tolerance and its error model").
MM_TOLERANCE = 2.0**-9


METRICS = {
    m.name: m
    for m in (
        Metric(
            "mpjpe",
            "mm",
            ".2f",
            False,
            "mean L2 error of the regressed joints (mm)",
            tolerance=MM_TOLERANCE,
            score=lambda pred, truth: truth.joint_errors(pred),
        ),
        # The SpecTrHuMS paper prints MELV as mean and standard deviation.
        Metric(
            "melv",
            "mm",
            ".3f",
            True,
            "mean over unique edges of |len_t - len_ref| (mm), reference = last observed "
            "ground-truth frame, on the frames of `melv_frames`; model `ground_truth` rows: the "
            "same for the ground-truth future (the data baseline)",
            tolerance=MM_TOLERANCE,
            score=lambda pred, truth: {
                "vertices": length_variation(truth.melv_lengths(pred), truth.reference_lengths)
            },
            ground_truth_rows=True,
        ),
        Metric(
            "rmse",
            "per vertex, normalised by the ground-truth frame's bounding-box diagonal",
            ".4f",
            False,
            "sqrt(mean_v |v_hat - v|^2) / |max_v v - min_v v| of the ground-truth "
            "frame (the zoo's own definition; SpecTrHuMS publishes none)",
            # an error normalised by a bounding-box diagonal near 2 m: the mm floor's share
            tolerance=2.0**-18,
            score=lambda pred, truth: {"vertices": vertex_rmse(pred, truth.target)},
        ),
    )
}


def scored_errors(predictions: dict[str, torch.Tensor], metrics, truth: BatchTruth) -> dict:
    """``{(row, metric, joint protocol): errors (B, T)}`` in float64 of each prediction (``{row
    name: frames}``) under each of ``metrics`` (a view's declared ones), each scored by its
    declaration on ``truth``."""
    return {
        (name, metric.name, joints): errors.detach().to("cpu", torch.float64).numpy()
        for name, frames in predictions.items()
        for metric in metrics
        for joints, errors in metric.score(frames, truth).items()
    }
