"""Meshes with constant connectivity: topology, mesh sequences and mesh datasets.

Conventions shared by every mesh dataset (cloth, CMU on Anny, AMASS):
- vertices are stored and evaluated in millimetres, like the skeleton datasets, so MPJPE and MELV
  come out in mm everywhere (body models in metres are scaled by 1000 on the way in);
- one triangulation for the whole dataset (``MeshTopology``), hashed, and the hash goes into
  every protocol record;
- an optional sparse joint regressor ``(J, V)`` turns vertices into joints, so mesh and skeleton
  predictors can share an MPJPE column.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp

from zoo.core.errors import ZooError
from zoo.core.io import atomic_path, atomic_write_json, canonical_json
from zoo.paths import REPO_ROOT

if TYPE_CHECKING:
    import torch


def cache_root(cache_dir: str | Path | None = None) -> Path:
    """Where generated data and spectral bases are cached: ``cache_dir`` if given, else
    ``$ZOO_CACHE_DIR`` if set, else ``<repo>/cache``."""
    if cache_dir is not None:
        return Path(cache_dir)
    env = os.environ.get("ZOO_CACHE_DIR")
    return Path(env).expanduser() if env else REPO_ROOT / "cache"


class MeshError(ZooError, ValueError):
    """A mesh, its connectivity or a mesh file is not what was expected."""


class MeshTopology:
    """A triangulation ``faces (F, 3)`` over ``num_vertices`` vertices, checked on creation."""

    def __init__(self, faces: np.ndarray, num_vertices: int, name: str = "mesh") -> None:
        faces = np.asarray(faces)
        if faces.size == 0 or num_vertices <= 0:
            raise MeshError(f"{name}: empty mesh ({num_vertices} vertices, {len(faces)} faces)")
        if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
            raise MeshError(
                f"{name}: faces must be an integer array (F, 3), got {faces.dtype} {faces.shape}"
            )
        if faces.min() < 0 or faces.max() >= num_vertices:
            raise MeshError(
                f"{name}: face indices must lie in [0, {num_vertices}), found "
                f"[{faces.min()}, {faces.max()}]"
            )
        degenerate = np.nonzero(
            (faces[:, 0] == faces[:, 1])
            | (faces[:, 1] == faces[:, 2])
            | (faces[:, 0] == faces[:, 2])
        )[0]
        if degenerate.size:
            raise MeshError(
                f"{name}: face {degenerate[0]} {faces[degenerate[0]].tolist()} repeats a vertex"
            )
        self.faces = faces.astype(np.int64)
        self.num_vertices = int(num_vertices)
        self.name = name
        edges, counts = np.unique(self._face_edges(), axis=0, return_counts=True)
        if (counts > 2).any():
            bad = edges[np.argmax(counts)]
            raise MeshError(
                f"{name}: non-manifold mesh: edge {bad.tolist()} is shared by "
                f"{counts.max()} faces (at most 2 allowed)"
            )
        self.edges = edges  # (E, 2), unique undirected, i < j
        isolated = np.setdiff1d(np.arange(num_vertices), self.faces.ravel())
        if isolated.size:
            raise MeshError(
                f"{name}: vertex {isolated[0]} belongs to no face "
                f"({isolated.size} isolated vertices)"
            )

    def _face_edges(self) -> np.ndarray:
        f = self.faces
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        return np.sort(e, axis=1)

    @cached_property
    def hash(self) -> str:
        digest = hashlib.sha256()
        digest.update(str(self.num_vertices).encode())
        digest.update(np.ascontiguousarray(self.faces, dtype="<i8").tobytes())
        return digest.hexdigest()

    def adjacency(self) -> sp.csr_matrix:
        i, j = self.edges.T
        n = self.num_vertices
        a = sp.coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
        return (a + a.T).tocsr()

    def laplacian(self) -> sp.csr_matrix:
        """Combinatorial Graph Laplacian ``L = D - A``."""
        a = self.adjacency()
        return (sp.diags(np.asarray(a.sum(axis=1)).ravel()) - a).tocsr()

    def check_vertices(self, vertices: np.ndarray, what: str) -> None:
        """Raise unless ``vertices (..., V, 3)`` fit this topology."""
        if vertices.ndim < 2 or vertices.shape[-2:] != (self.num_vertices, 3):
            raise MeshError(
                f"{what}: vertices of shape {tuple(vertices.shape)} do not fit "
                f"topology {self.name} ({self.num_vertices} vertices, hash "
                f"{self.hash[:12]})"
            )


# Two diagonals of a quad this close (relative, float64) are a tie: which one float32 arithmetic
# finds shorter differs between CPUs (Anny's full body has 56 mirror-symmetric quads whose
# diagonals are equal), so a tie takes the fixed diagonal a-c and the mesh is the same everywhere.
QUAD_TIE = 1e-5


def triangulate_quads(vertices: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Split each quad ``(a, b, c, d)`` along its shorter diagonal: ``(F, 4)`` -> ``(2F, 3)``.

    The shorter diagonal is measured in float64 on ``vertices (V, 3)``; a tie (diagonals within
    ``QUAD_TIE`` of each other, relative) splits along ``a-c``, so the result does not depend on
    the CPU's rounding. Triangles ``(a, b, c), (c, d, a)`` or ``(a, b, d), (d, b, c)`` keep the
    quad's orientation.
    """
    quads = np.asarray(quads, dtype=np.int64)
    if quads.ndim != 2 or quads.shape[1] != 4:
        raise MeshError(f"quads must be an integer array (F, 4), got {quads.shape}")
    v = np.asarray(vertices, dtype=np.float64)
    ac = np.linalg.norm(v[quads[:, 0]] - v[quads[:, 2]], axis=1)
    bd = np.linalg.norm(v[quads[:, 1]] - v[quads[:, 3]], axis=1)
    use_ac = (ac < bd) | (np.abs(ac - bd) <= QUAD_TIE * np.maximum(ac, bd))
    a, b, c, d = quads.T
    first = np.where(use_ac[:, None], np.stack([a, b, c], 1), np.stack([a, b, d], 1))
    second = np.where(use_ac[:, None], np.stack([c, d, a], 1), np.stack([d, b, c], 1))
    return np.stack([first, second], axis=1).reshape(-1, 3)


