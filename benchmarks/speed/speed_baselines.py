"""LTD and PGBIG training steps with the zoo's dropout against torch's, side by side.

On the CMU baselines' small graph networks torch's ``nn.Dropout`` draws one random number per
element on a CPU, which cost more than their matrix products; ``zoo.models.dropout.Dropout``
draws four 16-bit numbers per 64-bit word. Both are timed here in one run, on the same model
(the dropout modules swapped in place), with a mask timing alone first: a batch of 16 CMU
windows (10 observed + 25 predicted frames, 25 joints), the model's training loss, backward,
gradient clip and an Adam step, in float32. Step times are medians of ``--repeats`` steps, the
two kinds timed in turn so they share the machine's load.

Run: python benchmarks/speed/speed_baselines.py [--repeats 9] [--threads 1]
(``--tiny``: narrow models, a check of the script.)
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from torch import nn

from zoo.models.dropout import Dropout
from zoo.models.ltd import LTD
from zoo.models.pgbig import PGBIG

BATCH, T_IN, T_OUT, POINTS = 16, 10, 25, 25


def swap_dropout(model: nn.Module, kind: str) -> None:
    """Every dropout module of ``model`` as ``kind``: ``zoo`` or ``torch`` (same probability)."""
    for module in list(model.modules()):
        for name, child in module.named_children():
            if isinstance(child, (Dropout, nn.Dropout)):
                setattr(module, name, Dropout(child.p) if kind == "zoo" else nn.Dropout(child.p))


def step_time(model: nn.Module, repeats: int) -> float:
    g = torch.Generator().manual_seed(0)
    history = 100 * torch.randn(BATCH, T_IN, POINTS, 3, generator=g)
    future = 100 * torch.randn(BATCH, T_OUT, POINTS, 3, generator=g)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-6)
    model.train()
    times = []
    for i in range(repeats + 1):  # the first is a warm-up
        started = time.perf_counter()
        loss = model.training_loss(history, future)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimizer.step()
        if i:
            times.append(time.perf_counter() - started)
    return 1000 * statistics.median(times)


def mask_time(layer: nn.Module, x: torch.Tensor, repeats: int) -> float:
    layer.train()
    layer(x)
    started = time.perf_counter()
    for _ in range(repeats):
        layer(x)
    return 1000 * (time.perf_counter() - started) / repeats


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--tiny", action="store_true", help="narrow models (a script check)")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    hidden = 16 if args.tiny else 256
    x = torch.randn(BATCH, 3 * POINTS, hidden)
    ours = mask_time(Dropout(0.5), x, 10 * args.repeats)
    theirs = mask_time(nn.Dropout(0.5), x, 10 * args.repeats)
    print(
        f"dropout of a {tuple(x.shape)} tensor, {args.threads} thread(s): torch {theirs:.3f} ms, "
        f"zoo {ours:.3f} ms, ratio {theirs / ours:.1f}x"
    )
    models = {
        "ltd": LTD(T_IN, T_OUT, POINTS, hidden=hidden, blocks=2 if args.tiny else 12),
        "pgbig": PGBIG(T_IN, T_OUT, POINTS, d_model=4 if args.tiny else 16),
    }
    for name, model in models.items():
        timings = {"torch": [], "zoo": []}
        for _ in range(2):  # in turn, so both see the same load
            for kind in timings:
                swap_dropout(model, kind)
                timings[kind].append(step_time(model, args.repeats))
        slow, fast = min(timings["torch"]), min(timings["zoo"])
        print(
            f"{name} training step, batch {BATCH}, float32: torch dropout {slow:.1f} ms, "
            f"zoo dropout {fast:.1f} ms, ratio {slow / fast:.2f}x"
        )


if __name__ == "__main__":
    main()
