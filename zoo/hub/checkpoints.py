"""Trained models on disk: training checkpoints (``best.pt``, ``last.pt``) and the shipped
weights exported from them (:mod:`zoo.hub.weights` is their file format), read, checked against the
benchmark they are evaluated on, and turned back into models. No training happens here, so
loading weights for inference does not import the training engine.

Both kinds record where their model comes from (``origin``): the registry entry's name, class
path and registry file, with the file's sha256. A checkpoint of a model that no loaded registry
defines is refused naming the registry file to pass with ``--registry``; one whose name now
belongs to another class is refused naming both classes.
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from zoo.core.errors import NamesParameter, ZooError
from zoo.core.io import atomic_path, atomic_write_json, replace_folder, repo_relative, sha256_file
from zoo.hub.build import benchmark_inputs
from zoo.hub.records import RECORD_FORMAT, RunRecord, WeightsError, WeightsRecord
from zoo.hub.state_dicts import fit_summary, foreign_pointer
from zoo.hub.weights import (
    PAUSED_SUMMARY,
    STORAGE_DTYPES,
    checkpoint_label,
    paused_dir,
    read_weights,
    record_file,
    save_safetensors,
    weights_file,
)
from zoo.models.registry import ModelEntry, Registry, class_name, load_registry
from zoo.protocol.benchmark import Benchmark, get_benchmark
from zoo.protocol.views import View

CHECKPOINT_FORMAT = "motion-zoo-checkpoint/1"


class CheckpointError(NamesParameter, ZooError, ValueError):
    pass


def model_origin(entry: ModelEntry) -> dict[str, Any]:
    """Where a trained model's class comes from, as checkpoints and weights record it."""
    return {
        "name": entry.name,
        "class": entry.class_path,
        "registry": repo_relative(entry.source),
        "registry_sha256": sha256_file(entry.source),
        **({"replaces": entry.replaces} if entry.replaces else {}),
    }


def recorded_entry(meta: RunRecord, registry: Registry, source: str) -> ModelEntry:
    """The registry entry of the model that ``meta`` (a checkpoint's or weights' record) holds,
    checked against the class it recorded; ``source`` names the file in errors."""
    from zoo.paths import REPO_ROOT

    name, origin = meta.model, meta.origin or {}
    if name not in registry.entries:
        recorded = origin.get("registry")
        if recorded is None:
            registry.get(name)  # the registry's own error lists what is registered
        path = Path(recorded)
        path = path if path.is_absolute() else REPO_ROOT / path
        where = (
            f"registry file {path}"
            if path.is_file()
            else f"registry file {path}, which does not exist here (find that file)"
        )
        raise CheckpointError(
            f"{source} holds model {name!r} (class {origin.get('class')}) "
            f"from {where}; no loaded registry defines it: pass --registry "
            f"{path} (or set ZOO_REGISTRY). A registry runs code: use only "
            f"registries you trust"
        )
    entry = registry.get(name)
    # by the class's name: a class moved to another module is the same class
    if origin.get("class") and class_name(origin["class"]) != entry.class_name:
        raise CheckpointError(
            f"{source} holds model {name!r} of class {origin['class']} "
            f"(registry {origin.get('registry')}), but the loaded registry's "
            f"{name!r} is class {entry.class_path} ({entry.source}); load the "
            f"registry it was trained with"
        )
    return entry


def model_protocol(bench: Benchmark, view: View | None = None) -> dict[str, Any]:
    """What a trained model's weights depend on: it must match wherever they are evaluated.
    ``view``: ``joints`` for a skeleton model trained on a mesh benchmark's regressed joints."""
    return bench.strategy.weights_protocol(bench, view or bench.own_view)


def stored_hparams(hparams: dict[str, Any]) -> tuple[dict[str, Any], dict[str, str]]:
    """Hyper-parameters as stored: data objects (a spectral basis) become their hashes, and the
    benchmark supplies them again when the checkpoint is loaded."""
    values, hashes = {}, {}
    for key, value in hparams.items():
        if hasattr(value, "hash") and not isinstance(value, (str, int, float, dict, list)):
            hashes[key] = value.hash
        else:
            values[key] = plain(value)
    return values, hashes


