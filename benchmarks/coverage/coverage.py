"""Coverage of the intervals the tables print, measured: synthetic recordings (short memory;
long memory with heavy tails), paired differences, the bold rule's family-wise error, and real
data (CMU's training recordings as pseudo test sets of one recording per action; cloth_full's
4,000 test recordings as pseudo test sets of cloth's 100). Writes ``zoo/stats/coverage.yaml``, which
the tables quote, with ``--write``.

    python benchmarks/coverage/coverage.py --write            # everything (minutes)
    python benchmarks/coverage/coverage.py --only synthetic --repetitions 200
    python benchmarks/coverage/coverage.py --lengths          # coverage against length
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

import zoo
from zoo.stats.intervals import (
    BLOCK_WINDOWS,
    best_set,
    block_replicates,
    interval,
    protocol_mean,
    recording_interval,
    window_sampling_interval,
)

WINDOW = 35  # CMU: 10 observed + 25 predicted frames
CMU_COUNTS = (255, 1009, 48, 265, 146, 1343)  # windows per test recording under ``all``
HORIZONS_MS = (80, 400, 1000)
REPLICATES = 1000


@dataclass
class Windows:
    """Just what the intervals read of a :class:`zoo.evaluation.results.WindowErrors`."""

    sequence: np.ndarray
    start: np.ndarray
    action: np.ndarray
    window_frames: int
    sequences: list


def frame_noise(rng, frames: int, memory: str) -> np.ndarray:
    """Per-frame error noise: ``short`` iid Gaussian; ``long`` AR(1) at 0.98 per frame (about
    50 frames of memory, beyond a 35-frame window) driven by Student-t(3) shocks (heavy tails,
    excess kurtosis like real per-window errors')."""
    if memory == "short":
        return rng.standard_normal(frames)
    burn = 500
    shocks = rng.standard_t(3, frames + burn)
    return lfilter([1.0], [1.0, -0.98], shocks)[burn:] / 10.0


def window_errors(rng, n: int, memory: str) -> np.ndarray:
    """Errors of ``n`` stride-1 windows of one recording: a window's error is the mean of its
    frames' noise, so neighbouring windows share 34 of 35 frames, as CMU's do."""
    noise = frame_noise(rng, n + WINDOW - 1, memory)
    return np.convolve(noise, np.ones(WINDOW) / np.sqrt(WINDOW), mode="valid")


def synthetic_table(rng, memory: str, models: int = 1, counts=CMU_COUNTS):
    """One recording per action with CMU's window counts; ``models`` models whose errors share
    a component (hard windows are hard for all) and have their own, all of true mean 20."""
    sequence = np.concatenate([np.full(n, i) for i, n in enumerate(counts)])
    start = np.concatenate([np.arange(n) for n in counts])
    action = np.array([f"a{i}" for i in sequence])
    shared = np.concatenate([window_errors(rng, n, memory) for n in counts])
    errors = [
        (20.0 + 5 * shared + 3 * np.concatenate([window_errors(rng, n, memory) for n in counts]))[
            :, None
        ]
        for _ in range(models)
    ]
    windows = Windows(sequence, start, action, WINDOW, [f"r{i}" for i in range(len(counts))])
    return errors, windows


def synthetic_coverage(repetitions: int, memory: str, seed: int = 0) -> dict[str, float]:
    """Coverage of the window-sampling interval of one model's mean (truth 20) and of a paired
    difference (truth 0)."""
    rng = np.random.default_rng(seed)
    single = paired = 0
    for r in range(repetitions):
        (a, b), w = synthetic_table(rng, memory, models=2)
        i = interval(a, w, replicates=REPLICATES, seed=r)
        single += bool(i.lo[0] <= 20.0 <= i.hi[0])
        d = interval(a - b, w, replicates=REPLICATES, seed=r)
        paired += bool(d.lo[0] <= 0.0 <= d.hi[0])
    return {"single": single / repetitions, "paired": paired / repetitions}


def bold_error(repetitions: int, models: int = 7, seed: int = 0) -> dict[str, float]:
    """Family-wise error of the bold rule among ``models`` equally good models (short-memory
    process): how often at least one is left unbolded; and of the rule it replaces (each model's
    paired 95% percentile interval against the data's best, uncorrected)."""
    rng = np.random.default_rng(seed)
    simultaneous = unadjusted = 0
    for r in range(repetitions):
        errors, w = synthetic_table(rng, "short", models=models)
        named = {f"m{i}": e for i, e in enumerate(errors)}
        bold = best_set(named, w, replicates=REPLICATES, seed=r)
        simultaneous += not all(bool(v[0]) for v in bold.values())
        reps = {
            m: block_replicates(
                e, w.sequence, w.start, w.action, BLOCK_WINDOWS * WINDOW, REPLICATES, r, WINDOW
            ).mean[:, 0]
            for m, e in named.items()
        }
        means = {m: protocol_mean(e, w.action)[0] for m, e in named.items()}
        best = min(means, key=means.get)
        for m in named:
            if m != best:
                lo, hi = np.percentile(reps[m] - reps[best], [2.5, 97.5])
                if not lo <= 0 <= hi:
                    unadjusted += 1
                    break
    return {"fwe": simultaneous / repetitions, "fwe_unadjusted": unadjusted / repetitions}


def recording_coverage(repetitions: int, per_action: int, seed: int = 0) -> float:
    """Coverage of the recording-level t interval with ``per_action`` recordings per action (6
    actions, 100-300 windows each, a heavy-tailed recording effect), truth the process mean."""
    rng = np.random.default_rng(seed)
    covered = 0
    for _ in range(repetitions):
        counts = rng.integers(100, 300, size=6 * per_action)
        sequence = np.concatenate([np.full(n, i) for i, n in enumerate(counts)])
        action = np.array([f"a{i // per_action}" for i in sequence])
        effect = rng.standard_t(3, len(counts))[sequence]
        noise = np.concatenate([window_errors(rng, n, "short") for n in counts])
        errors = (20.0 + 4 * effect + 2 * noise)[:, None]
        i = recording_interval(errors, sequence, action)
        covered += bool(i.lo[0] <= 20.0 <= i.hi[0])
    return covered / repetitions


def _load_windows(folder: Path, model: str, metric: str, joints: str):
    from zoo.evaluation.results import EvalResult

    result = EvalResult.read(folder)
    return result.windows, result.windows.get(model, metric, joints).astype(np.float64)


def cloth_coverage(sets: int, root: Path, seed: int = 0) -> dict:
    """Pseudo cloth test sets: 100 of cloth_full's 4,000 test recordings (one window each),
    the interval of repeat_last's and spectrhums' RMSE and of their difference against the
    4,000 recordings' mean, at ``HORIZONS_MS``."""
    folder = root / "results" / "cloth_full" / "all"
    windows, a = _load_windows(folder / "repeat_last", "repeat_last", "rmse", "vertices")
    _, b = _load_windows(folder / "spectrhums", "spectrhums", "rmse", "vertices")
    columns = [round(h / 40) - 1 for h in HORIZONS_MS]
    a, b = a[:, columns], b[:, columns]
    rng = np.random.default_rng(seed)
    single, paired = np.zeros(len(columns)), np.zeros(len(columns))
    action = windows.action
    for _ in range(sets):
        pick = rng.choice(len(a), 100, replace=False)
        i = recording_interval(a[pick], windows.sequence[pick], action[pick])
        single += (i.lo <= a.mean(0)) & (a.mean(0) <= i.hi)
        d = recording_interval(a[pick] - b[pick], windows.sequence[pick], action[pick])
        paired += (d.lo <= (a - b).mean(0)) & ((a - b).mean(0) <= d.hi)
    return {
        "single": float(single.min() / sets),
        "paired": float(paired.min() / sets),
        "sets": sets,
        "recordings": 100,
        "horizons_ms": list(HORIZONS_MS),
    }


def cmu_training_errors(data_root: Path):
    """repeat_last and constant_velocity scored on CMU's training recordings (sampler
    ``all``), actions with at least three recordings: per-window MPJPE at ``HORIZONS_MS``."""
    from zoo import create_model
    from zoo.protocol.benchmark import get_benchmark

    bench = get_benchmark("cmu")
    dataset = bench.load(data_root, split="train")
    errors, windows = {}, None
    for name in ("repeat_last", "constant_velocity"):
        model = create_model(
            name, input_frames=bench.input_frames, output_frames=bench.output_frames, num_points=38
        )
        result = zoo.evaluate(model, bench, label=name, sampler="all", dataset=dataset)
        metric, joints = "mpjpe", "used25"
        errors[name] = result.windows.get(name, metric, joints).astype(np.float64)
        windows = result.windows
    columns = [round(h / 40) - 1 for h in HORIZONS_MS]
    return {m: e[:, columns] for m, e in errors.items()}, windows


def cmu_coverage(sets: int, data_root: Path, seed: int = 0) -> dict:
    """Pseudo test sets of one training recording per action: does its window-sampling
    interval cover the mean of the action's other recordings (averaged over actions)?"""
    errors, w = cmu_training_errors(data_root)
    actions = [a for a in np.unique(w.action) if len(np.unique(w.sequence[w.action == a])) >= 3]
    recordings = {a: np.unique(w.sequence[w.action == a]) for a in actions}
    rng = np.random.default_rng(seed)
    cases = {
        "repeat_last": errors["repeat_last"],
        "constant_velocity": errors["constant_velocity"],
        "paired": errors["repeat_last"] - errors["constant_velocity"],
    }
    hits = {k: np.zeros(len(HORIZONS_MS)) for k in cases}
    for s in range(sets):
        chosen = {a: rng.choice(recordings[a]) for a in actions}
        rows = np.concatenate([np.flatnonzero(w.sequence == chosen[a]) for a in actions])
        held = {a: (w.action == a) & (w.sequence != chosen[a]) for a in actions}
        sub = Windows(w.sequence[rows], w.start[rows], w.action[rows], w.window_frames, [])
        for k, e in cases.items():
            truth = np.mean([e[held[a]].mean(axis=0) for a in actions], axis=0)
            i = interval(e[rows], sub, replicates=REPLICATES, seed=s)
            hits[k] += (i.lo <= truth) & (truth <= i.hi)
    return {
        "horizons_ms": list(HORIZONS_MS),
        **{k: [round(float(v) / sets, 3) for v in h] for k, h in hits.items()},
        "sets": sets,
        "actions": [str(a) for a in actions],
        "recordings_per_action": {str(a): int(len(r)) for a, r in recordings.items()},
    }


def length_curve(repetitions: int) -> list[dict]:
    """Coverage of one recording's window-sampling interval against its length in windows, for
    blocks of 2, 4 and 8 window lengths, with short and with long memory."""
    out = []
    for memory in ("short", "long"):
        for blocks in (2, 4, 8):
            for n in (48, 70, 100, 146, 255, 500, 1009, 1343):
                rng = np.random.default_rng(0)
                covered = 0
                for r in range(repetitions):
                    e = window_errors(rng, n, memory)[:, None]
                    i = window_sampling_interval(
                        e,
                        np.zeros(n, int),
                        np.arange(n),
                        np.array(["a"] * n),
                        blocks * WINDOW,
                        WINDOW,
                        replicates=500,
                        seed=r,
                    )
                    covered += bool(i.lo[0] <= 0.0 <= i.hi[0])
                row = {"memory": memory, "block_windows": blocks, "windows": n}
                out.append(row | {"coverage": covered / repetitions})
                print(out[-1], flush=True)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--repetitions", type=int, default=1000)
    p.add_argument("--sets", type=int, default=500, help="pseudo test sets (real data)")
    p.add_argument("--only", choices=["synthetic", "bold", "recordings", "cloth", "cmu"])
    p.add_argument(
        "--lengths", action="store_true", help="coverage against recording length, then stop"
    )
    p.add_argument("--data-root", default=None, help="CMU folder (default: the benchmark's)")
    p.add_argument("--root", default=str(Path(__file__).resolve().parents[2]))
    p.add_argument("--write", action="store_true", help="write zoo/stats/coverage.yaml")
    args = p.parse_args(argv)
    root = Path(args.root)
    if args.lengths:
        length_curve(args.repetitions)
        return 0
    started = time.time()
    record: dict = {}
    parts = [args.only] if args.only else ["synthetic", "bold", "recordings", "cloth", "cmu"]
    for part in parts:
        t0 = time.time()
        if part == "synthetic":
            record.setdefault("window_sampling", {})["synthetic"] = {
                "short_memory": synthetic_coverage(args.repetitions, "short"),
                "long_memory": synthetic_coverage(args.repetitions, "long"),
                "repetitions": args.repetitions,
            }
        elif part == "bold":
            record["bold"] = {
                **bold_error(args.repetitions),
                "models": 7,
                "repetitions": args.repetitions,
            }
        elif part == "recordings":
            record.setdefault("confidence", {})["synthetic"] = {
                f"{k}_per_action": recording_coverage(args.repetitions, k) for k in (3, 5)
            } | {"repetitions": args.repetitions}
        elif part == "cloth":
            record.setdefault("confidence", {})["cloth_full"] = cloth_coverage(args.sets, root)
        elif part == "cmu":
            record.setdefault("window_sampling", {})["cmu_training"] = cmu_coverage(
                args.sets, Path(args.data_root) if args.data_root else None
            )
        print(f"{part}: {record} ({time.time() - t0:.0f} s)", flush=True)
    command = "python benchmarks/coverage/coverage.py " + " ".join(
        sys.argv[1:] if argv is None else argv
    )
    record["measured"] = {
        part: f"{command} ({platform.machine()}, {round(time.time() - started)} s)"
        for part in parts
    }
    if args.write:
        import yaml

        from zoo.core.io import atomic_write_text

        path = root / "zoo" / "coverage.yaml"
        old = yaml.safe_load(path.read_text()) if path.is_file() else {}
        for key, value in record.items():
            if isinstance(value, dict) and isinstance(old.get(key), dict):
                old[key].update(value)
            else:
                old[key] = value
        atomic_write_text(
            path,
            "# written by benchmarks/coverage/coverage.py\n" + yaml.safe_dump(old, sort_keys=False),
        )
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
