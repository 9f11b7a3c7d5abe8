"""Weights from outside the zoo (an authors' ``.pth``) made shipped weights of a registered model:
each file read as a state dict without running its code, its keys mapped onto the model's
(:func:`map_keys`), fitted strictly (a mismatch summarised,
:func:`zoo.hub.state_dicts.fit_summary`), and written as
``<benchmark>/<label>.safetensors`` with a record that names every source file by its sha256 and
where it came from (:func:`import_weights`). The rows scored from them say so (``imported``).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import torch
from torch import nn

from zoo.core.io import atomic_path, atomic_write_json, load_yaml, sha256_file
from zoo.hub.build import model_args_for
from zoo.hub.checkpoints import model_origin, model_protocol, stored_hparams
from zoo.hub.records import RECORD_FORMAT, WeightsError, WeightsRecord
from zoo.hub.state_dicts import fit_summary
from zoo.hub.weights import record_file, save_safetensors, weights_file

# the label suffix of imported weights: their rows sit beside the model's own as <model>@authors
AUTHORS_SUFFIX = "@authors"
# where a training script keeps the state dict inside what it saved, most specific first
_STATE_KEYS = ("state_dict", "model_state_dict", "model", "net", "network", "weights")


def read_state(path: str | Path, state_key: str | None = None) -> tuple[dict, str | None]:
    """``(tensors by key, the key it was found under or None)``: the state dict a file holds,
    read with ``weights_only`` (no code runs); a training script's dictionary is searched for
    it under ``state_key`` or the usual names."""
    path = Path(path)
    if not path.is_file():
        raise WeightsError(f"{path}: no such file")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises several types for pickles of objects, or damage
        first = (str(e).splitlines() or [""])[0][:160]
        raise WeightsError(
            f"{path}: not a state dict that loads without running code ({type(e).__name__}: "
            f"{first}); save its model's state_dict() with torch.save and import that"
        ) from e
    if isinstance(data, nn.Module):
        data = data.state_dict()
    keys = [state_key] if state_key else [None, *_STATE_KEYS]
    for key in keys:
        found = data if key is None else data.get(key) if isinstance(data, dict) else None
        if isinstance(found, dict) and found and all(torch.is_tensor(v) for v in found.values()):
            return dict(found), key
    top = sorted(map(str, data))[:8] if isinstance(data, dict) else [type(data).__name__]
    where = (
        f"under key {state_key!r}" if state_key else "at the top or under " + "/".join(_STATE_KEYS)
    )
    raise WeightsError(
        f"{path}: no state dict (a mapping of names to tensors) {where}; it holds "
        f"{', '.join(top)}: name the key with --state-key"
    )


def read_key_map(path: str | Path | None) -> dict[str, str | None]:
    """A key map file: YAML ``{source prefix: zoo prefix}``, the longest matching prefix
    applied to each key; a prefix mapped to null drops those keys (buffers the zoo's model
    does not keep)."""
    if path is None:
        return {}
    path = Path(path)
    try:
        data = load_yaml(path.read_text())
    except OSError as e:
        raise WeightsError(f"key map {path}: cannot be read ({e.strerror})") from e
    except ValueError as e:
        raise WeightsError(f"key map {path}: not YAML ({e})") from e
    if not isinstance(data, dict) or not all(
        isinstance(k, str) and (v is None or isinstance(v, str)) for k, v in data.items()
    ):
        raise WeightsError(
            f"key map {path}: expected a mapping of key prefixes to prefixes (or null), "
            f"e.g. 'module.encoder.': 'encoder.'"
        )
    return data


def map_keys(state: dict[str, Any], key_map: dict[str, str | None]) -> dict[str, Any]:
    """``state`` with each key's longest prefix in ``key_map`` replaced (or the key dropped)."""
    prefixes = sorted(key_map, key=len, reverse=True)
    out = {}
    for key, value in state.items():
        prefix = next((p for p in prefixes if key.startswith(p)), None)
        if prefix is None:
            out[key] = value
        elif key_map[prefix] is not None:
            out[key_map[prefix] + key[len(prefix) :]] = value
    return out


def import_weights(
    sources: list[tuple[str, Path]],
    *,
    model: str,
    benchmark,
    registry,
    key_map: dict[str, str | None] | None = None,
    state_key: str | None = None,
    label: str | None = None,
    origin: str | None = None,
    licence: str | None = None,
    redistributable: bool = False,
    root: str | Path | None = None,
    data_root: str | Path | None = None,
) -> Path:
    """Write ``sources`` (``(prefix, file)`` pairs: each file's keys under that prefix, ""
    for one file) as shipped float32 weights of registry ``model`` on ``benchmark``; returns the
    ``.safetensors`` path. Refused unless the mapped keys fit the model exactly."""
    label = label or f"{model}{AUTHORS_SUFFIX}"
    if not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.@+=-]*", label):
        raise WeightsError(f"--label {label!r}: expected a plain file name, e.g. {model}@authors")
    state: dict[str, torch.Tensor] = {}
    files = []
    for prefix, path in sources:
        tensors, found_under = read_state(path, state_key)
        state.update({f"{prefix}{k}": v for k, v in tensors.items()})
        files.append(
            {
                "file": Path(path).name,
                "sha256": sha256_file(path),
                **({"prefix": prefix} if prefix else {}),
                **({"state_key": found_under} if found_under else {}),
            }
        )
    state = map_keys(state, key_map or {})
    entry = registry.get(model)
    view, hparams = model_args_for(registry, model, benchmark, data_root=data_root)
    built = registry.create_model(model, **hparams)
    problem = fit_summary(built, state)
    if problem:
        names = ", ".join(str(p) for _, p in sources)
        raise WeightsError(f"{names}: the state dict does not fit model {model!r}: {problem}")
    built.load_state_dict(state)
    tensors = {k: v.detach().float().contiguous() if v.is_floating_point() else v.contiguous()
               for k, v in built.state_dict().items()}  # fmt: skip
    plain, hashes = stored_hparams(hparams)
    path = weights_file(benchmark.name, label, root)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        save_safetensors(tensors, tmp, {"format": RECORD_FORMAT, "model": model})
        digest = sha256_file(tmp)
    record = WeightsRecord(
        model=model,
        hparams=plain,
        protocol=model_protocol(benchmark, view),
        origin=model_origin(entry),
        context_hashes=hashes,
        code_version=None,
        torch=torch.__version__,
        label=label,
        benchmark=benchmark.name,
        file=path.name,
        sha256=digest,
        dtype="float32",
        parameters=int(sum(t.numel() for t in tensors.values())),
        imported={
            "whose": "authors",
            "files": files,
            **({"source": origin} if origin else {}),
            **({"key_map": dict(key_map)} if key_map else {}),
            **({"licence": licence} if licence else {}),
            "redistributable": redistributable,
        },
    )
    atomic_write_json(record_file(path), record.to_json())
    return path
