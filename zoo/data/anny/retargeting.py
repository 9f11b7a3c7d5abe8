"""CMU BVH motion onto the Anny body: the BVH -> Anny mapping (change of axes, per-bone rest
corrections, the root modes), resampling to 25 Hz by slerp, and skinning. docs/datasets.md
("CMU motion on the Anny body") gives the mapping step by step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from scipy.spatial.transform import Rotation, Slerp

from zoo.data.anny.body import BVH_TO_ANNY, phenotype_tensor, rest_skeleton
from zoo.data.bvh import BVH, bone_directions, forward_kinematics
from zoo.data.expmap import DataFormatError

# Bones whose rest correction is their parent's (step 3 of the mapping in docs/datasets.md), BVH
# names.
NO_DIRECTION_BONES = frozenset(
    {
        "Hips",
        "LHipJoint",
        "RHipJoint",
        "Spine1",
        "LeftShoulder",
        "RightShoulder",
        "LThumb",
        "RThumb",
        "LeftFingerBase",
        "RightFingerBase",
        "LeftHandIndex1",
        "RightHandIndex1",
    }
)
# Change of axes BVH (Y up) -> Anny (Z up): (x, y, z) -> (x, -z, y).
AXES_M = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
ROOT_MODES = ("identity", "no_heading")
TARGET_FPS = 25.0
SKIN_BATCH = 256


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation ``(3, 3)`` taking direction ``a`` onto direction ``b``."""
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(np.dot(a, b))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        # Opposite directions: half a turn about any axis perpendicular to a.
        perp = np.cross(a, np.eye(3)[np.argmin(np.abs(a))])
        return Rotation.from_rotvec(np.pi * perp / np.linalg.norm(perp)).as_matrix()
    return Rotation.from_rotvec(axis / s * math.atan2(s, c)).as_matrix()


def remove_heading(rotations: np.ndarray, up: int = 1) -> np.ndarray:
    """``(..., 3, 3)``: the swing ``S`` of ``Q = H S``, ``H`` about axis ``up`` (BVH: Y).

    ``S`` turns about a horizontal axis: the tilt of ``Q`` with its heading removed.
    """
    shape = rotations.shape
    q = Rotation.from_matrix(rotations.reshape(-1, 3, 3)).as_quat()  # x, y, z, w
    twist = np.zeros_like(q)
    twist[:, up] = q[:, up]
    twist[:, 3] = q[:, 3]
    norm = np.linalg.norm(twist, axis=1, keepdims=True)
    degenerate = norm[:, 0] < 1e-9  # upside down: the heading is undefined; keep Q
    twist[degenerate] = [0.0, 0.0, 0.0, 1.0]
    norm[degenerate] = 1.0
    swing = Rotation.from_quat(twist / norm).inv() * Rotation.from_quat(q)
    return swing.as_matrix().reshape(shape)


def snapped_fps(frame_time: float) -> float:
    """``1 / frame_time``, snapped to the nearest integer rate when within 0.1 %."""
    fps = 1.0 / frame_time
    nearest = round(fps)
    return float(nearest) if nearest > 0 and abs(fps - nearest) <= 1e-3 * nearest else fps


def resample_times(
    num_frames: int, source_fps: float, target_fps: float = TARGET_FPS
) -> np.ndarray:
    """Output frame times (s) ``k / target_fps`` for all k within the source's span."""
    if num_frames < 1:
        return np.zeros(0)
    duration = (num_frames - 1) / source_fps
    count = int(math.floor(duration * target_fps + 1e-9)) + 1
    return np.arange(count) / target_fps


