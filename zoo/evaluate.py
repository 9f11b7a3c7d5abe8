"""The one evaluator: any registered model on any benchmark, every row with its protocol.

(Called, ``zoo.evaluate(model, benchmark, label=..., sampler=..., store=False, out=None)`` runs
:func:`zoo.api.evaluate`: a model object, registered name or trained file in, an
:class:`EvalResult` carrying its identity out. Below, the evaluator itself.)

``evaluate`` returns an :class:`EvalResult`: a long-format DataFrame (one row per model, action,
metric, averaging, joint protocol and horizon) and the protocol record that produced it. The
record's comparable part (everything but provenance) is hashed into ``protocol_id``, which every
row carries, so rows measured differently can never be mistaken for each other.

Mesh benchmarks go through the same entry point (:func:`evaluate_mesh`): windows of the mesh
sequences, metrics ``melv`` (with the ground-truth future's own MELV as model ``ground_truth``),
``rmse`` and, with a joint regressor, ``mpjpe``, in the same long format.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import inspect
import json
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from zoo.benchmark import Benchmark, get_benchmark
from zoo.data.motion import MotionDataset
from zoo.data.windows import check_sampler, gather_windows, window_sampler
from zoo.distributed import DistInfo, gather_shares, init_distributed
from zoo.errors import ZooError
from zoo.io import (
    atomic_path,
    atomic_write_json,
    atomic_write_text,
    canonical_json,
    code_version,
    replace_folder,
)
from zoo.metrics import (
    ACTION_AVERAGING,
    AVERAGING,
    METRICS,
    STD_DESCRIPTION,
    FrameErrorMean,
    cumulative_mean,
    joint_protocols,
    skeleton_errors,
)
from zoo.tables import FLOOR_SUFFIX, markdown_tables

# Windows per forward pass. Small batches keep a model's intermediate tensors in the CPU's
# caches: SPGSN evaluates 3.4 times faster per window at 64 than at 1024 (77 against 262 ms a
# window, one thread).
EVAL_BATCH = 64
RESULT_COLUMNS = [
    "model",
    "benchmark",
    "action",
    "metric",
    "averaging",
    "joints",
    "horizon_ms",
    "frame",
    "value",
    "std",
    "windows",
    "dataset",
    "split",
    "sampler",
    "task",
    "input_frames",
    "output_frames",
    "fps",
    "protocol_id",
]
TASKS = {
    "prediction": "the T_out frames after the observed ones",
    "completion": "in-betweening: the T_out frames after the observed ones, the last of them "
    "given to the model (final_frame)",
    "longterm": "long-term prediction: horizon frames, the model's predictions fed back as its "
    "next observed frames (autoregressive)",
}


class EvaluationError(ZooError, RuntimeError):
    pass


WINDOWS_FILE = "windows.npz"


@dataclass
class WindowErrors:
    """Every scored window's per-frame error, beside the averages (``windows.npz``): where each
    window comes from (``sequence`` index into ``sequences``, first frame ``start``, ``action``)
    and, per ``(model, metric, joints)``, its errors ``(W, T_out)`` at every predicted frame
    (float32; the averages in ``results.csv`` are summed in float64 from the exact values)."""

    sequences: list[str]
    sequence: np.ndarray
    start: np.ndarray
    action: np.ndarray
    errors: dict[tuple[str, str, str], np.ndarray]
    protocol_id: str
    window_frames: int

    def get(self, model: str, metric: str, joints: str) -> np.ndarray:
        key = (model, metric, joints)
        if key not in self.errors:
            raise EvaluationError(
                f"no per-window errors for model {model!r}, metric "
                f"{metric!r}, joints {joints!r}; stored: "
                f"{', '.join('/'.join(k) for k in self.errors)}"
            )
        return self.errors[key]

    def write(self, path: str | Path) -> None:
        arrays = {
            "sequences": np.asarray(self.sequences, dtype=str),
            "sequence": self.sequence.astype(np.int32),
            "start": self.start.astype(np.int32),
            "action": np.asarray(self.action, dtype=str),
            "protocol_id": np.asarray(self.protocol_id),
            "window_frames": np.asarray(self.window_frames),
        }
        for (model, metric, joints), values in self.errors.items():
            arrays[f"errors/{model}/{metric}/{joints}"] = values.astype(np.float32)
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)

    @classmethod
    def read(cls, path: str | Path) -> WindowErrors:
        try:
            with np.load(path, allow_pickle=False) as data:
                keys = [k for k in data.files if k.startswith("errors/")]
                return cls(
                    sequences=[str(x) for x in data["sequences"]],
                    sequence=data["sequence"].astype(np.int64),
                    start=data["start"].astype(np.int64),
                    action=data["action"].astype(str),
                    errors={tuple(k.split("/", 3)[1:]): data[k] for k in keys},
                    protocol_id=str(data["protocol_id"]),
                    window_frames=int(data["window_frames"]),
                )
        except (OSError, ValueError, KeyError) as exc:
            raise EvaluationError(
                f"{path}: not a readable per-window error file ({exc}); "
                f"re-evaluate to rebuild it (zoo eval / zoo leaderboard)"
            ) from exc


class _WindowLog:
    """Collects per-window errors batch by batch, in window order."""

    def __init__(self) -> None:
        self.errors: dict[tuple[str, str, str], list[np.ndarray]] = {}

    def update(self, model: str, metric: str, joints: str, errors: np.ndarray) -> None:
        self.errors.setdefault((model, metric, joints), []).append(errors.astype(np.float32))

    def compute(
        self,
        sequences,
        index: np.ndarray,
        actions: np.ndarray,
        protocol_id: str,
        window_frames: int,
    ) -> WindowErrors:
        return WindowErrors(
            sequences=[s.name for s in sequences],
            sequence=index[:, 0],
            start=index[:, 1],
            action=actions,
            errors={k: np.concatenate(v) for k, v in self.errors.items()},
            protocol_id=protocol_id,
            window_frames=window_frames,
        )


@dataclass
class EvalResult:
    frame: pd.DataFrame
    protocol: dict[str, Any]
    windows: WindowErrors | None = None

    def write(self, out_dir: str | Path, replace: bool = True) -> Path:
        """``results.csv``, ``protocol.json``, ``tables.md`` and ``windows.npz`` in ``out_dir``.
        The folder is replaced as a whole (filled beside it, then renamed into place) under a
        lock that refuses a second writer; ``replace=False`` writes into a fresh folder that the
        caller replaces as a whole itself."""
        out_dir = Path(out_dir)
        tables = markdown_tables(self.frame, {self.protocol["protocol_id"]: self.protocol})
        with replace_folder(out_dir) if replace else nullcontext(out_dir) as folder:
            atomic_write_text(folder / "results.csv", self.frame.to_csv(index=False))
            atomic_write_json(folder / "protocol.json", self.protocol)
            atomic_write_text(folder / "tables.md", tables)
            if self.windows is not None:
                self.windows.write(folder / WINDOWS_FILE)
        return out_dir

    def summary(self, metric: str | None = None, averaging: str = "frame") -> pd.DataFrame:
        """The action average per horizon (columns, ms) of every model and joint protocol of
        ``metric`` (default: every metric), under ``averaging``."""
        frame = self.frame[
            (self.frame["action"] == "average") & (self.frame["averaging"] == averaging)
        ]
        if metric is not None:
            frame = frame[frame["metric"] == metric]
        return frame.pivot_table(
            index=["model", "metric", "joints"], columns="horizon_ms", values="value"
        )

    @property
    def identity(self) -> dict[str, Any] | None:
        """What was measured (:mod:`zoo.store`), as recorded in ``protocol.json``."""
        return self.protocol.get("provenance", {}).get("identity")

    @classmethod
    def read(cls, out_dir: str | Path) -> EvalResult:
        out_dir = Path(out_dir)
        for name in ("results.csv", "protocol.json"):
            if not (out_dir / name).is_file():
                raise EvaluationError(f"{out_dir / name}: missing (not an evaluation folder)")
        protocol = json.loads((out_dir / "protocol.json").read_text())
        windows = (
            WindowErrors.read(out_dir / WINDOWS_FILE)
            if (out_dir / WINDOWS_FILE).is_file()
            else None
        )
        if windows is not None and windows.protocol_id != protocol["protocol_id"]:
            raise EvaluationError(
                f"{out_dir / WINDOWS_FILE}: measured under protocol "
                f"{windows.protocol_id}, but {out_dir / 'protocol.json'} says "
                f"{protocol['protocol_id']}; re-evaluate the folder"
            )
        return cls(frame=pd.read_csv(out_dir / "results.csv"), protocol=protocol, windows=windows)


def check_task(task: str, horizon: int | None, output_frames: int) -> int:
    """The number of predicted frames a task scores."""
    if task not in TASKS:
        raise EvaluationError(f"unknown task {task!r}; valid tasks: {', '.join(TASKS)}")
    if task == "longterm":
        if horizon is None or horizon <= output_frames:
            raise EvaluationError(
                f"task longterm needs a horizon of more than the model's "
                f"{output_frames} output frames (--horizon-frames), got "
                f"{horizon}"
            )
        return horizon
    if horizon is not None:
        raise EvaluationError(f"a horizon applies to task longterm, not {task}")
    return output_frames


def predict(
    model: torch.nn.Module,
    history: torch.Tensor,
    task: str,
    frames: int,
    final_frame: torch.Tensor | None = None,
) -> torch.Tensor:
    """A model's prediction for one of the evaluator's tasks (see ``TASKS``)."""
    if task == "prediction":
        return model(history)
    if task == "completion":
        if "final_frame" not in inspect.signature(model.forward).parameters:
            raise EvaluationError(
                f"{type(model).__name__} does no completion: its forward takes no final_frame"
            )
        return model(history, final_frame=final_frame)
    if hasattr(model, "rollout"):  # a model's own (cheaper) autoregression
        return model.rollout(history, frames)
    t_in, window, out, produced = history.shape[1], history, [], 0
    while produced < frames:
        step = model(window[:, -t_in:])
        out.append(step)
        produced += step.shape[1]
        window = torch.cat([window, step], dim=1)
    return torch.cat(out, dim=1)[:, :frames]


def _checked(pred, expected: tuple, model_name: str, start: int) -> torch.Tensor:
    """A model's output on CPU in float32, or an error if it breaks the contract."""
    if not isinstance(pred, torch.Tensor) or tuple(pred.shape) != expected:
        got = tuple(pred.shape) if isinstance(pred, torch.Tensor) else type(pred).__name__
        raise EvaluationError(
            f"model {model_name!r} returned {got}; the contract (zoo.models) expects {expected}"
        )
    pred = pred.detach().to("cpu", torch.float32)
    if not torch.isfinite(pred).all():
        raise EvaluationError(
            f"model {model_name!r} predicted non-finite values (windows "
            f"{start}..{start + len(pred) - 1})"
        )
    return pred


