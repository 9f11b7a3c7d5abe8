"""One evaluation pass for all of a table's rows against one pass per row, side by side.

``zoo leaderboard`` (and its ``--check``) scores every row of a table in one pass over the windows
(:func:`zoo.evaluation.evaluator.evaluate_models`): each batch of ground truth, with what it alone
gives (on a mesh benchmark its spectral reconstruction, the reference frame's edge lengths, its own
MELV, its regressed joints), is made once for all the models. Here the same rows are timed both ways
in one run, on the first ``--windows`` windows of a table, each way in turn and ``--repeats`` times
(medians), and the results of both ways are checked equal.

Run: python benchmarks/speed/speed_pass.py [--benchmark cmu_anny_oi_low] [--truth spectral]
     [--windows 116] [--repeats 3] [--threads 1] [--data-root DIR] [--weights DIR]
The rows are the leaderboard's own (shipped weights, no checkpoints).
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from zoo.evaluation.evaluator import Scored, evaluate_models
from zoo.protocol.benchmark import get_benchmark
from zoo.protocol.plan import plan_protocol


def table_models(bench, data_root=None, weights=None) -> tuple[object, list[Scored]]:
    """The dataset and the rows of the benchmark's leaderboard (shipped weights from
    ``weights``, default the repository's; no checkpoints), as ``zoo leaderboard`` loads them."""
    from zoo.evaluation.pipeline import Subject
    from zoo.leaderboard.plan import Leaderboard, Plan
    from zoo.models.registry import load_registry
    from zoo.paths import REPO_ROOT

    board = Leaderboard(
        bench=bench,
        registry=load_registry(),
        root=REPO_ROOT / "results",
        weights=Path(weights) if weights else REPO_ROOT / "weights",
        checkpoints=None,
        device="cpu",
        plan=Plan(),
        data_root=data_root,
    )
    models = []
    for row in board.rows("prediction"):
        models.append(Subject.of_loaded(board.load(row)).scored())
    return board.dataset, models


def timed(run) -> tuple[float, list]:
    started = time.perf_counter()
    out = run()
    return time.perf_counter() - started, out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--benchmark", default="cmu_anny_oi_low")
    parser.add_argument("--truth", default=None, help="ground truth (mesh benchmarks)")
    parser.add_argument("--windows", type=int, default=116)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--data-root", default=None, help="dataset folder")
    parser.add_argument("--weights", default=None, help="shipped weights folder")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    bench = get_benchmark(args.benchmark)
    dataset, models = table_models(bench, args.data_root, args.weights)
    protocol = plan_protocol(bench, dataset, ground_truth=args.truth)
    protocol = dataclasses.replace(
        protocol, index=protocol.index[: args.windows], actions=protocol.actions[: args.windows]
    )
    print(
        f"{bench.name}, ground truth {protocol.ground_truth or '-'}: {len(models)} rows "
        f"({', '.join(m.name for m in models)}) on {len(protocol.index)} windows, "
        f"{args.threads} thread(s)"
    )
    one, each = [], []
    for _ in range(args.repeats):
        seconds, together = timed(lambda: evaluate_models(models, protocol))
        one.append(seconds)
        seconds, apart = timed(lambda: [evaluate_models([m], protocol)[0] for m in models])
        each.append(seconds)
    for a, b in zip(together, apart):
        for failed in (a, b):
            if isinstance(failed, Exception):
                raise failed
        for key, errors in a.windows.errors.items():
            if not np.array_equal(errors, b.windows.errors[key]):
                raise SystemExit(f"{key}: one pass and a pass per row differ")
    one, each = statistics.median(one), statistics.median(each)
    print(
        f"one pass for all rows: {one:.1f} s; a pass per row: {each:.1f} s; ratio "
        f"{each / one:.2f}x (medians of {args.repeats}; per-window errors of both equal)"
    )


if __name__ == "__main__":
    main()
