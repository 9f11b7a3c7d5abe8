"""The joint regressor of CMU-on-Anny: a sparse ``(31, V)`` matrix that gives the 31 CMU joints
as convex combinations of skinned vertices, fitted by non-negative least squares to Anny's posed
bone heads. Its fit follows the CPU's rounding, so each topology's fit ships as data
(``SHIPPED_REGRESSORS``) and every machine scores through it; docs/reproducibility.md ("Joint
regressors: fitted once, shipped") says why.
"""

from __future__ import annotations

import hashlib
import math
import sys
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.optimize import nnls

from zoo.core.errors import DataNotFoundError, ZooError
from zoo.core.io import atomic_path, sha256_file
from zoo.data.anny.body import (
    TOPOLOGIES,
    anny_version,
    bvh_joint_order,
    mi_phenotype,
    one_thread,
    rest_skeleton,
    shared_model,
)
from zoo.data.anny.retargeting import motion_rotations, retarget, skin
from zoo.data.anny.trials import list_trials
from zoo.data.bvh import CMU_BVH_JOINTS, read_bvh
from zoo.data.expmap import DataFormatError
from zoo.data.mesh import cache_root, recipe_hash
from zoo.paths import REPO_ROOT

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


class RegressorShippedError(ZooError, ValueError):
    """A regressor ships already for this recipe: shipping another is refused."""


@dataclass
class JointRegressor:
    """A sparse ``(31, V)`` regressor (rows in BVH joint order, non-negative, summing to 1)."""

    matrix: sp.csr_matrix
    joint_names: list[str]
    recipe: dict[str, Any]
    source: str = ""  # the file it was read from


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
    order = bvh_joint_order(model)
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
    return SHIPPED_REGRESSORS / f"joint_regressor-{topology}-{recipe_hash(recipe)}.npz"


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
        matrix, stats = _fit(topology, files, model)
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
    model = shared_model(topology) if model is None else model
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
    order = bvh_joint_order(model)
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


def ship_joint_regressor(bvh_root: str | Path, topology: str) -> tuple[Path, JointRegressor]:
    """Fit the topology's regressor here and write it where it ships (``SHIPPED_REGRESSORS``),
    for a recipe that has none; refused (``RegressorShippedError``) where one ships already.
    Returns that path and the regressor."""
    recipe, files = regressor_recipe(bvh_root, topology)
    path = shipped_regressor_path(topology, recipe)
    if path.is_file():
        raise RegressorShippedError(
            f"{path} is shipped already (committed MPJPE rows depend on it); delete it "
            f"deliberately to ship another"
        )
    matrix, stats = _fit(topology, files)
    save_regressor(path, matrix, stats)
    return path, JointRegressor(
        matrix, list(CMU_BVH_JOINTS), recipe={**recipe, **stats}, source=str(path)
    )


def _fit(topology: str, files: Sequence[Path], model=None) -> tuple[sp.csr_matrix, dict]:
    """The one fit of a topology's regressor (``fit_joint_regressor`` with its settings, on
    one thread, seed 0)."""
    model = shared_model(topology) if model is None else model
    with one_thread():
        return fit_joint_regressor(model, files, seed=0, **REGRESSOR_SETTINGS[topology])
