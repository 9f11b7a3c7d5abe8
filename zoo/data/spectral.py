"""Spectral basis of a mesh: the eigenvectors of its combinatorial Graph Laplacian ``L = D - A``
with the ``k`` smallest eigenvalues (``Phi (V, k)``: coefficients ``C = Phi^T X``, reconstruction
``X = Phi C``), computed canonically, cached, and aligned to a benchmark's shipped reference
(:class:`BasisReference`) so that every machine gets the vectors the shipped weights were
trained on. docs/reproducibility.md ("Spectral bases") says why and how well.
"""

from __future__ import annotations

import hashlib
import time
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch

from zoo.core.io import atomic_path
from zoo.data.mesh import MeshError, MeshTopology, cache_root
from zoo.paths import REPO_ROOT

# Shift of the shift-invert solver: slightly below the smallest eigenvalue (0) of a Laplacian,
# so that L - sigma I is positive definite and its sparse LU factorisation never meets a zero pivot.
SIGMA = -1e-3
# Above this fraction of the vertex count the Lanczos solver loses its advantage (and ARPACK
# cannot return k >= V - 1 vectors at all): use the dense symmetric solver instead.
DENSE_FRACTION = 0.25
DENSE_MAX_VERTICES = 600  # small meshes: the dense solver is fast and exact
SLICE = 128  # eigenvalues per shift-invert solve (see _lanczos)
FORMAT_VERSION = 3  # 1: `hash` was the checksum of the vectors' bytes; 2: no `method` field
# What a basis's identity (``basis_hash``) names besides topology and k; change it with any change
# to what ``SpectralBasis.compute`` returns (solver choice, ordering, sign convention). A file
# records the method it was computed with (files before format 3: METHOD_V1).
BASIS_METHOD = (
    "combinatorial-laplacian/lowest-k/sorted/canonical-clusters/largest-entry-positive/v2"
)
METHOD_V1 = "combinatorial-laplacian/lowest-k/sorted/largest-entry-positive/v1"
PROBES = 4  # probe vectors of ``probe_projections``
# Consecutive eigenvalues closer than CLUSTER_GAP * max(1, lambda_k) share one cluster, whose
# frame is made canonical. Solvers place an eigenvalue to ~1e-13 here, so a gap this wide is never
# mistaken for a cluster nor a cluster split, and the vectors outside clusters are accurate to
# ~2e-8 (module docstring).
CLUSTER_GAP = 1e-7
# Largest |difference| between two bases of one topology (unit vectors, per entry; per cluster
# for subspaces: 1 - the smallest cosine of their principal angles) that counts as the same basis.
BASIS_TOLERANCE = 1e-6
# Where the benchmarks' basis references are shipped (module docstring).
SHIPPED_DIR = REPO_ROOT / "benchmarks" / "bases"
# A reference's probe projections per vector: more than the largest group it aligns.
FRAME_PROBES = 32
# Consecutive eigenvalues closer than this (times max(1, lambda_k)) are aligned to a reference
# together: wide enough for any pair a solver could mix up (a rotation of well-separated
# vectors is found as the identity or a sign), narrow enough for groups of a few vectors.
ALIGN_GAP = 1e-4
# Largest misfit (relative, per group) of a computed basis's probe projections to its reference
# after alignment: the solver's rounding gives ~1e-8; another subspace gives order one.
ALIGN_TOLERANCE = 1e-5
SOLVERS = ("auto", "dense", "lanczos")


class SpectralError(MeshError):
    """A spectral basis does not fit its mesh, or a cached basis file is not what was expected."""


