"""How many times its measured rounding sensitivity another machine's rounding moves a window.

``zoo leaderboard --check`` holds a window beyond the a-priori tolerance to ``SENSITIVITY_MULTIPLE``
times its rounding sensitivity (:mod:`zoo.leaderboard.rounding`: the largest change of its errors
over a float64 pass and two passes on inputs moved by two units in the last place). This measures,
on committed rows and a sample of their windows, how far a stand-in for another CPU moves each
window's errors (the row's model on inputs moved by two units in the last place with other draws:
data built elsewhere differs in its last bits) as a multiple of that sensitivity, measured here as
the check measures it, and how many windows that stand-in moves beyond the a-priori tolerance at
all; and the same for the real other machine: the stored rows, written on another CPU (on a
generated mesh, from data built there: ``data_hash``).

    python benchmarks/check/rounding_multiple.py --benchmark cmu --windows 256
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from zoo.evaluation.evaluator import Scored, evaluate_models
from zoo.evaluation.results import WINDOWS_FILE, WindowErrors
from zoo.evaluation.tolerance import allowed
from zoo.leaderboard.plan import Leaderboard, Plan
from zoo.leaderboard.rounding import SENSITIVITY_MULTIPLE, rounding_sensitivity, with_inputs_moved
from zoo.leaderboard.verdict import CheckReport
from zoo.paths import REPO_ROOT

OTHER_MACHINES = (98, 99)  # draws of the stand-in for another CPU, not the check's own


def _per_window(values: np.ndarray) -> np.ndarray:
    return values.reshape(len(values), -1).max(axis=1)


def measure(
    benchmark: str, windows: int, seed: int, only: str | None = None, positions=None
) -> list[dict]:
    board = Leaderboard.of(
        benchmark,
        weights=REPO_ROOT / "weights",
        plan=Plan(check=CheckReport(windows=windows, seed=seed)),
    )
    out = []
    for sampler, task, truth, folder in board.tables():
        if only is not None and folder != only:
            continue
        table = board.plan_table(sampler, task, truth, folder)
        if table is None or not (table.path / "leaderboard.md").is_file():
            continue
        chosen = table.sample if positions is None else np.asarray(positions)
        protocol = table.protocol.subset(chosen)
        for r in table.rows:
            if r.loaded is None:
                continue
            model, label, view = r.loaded.model, r.row.label, r.loaded.view
            started = time.perf_counter()
            variants = [model, *(with_inputs_moved(model, s) for s in OTHER_MACHINES)]
            results = evaluate_models([Scored(v, label, view) for v in variants], protocol)
            if any(isinstance(x, Exception) for x in results):
                print(f"{table.where}: {label}: a pass failed, skipped", file=sys.stderr)
                continue
            fresh = results[0].windows.errors
            # as the check measures it (one value a window)
            measured = rounding_sensitivity(model, label, view, protocol, results[0].windows)
            stored = WindowErrors.read(table.path / label / WINDOWS_FILE).errors
            ratios, relevant, beyond, real, real_share = [], [], 0, [], 0.0
            for key, values in fresh.items():
                base = values.astype(np.float64)

                def change(result, key=key, base=base):
                    return np.abs(result.windows.errors[key].astype(np.float64) - base)

                sensitivity = _per_window(measured[key])
                if positions is not None:  # the windows asked for: their own figures
                    for at, s in zip(chosen, sensitivity):
                        print(f"  {label} {'/'.join(key)} window {at}: sensitivity {s:.2g}")
                there = stored[key][chosen].astype(np.float64)
                moved = np.abs(there - base)
                share = _per_window(moved / allowed(key[1], there))
                real_share = max(real_share, float(np.nanmax(share, initial=0.0)))
                with np.errstate(divide="ignore", invalid="ignore"):  # where it matters
                    real.append((_per_window(moved) / sensitivity)[share > 1])
                for other in results[1:]:
                    moved = change(other)
                    outside = (moved > allowed(key[1], base)).reshape(len(base), -1).any(axis=1)
                    beyond += int(outside.sum())
                    per_window = _per_window(moved)
                    with np.errstate(divide="ignore", invalid="ignore"):
                        ratio = np.where(per_window > 0, per_window / sensitivity, 0.0)
                    ratios.append(ratio)
                    relevant.append(ratio[outside])
            ratios, relevant = np.concatenate(ratios), np.concatenate(relevant)
            out.append(
                {
                    "table": table.where,
                    "row": label,
                    "windows": len(protocol.index),
                    "beyond_a_priori": beyond,
                    "largest_ratio": float(ratios.max(initial=0.0)),
                    "p99_ratio": float(np.percentile(ratios, 99)) if ratios.size else 0.0,
                    "largest_ratio_beyond": float(relevant.max(initial=0.0)),
                    "stored_share": real_share,
                    "stored_beyond": int(sum(len(r) for r in real)),
                    "stored_ratio": float(np.concatenate(real).max(initial=0.0)),
                    "seconds": time.perf_counter() - started,
                }
            )
            o = out[-1]
            print(
                f"{table.where}: {label}: the stand-in's change / the measured sensitivity: "
                f"largest {o['largest_ratio']:.2f}, 99th percentile {o['p99_ratio']:.2f}; "
                f"{beyond} window-series of {len(OTHER_MACHINES) * len(fresh) * o['windows']} "
                f"beyond the a-priori tolerance, largest ratio there "
                f"{o['largest_ratio_beyond']:.2f}; the stored row (another machine): up to "
                f"{o['stored_share']:.2f} of the a-priori tolerance, {o['stored_beyond']} "
                f"window-series beyond it, at most {o['stored_ratio']:.2f} times their "
                f"sensitivity ({o['seconds']:.0f} s)",
                flush=True,
            )
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--benchmark", action="append", required=True)
    parser.add_argument("--windows", type=int, default=256)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--table", help="one table folder (all, all-gt_spectral, ...)")
    parser.add_argument(
        "--positions", type=int, nargs="+", help="these windows (stored positions) alone"
    )
    args = parser.parse_args(argv)
    rows = [
        r
        for b in args.benchmark
        for r in measure(b, args.windows, args.seed, args.table, args.positions)
    ]
    largest = max((r["largest_ratio"] for r in rows), default=float("nan"))
    beyond = max((r["largest_ratio_beyond"] for r in rows), default=float("nan"))
    count = sum(r["beyond_a_priori"] for r in rows)
    stored_share = max((r["stored_share"] for r in rows), default=float("nan"))
    stored_ratio = max((r["stored_ratio"] for r in rows), default=float("nan"))
    print(
        f"{len(rows)} rows: the stand-in moved a window by at most {largest:.2f} times its "
        f"measured rounding sensitivity; {count} window-series beyond the a-priori tolerance, "
        f"by at most {beyond:.2f} times it; the stored rows sit up to {stored_share:.2f} of "
        f"the a-priori tolerance away (beyond it: at most {stored_ratio:.2f} times the "
        f"sensitivity; the check allows {SENSITIVITY_MULTIPLE:g} times it)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
