"""Speed of the spectral mesh pipeline and of the cloth generator.

    python benchmarks/speed/speed_spectral.py [--k 512] [--repeats 5] [--default-split]

Prints:
1. the time to compute a spectral basis (k = 512) cold on Anny's default topology (13,718
   vertices) when ``anny`` is installed, else on a synthetic closed mesh of the same vertex
   count: a UV sphere of 127 rings x 108 segments plus two poles, every quad split along a
   random diagonal so that the connectivity has no symmetry (``--sphere RINGS SEGMENTS``: a
   sphere of that size in any case);
2. the time to load the same basis from the cache;
3. the cloth simulator's throughput in mesh frames per second (a batch of 100 sequences, the size
   of the default test split, or ``--cloth-sequences``), and with ``--default-split`` the wall
   time to generate the default train and test splits (400 + 100 sequences) into a temporary
   cache;
4. the time of one reshaped matrix product against a frame-by-frame loop for reconstructing
   32 windows x 25 frames on 6,890 vertices (SMPL's count) with k = 512, and their ratio.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from zoo.data.cloth import ClothConfig, load_cloth, simulate_cloth
from zoo.data.mesh import MeshTopology
from zoo.data.spectral import SpectralBasis


def uv_sphere(rings: int = 127, segments: int = 108, seed: int = 0) -> MeshTopology:
    """A closed UV sphere: ``rings * segments + 2`` vertices, quads split at random."""
    rng = np.random.default_rng(seed)
    ring = np.arange(rings * segments).reshape(rings, segments) + 1  # vertex 0: north pole
    south = rings * segments + 1
    nxt = np.roll(ring, -1, axis=1)
    faces = [
        np.stack([np.zeros(segments, int), nxt[0], ring[0]], 1),
        np.stack([np.full(segments, south), ring[-1], nxt[-1]], 1),
    ]
    a, b, c, d = ring[:-1].ravel(), nxt[:-1].ravel(), ring[1:].ravel(), nxt[1:].ravel()
    flip = (rng.random(a.size) < 0.5)[:, None]
    faces.append(np.where(flip, np.stack([a, b, d], 1), np.stack([a, b, c], 1)))
    faces.append(np.where(flip, np.stack([a, d, c], 1), np.stack([b, d, c], 1)))
    return MeshTopology(np.concatenate(faces), south + 1, name=f"uv_sphere_{south + 1}")


def anny_topology() -> MeshTopology | None:
    """Anny's full-resolution triangulation, or None without ``anny`` (or its cached build)."""
    try:
        from zoo.data.anny import load_anny_model, model_faces
    except ImportError:
        return None
    model = load_anny_model("full")
    return MeshTopology(model_faces(model), model.template_vertices.shape[0], name="anny_full")


def timed(fn, repeats: int = 1) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--k", type=int, default=512)
    parser.add_argument("--repeats", type=int, default=3, help="repeats of the product timings")
    parser.add_argument(
        "--default-split",
        action="store_true",
        help="also time generating the default cloth splits (about a minute)",
    )
    parser.add_argument(
        "--sphere",
        type=int,
        nargs=2,
        metavar=("RINGS", "SEGMENTS"),
        help="the basis of a UV sphere of this size instead of Anny's topology",
    )
    parser.add_argument(
        "--cloth-sequences",
        type=int,
        default=100,
        help="sequences simulated together for the cloth throughput",
    )
    args = parser.parse_args(argv)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads; numpy {np.__version__}")

    # 1-2. basis: cold, then cached
    topology = uv_sphere(*args.sphere) if args.sphere else anny_topology() or uv_sphere()
    with tempfile.TemporaryDirectory() as cache:
        cold, basis = timed(lambda: SpectralBasis.load_or_compute(topology, args.k, cache))
        cached, again = timed(lambda: SpectralBasis.load_or_compute(topology, args.k, cache), 3)
        assert again.hash == basis.hash
        size = sum(p.stat().st_size for p in Path(cache).iterdir()) / 2**20
    error = np.abs(basis.vectors.T @ basis.vectors - np.eye(args.k)).max()
    print(
        f"spectral basis, {topology.name} ({topology.num_vertices} vertices, "
        f"{len(topology.faces)} faces), k={args.k}: cold {cold:.1f} s ({basis.solver}; "
        f"eigenvalues {basis.eigenvalues[0]:.3g}..{basis.eigenvalues[-1]:.4g}; "
        f"|Phi^T Phi - I| max {error:.1e}), cached load {cached * 1000:.0f} ms "
        f"({size:.0f} MiB file)"
    )

    # 3. cloth generator
    config = ClothConfig()
    batch = args.cloth_sequences
    seconds, (vertices, _) = timed(lambda: simulate_cloth(config, "test", list(range(batch))))
    frames = vertices.shape[0] * (vertices.shape[1] - 1)  # frame 0 is the initial state
    print(
        f"cloth simulator: {frames / seconds:.0f} mesh frames/s ({vertices.shape[2]} vertices, "
        f"{config.substeps} substeps per frame, batch of {batch} sequences: {seconds:.1f} s)"
    )
    if args.default_split:
        with tempfile.TemporaryDirectory() as cache:
            total = 0.0
            for split in ("test", "train"):
                seconds, ds = timed(lambda split=split: load_cloth(split, config, cache_dir=cache))
                total += seconds
                print(
                    f"cloth default {split} split: {len(ds.sequences)} sequences in {seconds:.1f} s"
                )
            print(f"cloth default splits: {total:.1f} s in all")

    # 4. reconstruction: one reshaped product against a loop over frames
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.normal(size=(6890, args.k)))
    smpl_like = SpectralBasis("synthetic-6890", np.arange(args.k, dtype=float), q, "synthetic")
    coeffs = torch.from_numpy(rng.normal(size=(32, 25, args.k, 3)).astype(np.float32))
    phi = smpl_like.torch_vectors()

    def per_frame():
        return torch.stack(
            [
                torch.stack([phi @ coeffs[w, t] for t in range(coeffs.shape[1])])
                for w in range(coeffs.shape[0])
            ]
        )

    smpl_like.reconstruct(coeffs)  # warm-up (and the cached float32 copy of Phi)
    one, batched = timed(lambda: smpl_like.reconstruct(coeffs), args.repeats)
    loop, looped = timed(per_frame, args.repeats)
    torch.testing.assert_close(batched, looped, rtol=1e-4, atol=1e-3)
    print(
        f"reconstruction of 32 x 25 frames, 6890 vertices, k={args.k} (float32): one reshaped "
        f"product {one * 1000:.1f} ms, frame by frame {loop * 1000:.1f} ms, ratio "
        f"{loop / one:.1f}x"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
