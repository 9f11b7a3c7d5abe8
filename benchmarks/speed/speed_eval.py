"""Evaluation speed on every window of the CMU test files (sampler `all`).

Prints windows per second of the zoo's evaluator (batched windows, batched errors) and, side by
side in the same run, of a per-window loop doing the same work, with their ratio.
Run: python benchmarks/speed/speed_eval.py [--data-root ../shared/data/cmu_mocap]
"""

import argparse
import statistics
import time

import torch

import zoo
from zoo.data.windows import gather_windows, window_sampler
from zoo.protocol.benchmark import get_benchmark
from zoo.protocol.metrics import skeleton_errors


def per_window_loop(dataset, bench, model):
    """The same windows and errors, one window at a time (what a naive evaluator does)."""
    t_in, t_out = bench.input_frames, bench.output_frames
    seqs = dataset.sequences
    index = window_sampler("all", [len(s) for s in seqs], t_in, t_out)
    used = list(dataset.skeleton.used)
    positions = [s.positions for s in seqs]
    total = 0.0
    with torch.no_grad():
        for row in index:
            w = torch.from_numpy(gather_windows(positions, row[None], t_in + t_out))
            pred = model(w[:, :t_in, used])
            total += sum(
                e.sum().item()
                for e in skeleton_errors(pred, w[:, t_in:], dataset.skeleton).values()
            )
    return len(index)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--data-root")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--threads",
        type=int,
        default=None,
        help="torch threads (default: torch's own choice; on a loaded machine "
        "--threads 1 gives steadier figures)",
    )
    args = parser.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    bench = get_benchmark("cmu")
    t0 = time.perf_counter()
    dataset = bench.load(args.data_root)
    load_s = time.perf_counter() - t0
    model = zoo.create_model("repeat_last", benchmark=bench)
    zoo_times, loop_times = [], []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        result = zoo.evaluate(model, bench, label="repeat_last", sampler="all", dataset=dataset)
        zoo_times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        n_loop = per_window_loop(dataset, bench, model)
        loop_times.append(time.perf_counter() - t0)
    windows = sum(result.protocol["windows_per_action"].values())
    assert windows == n_loop
    zoo_s, loop_s = statistics.median(zoo_times), statistics.median(loop_times)
    print(f"CMU test files: {len(dataset.sequences)} files, load + FK {load_s:.2f} s")
    print(f"sampler all: {windows} windows of {bench.input_frames}+{bench.output_frames} frames")
    print(
        f"zoo evaluator    : {zoo_s:.3f} s  ({windows / zoo_s:,.0f} windows/s, "
        f"both joint protocols, both averagings)"
    )
    print(f"per-window loop  : {loop_s:.3f} s  ({windows / loop_s:,.0f} windows/s)")
    print(f"ratio            : {loop_s / zoo_s:.1f}x faster (median of {args.repeats})")


if __name__ == "__main__":
    main()
