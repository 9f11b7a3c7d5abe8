"""CPU speed of SPGSN (paper design) against the public SPGSN code, and of the MLP baseline.

Run from the repository root::

    python benchmarks/speed/speed_spgsn.py [--threads N] [--repeats R] [--bf16] [--models spgsn mlp]

For each model in its registry configuration on the CMU benchmark (SPGSN: 10 blocks, hidden 256,
L = 2, K = 2, dct_n 30; 10 frames in, 25 out, 25 joints) it prints: parameters, forward FLOPs per
sample (``torch.utils.flop_counter.FlopCounterMode``), inference latency at batch 1 and 32,
training speed at batch 32 (forward, backward, gradient clipping as the recipe says, Adam step)
and the GFLOP/s achieved. Every time is the median of ``--repeats`` runs after a warm-up. The
machine is shared, so the script also prints the load average and the CPU time the process got:
wall-clock times rise when other processes take the cores.

SPGSN is measured side by side with the public SPGSN code's CMU model (``public_spgsn.py``, our
re-implementation of its computation) in the same run, their timed runs interleaved so that load
changes hit both alike. The aim (issue: at least equal training samples/s in float32 at equal or
larger forward FLOPs per sample) is printed with the ceiling the FLOPs allow: a training step
cannot take less than its counted FLOPs at the best matrix-product rate measured in this run.
``--tiny`` (one block of width 16 on both sides) checks the script quickly; it measures nothing.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch
from torch.utils.flop_counter import FlopCounterMode

import zoo
from zoo.protocol.benchmark import get_benchmark
from zoo.protocol.metrics import mpjpe

sys.path.insert(0, str(Path(__file__).resolve().parent))  # public_spgsn.py lies beside this file
from public_spgsn import forward_gflop_per_sample, make_public_step, public_batch

TRAINING_SPEED_AIM = 1.0  # times the public code's float32 training samples/s
PAPER_TABLE9_PARAMS_M = 5.66  # SPGSN paper, Table 9: H3.6M, 10 in / 10 out, dct_n 15
TRAIN_BATCH = 32
# --tiny: ours (those of these hyper-parameters that a model has) and the public code's model
TINY = {"blocks": 1, "hidden": 16}
TINY_PUBLIC = {"num_stage": 1, "hidden": 16}


def table9_params_m(name: str, **overrides) -> float:
    """Parameters (M) of registry model ``name`` in the paper's Table 9 setting: Human3.6M's 22
    used joints and body parts, 10 frames in and 10 out, 15 DCT coefficients."""
    from zoo.data.skeleton import H36M

    parts = {k: list(v) for k, v in H36M.parts.items()}
    model = zoo.create_model(
        name,
        input_frames=10,
        output_frames=10,
        num_points=len(H36M.used),
        parts=parts,
        dct_n=15,
        **overrides,
    )
    return sum(p.numel() for p in model.parameters()) / 1e6


def timed(fn: Callable[[], object], repeats: int, warmup: int = 1) -> tuple[float, float]:
    """Median wall-clock and median process CPU seconds of ``fn`` over ``repeats`` runs."""
    for _ in range(warmup):
        fn()
    walls, cpus = [], []
    for _ in range(repeats):
        wall, cpu = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
    return statistics.median(walls), statistics.median(cpus)


def timed_interleaved(
    fns: dict[str, Callable[[], object]], repeats: int
) -> dict[str, tuple[float, float]]:
    """``timed`` for several functions, their runs alternated (one warm-up each first)."""
    for fn in fns.values():
        fn()
    walls = {name: [] for name in fns}
    cpus = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            wall, cpu = time.perf_counter(), time.process_time()
            fn()
            walls[name].append(time.perf_counter() - wall)
            cpus[name].append(time.process_time() - cpu)
    return {name: (statistics.median(walls[name]), statistics.median(cpus[name])) for name in fns}


def matmul_gflops(repeats: int) -> float:
    """The best float32 matrix-product rate of this run (1024^3 and 4096 x 256 x 256, the
    scattering tree's shape; the better of the two medians)."""
    rates = []
    for m, k, n in ((1024, 1024, 1024), (4096, 256, 256)):
        a, b = torch.randn(m, k), torch.randn(k, n)
        wall, _ = timed(lambda a=a, b=b: a @ b, max(repeats, 5))
        rates.append(2 * m * k * n / wall / 1e9)
    return max(rates)


def synthetic_motion(batch: int, frames: int, points: int, seed: int) -> torch.Tensor:
    """Smooth motion in mm (timings do not depend on the values, only on the shapes)."""
    g = torch.Generator().manual_seed(seed)
    offsets = torch.randn(batch, 1, points, 3, generator=g) * 400
    return offsets + (torch.randn(batch, frames, points, 3, generator=g) * 5).cumsum(dim=1)


def measure(
    name: str, repeats: int, bf16: bool, tiny: bool = False
) -> tuple[dict[str, float], dict | None]:
    """Figures of registry model ``name``; for an SPGSN model also those of the public code's
    CMU model, timed interleaved with it on the same inputs."""
    bench = get_benchmark("cmu")
    entry = zoo.load_registry().get(name)
    overrides = {k: v for k, v in TINY.items() if k in entry.hparams} if tiny else {}
    torch.manual_seed(0)
    model = zoo.create_model(name, benchmark=bench, **overrides)
    t_in, t_out, points = bench.input_frames, bench.output_frames, len(bench.skeleton.used)
    history = synthetic_motion(TRAIN_BATCH, t_in, points, seed=1)
    future = synthetic_motion(TRAIN_BATCH, t_out, points, seed=2)
    ours: dict[str, float] = {"params_m": sum(p.numel() for p in model.parameters()) / 1e6}
    public = None
    if name.startswith("spgsn"):
        public_step, public_model = make_public_step(
            history_mm=history, future_mm=future, **(TINY_PUBLIC if tiny else {})
        )
        public_input = public_batch(history, future)[0]
        public = {
            "params_m": sum(p.numel() for p in public_model.parameters()) / 1e6,
            "gflop_per_sample": forward_gflop_per_sample(public_model),
        }
        if name == "spgsn":
            ours["table9_params_m"] = table9_params_m(name, **overrides)

    model.eval()
    with torch.no_grad():
        with FlopCounterMode(display=False) as counter:
            model(history[:1])
        ours["gflop_per_sample"] = counter.get_total_flops() / 1e9
        if public is not None:
            public_model.eval()
        for batch in (1, TRAIN_BATCH):
            runs = {"ours": lambda batch=batch: model(history[:batch])}
            if public is not None:
                runs["public"] = lambda batch=batch: public_model(public_input[:batch])
            for who, (wall, _cpu) in timed_interleaved(runs, repeats).items():
                figures = ours if who == "ours" else public
                figures[f"latency_b{batch}_ms"] = wall * 1e3
                figures[f"inference_b{batch}_gflops"] = figures["gflop_per_sample"] * batch / wall

    recipe = entry.train
    model.train()
    if public is not None:
        public_model.train()
    optimizer = torch.optim.Adam(
        model.parameters(), lr=recipe.get("lr", 1e-3), weight_decay=recipe.get("weight_decay", 0.0)
    )
    clip = recipe.get("grad_clip")

    def loss_of(autocast: bool) -> torch.Tensor:
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
            if hasattr(model, "training_loss"):
                return model.training_loss(history, future)
            return mpjpe(model(history), future).mean()

    def train_step(autocast: bool = False) -> None:
        loss = loss_of(autocast)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if clip is not None:
            torch.nn.utils.clip_grad_norm_(model.parameters(), clip)
        optimizer.step()

    with FlopCounterMode(display=False) as counter:
        loss_of(False).backward()
    optimizer.zero_grad(set_to_none=True)
    ours["train_gflop_per_step"] = counter.get_total_flops() / 1e9
    runs = {"ours": train_step}
    if public is not None:
        runs["public"] = public_step
    if bf16:
        runs["ours_bf16"] = lambda: train_step(True)
    for who, (wall, cpu) in timed_interleaved(runs, repeats).items():
        figures = public if who == "public" else ours
        prefix = "bf16_" if who == "ours_bf16" else ""
        figures[f"{prefix}train_step_b32_s"] = wall
        figures[f"{prefix}train_step_b32_cpu_s"] = cpu
        figures[f"{prefix}train_samples_per_s"] = TRAIN_BATCH / wall
    ours["train_gflops"] = ours["train_gflop_per_step"] / ours["train_step_b32_s"]
    return ours, public


def report(
    name: str, f: dict[str, float], reference: dict[str, float] | None, best_matmul_gflops: float
) -> None:
    rows = [
        ("parameters (M)", "params_m", "{:.3f}", "ours/public"),
        ("forward GFLOP per sample", "gflop_per_sample", "{:.3f}", "ours/public"),
        ("inference latency, batch 1 (ms)", "latency_b1_ms", "{:.1f}", "speed-up"),
        ("inference latency, batch 32 (ms)", "latency_b32_ms", "{:.1f}", "speed-up"),
        ("training step, batch 32 (s)", "train_step_b32_s", "{:.3f}", "speed-up"),
        ("training samples/s", "train_samples_per_s", "{:.2f}", "ours/public"),
    ]
    print(f"\n== {name} ==")
    header = f"{'':42s}{'this zoo':>12s}"
    if reference:
        header += f"{'public code':>14s}{'ratio':>10s}"
    print(header)
    for label, key, fmt, kind in rows:
        line = f"{label:42s}{fmt.format(f[key]):>12s}"
        if reference:
            ref = reference[key]
            ratio = ref / f[key] if kind == "speed-up" else f[key] / ref
            line += f"{fmt.format(ref):>14s}{ratio:>9.2f}x  ({kind})"
        print(line)
    print(f"{'training GFLOP per step (fwd + bwd, counted)':42s}{f['train_gflop_per_step']:>12.1f}")
    print(
        f"{'achieved GFLOP/s, training':42s}{f['train_gflops']:>12.1f}"
        f"  (best matrix product this run: {best_matmul_gflops:.1f})"
    )
    print(
        f"{'achieved GFLOP/s, inference batch 1 / 32':42s}"
        f"{f['inference_b1_gflops']:>12.1f} / {f['inference_b32_gflops']:.1f}"
    )
    # The FLOP-bound ceiling: every counted FLOP at the best matrix-product rate of this run.
    ceiling = TRAIN_BATCH * best_matmul_gflops / f["train_gflop_per_step"]
    print(f"{'training samples/s if every FLOP ran at best':42s}{ceiling:>12.2f}")
    cpu_share = f["train_step_b32_cpu_s"] / f["train_step_b32_s"]
    print(
        f"{'CPU seconds per training step (share)':42s}{f['train_step_b32_cpu_s']:>12.3f}"
        f"  ({cpu_share:.2f} CPU-s per wall-s)"
    )
    if "bf16_train_step_b32_s" in f:
        line = f"{'bf16 autocast training samples/s':42s}{f['bf16_train_samples_per_s']:>12.2f}"
        if reference:
            ratio = f["bf16_train_samples_per_s"] / reference["train_samples_per_s"]
            line += f"{reference['train_samples_per_s']:>14.2f}{ratio:>9.2f}x  (ours/public)"
        print(line)
    if "table9_params_m" in f:
        print(
            f"{'parameters (M), paper Table 9 setting':42s}{f['table9_params_m']:>12.3f}"
            f"{PAPER_TABLE9_PARAMS_M:>14.2f}"
            f"{f['table9_params_m'] / PAPER_TABLE9_PARAMS_M:>9.2f}x  (ours/paper)"
        )
    if reference:
        speed = f["train_samples_per_s"] / reference["train_samples_per_s"]
        flops = f["gflop_per_sample"] / reference["gflop_per_sample"]
        met = speed >= TRAINING_SPEED_AIM and flops >= 1.0
        print(
            f"aim (>= {TRAINING_SPEED_AIM}x the public float32 training samples/s at >= its "
            f"FLOPs/sample): {speed:.2f}x at {flops:.2f}x FLOPs -> "
            f"{'met' if met else 'NOT met'}; the FLOP-bound ceiling is "
            f"{ceiling / reference['train_samples_per_s']:.2f}x"
        )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--threads",
        type=int,
        default=None,
        help="torch intra-op threads (default: torch's own choice)",
    )
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per figure (median)")
    parser.add_argument(
        "--bf16", action="store_true", help="also time a training step under CPU bf16 autocast"
    )
    parser.add_argument("--models", nargs="+", default=["spgsn", "mlp"])
    parser.add_argument(
        "--tiny",
        action="store_true",
        help="tiny models (one block, width 16): a quick check of the script",
    )
    args = parser.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    load_before = os.getloadavg()
    print(
        f"machine: {os.cpu_count()} CPUs, {platform.processor() or platform.machine()}, "
        f"torch {torch.__version__}, {torch.get_num_threads()} threads, "
        f"CPU capability {torch.backends.cpu.get_cpu_capability()}"
    )
    best = matmul_gflops(args.repeats)
    print(
        f"best float32 matrix-product rate now: {best:.1f} GFLOP/s; "
        f"load average {load_before[0]:.2f}"
    )
    if load_before[0] > 0.5:
        print(
            "note: other processes are using the CPUs; wall-clock figures will be slower "
            "than on an idle machine (with more threads than free cores, much slower: "
            "try --threads 1)"
        )
    results = {name: measure(name, args.repeats, args.bf16, args.tiny) for name in args.models}
    for name, (ours, public) in results.items():
        report(name, ours, public, best)
    print(f"\nload average after: {os.getloadavg()[0]:.2f}; medians of {args.repeats} runs")


if __name__ == "__main__":
    main()
