"""The training loop: a run set up from its recipe, data and model, resumed or started, then its
epochs, each validated and saved."""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from zoo.core.distributed import DistInfo, init_distributed
from zoo.core.errors import TrainingError
from zoo.core.io import progress_bar, repo_relative
from zoo.data.windows import frame_counts, gather_windows
from zoo.hub.build import model_args_for
from zoo.hub.checkpoints import CheckpointError, read_checkpoint, stored_hparams
from zoo.models.hooks import Hooks, model_hooks
from zoo.models.recipe import (
    DEFAULT_RECIPE,
    Recipe,
    learning_rate,
    patience_spent,
    training_recipe,
)
from zoo.models.registry import ModelEntry, Registry, load_registry
from zoo.paths import REPO_ROOT
from zoo.protocol.benchmark import Benchmark, get_benchmark
from zoo.train.host import cpu_has_native_bfloat16, device_name, precision_on
from zoo.train.options import RunOptions
from zoo.train.split import (
    split_train_val,
    training_view_arrays,
    usable_windows,
    validation_record,
)
from zoo.train.state import (
    initial_weights,
    restore_paused,
    resume_changes,
    run_record,
    save_epoch,
    write_rank_digest,
)
from zoo.train.step import (
    CudaGraphStep,
    TrainingObjective,
    make_optimizer,
    optimizer_for_device,
    prepare_epoch,
    set_learning_rate,
    training_step,
)
from zoo.train.validation import (
    LIKE_REPEAT_LAST,
    check_output,
    horizons_text,
    like_repeat_last,
    validate,
)