def _seal(record: dict[str, Any], model_name: str, device, provenance: dict | None) -> None:
    """Hash the comparable record into ``protocol_id`` and add who measured it, when and how."""
    record["protocol_id"] = protocol_id(record)
    record["provenance"] = {
        "model": model_name,
        "code_version": code_version(),
        "torch": str(torch.__version__),
        "device": str(device),
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        # float32 kernels round differently on other CPUs (summation order, fused
        # multiply-adds): a re-run elsewhere agrees to rounding, not to the last bit
        "exactness": "float32 evaluation: another CPU reproduces these values and per-window "
        "errors to rounding (zoo leaderboard --check's tolerance), not bit for bit",
        **(provenance or {}),
    }


def _task_record(task: str, frames: int) -> dict[str, Any]:
    return {"task": task, "task_rule": TASKS[task], "predicted_frames": frames}


def protocol_id(record: dict[str, Any]) -> str:
    comparable = {k: v for k, v in record.items() if k not in ("provenance", "protocol_id")}
    return hashlib.sha256(canonical_json(comparable).encode()).hexdigest()[:16]


def protocol_record(
    bench: Benchmark, dataset: MotionDataset, sampler: str, windows_per_action: dict[str, int]
) -> dict[str, Any]:
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
        "files": [
            {"file": f["file"], "sha256": f["sha256"], "frames": f["frames"]}
            for f in dataset.files()
        ],
        "joint_protocols": joint_protocols(skeleton),
        "averaging": AVERAGING,
        "action_averaging": ACTION_AVERAGING,
        "global_motion": "root translation and rotation removed by FK (never applied)",
    }


