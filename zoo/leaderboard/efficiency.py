"""What a model costs (parameters, forward GFLOPs per window, latency of one window, training
throughput; :func:`measure`, run only by ``zoo costs``), and where those costs are kept
(``results/<benchmark>/costs.json``, :class:`Costs`, keyed by :func:`cost_key`). The format and
what a cost depends on: docs/results.md ("Cost columns").
"""

from __future__ import annotations

import copy
import hashlib
import json
import statistics
import time
from collections.abc import Callable
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import torch

from zoo.models.hooks import model_hooks
from zoo.models.recipe import DEFAULT_RECIPE, Recipe
from zoo.train.host import device_name
from zoo.train.step import TrainingObjective, prepare_epoch, training_step

LATENCY_REPEATS = 20
TRAINING_STEPS = 3
PRECISION = "float32"  # every model is timed in it (see the module docstring)
COSTS_FILE = "costs.json"
COSTS_VERSION = 2


def _windows(batch: int, frames: int, points: int, device) -> torch.Tensor:
    # Positions of the order of a body's (mm); the values do not change the work done.
    generator = torch.Generator().manual_seed(0)
    windows = 100 * torch.randn(batch, frames, points, 3, generator=generator, dtype=torch.float32)
    return windows.to(device)


def forward_gflop(model: torch.nn.Module, history: torch.Tensor) -> float:
    """Forward GFLOPs per window (one window, no gradient), as ``FlopCounterMode`` counts them
    (a multiply-add is 2 FLOPs; element-wise work is not counted)."""
    from torch.utils.flop_counter import FlopCounterMode

    counter = FlopCounterMode(display=False)
    with torch.no_grad(), counter:
        model(history[:1])
    return counter.get_total_flops() / 1e9


def _timed(call: Callable[[], Any], most: int, seconds: float | None) -> list[float]:
    """Wall times (s) of up to ``most`` calls after one warm-up call; with ``seconds``, fewer
    once another call would end past that budget (counted from the warm-up), at least one."""
    started = time.perf_counter()
    call()
    times: list[float] = []
    while len(times) < most:
        before = time.perf_counter()
        call()
        times.append(time.perf_counter() - before)
        if seconds is not None and time.perf_counter() + times[-1] > started + seconds:
            break
    return times


def latency_ms(
    model: torch.nn.Module,
    history: torch.Tensor,
    repeats: int = LATENCY_REPEATS,
    seconds: float | None = None,
) -> tuple[float, int]:
    """Median wall time (ms) of one forward at batch 1, after one warm-up call, and how many
    calls it is the median of (``repeats``, fewer where ``seconds`` runs out)."""
    with torch.no_grad():
        times = _timed(lambda: model(history[:1]), repeats, seconds)
    return 1000 * statistics.median(times), len(times)


def timed_epoch(model: torch.nn.Module, recipe: dict[str, Any]) -> int | None:
    """The epoch whose training step is timed for a model with a ``start_epoch`` hook (None
    without one): the recipe's last (the engine's default epochs where it gives none)."""
    if not model_hooks(model).start_epoch:
        return None
    return max(int({**DEFAULT_RECIPE, **recipe}["epochs"]) - 1, 0)


def training_samples_per_s(
    model: torch.nn.Module,
    task: str,
    recipe: dict[str, Any],
    input_frames: int,
    output_frames: int,
    points: int,
    device="cpu",
    steps: int = TRAINING_STEPS,
    seconds: float | None = None,
) -> tuple[float, int]:
    """Training windows per second of full optimizer steps in float32 (whatever the recipe's
    precision) on a copy of ``model`` (the model itself is left untouched), after one warm-up
    step, and how many steps were timed (``steps``, fewer where ``seconds`` runs out); a model
    with a training view steps on windows of it, and one with a ``start_epoch`` hook in the
    recipe's last epoch, as the engine trains it."""
    trainee = copy.deepcopy(model).to(device).train()
    view = model_hooks(trainee).training_view  # trained on its view, computed once (zoo.train)
    objective = TrainingObjective(trainee, task, view=view)
    optimizer = torch.optim.Adam(trainee.parameters(), lr=1e-6)
    batch = recipe["batch_size"]
    windows = _windows(batch, input_frames + output_frames, points, device)
    if view:
        with torch.no_grad():
            flat = trainee.training_view(windows.flatten(0, 1)).to(windows.dtype)
        windows = flat.view(batch, input_frames + output_frames, *flat.shape[1:])
    last = timed_epoch(trainee, recipe)
    if last is not None:
        # the step of the recipe's last epoch, as the engine prepares it: a model whose epochs
        # differ (SpecTrHuMS: autoencoder-only first, then the transformer too) is timed in the
        # phase that ends its training; the statistics the hook computes (on the copy) are taken
        # over the timed windows' frames
        frames = windows.flatten(0, 1)
        every = [(frames, torch.ones(len(frames), dtype=torch.long, device=device))]
        prepare_epoch(trainee, last, lambda: iter(every), view=view)
    history, future = windows[:, :input_frames], windows[:, input_frames:]

    # every model's column in one precision
    in_float32 = replace(Recipe.of(recipe), precision="float32")

    def step():
        training_step(
            objective, trainee, optimizer, history, future, in_float32, device,
            where=f"timing a training step of {type(model).__name__}: {{loss}} on random "
            f"windows (zoo costs)",
        )  # fmt: skip

    times = _timed(step, steps, seconds)
    return len(times) * batch / sum(times), len(times)


