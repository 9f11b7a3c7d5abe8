"""Speed of CMU-on-Anny mesh generation: model load (first build vs cached) and frames/s.

    python benchmarks/speed/speed_anny.py          # cached load, skinning at full and low res
    python benchmarks/speed/speed_anny.py --cold   # also the first build into an empty cache
    python benchmarks/speed/speed_anny.py --frames 2000 --batch 1000 --batch 256

Loads run in a fresh Python process each (the model is built or read from anny's cache there);
the figures leave out importing torch and anny. Skinning figures are in the model's precision
(float64, as the datasets are built) on this machine's CPU,
after one warm-up batch; "end to end" adds reading the BVH, resampling to 25 Hz and the
retargeting of one trial.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from tabulate import tabulate

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from zoo.data import anny as zoo_anny  # noqa: E402
from zoo.data.bvh import CMU_BVH_JOINTS, read_bvh  # noqa: E402

DEFAULT_BVH = REPO.parent / "shared" / "data" / "cmu_bvh"
LOAD_SNIPPET = (
    "import time; import anny; from zoo.data.anny import load_anny_model; "
    "t = time.perf_counter(); load_anny_model({topology!r}); "
    "print(time.perf_counter() - t)"
)


def timed_load(topology: str, cache: str | None) -> float:
    env = dict(os.environ)
    if cache is not None:
        env["ANNY_CACHE_DIR"] = cache
    out = subprocess.run(
        [sys.executable, "-c", LOAD_SNIPPET.format(topology=topology)],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return float(out.stdout.strip().splitlines()[-1])


def skin_rate(model, params: np.ndarray, batch: int) -> float:
    zoo_anny.skin(model, params[:batch], batch_size=batch)  # warm-up (kernel load, allocations)
    t = time.perf_counter()
    zoo_anny.skin(model, params, batch_size=batch)
    return len(params) / (time.perf_counter() - t)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bvh-root", type=Path, default=DEFAULT_BVH)
    parser.add_argument("--trial", default="02_01", help="trial whose frames are skinned")
    parser.add_argument("--frames", type=int, default=1000, help="frames skinned per figure")
    parser.add_argument("--batch", type=int, action="append", help="skinning batch sizes")
    parser.add_argument(
        "--cold",
        action="store_true",
        help="also time the first build into an empty anny cache (minutes)",
    )
    parser.add_argument("--threads", type=int, default=None, help="torch threads")
    args = parser.parse_args(argv)
    batches = args.batch or [1000, 256]
    if args.threads:
        torch.set_num_threads(args.threads)

    rows = []
    if args.cold:
        with tempfile.TemporaryDirectory(prefix="anny-cold-") as cold:
            first = timed_load("low", cold)  # builds the full-body data, then the low topology
            rows.append(["first build: low (empty cache)", f"{first:.1f} s"])
            rows.append(["first build: full (after low)", f"{timed_load('full', cold):.1f} s"])
    for topology in ("low", "full"):
        rows.append([f"cached load: {topology}", f"{timed_load(topology, None):.2f} s"])
    print(tabulate(rows, headers=["model load", "time"]))
    print()

    trial = next(t for t in zoo_anny.list_trials(args.bvh_root) if t.key == args.trial)
    rows = []
    for topology in ("low", "full"):
        model = zoo_anny.load_anny_model(topology)
        t = time.perf_counter()
        bvh = read_bvh(trial.path, CMU_BVH_JOINTS)
        rots = zoo_anny.motion_rotations(bvh)
        target = zoo_anny.retarget(model, bvh)
        params = target.pose_parameters(rots)
        prep = time.perf_counter() - t
        tiled = np.concatenate([params] * (args.frames // len(params) + 1))[: args.frames]
        for batch in batches:
            rate = skin_rate(model, tiled, batch)
            rows.append(
                [
                    topology,
                    model.template_vertices.shape[0],
                    batch,
                    f"{rate:,.0f}",
                    f"{1000 / rate:.2f}",
                ]
            )
        t = time.perf_counter()
        zoo_anny.skin(model, params, batch_size=max(batches))
        end_to_end = len(params) / (prep + time.perf_counter() - t)
        rows.append(
            [
                topology,
                model.template_vertices.shape[0],
                f"end to end ({trial.key}, {len(params)} frames)",
                f"{end_to_end:,.0f}",
                f"{1000 / end_to_end:.2f}",
            ]
        )
    print(tabulate(rows, headers=["topology", "vertices", "batch", "frames/s", "ms/frame"]))
    print(
        f"\n{args.frames} frames of {trial.key} per figure, float64 skinning, torch threads "
        f"{torch.get_num_threads()}, anny {zoo_anny.anny_version()}"
    )


if __name__ == "__main__":
    main()