def train(
    model_name: str,
    benchmark: str | Benchmark,
    options: RunOptions | None = None,
    *,
    registry: Registry | None = None,
    overrides: dict[str, Any] | None = None,
    recipe_overrides: dict[str, Any] | None = None,
) -> Path:
    """Train ``model_name`` on ``benchmark``'s training split; returns the best checkpoint path.

    ``overrides`` replace the model's hyper-parameters, ``recipe_overrides`` fields of its
    registry recipe (``epochs``, ``lr``, ``precision``, ...); ``options`` say how the run is
    carried out (:class:`zoo.train.options.RunOptions`: seed, device, folders, resume or a new
    stage, time limits)."""
    registry = registry or load_registry()
    bench = get_benchmark(benchmark) if isinstance(benchmark, (str, Path)) else benchmark
    entry = registry.get(model_name)
    _check_trainable(entry)
    entry.load_class()  # a class that cannot load fails here, before the data is read
    options = options or RunOptions()
    device, init_from, data_root = options.device, options.init_from, options.data_root
    dist_info = init_distributed(device)
    out_dir = (
        Path(options.out_dir)
        if options.out_dir
        else REPO_ROOT / "checkpoints" / bench.name / model_name
    )
    registry_train = {**({"val_split": bench.val_split} if bench.val_split else {}), **entry.train}
    state = _resume_state(out_dir, bench, model_name, dist_info.rank) if options.resume else None
    continued: dict[str, Any] = {}
    if state is not None:
        continued, said = _continued_budget(
            state, training_recipe(registry_train), recipe_overrides or {}
        )
        for line in said if dist_info.rank == 0 else ():
            print(line)
    recipe = training_recipe(registry_train, {**continued, **(recipe_overrides or {})})
    _warn_slow_bfloat16(model_name, recipe, device)
    view = bench.view_for(entry.representation)
    # a skeleton model on a mesh benchmark trains on its regressed joints
    dataset, points = bench.strategy.training_data(
        bench.load(data_root, split=bench.train_split), view
    )
    _, hparams = model_args_for(
        registry, model_name, bench, data_root=data_root, dataset=dataset, overrides=overrides
    )
    initial = _initial_stage(init_from, out_dir, model_name, bench, registry, data_root, dataset)

    model = _new_model(registry, model_name, hparams, options.seed, device, initial, init_from)
    hooks = model_hooks(model, model_name)  # refuses a model defining half a group of hooks
    graphed = options.cuda_graph and torch.device(device).type == "cuda" and not dist_info.active
    optimizer = make_optimizer(model, recipe, device, graphed)
    data = _training_windows(
        model, model_name, bench, dataset, points, recipe, hooks, options.progress
    )

    run = _Run(first_epoch=0, best={"val_mpjpe": math.inf, "epoch": -1}, history=[])
    run.init_record = initial[1] if initial is not None else None
    if state is not None:
        run = _resumed(
            out_dir / "last.pt", state, model_name, hparams, model, optimizer, recipe, options,
            graphed,
        )  # fmt: skip

    epochs = _Epochs(
        model_name, model, optimizer, recipe, data, options, dist_info, graphed, task=entry.task,
        fps=dataset.fps,
        curve=bench.strategy.validation_curve(view),
        points=bench.strategy.training_points(dataset, view),
    )  # fmt: skip
    # a resumed run knows how long its epochs take on this machine (not on another one)
    here = device_name(device)
    epochs.longest_epoch = max(
        (h["seconds"] for h in run.history if h.get("device") == here), default=0.0
    )
    record = run_record(
        entry, hparams, bench, dataset, recipe, options.seed, dist_info, view,
        max_batches=options.max_batches,
        recipe_changes=run.recipe_changes,
        init_from=run.init_record,
        validation=validation_record(
            dataset, recipe, data.length, len(data.val_index), len(data.train_index)
        ),
    )  # fmt: skip
    if not data.view and not hooks.training_loss:
        check_output(
            model, model_name, data.val_pos, data.val_index, data.used,
            bench.input_frames, bench.output_frames, entry.task, device,
        )  # fmt: skip
    if dist_info.rank == 0:
        _print_plan(model_name, bench, data, epochs, run.first_epoch, options.seed, out_dir)
    for epoch in range(run.first_epoch, recipe.epochs):
        if patience_spent(recipe, epoch, run.best["epoch"]):
            if dist_info.rank == 0:
                print(
                    f"{model_name}: stopped after epoch {epoch}: no better validation error "
                    f"for {recipe.patience} epochs (patience; best at epoch "
                    f"{run.best['epoch']})",
                    flush=True,
                )
            break
        try:
            line = epochs.run(epoch)
        except OutOfTime as e:
            if dist_info.rank == 0:
                print(f"{model_name}: {e}", flush=True)
            break
        run.history.append(line)
        if dist_info.rank == 0:
            _finish_epoch(out_dir, record, model, optimizer, epoch, run, recipe, device, line)
        if options.stop_after_epoch is not None and epoch + 1 >= options.stop_after_epoch:
            break
    if dist_info.active:
        write_rank_digest(out_dir, model, dist_info)
    if dist_info.rank == 0:
        _warn_if_repeat_last(model_name, run)
    return out_dir / "best.pt"


def _warn_if_repeat_last(model_name: str, run: _Run) -> None:
    """A best epoch whose validation errors are repeat-last's at every horizon: the model has
    learnt to predict no motion, and its rows would say nothing more than repeat-last's."""
    best = next((h for h in run.history if h["epoch"] == run.best["epoch"]), None)
    if best is None or not like_repeat_last(best.get("val_horizons")):
        return
    pairs = horizons_text(best["val_horizons"])
    warnings.warn(
        f"{model_name}: its best epoch ({run.best['epoch']}) cannot be told apart from "
        f"repeat-last (validation within {LIKE_REPEAT_LAST:.0%} of it at every horizon: "
        f"{pairs}); it predicts no motion yet: train longer before scoring it (a model such as "
        f"siMLPe needs about 5 epochs to leave repeat-last)",
        RuntimeWarning,
        stacklevel=3,
    )


