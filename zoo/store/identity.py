"""What a stored result is: its identity (:func:`result_identity`, code fingerprints by
:func:`zoo.store.fingerprint.model_fingerprint`) is what was measured, and a store never replaces
a result of another identity unless told to (:func:`check_replace`). Two identities differ in
:class:`Difference` values, each a field with its stored and new value. The identity's fields:
docs/results.md ("What a stored row is").
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from zoo.core.io import canonical_json
from zoo.store.fingerprint import (
    code_closure,
    code_fingerprint,
    definition_fingerprint,
    model_fingerprint,
    zoo_module_file,
)
from zoo.store.layout import StoreError

IDENTITY_VERSION = 2  # 2: code fingerprints that do not depend on where the code lives


# ---- the code a result's identity covers ----------------------------------------------------


def dataset_code(bench) -> list[Path]:
    """The zoo modules that hold a benchmark's data loader and skeleton (``bench.loader``,
    ``bench.skeleton_def``: CMU's exp-map reader, the cloth simulation, CMU motion on the Anny
    body) and those they import, which the evaluator runs by name, not by import. Code outside
    the zoo is :func:`own_data_code`'s."""
    if bench is None:
        return []
    files: set[Path] = set()
    for named in (bench.loader, bench.skeleton_def):
        file = zoo_module_file(named.rsplit(":", 1)[0]) if named else None
        if file is not None:
            files |= set(code_closure(file, computing_only=True))
    return sorted(files)


def own_data_code(bench) -> list[str]:
    """What a row depends on in a benchmark's loader and skeleton outside the zoo (a
    researcher's ``file.py:load`` or ``package.module:load``): each one's name and the
    fingerprint of the code it reaches (modules beside it included), and the loader's options
    (a zoo loader's options are recorded with its data: a mesh recipe, the actions)."""
    if bench is None:
        return []
    own = []
    for field, named in (("loader", bench.loader), ("skeleton", bench.skeleton_def)):
        where, name = named.rsplit(":", 1) if named else ("", "")
        if not where or zoo_module_file(where) is not None:
            continue
        file = (bench.source.parent / where) if where.endswith(".py") else _module_origin(where)
        digest = definition_fingerprint(file, name) if file is not None else None
        own.append(f"{field}:{name}#{digest}")
        if field == "loader":
            own.append(f"loader_options:{canonical_json(bench.loader_options)}")
    return own


def _module_origin(module: str) -> Path | None:
    import importlib.util

    try:
        spec = importlib.util.find_spec(module)
    except (ImportError, ValueError):
        return None
    origin = getattr(spec, "origin", None)
    return Path(origin) if origin and origin.endswith(".py") else None


def evaluation_code(evaluator: Path, model_class: type | None, bench=None) -> dict[str, str | None]:
    """The ``code`` part of an identity: the evaluator's fingerprint and the model's (None
    where its source cannot be read, a class typed into an interpreter: such a result is never
    taken for another). The evaluator's code is the module file ``evaluator`` and every zoo
    module it imports, directly or through others, less the modules that say, by a line of
    their own, that they cannot change a number (zoo.store.fingerprint.COMPUTES_NO_NUMBER),
    with the code that loads ``bench``'s data; the layer that runs the evaluator names its file
    (its ``row_code``), so the store names nothing above it."""
    evaluator = code_closure(Path(evaluator), computing_only=True)
    files = sorted(set(evaluator) | set(dataset_code(bench)))
    fingerprint = code_fingerprint(*files)
    own = own_data_code(bench)
    if own:  # a researcher's own loader: its code, name and options count as the evaluator's
        fingerprint = hashlib.sha256("\n".join([fingerprint, *own]).encode()).hexdigest()[:16]
    code: dict[str, str | None] = {"evaluator": fingerprint}
    if model_class is not None:
        code["model"] = model_fingerprint(model_class)
    return code


# ---- the data files a model reads ------------------------------------------------------------


def files_read_record(
    files: frozenset[Path] | set[Path], hparams: dict[str, Any], registry_file: str | Path
) -> dict[str, str]:
    """The ``reads`` part of a model's identity: each data file its module or constructor
    opened while it was built (:func:`zoo.models.registry.files_read_while_built`), and each
    file a hyper-parameter names (absolute, or relative to the registry file), as
    ``{name: sha256}``. Named relative to the registry file's
    folder where inside it, else to the repository, else by the file's name: no machine's
    folders. Empty for a model that reads none (the zoo's own)."""
    from zoo.core.files_read import is_data_file
    from zoo.core.io import sha256_file
    from zoo.paths import REPO_ROOT

    base = Path(registry_file).resolve().parent
    named = set(files)
    for value in hparams.values():
        if isinstance(value, str) and value and len(value) < 4096:
            # absolute, or relative to the registry file (as a class path is): never to the
            # folder a command runs in, which would make the identity depend on it
            try:  # a value that is no path (too long a name, ~nosuchuser) names no file
                candidate = Path(value).expanduser()
                candidate = candidate if candidate.is_absolute() else base / candidate
                if candidate.is_file() and is_data_file(candidate, (REPO_ROOT / "zoo",)):
                    named.add(candidate.resolve())
            except (OSError, RuntimeError, ValueError):
                continue
    record = {}
    for file in sorted(named):
        label = next(
            (
                str(file.relative_to(root))
                for root in (base, REPO_ROOT)
                if file.is_relative_to(root)
            ),
            file.name,
        )
        stat = file.stat()
        record[label] = _file_digest(str(file), stat.st_mtime_ns, stat.st_size, sha256_file)
    return record


