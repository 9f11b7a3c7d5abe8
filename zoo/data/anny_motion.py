"""CMU BVH motion on the Anny body: retargeting, resampling, the joint regressor and the mesh
datasets (``cmu_anny_*``). docs/datasets.md ("CMU motion on the Anny body") gives the mapping
step by step, the resampling and why the joint regressor ships as data.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import math
import os
import sys
import zipfile
from collections.abc import Iterable, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import scipy.sparse as sp
import torch
from scipy.optimize import nnls
from scipy.spatial.transform import Rotation, Slerp

from zoo.data.bvh import BVH, CMU_BVH_JOINTS, bone_directions, forward_kinematics, read_bvh
from zoo.data.expmap import DataFormatError
from zoo.data.mesh import (
    QUAD_TIE,
    MeshDataset,
    MeshSequence,
    MeshTopology,
    cache_root,
    triangulate_quads,
)
from zoo.data.motion import found_entries
from zoo.errors import DataNotFoundError
from zoo.io import atomic_path, progress_bar, sha256_file
from zoo.paths import REPO_ROOT

# BVH name -> Anny ``cmu_mb`` bone name where they differ (all others are the same).
BVH_TO_ANNY = {"LeftHandIndex1": "LeftHandFinger1", "RightHandIndex1": "RightHandFinger1"}
# Bones whose rest correction is their parent's (step 3 of the mapping above), BVH names.
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

TOPOLOGIES = {"full": "anny", "low": "notoes_collapse10pc"}
# The full body is loaded as anny's quads and triangulated by the zoo (mesh.triangulate_quads):
# anny's own split picks the shorter diagonal in float32, and on the body's 56 symmetric quads
# (equal diagonals) that choice differs between CPUs, and with it the faces, the Graph Laplacian
# and every protocol id. The low body is anny's triangles (no quads).
QUAD_TOPOLOGIES = {"full": "anny-quads"}
TRIANGULATION = {
    "full": "anny-quads split along the shorter diagonal (float64 on the template), ties "
    f"within {QUAD_TIE:g} relative along a-c"
}
ROOT_MODES = ("identity", "no_heading")
IDENTITY_MODES = ("one", "many")
SPLITS = ("train", "test")
PHENOTYPE_LABELS = ("gender", "age", "muscle", "weight", "height", "proportions")
# OI: Anny's default body, every parameter 0.5 (an androgynous body about 1.6 m tall; age 0.5
# is about 13 years on anny's morphological-age calibration).
DEFAULT_PHENOTYPE = {k: 0.5 for k in PHENOTYPE_LABELS}
# MI: each parameter uniform on this range, drawn per sequence. Age 0.67..0.85 are adults (16 to
# about 69 years on anny's morphological-age calibration); the others stay clear of the extreme
# blend shapes.
MI_PHENOTYPE_RANGES = {
    "gender": (0.0, 1.0),
    "age": (0.67, 0.85),
    "muscle": (0.1, 0.9),
    "weight": (0.1, 0.9),
    "height": (0.1, 0.9),
    "proportions": (0.1, 0.9),
}
TARGET_FPS = 25.0
TEST_EVERY = 5  # split rule: trial numbers divisible by 5 are test, the others train
DATASET_FORMAT = 1
SKIN_BATCH = 256


class AnnyUnavailable(ImportError):
    """The ``anny`` package is not installed (``pip install anny==0.6.2``)."""


@contextmanager
def one_thread():
    """Torch on one thread while a dataset or regressor is computed: its float sums follow the
    thread count (two threads and one built CMU-on-Anny meshes differing by up to 1e-4 mm, so
    different content hashes), and one thread gives the same bytes on every machine."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def anny_version() -> str:
    try:
        return importlib.metadata.version("anny")
    except importlib.metadata.PackageNotFoundError as e:
        raise AnnyUnavailable(
            "the anny package is not installed; pip install anny==0.6.2 "
            "(Apache-2.0 code, CC0 assets)"
        ) from e


# ---- the Anny model --------------------------------------------------------------------------


