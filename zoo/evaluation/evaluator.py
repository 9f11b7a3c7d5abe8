"""The one evaluator: models scored in one pass over a planned protocol's windows
(:func:`evaluate_models`), every row carrying its protocol.

Skeleton and mesh benchmarks take the same path: what a model is fed and what it is scored
against come from the benchmark's representation (:mod:`zoo.protocol.representation`), and the
rows share the long format of :class:`zoo.evaluation.results.EvalResult` (one row per model,
action, metric, averaging, joint protocol and horizon). Users call
:func:`zoo.evaluate` (:mod:`zoo.api`), which plans the protocol and stamps the identity.
"""

from __future__ import annotations

import copy
import dataclasses
import datetime as _dt
import inspect
import math
import sys
import traceback
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
import pandas as pd
import torch

from zoo.core.distributed import DistInfo, gather_shares, init_distributed
from zoo.core.errors import EvaluationError
from zoo.core.io import code_version, progress_bar
from zoo.core.options import EVAL_BATCH
from zoo.evaluation.results import RESULT_COLUMNS, EvalResult, WindowErrors
from zoo.models.hooks import Hooks, model_hooks
from zoo.protocol.metrics import FLOOR_SUFFIX, FrameErrorMean, cumulative_mean, scored_errors
from zoo.protocol.plan import Protocol
from zoo.protocol.views import View


@dataclass
class Scored:
    """A model in an evaluation pass: the module, its row name, what it is fed (``view``: the
    mesh, or joints: a skeleton benchmark's, or a mesh benchmark's regressed joints for a
    skeleton model; None: the benchmark's own points) and what its results record about it."""

    model: torch.nn.Module
    name: str
    view: View | None = None  # None: the benchmark's own
    provenance: dict[str, Any] | None = None
    # the observed frames it reads, the last of those the protocol gives (None: all), and the
    # length it pads them to itself (its ``history_frames``): both shown beside its row
    history_frames: int | None = None
    padded_to: int | None = None
    hooks: Hooks | None = field(default=None, init=False, repr=False)  # set by the pass

    def __post_init__(self) -> None:
        # a view given by its word ("joints") becomes the View; another stays, for the pass to
        # refuse this model alone (its scoring's check_view)
        if self.view in tuple(View):
            self.view = View(self.view)

    def history(self, observed: torch.Tensor) -> torch.Tensor:
        """What it reads of ``observed`` ``(B, T_in, ...)``: its last ``history_frames``."""
        given = observed.shape[1]
        if self.history_frames is None or self.history_frames == given:
            return observed
        if self.history_frames > given:
            raise EvaluationError(
                f"model {self.name!r} reads {self.history_frames} observed frames; this "
                f"protocol gives {given}"
            )
        return observed[:, given - self.history_frames :]

    def history_record(self, given: int) -> dict[str, Any]:
        """``{"history": ...}`` where it says more than "all ``given`` frames, as they are"."""
        read = self.history_frames or given
        padded = self.padded_to if self.padded_to and self.padded_to > read else None
        if read == given and padded is None:
            return {}
        return {
            "history": {"given": given, "read": read, **({"padded_to": padded} if padded else {})}
        }


def evaluate_models(
    models: list[Scored],
    protocol: Protocol,
    *,
    batch_size: int = EVAL_BATCH,
    device: str | torch.device = "cpu",
    keep_going: bool = True,
) -> list[EvalResult | Exception]:
    """Every model of ``models`` on the windows of ``protocol`` in one pass: each batch of
    windows, and all that the ground truth alone gives (its spectral reconstruction, regressed
    joints, edge lengths and MELV), is made once and every model scored on it. A model's result
    is the one it gets evaluated alone (for models deterministic in eval mode, as every
    registered one is: models that draw random numbers share the stream).

    A model that fails (a broken contract, non-finite values, an error of its own, on any
    process of a distributed run) leaves the pass and its error stands in its place; with
    ``keep_going=False`` the first failure is raised at once instead."""
    if not models:
        return []
    scoring = protocol.benchmark.strategy.scoring(protocol, device)
    own = protocol.benchmark.own_view
    models = [dataclasses.replace(m, view=own) if m.view is None else m for m in models]
    run = _Pass(models, device, keep_going)
    for i, scored in run.live():
        run.attempt(i, partial(scoring.check_view, scored.view, scored.name))
    index, dist_info = protocol.index, init_distributed(device)
    batch = scoring.batch_size(batch_size)
    with torch.no_grad(), _progress(protocol, models, dist_info) as bar:
        for start in _my_batches(len(index), batch, dist_info):
            bar.update(min(batch, len(index) - start) * dist_info.world)
            live = run.live()
            if not live:
                continue  # every model has left the pass: no window is worth reading
            truth = scoring.truth(index[start : start + batch], {s.view for _, s in live})
            for i, scored in live:
                run.score(i, start, partial(_errors, protocol, scored, truth, start, device))
    return run.results(
        dist_info,
        lambda scored, batches: _finished(
            protocol, scored, batches, device, scoring.recorded(scored.view, scored.model)
        ),
    )