def plain(value):
    """Checkpoint metadata as plain Python (loadable with weights_only=True)."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    return value


def weights_digest(model: nn.Module) -> str:
    digest = hashlib.sha256()
    for name, tensor in sorted(model.state_dict().items()):
        digest.update(name.encode())
        digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()


@dataclass
class ResumeState:
    """What ``last.pt`` adds for ``--resume``: the optimiser, the RNG states (the CUDA one on a
    GPU), the last finished epoch (0-based) and the best so far."""

    optimizer: dict[str, Any]
    rng: torch.Tensor
    epoch: int
    best: dict[str, Any]
    cuda_rng: torch.Tensor | None = None


def checkpoint_payload(
    record: RunRecord,
    state_dict: dict[str, torch.Tensor],
    history: list[dict[str, Any]],
    training: dict[str, Any],
    resume: ResumeState | None = None,
) -> dict[str, Any]:
    """What a checkpoint file holds (:data:`CHECKPOINT_FORMAT`): the run's record, the weights,
    the validation curve so far and the training summary, and for ``last.pt`` the resume
    state; :func:`read_checkpoint` reads it back."""
    state = {}
    if resume is not None:
        state = {"optimizer": resume.optimizer, "rng": resume.rng}
        if resume.cuda_rng is not None:
            state["cuda_rng"] = resume.cuda_rng
        state.update(epoch=resume.epoch, best=resume.best)
    return {
        "format": CHECKPOINT_FORMAT,
        **asdict(record),
        "state_dict": state_dict,
        **state,
        "history": history,
        "training": training,
    }


# A paused run's committed state (weights/in_progress): weights in float16 (float32 for a tensor
# past float16's range); Adam's first moments in 8 bits per value with one scale per block of
# MOMENT_BLOCK (signed, symmetric: each decays by beta1 a step, so its rounding fades within a few
# dozen steps), its second moments in bfloat16 (float32's range, so v never underflows to 0).
# read_checkpoint restores the first moments; the rest loads as it is (load_state_dict and
# Optimizer.load_state_dict cast to the parameters' dtype). docs/training.md measures the resume.
PAUSED_WEIGHTS_DTYPE = torch.float16
PAUSED_MOMENTS_DTYPE = torch.bfloat16
MOMENT_BLOCK = 64
QUANTIZED_MOMENTS = ("exp_avg",)


def _compact_tensor(tensor: torch.Tensor) -> torch.Tensor:
    if not tensor.is_floating_point() or tensor.dtype != torch.float32:
        return tensor
    small = tensor.to(PAUSED_WEIGHTS_DTYPE)
    overflow = bool((torch.isfinite(tensor) & ~torch.isfinite(small)).any())
    return tensor if overflow else small


def _quantized(tensor: torch.Tensor) -> dict[str, Any]:
    """``tensor`` as int8 values with a float32 scale per block of :data:`MOMENT_BLOCK`."""
    flat = tensor.detach().float().flatten()
    blocks = torch.nn.functional.pad(flat, (0, -flat.numel() % MOMENT_BLOCK))
    blocks = blocks.view(-1, MOMENT_BLOCK)
    scale = blocks.abs().amax(dim=1) / 127.0
    values = (blocks / torch.where(scale > 0, scale, 1.0)[:, None]).round().to(torch.int8)
    return {"int8": values, "scale": scale, "shape": list(tensor.shape)}


def _dequantized(stored: dict[str, Any]) -> torch.Tensor:
    values = stored["int8"].float() * stored["scale"][:, None]
    count = math.prod(stored["shape"])
    return values.flatten()[:count].reshape(stored["shape"])


def _compact_moment(key: str, value):
    if not torch.is_tensor(value) or not value.is_floating_point() or key == "step":
        return value
    if key in QUANTIZED_MOMENTS:
        return _quantized(value)
    return value.to(PAUSED_MOMENTS_DTYPE)


def compact_payload(payload: dict[str, Any]) -> dict[str, Any]:
    """``payload`` (a checkpoint's contents) in the paused state's storage: float16 weights
    where each tensor fits, 8-bit first and bfloat16 second Adam moments (the step counters as
    they are). ``stored_as`` records what was done; :func:`read_checkpoint` undoes the 8 bits."""
    compact = dict(payload)
    compact["state_dict"] = {k: _compact_tensor(t) for k, t in payload["state_dict"].items()}
    kept = [k for k, t in compact["state_dict"].items() if t.dtype == torch.float32]
    stored = {"weights": "float16", "weights_kept_float32": kept}
    if "optimizer" in payload:
        optimizer = dict(payload["optimizer"])
        optimizer["state"] = {
            index: {key: _compact_moment(key, value) for key, value in state.items()}
            for index, state in payload["optimizer"]["state"].items()
        }
        compact["optimizer"] = optimizer
        stored["optimizer_moments"] = "bfloat16"
        stored["optimizer_int8_blocks"] = {
            "moments": list(QUANTIZED_MOMENTS),
            "block": MOMENT_BLOCK,
        }
    compact["stored_as"] = stored
    return compact


def _expanded(payload: dict[str, Any]) -> dict[str, Any]:
    """A paused state's 8-bit moments as tensors again (a checkpoint without them as it is)."""
    if "optimizer_int8_blocks" not in (payload.get("stored_as") or {}):
        return payload
    for state in payload["optimizer"]["state"].values():
        for key, value in state.items():
            if isinstance(value, dict) and "int8" in value:
                state[key] = _dequantized(value)
    return payload


def save_checkpoint(path: Path, payload: dict[str, Any]) -> None:
    # through a file object: torch.save names the archive inside after the file it writes, and
    # the temporary name is new each time, so an unchanged state would differ in its bytes
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        torch.save(payload, f)


def pause_run(
    run_dir: str | Path,
    root: str | Path | None = None,
    epochs: int | None = None,
    name: str | None = None,
) -> Path:
    """Store the paused training of ``run_dir`` (its ``last.pt`` and ``best.pt``) as the one
    committed state of its model (:func:`zoo.hub.weights.paused_dir`), in the paused storage
    (:func:`compact_payload`), with a ``state.json`` summary; the previous state of that model is
    replaced as a whole. ``epochs``: the run's budget from here, larger than its recipe's (a run
        begun as a pilot), recorded as ``--epochs`` on resume records it. ``name``: a run of its own
    beside the model's queue (a study's run, ``ltd_bf16_seed0``), stored under that name and
    resumed into ``checkpoints/<benchmark>/<name>``. Returns the folder."""
    run_dir = Path(run_dir)
    last = read_checkpoint(run_dir / "last.pt")
    best_path = run_dir / "best.pt"
    best = read_checkpoint(best_path) if best_path.is_file() else None
    if epochs is not None:
        for state in (last, best) if best is not None else (last,):
            _grow_budget(state, epochs, last["epoch"] + 1, run_dir / "last.pt")
    benchmark, model = last["protocol"]["benchmark"], last["model"]
    if best is not None and best["model"] != model:
        raise CheckpointError(
            f"{best_path} holds {best['model']!r}, {run_dir / 'last.pt'} holds {model!r}"
        )
    if name is not None and (
        not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.-]*", name) or name == model
    ):
        raise CheckpointError(
            f"--as {name!r}: expected a run name other than the model's, a plain file name "
            f"(e.g. {model}_bf16_seed0)"
        )
    dest = paused_dir(benchmark, name or model, root)
    summary = paused_summary(last, run=name)
    # a best epoch that is the last one is stored once: resuming copies last.pt as best.pt
    summary["best_is_last"] = best is not None and _same_weights(best, last)
    with replace_folder(dest, markers=(PAUSED_SUMMARY,)) as tmp:
        save_checkpoint(tmp / "last.pt", compact_payload(last))
        if best is not None and not summary["best_is_last"]:
            save_checkpoint(tmp / "best.pt", compact_payload(best))
        summary["files"] = {p.name: p.stat().st_size for p in sorted(tmp.glob("*.pt"))}
        atomic_write_json(tmp / PAUSED_SUMMARY, summary)
    return dest