def resample_rotations(
    local_rotations: np.ndarray, source_fps: float, target_fps: float = TARGET_FPS
) -> np.ndarray:
    """``(F, J, 3, 3)`` at ``source_fps`` -> ``(F', J, 3, 3)`` at ``target_fps`` by slerp."""
    n, joints = local_rotations.shape[:2]
    times = resample_times(n, source_fps, target_fps)
    if n == 1:
        return local_rotations[:1].copy()
    source_times = np.arange(n) / source_fps
    times = np.minimum(times, source_times[-1])  # guard the last sample against round-off
    out = np.empty((len(times), joints, 3, 3))
    for j in range(joints):
        out[:, j] = Slerp(source_times, Rotation.from_matrix(local_rotations[:, j]))(
            times
        ).as_matrix()
    return out


class CMUAnnyRetarget:
    """BVH local rotations -> Anny ``cmu_mb`` pose parameters for one file and one identity.

    ``rest_heads``/``rest_tails`` ``(31, 3)`` are the identity's rest bone ends in Anny bone
    order (``rest_skeleton``); ``bvh`` supplies the skeleton and zero-pose directions.
    """

    def __init__(
        self,
        bvh: BVH,
        anny_labels: Sequence[str],
        anny_parents: Sequence[int],
        rest_heads: np.ndarray,
        rest_tails: np.ndarray,
    ) -> None:
        self.bvh = bvh
        self.anny_labels = list(anny_labels)
        lookup = {BVH_TO_ANNY.get(n, n): j for j, n in enumerate(bvh.names)}
        missing = [a for a in self.anny_labels if a not in lookup]
        if missing or len(lookup) != len(self.anny_labels):
            raise DataFormatError(
                f"{bvh.path}: the BVH joints {list(bvh.names)} do not map "
                f"onto Anny's cmu_mb bones {self.anny_labels} (missing "
                f"{missing})"
            )
        # bvh_index[c]: the BVH joint driving Anny bone c.
        self.bvh_index = np.array([lookup[a] for a in self.anny_labels])
        self.anny_parents = list(anny_parents)
        for c, p in enumerate(self.anny_parents):
            bvh_parent = bvh.parents[self.bvh_index[c]]
            if (p < 0) != (bvh_parent < 0) or (p >= 0 and self.bvh_index[p] != bvh_parent):
                raise DataFormatError(
                    f"{bvh.path}: joint {bvh.names[self.bvh_index[c]]!r} has parent "
                    f"{bvh.names[bvh_parent] if bvh_parent >= 0 else None!r} in the BVH but "
                    f"{self.anny_labels[p] if p >= 0 else None!r} in Anny's rig"
                )
        self.directed = np.array(
            [
                bvh.names[j] not in NO_DIRECTION_BONES
                and bool(bvh.has_direction[j])
                and self.anny_parents[c] >= 0
                for c, j in enumerate(self.bvh_index)
            ]
        )
        anny_dirs = rest_tails - rest_heads
        bvh_dirs = bvh.tail_offsets @ AXES_M.T  # zero-pose directions in Anny axes
        corrections = np.empty((len(self.anny_labels), 3, 3))
        for c, p in enumerate(self.anny_parents):  # parents come first in Anny's order
            if p < 0:
                corrections[c] = np.eye(3)
                continue
            corrections[c] = corrections[p]
            if self.directed[c]:
                corrections[c] = (
                    rotation_between(corrections[p] @ anny_dirs[c], bvh_dirs[self.bvh_index[c]])
                    @ corrections[p]
                )
        self.corrections = corrections

    def pose_parameters(self, local_rotations: np.ndarray, root: str = "identity") -> np.ndarray:
        """``(F, 31, 4, 4)`` float64 pose parameters (Anny bone order) of BVH rotations
        ``(F, J, 3, 3)`` (BVH joint order)."""
        if root not in ROOT_MODES:
            raise ValueError(f"root must be one of {ROOT_MODES}, got {root!r}")
        n = len(local_rotations)
        rot = local_rotations[:, self.bvh_index]  # Anny order
        rot_anny = AXES_M @ rot @ AXES_M.T
        c = self.corrections
        parent_c = c[[max(p, 0) for p in self.anny_parents]]
        deltas = np.swapaxes(parent_c, -1, -2) @ rot_anny @ c
        if root == "identity":
            deltas[:, 0] = np.eye(3)
        else:
            deltas[:, 0] = AXES_M @ remove_heading(rot[:, 0]) @ AXES_M.T
        out = np.zeros((n, len(self.anny_labels), 4, 4))
        out[..., :3, :3] = deltas
        out[..., 3, 3] = 1.0
        return out

    def expected_directions(
        self, local_rotations: np.ndarray, root: str = "identity"
    ) -> np.ndarray:
        """``(F, 31, 3)`` unit bone directions the BVH's own FK gives, in Anny axes and Anny
        bone order (root rotation as ``pose_parameters`` treats it); NaN for undirected bones."""
        rotations = local_rotations.copy()
        if root == "identity":
            rotations[:, 0] = np.eye(3)
        else:
            rotations[:, 0] = remove_heading(rotations[:, 0])
        world, _ = forward_kinematics(self.bvh, rotations)
        dirs = bone_directions(self.bvh, world) @ AXES_M.T
        out = dirs[:, self.bvh_index]
        out[:, ~self.directed] = np.nan
        return out


