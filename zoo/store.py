"""Where results go, and what a stored result is: its location and its identity.

A result lives in ``<root>/<benchmark>/<table>/<label>/`` (``results.csv``, ``protocol.json``,
``tables.md``, ``windows.npz``), where ``<table>`` names the sampler, task and ground truth
(:func:`table_folder`) and ``<label>`` the row (a model's name, ``<model>@last``, or a label of
the user's own). Its **identity** is what was measured, recorded in ``protocol.json`` under
``provenance.identity``:

- ``benchmark`` and ``protocol_id`` (data files and their hashes, windows, frames, metrics);
- ``model``: the registry name, class path, registry file and every hyper-parameter (a bare
  ``nn.Module`` handed to :func:`zoo.evaluate`: its class and a hash of its weights);
- ``trained``: the sha256 of the shipped weights or checkpoint it was computed from;
- ``code``: fingerprints of the evaluator, the metrics, the window sampler and the model's
  source (:func:`code_fingerprint`: the syntax tree without docstrings, so comments and
  formatting do not count and any change to what the code does does).

A store never replaces a result of another identity unless told to (the error names the fields
that differ), and the leaderboard reuses a stored row exactly while its identity holds.
"""

from __future__ import annotations

import ast
import hashlib
import inspect
import json
import re
import sys
from functools import cache
from pathlib import Path
from typing import Any

from zoo.errors import ZooError
from zoo.io import canonical_json
from zoo.paths import REPO_ROOT

RESULTS_DIR = REPO_ROOT / "results"
IDENTITY_VERSION = 1
# Modules whose code computes every result (besides the model's own source).
EVALUATION_CODE = {
    "evaluator": "zoo/evaluate.py",
    "metrics": "zoo/metrics.py",
    "windows": "zoo/data/windows.py",
}
LABEL_PATTERN = r"[A-Za-z0-9_][A-Za-z0-9_.@+=,-]*"


class StoreError(ZooError, ValueError):
    pass


def table_folder(
    sampler: str,
    task: str = "prediction",
    truth: str | None = None,
    horizon: int | None = None,
    melv: str | None = None,
) -> str:
    """The folder under ``<root>/<benchmark>/`` of one sampler, task, ground truth and (when
    not the benchmark's default) MELV frames: ``all``, ``all-completion``, ``all-longterm50``,
    ``all-gt_spectral``, ``all-melv_raw``, ..."""
    folder = sampler if task == "prediction" else f"{sampler}-{task}{horizon or ''}"
    folder = folder if truth in (None, "raw") else f"{folder}-gt_{truth}"
    return folder if melv is None else f"{folder}-melv_{melv}"


def result_path(root: str | Path | None, benchmark: str, table: str, label: str) -> Path:
    return Path(root or RESULTS_DIR) / benchmark / table / check_label(label)


def check_label(label: str) -> str:
    """A row label names a folder: letters, digits and ``_ . @ + = , -``."""
    if not isinstance(label, str) or not re.fullmatch(LABEL_PATTERN, label) or len(label) > 120:
        raise StoreError(
            f"label {label!r}: a label is letters, digits and '_.@+=,-' (at most "
            f"120, not starting with '.', '-' or another sign); it names the "
            f"result folder"
        )
    return label


def variant_label(name: str, overrides: dict[str, Any]) -> str:
    """The default label of a run with overridden hyper-parameters: ``name+key=value,...``
    (never the plain model's label), or ``name+<hash>`` when the values do not fit a name."""
    if not overrides:
        return name
    parts = ",".join(f"{k}={_compact(v)}" for k, v in sorted(overrides.items()))
    label = f"{name}+{parts}"
    if re.fullmatch(LABEL_PATTERN, label) and len(label) <= 80:
        return label
    return f"{name}+{hashlib.sha256(canonical_json(overrides).encode()).hexdigest()[:8]}"


def _compact(value: Any) -> str:
    return value if isinstance(value, str) else json.dumps(value, separators=(",", ":"))


# ---- code fingerprints ------------------------------------------------------------------------


def _tree_text(node: Any) -> str:
    """A syntax tree as text: node types and field values, docstrings and empty fields left
    out (so the text is the same on every Python version that parses the file alike)."""
    if isinstance(node, ast.AST):
        body = getattr(node, "body", None)
        fields = []
        for name in node._fields:
            value = getattr(node, name, None)
            if name == "body" and isinstance(body, list) and _is_docstring(body):
                value = body[1:]
            if value is None or value == [] or name in ("kind", "type_comment"):
                continue
            fields.append(f"{name}={_tree_text(value)}")
        return f"{type(node).__name__}({','.join(fields)})"
    if isinstance(node, list):
        return "[" + ",".join(_tree_text(v) for v in node) + "]"
    return repr(node)


def _is_docstring(body: list) -> bool:
    first = body[0] if body else None
    return (
        isinstance(first, ast.Expr)
        and isinstance(first.value, ast.Constant)
        and isinstance(first.value.value, str)
    )