def _same_weights(best: dict[str, Any], last: dict[str, Any]) -> bool:
    """Whether a run's best epoch is its last (1-based in ``best``, 0-based in ``epoch``), both
    checkpoints holding the same weights."""
    a, b = best["state_dict"], last["state_dict"]
    return (
        (last.get("best") or {}).get("epoch") == last["epoch"] + 1
        and a.keys() == b.keys()
        and all(torch.equal(a[k], b[k]) for k in a)
    )


def _grow_budget(state: dict[str, Any], epochs: int, done: int, path: Path) -> None:
    planned = (state.get("recipe") or {}).get("epochs")
    if isinstance(epochs, bool) or not isinstance(epochs, int) or epochs < max(done, planned or 0):
        raise CheckpointError(
            f"epochs: {path} has run {done} of {planned} epochs; its budget can only grow "
            f"(got {epochs!r})",
            parameter="epochs",
        )
    if epochs == planned:
        return
    state["recipe"] = {**state["recipe"], "epochs": epochs}
    state["recipe_changes"] = [
        *(state.get("recipe_changes") or []),
        {"field": "epochs", "from": planned, "to": epochs, "from_epoch": done + 1},
    ]
    if state.get("training"):
        state["training"] = {**state["training"], "epochs_planned": epochs}