def _threads() -> str:
    n = torch.get_num_threads()
    return f"{n} thread{'s' if n != 1 else ''}"


def machine(device="cpu") -> str:
    """The machine a cost was measured on: the device's name and torch's thread count."""
    return f"{device_name(device)}, {_threads()}"


def measure(
    model: torch.nn.Module,
    *,
    input_frames: int,
    output_frames: int,
    points: int,
    task: str = "prediction",
    recipe: dict[str, Any] | None = None,
    device="cpu",
    seconds: float | None = None,
    say: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """The cost columns of one model, in float32, with the machine, thread count and date that
    measured them; ``recipe`` (a trainable model's training recipe) adds its training
    throughput. ``seconds``: the time budget (a quarter for latency where the model also
    trains; None: always ``LATENCY_REPEATS`` and ``TRAINING_STEPS``); ``say``: progress."""
    say = say or (lambda text: None)
    started = time.perf_counter()
    model = model.to(device).eval()
    history = _windows(1, input_frames, points, device)
    parameters = sum(p.numel() for p in model.parameters())
    trains = recipe is not None and parameters > 0
    row = {
        "parameters": parameters,
        "gflop_per_sample": None,
        "latency_ms": None,
        "train_samples_per_s": None,
        "precision": PRECISION,
        "latency_repeats": None,
        "training_steps": None,
        "device": machine(device),
        "threads": torch.get_num_threads(),
        "date": datetime.now(timezone.utc).date().isoformat(),
    }

    def left(share: float) -> float | None:
        return None if seconds is None else started + share * seconds - time.perf_counter()

    def fewer(done: int, most: int) -> str:
        return f" (not {most}: time budget of {seconds:g} s)" if done < most else ""

    if task == "prediction":  # the other tasks take more than the history
        row["gflop_per_sample"] = forward_gflop(model, history)
        say(f"{parameters:,} parameters, {row['gflop_per_sample']:.3g} GFLOP / window")
        row["latency_ms"], row["latency_repeats"] = latency_ms(
            model, history, seconds=left(0.25 if trains else 1.0)
        )
        say(
            f"latency {row['latency_ms']:.3g} ms, median of {row['latency_repeats']} "
            f"call(s){fewer(row['latency_repeats'], LATENCY_REPEATS)}"
        )
    if trains:
        row["train_samples_per_s"], row["training_steps"] = training_samples_per_s(
            model, task, recipe, input_frames, output_frames, points, device, seconds=left(1.0)
        )
        say(
            f"training {row['train_samples_per_s']:.3g} windows / s in {PRECISION}, "
            f"{row['training_steps']} step(s) of {recipe['batch_size']}"
            f"{fewer(row['training_steps'], TRAINING_STEPS)}"
        )
    return row


def cost_key(loaded, bench, dataset, task: str) -> dict[str, Any]:
    """What a model's costs depend on besides the machine (``loaded``: a
    :class:`zoo.hub.model_source.LoadedModel` of ``bench``): its ``architecture`` is the digest of
    this (:func:`architecture`)."""
    from zoo.store.fingerprint import model_fingerprint

    recipe = loaded.recipe or {}
    key = {
        "class": loaded.entry.class_name,
        "hparams": loaded.hparams,
        "view": loaded.view,
        "task": task,
        "points": bench.model_inputs(dataset=dataset, view=loaded.view)["num_points"],
        "input_frames": loaded.frames_read or bench.input_frames,
        "output_frames": bench.output_frames,
        "batch_size": recipe.get("batch_size"),
        "grad_clip": recipe.get("grad_clip"),
        "code": model_fingerprint(type(loaded.model)),
    }
    epoch = timed_epoch(loaded.model, recipe)
    if epoch is not None:  # a model whose step changes with the epoch: which one was timed
        key["timed_epoch"] = epoch
    return key


def architecture(key: dict[str, Any]) -> str:
    text = json.dumps(key, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class Costs:
    """The cost columns of a benchmark's rows, kept in ``<results>/<benchmark>/costs.json``
    (format in the module docstring); ``old``: the file is of the older format, not read."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        data = json.loads(self.path.read_text()) if self.path.is_file() else {}
        self.old = bool(data) and data.get("version") != COSTS_VERSION
        self.rows: dict[str, dict[str, Any]] = {} if self.old else dict(data.get("rows", {}))

    def get(self, label: str, architecture_: str) -> dict[str, Any] | None:
        """The stored costs of row ``label``, while they are those of its ``architecture``."""
        entry = self.rows.get(label)
        if entry is None or entry.get("architecture") != architecture_:
            return None
        return {k: v for k, v in entry.items() if k != "architecture"}

    def as_stored(self, label: str) -> dict[str, Any] | None:
        """The stored costs of row ``label`` whatever architecture they were measured for (a
        row a rebuild keeps as it is, unchecked)."""
        entry = self.rows.get(label)
        return None if entry is None else {k: v for k, v in entry.items() if k != "architecture"}

    def save(self) -> None:
        from zoo.core.io import atomic_write_json

        atomic_write_json(
            self.path, {"version": COSTS_VERSION, "rows": dict(sorted(self.rows.items()))}
        )
