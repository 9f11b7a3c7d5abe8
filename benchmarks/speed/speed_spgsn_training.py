"""SPGSN's training step on this CPU: samples/s for float32 and bfloat16, 1 and 2 threads, eager
and compiled, beside the public SPGSN code's float32 step, all in one run; then where the time
of each eager step goes.

Run from the repository root, with nothing else computing::

    python benchmarks/speed/speed_spgsn_training.py [--repeats 5] [--no-compile]

The step is the engine's (:func:`zoo.train.step.training_step`: the model's training loss in the
recipe's precision, backward, the recipe's gradient clip, Adam) at the recipe's batch of 32, on
smooth synthetic motion (a step's time does not depend on the values). Each figure is the
median of ``--repeats`` steps after warm-up steps, the configurations of one thread count timed
interleaved so that a change of load hits them alike. "compiled" is ``torch.compile`` (inductor,
default options) of the model; its compile time is printed, not counted. bfloat16 is an autocast
with float32 master weights, as ``zoo train`` runs it; on a CPU without ``avx512_bf16`` or AMX
it runs on a slow fallback (printed). ``--tiny`` (one block of width 16, batch 4): a check of the
script; it measures nothing.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import torch

import zoo
from zoo.models.recipe import training_recipe
from zoo.protocol.benchmark import get_benchmark
from zoo.train.host import cpu_has_native_bfloat16
from zoo.train.step import TrainingObjective, make_optimizer, training_step

sys.path.insert(0, str(Path(__file__).resolve().parent))  # scripts beside this one
from public_spgsn import make_public_step
from speed_spgsn import TINY, TINY_PUBLIC, TRAIN_BATCH, synthetic_motion, timed_interleaved

THREADS = (1, 2)
PRECISIONS = ("float32", "bfloat16")
TOP_OPS = 8
TINY_BATCH = 4  # --tiny checks the script, not a rate: 4 windows run every path 32 do


def make_step(precision: str, compiled: bool, tiny: bool, batch: int):
    """One engine training step of a fresh seeded SPGSN in ``precision`` on ``batch`` windows
    (a closure), and the compile time where ``compiled``."""
    bench = get_benchmark("cmu")
    entry = zoo.load_registry().get("spgsn")
    recipe = training_recipe(entry.train, {"precision": precision})
    torch.manual_seed(0)
    model = zoo.create_model("spgsn", benchmark=bench, **(TINY if tiny else {}))
    model.train()
    t_in, t_out, points = bench.input_frames, bench.output_frames, len(bench.skeleton.used)
    history = synthetic_motion(batch, t_in, points, seed=1)
    future = synthetic_motion(batch, t_out, points, seed=2)
    objective = TrainingObjective(model)
    optimizer = make_optimizer(model, recipe, "cpu")
    net = torch.compile(objective) if compiled else objective

    def step():
        return training_step(net, model, optimizer, history, future, recipe, "cpu")

    seconds = 0.0
    if compiled:  # the first call compiles
        started = time.perf_counter()
        step()
        seconds = time.perf_counter() - started
    return step, seconds


def where_time_goes(step, label: str, steps: int = 2) -> None:
    """The operators that take the most of one step's time (self CPU time over ``steps``)."""
    from torch.profiler import ProfilerActivity, profile

    step()
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(steps):
            step()
    events = sorted(prof.key_averages(), key=lambda e: e.self_cpu_time_total, reverse=True)
    total = sum(e.self_cpu_time_total for e in events)
    shares = ", ".join(f"{e.key} {e.self_cpu_time_total / total:.0%}" for e in events[:TOP_OPS])
    print(f"  {label}: {shares}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5, help="timed steps per figure (median)")
    parser.add_argument("--no-compile", action="store_true", help="eager steps only")
    parser.add_argument("--tiny", action="store_true", help="a quick check: measures nothing")
    args = parser.parse_args(argv)
    native = cpu_has_native_bfloat16()
    print(
        f"machine: {os.cpu_count()} CPUs, CPU capability "
        f"{torch.backends.cpu.get_cpu_capability()}, native bfloat16 "
        f"{'yes' if native else 'no (slow fallback)'}, torch {torch.__version__}; load average "
        f"{os.getloadavg()[0]:.2f}"
    )
    modes = [False] if args.no_compile else [False, True]
    batch = TINY_BATCH if args.tiny else TRAIN_BATCH
    steps, compile_seconds = {}, {}
    for precision in PRECISIONS:
        for compiled in modes:
            label = f"{precision} {'compiled' if compiled else 'eager'}"
            steps[label], compile_seconds[label] = make_step(precision, compiled, args.tiny, batch)
    public_step, _ = make_public_step(batch_size=batch, **(TINY_PUBLIC if args.tiny else {}))
    steps["public code, float32 eager"] = public_step
    rates: dict[tuple[str, int], float] = {}
    for threads in THREADS:
        torch.set_num_threads(threads)
        for label, (wall, _cpu) in timed_interleaved(steps, args.repeats).items():
            rates[label, threads] = batch / wall
    public = {t: rates["public code, float32 eager", t] for t in THREADS}
    print(f"\ntraining samples/s, batch {batch} (median of {args.repeats} steps):")
    header = "".join(f"{f'{t} thread' + ('s' if t > 1 else ''):>12s}" for t in THREADS)
    print(f"{'':32s}{header}{'x public, 2 threads':>22s}")
    for label in steps:
        cells = "".join(f"{rates[label, t]:12.2f}" for t in THREADS)
        ratio = rates[label, THREADS[-1]] / public[THREADS[-1]]
        note = f"  (compile {compile_seconds[label]:.0f} s)" if compile_seconds.get(label) else ""
        print(f"{label:32s}{cells}{ratio:21.2f}x{note}")
    print("\nwhere the time goes (share of the step's self CPU time, 2 threads):")
    for label in ("float32 eager", "bfloat16 eager"):
        where_time_goes(steps[label], label, steps=1 if args.tiny else 2)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