@contextmanager
def _quiet_warp():
    """anny initialises NVIDIA Warp when it builds a model, which prints a CUDA-driver warning
    and a banner from native code; on a machine without a CUDA device that says nothing useful,
    so stderr is silenced meanwhile there (a failure still raises)."""
    import torch

    if torch.cuda.is_available():
        yield
        return
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), 2)
            try:
                import warp

                warp.config.log_level = warp.LOG_WARNING
            except (ImportError, AttributeError):  # an anny that does not use warp
                pass
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def load_anny_model(
    topology: Literal["full", "low"] = "low",
    *,
    dtype: torch.dtype = torch.float32,
    anny_cache_dir: str | Path | None = None,
):
    """``anny.Anny(rig="cmu_mb")`` at the ``full`` (13,718 vertices) or ``low`` (1,229) topology.

    The first build of a topology takes minutes; anny caches it (``ANNY_CACHE_DIR``, or
    ``anny_cache_dir``), after which loading takes about a second.
    """
    if topology not in TOPOLOGIES:
        raise ValueError(f"topology must be one of {sorted(TOPOLOGIES)}, got {topology!r}")
    anny_version()
    with _quiet_warp():
        import anny
        import anny.paths

        if anny_cache_dir is not None:
            anny.paths.set_anny_cache_path(Path(anny_cache_dir))
        model = anny.Anny(
            rig="cmu_mb", topology=QUAD_TOPOLOGIES.get(topology, TOPOLOGIES[topology])
        )
    model = model.to(dtype)
    missing = [
        BVH_TO_ANNY.get(n, n)
        for n in CMU_BVH_JOINTS
        if BVH_TO_ANNY.get(n, n) not in model.bone_labels
    ]
    if missing or len(model.bone_labels) != len(CMU_BVH_JOINTS):
        raise RuntimeError(
            f"anny's cmu_mb rig does not have the 31 CMU bones (missing "
            f"{missing}; has {model.bone_labels})"
        )
    return model


def model_faces(model) -> np.ndarray:
    """The triangles of a model from ``load_anny_model`` (its quads split, if it has quads)."""
    faces = np.asarray(model.faces.detach().cpu().numpy(), dtype=np.int64)
    if faces.ndim == 2 and faces.shape[1] == 4:
        return triangulate_quads(model.template_vertices.detach().cpu().numpy(), faces)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise RuntimeError(f"anny model faces are not triangles: {faces.shape}")
    return faces


def phenotype_tensor(model, phenotype: dict[str, float] | None) -> dict[str, torch.Tensor]:
    phenotype = dict(DEFAULT_PHENOTYPE if phenotype is None else phenotype)
    unknown = set(phenotype) - set(PHENOTYPE_LABELS)
    if unknown:
        raise ValueError(
            f"unknown phenotype parameter(s) {sorted(unknown)}; expected {list(PHENOTYPE_LABELS)}"
        )
    return {
        k: torch.tensor([float(phenotype.get(k, 0.5))], dtype=model.dtype) for k in PHENOTYPE_LABELS
    }


def rest_skeleton(model, phenotype: dict[str, float] | None = None) -> dict[str, np.ndarray]:
    """Rest bone heads and tails ``(31, 3)`` (float64, metres, Anny bone order)."""
    with torch.no_grad():
        out = model(phenotype_kwargs=phenotype_tensor(model, phenotype), return_bone_ends=True)
    return {
        "heads": out["rest_bone_heads"][0].double().numpy(),
        "tails": out["rest_bone_tails"][0].double().numpy(),
        "vertices": out["rest_vertices"][0].double().numpy(),
    }


# ---- rotations -------------------------------------------------------------------------------


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