@dataclass
class MeshSequence:
    """One motion of the mesh: ``vertices (T, V, 3)`` float32 in mm at ``fps``."""

    name: str
    action: str
    vertices: np.ndarray
    fps: float
    identity: str = "default"
    meta: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.vertices)


def recipe_hash(recipe: dict[str, Any]) -> str:
    """The name a recipe gives what is built from it (a dataset's cache folder, a shipped
    regressor's file): its canonical JSON, hashed."""
    return hashlib.sha256(canonical_json(recipe).encode()).hexdigest()[:16]


@dataclass
class MeshDataset:
    """Mesh sequences sharing one topology; ``recipe`` says how they were made (hashed)."""

    name: str
    split: str
    topology: MeshTopology
    sequences: list[MeshSequence]
    recipe: dict[str, Any]
    joint_regressor: sp.csr_matrix | None = None  # (J, V); rows sum to 1
    joint_names: list[str] | None = None
    _content_hash: str | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for s in self.sequences:
            self.topology.check_vertices(s.vertices, f"{self.name}/{s.name}")
        if self.joint_regressor is not None:
            if self.joint_regressor.shape[1] != self.topology.num_vertices:
                raise MeshError(
                    f"{self.name}: joint regressor has {self.joint_regressor.shape[1]}"
                    f" columns, the mesh {self.topology.num_vertices} vertices"
                )

    @property
    def recipe_hash(self) -> str:
        return recipe_hash(self.recipe)

    @property
    def fps(self) -> float:
        rates = {s.fps for s in self.sequences}
        if len(rates) != 1:
            raise MeshError(f"{self.name}: sequences have different frame rates {sorted(rates)}")
        return rates.pop()

    @property
    def actions_present(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(s.action for s in self.sequences))

    def content_hash(self) -> str:
        """sha256 over topology and every sequence's vertices (the data's own identity);
        computed once per dataset object (hundreds of MB for the full-resolution bodies)."""
        if self._content_hash is None:
            digest = hashlib.sha256(self.topology.hash.encode())
            for s in self.sequences:
                digest.update(s.name.encode())
                digest.update(np.ascontiguousarray(s.vertices, dtype="<f4").tobytes())
            self._content_hash = digest.hexdigest()
        return self._content_hash

    def joints_view(self) -> JointsView:
        """This dataset seen through its joint regressor (see :class:`JointsView`)."""
        return JointsView(self)

    # ---- on-disk format: one folder, arrays in an .npz, metadata in a JSON ----------------------

    def save(self, folder: str | Path, step_mm: float | None = None) -> Path:
        """Write ``meshes.npz`` and ``dataset.json`` into ``folder``, each atomically.

        ``step_mm``: store vertices as int16 multiples of ``step_mm`` around a per-sequence,
        per-axis origin (half the bytes of float32); the vertices must already lie on that grid
        (:func:`quantise_vertices`), so what is loaded equals what was saved."""
        folder = Path(folder)
        arrays = {
            "faces": self.topology.faces,
            "num_vertices": np.int64(self.topology.num_vertices),
        }
        for i, s in enumerate(self.sequences):
            if step_mm is None:
                arrays[f"seq{i}"] = s.vertices.astype(np.float32)
                continue
            codes, origin = _int16_codes(s.vertices, step_mm, f"{self.name}/{s.name}")
            arrays.update(
                {f"seq{i}": codes, f"seq{i}_origin": origin, f"seq{i}_step": np.float64(step_mm)}
            )
        if self.joint_regressor is not None:
            r = self.joint_regressor.tocoo()
            arrays.update(
                reg_row=r.row, reg_col=r.col, reg_val=r.data, reg_shape=np.asarray(r.shape)
            )
        with atomic_path(folder / "meshes.npz") as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, **arrays)
        atomic_write_json(
            folder / "dataset.json",
            {
                "name": self.name,
                "split": self.split,
                "recipe": self.recipe,
                "recipe_hash": self.recipe_hash,
                "topology_hash": self.topology.hash,
                "joint_names": self.joint_names,
                "sequences": [
                    {
                        "name": s.name,
                        "action": s.action,
                        "fps": s.fps,
                        "identity": s.identity,
                        "frames": len(s),
                        "meta": s.meta,
                    }
                    for s in self.sequences
                ],
            },
        )
        return folder

    @classmethod
    def load(cls, folder: str | Path) -> MeshDataset:
        folder = Path(folder)
        meta_path, npz_path = folder / "dataset.json", folder / "meshes.npz"
        for p in (meta_path, npz_path):
            if not p.is_file():
                raise MeshError(f"{p}: mesh dataset file missing (build it with `zoo data build`)")
        try:
            return cls._read(folder, meta_path, npz_path)
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as e:
            raise MeshError(
                f"{folder}: damaged or truncated dataset cache ({type(e).__name__}: "
                f"{e}); delete the folder and it is rebuilt on next use (zoo data "
                f"build <benchmark>)"
            ) from None

    @classmethod
    def _read(cls, folder: Path, meta_path: Path, npz_path: Path) -> MeshDataset:
        meta = json.loads(meta_path.read_text())
        with np.load(npz_path) as z:
            topology = MeshTopology(z["faces"], int(z["num_vertices"]), name=meta["name"])
            if topology.hash != meta["topology_hash"]:
                raise MeshError(
                    f"{npz_path}: topology hash {topology.hash[:12]} differs from "
                    f"the recorded {meta['topology_hash'][:12]}"
                )
            sequences = [
                MeshSequence(
                    name=m["name"],
                    action=m["action"],
                    vertices=_stored_vertices(z, f"seq{i}"),
                    fps=m["fps"],
                    identity=m["identity"],
                    meta=m["meta"],
                )
                for i, m in enumerate(meta["sequences"])
            ]
            regressor = None
            if "reg_row" in z:
                regressor = sp.coo_matrix(
                    (z["reg_val"], (z["reg_row"], z["reg_col"])), shape=tuple(z["reg_shape"])
                ).tocsr()
        return cls(
            name=meta["name"],
            split=meta["split"],
            topology=topology,
            sequences=sequences,
            recipe=meta["recipe"],
            joint_regressor=regressor,
            joint_names=meta.get("joint_names"),
        )


