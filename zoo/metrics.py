"""The one implementation of every metric, plus the accumulator the evaluator streams into.

Per-frame errors are computed per window as ``(B, T_out)`` tensors; :class:`FrameErrorMean`
accumulates them per action (``update`` / ``compute``, as in torchmetrics); averaging over time
(``frame`` or ``cumulative``) and over actions happens once, at the end.
"""
from __future__ import annotations

from collections import defaultdict
from typing import Sequence

import numpy as np
import torch

from zoo.data.skeleton import Skeleton

AVERAGING = {
    "frame": "error at predicted frame t alone (LTD, HisRep, SPGSN, siMLPe, SpecTrHuMS)",
    "cumulative": "mean of the per-frame errors over predicted frames 1..t (STS-GCN)",
}
ACTION_AVERAGING = "mean over windows inside an action, then unweighted mean over actions present"


def mpjpe(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean per-joint position error: ``(..., J, 3)`` -> ``(...)``, L2 norm averaged over J."""
    if pred.shape != target.shape:
        raise ValueError(f"mpjpe: prediction {tuple(pred.shape)} and target "
                         f"{tuple(target.shape)} differ in shape")
    return torch.linalg.vector_norm(pred - target, dim=-1).mean(dim=-1)


def cumulative_mean(per_frame: np.ndarray | torch.Tensor, axis: int = -1):
    """Mean of the first t values for every t (the ``cumulative`` averaging protocol)."""
    steps = np.arange(1, per_frame.shape[axis] + 1)
    if isinstance(per_frame, torch.Tensor):
        shape = [1] * per_frame.ndim
        shape[axis] = -1
        return per_frame.cumsum(axis) / torch.as_tensor(steps, dtype=per_frame.dtype).view(shape)
    shape = [1] * per_frame.ndim
    shape[axis] = -1
    return np.cumsum(per_frame, axis=axis) / steps.reshape(shape)


# ---- joint protocols of the skeleton benchmarks (SPEC section 3) ----------------------------

def joint_protocols(skeleton: Skeleton) -> dict[str, str]:
    """Named joint protocols of a skeleton and what each means."""
    return {
        f"all{skeleton.num_joints}": (
            f"official scoring: the {len(skeleton.used)} predicted joints written into the "
            f"ground-truth {skeleton.num_joints}-joint pose, joints {list(skeleton.copy_to)} "
            f"overwritten by predicted joints {list(skeleton.copy_from)}, L2 error averaged over "
            f"all {skeleton.num_joints} joints (static joints count as zero)"),
        f"used{len(skeleton.used)}": (
            f"plain mean L2 error over the {len(skeleton.used)} predicted joints"),
    }


def skeleton_errors(pred_used: torch.Tensor, target: torch.Tensor,
                    skeleton: Skeleton) -> dict[str, torch.Tensor]:
    """Per-frame MPJPE ``(B, T)`` under each joint protocol.

    ``pred_used``: ``(B, T, len(used), 3)``; ``target``: the full ground truth ``(B, T, J, 3)``.
    """
    used = list(skeleton.used)
    full = target.clone()
    full[:, :, used] = pred_used
    full[:, :, list(skeleton.copy_to)] = full[:, :, list(skeleton.copy_from)]
    all_name, used_name = joint_protocols(skeleton)
    return {all_name: mpjpe(full, target), used_name: mpjpe(pred_used, target[:, :, used])}


# ---- accumulation ------------------------------------------------------------------------------

class FrameErrorMean:
    """Running mean over windows of per-frame errors, kept per group (action).

    Sums in float64 so that thousands of windows add up without drift.
    """

    def __init__(self) -> None:
        self.sums: dict[str, np.ndarray] = {}
        self.counts: dict[str, int] = defaultdict(int)

    def update(self, errors: torch.Tensor, groups: Sequence[str]) -> None:
        errors = errors.detach().to("cpu", torch.float64).numpy()
        if errors.ndim != 2 or len(errors) != len(groups):
            raise ValueError(f"FrameErrorMean.update: expected errors (B, T) with one group per "
                             f"window, got {errors.shape} and {len(groups)} groups")
        groups = np.asarray(groups)
        for g in np.unique(groups):
            rows = errors[groups == g]
            if g in self.sums:
                self.sums[g] += rows.sum(axis=0)
            else:
                self.sums[g] = rows.sum(axis=0)
            self.counts[g] += len(rows)

    def compute(self) -> dict[str, np.ndarray]:
        """Per-group mean per-frame error ``(T,)``; the group ``average`` is their unweighted mean."""
        means = {g: self.sums[g] / self.counts[g] for g in self.sums}
        if means:
            means["average"] = np.mean(np.stack(list(means.values())), axis=0)
        return means
