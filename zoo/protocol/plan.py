"""A protocol, planned once: which windows of which dataset are scored, for which task and
against which ground truth, and the record every result row of it carries.

:func:`plan_protocol` is the one function that builds a :class:`Protocol` from (benchmark,
dataset, sampler, task, horizon, ground truth, MELV frames); the evaluator, the store, the tables
and ``--check`` read it and never plan again. Its record's comparable part (everything but
provenance) is hashed into ``protocol_id``, which every row carries, so rows measured
differently can never be mistaken for each other.
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from zoo.core.errors import EvaluationError
from zoo.core.io import canonical_json
from zoo.core.options import TASKS
from zoo.data import windows as window_rules
from zoo.protocol.benchmark import Benchmark


@dataclass(frozen=True, eq=False)
class Protocol:
    """One planned protocol: the dataset it reads (loaded once), its windows (``index``:
    sequence and first frame of each, in scoring order; ``actions``: each window's action), the
    frames a model sees and predicts, the spectral basis a mesh protocol needs (or None) and its
    record (``record["protocol_id"]`` included; provenance is added per result)."""

    benchmark: Benchmark
    dataset: Any
    sampler: str
    task: str
    input_frames: int
    predicted_frames: int
    index: np.ndarray
    actions: np.ndarray
    record: dict[str, Any]
    ground_truth: str | None = None
    melv_frames: str | None = None
    basis: Any = None

    @property
    def id(self) -> str:
        return self.record["protocol_id"]

    @property
    def window_frames(self) -> int:
        return self.input_frames + self.predicted_frames

    def subset(self, rows: np.ndarray) -> Protocol:
        """Only the windows at positions ``rows`` of this protocol's (a sampled check), its
        record and id kept: a pass over them gives the protocol's per-window errors of those
        windows, not its averages."""
        return dataclasses.replace(self, index=self.index[rows], actions=self.actions[rows])


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


def protocol_id(record: dict[str, Any]) -> str:
    comparable = {k: v for k, v in record.items() if k not in ("provenance", "protocol_id")}
    return hashlib.sha256(canonical_json(comparable).encode()).hexdigest()[:16]


def plan_protocol(
    bench: Benchmark,
    dataset,
    *,
    sampler: str | None = None,
    task: str = "prediction",
    horizon: int | None = None,
    ground_truth: str | None = None,
    melv_frames: str | None = None,
) -> Protocol:
    """The protocol these settings define on ``dataset`` (``bench.load()``), found without
    running any model. ``ground_truth`` and ``melv_frames`` (mesh benchmarks only): ``raw`` or
    ``spectral``, default the benchmark's; ``task``: see :data:`TASKS` (``longterm`` with
    ``horizon`` frames)."""
    sampler = window_rules.check_sampler(sampler or bench.sampler)
    t_out = check_task(task, horizon, bench.output_frames)
    planned = bench.strategy.plan(bench, dataset, sampler, t_out, ground_truth, melv_frames)
    record = {**planned.record, **_task_record(task, t_out)}
    record["protocol_id"] = protocol_id(record)
    return Protocol(
        bench,
        dataset,
        sampler,
        task,
        bench.input_frames,
        t_out,
        planned.index,
        planned.actions,
        record,
        ground_truth=planned.ground_truth,
        melv_frames=planned.melv_frames,
        basis=planned.basis,
    )


def _task_record(task: str, frames: int) -> dict[str, Any]:
    return {"task": task, "task_rule": TASKS[task], "predicted_frames": frames}
