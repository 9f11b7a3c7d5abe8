"""Shipped weights: trained models that a fresh clone evaluates without training.

``weights/<benchmark>/<label>.safetensors`` holds a trained model's tensors (safetensors: loading
runs no pickled code), and ``<label>.json`` beside it its record: model, hyper-parameters,
protocol, training recipe and budget, device, training data and basis hashes, code version, the
checkpoint it came from, and the sha256 of the tensor file, checked on every load. The label is
the model's name for an early-stopped checkpoint (``best.pt``) and ``<model>@last`` for a fully
trained one, as in the leaderboard. Tensors may be stored as float16 to keep the repository
small; they are loaded back into the model's float32, and every committed result of a label is
computed from exactly these stored values.

    zoo weights export checkpoints/cmu/spgsn/last.pt      # -> weights/cmu/spgsn@last.*
    zoo.create_model("spgsn", benchmark="cmu", pretrained=True)
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch

from zoo.core.io import repo_relative, sha256_file
from zoo.hub.records import WeightsError, WeightsRecord
from zoo.hub.state_dicts import FOREIGN_SUFFIXES, foreign_pointer
from zoo.paths import REPO_ROOT

WEIGHTS_DIR = REPO_ROOT / "weights"
STORAGE_DTYPES = {"float32": torch.float32, "float16": torch.float16}


def weights_file(benchmark: str, label: str, root: str | Path | None = None) -> Path:
    return Path(root or WEIGHTS_DIR) / benchmark / f"{label}.safetensors"


def record_file(weights: str | Path) -> Path:
    return Path(weights).with_suffix(".json")


def checkpoint_label(checkpoint: str | Path, model: str) -> str:
    """``<model>@last`` for a fully trained checkpoint (``last.pt``), else the model's name."""
    return f"{model}@last" if Path(checkpoint).name == "last.pt" else model


def read_weights_record(path: str | Path) -> WeightsRecord:
    """The record of shipped weights (tensors neither read nor checked); for weights whose
    licence keeps them out of the repository (:func:`withheld`), the record alone."""
    path = Path(path)
    record_path = record_file(path)
    if path.suffix in FOREIGN_SUFFIXES:
        raise WeightsError(foreign_pointer(path, "--weights"))
    missing = "(a shipped model needs its .safetensors file and the .json record beside it)"
    if not record_path.is_file():
        raise WeightsError(f"weights {path}: {record_path} does not exist {missing}")
    try:
        data = json.loads(record_path.read_text())
    except (OSError, ValueError) as e:
        raise WeightsError(f"weights record {record_path} is not readable JSON ({e})") from e
    record = WeightsRecord.from_json(data, str(record_path))
    if not path.is_file() and not withheld(record):
        raise WeightsError(f"weights {path}: {path} does not exist {missing}")
    return record


def withheld(record: WeightsRecord) -> bool:
    """Imported weights whose licence does not let them be shipped: their record is, naming
    each source file, and the tensors are made where they are needed (:func:`fetch_command`)."""
    return bool(record.imported) and not record.imported.get("redistributable")


def fetch_command(path: Path, record: WeightsRecord) -> str:
    """What makes withheld weights ``path`` here: where their files are and the import that
    rebuilds the very file their record names (its sha256 is checked when they load)."""
    imported = record.imported
    files = ", ".join(f"{f['file']} (sha256 {f['sha256'][:12]}...)" for f in imported["files"])
    sources = " ".join(
        f"{f.get('prefix') or ''}{'=' if f.get('prefix') else ''}FOLDER/{f['file']}"
        for f in imported["files"]
    )
    mapping = imported.get("key_map") or {}
    licence = imported.get("licence") or "none stated"
    return (
        f"its authors' weights are not shipped (licence: {licence}): "
        f"get {files} from {imported.get('source') or 'their authors'} into FOLDER, then "
        f"zoo weights import {sources} --model {record.model} --benchmark {record.benchmark} "
        f"--label {record.label} --weights-dir {path.parent.parent}"
        + (f" --key-map MAP.yaml (MAP.yaml: {json.dumps(mapping)})" if mapping else "")
    )