def evaluate(
    model: torch.nn.Module,
    benchmark: str | Benchmark,
    *,
    model_name: str,
    sampler: str | None = None,
    data_root: str | Path | None = None,
    dataset: MotionDataset | None = None,
    batch_size: int = EVAL_BATCH,
    device: str | torch.device = "cpu",
    provenance: dict[str, Any] | None = None,
    ground_truth: str | None = None,
    task: str = "prediction",
    horizon: int | None = None,
    view: str = "mesh",
    melv_frames: str | None = None,
) -> EvalResult:
    """Evaluate ``model`` under ``benchmark`` with ``sampler`` (default: the benchmark's).

    ``ground_truth`` and ``melv_frames`` (mesh benchmarks only): ``raw`` or ``spectral``,
    default the benchmark's.
    ``task``: ``prediction``, ``completion`` or ``longterm`` (``horizon`` frames), see ``TASKS``.
    ``view`` (mesh benchmarks only): ``mesh``, or ``joints`` for a skeleton model fed the
    regressed joints (``Benchmark.view_for`` says which a registry entry needs).
    """
    bench = get_benchmark(benchmark) if isinstance(benchmark, (str, Path)) else benchmark
    if bench.representation == "mesh":
        return evaluate_mesh(
            model,
            bench,
            model_name=model_name,
            sampler=sampler,
            data_root=data_root,
            dataset=dataset,
            batch_size=batch_size,
            device=device,
            provenance=provenance,
            ground_truth=ground_truth,
            task=task,
            horizon=horizon,
            view=view,
            melv_frames=melv_frames,
        )
    for name, value in (("ground_truth", ground_truth), ("melv_frames", melv_frames)):
        if value is not None:
            raise EvaluationError(
                f"benchmark {bench.name}: {name}={value!r} applies to mesh benchmarks only"
            )
    dataset = dataset if dataset is not None else bench.load(data_root)
    skeleton = dataset.skeleton
    plan = _skeleton_plan(bench, dataset, sampler, task, horizon)
    sampler, t_out, index, actions, record = plan
    t_in = bench.input_frames
    sequences = dataset.sequences
    positions = [s.positions for s in sequences]
    used = list(skeleton.used)
    dist_info = init_distributed(device)
    scored = {}
    model = model.to(device).eval()
    with torch.no_grad():
        for start in _my_batches(len(index), batch_size, dist_info):
            rows = slice(start, start + batch_size)
            windows = torch.from_numpy(gather_windows(positions, index[rows], t_in + t_out))
            history = windows[:, :t_in, used].to(device)
            pred = predict(model, history, task, t_out, windows[:, -1, used].to(device))
            pred = _checked(pred, (len(history), t_out, len(used), 3), model_name, start)
            scored[start] = {
                (model_name, "mpjpe", joints): _float64(errors)
                for joints, errors in skeleton_errors(pred, windows[:, t_in:], skeleton).items()
            }
    accumulators, log = _accumulate(gather_shares(scored, dist_info), actions)

    _seal(record, model_name, device, provenance)
    return EvalResult(
        frame=_frame(accumulators, record, record["windows_per_action"]),
        protocol=record,
        windows=log.compute(sequences, index, actions, record["protocol_id"], t_in + t_out),
    )