def _check_trainable(entry: ModelEntry) -> None:
    """Refuse a model that cannot train before any data is read."""
    if not entry.trainable:
        raise TrainingError(
            f"model {entry.name!r} runs the weights of {entry.weights_of!r} (registry: "
            f"weights_of): train that one ({entry.weights_of})"
            if entry.weights_of
            else f"model {entry.name!r} has nothing to train (registry: trainable: false)"
        )
    if entry.train is None:
        raise TrainingError(
            f"model {entry.name!r} has no training recipe yet (registry: train: null): "
            f"its weights come from elsewhere (zoo weights import, docs/adding-a-model.md)"
        )


def _initial_stage(init_from, out_dir: Path, model_name, bench, registry, data_root, dataset):
    """The weights and record a new stage starts from (``init_from``; None: a first stage),
    refused where this run would overwrite them."""
    if init_from is None:
        return None
    if Path(init_from).resolve() in {(out_dir / f).resolve() for f in ("best.pt", "last.pt")}:
        raise TrainingError(
            f"init_from: {init_from}: this run would overwrite it; give the new stage its own "
            f"out_dir",
            parameter="init_from",
        )
    return initial_weights(init_from, model_name, bench, registry, data_root, dataset)


def _new_model(registry, model_name, hparams, seed, device, initial, init_from) -> nn.Module:
    """The model, seeded (its initial weights, then the run's, derive from ``seed``), with the
    weights a new stage starts from where ``initial`` gives them."""
    torch.manual_seed(seed)
    np.random.seed(seed)
    torch.use_deterministic_algorithms(True, warn_only=True)
    model = registry.create_model(model_name, **hparams).to(device)
    if initial is not None:
        try:
            model.load_state_dict(initial[0])
        except RuntimeError as e:
            raise TrainingError(
                f"init_from: {init_from}: its weights do not fit {model_name} with these "
                f"hyper-parameters: {e}",
                parameter="init_from",
            ) from None
    return model


def _warn_slow_bfloat16(model_name: str, recipe: Recipe, device) -> None:
    if (
        recipe.precision == "bfloat16"
        and torch.device(device).type == "cpu"
        and cpu_has_native_bfloat16() is False
    ):
        warnings.warn(
            f"training {model_name} with precision bfloat16 on a CPU without native "
            f"bfloat16 products (no avx512_bf16 or amx_bf16 flag): torch falls back to a slow "
            f"path (docs/training.md); the recipe's precision float32 is faster here",
            RuntimeWarning,
            stacklevel=3,
        )


@dataclass
class _Data:
    """A run's windows: training ones (``train_src``: the frames, or the model's training view
    of them, ``src_points`` the points taken from each) and validation ones (always frames)."""

    train_src: list
    train_pos: list
    train_index: np.ndarray
    val_pos: list
    val_index: np.ndarray
    used: Any
    src_points: Any
    t_in: int
    length: int

    @property
    def view(self) -> bool:
        return self.train_src is not self.train_pos


def _training_windows(
    model, model_name, bench, dataset, used, recipe, hooks: Hooks, progress
) -> _Data:
    """The training and validation windows of ``dataset``, of its points ``used`` (a
    representation's :meth:`~zoo.protocol.representation.Representation.training_data`)."""
    t_in, t_out = bench.input_frames, bench.output_frames
    length = t_in + t_out
    train_seqs, val_seqs = split_train_val(
        dataset, recipe.val_fraction, length, rule=recipe.val_split
    )
    train_pos, train_index = usable_windows(train_seqs, length, recipe.train_sampler, t_in, t_out)
    val_pos, val_index = usable_windows(val_seqs, length, recipe.val_sampler, t_in, t_out)
    if len(train_index) == 0:
        raise TrainingError(
            f"{dataset.name}/{dataset.split}: training sampler "
            f"{recipe.train_sampler!r} finds no window of {length} frames in "
            f"the training sequences (longest: "
            f"{max((len(a) for a in train_seqs), default=0)} frames); choose "
            f"another train_sampler for the recipe (e.g. all)"
        )
    if len(val_index) == 0:
        raise TrainingError(
            f"{dataset.name}/{dataset.split}: validation sampler "
            f"{recipe.val_sampler!r} finds no window of {length} frames in the held-out "
            f"sequences; choose another val_sampler for the recipe (e.g. all)"
        )
    # A model with a training view trains on windows of that view of every frame, computed once
    # (cached): train_src and src_points say where training windows come from.
    train_src, src_points = train_pos, used
    if hooks.training_view:
        views = training_view_arrays(model, dataset, used, progress=progress)
        view_train, _ = split_train_val(
            dataset, recipe.val_fraction, length, arrays=views, rule=recipe.val_split
        )
        train_src, view_index = usable_windows(
            view_train, length, recipe.train_sampler, t_in, t_out
        )
        src_points = slice(None)
        if not np.array_equal(view_index, train_index):
            raise TrainingError(
                f"{model_name}: its training view changes the sequences' lengths "
                f"(training_view must map every frame to one)"
            )
    return _Data(
        train_src, train_pos, train_index, val_pos, val_index, used, src_points, t_in, length
    )