_DIGESTS: dict[tuple[str, int, int], str] = {}


def _file_digest(path: str, mtime_ns: int, size: int, digest) -> str:
    """A file's sha256, hashed once per process while it is unchanged (a rebuild asks for a
    model's identity once per row)."""
    key = (path, mtime_ns, size)
    if key not in _DIGESTS:
        _DIGESTS[key] = digest(path)
    return _DIGESTS[key]


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


def stamp(result, identity: dict, made_by: str) -> None:
    """Record ``identity`` in a result's provenance (written to its ``protocol.json``), and
    what made it (``zoo leaderboard``, ``zoo eval``, ``zoo.evaluate``): a rebuild replaces only
    rows it made."""
    stamp_record(result.protocol, identity)
    result.protocol["provenance"]["made_by"] = made_by


def stamp_record(protocol: dict, identity: dict) -> None:
    """``identity`` into a protocol record's provenance (its ``made_by`` unchanged)."""
    protocol["provenance"]["identity"] = identity
    protocol["provenance"]["identity_id"] = identity_id(identity)


def restamp_record(protocol: dict, identity: dict, verification: dict | None = None) -> None:
    """A stored row's record given the identity it has now, its numbers kept: for a row whose
    identity went stale only because code changed, with how its numbers were verified under the
    new code (``verification``: windows, seed, old and new code), kept in order under
    ``provenance.verified``."""
    if verification is not None:
        protocol["provenance"].setdefault("verified", []).append(verification)
    stamp_record(protocol, identity)


class Difference(str):
    """One field in which two identities differ, as data: ``field``, the ``stored`` and the
    ``new`` value, and its ``kind``: ``changed`` (both recorded, unequal), ``unrecorded``
    (a result written by an older zoo: no identity) or ``unreadable`` (the model's source cannot
    be read, so no result can be its twin). Its text (``field: stored X, now Y``), made from
    them, is what messages print; code decides on the fields."""

    field: str
    stored: Any
    new: Any
    kind: str

    def __new__(cls, field: str, stored: Any = None, new: Any = None, kind: str = "changed"):
        if kind not in _DIFFERENCE_WORDS:
            raise ValueError(f"kind {kind!r}: expected one of {', '.join(_DIFFERENCE_WORDS)}")
        words = _DIFFERENCE_WORDS[kind] or f"stored {_short(stored)}, now {_short(new)}"
        difference = super().__new__(cls, f"{field}: {words}")
        difference.field, difference.stored, difference.new = field, stored, new
        difference.kind = kind
        return difference

    @property
    def comparable(self) -> bool:
        """False where no result can be this one's twin (a model whose source is unreadable)."""
        return self.kind != "unreadable"

    def __reduce__(self):  # copy and pickle keep the values and the kind
        return (Difference, (self.field, self.stored, self.new, self.kind))


_DIFFERENCE_WORDS = {
    "changed": None,  # made from the values
    "unrecorded": "none recorded (written by an older zoo)",
    "unreadable": "the model's source cannot be read, so no result is its twin",
}


def only_code_changed(differences: list[Difference]) -> bool:
    """Whether identity differences (:func:`identity_differences`) are of code alone: the same
    data, protocol, hyper-parameters and weights, so a sample can verify the stored numbers."""
    return bool(differences) and all(
        d.field.startswith("code.") and d.comparable for d in differences
    )


def identity_differences(stored: dict[str, Any] | None, new: dict[str, Any]) -> list[Difference]:
    """The fields in which two identities differ, as ``field: stored X, now Y``; one line for
    a result that records none (written by an older zoo)."""
    if not stored:
        return [Difference("identity", None, new, kind="unrecorded")]
    out: list[Difference] = []
    if (new.get("code") or {}).get("model", "") is None:
        out.append(
            Difference("code.model", (stored.get("code") or {}).get("model"), None, "unreadable")
        )

    def walk(a, b, path):
        if isinstance(a, dict) and isinstance(b, dict):
            for key in sorted(set(a) | set(b), key=str):
                walk(a.get(key), b.get(key), f"{path}.{key}" if path else str(key))
        elif a != b:
            out.append(Difference(path, a, b))

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
    if replace:
        return "replace"
    differences = identity_differences(stored_identity(folder), identity)
    if not differences:
        return "same"
    if protocol is not None:
        from zoo.protocol.comparable import protocol_differences

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