def save_safetensors(tensors: dict[str, torch.Tensor], path: Path, metadata: dict[str, str]):
    """``tensors`` written to ``path`` as safetensors, the same bytes for the same tensors and
    metadata: the library writes its metadata in a hash map's order, which varies from call to
    call, so the header is written again with that map's keys sorted (its length unchanged)."""
    from safetensors.torch import save_file

    save_file(tensors, str(path), metadata=metadata)
    with open(path, "r+b") as f:
        size = int.from_bytes(f.read(8), "little")
        raw = f.read(size)
        header = json.loads(raw)
        header["__metadata__"] = dict(sorted(header.get("__metadata__", {}).items()))
        text = json.dumps(header, separators=(",", ":"), ensure_ascii=False).encode()
        if len(text) > size:  # never here: the same keys, compact, as the library writes
            raise WeightsError(f"{path}: its safetensors header could not be ordered")
        f.seek(8)
        f.write(text + b" " * (size - len(text)))


def read_weights(path: str | Path) -> tuple[dict[str, torch.Tensor], WeightsRecord]:
    """The float32 state dict and the record of shipped weights, after checking the file's
    sha256 against its record."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    path = Path(path)
    record_path = record_file(path)
    record = read_weights_record(path)
    if not path.is_file():
        raise WeightsError(f"weights {path}: {fetch_command(path, record)}")
    digest = sha256_file(path)
    if digest != record.sha256:
        raise WeightsError(
            f"weights {path}: sha256 {digest[:16]}... differs from its record's "
            f"{record.sha256[:16]}... ({record_path}): the file was "
            f"changed or damaged; restore it (git checkout) or export it again"
        )
    try:
        tensors = load_file(str(path))
    except (SafetensorError, OSError) as e:
        raise WeightsError(f"weights {path} is not a readable safetensors file ({e})") from e
    state = {name: t.float() if t.is_floating_point() else t for name, t in tensors.items()}
    return state, record


def available_weights(root: str | Path | None = None) -> list[tuple[str, str]]:
    """``(benchmark, label)`` of every shipped model under ``root``: each record, with its
    tensors beside it or withheld by their licence (:func:`withheld`)."""
    return sorted((p.parent.name, p.stem) for p in Path(root or WEIGHTS_DIR).glob("*/*.json"))


def training_points(record: WeightsRecord) -> list[tuple[int, float]]:
    """``[(optimizer steps, validation error), ...]`` from a weights record's training history
    (empty where the record holds none)."""
    return [(steps, epoch["val_mpjpe"]) for steps, epoch in record.epochs_by_steps]


def training_horizons(record: WeightsRecord) -> list[tuple[int, dict[str, Any]]]:
    """``[(optimizer steps, val_horizons), ...]``: the per-horizon validation errors (the
    model's and repeat-last's, see :func:`zoo.train.validation.validate`) of every epoch that logged
    them."""
    return [
        (steps, epoch["val_horizons"])
        for steps, epoch in record.epochs_by_steps
        if "val_horizons" in epoch
    ]


# A paused training's state, committed so that the run resumes on the next machine: one folder
# per benchmark and model under weights/in_progress, replaced at each pause. state.json says
# where the run stands without loading the state itself.
PAUSED_FOLDER = "in_progress"
PAUSED_SUMMARY = "state.json"


def paused_dir(benchmark: str, model: str, root: str | Path | None = None) -> Path:
    return Path(root or WEIGHTS_DIR) / PAUSED_FOLDER / benchmark / model


def paused_runs(root: str | Path | None = None) -> dict[tuple[str, str], dict[str, Any]]:
    """``{(benchmark, model): summary}`` of every paused training under ``root``: epochs done and
    planned, best validation epoch, minutes, precision and device of each epoch."""
    runs = {}
    for path in sorted((Path(root or WEIGHTS_DIR) / PAUSED_FOLDER).glob(f"*/*/{PAUSED_SUMMARY}")):
        runs[path.parent.parent.name, path.parent.name] = paused_summary_of(path.parent)
    return runs


def paused_summary_of(folder: Path) -> dict[str, Any]:
    """The ``state.json`` of the paused state in ``folder`` (``{}`` where it has none)."""
    path = Path(folder) / PAUSED_SUMMARY
    if not path.is_file():
        return {}
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise WeightsError(f"{path}: not a readable paused-training summary ({e})") from e


def training_status(paused: dict[str, Any] | None, epochs_planned: int | None) -> str:
    """What a trainable model without shipped weights shows where its rows would be: the
    epochs its paused training has done (``paused``: its summary, or None where none is paused)
    of those planned (the paused run's, else the registry recipe's ``epochs_planned``), its best
    validation so far and the command that resumes it."""
    return f"training: no weights shipped yet ({_progress(paused, epochs_planned)})"


def _progress(paused: dict[str, Any] | None, epochs_planned: int | None) -> str:
    """A paused run's epochs done of those planned, best validation and resume command."""
    done = paused["epochs_run"] if paused else 0
    planned = paused["epochs_planned"] if paused else epochs_planned
    best = (paused or {}).get("best") or {}
    said = [f"{done} of {planned or '?'} epochs done"]
    if best.get("val_mpjpe") is not None:
        said.append(f"best validation {best['val_mpjpe']:.2f} mm at epoch {best['epoch']}")
    if (paused or {}).get("resume"):
        said.append(f"resume: {paused['resume']}")
    return "; ".join(said)