def paused_summary(last: dict[str, Any], run: str | None = None) -> dict[str, Any]:
    """Where a run stands, from its ``last.pt``: what ``zoo list``, the tables and the site say
    of a model still training, and how to resume it."""
    from zoo.models.recipe import Recipe, patience_spent

    history = last.get("history") or []
    recipe = last.get("recipe") or {}
    training = last.get("training") or {}
    done = last["epoch"] + 1
    best = last.get("best") or {"epoch": -1}
    return {
        "model": last["model"],
        "benchmark": last["protocol"]["benchmark"],
        "epochs_run": done,
        "epochs_planned": recipe.get("epochs"),
        # every planned epoch run, or stopped early by the recipe's patience
        "finished": done >= recipe.get("epochs", done)
        or patience_spent(Recipe.of(recipe), done, best["epoch"]),
        "best": last.get("best"),
        "samples_seen": training.get("samples_seen"),
        "minutes": round(training.get("seconds", 0.0) / 60, 1),
        "device_name": training.get("device_name"),
        "epochs": [
            {
                "epoch": h["epoch"],
                "val_mpjpe": h["val_mpjpe"],
                "seconds": round(h["seconds"], 1),
                "precision": h.get("precision", recipe.get("precision", "float32")),
                "device": h.get("device"),
                **({"compiled": True} if h.get("compiled") else {}),
            }
            for h in history
        ],
        "recipe": recipe,
        "seed": last.get("seed"),
        "resume": f"zoo train --model {last['model']} --benchmark "
        f"{last['protocol']['benchmark']} --seed {last.get('seed')} --resume"
        + (f" --max-batches {last['max_batches']}" if last.get("max_batches") else "")
        + (" --compile" if history and history[-1].get("compiled") else "")
        + (f" --out checkpoints/{last['protocol']['benchmark']}/{run}" if run else ""),
        **({"run": run} if run else {}),
    }


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} does not exist")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises several types for truncated or foreign files
        first = (str(e).splitlines() or [""])[0][:200]
        raise CheckpointError(
            f"checkpoint {path} is empty, truncated or not a motion-zoo "
            f"checkpoint ({type(e).__name__}: {first}); train again, or "
            f"restore the file"
        ) from e
    if isinstance(payload, dict) and "format" not in payload:
        raise CheckpointError(foreign_pointer(path, "--checkpoint"))
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(
            f"checkpoint {path} is not a motion-zoo checkpoint (format "
            f"{payload.get('format') if isinstance(payload, dict) else None!r},"
            f" expected {CHECKPOINT_FORMAT!r})"
        )
    return _expanded(payload)