class OutOfTime(Exception):
    """The run's ``stop_by`` came, or would come, before the epoch could finish."""


@dataclass
class _Run:
    """Where a run stands: its next epoch, best epoch, history and recorded recipe changes."""

    first_epoch: int
    best: dict[str, Any]
    history: list[dict[str, Any]]
    recipe_changes: list[dict[str, Any]] | None = None
    init_record: dict[str, Any] | None = None
    state: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        self.recipe_changes = self.recipe_changes or []


def _resume_state(out_dir: Path, bench, model_name: str, rank: int) -> dict[str, Any]:
    """The run ``out_dir/last.pt`` holds, copied there first from its committed paused state
    where there is none."""
    restored = restore_paused(out_dir, bench.name, model_name)
    if restored is not None and rank == 0:
        print(f"resuming {model_name} from its paused state in {repo_relative(restored)}")
    return read_checkpoint(out_dir / "last.pt")


# A resume continues the run as it last trained: a budget field it is not given keeps the
# checkpoint's value (a study's lifted patience, a forced precision), not the registry's.
CONTINUED = {"epochs": "--epochs {}", "patience": "--train-set patience={}",
             "precision": "--train-set precision={}"}  # fmt: skip


def _continued_budget(
    state: dict[str, Any], registry_recipe: Recipe, given: dict[str, Any]
) -> tuple[dict[str, Any], list[str]]:
    """The budget fields ``state``'s run trained with that this resume is not given, and a
    line for each that is not the registry's, naming the option that takes the registry's."""
    # a patience or precision a checkpoint predates held its default then (as resume_changes
    # reads it); one with no epochs says nothing of them
    defaults = {key: DEFAULT_RECIPE[key] for key in ("patience", "precision")}
    stored = {**defaults, **(state.get("recipe") or {})}
    kept = {key: stored[key] for key in CONTINUED if key in stored and key not in given}
    done = state["epoch"] + 1
    said = []
    for key, value in kept.items():
        registry_value = getattr(registry_recipe, key)
        if value == registry_value:
            continue
        line = f"resuming with the run's {key} {_yaml_text(value)}, not the registry's "
        line += _yaml_text(registry_value)
        if key != "epochs" or registry_value > done:  # an option a resume would refuse: none
            line += f" ({CONTINUED[key].format(_yaml_text(registry_value))} takes it)"
        said.append(line)
    return kept, said


def _yaml_text(value: Any) -> str:
    return "null" if value is None else str(value)


