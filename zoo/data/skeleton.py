"""Skeletons of the exponential-map datasets and the one forward-kinematics routine.

Everything here follows the row-vector convention of the LTD / convSeq2Seq code:
the root's rotation and position are never applied, so positions come out root-relative.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

# float32 machine epsilon, the reference code's guard against a zero rotation angle.
RODRIGUES_EPS = float(np.finfo(np.float32).eps)


@dataclass(frozen=True)
class Skeleton:
    """A kinematic tree with fixed bone offsets and the scoring rules of its benchmark.

    ``used`` are the joints a predictor sees and predicts; ``copy_to`` / ``copy_from`` are the
    official scoring rule: joints in ``copy_to`` are overwritten by the predicted ``copy_from``
    joints before the error is averaged over all joints.
    """

    name: str
    parents: tuple[int, ...]
    offsets: np.ndarray  # (J, 3), millimetres
    ignored: tuple[int, ...]
    copy_to: tuple[int, ...]
    copy_from: tuple[int, ...]
    parts: dict[str, tuple[int, ...]] = field(default_factory=dict)  # indices into `used`
    # Which joint protocol the literature reports first: "all" (the predicted joints written
    # into the ground-truth pose, averaged over all joints) or "used" (the predicted ones).
    official: str = "all"

    @property
    def num_joints(self) -> int:
        return len(self.parents)

    @property
    def used(self) -> tuple[int, ...]:
        ignored = set(self.ignored)
        return tuple(j for j in range(self.num_joints) if j not in ignored)

    @property
    def num_channels(self) -> int:
        """Numbers per frame in an exp-map file: root position, then 3 per joint."""
        return 3 + 3 * self.num_joints


_CMU_OFFSETS = (
    np.array(
        [
            [0, 0, 0],
            [0, 0, 0],
            [1.65674, -1.80282, 0.62477],
            [2.5972, -7.13576, 0],
            [2.49236, -6.8477, 0],
            [0.19704, -0.54136, 2.14581],
            [0, 0, 1.11249],
            [0, 0, 0],
            [-1.6107, -1.80282, 0.62476],
            [-2.59502, -7.12977, 0],
            [-2.4678, -6.78024, 0],
            [-0.23024, -0.63258, 2.13368],
            [0, 0, 1.11569],
            [0, 0, 0],
            [0.01961, 2.0545, -0.14112],
            [0.01021, 2.06436, -0.05921],
            [0, 0, 0],
            [0.00713, 1.56711, 0.14968],
            [0.03429, 1.56041, -0.10006],
            [0.01305, 1.6256, -0.05265],
            [0, 0, 0],
            [3.54205, 0.90436, -0.17364],
            [4.86513, 0, 0],
            [3.35554, 0, 0],
            [0, 0, 0],
            [0.66117, 0, 0],
            [0.53306, 0, 0],
            [0, 0, 0],
            [0.5412, 0, 0.5412],
            [0, 0, 0],
            [-3.49802, 0.75994, -0.32616],
            [-5.02649, 0, 0],
            [-3.36431, 0, 0],
            [0, 0, 0],
            [-0.73041, 0, 0],
            [-0.58887, 0, 0],
            [0, 0, 0],
            [-0.59786, 0, 0.59786],
        ],
        dtype=np.float64,
    )
    * 70.0
)

CMU = Skeleton(
    name="cmu38",
    parents=(
        -1,
        0,
        1,
        2,
        3,
        4,
        5,
        0,
        7,
        8,
        9,
        10,
        11,
        0,
        13,
        14,
        15,
        16,
        17,
        18,
        15,
        20,
        21,
        22,
        23,
        24,
        25,
        23,
        27,
        15,
        29,
        30,
        31,
        32,
        33,
        34,
        32,
        36,
    ),
    offsets=_CMU_OFFSETS,
    ignored=(0, 1, 2, 7, 8, 13, 16, 20, 24, 27, 29, 33, 36),
    copy_to=(16, 20, 29, 24, 27, 33, 36),
    copy_from=(15, 15, 15, 23, 23, 32, 32),
    # SPGSN's CMU split, as indices into the 25 used joints (legs first, then torso and arms).
    parts={"upper": tuple(range(10, 25)), "lower": tuple(range(0, 10))},
)

_H36M_OFFSETS = np.array(
    [
        [0, 0, 0],
        [-132.948591, 0, 0],
        [0, -442.894612, 0],
        [0, -454.206447, 0],
        [0, 0, 162.767078],
        [0, 0, 74.999437],
        [132.948826, 0, 0],
        [0, -442.894413, 0],
        [0, -454.20659, 0],
        [0, 0, 162.767426],
        [0, 0, 74.999948],
        [0, 0.1, 0],
        [0, 233.383263, 0],
        [0, 257.077681, 0],
        [0, 121.134938, 0],
        [0, 115.002227, 0],
        [0, 257.077681, 0],
        [0, 151.034226, 0],
        [0, 278.882773, 0],
        [0, 251.733451, 0],
        [0, 0, 0],
        [0, 0, 99.999627],
        [0, 100.000188, 0],
        [0, 0, 0],
        [0, 257.077681, 0],
        [0, 151.031437, 0],
        [0, 278.892924, 0],
        [0, 251.72868, 0],
        [0, 0, 0],
        [0, 0, 99.999888],
        [0, 137.499922, 0],
        [0, 0, 0],
    ],
    dtype=np.float64,
)

H36M = Skeleton(
    name="h36m32",
    parents=(
        -1,
        0,
        1,
        2,
        3,
        4,
        0,
        6,
        7,
        8,
        9,
        0,
        11,
        12,
        13,
        14,
        12,
        16,
        17,
        18,
        19,
        20,
        19,
        22,
        12,
        24,
        25,
        26,
        27,
        28,
        27,
        30,
    ),
    offsets=_H36M_OFFSETS,
    ignored=(0, 1, 6, 11, 16, 20, 23, 24, 28, 31),
    copy_to=(16, 20, 23, 24, 28, 31),
    copy_from=(13, 19, 22, 13, 27, 30),
    # SPGSN's H3.6M split as the authors' code makes it: used joints 0..9 (the legs, 0..7, and
    # the two lowest spine joints) are the lower body, 10..21 (upper spine, head, arms) the upper.
    parts={"upper": tuple(range(10, 22)), "lower": tuple(range(0, 10))},
)


def rodrigues(rotvec: torch.Tensor, exact: bool = False) -> torch.Tensor:
    """Rotation matrices ``(..., 3, 3)`` from exponential maps / axis-angle vectors ``(..., 3)``.

    Default: the reference code's formula, unit axis ``r / (theta + eps)``
    with eps = float32 epsilon, which the exp-map benchmarks must reproduce to the digit.
    ``exact=True``: the exact map, with Taylor series near zero (body models, e.g. SMPL-H).
    """
    x, y, z = rotvec.unbind(-1)
    zero = torch.zeros_like(x)
    skew = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1)
    skew = skew.reshape(*rotvec.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=rotvec.dtype, device=rotvec.device)
    theta2 = (rotvec * rotvec).sum(-1, keepdim=True)
    theta = theta2.sqrt()
    if exact:
        # sin(t)/t and (1 - cos t)/t^2 applied to the unnormalised skew matrix.
        small = theta < 1e-4
        safe = torch.where(small, torch.ones_like(theta), theta)
        a = torch.where(small, 1 - theta2 / 6, torch.sin(safe) / safe)
        b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(safe)) / (safe * safe))
    else:
        # The unit axis is r / (theta + eps): scale the skew of r accordingly.
        a = torch.sin(theta) / (theta + RODRIGUES_EPS)
        b = (1 - torch.cos(theta)) / (theta + RODRIGUES_EPS) ** 2
    return eye + a[..., None] * skew + b[..., None] * (skew @ skew)


def kinematic_chain(
    parents,
    local_rotations: torch.Tensor,
    offsets: torch.Tensor,
    root_position: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Standard forward kinematics (column vectors), shared by BVH files and body models.

    ``local_rotations (..., J, 3, 3)``, ``offsets (J, 3)`` from each joint's parent (the root's:
    its position), ``parents`` with the root at -1 and parents before children; returns world
    rotations ``(..., J, 3, 3)`` and positions ``(..., J, 3)``. (The exp-map benchmarks use
    :func:`forward_kinematics` instead: the reference code's own row-vector variant.)
    """
    lead = local_rotations.shape[:-3]
    world_rot, world_pos = [], []
    for j, p in enumerate(parents):
        if p < 0:
            world_rot.append(local_rotations[..., j, :, :])
            root = offsets[j] if root_position is None else offsets[j] + root_position
            world_pos.append(root.expand(*lead, 3))
        else:
            world_rot.append(world_rot[p] @ local_rotations[..., j, :, :])
            world_pos.append(world_pos[p] + (world_rot[p] @ offsets[j, :, None])[..., 0])
    return torch.stack(world_rot, -3), torch.stack(world_pos, -2)


