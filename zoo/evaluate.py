"""The one evaluator: any registered model on any benchmark, every row with its protocol.

``evaluate`` returns an :class:`EvalResult`: a long-format DataFrame (one row per model, action,
metric, averaging, joint protocol and horizon) and the protocol record that produced it. The
record's comparable part (everything but provenance) is hashed into ``protocol_id``, which every
row carries, so rows measured differently can never be mistaken for each other.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from zoo.benchmark import Benchmark, get_benchmark
from zoo.data.motion import MotionDataset
from zoo.data.windows import check_sampler, gather_windows, window_sampler
from zoo.errors import ZooError
from zoo.io import atomic_write_json, atomic_write_text, canonical_json, code_version
from zoo.metrics import ACTION_AVERAGING, AVERAGING, FrameErrorMean, cumulative_mean, \
    joint_protocols, skeleton_errors

RESULT_COLUMNS = ["model", "benchmark", "action", "metric", "averaging", "joints", "horizon_ms",
                  "frame", "value", "windows", "dataset", "split", "sampler", "input_frames",
                  "output_frames", "fps", "protocol_id"]


class EvaluationError(ZooError, RuntimeError):
    pass


@dataclass
class EvalResult:
    frame: pd.DataFrame
    protocol: dict[str, Any]

    def write(self, out_dir: str | Path) -> Path:
        """``results.csv``, ``protocol.json`` and ``tables.md`` in ``out_dir``, each atomically."""
        from zoo.leaderboard import markdown_tables

        out_dir = Path(out_dir)
        tables = markdown_tables(self.frame, {self.protocol["protocol_id"]: self.protocol})
        atomic_write_text(out_dir / "results.csv", self.frame.to_csv(index=False))
        atomic_write_json(out_dir / "protocol.json", self.protocol)
        atomic_write_text(out_dir / "tables.md", tables)
        return out_dir

    @classmethod
    def read(cls, out_dir: str | Path) -> "EvalResult":
        out_dir = Path(out_dir)
        for name in ("results.csv", "protocol.json"):
            if not (out_dir / name).is_file():
                raise EvaluationError(f"{out_dir / name}: missing (not an evaluation folder)")
        protocol = json.loads((out_dir / "protocol.json").read_text())
        return cls(frame=pd.read_csv(out_dir / "results.csv"), protocol=protocol)


def protocol_id(record: dict[str, Any]) -> str:
    comparable = {k: v for k, v in record.items() if k not in ("provenance", "protocol_id")}
    return hashlib.sha256(canonical_json(comparable).encode()).hexdigest()[:16]


def protocol_record(bench: Benchmark, dataset: MotionDataset, sampler: str,
                    windows_per_action: dict[str, int]) -> dict[str, Any]:
    skeleton = dataset.skeleton
    return {
        "benchmark": bench.name,
        "dataset": dataset.name,
        "split": dataset.split,
        "skeleton": skeleton.name,
        "units": "mm",
        "source_fps": dataset.source_fps,
        "subsample": dataset.subsample,
        "fps": dataset.fps,
        "input_frames": bench.input_frames,
        "output_frames": bench.output_frames,
        "horizon_rule": f"predicted frame t (1-based) is at t * {1000 / dataset.fps:g} ms",
        "sampler": sampler,
        "windows_per_action": windows_per_action,
        "actions_requested": list(dataset.actions_requested),
        "actions_present": list(dataset.actions_present),
        "files": [{"file": f["file"], "sha256": f["sha256"], "frames": f["frames"]}
                  for f in dataset.files()],
        "joint_protocols": joint_protocols(skeleton),
        "averaging": AVERAGING,
        "action_averaging": ACTION_AVERAGING,
        "global_motion": "root translation and rotation removed by FK (never applied)",
    }


def evaluate(model: torch.nn.Module, benchmark: str | Benchmark, *, model_name: str,
             sampler: str | None = None, data_root: str | Path | None = None,
             dataset: MotionDataset | None = None, batch_size: int = 1024,
             device: str | torch.device = "cpu",
             provenance: dict[str, Any] | None = None) -> EvalResult:
    """Evaluate ``model`` under ``benchmark`` with ``sampler`` (default: the benchmark's)."""
    bench = get_benchmark(benchmark) if isinstance(benchmark, (str, Path)) else benchmark
    sampler = check_sampler(sampler or bench.sampler)
    dataset = dataset if dataset is not None else bench.load(data_root)
    skeleton = dataset.skeleton
    t_in, t_out = bench.input_frames, bench.output_frames
    sequences = dataset.sequences
    index = window_sampler(sampler, [len(s) for s in sequences], t_in, t_out, dataset.ltd_rule,
                           groups=[s.action for s in sequences],
                           subactions=[s.subaction for s in sequences])
    if len(index) == 0:
        raise EvaluationError(f"benchmark {bench.name}: sampler {sampler} found no window of "
                              f"{t_in + t_out} frames in {dataset.root}")
    actions = np.asarray([sequences[i].action for i in index[:, 0]])
    positions = [s.positions for s in sequences]
    used = list(skeleton.used)
    accumulators: dict[str, FrameErrorMean] = {}
    model = model.to(device).eval()
    with torch.no_grad():
        for start in range(0, len(index), batch_size):
            rows = slice(start, start + batch_size)
            windows = torch.from_numpy(gather_windows(positions, index[rows], t_in + t_out))
            history = windows[:, :t_in, used].to(device)
            pred = model(history)
            expected = (len(history), t_out, len(used), 3)
            if not isinstance(pred, torch.Tensor) or tuple(pred.shape) != expected:
                got = tuple(pred.shape) if isinstance(pred, torch.Tensor) else type(pred).__name__
                raise EvaluationError(f"model {model_name!r} returned {got}; the contract "
                                      f"(zoo.models) expects {expected}")
            pred = pred.detach().to("cpu", torch.float32)
            if not torch.isfinite(pred).all():
                raise EvaluationError(f"model {model_name!r} predicted non-finite values "
                                      f"(windows {start}..{start + len(pred) - 1})")
            for joints, errors in skeleton_errors(pred, windows[:, t_in:], skeleton).items():
                accumulators.setdefault(joints, FrameErrorMean()).update(errors, actions[rows])

    windows_per_action = {a: int((actions == a).sum()) for a in dataset.actions_present}
    record = protocol_record(bench, dataset, sampler, windows_per_action)
    record["protocol_id"] = protocol_id(record)
    record["provenance"] = {
        "model": model_name,
        "code_version": code_version(),
        "torch": torch.__version__,
        "device": str(device),
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        **(provenance or {}),
    }
    frame = _long_frame(accumulators, record, model_name, windows_per_action)
    return EvalResult(frame=frame, protocol=record)


def _long_frame(accumulators: dict[str, FrameErrorMean], record: dict[str, Any], model_name: str,
                windows_per_action: dict[str, int]) -> pd.DataFrame:
    frame_ms = 1000.0 / record["fps"]
    total = sum(windows_per_action.values())
    rows = []
    for joints, acc in accumulators.items():
        for action, per_frame in acc.compute().items():
            for averaging, values in (("frame", per_frame), ("cumulative",
                                                             cumulative_mean(per_frame))):
                for t, value in enumerate(values, start=1):
                    rows.append((model_name, record["benchmark"], action, "mpjpe", averaging,
                                 joints, int(round(t * frame_ms)), t, float(value),
                                 windows_per_action.get(action, total), record["dataset"],
                                 record["split"], record["sampler"], record["input_frames"],
                                 record["output_frames"], record["fps"], record["protocol_id"]))
    return pd.DataFrame(rows, columns=RESULT_COLUMNS)