def _resumed(
    path: Path, state: dict[str, Any], model_name, hparams, model, optimizer, recipe, options,
    graphed,
) -> _Run:  # fmt: skip
    """The run ``state`` (read from ``path``) resumed: its weights, optimiser and RNG states
    loaded onto the run's device, and the budget changes this resume makes recorded."""
    if state["model"] != model_name or state["hparams"] != stored_hparams(hparams)[0]:
        raise CheckpointError(
            f"{path}: cannot resume: it holds {state['model']!r} with other hyper-parameters"
        )
    model.load_state_dict(state["state_dict"])
    optimizer.load_state_dict(state["optimizer"])
    torch.set_rng_state(state["rng"])
    history = state["history"]
    for record in history:  # epochs written before they named their device and precision
        record.setdefault("device", (state.get("training") or {}).get("device_name"))
        record.setdefault("precision", (state.get("recipe") or {}).get("precision", "float32"))
    run = _Run(
        first_epoch=state["epoch"] + 1,
        best=state["best"],
        history=history,
        init_record=state.get("init_from"),
        state=state,
    )
    run.recipe_changes += resume_changes(path, state, recipe, options.seed, options.max_batches)
    optimizer_for_device(optimizer, options.device, graphed)
    if "cuda_rng" in state and torch.device(options.device).type == "cuda":
        torch.cuda.set_rng_state(state["cuda_rng"], torch.device(options.device))
    return run


def _print_plan(model_name, bench, data: _Data, epochs: _Epochs, first_epoch, seed, out_dir):
    recipe, taken = epochs.recipe, epochs.step_recipe.precision
    precision = recipe.precision if taken == recipe.precision else f"auto ({taken} here)"
    steps = epochs.steps
    schedule = recipe.schedule or {"type": "constant"}
    print(
        f"training {model_name} on {bench.name}: {len(data.train_index)} training windows "
        f"({recipe.train_sampler}), {len(data.val_index)} validation windows; "
        f"{steps} steps of batch {recipe.batch_size} an epoch, epochs "
        f"{first_epoch + 1}..{recipe.epochs}; adam lr {recipe.lr:g}, schedule "
        f"{schedule}, weight decay {recipe.weight_decay:g}, gradient clip "
        f"{recipe.grad_clip}, {precision}; seed {seed}; checkpoints in {out_dir}",
        flush=True,
    )