def _skeleton_plan(
    bench: Benchmark, dataset: MotionDataset, sampler: str | None, task: str, horizon: int | None
):
    """The windows a skeleton evaluation scores and its protocol record (not yet sealed)."""
    sampler = check_sampler(sampler or bench.sampler)
    t_in = bench.input_frames
    t_out = check_task(task, horizon, bench.output_frames)
    sequences = dataset.sequences
    index = window_sampler(
        sampler,
        [len(s) for s in sequences],
        t_in,
        t_out,
        dataset.ltd_rule,
        groups=[s.action for s in sequences],
        subactions=[s.subaction for s in sequences],
    )
    if len(index) == 0:
        raise EvaluationError(
            f"benchmark {bench.name}: sampler {sampler} found no window of "
            f"{t_in + t_out} frames in {dataset.root}"
        )
    actions = np.asarray([sequences[i].action for i in index[:, 0]])
    windows_per_action = {a: int((actions == a).sum()) for a in dataset.actions_present}
    record = protocol_record(bench, dataset, sampler, windows_per_action)
    record.update(_task_record(task, t_out))
    return sampler, t_out, index, actions, record


def protocol_for(
    benchmark: str | Benchmark,
    dataset=None,
    *,
    sampler: str | None = None,
    task: str = "prediction",
    horizon: int | None = None,
    ground_truth: str | None = None,
    melv_frames: str | None = None,
    data_root: str | Path | None = None,
) -> dict[str, Any]:
    """The protocol record (with its ``protocol_id``) that ``evaluate`` would write for these
    settings, found without running any model: what a stored result is checked against."""
    bench = get_benchmark(benchmark) if isinstance(benchmark, (str, Path)) else benchmark
    dataset = dataset if dataset is not None else bench.load(data_root)
    if bench.representation == "mesh":
        record = _mesh_plan(bench, dataset, sampler, task, horizon, ground_truth, melv_frames)[-1]
    else:
        record = _skeleton_plan(bench, dataset, sampler, task, horizon)[-1]
    return {**record, "protocol_id": protocol_id(record)}