def forward_kinematics(expmaps: torch.Tensor, skeleton: Skeleton) -> torch.Tensor:
    """Joint positions ``(N, J, 3)`` in mm from per-joint exponential maps ``(N, J, 3)``.

    Batched over frames; the loop runs over joints only, in the tree's order, because each joint
    needs its parent's accumulated rotation.
    """
    if expmaps.ndim != 3 or expmaps.shape[1:] != (skeleton.num_joints, 3):
        raise ValueError(
            f"forward_kinematics({skeleton.name}): expected exp-maps of shape (N, "
            f"{skeleton.num_joints}, 3), got {tuple(expmaps.shape)}"
        )
    offsets = torch.as_tensor(skeleton.offsets, dtype=expmaps.dtype, device=expmaps.device)
    local = rodrigues(expmaps)
    rotations = [local[:, 0]]
    positions = [offsets[0].expand(expmaps.shape[0], 3)]
    for i in range(1, skeleton.num_joints):
        p = skeleton.parents[i]
        if p > 0:
            rotations.append(local[:, i] @ rotations[p])
            positions.append(offsets[i] @ rotations[p] + positions[p])
        else:
            rotations.append(local[:, i])
            positions.append(offsets[i].expand(expmaps.shape[0], 3))
    return torch.stack(positions, dim=1)


# 3DPW (SMPL's 24 joints, ``jointPositions``): positions are given, so there is no FK and no
# offset. The root is subtracted, so it is never predicted; LTD's and SPGSN's 3DPW code scores
# the 23 other joints, hence ``official = "used"``. Body parts for SPGSN (the zoo's choice; the
# authors publish no 3DPW split): hips, knees, ankles and feet below, spine, head and arms above.
_SMPL_LOWER = (1, 2, 4, 5, 7, 8, 10, 11)
THREEDPW = Skeleton(
    name="smpl24",
    parents=(-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21),
    offsets=np.zeros((24, 3)),
    ignored=(0,),
    copy_to=(),
    copy_from=(),
    parts={
        "upper": tuple(j - 1 for j in range(1, 24) if j not in _SMPL_LOWER),
        "lower": tuple(j - 1 for j in _SMPL_LOWER),
    },
    official="used",
)