def retarget(model, bvh: BVH, phenotype: dict[str, float] | None = None) -> CMUAnnyRetarget:
    rest = rest_skeleton(model, phenotype)
    return CMUAnnyRetarget(bvh, model.bone_labels, model.bone_parents, rest["heads"], rest["tails"])


def motion_rotations(bvh: BVH, target_fps: float = TARGET_FPS) -> np.ndarray:
    """The file's local rotations without the T-pose frame 0, resampled to ``target_fps``."""
    if bvh.num_frames < 2:
        raise DataFormatError(
            f"{bvh.path}: {bvh.num_frames} frame(s); need the T-pose frame "
            f"and at least one motion frame"
        )
    return resample_rotations(
        bvh.local_rotations(slice(1, None)), snapped_fps(bvh.frame_time), target_fps
    )


def skin(
    model,
    pose_parameters: np.ndarray | torch.Tensor,
    phenotype: dict[str, float] | None = None,
    *,
    batch_size: int = SKIN_BATCH,
    return_bone_ends: bool = False,
) -> dict[str, np.ndarray]:
    """Skinned vertices ``(F, V, 3)`` in millimetres (float32), batch by batch: computed in the
    model's precision (float64 from ``load_anny_model``) and rounded to float32 once, at the end.

    With ``return_bone_ends``, also the posed bone ``heads`` and ``tails`` ``(F, 31, 3)`` (mm).
    """
    poses = torch.as_tensor(pose_parameters).to(model.dtype)
    pheno = phenotype_tensor(model, phenotype)
    chunks: dict[str, list[np.ndarray]] = {"vertices": [], "heads": [], "tails": []}
    with torch.no_grad():
        for start in range(0, len(poses), batch_size):
            out = model(
                pose_parameters=poses[start : start + batch_size],
                phenotype_kwargs=pheno,
                return_bone_ends=return_bone_ends,
            )
            chunks["vertices"].append((out["vertices"] * 1000.0).float().numpy())
            if return_bone_ends:
                chunks["heads"].append((out["bone_heads"] * 1000.0).double().numpy())
                chunks["tails"].append((out["bone_tails"] * 1000.0).double().numpy())
    result = {
        "vertices": np.concatenate(chunks["vertices"])
        if chunks["vertices"]
        else np.zeros((0, model.template_vertices.shape[0], 3), np.float32)
    }
    if return_bone_ends:
        result["heads"] = np.concatenate(chunks["heads"])
        result["tails"] = np.concatenate(chunks["tails"])
    return result


def angle_degrees(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angles (degrees) between the vectors of ``u`` and ``v`` (``(..., 3)``), robust near 0."""
    cross = np.linalg.norm(np.cross(u, v), axis=-1)
    dot = np.sum(u * v, axis=-1)
    return np.degrees(np.arctan2(cross, dot))
