"""What a model costs, measured on the machine that writes a leaderboard: parameters, forward
GFLOPs per sample (torch's FLOP counter), latency of one window (batch 1) and training
throughput (forward, backward, gradient clip and Adam, at the recipe's batch size and precision).

Timings depend on the machine and its load; they go into ``leaderboard.md`` beside the device
that measured them, never into ``results.csv`` (which ``zoo leaderboard --check`` compares).
"""

from __future__ import annotations

import copy
import statistics
import time
from typing import Any

import torch

from zoo.train import TrainingObjective, device_name, forward_precision

LATENCY_REPEATS = 20
TRAINING_STEPS = 3


def _windows(batch: int, frames: int, points: int, device) -> torch.Tensor:
    # Positions of the order of a body's (mm); the values do not change the work done.
    generator = torch.Generator().manual_seed(0)
    return (100 * torch.randn(batch, frames, points, 3, generator=generator)).to(device)


def forward_gflop(model: torch.nn.Module, history: torch.Tensor) -> float:
    """Forward GFLOPs per window (one window, no gradient), as ``FlopCounterMode`` counts them
    (a multiply-add is 2 FLOPs; element-wise work is not counted)."""
    from torch.utils.flop_counter import FlopCounterMode

    counter = FlopCounterMode(display=False)
    with torch.no_grad(), counter:
        model(history[:1])
    return counter.get_total_flops() / 1e9


def latency_ms(
    model: torch.nn.Module, history: torch.Tensor, repeats: int = LATENCY_REPEATS
) -> float:
    """Median wall time (ms) of one forward at batch 1, after one warm-up call."""
    times = []
    with torch.no_grad():
        model(history[:1])
        for _ in range(repeats):
            started = time.perf_counter()
            model(history[:1])
            times.append(time.perf_counter() - started)
    return 1000 * statistics.median(times)


def training_samples_per_s(
    model: torch.nn.Module,
    task: str,
    recipe: dict[str, Any],
    input_frames: int,
    output_frames: int,
    points: int,
    device="cpu",
    steps: int = TRAINING_STEPS,
) -> float:
    """Training windows per second of full optimizer steps on a copy of ``model`` (the model
    itself is left untouched), after one warm-up step; a model with a training view steps on
    windows of it, as the engine trains it."""
    trainee = copy.deepcopy(model).to(device).train()
    view = hasattr(trainee, "training_view")  # trained on its view, computed once (zoo.train)
    objective = TrainingObjective(trainee, task, view=view)
    optimizer = torch.optim.Adam(trainee.parameters(), lr=1e-6)
    batch = recipe["batch_size"]
    windows = _windows(batch, input_frames + output_frames, points, device)
    if view:
        with torch.no_grad():
            flat = trainee.training_view(windows.flatten(0, 1)).to(windows.dtype)
        windows = flat.view(batch, input_frames + output_frames, *flat.shape[1:])
    history, future = windows[:, :input_frames], windows[:, input_frames:]

    def step():
        with forward_precision(recipe.get("precision", "float32"), device):
            loss = objective(history, future)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if recipe.get("grad_clip"):
            torch.nn.utils.clip_grad_norm_(trainee.parameters(), recipe["grad_clip"])
        optimizer.step()

    step()
    started = time.perf_counter()
    for _ in range(steps):
        step()
    return steps * batch / (time.perf_counter() - started)


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
) -> dict[str, Any]:
    """The efficiency columns of one model; ``recipe`` (a trainable model's training recipe)
    adds its training throughput."""
    model = model.to(device).eval()
    history = _windows(1, input_frames, points, device)
    row = {
        "parameters": sum(p.numel() for p in model.parameters()),
        "gflop_per_sample": None,
        "latency_ms": None,
        "train_samples_per_s": None,
        "device": machine(device),
    }
    if task == "prediction":  # the other tasks take more than the history
        row["gflop_per_sample"] = forward_gflop(model, history)
        row["latency_ms"] = latency_ms(model, history)
    if recipe is not None and row["parameters"]:
        row["train_samples_per_s"] = training_samples_per_s(
            model, task, recipe, input_frames, output_frames, points, device
        )
    return row
