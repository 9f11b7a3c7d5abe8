"""How far a row's forward pass moves when its float32 arithmetic rounds otherwise: the part of a
recomputed result that the a-priori tolerance (:mod:`zoo.evaluation.tolerance`) does not bound,
measured on the spot by ``zoo leaderboard --check`` for a window beyond that tolerance.

A window's *rounding sensitivity*, per error series, is the largest change of any of its
per-frame errors over :data:`PASSES` re-runs of the row's model on it: once in float64 (its
float32 rounding taken away) and four times with its input frames moved by up to :data:`INPUT_ULPS`
float32 units in the last place (data built on another CPU, which differs in its last bits).
Another CPU reproduces a window's errors to within :data:`SENSITIVITY_MULTIPLE` times it;
docs/reproducibility.md ("A tolerance measured where the error model ends") derives the
multiple and measures it.
"""

from __future__ import annotations

import copy
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch
from torch import nn

from zoo.core.errors import ZooError
from zoo.evaluation.evaluator import Scored, evaluate_models
from zoo.evaluation.results import WINDOWS_FILE, WindowErrors
from zoo.evaluation.tolerance import Incomparable, windows_beyond
from zoo.protocol.plan import Protocol
from zoo.protocol.views import View

SENSITIVITY_MULTIPLE = 8.0
INPUT_ULPS = 2
MOVED_INPUTS = (1, 2, 3, 4)  # the draws (seeds) of the passes on moved inputs
PASSES = ("float64", *(f"inputs moved ({seed})" for seed in MOVED_INPUTS))


def _cast(value, dtype: torch.dtype):
    if isinstance(value, torch.Tensor) and value.is_floating_point():
        return value.to(dtype)
    if isinstance(value, (tuple, list)):
        return type(value)(_cast(v, dtype) for v in value)
    if isinstance(value, dict):
        return {k: _cast(v, dtype) for k, v in value.items()}
    return value


def in_float64(model: nn.Module) -> nn.Module:
    """A copy of ``model`` computing in float64 and answering in float32 (one rounding)."""
    copied = copy.deepcopy(model).double()
    copied.register_forward_pre_hook(
        lambda _, args, kwargs: (_cast(args, torch.float64), _cast(kwargs, torch.float64)),
        with_kwargs=True,
    )
    copied.register_forward_hook(lambda _, __, output: _cast(output, torch.float32))
    return copied


def with_inputs_moved(model: nn.Module, seed: int, ulps: int = INPUT_ULPS) -> nn.Module:
    """A copy of ``model`` whose input frames are moved by up to ``ulps`` float32 units in the
    last place, each coordinate by its own draw (seeded: the same every run)."""
    generator = torch.Generator().manual_seed(seed)

    def move(value):
        if not (isinstance(value, torch.Tensor) and value.dtype == torch.float32):
            return value
        steps = torch.randint(-ulps, ulps + 1, value.shape, generator=generator)
        moved = value.double() * (1 + steps.double() * 2.0**-23)
        return moved.to(value.device, torch.float32)

    copied = copy.deepcopy(model)
    copied.register_forward_pre_hook(
        lambda _, args, kwargs: (
            tuple(move(a) for a in args),
            {k: move(v) for k, v in kwargs.items()},
        ),
        with_kwargs=True,
    )
    return copied


def rounding_sensitivity(
    model: nn.Module, label: str, view: View, protocol: Protocol, fresh, device: str = "cpu"
) -> dict[tuple, np.ndarray]:
    """Per error series (``fresh``'s keys), each window's rounding sensitivity on the windows
    of ``protocol``, whose per-window errors ``fresh`` holds (this CPU's float32 pass): the
    largest change of any of its frames over the :data:`PASSES`, shaped like ``fresh`` (one
    value repeated over a window's frames). A pass that fails counts as no measurement (the
    window is then held to the a-priori tolerance alone)."""
    variants = [in_float64(model), *(with_inputs_moved(model, seed) for seed in MOVED_INPUTS)]
    results = evaluate_models(
        [Scored(v, label, view) for v in variants], protocol, device=device, keep_going=True
    )
    sensitivity = {key: np.zeros(values.shape) for key, values in fresh.errors.items()}
    for result in results:
        if isinstance(result, Exception) or result.windows is None:
            continue
        for key, values in fresh.errors.items():
            moved = result.windows.errors.get(key)
            if moved is None or moved.shape != values.shape:
                continue
            change = np.abs(moved.astype(np.float64) - values.astype(np.float64))
            sensitivity[key] = np.fmax(sensitivity[key], np.nan_to_num(change, nan=0.0))
    for key, values in sensitivity.items():  # a window's frames share its largest change
        if values.ndim == 2:
            sensitivity[key] = np.broadcast_to(values.max(axis=1, keepdims=True), values.shape)
    return sensitivity


def rounding_margins(
    computed: list, table: Path, sample: np.ndarray | None, protocol: Protocol, device="cpu"
) -> dict[str, dict[tuple, np.ndarray]]:
    """Per row label, the margin of each of its recomputed values beyond the a-priori
    tolerance: :data:`SENSITIVITY_MULTIPLE` times its rounding sensitivity, measured on those
    windows alone (zero elsewhere). ``computed``: ``(label, model, view, result)`` of the rows
    recomputed on the windows at positions ``sample`` (None: every one) of ``protocol``,
    compared with the stored rows in folder ``table``."""
    margins: dict[str, dict[tuple, np.ndarray]] = {}
    for label, model, view, result in computed:
        try:
            stored = WindowErrors.read(table / label / WINDOWS_FILE)
            beyond = windows_beyond(result.windows, stored, sample)
        except (ZooError, OSError, ValueError, KeyError, Incomparable):
            continue  # missing, unreadable, other windows: the comparison names what is wrong
        if not len(beyond):
            continue
        positions = beyond if sample is None else np.asarray(sample)[beyond]
        fresh = SimpleNamespace(errors={k: v[beyond] for k, v in result.windows.errors.items()})
        measured = rounding_sensitivity(
            model, label, view, protocol.subset(positions), fresh, device
        )
        margins[label] = {}
        for key, values in result.windows.errors.items():
            margin = np.zeros(values.shape)
            margin[beyond] = SENSITIVITY_MULTIPLE * measured[key]
            margins[label][key] = margin
    return margins