def _errors(protocol: Protocol, scored: Scored, truth, start: int, device) -> dict:
    """A model's errors on a batch of ground truth (a
    :class:`zoo.protocol.representation.TruthBatch`): its prediction's (and its autoencoder
    floor's, where it has one) under its view's metrics, and the data's own rows beside them."""
    observed, final_frame = truth.observed(scored.view)
    history = scored.history(observed)
    pred = predict(
        scored.model,
        history.to(device),
        protocol.task,
        protocol.predicted_frames,
        final_frame.to(device),
        hooks=scored.hooks,
    )
    expected = (len(history), protocol.predicted_frames, *history.shape[2:])
    against = truth.scored_as(scored.view)
    frames = {scored.name: checked_prediction(pred, expected, scored.name, start, history)}
    future = truth.floor_target(scored.view) if scored.hooks.autoencoder_floor else None
    if future is not None:
        name = scored.name + FLOOR_SUFFIX
        rebuilt = scored.model.autoencoder_floor(future.to(device))
        frames[name] = checked_prediction(rebuilt, tuple(future.shape), name, start)
    return {**scored_errors(frames, scored.view.metrics, against), **truth.own_errors(scored.view)}


class _Pass:
    """The models of a pass: those still in it, the errors of those that left, and each
    model's errors per batch (``batches[i]``: ``{first window: {(model, metric, joints):
    errors}}``)."""

    def __init__(self, models: list[Scored], device, keep_going: bool) -> None:
        self.models, self.keep_going = models, keep_going
        self.failed: dict[int, Exception] = {}
        self.batches: list[dict[int, dict]] = [{} for _ in models]
        for i, scored in enumerate(models):
            model = self.attempt(i, lambda model=scored.model: model.to(device).eval())
            if model is not None:
                scored.model = model
                # the optional hooks, read and checked once (zoo.models.hooks)
                scored.hooks = self.attempt(i, partial(model_hooks, model, scored.name))

    def live(self) -> list[tuple[int, Scored]]:
        return [(i, m) for i, m in enumerate(self.models) if i not in self.failed]

    def attempt(self, i: int, work) -> Any:
        """``work()`` for model ``i``, or the model leaves the pass with the error (raised at
        once without ``keep_going``). The error's frames are cleared: a failed model's
        activations and batch are not kept for the rest of the pass."""
        try:
            return work()
        except Exception as e:
            if not self.keep_going:
                raise
            traceback.clear_frames(e.__traceback__)
            self.failed[i] = e
            return None

    def score(self, i: int, start: int, compute) -> None:
        """Model ``i``'s errors on the batch at ``start`` (``compute()``), or its leaving."""
        errors = self.attempt(i, compute)
        if i not in self.failed:
            self.batches[i][start] = errors

    def results(self, dist_info: DistInfo, finish) -> list[EvalResult | Exception]:
        """Each model's result, ``finish(model, its batches in window order)``, or its error.
        Under torchrun every process's batches and failures are gathered in one collective: a
        model that failed on any process fails on all of them (none writes a result missing
        that process's windows)."""
        shares = gather_shares(
            {
                dist_info.rank: (
                    {i: b for i, b in enumerate(self.batches) if i not in self.failed},
                    {i: f"{type(e).__name__}: {e}" for i, e in self.failed.items()},
                )
            },
            dist_info,
        )
        self.batches = [{} for _ in self.models]  # released: the gathered copies are used
        merged: list[dict[int, dict]] = [{} for _ in self.models]
        for rank, (batches, failures) in shares.items():
            for i, message in failures.items():
                if i not in self.failed:
                    self.failed[i] = EvaluationError(
                        f"model {self.models[i].name!r} failed on process {rank}: {message}"
                    )
            for i, theirs in batches.items():
                merged[i].update(theirs)
        out: list[EvalResult | Exception] = []
        for i, scored in enumerate(self.models):
            if i in self.failed:
                out.append(self.failed[i])
                continue
            batches = dict(sorted(merged[i].items()))
            result = self.attempt(i, lambda scored=scored, batches=batches: finish(scored, batches))
            out.append(self.failed[i] if i in self.failed else result)
        return out


def _finished(
    protocol: Protocol, scored: Scored, batches: dict, device, recorded: dict[str, Any]
) -> EvalResult:
    """A model's result from its errors per batch: per-action sums, the long-format rows of
    both averagings, per-window errors, and the sealed protocol record (with ``recorded``
    beside the model's own provenance)."""
    accumulators, log = _accumulate(batches, protocol.actions)
    history = scored.history_record(protocol.input_frames)
    record = _sealed(
        protocol, scored.name, device, {**recorded, **history, **(scored.provenance or {})}
    )
    return EvalResult(
        frame=_frame(accumulators, record, record["windows_per_action"]),
        protocol=record,
        windows=log.compute(
            protocol.dataset.sequences,
            protocol.index,
            protocol.actions,
            record["protocol_id"],
            protocol.window_frames,
        ),
    )


