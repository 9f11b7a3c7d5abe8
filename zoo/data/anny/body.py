"""The Anny body model (``anny.Anny(rig="cmu_mb")``): loading it at the ``full`` or ``low``
topology, its triangles, its phenotype parameters (the default body and the drawn MI bodies)
and its rest skeleton. docs/datasets.md ("CMU motion on the Anny body") describes the bodies.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import os
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from zoo.data.bvh import CMU_BVH_JOINTS
from zoo.data.mesh import QUAD_TIE, triangulate_quads

# BVH name -> Anny ``cmu_mb`` bone name where they differ (all others are the same).
BVH_TO_ANNY = {"LeftHandIndex1": "LeftHandFinger1", "RightHandIndex1": "RightHandFinger1"}

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
PHENOTYPE_LABELS = ("gender", "age", "muscle", "weight", "height", "proportions")
# OI: Anny's default body, every parameter 0.5 (an androgynous body; docs/datasets.md gives its
# height and age).
DEFAULT_PHENOTYPE = {k: 0.5 for k in PHENOTYPE_LABELS}
# MI: each parameter uniform on this range, drawn per sequence. The age range holds adults only
# (docs/datasets.md gives the ages on anny's calibration); the others stay clear of the extreme
# blend shapes.
MI_PHENOTYPE_RANGES = {
    "gender": (0.0, 1.0),
    "age": (0.67, 0.85),
    "muscle": (0.1, 0.9),
    "weight": (0.1, 0.9),
    "height": (0.1, 0.9),
    "proportions": (0.1, 0.9),
}


class AnnyUnavailable(ImportError):
    """The ``anny`` package is not installed (``pip install anny==0.6.2``)."""


@contextmanager
def one_thread():
    """Torch on one thread while a dataset or regressor is computed: its float sums follow the
    thread count (docs/reproducibility.md), and one thread gives the same bytes on every
    machine."""
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


@contextmanager
def _quiet_warp():
    """anny initialises NVIDIA Warp when it builds a model, which prints a CUDA-driver warning
    and a banner from native code; on a machine without a CUDA device that says nothing useful,
    so stderr is silenced meanwhile there (a failure still raises)."""
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
    dtype: torch.dtype = torch.float64,
    anny_cache_dir: str | Path | None = None,
):
    """``anny.Anny(rig="cmu_mb")`` at the ``full`` (13,718 vertices) or ``low`` (1,229) topology.

    In float64 by default: meshes skinned with it and rounded once to float32 had the same bytes
    under every CPU kind's kernels measured, where float32 skinning follows each CPU's kernels
    (docs/reproducibility.md).

    The first build of a topology is slow; anny caches it (``ANNY_CACHE_DIR``, or
    ``anny_cache_dir``) and later loads read the cache (docs/datasets.md gives the times).
    """
    if topology not in TOPOLOGIES:
        raise ValueError(f"topology must be one of {sorted(TOPOLOGIES)}, got {topology!r}")
    anny_version()
    with _quiet_warp():
        import anny  # the third-party package (absolute import), not this one
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


_MODELS: dict[str, Any] = {}


def shared_model(topology: str):
    """The topology's model from ``load_anny_model``, loaded once per process."""
    if topology not in _MODELS:
        _MODELS[topology] = load_anny_model(topology)
    return _MODELS[topology]


def bvh_joint_order(model) -> list[int]:
    """The model's bone index of each CMU BVH joint (``CMU_BVH_JOINTS`` order)."""
    return [model.bone_labels.index(BVH_TO_ANNY.get(n, n)) for n in CMU_BVH_JOINTS]


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


def mi_phenotype(seed: int, key: str) -> dict[str, float]:
    """The MI identity of sequence ``key`` (e.g. ``"02_01"``) under ``seed``: each parameter
    uniform on ``MI_PHENOTYPE_RANGES``, from a generator seeded by ``sha256(seed, key)`` so an
    identity does not depend on which other trials are built."""
    digest = hashlib.sha256(f"cmu_anny-mi:{seed}:{key}".encode()).digest()
    rng = np.random.default_rng(int.from_bytes(digest[:8], "little"))
    return {k: float(rng.uniform(*MI_PHENOTYPE_RANGES[k])) for k in PHENOTYPE_LABELS}


def rest_skeleton(model, phenotype: dict[str, float] | None = None) -> dict[str, np.ndarray]:
    """Rest bone heads and tails ``(31, 3)`` (float64, metres, Anny bone order)."""
    with torch.no_grad():
        out = model(phenotype_kwargs=phenotype_tensor(model, phenotype), return_bone_ends=True)
    return {
        "heads": out["rest_bone_heads"][0].double().numpy(),
        "tails": out["rest_bone_tails"][0].double().numpy(),
        "vertices": out["rest_vertices"][0].double().numpy(),
    }