class SpectralBasis:
    """``k`` Laplacian eigenvectors of one topology, with their eigenvalues and a hash.

    ``vectors`` is float64 numpy ``(V, k)``; ``vectors_torch`` is a cached float32 torch copy and
    :meth:`torch_vectors` one per device and dtype, used by :meth:`project` and
    :meth:`reconstruct`.
    """

    def __init__(
        self,
        topology_hash: str,
        eigenvalues: np.ndarray,
        vectors: np.ndarray,
        topology_name: str = "mesh",
        solver: str = "",
        method: str = BASIS_METHOD,
    ) -> None:
        vectors = np.ascontiguousarray(vectors, dtype=np.float64)
        eigenvalues = np.ascontiguousarray(eigenvalues, dtype=np.float64)
        if vectors.ndim != 2 or eigenvalues.shape != (vectors.shape[1],):
            raise SpectralError(
                f"spectral basis of {topology_name}: vectors (V, k) and "
                f"eigenvalues (k,) expected, got {vectors.shape} and "
                f"{eigenvalues.shape}"
            )
        self.topology_hash = str(topology_hash)
        self.topology_name = topology_name
        self.k = int(vectors.shape[1])
        self.num_vertices = int(vectors.shape[0])
        self.eigenvalues = eigenvalues
        self.vectors = vectors
        self.solver = solver
        self.method = method
        self.hash = basis_hash(self.k, self.topology_hash, method)
        self.checksum = vectors_checksum(self.vectors)
        self._torch: dict[tuple[str, torch.dtype], torch.Tensor] = {}

    def __repr__(self) -> str:
        return (
            f"SpectralBasis(topology={self.topology_name} {self.topology_hash[:12]}, "
            f"V={self.num_vertices}, k={self.k}, hash={self.hash[:12]})"
        )

    # ---- construction -------------------------------------------------------------------------

    @classmethod
    def compute(
        cls,
        topology: MeshTopology,
        k: int,
        *,
        solver: str = "auto",
        start: np.ndarray | None = None,
        threads: int = 1,
    ) -> SpectralBasis:
        """The ``k`` lowest eigenvectors of ``topology.laplacian()``, sorted by eigenvalue, in
        the canonical frame inside clusters of repeated eigenvalues (module docstring).

        ``solver``: ``auto`` (dense for small meshes or large ``k``, else Lanczos), ``dense`` or
        ``lanczos``; ``start``: the Lanczos start vector (default: a fixed smooth one);
        ``threads``: BLAS threads (one by default: then the bytes are the same to the last bit
        on a given machine whatever its settings)."""
        if solver not in SOLVERS:
            raise SpectralError(f"spectral basis: solver must be one of {SOLVERS}, got {solver!r}")
        n = topology.num_vertices
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= n:
            raise SpectralError(
                f"spectral basis of {topology.name}: k must be an integer in "
                f"[1, {n}] (the number of vertices), got {k!r}"
            )
        k = int(k)
        lap = topology.laplacian().astype(np.float64)
        # One BLAS thread for both solvers: the result is then the same to the last bit on a
        # given machine whatever its thread settings (the dense solver's last bits, and so the
        # checksum, change with the thread count), and ARPACK runs faster on shared cores.
        # One eigenpair more than asked, to see whether k would cut a cluster in two.
        count = min(k + 1, n)
        dense = (
            n <= DENSE_MAX_VERTICES or count >= DENSE_FRACTION * n or count >= n - 1
            if solver == "auto"
            else solver == "dense" or count >= n - 1  # ARPACK cannot return V - 1 vectors
        )
        with _blas_threads(threads):
            if dense:
                values, vectors = scipy.linalg.eigh(lap.toarray(), subset_by_index=[0, count - 1])
                used = "scipy.linalg.eigh (dense)"
            else:
                values, vectors = _lanczos(lap, count, start)
                used = (
                    f"scipy.sparse.linalg.eigsh (shift-invert from sigma={SIGMA:g}, "
                    f"slices of {SLICE})"
                )
        order = np.argsort(values, kind="stable")
        values, vectors = values[order], vectors[:, order]
        values[np.abs(values) < 1e-12] = 0.0  # the constant vector's eigenvalue, without noise
        if count > k:
            cut = next(c for c in clusters(values) if c.stop > k - 1)
            if cut.stop > k:
                # The kept vectors span an arbitrary part of the cluster's eigenspace: a basis
                # this machine's solver chose, which another machine will not reproduce.
                warnings.warn(
                    f"spectral basis of {topology.name}: k={k} cuts a cluster of "
                    f"{cut.stop - cut.start} (nearly) repeated eigenvalues "
                    f"(vectors {cut.start}..{cut.stop - 1}, eigenvalue {values[k - 1]:.6g}), "
                    f"whose kept part has no canonical basis (other machines compute another); "
                    f"use k={cut.start} or k={cut.stop}",
                    RuntimeWarning,
                    stacklevel=2,
                )
            values, vectors = values[:k], vectors[:, :k]
        vectors = _fix_signs(canonical_clusters(values, vectors))
        return cls(topology.hash, values, vectors, topology.name, used)

    @classmethod
    def load_or_compute(
        cls, topology: MeshTopology, k: int, cache_dir: str | Path | None = None
    ) -> SpectralBasis:
        """The cached basis of ``topology`` with ``k`` vectors; computed and cached if absent.

        The file is ``<cache_dir>/spectral-<topology hash>-k<k>.npz`` (``cache_dir`` defaults to
        ``<cache root>/spectral``, see :func:`zoo.data.mesh.cache_root`). A file there that
        belongs to another topology, or whose content no longer matches its checksum, raises
        :class:`SpectralError`: delete it deliberately to recompute.
        """
        reference = BasisReference.load(reference_path(topology, k))
        path = cache_path(topology, k, cache_dir)
        if path.is_file():
            basis = cls.load(path)
            basis.check_topology(topology)
            if basis.k != k:
                raise SpectralError(f"{path}: cached basis has k={basis.k}, expected {k}")
            if reference is None or basis.hash == reference.hash:
                return basis
        basis = cls.compute(topology, k)
        if reference is not None:  # a benchmark's basis: in the frame it was trained in
            basis = reference.align(basis)
        basis.save(path)
        return basis

    # ---- files --------------------------------------------------------------------------------

    def save(self, path: str | Path) -> Path:
        """Write the basis as an ``.npz`` atomically."""
        path = Path(path)
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as f:
                np.savez(
                    f,
                    format_version=np.int64(FORMAT_VERSION),
                    k=np.int64(self.k),
                    topology_hash=np.str_(self.topology_hash),
                    topology_name=np.str_(self.topology_name),
                    solver=np.str_(self.solver),
                    method=np.str_(self.method),
                    hash=np.str_(self.hash),
                    checksum=np.str_(self.checksum),
                    eigenvalues=self.eigenvalues,
                    vectors=self.vectors,
                )
        return path

    @classmethod
    def load(cls, path: str | Path) -> SpectralBasis:
        """Read a basis written by :meth:`save`, checking its recorded checksum."""
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                fields = {
                    name: z[name]
                    for name in (
                        "format_version",
                        "k",
                        "topology_hash",
                        "topology_name",
                        "solver",
                        "hash",
                        "eigenvalues",
                        "vectors",
                    )
                }
                version = int(fields["format_version"])
                # version 1 stored the checksum of the vectors as its `hash`
                fields["checksum"] = z["checksum"] if version >= 2 else fields["hash"]
                fields["method"] = str(z["method"]) if version >= 3 else METHOD_V1
        except FileNotFoundError:
            raise SpectralError(f"{path}: spectral basis file does not exist") from None
        except KeyError as e:
            raise SpectralError(f"{path}: not a spectral basis file (field {e} missing)") from None
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
            raise SpectralError(
                f"{path}: unreadable spectral basis file ({e}); delete it to recompute"
            ) from None
        if version not in (1, 2, FORMAT_VERSION):
            raise SpectralError(f"{path}: format version {version}, expected {FORMAT_VERSION}")
        basis = cls(
            str(fields["topology_hash"]),
            fields["eigenvalues"],
            fields["vectors"],
            str(fields["topology_name"]),
            str(fields["solver"]),
            fields["method"],
        )
        if basis.k != int(fields["k"]) or basis.checksum != str(fields["checksum"]):
            raise SpectralError(
                f"{path}: corrupted spectral basis: checksum "
                f"{basis.checksum[:12]} (k={basis.k}) differs from the recorded "
                f"{str(fields['checksum'])[:12]} (k={int(fields['k'])}); delete "
                f"it to recompute"
            )
        return basis

    # ---- use ----------------------------------------------------------------------------------

    def check_topology(self, topology: MeshTopology) -> None:
        """Raise :class:`SpectralError` unless this basis was computed on ``topology``."""
        if topology.hash != self.topology_hash or topology.num_vertices != self.num_vertices:
            raise SpectralError(
                f"spectral basis {self.hash[:12]} belongs to topology "
                f"{self.topology_name} (hash {self.topology_hash[:12]}, "
                f"{self.num_vertices} vertices), not to {topology.name} (hash "
                f"{topology.hash[:12]}, {topology.num_vertices} vertices)"
            )

    @property
    def vectors_torch(self) -> torch.Tensor:
        """``Phi (V, k)`` as a float32 CPU tensor (cached; see :meth:`torch_vectors`)."""
        return self.torch_vectors()

    def torch_vectors(
        self, device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32
    ) -> torch.Tensor:
        """``Phi (V, k)`` as a torch tensor, cached per device and dtype."""
        key = (str(torch.device(device)), dtype)
        if key not in self._torch:
            self._torch[key] = torch.from_numpy(self.vectors).to(device=device, dtype=dtype)
        return self._torch[key]

    def project(self, vertices: torch.Tensor) -> torch.Tensor:
        """Spectral coefficients ``Phi^T X``: ``(..., V, 3)`` -> ``(..., k, 3)``.

        One matrix product over all leading dimensions. Torch tensors stay on their device and
        dtype, also under an autocast (coefficients of vertices in mm would lose millimetres in
        bfloat16); a numpy array is projected in float64 and returned as numpy.
        """
        if isinstance(vertices, np.ndarray):
            return self.project(torch.from_numpy(np.asarray(vertices, np.float64))).numpy()
        self._check_last(vertices, self.num_vertices, "project", "vertices (..., V, 3)")
        phi = self.torch_vectors(vertices.device, vertices.dtype)
        lead = vertices.shape[:-2]
        # (..., V, 3) -> (N*3, V) @ (V, k) -> (N, 3, k) -> (..., k, 3)
        flat = (
            vertices.reshape(-1, self.num_vertices, 3)
            .transpose(1, 2)
            .reshape(-1, self.num_vertices)
        )
        with torch.autocast(vertices.device.type, enabled=False):
            coeffs = (flat @ phi).reshape(-1, 3, self.k).transpose(1, 2)
        return coeffs.reshape(*lead, self.k, 3)

    def reconstruct(self, coeffs: torch.Tensor) -> torch.Tensor:
        """Vertices ``Phi C``: ``(..., k, 3)`` -> ``(..., V, 3)``, one matrix product (in the
        coefficients' dtype, also under an autocast)."""
        if isinstance(coeffs, np.ndarray):
            return self.reconstruct(torch.from_numpy(np.asarray(coeffs, np.float64))).numpy()
        self._check_last(coeffs, self.k, "reconstruct", "coefficients (..., k, 3)")
        phi = self.torch_vectors(coeffs.device, coeffs.dtype)
        lead = coeffs.shape[:-2]
        flat = coeffs.reshape(-1, self.k, 3).transpose(1, 2).reshape(-1, self.k)
        with torch.autocast(coeffs.device.type, enabled=False):
            out = (flat @ phi.T).reshape(-1, 3, self.num_vertices).transpose(1, 2)
        return out.reshape(*lead, self.num_vertices, 3)

    def _check_last(self, x: torch.Tensor, n: int, what: str, expected: str) -> None:
        if not isinstance(x, torch.Tensor):
            raise TypeError(
                f"SpectralBasis.{what}: expected a torch tensor or numpy array, got "
                f"{type(x).__name__}"
            )
        if x.ndim < 2 or x.shape[-2:] != (n, 3):
            raise SpectralError(
                f"SpectralBasis.{what}: expected {expected} with {n} in the "
                f"second-to-last axis for topology {self.topology_name} (hash "
                f"{self.topology_hash[:12]}, V={self.num_vertices}, k={self.k}),"
                f" got shape {tuple(x.shape)}"
            )