def quantise_vertices(vertices: np.ndarray, step_mm: float) -> np.ndarray:
    """``vertices (T, V, 3)`` rounded to the int16 grid of :meth:`MeshDataset.save`: multiples
    of ``step_mm`` from the middle of each axis' range, as float32."""
    origin = _grid_origin(vertices, step_mm)
    codes = np.rint((vertices.astype(np.float64) - origin) / step_mm)
    return (codes * step_mm + origin).astype(np.float32)


def _grid_origin(vertices: np.ndarray, step_mm: float) -> np.ndarray:
    flat = vertices.reshape(-1, 3).astype(np.float64)
    middle = (flat.max(axis=0) + flat.min(axis=0)) / 2
    return np.rint(middle / step_mm) * step_mm  # on the grid itself: re-quantising is exact


def _int16_codes(vertices: np.ndarray, step_mm: float, what: str) -> tuple[np.ndarray, np.ndarray]:
    origin = _grid_origin(vertices, step_mm)
    codes = (vertices.astype(np.float64) - origin) / step_mm
    if np.abs(codes).max() > np.iinfo(np.int16).max:
        span = np.ptp(vertices.reshape(-1, 3), axis=0).max()
        raise MeshError(
            f"{what}: spans {span:.0f} mm, more than int16 steps of {step_mm:g} mm "
            f"can hold ({2 * np.iinfo(np.int16).max * step_mm:.0f} mm); store it as "
            f"float32 or with a larger step"
        )
    rounded = np.rint(codes)
    if np.abs(codes - rounded).max() > 0.05:  # float32 rounding of mm values: < 0.01 steps
        raise MeshError(
            f"{what}: vertices are not on the {step_mm:g} mm grid; quantise them "
            f"first (zoo.data.mesh.quantise_vertices) so the saved data is the data"
        )
    return rounded.astype(np.int16), origin