class _Epochs:
    """Every epoch's work: the model's epoch hook, the epoch's data order (from seed and epoch
    alone, so a resumed run sees what an uninterrupted one would), its steps, its validation."""

    def __init__(
        self, model_name, model, optimizer, recipe, data: _Data, options: RunOptions,
        dist_info: DistInfo, graphed: bool, *, task: str, fps: float, curve: str,
        points=None,
    ) -> None:  # fmt: skip
        self.model_name, self.model, self.optimizer = model_name, model, optimizer
        self.recipe, self.data, self.seed, self.device = recipe, data, options.seed, options.device
        # the precision steps run in here (the recipe, and so the run's record, may say auto)
        native = cpu_has_native_bfloat16() is True
        taken = precision_on(recipe.precision, options.device, native)
        self.step_recipe = replace(recipe, precision=taken)
        self.dist_info, self.graphed = dist_info, graphed
        self.progress = options.progress and dist_info.rank == 0
        self.task, self.fps, self.curve, self.points = task, fps, curve, points
        self.stop_by, self.longest_epoch = options.stop_by, 0.0
        objective = TrainingObjective(model, task, view=data.view)
        # Some phases leave parameters without gradients (SpecTrHuMS's transformer while the
        # autoencoder trains alone), which DDP must be told to expect.
        self.net = (
            torch.nn.parallel.DistributedDataParallel(objective, find_unused_parameters=True)
            if dist_info.active
            else objective
        )
        self.eager_net, self.compile_proven = self.net, False
        if options.compile:
            if dist_info.active:
                raise TrainingError(
                    "--compile trains in one process: a data-parallel run trains eagerly "
                    "(each process could fall back on its own)",
                    parameter="compile",
                )
            # fallback_random: the compiled step draws eager's random numbers (dropout,
            # AuxFormer's masks), so compiling changes float32 rounding and nothing else
            self.net = torch.compile(self.net, options={"fallback_random": True})
        batch_size = recipe.batch_size
        if batch_size % dist_info.world:
            raise TrainingError(
                f"batch_size {batch_size} must divide evenly over {dist_info.world} processes"
            )
        # Incomplete last batches are dropped, so every process always gets an equal share.
        steps = max(1, len(data.train_index) // batch_size)
        self.steps = min(steps, options.max_batches) if options.max_batches else steps

    def run(self, epoch: int) -> dict[str, Any]:
        """0-based ``epoch`` trained and validated: its record in the run's history."""
        if self.stop_by is not None and time.time() + self.longest_epoch > self.stop_by:
            raise OutOfTime(
                f"stopped before epoch {epoch + 1}: it would end past the time limit (the "
                f"longest epoch so far took {self.longest_epoch:.0f} s)"
            )
        lr, train_loss, started, seen = self.train_epoch(epoch)
        data = self.data
        validation = validate(
            self.model,
            data.val_pos,
            data.val_index,
            data.t_in,
            data.length - data.t_in,
            data.used,
            self.device,
            task=self.task,
            fps=self.fps,
            curve=self.curve,
            points=self.points,
        )
        self.longest_epoch = max(self.longest_epoch, time.perf_counter() - started)
        return {
            "epoch": epoch + 1,
            "lr": lr,
            "train_loss": train_loss,
            **validation,
            "seconds": time.perf_counter() - started,
            "samples": seen,
            "device": device_name(self.device),  # a resumed run may move between machines
            "precision": self.step_recipe.precision,
            **({"compiled": True} if self.net is not self.eager_net else {}),
        }

    def frames(self):
        """``(frames (N, P, 3), counts (N,))``: every distinct frame of the training windows
        once, in a fixed order, with how many training windows hold it (statistics over every
        frame of every window at a fraction of the cost: sampler all puts each frame in
        ``length`` windows), in batches of at most 2**24 values (64 MiB) so big meshes fit."""
        data = self.data
        counts = frame_counts(data.train_index, [len(a) for a in data.train_pos], data.length)
        flat = np.concatenate(counts)
        held = flat > 0
        # each held frame as a one-frame window (sequence, frame) for gather_windows
        frame_index = np.stack(
            [
                np.repeat(np.arange(len(counts)), [len(c) for c in counts]),
                np.concatenate([np.arange(len(c)) for c in counts]),
            ],
            1,
        )[held]
        weights = torch.from_numpy(flat[held])
        src = data.train_src
        batch = max(1, 2**24 // int(np.prod(src[0][:1, data.src_points].shape)))
        for start in range(0, len(frame_index), batch):
            frames = gather_windows(src, frame_index[start : start + batch], 1)[
                :, 0, data.src_points
            ]
            yield (
                torch.from_numpy(np.ascontiguousarray(frames)).to(self.device),
                weights[start : start + batch].to(self.device),
            )

    def train_epoch(self, epoch: int) -> tuple[float, float, float, int]:
        """Runs 0-based ``epoch``'s steps: its last learning rate, mean loss, start time
        (``time.perf_counter``) and the windows seen by all processes."""
        recipe, data, model = self.recipe, self.data, self.model
        # captured anew every epoch: start_epoch may change what a step does (SpecTrHuMS's
        # autoencoder-only phase, then the joint one)
        step_graph = (
            CudaGraphStep(self.net, model, self.optimizer, self.step_recipe, self.device)
            if self.graphed
            else None
        )
        # e.g. warm-up phases, statistics over the data; frames in the model's training view
        # where it trains on one
        prepare_epoch(model, epoch, self.frames, view=data.view)
        order = torch.randperm(
            len(data.train_index),
            generator=torch.Generator().manual_seed(self.seed * 100003 + epoch),
        )
        augment_rng = np.random.default_rng([self.seed, epoch])
        model.train()
        bar = progress_bar(
            total=self.steps,
            desc=f"{self.model_name} epoch {epoch + 1}/{recipe.epochs}",
            unit="batch",
            leave=False,
            dynamic_ncols=True,
            disable=not self.progress,
        )
        started, seen, loss_sum = time.perf_counter(), 0, 0.0
        batch_size, rank, world = recipe.batch_size, self.dist_info.rank, self.dist_info.world
        for step in range(self.steps):
            if self.stop_by is not None and time.time() > self.stop_by:
                raise OutOfTime(
                    f"epoch {epoch + 1} abandoned at batch {step + 1} of {self.steps}: the "
                    f"time limit came; the run stands at its last finished epoch"
                )
            lr = learning_rate(
                recipe.schedule, recipe.lr, epoch, recipe.epochs, epoch * self.steps + step
            )
            set_learning_rate(self.optimizer, lr)
            rows = order[step * batch_size : (step + 1) * batch_size].numpy()
            rows = rows[rank::world]  # this process's share of the batch
            windows = gather_windows(data.train_src, data.train_index[rows], data.length)[
                :, :, data.src_points
            ]
            if "time_reversal" in (recipe.augment or ()):
                flip = augment_rng.random(len(windows)) < 0.5
                windows[flip] = windows[flip, ::-1]
            windows = torch.from_numpy(np.ascontiguousarray(windows)).to(self.device)
            where = f"{self.model_name}: {{loss}} at epoch {epoch + 1}, batch {step + 1}"
            history, future = windows[:, : data.t_in], windows[:, data.t_in :]
            if step_graph is not None:
                loss = step_graph(history, future, where)
            else:
                loss = self.step(history, future, where)
            seen += len(rows) * world
            loss_sum += loss.item()
            bar.update(1)
            bar.set_postfix(
                loss=f"{loss.item():.3f}",
                samples_per_s=f"{seen / (time.perf_counter() - started):.0f}",
            )
        bar.close()
        return lr, loss_sum / self.steps, started, seen

    def step(self, history: torch.Tensor, future: torch.Tensor, where: str) -> torch.Tensor:
        """One optimizer step. A compiler that fails (compiling the forward, or the backward
        at its first call) is said once, and the step is taken again eagerly from the random
        state it began with: no parameter has moved, so the run is the eager one (a BatchNorm's
        running statistics may have taken that batch twice)."""
        args = (self.model, self.optimizer, history, future, self.step_recipe, self.device, where)
        if self.net is self.eager_net or self.compile_proven:
            return training_step(self.net, *args)
        cuda = torch.device(self.device).type == "cuda"
        rng = torch.get_rng_state(), (torch.cuda.get_rng_state(self.device) if cuda else None)
        try:
            loss = training_step(self.net, *args)
        except Exception as e:
            from torch._dynamo.exc import TorchDynamoException  # loaded once compiling ran

            if not isinstance(e, TorchDynamoException):
                raise
            reason = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            print(f"{self.model_name}: torch.compile failed ({reason}); training on eagerly")
            torch.set_rng_state(rng[0])
            if cuda:
                torch.cuda.set_rng_state(rng[1], self.device)
            self.net = self.eager_net
            return training_step(self.net, *args)
        self.compile_proven = True
        return loss


def _finish_epoch(out_dir, record, model, optimizer, epoch, run: _Run, recipe, device, line):
    """Rank 0: the best epoch so far, both checkpoints, and the epoch's log line (``line``: the
    epoch's history record; ``record``: the run's)."""
    val = line["val_mpjpe"]
    if val < run.best["val_mpjpe"]:
        run.best = {"val_mpjpe": val, "epoch": epoch + 1}
    save_epoch(out_dir, record, model, optimizer, epoch, run.best, run.history, recipe, device)
    best = run.best
    print(
        f"{record.model} epoch {epoch + 1}: train loss {line['train_loss']:.4f}, "
        f"val MPJPE {val:.2f} mm (best {best['val_mpjpe']:.2f} at epoch {best['epoch']}), "
        f"{line['seconds']:.1f} s; " + horizons_text(line["val_horizons"]),
        flush=True,
    )


__all__ = ["train"]
