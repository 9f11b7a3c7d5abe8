"""Validation: the mean error that picks the best epoch, and the error at a few horizons beside
repeat-last's, logged every epoch; and the check of a model's output before the first step."""

from __future__ import annotations

from typing import Any

import torch

from zoo.core.errors import EvaluationError, TrainingError
from zoo.core.options import EVAL_BATCH
from zoo.data.windows import gather_windows
from zoo.evaluation.evaluator import checked_prediction, predict
from zoo.protocol.metrics import mpjpe, vertex_rmse


def check_output(model, model_name, positions, index, used, t_in, t_out, task, device) -> None:
    """Before the first step: the model's prediction for one validation window has the
    contract's shape, or the one-line error ``zoo eval`` gives (else a wrong shape ends training
    in a traceback from inside the loss). Its values are not judged: a model may set itself up
    in its first epoch's hook, which has not run yet."""
    window = torch.from_numpy(gather_windows(positions, index[:1], t_in + t_out)[:, :, used])
    window = window.to(device)
    was_training = model.training
    model.eval()
    try:
        with torch.no_grad():
            pred = predict(model, window[:, :t_in], task, t_out, window[:, -1])
        shape_only = torch.nan_to_num(pred) if isinstance(pred, torch.Tensor) else pred
        checked_prediction(shape_only, (1, t_out, window.shape[2], 3), model_name, 0)
    except EvaluationError as e:
        raise TrainingError(f"{e}; nothing was trained") from None
    finally:
        model.train(was_training)


# Validation horizons logged every epoch beside the mean (the first predicted frame, then the
# short, middle and long horizons of the papers' tables), each with repeat-last's error on the
# same windows as the reference a prediction must beat.
VALIDATION_HORIZONS_MS = (80, 400, 1000)


def validation_frames(t_out: int, fps: float) -> dict[str, int]:
    """``{label: 0-based predicted frame}``: the first predicted frame and the frame nearest
    each of :data:`VALIDATION_HORIZONS_MS` that the window reaches, each labelled with its own
    time (frame ``t`` is at ``t * 1000 / fps`` ms: at 30 fps the frame nearest 80 ms is at 67)."""
    frames = {f"{1000 / fps:.0f} ms (first frame)": 0}
    for ms in VALIDATION_HORIZONS_MS:
        t = int(round(ms * fps / 1000))
        if 1 < t <= t_out:
            frames[f"{t * 1000 / fps:.0f} ms"] = t - 1
    return frames


@torch.no_grad()
def validate(
    model,
    positions,
    index,
    t_in,
    t_out,
    used,
    device,
    batch_size: int = EVAL_BATCH,
    task: str = "prediction",
    fps: float | None = None,
    curve: str = "mpjpe",
    points=None,
) -> dict[str, Any]:
    """Validation errors: ``val_mpjpe``, the mean MPJPE (mm; mean vertex error on a mesh) over
    windows and predicted frames, which picks the best epoch; and, given ``fps``,
    ``val_horizons``: the error ``curve`` (``mpjpe`` or ``rmse``, the normalised vertex RMSE:
    its representation's choice) at each of :func:`validation_frames`, the model's and
    repeat-last's on the same windows. A completion model (``task``) is given each window's last
    frame as its final frame. ``points``: what the windows' frames are scored as, where not
    as they are (a representation's ``training_points``: an angle model's, FK joints)."""
    model.eval()
    total, count = 0.0, 0
    per_frame = {who: torch.zeros(t_out, dtype=torch.float64) for who in ("model", "repeat_last")}
    error = {"mpjpe": mpjpe, "rmse": vertex_rmse}[curve]
    for start in range(0, len(index), batch_size):
        w = torch.from_numpy(
            gather_windows(positions, index[start : start + batch_size], t_in + t_out)[:, :, used]
        ).to(device)
        pred = predict(model, w[:, :t_in], task, t_out, w[:, -1])
        future = w[:, t_in:]
        same = w[:, t_in - 1 : t_in]
        if points is not None:  # the last observed frame's points once, not once a future frame
            pred, future, same = points(pred), points(future), points(same)
        same = same.expand_as(future)
        err = mpjpe(pred, future)
        total += err.sum().item()
        count += err.numel()
        if fps is not None:
            per_frame["model"] += (
                (err if error is mpjpe else error(pred, future)).double().sum(0).cpu()
            )
            per_frame["repeat_last"] += error(same, future).double().sum(0).cpu()
    result: dict[str, Any] = {"val_mpjpe": total / count}
    if fps is not None:
        frames = validation_frames(t_out, fps)
        result["val_horizons"] = {
            "metric": curve,
            "horizons": list(frames),
            **{
                who: [float(errors[t]) / len(index) for t in frames.values()]
                for who, errors in per_frame.items()
            },
        }
    return result


def horizons_text(horizons: dict[str, Any]) -> str:
    """One log line's worth of :func:`validate`'s ``val_horizons``."""
    digits = 4 if horizons["metric"] == "rmse" else 1
    return f"val {horizons['metric']} " + ", ".join(
        f"{h} {m:.{digits}f} (repeat-last {r:.{digits}f})"
        for h, m, r in zip(horizons["horizons"], horizons["model"], horizons["repeat_last"])
    )


# How close to repeat-last's validation error, at every logged horizon, an epoch must be for
# the engine to say it cannot be told apart from predicting no motion.
LIKE_REPEAT_LAST = 0.01


def like_repeat_last(horizons: dict[str, Any] | None) -> bool:
    """Whether :func:`validate`'s ``val_horizons`` are repeat-last's at every horizon, within
    :data:`LIKE_REPEAT_LAST` of it: a model that has learnt to predict no motion."""
    if not horizons:
        return False
    return all(
        abs(m - r) <= LIKE_REPEAT_LAST * r
        for m, r in zip(horizons["model"], horizons["repeat_last"])
    )