def _my_batches(windows: int, batch_size: int, dist_info: DistInfo) -> range:
    """First windows of this process's batches: every ``world``-th batch (all of them alone)."""
    return range(dist_info.rank * batch_size, windows, dist_info.world * batch_size)


def _float64(errors: torch.Tensor) -> np.ndarray:
    return errors.detach().to("cpu", torch.float64).numpy()


def _accumulate(
    scored: dict[int, dict[tuple[str, str, str], np.ndarray]], actions: np.ndarray
) -> tuple[dict[tuple[str, str, str], FrameErrorMean], _WindowLog]:
    """Per-action sums and per-window errors from ``{first window: {(model, metric, joints):
    errors (B, T)}}``, batch after batch in window order: one process or several (each scoring
    every ``world``-th batch), the sums are added in the same order, to the last digit."""
    accumulators: dict[tuple[str, str, str], FrameErrorMean] = {}
    log = _WindowLog()
    for start, batch in scored.items():
        for key, errors in batch.items():
            groups = actions[start : start + len(errors)]
            accumulators.setdefault(key, FrameErrorMean()).update(errors, groups)
            log.update(*key, errors)
    return accumulators, log


def _frame(
    accumulators: dict[tuple[str, str, str], FrameErrorMean],
    record: dict[str, Any],
    windows_per_action: dict[str, int],
) -> pd.DataFrame:
    """The long-format rows of every (model, metric, joints), both averagings."""
    frame_ms = 1000.0 / record["fps"]
    total = sum(windows_per_action.values())
    rows = []
    for (model, metric, joints), acc in accumulators.items():
        spread = {averaging: acc.std(averaging) for averaging in ("frame", "cumulative")}
        for action, per_frame in acc.compute().items():
            for averaging, values in (
                ("frame", per_frame),
                ("cumulative", cumulative_mean(per_frame)),
            ):
                for t, value in enumerate(values, start=1):
                    rows.append(
                        (
                            model,
                            record["benchmark"],
                            action,
                            metric,
                            averaging,
                            joints,
                            int(round(t * frame_ms)),
                            t,
                            float(value),
                            float(spread[averaging][action][t - 1]),
                            windows_per_action.get(action, total),
                            record["dataset"],
                            record["split"],
                            record["sampler"],
                            record["task"],
                            record["input_frames"],
                            record["output_frames"],
                            record["fps"],
                            record["protocol_id"],
                        )
                    )
    return pd.DataFrame(rows, columns=RESULT_COLUMNS)


# ---- mesh benchmarks ---------------------------------------------------------------------------

MESH_BATCH_VALUES = 2**24  # float32 values of ground-truth windows held at once (64 MiB)


