"""How long ``zoo leaderboard --check`` takes, per benchmark, against the models' own arithmetic.

For each benchmark with committed tables this runs ``zoo leaderboard --check --benchmark NAME``
(its default sample of every table's windows, or ``--windows N`` / ``--full``, one seed for the
run; run it once first so datasets and bases are cached: this times the warm check) and prints,
side by side in the same run:

- the check's wall time;
- its arithmetic floor: every checked row's forward GFLOPs per window (``costs.json``) times the
  windows it is scored on, over this machine's float32 matrix-product rate measured here;
- their ratio: how far the check is above what its models' forward passes cost at best;
- with ``--against-full``, the same benchmark checked on every window, and how many times
  faster the sampled check is.

A ratio near 1 says the check is the models' arithmetic and only a faster CPU (or fewer rows)
makes it shorter; a large ratio says the check's own work (data, ground truth, scoring) is what
to make faster.

Run: python benchmarks/speed/speed_check.py [--benchmark NAME ...] [--results results]
     [--windows N | --full] [--seed S] [--against-full] [--data-root PATH] [--weights weights]
     [--checkpoints checkpoints]
"""

import argparse
import contextlib
import io
import json
import time
from pathlib import Path

import numpy as np
import torch

from zoo.cli import main as zoo_main
from zoo.cli.common import committed_benchmarks
from zoo.evaluation.results import WINDOWS_FILE, WindowErrors
from zoo.leaderboard.verdict import CHECK_WINDOWS, fresh_seed


def matmul_gflops(size: int = 1024, repeats: int = 10) -> float:
    """This machine's float32 matrix-product rate at torch's current thread count."""
    a, b = torch.randn(size, size), torch.randn(size, size)
    torch.mm(a, b)
    started = time.perf_counter()
    for _ in range(repeats):
        torch.mm(a, b)
    return 2 * size**3 * repeats / (time.perf_counter() - started) / 1e9


def forward_gflop(results: Path, benchmark: str, windows: int | None = None) -> float:
    """Forward GFLOPs of every committed row of ``benchmark``: per-window cost times the windows
    checked (``windows`` a table, or every one)."""
    costs_file = results / benchmark / "costs.json"
    costs = json.loads(costs_file.read_text())["rows"] if costs_file.is_file() else {}
    total = 0.0
    for windows_file in sorted((results / benchmark).glob(f"*/*/{WINDOWS_FILE}")):
        label = windows_file.parent.name
        per_window = (costs.get(label) or {}).get("gflop_per_sample") or 0.0
        count = len(WindowErrors.read(windows_file).start)
        total += per_window * (count if windows is None else min(windows, count))
    return total


def timed_check(name: str, results: Path, passed: list[str]) -> tuple[float, int, str, str]:
    """``zoo leaderboard --check --benchmark NAME`` run here: seconds, exit code, output."""
    out, err = io.StringIO(), io.StringIO()
    started = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = zoo_main(
            ["leaderboard", "--check", "--benchmark", name, "--out", str(results), *passed]
        )
    return time.perf_counter() - started, code, out.getvalue(), err.getvalue()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--benchmark", action="append", help="default: every committed one")
    parser.add_argument("--results", default="results", help="results root (default results/)")
    parser.add_argument("--data-root", help="dataset folder (default: each benchmark's)")
    parser.add_argument("--weights", help="shipped weights folder (default weights/)")
    parser.add_argument("--checkpoints", help="checkpoints folder (default checkpoints/)")
    parser.add_argument("--windows", type=int, help=f"sample a table (default {CHECK_WINDOWS})")
    parser.add_argument("--full", action="store_true", help="every window of every table")
    parser.add_argument("--seed", type=int, help="the samples' seed (default: drawn, printed)")
    parser.add_argument(
        "--against-full", action="store_true", help="also time the check on every window"
    )
    args = parser.parse_args(argv)
    seed = args.seed if args.seed is not None else fresh_seed()
    windows = None if args.full else (args.windows or CHECK_WINDOWS)
    sample = ["--full"] if windows is None else ["--windows", str(windows), "--seed", str(seed)]
    passed = [*(["--data-root", args.data_root] if args.data_root else [])]
    passed += ["--weights", args.weights] if args.weights else []
    passed += ["--checkpoints", args.checkpoints] if args.checkpoints else []
    results = Path(args.results)
    names = args.benchmark or committed_benchmarks(results)
    rate = matmul_gflops()
    print(f"float32 matrix products here: {rate:.1f} GFLOP/s ({torch.get_num_threads()} threads)")
    print(
        "check: every window"
        if windows is None
        else f"check: {windows} windows a table, seed {seed}"
    )
    full_head = f" {'full s':>9} {'faster':>7}" if args.against_full else ""
    print(f"{'benchmark':<18} {'check s':>9} {'floor s':>9} {'ratio':>7}{full_head}  verdict")
    total = 0.0
    for name in names:
        seconds, code, out, err = timed_check(name, results, [*sample, *passed])
        total += seconds
        floor = forward_gflop(results, name, windows) / rate
        ratio = seconds / floor if floor > 0 else np.inf
        said = (out + err).strip().splitlines() or [""]
        verdict = "passed" if code == 0 else f"exit {code}: {said[-1]}"
        full = ""
        if args.against_full:
            full_seconds, *_ = timed_check(name, results, ["--full", *passed])
            full = f" {full_seconds:>9.1f} {full_seconds / seconds:>7.1f}"
        print(f"{name:<18} {seconds:>9.1f} {floor:>9.1f} {ratio:>7.1f}{full}  {verdict}")
        for line in out.splitlines():  # the check's own line per table
            if line.startswith(f"{name}/"):
                print(f"    {line}")
    print(f"{'all':<18} {total:>9.1f}")


if __name__ == "__main__":
    main()