# ---- the retargeting -------------------------------------------------------------------------


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
    """Skinned vertices ``(F, V, 3)`` in millimetres (float32), batch by batch.

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


# ---- the joint regressor ---------------------------------------------------------------------

# Training trials (trial numbers not divisible by 5) whose frames fit the regressor: walking,
# running, jumping, climbing and sitting, bending over, dance, dribbling.
REGRESSOR_TRIALS = ("02_01", "02_03", "02_04", "01_08", "02_06", "05_03", "06_04", "09_01")
REGRESSOR_SETTINGS = {
    "full": {"support": 100, "frames_per_trial": 20, "identities": 8},
    "low": {"support": 40, "frames_per_trial": 20, "identities": 8},
}
REGRESSOR_STATS = ("fit_mean_mm", "fit_p99_mm", "fit_frames")
# Every topology's fitted regressor ships here, one file per recipe (module docstring).
SHIPPED_REGRESSORS = REPO_ROOT / "benchmarks" / "regressors"
# Largest distance (mm) between a joint regressed by a fresh fit and by the shipped regressor,
# on the fit's own frames, that counts as the same regressor (docs/reproducibility.md says why).
REGRESSOR_TOLERANCE_MM = 0.05


@dataclass
class JointRegressor:
    """A sparse ``(31, V)`` regressor (rows in BVH joint order, non-negative, summing to 1)."""

    matrix: sp.csr_matrix
    joint_names: list[str]
    recipe: dict[str, Any]
    source: str = ""  # the file it was read from


def mi_phenotype(seed: int, key: str) -> dict[str, float]:
    """The MI identity of sequence ``key`` (e.g. ``"02_01"``) under ``seed``: each parameter
    uniform on ``MI_PHENOTYPE_RANGES``, from a generator seeded by ``sha256(seed, key)`` so an
    identity does not depend on which other trials are built."""
    digest = hashlib.sha256(f"cmu_anny-mi:{seed}:{key}".encode()).digest()
    rng = np.random.default_rng(int.from_bytes(digest[:8], "little"))
    return {k: float(rng.uniform(*MI_PHENOTYPE_RANGES[k])) for k in PHENOTYPE_LABELS}


def regressor_fit_frames(
    model,
    bvh_files: Sequence[str | Path],
    *,
    frames_per_trial: int,
    identities: int,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """The frames a joint regressor is fitted on: ``frames_per_trial`` evenly spaced 25 Hz
    frames of each BVH file, skinned for the default identity and ``identities - 1`` MI
    identities. Returns vertices ``(F, V, 3)`` float32 and Anny's posed bone heads ``(F, B, 3)``
    in Anny's bone order."""
    vertices, heads = [], []
    phenotypes = [None] + [mi_phenotype(seed, f"regressor-{i}") for i in range(1, identities)]
    for path in bvh_files:
        bvh = read_bvh(path, CMU_BVH_JOINTS)
        rots = motion_rotations(bvh)
        rots = rots[np.unique(np.linspace(0, len(rots) - 1, frames_per_trial).round().astype(int))]
        for pheno in phenotypes:
            target = retarget(model, bvh, pheno)
            out = skin(model, target.pose_parameters(rots), pheno, return_bone_ends=True)
            vertices.append(out["vertices"])
            heads.append(out["heads"])
    return np.concatenate(vertices), np.concatenate(heads)


def regressed_joints(regressor: sp.spmatrix, vertices: np.ndarray) -> np.ndarray:
    """``(F, J, 3)`` float64 joints of vertices ``(F, V, 3)`` through a ``(J, V)`` regressor."""
    return np.einsum("jv,fvc->fjc", regressor.toarray(), vertices.astype(np.float64))