def mesh_protocol_record(
    bench: Benchmark,
    dataset,
    sampler: str,
    windows_per_action: dict[str, int],
    ground_truth: str,
    basis=None,
    melv_frames: str = "raw",
) -> dict[str, Any]:
    """The protocol record of a mesh evaluation: the data, windows and frames, as for skeletons,
    plus the mesh's own elements (topology, ground truth, spectral basis, MELV frames)."""
    topology = dataset.topology
    joints = {
        "vertices": f"all {topology.num_vertices} vertices (MELV: their "
        f"{len(topology.edges)} unique undirected edges)"
    }
    if dataset.joint_regressor is not None:
        n = dataset.joint_regressor.shape[0]
        names = f" ({', '.join(dataset.joint_names)})" if dataset.joint_names else ""
        joints[f"regressor{n}"] = (
            f"{n} joints regressed from the vertices by the dataset's "
            f"sparse joint regressor{names}, mean L2 error over them"
        )
    if ground_truth == "spectral":
        truth = f"spectral{basis.k}"
        truth_rule = (
            f"every window (observed and future frames) replaced by its reconstruction "
            f"from the k={basis.k} lowest-frequency Laplacian coefficients, as "
            f"SpecTrHuMS scores"
        )
    else:
        truth, truth_rule = "raw", "the dataset's vertices as stored"
    fps = dataset.fps
    return {
        "benchmark": bench.name,
        "dataset": dataset.name,
        "split": dataset.split,
        "representation": "mesh",
        "units": "mm (rmse: none, normalised)",
        "fps": fps,
        "input_frames": bench.input_frames,
        "output_frames": bench.output_frames,
        "horizon_rule": f"predicted frame t (1-based) is at t * {1000 / fps:g} ms",
        "sampler": sampler,
        "windows_per_action": windows_per_action,
        "actions_present": [a for a in dataset.actions_present if a in windows_per_action],
        "topology_hash": topology.hash,
        "num_vertices": topology.num_vertices,
        "recipe_hash": dataset.recipe_hash,
        "ground_truth": truth,
        "ground_truth_rule": truth_rule,
        "spectral_basis": (
            {"k": basis.k, "hash": basis.hash, "topology_hash": basis.topology_hash}
            if basis is not None
            else None
        ),
        "melv_frames": (
            f"spectral{basis.k}: the reference frame and the scored frames "
            f"reconstructed from their k={basis.k} lowest-frequency Laplacian "
            f"coefficients (as SpecTrHuMS measures)"
            if melv_frames == "spectral"
            else "raw: the frames as scored"
        ),
        "joint_protocols": joints,
        "metrics": {
            "melv": METRICS["melv"].description,
            "rmse": METRICS["rmse"].description,
            "std": STD_DESCRIPTION,
            "floor": f"model `<name>{FLOOR_SUFFIX}` rows: the ground-truth future through the "
            f"model's autoencoder alone (it sees the future: a bound, not a "
            f"prediction)",
            "mpjpe": METRICS["mpjpe"].description,
        },
        "averaging": AVERAGING,
        "action_averaging": ACTION_AVERAGING,
        "global_motion": dataset.recipe.get("global_motion", "as stored in the dataset"),
    }