def basis_hash(k: int, topology_hash: str, method: str = BASIS_METHOD) -> str:
    """A basis's identity: sha256 over its method (``BASIS_METHOD`` for a basis computed now),
    ``k`` and the topology hash. The same on every machine; the numbers are checked by
    :func:`probe_projections`."""
    return hashlib.sha256(f"{method}|k={int(k)}|{topology_hash}".encode()).hexdigest()


def vectors_checksum(vectors: np.ndarray) -> str:
    """sha256 over the float64 little-endian bytes of ``vectors``: a file's integrity on the
    machine that wrote it (other machines' solvers differ in the last bits)."""
    return hashlib.sha256(np.ascontiguousarray(vectors, dtype="<f8").tobytes()).hexdigest()


def probe_projections(vectors: np.ndarray) -> np.ndarray:
    """``Phi^T R`` for ``PROBES`` fixed probe vectors ``R (V, PROBES)``: ``(k, PROBES)`` numbers of
    order one that change by about 1 when any vector of the basis changes sign or an eigenspace
    is rotated, and by rounding only when the same basis is recomputed elsewhere. The probes are
    smooth functions of the vertex index with no random generator, so every machine builds the
    same ones (to the last bit of its ``cos``)."""
    vectors = np.asarray(vectors, dtype=np.float64)
    index = np.arange(vectors.shape[0], dtype=np.float64)[:, None]
    probes = np.cos(
        index * (0.7071067811865476 + 0.3819660112501051 * np.arange(PROBES)) + np.arange(PROBES)
    )
    return vectors.T @ probes