@cache
def _file_fingerprint(path: str, mtime_ns: int) -> str:
    tree = ast.parse(Path(path).read_text(), filename=path)
    return hashlib.sha256(_tree_text(tree).encode()).hexdigest()[:16]


def code_fingerprint(*files: str | Path) -> str:
    """What the code in ``files`` does, as a short hash of their syntax trees (docstrings,
    comments and formatting do not count)."""
    digests = []
    for file in files:
        path = Path(file)
        path = path if path.is_absolute() else REPO_ROOT / path
        digests.append(_file_fingerprint(str(path), path.stat().st_mtime_ns))
    return (
        digests[0]
        if len(digests) == 1
        else hashlib.sha256("".join(digests).encode()).hexdigest()[:16]
    )


def model_source_files(cls: type) -> list[Path]:
    """The file defining a model class, plus the ``zoo.models`` modules it imports (helpers
    such as the DCT): the model's source, as far as the zoo can tell."""
    module = sys.modules.get(cls.__module__)
    file = inspect.getsourcefile(cls) or (getattr(module, "__file__", None))
    if file is None:
        return []
    files = [Path(file).resolve()]
    try:
        tree = ast.parse(files[0].read_text())
    except (OSError, SyntaxError):
        return files
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("zoo.models"):
            helper = REPO_ROOT / (node.module.replace(".", "/") + ".py")
            if helper.is_file() and helper.resolve() not in files:
                files.append(helper.resolve())
    return files


def evaluation_code(model_class: type | None) -> dict[str, str]:
    """The ``code`` part of an identity."""
    code = {name: code_fingerprint(path) for name, path in EVALUATION_CODE.items()}
    files = model_source_files(model_class) if model_class is not None else []
    if files:
        code["model"] = code_fingerprint(*files)
    return code


# ---- identities ------------------------------------------------------------------------------


def result_identity(
    *,
    benchmark: str,
    protocol_id: str,
    label: str,
    model: dict[str, Any],
    trained: dict[str, Any] | None,
    code: dict[str, str],
) -> dict[str, Any]:
    return {
        "version": IDENTITY_VERSION,
        "benchmark": benchmark,
        "protocol_id": protocol_id,
        "label": label,
        "model": model,
        "trained": trained,
        "code": code,
    }


def identity_id(identity: dict[str, Any]) -> str:
    return hashlib.sha256(canonical_json(identity).encode()).hexdigest()[:16]


def identity_differences(stored: dict[str, Any] | None, new: dict[str, Any]) -> list[str]:
    """The fields in which two identities differ, as ``field: stored X, now Y``; one line for
    a result that records none (written by an older zoo)."""
    if not stored:
        return ["identity: none recorded (written by an older zoo)"]
    out: list[str] = []

    def walk(a, b, path):
        if isinstance(a, dict) and isinstance(b, dict):
            for key in sorted(set(a) | set(b), key=str):
                walk(a.get(key), b.get(key), f"{path}.{key}" if path else str(key))
        elif a != b:
            out.append(f"{path}: stored {_short(a)}, now {_short(b)}")

    walk(stored, new, "")
    return out


def _short(value: Any) -> str:
    text = json.dumps(value, default=str)
    return text if len(text) <= 70 else text[:67] + "..."


def stored_identity(folder: str | Path) -> dict[str, Any] | None:
    """The identity recorded in a result folder, or None (no result, or one without)."""
    path = Path(folder) / "protocol.json"
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise StoreError(
            f"{path}: not readable JSON ({e}); remove the folder or re-evaluate with --replace"
        ) from e
    return (record.get("provenance") or {}).get("identity")


def check_replace(
    folder: str | Path,
    identity: dict[str, Any],
    replace: bool = False,
    protocol: dict[str, Any] | None = None,
) -> str:
    """Whether ``folder`` may receive a result of ``identity``: ``new`` (nothing there),
    ``same`` (a result of this identity, re-measured), ``replace`` (another identity, and
    ``replace`` was asked); otherwise an error naming the fields that differ (with
    ``protocol``, the new protocol record, the protocol's own fields too: data files, windows)."""
    folder = Path(folder)
    if not (folder / "protocol.json").is_file():
        return "new"
    differences = identity_differences(stored_identity(folder), identity)
    if not differences:
        return "same"
    if replace:
        return "replace"
    if protocol is not None:
        from zoo.tables import protocol_differences

        stored = json.loads((folder / "protocol.json").read_text())
        differences += [f"protocol {d}" for d in protocol_differences(stored, protocol)]
    shown = "; ".join(differences[:6]) + (
        f"; and {len(differences) - 6} more" if len(differences) > 6 else ""
    )
    raise StoreError(
        f"{folder} holds a result of another identity ({shown}); store this one "
        f"beside it under its own --label, write elsewhere with --out, or replace "
        f"it with --replace"
    )