def evaluate_mesh(
    model: torch.nn.Module,
    benchmark: str | Benchmark,
    *,
    model_name: str,
    sampler: str | None = None,
    data_root: str | Path | None = None,
    dataset=None,
    batch_size: int = EVAL_BATCH,
    device: str | torch.device = "cpu",
    provenance: dict[str, Any] | None = None,
    ground_truth: str | None = None,
    task: str = "prediction",
    horizon: int | None = None,
    view: str = "mesh",
    melv_frames: str | None = None,
) -> EvalResult:
    """Evaluate ``model`` on a mesh benchmark: windows ``(B, T_in, V, 3)`` in, ``(B, T_out, V,
    3)`` out, rows for ``melv``, ``rmse`` and (with a joint regressor) ``mpjpe``.

    ``melv_frames``: ``spectral`` (the default of benchmarks with a basis) measures MELV on the
    k-coefficient reconstruction of the reference frame and of the scored frames, as SpecTrHuMS
    does; ``raw`` on the frames as they are.

    A model with an ``autoencoder_floor(frames)`` method (SpecTrHuMS) also gets the rows of
    ``<name>:autoencoder``: the ground-truth future passed through its autoencoder alone, scored
    like a prediction; what the model could reach if its transformer were perfect.

    ``view='joints'``: a skeleton model sees the regressed joints ``(B, T_in, J, 3)`` of the same
    windows and predicts ``(B, T_out, J, 3)``; it gets the ``mpjpe`` rows only, under the very
    protocol record of the mesh models, so both share one MPJPE table."""
    from zoo.data.mesh import regress_joints
    from zoo.data.spectral import SpectralBasis
    from zoo.metrics import melv, mpjpe, regressed_mpjpe, vertex_rmse

    bench = get_benchmark(benchmark) if isinstance(benchmark, (str, Path)) else benchmark
    if view not in ("mesh", "joints"):
        raise EvaluationError(f"view must be mesh or joints, got {view!r}")
    dataset = dataset if dataset is not None else bench.load(data_root)
    topology = dataset.topology
    regressor = dataset.joint_regressor
    if view == "joints" and regressor is None:
        raise EvaluationError(
            f"benchmark {bench.name}: {dataset.name} has no joint regressor, so "
            f"skeleton model {model_name!r} cannot be evaluated on it"
        )
    sampler, t_out, index, actions, basis, record = _mesh_plan(
        bench, dataset, sampler, task, horizon, ground_truth, melv_frames
    )
    ground_truth, melv_frames = (
        bench.ground_truth if ground_truth is None else ground_truth,
        melv_frames or bench.melv_on,
    )
    truth_basis = basis if ground_truth == "spectral" else None

    def melv_of(frames: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
        if melv_frames == "spectral":  # both reconstructed from k coefficients (SpecTrHuMS)
            frames, reference = (
                basis.reconstruct(basis.project(x.double())).float() for x in (frames, reference)
            )
        return melv(frames, reference, edges)

    floor = getattr(model, "autoencoder_floor", None) if view == "mesh" else None
    t_in = bench.input_frames
    sequences = dataset.sequences
    vertices = [s.vertices for s in sequences]
    edges = topology.edges
    dist_info = init_distributed(device)
    scored = {}
    batch = max(
        1, min(batch_size, MESH_BATCH_VALUES // ((t_in + t_out) * topology.num_vertices * 3))
    )
    expected_tail = (t_out, topology.num_vertices, 3)
    model = model.to(device).eval()
    with torch.no_grad():
        for start in _my_batches(len(index), batch, dist_info):
            rows = slice(start, start + batch)
            windows = torch.from_numpy(gather_windows(vertices, index[rows], t_in + t_out))
            if truth_basis is not None:
                windows = truth_basis.reconstruct(truth_basis.project(windows.double())).float()
            if view == "joints":
                joints = regress_joints(windows, regressor)
                pred = predict(
                    model, joints[:, :t_in].to(device), task, t_out, joints[:, -1].to(device)
                )
                pred = _checked(
                    pred, (len(windows), t_out, regressor.shape[0], 3), model_name, start
                )
                scored[start] = {
                    (model_name, "mpjpe", f"regressor{regressor.shape[0]}"): _float64(
                        mpjpe(pred, joints[:, t_in:])
                    )
                }
                continue
            pred = predict(
                model, windows[:, :t_in].to(device), task, t_out, windows[:, -1].to(device)
            )
            pred = _checked(pred, (len(windows), *expected_tail), model_name, start)
            target, reference = windows[:, t_in:], windows[:, t_in - 1]
            scored_frames = {model_name: pred}
            if floor is not None:
                rebuilt = floor(target.to(device))
                scored_frames[model_name + FLOOR_SUFFIX] = _checked(
                    rebuilt, (len(windows), *expected_tail), model_name + FLOOR_SUFFIX, start
                )
            errors = {}
            for name, frames in scored_frames.items():
                errors[(name, "melv", "vertices")] = melv_of(frames, reference)
                errors[(name, "rmse", "vertices")] = vertex_rmse(frames, target)
                if regressor is not None:
                    errors[(name, "mpjpe", f"regressor{regressor.shape[0]}")] = regressed_mpjpe(
                        frames, target, regressor
                    )
            # the data's own MELV, once per mesh evaluation: the ground-truth rows
            errors[("ground_truth", "melv", "vertices")] = melv_of(target, reference)
            scored[start] = {key: _float64(value) for key, value in errors.items()}
    accumulators, log = _accumulate(gather_shares(scored, dist_info), actions)

    model_basis = getattr(model, "basis", None)
    _seal(
        record,
        model_name,
        device,
        {
            # The data are named by their recipe in the protocol; the bytes of a generated mesh
            # follow the machine's float kernels (CMU-on-Anny's skinning: other bytes on another
            # CPU), so their hash is this build's provenance, not part of the protocol.
            "data_hash": dataset.content_hash(),
            "data_exactness": "generated from its recipe on this machine: another CPU's build may "
            "differ in the last bits of its vertices (data_hash), and so may "
            "errors computed from them (MELV most: a difference of edge lengths)",
            **({"basis_checksum": basis.checksum} if isinstance(basis, SpectralBasis) else {}),
            **(
                {"model_basis": {"k": model_basis.k, "hash": model_basis.hash}}
                if isinstance(model_basis, SpectralBasis)
                else {}
            ),
            **(
                {"model_input": f"regressed joints (regressor{regressor.shape[0]})"}
                if view == "joints"
                else {}
            ),
            **(provenance or {}),
        },
    )
    return EvalResult(
        frame=_frame(accumulators, record, record["windows_per_action"]),
        protocol=record,
        windows=log.compute(sequences, index, actions, record["protocol_id"], t_in + t_out),
    )


def _mesh_plan(
    bench: Benchmark,
    dataset,
    sampler: str | None,
    task: str,
    horizon: int | None,
    ground_truth: str | None,
    melv_frames: str | None,
):
    """The windows a mesh evaluation scores, the spectral basis it needs (or None) and its
    protocol record (not yet sealed)."""
    from zoo.benchmark import GROUND_TRUTHS

    sampler = check_sampler(sampler or bench.sampler)
    ground_truth = ground_truth or bench.ground_truth
    if ground_truth not in GROUND_TRUTHS:
        raise EvaluationError(
            f"ground_truth must be one of {', '.join(GROUND_TRUTHS)}, got {ground_truth!r}"
        )
    melv_frames = melv_frames or bench.melv_on
    if melv_frames not in GROUND_TRUTHS:
        raise EvaluationError(
            f"melv_frames must be one of {', '.join(GROUND_TRUTHS)}, got {melv_frames!r}"
        )
    if "spectral" in (ground_truth, melv_frames) and bench.spectral_k is None:
        raise EvaluationError(
            f"benchmark {bench.name}: spectral ground truth or MELV needs a "
            f"spectral basis (field spectral_k in {bench.source})"
        )
    basis = bench.spectral_basis(dataset) if "spectral" in (ground_truth, melv_frames) else None
    t_in = bench.input_frames
    t_out = check_task(task, horizon, bench.output_frames)
    sequences = dataset.sequences
    index = window_sampler(
        sampler,
        [len(s) for s in sequences],
        t_in,
        t_out,
        "per_file",
        groups=[s.action for s in sequences],
    )
    if len(index) == 0:
        raise EvaluationError(
            f"benchmark {bench.name}: sampler {sampler} found no window of "
            f"{t_in + t_out} frames in {dataset.name}/{dataset.split} "
            f"(sequences of {min(len(s) for s in sequences)} to "
            f"{max(len(s) for s in sequences)} frames)"
        )
    actions = np.asarray([sequences[i].action for i in index[:, 0]])
    windows_per_action = {
        a: int((actions == a).sum()) for a in dataset.actions_present if (actions == a).any()
    }
    record = {
        **mesh_protocol_record(
            bench, dataset, sampler, windows_per_action, ground_truth, basis, melv_frames
        ),
        **_task_record(task, t_out),
    }
    return sampler, t_out, index, actions, basis, record