def checkpoint_provenance(path: str | Path, checkpoint: dict[str, Any]) -> dict[str, Any]:
    """What a result computed from ``checkpoint`` records about it: the file (relative to the
    repository when inside it, so stored results name no machine's folders), the
    hyper-parameters, the training summary and the budget it had."""
    return {
        "checkpoint": repo_relative(path),
        "hparams": checkpoint["hparams"],
        "training": checkpoint.get("training", {}),
        # what its budget is measured against (zoo.report.cards.budget_note): a run short of its
        # recipe is marked where its rows are shown
        **{
            key: checkpoint[key]
            for key in ("recipe", "validation", "max_batches")
            if checkpoint.get(key) is not None
        },
    }


def trained_model(
    meta: RunRecord,
    state_dict: dict[str, torch.Tensor],
    kind: str,
    path: str | Path,
    *,
    registry: Registry | None = None,
    benchmark: str | Benchmark | None = None,
    data_root: str | Path | None = None,
    dataset=None,
    model_name: str | None = None,
) -> nn.Module:
    """The model that ``meta`` (a checkpoint's or shipped weights' record) describes, holding
    ``state_dict``, in eval mode; refused with an error naming the ``kind`` ("checkpoint",
    "weights") and ``path`` it came from if it was trained for another protocol or data than
    ``benchmark``. ``model_name``: build it as that entry instead, which must run the recorded
    model's weights (registry ``weights_of``)."""
    source = f"{kind} {path}"
    registry = registry or load_registry()
    entry = recorded_entry(meta, registry, source)
    if model_name is not None and model_name != entry.name:
        variant = registry.get(model_name)
        if variant.weights_of != entry.name:
            raise CheckpointError(
                f"{source} holds model {entry.name!r}, not {model_name!r} (an entry runs "
                f"another's weights only where its registry entry says weights_of: "
                f"{entry.name})"
            )
        entry = variant
    bench = (
        get_benchmark(benchmark or meta.protocol["benchmark"])
        if not isinstance(benchmark, Benchmark)
        else benchmark
    )
    view = bench.view_for(entry.representation)
    expected = model_protocol(bench, view)
    diff = [
        f"{k} ({kind} {meta.protocol.get(k)!r}, benchmark {v!r})"
        for k, v in expected.items()
        if meta.protocol.get(k) != v
    ]
    if diff and bench.weights_from and meta.protocol.get("benchmark") == bench.weights_from:
        # trained on the benchmark this one takes weights from: the same data, other sizes
        source_protocol = model_protocol(get_benchmark(bench.weights_from), view)
        diff = [
            f"{k} ({kind} {meta.protocol.get(k)!r}, benchmark {bench.weights_from} {v!r})"
            for k, v in source_protocol.items()
            if meta.protocol.get(k) != v
        ]
    if diff:
        raise CheckpointError(
            f"{source} was trained for another protocol than benchmark "
            f"{bench.name!r}: " + "; ".join(diff)
        )
    hparams = dict(meta.hparams)
    hashes = meta.context_hashes
    if hashes:
        _, supplied = benchmark_inputs(bench, entry, data_root=data_root, dataset=dataset)
        for key, trained_hash in hashes.items():
            if supplied[key].hash != trained_hash:
                raise CheckpointError(
                    f"{source}: its {key} hash {trained_hash[:16]} "
                    f"differs from benchmark {bench.name!r}'s "
                    f"{supplied[key].hash[:16]} (another basis or mesh); "
                    f"never silently recomputed, retrain for this data"
                )
            hparams[key] = supplied[key]
    model = registry.create_model(entry.name, **hparams)
    problem = fit_summary(model, state_dict)
    if problem:
        raise CheckpointError(f"{source}: weights do not fit model {entry.name!r}: {problem}")
    model.load_state_dict(state_dict)
    return model.eval()


