"""Spectral basis: orthonormality, reconstruction, frequency order, topology checks, cache."""

import shutil

import numpy as np
import pytest
import torch

from zoo.data.mesh import MeshTopology
from zoo.data.spectral import (
    BASIS_TOLERANCE,
    METHOD_V1,
    BasisReference,
    SpectralBasis,
    SpectralError,
    basis_hash,
    cache_path,
    canonical_clusters,
    clusters,
    probe_projections,
)


def grid(nx: int, ny: int, seed: int = 0, name: str = "grid") -> MeshTopology:
    """A triangulated nx-by-ny grid, each quad split along a random diagonal."""
    rng = np.random.default_rng(seed)
    idx = np.arange(nx * ny).reshape(ny, nx)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    flip = (rng.random(a.size) < 0.5)[:, None]
    f1 = np.where(flip, np.stack([a, b, d], 1), np.stack([a, b, c], 1))
    f2 = np.where(flip, np.stack([a, d, c], 1), np.stack([b, d, c], 1))
    return MeshTopology(np.concatenate([f1, f2]), nx * ny, name=name)


def grid_xy(nx: int, ny: int) -> np.ndarray:
    x, y = np.meshgrid(np.linspace(0, 1, nx), np.linspace(0, 1, ny))
    return np.stack([x.ravel(), y.ravel()], axis=1)


@pytest.mark.parametrize("nx, ny, k", [(8, 7, 20), (30, 25, 24)])  # dense and Lanczos paths
def test_orthonormal_sorted_eigenvectors(nx, ny, k):
    topo = grid(nx, ny)
    basis = SpectralBasis.compute(topo, k)
    phi = basis.vectors
    assert phi.shape == (nx * ny, k) and phi.dtype == np.float64
    np.testing.assert_allclose(phi.T @ phi, np.eye(k), atol=1e-10)
    lap = topo.laplacian()
    np.testing.assert_allclose(lap @ phi, phi * basis.eigenvalues, atol=1e-9)
    assert np.all(np.diff(basis.eigenvalues) >= -1e-12)
    assert basis.eigenvalues[0] == 0.0  # the constant vector, sign fixed positive
    np.testing.assert_allclose(phi[:, 0], 1 / np.sqrt(nx * ny), atol=1e-10)
    # Largest-magnitude entry of every vector is positive: the sign convention.
    pivot = np.argmax(np.abs(phi), axis=0)
    assert (phi[pivot, np.arange(k)] > 0).all()


def test_lanczos_and_dense_solvers_agree():
    topo = grid(30, 25, seed=3)
    sparse = SpectralBasis.compute(topo, 24)
    assert "eigsh" in sparse.solver
    dense = np.linalg.eigvalsh(topo.laplacian().toarray())[:24]
    np.testing.assert_allclose(sparse.eigenvalues, dense, atol=1e-9)


def test_spectrum_slices_join_without_gaps_or_repeats(monkeypatch):
    from zoo.data import spectral

    monkeypatch.setattr(spectral, "SLICE", 8)  # 40 eigenpairs from 5 or more slices
    topo = grid(30, 25, seed=4)
    sliced = SpectralBasis.compute(topo, 40)
    dense = np.linalg.eigvalsh(topo.laplacian().toarray())[:40]
    np.testing.assert_allclose(sliced.eigenvalues, dense, atol=1e-9)
    np.testing.assert_allclose(sliced.vectors.T @ sliced.vectors, np.eye(40), atol=1e-10)
    # The inertia check counts eigenvalues below a point; a wrong count is an error.
    lap = topo.laplacian().tocsc()
    between = (dense[19] + dense[20]) / 2
    spectral._check_count(lap, between, 20, 40)
    with pytest.raises(SpectralError, match="found 19 eigenvalues below .* the matrix has 20"):
        spectral._check_count(lap, between, 19, 40)


