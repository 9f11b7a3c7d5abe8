"""What a run writes and reads back: the checkpoint's contents (``best.pt``, ``last.pt``), the
checks of a resume, and the weights a new stage starts from."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import nn

from zoo.core.distributed import DistInfo
from zoo.core.errors import TrainingError
from zoo.core.io import atomic_path, code_version, repo_relative, sha256_file
from zoo.hub.checkpoints import (
    CheckpointError,
    ResumeState,
    checkpoint_payload,
    model_origin,
    model_protocol,
    plain,
    read_checkpoint,
    save_checkpoint,
    stored_hparams,
    trained_model,
    weights_digest,
)
from zoo.hub.records import RunRecord
from zoo.hub.weights import read_weights
from zoo.models.recipe import DEFAULT_RECIPE, Recipe, patience_spent
from zoo.models.registry import Registry
from zoo.protocol.benchmark import Benchmark
from zoo.train.host import device_name, devices_text


def save_epoch(
    out_dir: Path,
    record: RunRecord,
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    epoch: int,
    best: dict[str, Any],
    history: list[dict[str, Any]],
    recipe: Recipe,
    device,
) -> None:
    """The checkpoints of a finished epoch (0-based ``epoch``): ``best.pt`` when it is the best
    so far, and ``last.pt``, the full state ``--resume`` continues from (optimiser, RNG)."""
    summary = _training_summary(recipe, history, best, device)
    if best["epoch"] == epoch + 1:
        # the curve up to this epoch travels too: a run whose best is its last epoch ships
        # one file, and its training plot with it
        save_checkpoint(
            out_dir / "best.pt",
            checkpoint_payload(record, model.state_dict(), list(history), summary),
        )
    resume = ResumeState(
        optimizer=optimizer.state_dict(),
        rng=torch.get_rng_state(),
        epoch=epoch,
        best=best,
        # dropout on a GPU draws from the device's generator
        cuda_rng=(
            torch.cuda.get_rng_state(torch.device(device))
            if torch.device(device).type == "cuda"
            else None
        ),
    )
    save_checkpoint(
        out_dir / "last.pt",
        checkpoint_payload(record, model.state_dict(), history, summary, resume),
    )


# The run's budget may change when it is resumed (its epochs, batches an epoch, and patience,
# which only says when to stop: counted from the best epoch of the whole history, a lower one may
# end the run after its next epoch, and one already spent is refused), and its precision with the
# machine (a GPU's float32 epochs, a bfloat16 CPU's): each change is recorded with the epoch it
# took effect, and each epoch records its precision; every other field of the recipe must stay
# what the checkpoint says.
BUDGET_FIELDS = ("epochs", "max_batches", "patience", "precision")


def resume_changes(
    path: Path, state: dict[str, Any], recipe: Recipe, seed: int, max_batches: int | None
) -> list[dict[str, Any]]:
    """The checkpoint's recorded recipe changes plus this resume's; refuses any change that is
    not the budget, naming the fields."""
    stored = state.get("recipe") or {}
    given = plain(recipe.as_dict())
    differ = [
        f"{key}: {stored.get(key, DEFAULT_RECIPE.get(key))!r} in the checkpoint, "
        f"{given.get(key)!r} now"
        for key in sorted(set(stored) | set(given))
        # a key the checkpoint predates held its default then
        if key not in BUDGET_FIELDS and stored.get(key, DEFAULT_RECIPE.get(key)) != given.get(key)
    ]
    if state.get("seed") != seed:
        differ.append(f"seed: {state.get('seed')!r} in the checkpoint, {seed!r} now")
    if differ:
        raise CheckpointError(
            f"{path}: cannot resume with another recipe ({'; '.join(differ)}); only the "
            f"budget (epochs, max_batches, patience) and precision may change on resume. Resume "
            f"with the checkpoint's values, or start a new run in another out_dir"
        )
    done = state["epoch"] + 1
    if recipe.epochs <= done:  # nothing left to train: a resume that would do nothing
        raise CheckpointError(
            f"epochs: cannot resume {path} with {recipe.epochs} epochs: the run has already "
            f"trained {done} epochs (--epochs with more continues it)",
            parameter="epochs",
        )
    best_epoch = (state.get("best") or {}).get("epoch", -1)
    if patience_spent(recipe, done, best_epoch):  # it would stop before an epoch
        since = done - max(best_epoch, 0)  # as patience_spent counts them
        best = f"its best (epoch {best_epoch})" if best_epoch > 0 else "it began (no best named)"
        raise CheckpointError(
            f"{path}: cannot resume with patience {recipe.patience}: its validation error has "
            f"not improved in the {since} epochs since {best}; "
            f"--train-set patience=null, or one over {since}, continues it"
        )
    changes = list(state.get("recipe_changes") or [])
    now = {
        "epochs": recipe.epochs,
        "max_batches": max_batches,
        "patience": recipe.patience,
        "precision": recipe.precision,
    }
    before = {
        "epochs": stored.get("epochs"),
        "max_batches": state.get("max_batches"),
        "patience": stored.get("patience", DEFAULT_RECIPE["patience"]),
        "precision": stored.get("precision", DEFAULT_RECIPE["precision"]),
    }
    for field in BUDGET_FIELDS:
        # Checkpoints written before max_batches was recorded cannot say what it was.
        if field in stored or field in state or field in ("patience", "precision"):
            if before[field] != now[field]:
                changes.append(
                    {
                        "field": field,
                        "from": before[field],
                        "to": now[field],
                        "from_epoch": done + 1,
                    }
                )
    return changes


def restore_paused(out_dir: Path, benchmark: str, model: str, root=None) -> Path | None:
    """Where ``out_dir`` holds no ``last.pt``: the committed paused state of ``model`` on
    ``benchmark`` copied there (its ``last.pt`` and ``best.pt``), so ``--resume`` continues it on
    a new machine; returns the folder copied from, or None where there is none."""
    import shutil

    from zoo.hub.weights import paused_dir, paused_summary_of

    # a run of its own, paused under its folder's name (zoo weights pause --as), else the model's
    own = paused_dir(benchmark, out_dir.name, root)
    source = own if own.name != model and paused_summary_of(own).get("model") == model else None
    source = source or paused_dir(benchmark, model, root)
    if (out_dir / "last.pt").is_file() or not (source / "last.pt").is_file():
        return None
    out_dir.mkdir(parents=True, exist_ok=True)
    # a state whose best epoch is its last stores it once (zoo weights pause)
    best = source / ("last.pt" if paused_summary_of(source).get("best_is_last") else "best.pt")
    # last.pt copied last: a half-copied run has none
    for name, path in (("best.pt", best), ("last.pt", source / "last.pt")):
        if path.is_file():
            with atomic_path(out_dir / name) as tmp:
                shutil.copyfile(path, tmp)
    return source


def initial_weights(
    path: str | Path, model_name: str, bench: Benchmark, registry: Registry, data_root, dataset
) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """The state dict a new training stage starts from, and what the run records about it: the
    file, its kind and sha256, and the source's own recipe, budget and origin (so a chain of
    stages keeps every budget). The source is a training checkpoint (``.pt``) or shipped weights
    (``.safetensors``, checked against their record's sha256), so anyone can extend a published
    row's training from the repository alone; shipped weights may be float16, and the record
    says so. Refused, naming the file, if it holds another model or was trained for another
    protocol or data (the checks of ``trained_model``)."""
    path = Path(path)
    if path.suffix not in (".pt", ".safetensors"):
        raise TrainingError(
            f"init_from: {path}: expected a training checkpoint (best.pt or last.pt) or "
            f"shipped weights (.safetensors with their .json record)",
            parameter="init_from",
        )
    if not path.is_file():
        raise TrainingError(f"init_from: {path}: no such file", parameter="init_from")
    if path.suffix == ".safetensors":
        state_dict, meta = read_weights(path)
        kind, digest, training = "weights", meta.sha256, meta.training
    else:
        payload = read_checkpoint(path)
        meta, state_dict = RunRecord.of_checkpoint(payload), payload["state_dict"]
        kind, digest, training = "checkpoint", sha256_file(path), payload.get("training")
    if meta.model != model_name:
        raise TrainingError(
            f"init_from: {path}: it holds {meta.model!r}, not {model_name!r}",
            parameter="init_from",
        )
    source = trained_model(
        meta,
        state_dict,
        kind,
        path,
        registry=registry,
        benchmark=bench,
        data_root=data_root,
        dataset=dataset,
    )
    record = {
        "path": repo_relative(path),
        "kind": kind,
        "sha256": digest,
        **({"dtype": meta.dtype} if kind == "weights" else {}),
        "hparams": meta.hparams,
        "recipe": meta.recipe,
        "max_batches": meta.max_batches,
        "recipe_changes": meta.recipe_changes,
        "training": training,
        "init_from": meta.init_from,
    }
    return source.state_dict(), record


def run_record(entry, hparams, bench, dataset, recipe, seed, dist_info, view, **run) -> RunRecord:
    """The run's record (``run``: its budget cap, recipe changes, initial stage, validation)."""
    stored, context_hashes = stored_hparams(hparams)
    return RunRecord(
        model=entry.name,
        origin=model_origin(entry),
        hparams=stored,
        context_hashes=context_hashes,
        protocol=model_protocol(bench, view),
        training_data=bench.strategy.training_record(dataset, view),
        recipe=plain(recipe.as_dict()),
        seed=seed,
        code_version=code_version(),
        torch=str(torch.__version__),
        world_size=dist_info.world,
        **run,
    )


def _training_summary(recipe, history, best, device) -> dict[str, Any]:
    return {
        "epochs_run": len(history),
        "epochs_planned": recipe.epochs,
        "samples_seen": int(sum(h["samples"] for h in history)),
        "seconds": float(sum(h["seconds"] for h in history)),
        "device": str(device),
        "device_name": devices_text(history, device_name(device)),
        "best": best,
        "final_val_mpjpe": history[-1]["val_mpjpe"] if history else None,
    }


def write_rank_digest(out_dir: Path, model: nn.Module, dist_info: DistInfo) -> None:
    from zoo.core.io import atomic_write_text

    atomic_write_text(
        out_dir / "ranks" / f"rank{dist_info.rank}.sha256", weights_digest(model) + "\n"
    )
