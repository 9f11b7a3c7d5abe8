"""A registered model's training step, eager against ``torch.compile``'d as ``zoo train --compile``
runs it, timed side by side in one process.

Both steps are the engine's (``zoo.train.step.training_step`` on its ``TrainingObjective``), on
the same random batch of CMU-shaped windows in mm, at the model's registry batch size, with
Adam; the compiled one first compiles (its time is printed, not counted), then the two run in
turn, ``--repeats`` pairs, so that a change of the machine's load hits both alike. The script
prints each side's median seconds a step and the ratio.

Run: python benchmarks/speed/speed_compile.py --model ggmotion [--repeats 3] [--batch N]
     [--backend inductor] [--threads 1]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import torch

import zoo
from zoo.models.recipe import training_recipe
from zoo.train.step import TrainingObjective, make_optimizer, training_step


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", required=True, help="a registered joints model")
    parser.add_argument("--repeats", type=int, default=3, help="timed pairs of steps (median)")
    parser.add_argument("--batch", type=int, help="default: the registry recipe's")
    parser.add_argument("--backend", default="inductor", help="torch.compile's backend")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="model hyper-parameter (integers), e.g. a smaller model")  # fmt: skip
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    entry = zoo.load_registry().get(args.model)
    recipe = training_recipe(entry.train)
    batch = args.batch or recipe.batch_size
    overrides = {k: int(v) for k, v in (item.split("=", 1) for item in args.set)}
    torch.manual_seed(0)
    g = torch.Generator().manual_seed(1)
    body = 300 * torch.randn(batch, 1, 25, 3, generator=g)
    windows = body + 10 * torch.randn(batch, 35, 25, 3, generator=g).cumsum(dim=1)
    history, future = windows[:, :10], windows[:, 10:]
    steps, compiled_in = {}, 0.0
    for name in ("eager", "compiled"):
        model = zoo.create_model(args.model, benchmark="cmu", **overrides).train()
        objective = TrainingObjective(model)
        if name == "compiled":
            objective = torch.compile(objective, backend=args.backend)
        optimizer = make_optimizer(model, recipe, "cpu")

        def step(objective=objective, model=model, optimizer=optimizer):
            training_step(objective, model, optimizer, history, future, recipe, "cpu")

        started = time.perf_counter()
        step()  # the compiled side compiles here; the eager one warms up
        if name == "compiled":
            compiled_in = time.perf_counter() - started
        steps[name] = step
    times = {name: [] for name in steps}
    for _ in range(args.repeats):
        for name, step in steps.items():
            started = time.perf_counter()
            step()
            times[name].append(time.perf_counter() - started)
    eager, compiled = (statistics.median(times[n]) for n in ("eager", "compiled"))
    print(
        f"{args.model} training step, batch {batch}, {args.threads} thread(s), float32: eager "
        f"{eager:.3f} s, compiled ({args.backend}) {compiled:.3f} s, speed-up "
        f"{eager / compiled:.2f}x; compiling took {compiled_in:.0f} s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