def fit_joint_regressor(
    model,
    bvh_files: Sequence[str | Path],
    *,
    support: int,
    frames_per_trial: int,
    identities: int,
    seed: int = 0,
    frames: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[sp.csr_matrix, dict[str, float]]:
    """Fit each bone head as a convex combination of its ``support`` nearest rest vertices.

    Fit data: ``regressor_fit_frames`` (or ``frames``, what it returned); targets are Anny's own
    posed bone heads. Non-negative least squares with the sum-to-one constraint as a heavily
    weighted row. Returns the ``(31, V)`` matrix in BVH joint order and the fit's residual
    statistics (mm).
    """
    if frames is None:
        frames = regressor_fit_frames(
            model, bvh_files, frames_per_trial=frames_per_trial, identities=identities, seed=seed
        )
    vertices, heads = frames
    rest = rest_skeleton(model)
    num_v = vertices.shape[1]
    order = [model.bone_labels.index(BVH_TO_ANNY.get(n, n)) for n in CMU_BVH_JOINTS]
    rows, cols, vals = [], [], []
    for row, c in enumerate(order):
        dist = np.linalg.norm(rest["vertices"] - rest["heads"][c], axis=1)
        idx = np.argsort(dist)[:support]
        a = vertices[:, idx, :].astype(np.float64).transpose(0, 2, 1).reshape(-1, len(idx))
        y = heads[:, c, :].reshape(-1)
        lam = 1e3 * math.sqrt(len(y))
        w, _ = nnls(
            np.vstack([a, np.full((1, len(idx)), lam)]), np.append(y, lam), maxiter=50 * len(idx)
        )
        if w.sum() <= 0:
            raise RuntimeError(f"joint regressor fit failed for bone {CMU_BVH_JOINTS[row]}")
        w /= w.sum()
        keep = w > 1e-8
        rows += [row] * int(keep.sum())
        cols += idx[keep].tolist()
        vals += (w[keep] / w[keep].sum()).tolist()
    matrix = sp.csr_matrix((vals, (rows, cols)), shape=(len(CMU_BVH_JOINTS), num_v))
    err = np.linalg.norm(regressed_joints(matrix, vertices) - heads[:, order], axis=-1)
    stats = {
        "fit_mean_mm": round(float(err.mean()), 3),
        "fit_p99_mm": round(float(np.percentile(err, 99)), 3),
        "fit_frames": float(len(vertices)),
    }
    return matrix, stats


def regressor_error(
    regressor: sp.spmatrix, vertices: np.ndarray, heads_bvh_order: np.ndarray
) -> np.ndarray:
    """Per frame and joint distance (mm) between regressed joints and the rig's bone heads."""
    return np.linalg.norm(regressed_joints(regressor, vertices) - heads_bvh_order, axis=-1)


# ---- trials, split and cache -----------------------------------------------------------------


@dataclass(frozen=True)
class Trial:
    """One CMU BVH trial: ``key`` like ``"02_01"`` (subject 02, trial 1)."""

    key: str
    path: Path
    relpath: str
    subject: str
    number: int
    description: str

    @property
    def split(self) -> str:
        return "test" if self.number % TEST_EVERY == 0 else "train"


SPLIT_RULE = (
    f"by trial: trial numbers divisible by {TEST_EVERY} (NN_05, NN_10, ...) are test, "
    f"all others train; subjects with fewer than {TEST_EVERY} trials are train only"
)


def _trial_from_path(path: Path, relpath: str, description: str, where: str) -> Trial:
    stem = path.stem
    parts = stem.split("_")
    if len(parts) != 2 or not all(p.isdigit() for p in parts):
        raise DataFormatError(
            f"{where}: BVH file name {path.name!r} is not SUBJECT_TRIAL.bvh (e.g. 02_01.bvh)"
        )
    return Trial(
        key=stem,
        path=path,
        relpath=relpath,
        subject=parts[0],
        number=int(parts[1]),
        description=description or f"subject {parts[0]}",
    )


def list_trials(bvh_root: str | Path) -> list[Trial]:
    """Trials under ``bvh_root`` from its ``MANIFEST.tsv`` (path, description columns) or, if
    there is none, every ``data/*/*.bvh``; descriptions fall back to the subject."""
    root = Path(bvh_root)
    if not root.is_dir():
        raise DataNotFoundError(
            f"{root}: CMU BVH folder not found (expected a folder like ../shared/data/cmu_bvh "
            f"with MANIFEST.tsv and data/NNN/NN_TT.bvh); {found_entries(root.parent, root.name)}"
        )
    manifest = root / "MANIFEST.tsv"
    trials: list[Trial] = []
    if manifest.is_file():
        lines = manifest.read_text().splitlines()
        if not lines:
            raise DataFormatError(f"{manifest}: empty manifest")
        header = lines[0].split("\t")
        for column in ("path", "description"):
            if column not in header:
                raise DataFormatError(
                    f"{manifest}, line 1: no {column!r} column in the header {header}"
                )
        ipath, idesc = header.index("path"), header.index("description")
        for lineno, line in enumerate(lines[1:], start=2):
            if not line.strip():
                continue
            fields = line.split("\t")
            if len(fields) != len(header):
                raise DataFormatError(
                    f"{manifest}, line {lineno}: {len(fields)} fields, the header has {len(header)}"
                )
            rel = fields[ipath]
            path = root / rel
            if not path.is_file():
                raise DataFormatError(f"{manifest}, line {lineno}: listed file {rel} is missing")
            trials.append(
                _trial_from_path(path, rel, fields[idesc].strip(), f"{manifest}, line {lineno}")
            )
    else:
        for path in sorted(root.glob("data/*/*.bvh")):
            trials.append(_trial_from_path(path, str(path.relative_to(root)), "", str(path)))
    if not trials:
        raise DataNotFoundError(
            f"{root}: no BVH trials (expected MANIFEST.tsv or data/NNN/NN_TT.bvh); "
            f"{found_entries(root, 'data')}"
        )
    keys = [t.key for t in trials]
    if len(set(keys)) != len(keys):
        dup = next(k for k in keys if keys.count(k) > 1)
        raise DataFormatError(f"{root}: trial {dup} is listed twice")
    return sorted(trials, key=lambda t: (t.subject, t.number))


def select_trials(
    bvh_root: str | Path, split: str, trials: Iterable[str] | None = None
) -> list[Trial]:
    """The trials of ``split``; ``trials`` (keys like ``"02_01"``) restricts them further."""
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    available = list_trials(bvh_root)
    if trials is None:
        return [t for t in available if t.split == split]
    by_key = {t.key: t for t in available}
    chosen = []
    for key in trials:
        key = Path(str(key)).stem
        if key not in by_key:
            raise ValueError(
                f"trials: {key!r} is not a trial under {bvh_root} (available: "
                f"{', '.join(sorted(by_key))})"
            )
        trial = by_key[key]
        if trial.split != split:
            raise ValueError(
                f"trials: {key!r} belongs to the {trial.split} split, not {split} "
                f"(split rule: {SPLIT_RULE})"
            )
        if trial not in chosen:
            chosen.append(trial)
    if not chosen:
        raise ValueError("trials: empty selection")
    return chosen


def dataset_name(identities: str, topology: str, split: str, root: str = "identity") -> str:
    tag = {"one": "oi", "many": "mi"}[identities]
    suffix = "" if root == "identity" else "-noheading"
    return f"cmu_anny-{tag}-{topology}{suffix}-{split}"


def dataset_folder(dataset: MeshDataset, cache_dir: str | Path | None = None) -> Path:
    """Where ``build_cmu_anny`` keeps ``dataset``: ``<cache>/datasets/<name>-<recipe_hash>``."""
    return cache_root(cache_dir) / "datasets" / f"{dataset.name}-{dataset.recipe_hash}"


def _recipe_hash(recipe: dict[str, Any]) -> str:
    # The same hash MeshDataset.recipe_hash computes.
    from zoo.io import canonical_json

    return hashlib.sha256(canonical_json(recipe).encode()).hexdigest()[:16]


_MODELS: dict[str, Any] = {}


def _model(topology: str):
    if topology not in _MODELS:
        _MODELS[topology] = load_anny_model(topology)
    return _MODELS[topology]


def regressor_recipe(bvh_root: str | Path, topology: str) -> tuple[dict[str, Any], list[Path]]:
    """What a topology's joint regressor is fitted from (hashed; the stats are added once
    fitted) and the BVH files of ``REGRESSOR_TRIALS`` under ``bvh_root``."""
    by_key = {t.key: t for t in list_trials(bvh_root)}
    missing = [k for k in REGRESSOR_TRIALS if k not in by_key]
    if missing:
        raise ValueError(
            f"{bvh_root}: the joint regressor is fitted on trials "
            f"{list(REGRESSOR_TRIALS)}; missing {missing}"
        )
    files = [by_key[k] for k in REGRESSOR_TRIALS]
    recipe = {
        "method": "nnls-posed-v1",
        "threads": 1,
        "anny_version": anny_version(),
        "rig": "cmu_mb",
        "topology": TOPOLOGIES[topology],
        "seed": 0,
        **REGRESSOR_SETTINGS[topology],
        "trials": [{"trial": t.key, "sha256": sha256_file(t.path)} for t in files],
    }
    return recipe, [t.path for t in files]


def shipped_regressor_path(topology: str, recipe: dict[str, Any]) -> Path:
    """Where the regressor fitted from ``recipe`` ships (``SHIPPED_REGRESSORS``)."""
    return SHIPPED_REGRESSORS / f"joint_regressor-{topology}-{_recipe_hash(recipe)}.npz"


def regressor_checksum(matrix: sp.csr_matrix) -> str:
    """sha256 of a regressor's shape, sparsity pattern and float64 weights."""
    m = sp.csr_matrix(matrix, copy=True)
    m.sort_indices()
    digest = hashlib.sha256(np.asarray(m.shape, dtype="<i8").tobytes())
    digest.update(m.indptr.astype("<i8").tobytes())
    digest.update(m.indices.astype("<i8").tobytes())
    digest.update(m.data.astype("<f8").tobytes())
    return digest.hexdigest()


def save_regressor(path: str | Path, matrix: sp.csr_matrix, stats: dict[str, float]) -> Path:
    """Write a regressor (CSR arrays, fit statistics, checksum) atomically."""
    m = sp.csr_matrix(matrix, copy=True)
    m.sort_indices()
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(
                f,
                data=m.data,
                indices=m.indices,
                indptr=m.indptr,
                shape=np.asarray(m.shape),
                checksum=np.asarray(regressor_checksum(m)),
                **stats,
            )
    return Path(path)


def load_regressor(
    path: str | Path, remedy: str = "restore it from the repository", checksum_required=True
) -> tuple[sp.csr_matrix, dict[str, float]]:
    """Read what ``save_regressor`` wrote; a file that is not one, lacks a field, or whose
    weights do not match its checksum is an error naming it and ``remedy``. Cache files written
    before regressors carried a checksum load with ``checksum_required=False``."""
    try:
        with np.load(path) as z:
            matrix = sp.csr_matrix((z["data"], z["indices"], z["indptr"]), shape=tuple(z["shape"]))
            stats = {k: float(z[k]) for k in REGRESSOR_STATS}
            checksum = str(z["checksum"]) if "checksum" in z.files else None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as e:
        raise DataFormatError(
            f"{path}: not a joint regressor file (CSR arrays data, indices, indptr, shape, "
            f"checksum and {', '.join(REGRESSOR_STATS)} expected; {remedy}): {e}"
        ) from e
    if checksum is None and checksum_required:
        raise DataFormatError(f"{path}: no checksum field ({remedy})")
    if checksum is not None and checksum != regressor_checksum(matrix):
        raise DataFormatError(
            f"{path}: its weights do not match its checksum {checksum[:12]}... (a damaged or "
            f"edited file: {remedy})"
        )
    return matrix, stats


def joint_regressor(
    bvh_root: str | Path, topology: str, *, cache_dir: str | Path | None = None, model=None
) -> JointRegressor:
    """The topology's joint regressor: the shipped one (``SHIPPED_REGRESSORS``) for this recipe,
    else fitted here once (``fit_joint_regressor`` on ``REGRESSOR_TRIALS``) and cached in
    ``<cache>/anny/``, with a warning whenever it is used: a fit follows the CPU's rounding
    (module docstring)."""
    recipe, files = regressor_recipe(bvh_root, topology)
    shipped = shipped_regressor_path(topology, recipe)
    path = cache_root(cache_dir) / "anny" / shipped.name
    if shipped.is_file():
        matrix, stats = load_regressor(shipped)
        return JointRegressor(
            matrix, list(CMU_BVH_JOINTS), recipe={**recipe, **stats}, source=str(shipped)
        )
    print(
        f"no shipped joint regressor for the {topology} Anny body with this recipe "
        f"({shipped.name}): "
        + ("using the one fitted here" if path.is_file() else "fitting one here")
        + "; its weights follow this CPU's rounding, so MPJPE through it may differ from "
        "another machine's (zoo data regressor NAME --ship ships it)",
        file=sys.stderr,
    )
    if path.is_file():
        matrix, stats = load_regressor(
            path, remedy="delete it and it is fitted again", checksum_required=False
        )
    else:
        model = _model(topology) if model is None else model
        with one_thread():
            matrix, stats = fit_joint_regressor(
                model, files, seed=0, **REGRESSOR_SETTINGS[topology]
            )
        save_regressor(path, matrix, stats)
    return JointRegressor(
        matrix, list(CMU_BVH_JOINTS), recipe={**recipe, **stats}, source=str(path)
    )


def check_joint_regressor(bvh_root: str | Path, topology: str, *, model=None) -> dict[str, Any]:
    """Fit the topology's regressor here and compare it with the shipped one: the largest
    difference of a weight, of the fit statistics, and of a regressed joint (mm) on the fit's
    own frames. ``same`` when every joint is within ``REGRESSOR_TOLERANCE_MM`` (on the machine
    that shipped it, always; elsewhere the ill-conditioned full-body fit may land on other
    weights). ``fits_here``, what holds on every CPU: the shipped regressor misses the bone
    heads of the fit frames skinned here by what its record says (mean and 99th percentile,
    within ``REGRESSOR_TOLERANCE_MM``)."""
    recipe, files = regressor_recipe(bvh_root, topology)
    shipped_path = shipped_regressor_path(topology, recipe)
    if not shipped_path.is_file():
        raise DataNotFoundError(
            f"no shipped joint regressor for the {topology} Anny body with this recipe "
            f"({shipped_path}); zoo data regressor ... --ship writes one"
        )
    shipped, shipped_stats = load_regressor(shipped_path)
    model = _model(topology) if model is None else model
    settings = REGRESSOR_SETTINGS[topology]
    with one_thread():
        frames = regressor_fit_frames(
            model,
            files,
            frames_per_trial=settings["frames_per_trial"],
            identities=settings["identities"],
        )
        fitted, stats = fit_joint_regressor(model, files, seed=0, frames=frames, **settings)
    gap = np.linalg.norm(
        regressed_joints(fitted, frames[0]) - regressed_joints(shipped, frames[0]), axis=-1
    )
    joints_mm = float(gap.max())
    order = [model.bone_labels.index(BVH_TO_ANNY.get(n, n)) for n in CMU_BVH_JOINTS]
    misses = regressor_error(shipped, frames[0], frames[1][:, order])
    here = {"fit_mean_mm": float(misses.mean()), "fit_p99_mm": float(np.percentile(misses, 99))}
    return {
        "path": shipped_path,
        "weights": float(abs(fitted - shipped).max()),
        # bounds a regressed joint's change per mm of vertex displacement, on any frames
        "rows_l1": float(abs(fitted - shipped).sum(axis=1).max()),
        "support": (int(fitted.nnz), int(shipped.nnz)),
        "stats": {k: (stats[k], shipped_stats[k]) for k in REGRESSOR_STATS},
        "joints_mm": joints_mm,
        "joints_mean_mm": float(gap.mean()),
        "same": joints_mm <= REGRESSOR_TOLERANCE_MM,
        "shipped_here": here,
        # the record's statistics are rounded to 0.001 mm
        "fits_here": all(
            abs(here[k] - shipped_stats[k]) <= REGRESSOR_TOLERANCE_MM + 5e-4 for k in here
        ),
    }


# ---- the dataset builder ---------------------------------------------------------------------


def build_cmu_anny(
    bvh_root: str | Path,
    *,
    identities: Literal["one", "many"],
    topology: Literal["full", "low"],
    split: Literal["train", "test"],
    seed: int = 0,
    cache_dir: str | Path | None = None,
    trials: Iterable[str] | None = None,
    progress: bool = True,
    root: Literal["identity", "no_heading"] = "identity",
) -> MeshDataset:
    """CMU BVH trials on the Anny body as a ``MeshDataset`` (vertices in mm, 25 Hz).

    - ``identities``: ``"one"`` (OI: Anny's default phenotype, every parameter 0.5) or
      ``"many"`` (MI: gender, age, muscle, weight, height, proportions drawn per sequence from
      ``MI_PHENOTYPE_RANGES`` by ``mi_phenotype(seed, trial)``);
    - ``topology``: ``"full"`` (13,718 vertices) or ``"low"`` (``notoes_collapse10pc``, 1,229);
    - ``split``: ``SPLIT_RULE``; ``trials`` (keys like ``"09_03"``) builds only those;
    - ``root``: ``"identity"`` (no global rotation: the motion-prediction protocol) or
      ``"no_heading"`` (heading removed, body tilt kept); root translation is always zero.

    Each sequence's ``action`` is the trial's MANIFEST description (or its subject); ``meta``
    records trial, file, sha256, source frames and fps and the phenotype. The dataset carries
    the topology's ``joint_regressor`` (BVH joint order). The result is cached in
    ``<cache>/datasets/<name>-<recipe_hash>`` (``cache_dir``, ``$ZOO_CACHE_DIR`` or
    ``<repo>/cache``), with the rig's exact per-frame bone heads beside it
    (``load_rig_joints``); a second call with the same recipe loads it.
    """
    if identities not in IDENTITY_MODES:
        raise ValueError(f"identities must be one of {IDENTITY_MODES}, got {identities!r}")
    if topology not in TOPOLOGIES:
        raise ValueError(f"topology must be one of {sorted(TOPOLOGIES)}, got {topology!r}")
    if root not in ROOT_MODES:
        raise ValueError(f"root must be one of {ROOT_MODES}, got {root!r}")
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool):
        raise ValueError(f"seed must be an integer, got {seed!r}")
    chosen = select_trials(bvh_root, split, trials)
    regressor = joint_regressor(bvh_root, topology, cache_dir=cache_dir)
    recipe = {
        "builder": "zoo.data.anny_motion.build_cmu_anny",
        "format": DATASET_FORMAT,
        "source": "cmu_bvh",
        "identities": identities,
        "topology": topology,
        "anny_topology": TOPOLOGIES[topology],
        # Only where the zoo triangulates: the low recipe (and its cache key) stays as it was.
        **({"triangulation": TRIANGULATION[topology]} if topology in TRIANGULATION else {}),
        "rig": "cmu_mb",
        "split": split,
        "split_rule": SPLIT_RULE,
        "root": root,
        # The seed only draws MI bodies: OI datasets of any seed are one dataset.
        "seed": int(seed) if identities == "many" else None,
        "anny_version": anny_version(),
        "fps": TARGET_FPS,
        "resampling": "drop frame 0 (T-pose); slerp of local rotations to 25 Hz",
        "mapping": "SPEC section 7: Z-Y-X local rotations, M (x,y,z)->(x,-z,y), rest "
        "correction C per bone, pose [[C_parent^T R' C, 0], [0, 1]]",
        "units": "mm",
        "dtype": "float32",
        "threads": 1,
        "phenotypes": (
            DEFAULT_PHENOTYPE
            if identities == "one"
            else {"ranges": MI_PHENOTYPE_RANGES, "draw": "mi_phenotype(seed, trial)"}
        ),
        "trials": [{"trial": t.key, "sha256": sha256_file(t.path)} for t in chosen],
        "joint_regressor": regressor.recipe,
    }
    name = dataset_name(identities, topology, split, root)
    folder = cache_root(cache_dir) / "datasets" / f"{name}-{_recipe_hash(recipe)}"
    if (folder / "dataset.json").is_file() and (folder / "meshes.npz").is_file():
        cached = MeshDataset.load(folder)
        if cached.recipe_hash == _recipe_hash(recipe):
            # A dataset cached before its regressor shipped carries this machine's fit.
            if (
                cached.joint_regressor is None
                or (abs(cached.joint_regressor - regressor.matrix) > 0).nnz
            ):
                cached.joint_regressor = regressor.matrix
            return cached
    model = _model(topology)
    topo = MeshTopology(
        model_faces(model), model.template_vertices.shape[0], name=f"anny-{TOPOLOGIES[topology]}"
    )
    to_bvh = [model.bone_labels.index(BVH_TO_ANNY.get(n, n)) for n in CMU_BVH_JOINTS]
    sequences, rig_joints = [], []

    bar = progress_bar(chosen, desc=name, unit="trial", disable=not progress)
    frames_done = 0
    for trial, entry in zip(bar, recipe["trials"]):
        bvh = read_bvh(trial.path, CMU_BVH_JOINTS)
        rots = motion_rotations(bvh)
        pheno = DEFAULT_PHENOTYPE if identities == "one" else mi_phenotype(seed, trial.key)
        with one_thread():
            target = retarget(model, bvh, pheno)
            out = skin(model, target.pose_parameters(rots, root), pheno, return_bone_ends=True)
        frames_done += len(rots)
        bar.set_postfix(frames=frames_done)
        sequences.append(
            MeshSequence(
                name=trial.key,
                action=trial.description,
                vertices=out["vertices"],
                fps=TARGET_FPS,
                identity="default" if identities == "one" else f"mi{seed}-{trial.key}",
                meta={
                    "trial": trial.key,
                    "bvh": trial.relpath,
                    "sha256": entry["sha256"],
                    "subject": trial.subject,
                    "source_frames": bvh.num_frames - 1,
                    "source_fps": snapped_fps(bvh.frame_time),
                    "phenotype": dict(pheno),
                    "root": root,
                },
            )
        )
        rig_joints.append(out["heads"][:, to_bvh].astype(np.float32))
    dataset = MeshDataset(
        name=name,
        split=split,
        topology=topo,
        sequences=sequences,
        recipe=recipe,
        joint_regressor=regressor.matrix,
        joint_names=list(CMU_BVH_JOINTS),
    )
    with atomic_path(folder / "rig_joints.npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **{f"seq{i}": j for i, j in enumerate(rig_joints)})
    dataset.save(folder)
    return dataset


def load_rig_joints(folder: str | Path) -> list[np.ndarray]:
    """The rig's posed bone heads ``(T, 31, 3)`` (mm, BVH joint order) per sequence of a
    dataset folder written by ``build_cmu_anny`` (``dataset_folder(dataset)``)."""
    path = Path(folder) / "rig_joints.npz"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no rig joints (build the dataset with build_cmu_anny)")
    with np.load(path) as z:
        return [z[f"seq{i}"] for i in range(len(z.files))]


def cmu_anny_dataset(
    root: str | Path | None, split: str, *, identities: str, topology: str
) -> MeshDataset:
    """The benchmark loader (``zoo.benchmark.MESH_DATASETS``): ``root`` is the CMU BVH folder
    (the benchmark's ``data_root``); built on first use, then loaded from the cache."""
    if root is None:
        raise DataNotFoundError(
            "no CMU BVH folder given: pass --data-root pointing at the folder "
            "holding MANIFEST.tsv and data/ (../shared/data/cmu_bvh here)"
        )
    return build_cmu_anny(root, identities=identities, topology=topology, split=split)
