"""SpecTrHuMS training steps on cached coefficients: full against low resolution, and against
training from vertices (the projection of every window's frames inside the step, as before).

The step is the training engine's: a batch of 32 windows (50 observed + 25 predicted frames)
gathered from per-sequence arrays, the loss (joint phase: static and dynamic), backward and an
Adam step, in float32. Resolutions are CMU-on-Anny's: full, 13,718 vertices with k = 512
coefficients; low, 1,229 vertices with k = 256. Bases are random orthonormal matrices of those
sizes (the cost of a step is the same for any orthonormal basis); the motion is a random walk
of ``--frames`` frames in mm. Step times are medians of ``--repeats`` steps, the three kinds
timed in turn so they share the machine's load.

Run: python benchmarks/speed/speed_training_view.py [--repeats 9] [--threads N]
(``--tiny``: a model of a few thousand parameters and small meshes, a check of the script.)
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))  # speed_spectrhums.py lies beside
from speed_spectrhums import TINY, random_basis

from zoo.data.windows import gather_windows, window_sampler
from zoo.models.registry import load_registry

T_IN, T_OUT, BATCH = 50, 25, 32
RESOLUTIONS = {"full": (13718, 512), "low": (1229, 256)}
TINY_RESOLUTIONS = {"full": (600, 48), "low": (120, 24)}


def setup(v: int, k: int, frames: int, tiny: bool):
    """A SpecTrHuMS of the registry's configuration on a random basis of ``v x k``, ready for
    the joint phase, with one motion as vertices and as cached coefficients."""
    basis = random_basis(v, k)
    model = load_registry().create_model(
        "spectrhums",
        input_frames=T_IN,
        output_frames=T_OUT,
        num_points=v,
        basis=basis,
        **(TINY if tiny else {}),
    )
    g = torch.Generator().manual_seed(1)
    vertices = torch.cumsum(torch.randn(frames, v, 3, generator=g), 0) + 500.0
    coefficients = basis.project(vertices.double()).float()
    counts = torch.ones(frames, dtype=torch.int64)
    model.start_epoch(0, lambda: iter([(coefficients, counts)]), view=True)
    model.start_epoch(model.autoencoder_epochs, lambda: iter([(coefficients, counts)]), view=True)
    model.train()
    return model, vertices.numpy(), coefficients.numpy()


def step(model, source: np.ndarray, index: np.ndarray, rng, view: bool):
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-5)

    def run():
        rows = rng.choice(len(index), BATCH, replace=False)
        windows = torch.from_numpy(gather_windows([source], index[rows], T_IN + T_OUT))
        history, future = windows[:, :T_IN], windows[:, T_IN:]
        loss = (
            model.training_loss_view(history, future)
            if view
            else model.training_loss(history, future)
        )
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()

    return run


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--frames", type=int, default=300, help="frames of the random motion")
    parser.add_argument("--tiny", action="store_true", help="small model and meshes")
    args = parser.parse_args(argv)
    if args.frames < T_IN + T_OUT + BATCH - 1:
        parser.error(
            f"--frames {args.frames}: a batch of {BATCH} windows of {T_IN + T_OUT} frames needs "
            f"at least {T_IN + T_OUT + BATCH - 1}"
        )
    if args.threads:
        torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    sizes = TINY_RESOLUTIONS if args.tiny else RESOLUTIONS
    index = window_sampler("all", [args.frames], T_IN, T_OUT)
    runs = {}
    for name, (v, k) in sizes.items():
        model, vertices, coefficients = setup(v, k, args.frames, args.tiny)
        rng = np.random.default_rng(0)
        runs[f"{name}, cached coefficients"] = step(model, coefficients, index, rng, True)
        runs[f"{name}, from vertices"] = step(model, vertices, index, rng, False)
    times: dict[str, list[float]] = {name: [] for name in runs}
    for run in runs.values():
        run()  # warm-up
    for _ in range(args.repeats):
        for name, run in runs.items():
            t0 = time.perf_counter()
            run()
            times[name].append(time.perf_counter() - t0)
    median = {name: statistics.median(t) for name, t in times.items()}
    print(
        f"SpecTrHuMS training step, batch {BATCH}, window {T_IN}+{T_OUT}, float32, "
        f"{torch.get_num_threads()} thread(s), median of {args.repeats}:"
    )
    for name, (v, k) in sizes.items():
        for kind in ("cached coefficients", "from vertices"):
            key = f"{name}, {kind}"
            print(f"  {key:<32} V={v:>6} k={k:>4}: {1000 * median[key]:8.1f} ms")
    ratio_view = median["full, cached coefficients"] / median["low, cached coefficients"]
    ratio_old = median["full, from vertices"] / median["full, cached coefficients"]
    print(f"full / low resolution, cached coefficients: {ratio_view:.2f}x")
    print(f"full resolution, from vertices / cached coefficients: {ratio_old:.2f}x")
    return {"full_over_low": ratio_view, "vertices_over_cached": ratio_old}


if __name__ == "__main__":
    main()