def test_recompute_is_bit_identical():
    topo = grid(30, 25, seed=1)
    a, b = SpectralBasis.compute(topo, 16), SpectralBasis.compute(topo, 16)
    assert a.hash == b.hash and np.array_equal(a.vectors, b.vectors)


def test_full_basis_reconstructs_exactly():
    topo = grid(6, 5)
    basis = SpectralBasis.compute(topo, topo.num_vertices)
    x = torch.randn(2, 3, topo.num_vertices, 3, dtype=torch.float64)
    coeffs = basis.project(x)
    assert coeffs.shape == (2, 3, topo.num_vertices, 3)
    torch.testing.assert_close(basis.reconstruct(coeffs), x, atol=1e-10, rtol=0)


def test_project_and_reconstruct_match_per_frame_products():
    topo = grid(9, 8)
    basis = SpectralBasis.compute(topo, 12)
    x = torch.randn(4, 5, topo.num_vertices, 3)
    phi = torch.from_numpy(basis.vectors).float()
    coeffs = basis.project(x)
    expected = torch.stack([torch.stack([phi.T @ x[i, t] for t in range(5)]) for i in range(4)])
    torch.testing.assert_close(coeffs, expected, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(basis.reconstruct(coeffs), phi @ expected, atol=1e-5, rtol=1e-5)
    assert basis.project(x[0, 0]).shape == (12, 3)  # no leading dimensions
    assert basis.vectors_torch.dtype == torch.float32 and basis.vectors_torch.shape == (72, 12)
    assert basis.vectors_torch is basis.torch_vectors()  # cached, not rebuilt
    # numpy in, float64 numpy out
    out = basis.reconstruct(basis.project(x.double().numpy()))
    assert isinstance(out, np.ndarray) and out.dtype == np.float64


def test_smooth_signals_live_in_low_frequencies():
    nx = ny = 16
    topo = grid(nx, ny)
    basis = SpectralBasis.compute(topo, topo.num_vertices)
    xy = grid_xy(nx, ny)
    bumpy = np.concatenate(
        [xy, 0.2 * (np.sin(np.pi * xy[:, :1]) * np.cos(np.pi * xy[:, 1:]))], axis=1
    )
    noise = np.random.default_rng(0).normal(size=bumpy.shape)
    low = 16  # 16 of 256 frequencies
    for signal, lower, upper in ((bumpy, 0.995, 1.0), (noise, 0.0, 0.2)):
        c = basis.project(signal)
        fraction = (c[:low] ** 2).sum() / (c**2).sum()
        assert lower <= fraction <= upper, fraction
    # Truncating to the low frequencies keeps the smooth shape to within a few percent.
    truncated = SpectralBasis.compute(topo, 32)
    error = np.abs(truncated.reconstruct(truncated.project(bumpy)) - bumpy).max()
    assert error < 0.05


@pytest.mark.parametrize("k", [0, -1, 31, 2.5, True])
def test_bad_k_is_a_clear_error(k):
    with pytest.raises(SpectralError, match=r"k must be an integer in \[1, 30\]"):
        SpectralBasis.compute(grid(6, 5), k)


def test_mismatched_mesh_is_an_error():
    topo, other = grid(6, 5), grid(6, 5, seed=9, name="other")
    basis = SpectralBasis.compute(topo, 8)
    basis.check_topology(topo)
    with pytest.raises(SpectralError, match="belongs to topology grid.*not to other"):
        basis.check_topology(other)
    with pytest.raises(SpectralError, match=r"project.*topology grid.*V=30.*\(2, 31, 3\)"):
        basis.project(torch.zeros(2, 31, 3))
    with pytest.raises(SpectralError, match=r"reconstruct.*k=8.*\(9, 3\)"):
        basis.reconstruct(torch.zeros(9, 3))


def test_cache_hit_returns_identical_basis(tmp_path, monkeypatch):
    topo = grid(7, 6)
    first = SpectralBasis.load_or_compute(topo, 10, tmp_path)
    assert cache_path(topo, 10, tmp_path).is_file()

    def no_compute(*args, **kwargs):
        raise AssertionError("recomputed although cached")

    monkeypatch.setattr(SpectralBasis, "compute", classmethod(no_compute))
    again = SpectralBasis.load_or_compute(topo, 10, tmp_path)
    assert again.hash == first.hash and np.array_equal(again.vectors, first.vectors)
    assert np.array_equal(again.eigenvalues, first.eigenvalues)
    assert again.topology_hash == topo.hash and again.k == 10


def test_default_cache_dir_follows_env(tmp_path, monkeypatch):
    monkeypatch.setenv("ZOO_CACHE_DIR", str(tmp_path))
    topo = grid(5, 4)
    SpectralBasis.load_or_compute(topo, 3)
    assert cache_path(topo, 3).parent == tmp_path / "spectral"
    assert cache_path(topo, 3).is_file()


def test_corrupted_or_foreign_cache_is_an_error(tmp_path):
    topo, other = grid(7, 6), grid(7, 6, seed=5, name="other")
    path = cache_path(topo, 10, tmp_path)
    SpectralBasis.load_or_compute(topo, 10, tmp_path)
    good = path.read_bytes()

    path.write_bytes(good[: len(good) // 2])  # truncated file
    with pytest.raises(SpectralError, match="unreadable spectral basis file"):
        SpectralBasis.load_or_compute(topo, 10, tmp_path)

    # Vectors changed after the hash was recorded.
    path.write_bytes(good)
    with np.load(path) as z:
        fields = dict(z)
    fields["vectors"] = fields["vectors"] * 1.001
    with open(path, "wb") as f:
        np.savez(f, **fields)
    with pytest.raises(SpectralError, match="corrupted spectral basis"):
        SpectralBasis.load_or_compute(topo, 10, tmp_path)

    # Another topology's basis under this topology's name: an error, not a recompute.
    path.unlink()
    shutil.copy(
        SpectralBasis.load_or_compute(other, 10, tmp_path) and cache_path(other, 10, tmp_path), path
    )
    with pytest.raises(SpectralError, match="belongs to topology other"):
        SpectralBasis.load_or_compute(topo, 10, tmp_path)


def test_version_1_cache_files_still_load(tmp_path):
    """Caches written before identity and checksum were told apart (their `hash` was the
    checksum) load with the identity of the method that computed them (before clusters were
    made canonical) and their checksum checked."""
    topo = grid(7, 6)
    basis = SpectralBasis.load_or_compute(topo, 10, tmp_path)
    path = cache_path(topo, 10, tmp_path)
    with np.load(path) as z:
        fields = {k: z[k] for k in z.files if k != "checksum"}
    fields.update(format_version=np.int64(1), hash=np.str_(basis.checksum))
    with open(path, "wb") as f:
        np.savez(f, **fields)
    again = SpectralBasis.load(path)
    assert again.hash == basis_hash(10, topo.hash, METHOD_V1) != basis.hash
    assert again.checksum == basis.checksum
    fields["vectors"] = fields["vectors"] * 1.001
    with open(path, "wb") as f:
        np.savez(f, **fields)
    with pytest.raises(SpectralError, match="corrupted spectral basis"):
        SpectralBasis.load(path)


def test_identity_is_the_same_on_every_machine_and_probes_tell_numbers_apart():
    """The name of a basis (its `hash`, in protocols and trained models) does not follow the last
    bits a machine's solver gives; its probe projections move by rounding then, and by about 1
    when a vector has the other sign."""
    topo = grid(8, 7)
    basis = SpectralBasis.compute(topo, 20)
    noise = np.random.default_rng(1).standard_normal(basis.vectors.shape) * 1e-12
    elsewhere = SpectralBasis(topo.hash, basis.eigenvalues, basis.vectors + noise, topo.name)
    assert elsewhere.hash == basis.hash and elsewhere.checksum != basis.checksum
    near = np.abs(probe_projections(elsewhere.vectors) - probe_projections(basis.vectors)).max()
    assert near < 1e-9
    flipped = basis.vectors.copy()
    flipped[:, 7] *= -1
    far = np.abs(probe_projections(flipped) - probe_projections(basis.vectors)).max()
    assert far > 0.1
    assert SpectralBasis.compute(grid(8, 7, seed=3), 20).hash != basis.hash  # another mesh
    assert SpectralBasis.compute(topo, 19).hash != basis.hash  # another k


def test_basis_bytes_do_not_depend_on_blas_threads():
    # On one machine a recompute with other thread settings gives the same bytes (the cloth
    # mesh's dense solve differs in the last bits otherwise), so its cache checksum holds.
    from threadpoolctl import threadpool_limits

    from zoo.data.cloth import ClothConfig, cloth_mesh

    topology, _ = cloth_mesh(ClothConfig())
    with threadpool_limits(limits=2, user_api="blas"):
        two = SpectralBasis.compute(topology, 256)
    with threadpool_limits(limits=1, user_api="blas"):
        one = SpectralBasis.compute(topology, 256)
    assert two.checksum == one.checksum


def torus(nx: int, ny: int) -> MeshTopology:
    """An nx-by-ny grid closed into a torus, every quad split along the same diagonal: a mesh
    with translation symmetry, whose Laplacian eigenvalues repeat 2, 4 (and more) times."""
    idx = np.arange(nx * ny).reshape(ny, nx)
    right, down = np.roll(idx, -1, axis=1), np.roll(idx, -1, axis=0)
    diagonal = np.roll(right, -1, axis=0)
    faces = np.concatenate(
        [
            np.stack([idx, right, diagonal], -1).reshape(-1, 3),
            np.stack([idx, diagonal, down], -1).reshape(-1, 3),
        ]
    )
    return MeshTopology(faces, nx * ny, name="torus")


def test_repeated_eigenvalues_give_one_basis_whatever_the_solver():
    """On a torus (eigenvalues repeated exactly), the dense solver and the Lanczos solver from
    two different start vectors, with one and two BLAS threads, return one basis within
    BASIS_TOLERANCE, vector by vector: each cluster of repeated eigenvalues is in its
    canonical frame."""
    from zoo.data.spectral import _fix_signs

    topo = torus(16, 12)
    values = np.linalg.eigvalsh(topo.laplacian().toarray())
    found = clusters(values[:60])
    assert max(c.stop - c.start for c in found) >= 4  # the test has repeated eigenvalues
    k = found[-2].stop  # a k that ends a cluster
    rng = np.random.default_rng(0)
    bases = [
        SpectralBasis.compute(topo, k, solver="dense", threads=1),
        SpectralBasis.compute(topo, k, solver="dense", threads=2),
        SpectralBasis.compute(topo, k, solver="lanczos", start=rng.random(topo.num_vertices)),
        SpectralBasis.compute(topo, k, solver="lanczos", start=rng.random(topo.num_vertices)),
    ]
    assert "eigsh" in bases[2].solver and "dense" in bases[0].solver
    for other in bases[1:]:
        assert np.abs(other.vectors - bases[0].vectors).max() <= BASIS_TOLERANCE
        assert np.abs(other.eigenvalues - bases[0].eigenvalues).max() <= BASIS_TOLERANCE
        assert BasisReference.of(bases[0]).misfit(other)["same"]
    # The frame is the cluster's, not the solver's: any rotation inside a cluster maps back.
    cluster = max(clusters(bases[0].eigenvalues), key=lambda c: c.stop - c.start)
    size = cluster.stop - cluster.start
    rotation, _ = np.linalg.qr(rng.standard_normal((size, size)))
    turned = bases[0].vectors.copy()
    turned[:, cluster] = turned[:, cluster] @ rotation
    back = _fix_signs(canonical_clusters(bases[0].eigenvalues, turned))
    np.testing.assert_allclose(back[:, cluster], bases[0].vectors[:, cluster], atol=1e-12)
    with pytest.warns(RuntimeWarning, match=f"cuts a cluster.*use k={cluster.start}"):
        SpectralBasis.compute(topo, cluster.start + 1)


def test_a_reference_aligns_rotations_and_refuses_other_subspaces():
    """A basis in another frame of the same eigenspaces (rotated inside a cluster, vectors of
    another sign) is rotated back into the reference's frame; vectors of other eigenspaces, or
    tilted between groups, are refused."""
    topo = torus(16, 12)
    basis = SpectralBasis.compute(topo, 21)
    reference = BasisReference.of(basis)
    cluster = next(c for c in clusters(basis.eigenvalues) if c.stop - c.start > 1)
    turned = basis.vectors.copy()
    turned[:, cluster] = turned[:, cluster][:, ::-1]  # another frame of the same subspace
    turned[:, 0] *= -1  # another sign
    aligned = reference.align(SpectralBasis(topo.hash, basis.eigenvalues, turned, topo.name))
    np.testing.assert_allclose(aligned.vectors, basis.vectors, atol=1e-12)
    assert aligned.hash == basis.hash
    mixed = basis.vectors.copy()
    mixed[:, [cluster.start, cluster.stop]] = mixed[:, [cluster.stop, cluster.start]]
    with pytest.raises(SpectralError, match="computed here is not the shipped one"):
        reference.align(SpectralBasis(topo.hash, basis.eigenvalues, mixed, topo.name))
    tilted = basis.vectors.copy()  # 3e-3 rad between two groups' vectors: another basis
    a, b = cluster.start, cluster.stop
    tilted[:, a], tilted[:, b] = (
        np.cos(3e-3) * tilted[:, a] + np.sin(3e-3) * tilted[:, b],
        -np.sin(3e-3) * tilted[:, a] + np.cos(3e-3) * tilted[:, b],
    )
    assert not reference.misfit(SpectralBasis(topo.hash, basis.eigenvalues, tilted))["same"]


def test_a_benchmark_basis_is_computed_in_its_shipped_frame(tmp_path, monkeypatch):
    """With a reference shipped for the mesh, the basis computed (and cached) here is the
    reference's, whatever frame the solver returned."""
    from zoo.data import spectral

    topo = torus(16, 12)
    trained = SpectralBasis.compute(topo, 21)
    rng = np.random.default_rng(2)
    frame = trained.vectors.copy()
    for group in clusters(trained.eigenvalues, spectral.ALIGN_GAP):
        q, _ = np.linalg.qr(rng.standard_normal((group.stop - group.start,) * 2))
        frame[:, group] = frame[:, group] @ q  # the frame "another machine" trained in
    shipped = SpectralBasis(topo.hash, trained.eigenvalues, frame, topo.name, method=METHOD_V1)
    monkeypatch.setattr(spectral, "SHIPPED_DIR", tmp_path / "shipped")
    BasisReference.of(shipped).save(spectral.reference_path(topo, 21))
    loaded = SpectralBasis.load_or_compute(topo, 21, tmp_path / "cache")
    assert loaded.hash == shipped.hash != trained.hash
    np.testing.assert_allclose(loaded.vectors, frame, atol=1e-10)
    again = SpectralBasis.load_or_compute(topo, 21, tmp_path / "cache")  # from the cache
    assert np.array_equal(again.vectors, loaded.vectors)


def test_zoo_data_basis_checks_the_shipped_basis_against_this_machine(capsys):
    """The cloth benchmark's shipped basis and the one computed here are the same basis."""
    from zoo.cli import main

    assert main(["data", "basis", "cloth"]) == 0
    out = capsys.readouterr().out
    assert "cloth: basis 40f7523315d7 computed here" in out and ": the same basis" in out
    assert main(["data", "basis", "cloth", "--ship"]) == 2  # never overwritten
    assert "is shipped already" in capsys.readouterr().err