def frame_from_windows(windows: WindowErrors, record: dict[str, Any]) -> pd.DataFrame:
    """The long-format rows that the per-window errors ``windows`` give under ``record`` (a
    result's protocol record), summed as the evaluator sums them: a stored ``results.csv``
    recomputed from its own ``windows.npz`` (which keeps the errors in float32, so the two
    agree to that rounding, far inside :mod:`zoo.evaluation.tolerance`)."""
    errors = {key: values.astype(np.float64) for key, values in windows.errors.items()}
    accumulators, _ = _accumulate({0: errors}, windows.action)
    return _frame(accumulators, record, record["windows_per_action"])


def _progress(protocol: Protocol, models: list[Scored], dist_info: DistInfo):
    """Windows scored so far, on stderr, for an evaluation that takes more than a few seconds
    (nothing for a short one; the first process only under torchrun)."""

    names = ", ".join(m.name for m in models) if len(models) <= 3 else f"{len(models)} rows"
    return progress_bar(
        total=len(protocol.index),
        desc=f"{names} on {protocol.benchmark.name}/{protocol.sampler}",
        unit="window",
        delay=3,
        mininterval=2,
        leave=False,
        dynamic_ncols=True,
        file=sys.stderr,
        disable=dist_info.rank != 0,
    )


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


def predict(
    model: torch.nn.Module,
    history: torch.Tensor,
    task: str,
    frames: int,
    final_frame: torch.Tensor | None = None,
    *,
    hooks: Hooks | None = None,
) -> torch.Tensor:
    """A model's prediction for one of the evaluator's tasks (see ``TASKS``); ``hooks``: the
    model's, when already read (:func:`zoo.models.hooks.model_hooks`)."""
    if task == "prediction":
        return model(history)
    if task == "completion":
        if "final_frame" not in inspect.signature(model.forward).parameters:
            raise EvaluationError(
                f"{type(model).__name__} does no completion: its forward takes no final_frame"
            )
        return model(history, final_frame=final_frame)
    if (hooks or model_hooks(model)).rollout:  # a model's own (cheaper) autoregression
        return model.rollout(history, frames)
    t_in, window, out, produced = history.shape[1], history, [], 0
    while produced < frames:
        step = model(window[:, -t_in:])
        out.append(step)
        produced += step.shape[1]
        window = torch.cat([window, step], dim=1)
    return torch.cat(out, dim=1)[:, :frames]


def checked_prediction(
    pred, expected: tuple, model_name: str, start: int, history: torch.Tensor | None = None
) -> torch.Tensor:
    """A model's output on CPU in float32, or an error if it breaks the contract (the shape,
    finite values and, given the ``history`` it saw, the history's units)."""
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
    if history is not None:
        _check_units(pred, history.detach().to("cpu", torch.float32), model_name)
    return pred


# what a factor of 10^k between a prediction's scale and its history's most likely is
_UNIT_SLIPS = {
    -3: "metres where the benchmark gives millimetres",
    -2: "decimetres where the benchmark gives millimetres, or metres where it gives centimetres",
    -1: "centimetres where the benchmark gives millimetres",
    1: "millimetres where the benchmark gives centimetres",
    3: "millimetres where the benchmark gives metres",
}


def _check_units(pred: torch.Tensor, history: torch.Tensor, model_name: str) -> None:
    """Refuse a prediction whose scale (mean absolute coordinate) is two or more orders of
    magnitude from its history's: a model answering in other units, not a worse prediction
    (a model that predicts nothing at all, zeros, is scored as it is)."""
    seen, said = history.abs().mean().item(), pred.abs().mean().item()
    if seen == 0 or said == 0:
        return
    ratio = said / seen
    if 1e-2 < ratio < 1e2:
        return
    power = round(math.log10(ratio))
    unit = _UNIT_SLIPS.get(power, f"a unit 10^{power} times the benchmark's")
    raise EvaluationError(
        f"model {model_name!r} predicted coordinates {ratio:.3g} times the scale of the history "
        f"it was given (mean absolute coordinate {said:.4g} against {seen:.4g}): likely "
        f"{unit}; a model answers in the dataset's units (zoo.models)"
    )


def _sealed(protocol: Protocol, model_name: str, device, provenance: dict | None) -> dict[str, Any]:
    """The protocol's record (with its ``protocol_id``) and who measured it, when and how."""
    record = copy.deepcopy(protocol.record)
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
    return record


def _my_batches(windows: int, batch_size: int, dist_info: DistInfo) -> range:
    """First windows of this process's batches: every ``world``-th batch (all of them alone)."""
    return range(dist_info.rank * batch_size, windows, dist_info.world * batch_size)


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