def _stored_vertices(z, key: str) -> np.ndarray:
    if f"{key}_step" not in z:
        return z[key]
    step, origin = float(z[f"{key}_step"]), z[f"{key}_origin"]
    return (z[key].astype(np.float64) * step + origin).astype(np.float32)


def regress_joints(vertices: torch.Tensor, regressor) -> torch.Tensor:
    """Joints ``(..., J, 3)`` from vertices ``(..., V, 3)`` with a ``(J, V)`` regressor (scipy
    sparse, numpy or torch), as one matrix product over all leading dimensions.

    The product is summed in float64 and rounded once to the vertices' dtype: a joint is a
    weighted sum over thousands of vertices, whose float32 rounding follows the CPU's kernels
    (measured: 0.006 mm between two CPUs on the 13,718-vertex Anny body, three times the
    tolerance of ``zoo leaderboard --check``); in float64 every CPU gives the same float32."""
    import torch

    if sp.issparse(regressor):
        r = regressor.tocoo()
        matrix = torch.sparse_coo_tensor(
            np.stack([r.row, r.col]), r.data, r.shape, check_invariants=True
        )
    else:
        matrix = torch.as_tensor(regressor)
    # float64 where the device has it (MPS does not: there the vertices' own dtype)
    wide = torch.float32 if vertices.device.type == "mps" else torch.float64
    matrix = matrix.to(device=vertices.device, dtype=wide)
    joints, num_vertices = matrix.shape
    if vertices.ndim < 2 or vertices.shape[-2:] != (num_vertices, 3):
        raise ValueError(
            f"regress_joints: regressor ({joints}, {num_vertices}) does not fit "
            f"vertices {tuple(vertices.shape)}"
        )
    lead = vertices.shape[:-2]
    flat = vertices.reshape(-1, num_vertices, 3).permute(1, 0, 2).reshape(num_vertices, -1)
    out = (matrix @ flat.to(wide)).reshape(joints, -1, 3).permute(1, 0, 2)
    return out.reshape(*lead, joints, 3).to(vertices.dtype)


@dataclass
class JointSequence:
    """One sequence of a :class:`JointsView`: ``positions (T, J, 3)`` float32 in mm."""

    name: str
    action: str
    positions: np.ndarray
    fps: float

    def __len__(self) -> int:
        return len(self.positions)


class JointsView:
    """A mesh dataset seen through its sparse joint regressor: every sequence as the ``(T, J,
    3)`` joints that the mesh benchmark's ``mpjpe`` column scores, so skeleton models train and
    are evaluated on exactly the windows and joints the mesh models are scored on."""

    def __init__(self, mesh: MeshDataset) -> None:
        if mesh.joint_regressor is None:
            raise MeshError(
                f"{mesh.name}/{mesh.split}: this mesh dataset has no joint regressor, "
                f"so skeleton models cannot run on it (they need joints)"
            )
        self.mesh = mesh
        self.name, self.split = mesh.name, mesh.split
        self.num_joints = mesh.joint_regressor.shape[0]
        self.joint_names = list(mesh.joint_names or [f"joint{i}" for i in range(self.num_joints)])

    @cached_property
    def sequences(self) -> list[JointSequence]:
        """The regressed joints, computed on first use (one sparse product per sequence)."""
        import torch

        return [
            JointSequence(
                s.name,
                s.action,
                regress_joints(
                    torch.from_numpy(np.asarray(s.vertices, dtype=np.float64)),
                    self.mesh.joint_regressor,
                )
                .float()
                .numpy(),
                s.fps,
            )
            for s in self.mesh.sequences
        ]

    @property
    def fps(self) -> float:
        return self.mesh.fps

    @property
    def parts(self) -> dict[str, list[int]]:
        """Body parts as joint indices (SPGSN's upper and lower body), from the joint names of
        the CMU BVH rig (zoo.data.bvh; Anny's cmu_mb uses the same names)."""
        from zoo.data.bvh import CMU_BVH_LOWER_BODY

        lower = [i for i, n in enumerate(self.joint_names) if n in CMU_BVH_LOWER_BODY]
        if not lower or len(lower) == self.num_joints:
            raise MeshError(
                f"{self.name}: cannot tell upper from lower body from its joint names "
                f"{self.joint_names[:4]}...; expected the CMU BVH rig's "
                f"({', '.join(CMU_BVH_LOWER_BODY[:3])}, ...)"
            )
        return {"upper": [i for i in range(self.num_joints) if i not in lower], "lower": lower}