def clusters(values: np.ndarray, relative_gap: float = CLUSTER_GAP) -> list[slice]:
    """The clusters of sorted ``values``: runs of consecutive eigenvalues closer than
    ``relative_gap * max(1, |largest|)``, as slices (a simple eigenvalue is a cluster of one)."""
    values = np.asarray(values, dtype=np.float64)
    if not len(values):
        return []
    gap = relative_gap * max(1.0, float(np.abs(values).max()))
    cuts = np.flatnonzero(np.diff(values) > gap) + 1
    bounds = [0, *cuts.tolist(), len(values)]
    return [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]


def cluster_probes(num_vertices: int, count: int) -> np.ndarray:
    """``(V, count)`` smooth probe vectors of the vertex index, without a random generator (the
    same on every machine to the last bit of its ``cos``), generic enough that no cluster's
    subspace is orthogonal to them."""
    index = np.arange(num_vertices, dtype=np.float64)[:, None]
    j = np.arange(count, dtype=np.float64)
    return np.cos(index * (0.5772156649015329 + 0.6180339887498949 * j) + 1.2 * j)


def canonical_clusters(values: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """``vectors`` with every cluster of repeated eigenvalues (:func:`clusters`) rotated to its
    canonical frame: the one in which the cluster's projections onto :func:`cluster_probes` are
    upper triangular with a positive diagonal (a QR factorisation of ``Phi_c^T R``). Any other
    orthonormal basis ``Phi_c U`` of the same subspace gives the same frame: ``U^T Phi_c^T R =
    (U^T Q) R_1``."""
    vectors = np.array(vectors, dtype=np.float64, copy=True)
    for cluster in clusters(values):
        size = cluster.stop - cluster.start
        if size < 2:
            continue
        block = vectors[:, cluster]
        q, r = np.linalg.qr(block.T @ cluster_probes(len(block), size))
        q = q * np.where(np.diag(r) < 0, -1.0, 1.0)  # a positive diagonal: QR made unique
        vectors[:, cluster] = block @ q
    return vectors


def reference_path(topology: MeshTopology, k: int) -> Path:
    """Where a benchmark mesh's basis reference is shipped (module docstring)."""
    return SHIPPED_DIR / f"reference-{topology.hash}-k{int(k)}.npz"


class BasisReference:
    """What a basis must be, in a few kilobytes: its identity (method, hash), eigenvalues and the
    projections ``Phi^T R`` of its vectors onto ``FRAME_PROBES`` fixed probes
    (:func:`cluster_probes`). :meth:`align` rotates a basis computed anywhere into this frame,
    group by group of close eigenvalues (orthogonal Procrustes on the projections), and refuses
    one whose subspaces differ."""

    FIELDS = ("k", "topology_hash", "topology_name", "method", "hash", "eigenvalues", "frame")

    def __init__(self, topology_hash, topology_name, method, eigenvalues, frame) -> None:
        self.topology_hash, self.topology_name = str(topology_hash), str(topology_name)
        self.method = str(method)
        self.eigenvalues = np.asarray(eigenvalues, dtype=np.float64)
        self.frame = np.asarray(frame, dtype=np.float64)
        self.k = len(self.eigenvalues)
        self.hash = basis_hash(self.k, self.topology_hash, self.method)

    @classmethod
    def of(cls, basis: SpectralBasis) -> BasisReference:
        probes = cluster_probes(basis.num_vertices, FRAME_PROBES)
        return cls(
            basis.topology_hash,
            basis.topology_name,
            basis.method,
            basis.eigenvalues,
            basis.vectors.T @ probes,
        )

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as f:
                np.savez(
                    f,
                    k=np.int64(self.k),
                    topology_hash=np.str_(self.topology_hash),
                    topology_name=np.str_(self.topology_name),
                    method=np.str_(self.method),
                    hash=np.str_(self.hash),
                    eigenvalues=self.eigenvalues,
                    frame=self.frame,
                )
        return path

    @classmethod
    def load(cls, path: str | Path) -> BasisReference | None:
        """The reference in ``path``; None when there is none."""
        path = Path(path)
        if not path.is_file():
            return None
        try:
            with np.load(path, allow_pickle=False) as z:
                fields = {name: z[name] for name in cls.FIELDS}
        except KeyError as e:
            raise SpectralError(f"{path}: not a basis reference (field {e} missing)") from None
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
            raise SpectralError(f"{path}: unreadable basis reference ({e})") from None
        reference = cls(
            fields["topology_hash"],
            fields["topology_name"],
            fields["method"],
            fields["eigenvalues"],
            fields["frame"],
        )
        if reference.hash != str(fields["hash"]) or reference.k != int(fields["k"]):
            raise SpectralError(f"{path}: corrupted basis reference (hash or k do not match)")
        return reference

    def align(self, basis: SpectralBasis) -> SpectralBasis:
        """``basis`` (computed on this machine) rotated into this reference's frame, with its
        identity; :class:`SpectralError` when it is not the same basis (eigenvalues beyond
        ``BASIS_TOLERANCE``, a group's probe projections beyond ``ALIGN_TOLERANCE``)."""
        if basis.topology_hash != self.topology_hash or basis.k != self.k:
            raise SpectralError(
                f"basis reference of {self.topology_name} (k={self.k}) does not fit {basis}"
            )
        report = self.misfit(basis)
        if not report["same"]:
            raise SpectralError(
                f"the spectral basis of {self.topology_name} computed here is not the shipped "
                f"one: eigenvalues differ by {report['eigenvalues']:.2g} (tolerance "
                f"{BASIS_TOLERANCE:g}), vectors {report['worst_group']} by "
                f"{report['misfit']:.2g} after alignment (tolerance {ALIGN_TOLERANCE:g})"
            )
        return SpectralBasis(
            basis.topology_hash,
            basis.eigenvalues,
            report["vectors"],
            basis.topology_name,
            basis.solver,
            self.method,
        )

    def misfit(self, basis: SpectralBasis) -> dict:
        """Align ``basis`` group by group; the aligned vectors, the largest eigenvalue
        difference (relative to ``max(1, lambda_k)``) and the largest relative misfit of a
        group's probe projections after alignment, with ``same`` (both within tolerance)."""
        scale = max(1.0, float(np.abs(self.eigenvalues).max()))
        eigen = float(np.abs(self.eigenvalues - basis.eigenvalues).max()) / scale
        probes = cluster_probes(basis.num_vertices, FRAME_PROBES)
        vectors = basis.vectors.copy()
        worst, where = 0.0, None
        for group in clusters(self.eigenvalues, ALIGN_GAP):
            if group.stop - group.start > FRAME_PROBES:
                raise SpectralError(
                    f"basis reference of {self.topology_name}: {group.stop - group.start} "
                    f"close eigenvalues from vector {group.start}, more than {FRAME_PROBES} probes "
                    f"can align"
                )
            block = vectors[:, group]
            mine, target = block.T @ probes, self.frame[group]
            u, _, vt = np.linalg.svd(mine @ target.T)
            rotation = u @ vt  # orthogonal Procrustes: rotation^T mine ~ target
            vectors[:, group] = block @ rotation
            misfit = float(
                np.linalg.norm(rotation.T @ mine - target) / max(np.linalg.norm(target), 1e-12)
            )
            if misfit > worst or where is None:
                worst, where = misfit, f"{group.start}..{group.stop - 1}"
        return {
            "vectors": vectors,
            "eigenvalues": eigen,
            "misfit": worst,
            "worst_group": where,
            "same": eigen <= BASIS_TOLERANCE and worst <= ALIGN_TOLERANCE,
        }


@dataclass(frozen=True)
class BasisCheck:
    """A basis computed on this machine against its shipped reference (:meth:`misfit`'s
    ``report``), and how long the computation took."""

    reference: BasisReference
    computed: SpectralBasis
    seconds: float
    report: dict[str, Any]


def _timed_basis(topology: MeshTopology, k: int) -> tuple[SpectralBasis, float]:
    started = time.perf_counter()
    computed = SpectralBasis.compute(topology, k)
    return computed, time.perf_counter() - started


def check_basis_reference(topology: MeshTopology, k: int) -> BasisCheck:
    """The basis of ``topology`` computed here, aligned to its shipped reference and measured
    against it; :class:`SpectralError` when no reference is shipped."""
    path = reference_path(topology, k)
    if not path.is_file():
        raise SpectralError(f"{path}: no shipped basis reference for {topology.name} (k={k})")
    reference = BasisReference.load(path)
    computed, seconds = _timed_basis(topology, k)
    return BasisCheck(reference, computed, seconds, reference.misfit(computed))


def ship_basis_reference(topology: MeshTopology, k: int) -> tuple[Path, SpectralBasis, float]:
    """Compute the basis of a mesh that has no reference yet and write its reference where it
    ships; a shipped one is never replaced (trained weights depend on its frame)."""
    path = reference_path(topology, k)
    if path.is_file():
        raise SpectralError(
            f"{path} is shipped already (trained weights depend on its frame); delete it "
            f"deliberately to ship another"
        )
    computed, seconds = _timed_basis(topology, k)
    BasisReference.of(computed).save(path)
    return path, computed, seconds


def cache_path(topology: MeshTopology, k: int, cache_dir: str | Path | None = None) -> Path:
    folder = Path(cache_dir) if cache_dir is not None else cache_root() / "spectral"
    return folder / f"spectral-{topology.hash}-k{int(k)}.npz"


def _lanczos(
    lap: sp.csr_matrix, k: int, start: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` smallest eigenpairs by shift-invert Lanczos (ARPACK), in spectrum slices.

    ARPACK's cost grows with the square of the number of vectors it keeps, so beyond
    ``SLICE`` vectors the spectrum is cut into slices of about ``SLICE`` eigenvalues, each found
    by its own shift-invert run centred where the previous one ended. A slice is complete on the
    interval it spans (shift-invert returns the eigenvalues nearest its shift), consecutive
    slices overlap, and they are joined at the widest gap inside the overlap, so no eigenvalue is
    counted twice and a cluster of repeated eigenvalues is never split between two solves. Every
    join, and the k-th eigenvalue, is checked with Sylvester's law of inertia: the number of
    eigenvalues found below the cut must be the number the matrix has. If the vectors are not
    orthonormal to 1e-10 in the end, a Rayleigh-Ritz step on their span makes them so.
    """
    n = lap.shape[0]
    lap = lap.tocsc()
    # A fixed start vector: ARPACK otherwise starts from a random one and recomputes differ.
    v0 = np.cos(np.arange(n) * 0.7071) + 1.5 if start is None else np.asarray(start, float)

    def solve(count: int, sigma: float) -> tuple[np.ndarray, np.ndarray]:
        count = min(count, n - 2)
        values, vectors = spla.eigsh(
            lap, k=count, sigma=sigma, which="LM", v0=v0, ncv=min(n, max(2 * count + 1, 20))
        )
        order = np.argsort(values, kind="stable")
        return values[order], vectors[:, order]

    first = k if k <= 1.5 * SLICE else SLICE
    values, vectors = solve(first, SIGMA)
    while len(values) < k:
        top = values[-1]  # every eigenvalue up to `top` has been found
        density = len(values) / max(top - values[0], 1e-12)  # eigenvalues per unit (Weyl: ~flat)
        need = min(SLICE, k - len(values) + 8)
        overlap = max(8, need // 8)
        for _ in range(4):
            sigma = top + need / 2 / density
            new_values, new_vectors = solve(need + 2 * overlap, sigma)
            shared = new_values[new_values <= top]
            if len(shared) >= 2 and new_values[-1] > top:
                break
            overlap *= 2  # the slice did not reach back below `top`: widen it
        else:
            raise SpectralError(
                f"spectrum slicing found no overlap above eigenvalue {top:.6g} (k={k}, V={n})"
            )
        gaps = np.diff(shared)
        cut = (shared[np.argmax(gaps)] + shared[np.argmax(gaps) + 1]) / 2
        keep_old, keep_new = values < cut, new_values > cut
        _check_count(lap, cut, int(keep_old.sum()), k)
        values = np.concatenate([values[keep_old], new_values[keep_new]])
        vectors = np.concatenate([vectors[:, keep_old], new_vectors[:, keep_new]], axis=1)
    if len(values) > k:  # the k-th and the next: nothing is missing below them
        _check_count(lap, (values[k - 1] + values[k]) / 2, k, k)
    values, vectors = values[:k], vectors[:, :k]
    if np.abs(vectors.T @ vectors - np.eye(k)).max() > 1e-10:
        q, _ = np.linalg.qr(vectors)
        small = q.T @ (lap @ q)
        values, rotation = np.linalg.eigh((small + small.T) / 2)
        vectors = q @ rotation
    return values, vectors


def _blas_threads(threads: int = 1):
    """Run the solvers with ``threads`` BLAS threads, one by default: ARPACK's level-2 products
    gain nothing from more, and OpenBLAS's spinning threads cost several times the work when the
    cores are shared (measured: 41 s of CPU for k=512 on 13,718 vertices with 2 threads against
    8 s with one)."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=threads, user_api="blas")


def _check_count(lap: sp.csc_matrix, x: float, found: int, k: int) -> None:
    """Raise unless ``found`` is the number of eigenvalues below ``x`` that Sylvester's law of
    inertia gives: the count of negative pivots of a symmetric LDL^T factorisation of
    ``L - x I`` (SuperLU in symmetric mode, diagonal pivots only)."""
    n = lap.shape[0]
    try:
        lu = spla.splu(
            (lap - x * sp.identity(n, format="csc")).tocsc(),
            permc_spec="MMD_AT_PLUS_A",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )
    except RuntimeError:  # exactly singular: x is an eigenvalue, the count is undefined
        return
    if not np.array_equal(lu.perm_r, lu.perm_c):
        return  # off-diagonal pivoting: not an LDL^T, no inertia to read
    below = int(np.count_nonzero(lu.U.diagonal() < 0))
    if below != found:
        raise SpectralError(
            f"the Lanczos solver found {found} eigenvalues below {x:.6g}, the "
            f"matrix has {below} (k={k}, V={n}); try another k"
        )


def _fix_signs(vectors: np.ndarray) -> np.ndarray:
    """Make the largest-magnitude entry of every column positive (ties, within a relative 1e-6,
    go to the lowest vertex index)."""
    magnitude = np.abs(vectors)
    near_max = magnitude >= magnitude.max(axis=0, keepdims=True) * (1 - 1e-6)
    pivot = np.argmax(near_max, axis=0)  # first True per column
    signs = np.sign(vectors[pivot, np.arange(vectors.shape[1])])
    signs[signs == 0] = 1.0
    return np.ascontiguousarray(vectors * signs)


def default_cache_dir() -> Path:
    return cache_root() / "spectral"


__all__ = [
    "SpectralBasis",
    "SpectralError",
    "basis_hash",
    "cache_path",
    "canonical_clusters",
    "clusters",
    "BasisReference",
    "reference_path",
    "default_cache_dir",
    "probe_projections",
    "vectors_checksum",
]