def load_checkpoint(
    path: str | Path,
    *,
    registry: Registry | None = None,
    benchmark: str | Benchmark | None = None,
    model_name: str | None = None,
    data_root: str | Path | None = None,
    dataset=None,
) -> tuple[nn.Module, dict[str, Any]]:
    """The trained model of a checkpoint, checked against the benchmark it will be evaluated on.

    With ``benchmark=None`` the checkpoint's own protocol is used. Data objects the model was
    built with (a spectral basis) come from the benchmark again and must hash the same.
    """
    ckpt = read_checkpoint(path)
    model = trained_model(
        RunRecord.of_checkpoint(ckpt),
        ckpt["state_dict"],
        "checkpoint",
        path,
        registry=registry,
        benchmark=benchmark,
        data_root=data_root,
        dataset=dataset,
        model_name=model_name,
    )
    return model, ckpt


def load_weights(
    path: str | Path,
    *,
    registry=None,
    benchmark=None,
    data_root=None,
    dataset=None,
    model_name: str | None = None,
) -> tuple[torch.nn.Module, WeightsRecord]:
    """The model of shipped weights, checked against ``benchmark`` (default: its own); built as
    ``model_name`` where that entry runs these weights (registry ``weights_of``)."""
    state, record = read_weights(path)
    model = trained_model(
        record,
        state,
        "weights",
        path,
        registry=registry,
        benchmark=benchmark,
        data_root=data_root,
        dataset=dataset,
        model_name=model_name,
    )
    return model, record


def export_weights(
    checkpoint: str | Path,
    *,
    label: str | None = None,
    root: str | Path | None = None,
    dtype: str = "float16",
) -> Path:
    """Write a checkpoint's weights and record under ``<root>/<benchmark>/``; returns the
    ``.safetensors`` path. Both files are written atomically, the record last."""
    if dtype not in STORAGE_DTYPES:
        raise WeightsError(f"weights dtype {dtype!r} unknown; valid: {', '.join(STORAGE_DTYPES)}")
    ckpt = read_checkpoint(checkpoint)
    label = label or checkpoint_label(checkpoint, ckpt["model"])
    if not label or "/" in label or label.startswith("."):
        raise WeightsError(
            f"weights label {label!r} must be a plain file name "
            f"(e.g. {ckpt['model']!r} or {ckpt['model'] + '@last'!r})"
        )
    benchmark = ckpt["protocol"]["benchmark"]
    path = weights_file(benchmark, label, root)
    tensors = {
        name: (t.to(STORAGE_DTYPES[dtype]) if t.is_floating_point() else t)
        .detach()
        .cpu()
        .contiguous()
        for name, t in ckpt["state_dict"].items()
    }
    # float16 ends at 65504: statistics of unnormalised inputs (BatchNorm's running variance of
    # positions in mm) pass it and would load as inf
    overflow = [
        f"{name} (largest magnitude {ckpt['state_dict'][name].abs().max().item():.4g})"
        for name, t in tensors.items()
        if t.is_floating_point()
        and not torch.isfinite(t).all()
        and torch.isfinite(ckpt["state_dict"][name]).all()
    ]
    if overflow:
        raise WeightsError(
            f"{checkpoint}: {len(overflow)} tensor(s) exceed {dtype}'s range: "
            f"{', '.join(overflow[:3])}{', ...' if len(overflow) > 3 else ''}; "
            f"export with --dtype float32"
        )
    with atomic_path(path) as tmp:
        save_safetensors(tensors, tmp, {"format": RECORD_FORMAT, "model": ckpt["model"]})
        digest = sha256_file(tmp)
    record = WeightsRecord(
        **asdict(RunRecord.of_checkpoint(ckpt)),
        label=label,
        benchmark=benchmark,
        file=path.name,
        sha256=digest,
        dtype=dtype,
        parameters=int(sum(t.numel() for t in ckpt["state_dict"].values())),
        training=ckpt.get("training", {}),
        history=ckpt.get("history"),
        checkpoint=repo_relative(checkpoint),
    )
    atomic_write_json(record_file(path), record.to_json())
    return path