def unshipped_models(
    registry, root: str | Path | None = None, shipped: set[str] | None = None
) -> dict[str, str]:
    """``{model: training status}`` of each trainable registered model with no shipped weights
    on any benchmark (a model running another's weights counts as that one), and of each whose
    shipped weights a paused retraining will replace. ``shipped``: the models with weights,
    where the caller has read the records already."""
    if shipped is None:  # weights of its own: an authors' imported ones do not end a training
        records = (read_weights_record(weights_file(b, label, root)) for b, label in
                   available_weights(root))  # fmt: skip
        shipped = {record.model for record in records if record.imported is None}
    paused = {model: summary for (_, model), summary in paused_runs(root).items()}
    out = {}
    for name in registry.list_models():
        entry = registry.get(name)
        if entry.trainable and entry.train is None and name not in shipped:
            out[name] = "training: no recipe here yet (registry: train: null)"
        elif entry.trainable and (entry.weights_of or name) not in shipped:
            out[name] = training_status(paused.get(name), (entry.train or {}).get("epochs"))
        elif entry.trainable and name in paused and not paused[name].get("finished"):
            out[name] = (
                f"retraining: {_progress(paused[name], None)} (its rows are the earlier "
                f"weights' until this run ships)"
            )
    return out


def pretrained_path(name: str, benchmark: str, root: str | Path | None = None) -> Path:
    """The shipped weights of ``name`` (a model or ``<model>@last``) on ``benchmark``; an error
    listing what exists if there are none."""
    path = weights_file(benchmark, name, root)
    if not path.is_file():
        shipped = [f"{b}/{label}" for b, label in available_weights(root)]
        raise WeightsError(
            f"no shipped weights for {name!r} on benchmark {benchmark!r} "
            f"({path} does not exist); shipped: "
            f"{', '.join(shipped) if shipped else 'none'}"
        )
    return path


def weights_provenance(path: str | Path, record: WeightsRecord) -> dict[str, Any]:
    """What a result computed from shipped weights records about them."""
    return {
        "weights": repo_relative(path),
        "weights_sha256": record.sha256,
        "weights_dtype": record.dtype,
        "hparams": record.hparams,
        "training": record.training,
        **({"imported": record.imported} if record.imported else {}),
    }
