"""Whether a CMU-on-Anny mesh has the same bytes under every CPU kind's float kernels.

Skins the first ``--trials`` test trials on the Anny body in float32 and in float64 (rounded once
to float32, as ``zoo.data.anny`` builds its datasets, and before rounding), once per kernel set a
CPU kind would run: torch's generic, AVX2 and AVX-512 kernels (``ATEN_CPU_CAPABILITY``) with
MKL's, which carry Anny's einsum, narrowed to match (``MKL_ENABLE_INSTRUCTIONS``; and MKL's
conditional numerical reproducibility off, ``MKL_CBWR=COMPATIBLE``, in a fourth set), and
numpy's vector code and OpenBLAS's kernels narrowed too (``NPY_DISABLE_CPU_FEATURES``,
``OPENBLAS_CORETYPE``). Prints, per precision and pair of kernel sets, how many coordinates
differ and by how much.

    python benchmarks/check/skinning_kernels.py --topology low --trials 3
"""

from __future__ import annotations

import argparse
import itertools
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from zoo.paths import REPO_ROOT

# Each kernel set: torch's capability, numpy's features switched off, OpenBLAS's core type, and
# the environment MKL reads.
KERNEL_SETS = {
    "generic": (
        "default",
        "X86_V3 X86_V4 AVX512_ICL AVX512_SPR",
        "Prescott",
        {"MKL_ENABLE_INSTRUCTIONS": "SSE4_2"},
    ),
    "avx2": (
        "avx2",
        "X86_V4 AVX512_ICL AVX512_SPR",
        "Haswell",
        {"MKL_ENABLE_INSTRUCTIONS": "AVX2"},
    ),
    "avx512": ("avx512", "", "", {"MKL_ENABLE_INSTRUCTIONS": "AVX512"}),
    "mkl_compatible": ("avx512", "", "", {"MKL_CBWR": "COMPATIBLE"}),
}


def skinned(topology: str, paths: list[str | Path]) -> dict[str, np.ndarray]:
    """The trials at ``paths`` skinned on the ``topology`` body with this process's kernels: in
    float32, in float64 rounded once to float32 (as ``zoo.data.anny`` builds its datasets), and
    in float64 before rounding."""
    import torch

    from zoo.data import anny
    from zoo.data.bvh import CMU_BVH_JOINTS, read_bvh

    out = {}
    for dtype in (torch.float32, torch.float64):
        model = anny.load_anny_model(topology, dtype=dtype)
        rounded, unrounded = [], []
        for path in paths:
            bvh = read_bvh(path, CMU_BVH_JOINTS)
            params = anny.retarget(model, bvh).pose_parameters(anny.motion_rotations(bvh))
            rounded.append(anny.skin(model, params)["vertices"])
            with torch.no_grad():  # what skin computes before it rounds
                posed = model(
                    pose_parameters=torch.as_tensor(params).to(dtype),
                    phenotype_kwargs=anny.phenotype_tensor(model, None),
                )
            unrounded.append((posed["vertices"] * 1000.0).numpy())
        name = str(dtype).removeprefix("torch.")
        out[name] = np.concatenate(rounded)
        if dtype == torch.float64:
            out["float64, before rounding"] = np.concatenate(unrounded)
    return out


# A process of its own per kernel set: torch, numpy and the BLAS libraries pick their kernels
# once, when they load.
SKIN = f"""
import sys, numpy as np, torch
sys.path.insert(0, {str(Path(__file__).resolve().parent)!r})
from skinning_kernels import skinned
np.savez(sys.argv[1], **skinned(sys.argv[2], sys.argv[3:]))
print(torch.backends.cpu.get_cpu_capability())
"""


def _supported(features: str) -> str:
    """``features`` less those this numpy does not know or this CPU lacks (numpy refuses to
    switch off a feature it does not have)."""
    import numpy._core._multiarray_umath as umath

    known = umath.__cpu_features__
    return " ".join(f for f in features.split() if known.get(f))


def skin_under(kernels: str, topology: str, paths: list[Path], out: Path) -> str:
    torch_cap, numpy_off, blas, mkl = KERNEL_SETS[kernels]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "ATEN_CPU_CAPABILITY": torch_cap, **mkl}
    if _supported(numpy_off):
        env["NPY_DISABLE_CPU_FEATURES"] = _supported(numpy_off)
    if blas:
        env["OPENBLAS_CORETYPE"] = blas
    run = subprocess.run(
        [sys.executable, "-c", SKIN, str(out), topology, *map(str, paths)],
        env=env,
        capture_output=True,
        text=True,
    )
    if run.returncode != 0:
        raise SystemExit(f"skinning under the {kernels} kernels failed:\n{run.stderr}")
    return run.stdout.split()[-1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--topology", choices=("low", "full"), default="low")
    parser.add_argument("--trials", type=int, default=3, help="test trials skinned (first N)")
    parser.add_argument(
        "--bvh-root", type=Path, default=REPO_ROOT.parent / "shared" / "data" / "cmu_bvh"
    )
    args = parser.parse_args(argv)
    from zoo.data.anny import select_trials

    paths = [t.path for t in select_trials(args.bvh_root, "test")[: args.trials]]
    start = time.perf_counter()
    arrays = {}
    with tempfile.TemporaryDirectory() as tmp:
        for kernels in KERNEL_SETS:
            out = Path(tmp) / f"{kernels}.npz"
            ran = skin_under(kernels, args.topology, paths, out)
            with np.load(out) as z:
                arrays[kernels] = {k: z[k] for k in z.files}
            print(f"{kernels}: torch ran its {ran} kernels")
    for dtype in ("float32", "float64", "float64, before rounding"):
        for a, b in itertools.combinations(KERNEL_SETS, 2):
            x, y = arrays[a][dtype], arrays[b][dtype]
            print(
                f"skinned in {dtype}: {a} vs {b}: {int((x != y).sum()):,} of {x.size:,} "
                f"coordinates differ, by at most {float(np.abs(x - y).max()):.2g} mm"
            )
    print(f"{args.trials} trials, {args.topology} body, {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
