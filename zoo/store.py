"""Where results go, and what a stored result is: its location and its identity.

A result's folder is ``<root>/<benchmark>/<table>/<label>/`` (:func:`table_folder`); its identity
(:func:`result_identity`, code fingerprints by :func:`model_fingerprint`) is what was measured,
and a store never replaces a result of another identity unless told to. The layout and the
identity's fields: docs/results.md ("What a stored row is").
"""

from __future__ import annotations

import ast
import hashlib
import inspect
import json
import re
from functools import cache
from pathlib import Path
from typing import Any

from zoo.errors import ZooError
from zoo.io import canonical_json
from zoo.paths import REPO_ROOT

RESULTS_DIR = REPO_ROOT / "results"
IDENTITY_VERSION = 1
# The evaluator's code is zoo/evaluation.py and every zoo module it imports, directly or through
# others (metrics, windows, benchmarks, data loaders and forward kinematics, spectral bases);
# a model's code is its file and the zoo modules it imports. Left out: modules that only
# present, store or move results and cannot change a number (tables, the result files,
# intervals, files and locks, paths, errors, the process group, the check's and costs'
# budgets).
EVALUATOR = "zoo/evaluation.py"
NOT_COMPUTING = frozenset(
    {
        "zoo/tables.py",
        "zoo/results.py",
        "zoo/intervals.py",
        "zoo/published.py",
        "zoo/io.py",
        "zoo/paths.py",
        "zoo/errors.py",
        "zoo/distributed.py",
        "zoo/budgets.py",
    }
)
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


def _zoo_module_file(module: str) -> Path | None:
    parts = module.split(".")
    if parts[0] != "zoo":
        return None
    for candidate in (
        REPO_ROOT.joinpath(*parts).with_suffix(".py"),
        REPO_ROOT.joinpath(*parts, "__init__.py"),
    ):
        if candidate.is_file():
            return candidate
    return None


def _imported_files(path: Path) -> set[Path]:
    """The zoo modules a file imports, at module level or inside functions, absolute or
    relative (``from zoo.models import dct`` names the module ``zoo.models.dct``)."""
    try:
        tree = ast.parse(path.read_text())
    except (OSError, SyntaxError):
        return set()
    package = _package_of(path)
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = _import_base(node, package)
            names += [base, *(f"{base}.{a.name}" for a in node.names)]
    found = {_zoo_module_file(n) for n in names}
    return {f.resolve() for f in found if f is not None}


def code_closure(*files: str | Path) -> list[Path]:
    """``files`` and every zoo module they import, transitively, but for :data:`NOT_COMPUTING`
    (sorted, so the fingerprint of a closure does not depend on the order it was found in)."""
    skip = {(REPO_ROOT / f).resolve() for f in NOT_COMPUTING} | {
        (REPO_ROOT / "zoo/__init__.py").resolve()
    }
    todo = [Path(f) if Path(f).is_absolute() else (REPO_ROOT / f) for f in files]
    seen: set[Path] = set()
    while todo:
        path = todo.pop().resolve()
        if path in seen or path in skip:
            continue
        seen.add(path)
        todo += sorted(_imported_files(path) - seen)
    return sorted(
        seen, key=lambda p: str(p.relative_to(REPO_ROOT)) if p.is_relative_to(REPO_ROOT) else str(p)
    )


# ---- a model's own code: the definitions its class reaches --------------------------------


def _import_base(node: ast.ImportFrom, package: str) -> str:
    """The absolute module a ``from ... import`` names, relative ones resolved in ``package``
    (the importing file's; empty outside the repository, where they stay unresolved)."""
    base = node.module or ""
    if node.level and package:
        parent = package.split(".")[: len(package.split(".")) - node.level + 1]
        base = ".".join([*parent, *([base] if base else [])])
    return base


def _package_of(path: Path) -> str:
    return (
        ".".join(path.relative_to(REPO_ROOT).with_suffix("").parts[:-1])
        if path.is_relative_to(REPO_ROOT)
        else ""
    )


@cache
def _module_parts(path: str, mtime_ns: int) -> tuple[dict, dict, list]:
    """A module's top level: ``defs`` (name -> the statements that bind it: functions,
    classes, assignments), ``imports`` (name -> ``("zoo", module, attribute or None)`` for a zoo
    module or one of its names, ``("outside", text)`` for anything else) and ``others`` (every
    other statement: it runs on import, whatever is reached)."""
    tree = ast.parse(Path(path).read_text(), filename=path)
    package = _package_of(Path(path))
    defs: dict[str, list] = {}
    imports: dict[str, tuple] = {}
    others: list = []
    body = tree.body[1:] if _is_docstring(tree.body) else tree.body
    for node in body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            defs.setdefault(node.name, []).append(node)
        elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names = [n for t in targets for n in _bound_names(t)]  # not mod.attr = ...
            for name in names:
                defs.setdefault(name, []).append(node)
            if not names:
                others.append(node)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            imports.update(_import_bindings(node, package, Path(path)))
        else:
            others.append(node)
    return defs, imports, others


def _bound_names(target) -> list[str]:
    """The names an assignment target binds: ``a``, ``a, (b, *c)``; none for ``m.a`` or
    ``m[i]``, which change something else."""
    if isinstance(target, ast.Name):
        return [target.id]
    if isinstance(target, ast.Starred):
        return _bound_names(target.value)
    if isinstance(target, (ast.Tuple, ast.List)):
        return [n for t in target.elts for n in _bound_names(t)]
    return []


def _beside(path: Path | None, module: str) -> Path | None:
    """The file of ``module`` where it lies beside ``path``, a model file outside the zoo
    package (a researcher's wrapper importing the authors' code from its folder, which the
    registry puts on ``sys.path``); None for zoo's own files and for installed modules."""
    if path is None or not module or path.is_relative_to(REPO_ROOT / "zoo"):
        return None
    parts = module.split(".")
    for candidate in (
        path.parent.joinpath(*parts).with_suffix(".py"),
        path.parent.joinpath(*parts, "__init__.py"),
    ):
        if candidate.is_file():
            return candidate.resolve()
    return None


def _import_bindings(node, package: str, path: Path | None = None) -> dict[str, tuple]:
    """The names an import statement binds: ``("zoo", module, attribute or None)`` for a zoo
    module or one of its names, ``("beside", module, attribute or None)`` for a module beside a
    model file outside zoo (:func:`_beside`), ``("outside", text)`` for anything else."""
    bindings: dict[str, tuple] = {}
    if isinstance(node, ast.Import):
        for alias in node.names:
            top = alias.name.split(".")[0]
            if _beside(path, alias.name if alias.asname else top) is not None:
                # import a.b as m binds the module a.b; import a.b binds a (a.b reached by name)
                bindings[alias.asname or top] = (
                    "beside",
                    alias.name if alias.asname else top,
                    None,
                )
            elif top == "zoo":
                # import zoo.a.b binds zoo; import zoo.a.b as m binds the module itself
                bound = alias.asname or "zoo"
                bindings[bound] = ("zoo", alias.name if alias.asname else "zoo", None)
            else:
                bindings[alias.asname or alias.name.split(".")[0]] = (
                    "outside",
                    _tree_text(ast.Import(names=[alias])),
                )
        return bindings
    base = _import_base(node, package)
    beside = not node.level and _beside(path, base) is not None
    for alias in node.names:
        bound = alias.asname or alias.name
        if beside and alias.name != "*":
            submodule = f"{base}.{alias.name}"
            bindings[bound] = (
                ("beside", submodule, None)
                if _beside(path, submodule)
                else ("beside", base, alias.name)
            )
        elif base.split(".")[0] == "zoo" and alias.name != "*":
            submodule = f"{base}.{alias.name}"
            bindings[bound] = (
                ("zoo", submodule, None)
                if _zoo_module_file(submodule)
                else ("zoo", base, alias.name)
            )
        else:
            bindings[bound] = ("outside", f"from {base} import {alias.name}")
    return bindings


def _used_names(nodes: list) -> set[tuple[str, ...]]:
    """Every name the statements use, with the attributes read from it (``a.b.c`` gives
    ``("a", "b", "c")``, a bare ``a`` gives ``("a",)``)."""
    used: set[tuple[str, ...]] = set()
    for node in nodes:
        for sub in ast.walk(node):
            if isinstance(sub, ast.Attribute):
                chain, base = [sub.attr], sub.value
                while isinstance(base, ast.Attribute):
                    chain.insert(0, base.attr)
                    base = base.value
                if isinstance(base, ast.Name):
                    used.add((base.id, *chain))
            elif isinstance(sub, ast.Name):
                used.add((sub.id,))
    return used


def reachable_code(cls: type) -> list[str] | None:
    """What a model class's results depend on in code, as text: its own definition and every
    zoo definition it reaches by name (functions, classes, constants; through imports across
    zoo modules, base classes included), the imports from outside zoo that those use, and the
    other top-level statements of every module reached. A second class in the same file is not
    among them; a changed helper, constant, base class or import is. None where Python keeps no
    source for the class, or it is not defined at a module's top level."""
    try:
        file = inspect.getsourcefile(cls)
    except (OSError, TypeError):
        return None
    if file is None or not Path(file).is_file():
        return None
    start = Path(file).resolve()
    if cls.__name__ not in _module_parts(str(start), start.stat().st_mtime_ns)[0]:
        return None

    def label(path: Path) -> str:
        return str(path.relative_to(REPO_ROOT)) if path.is_relative_to(REPO_ROOT) else path.name

    pieces: set[str] = set()
    seen: set[tuple[Path, str | None]] = set()
    todo: list[tuple[Path, str | None]] = [(start, cls.__name__)]
    while todo:
        path, name = todo.pop()
        if (path, name) in seen:
            continue
        seen.add((path, name))
        defs, imports, others = _module_parts(str(path), path.stat().st_mtime_ns)
        if (path, "") not in seen:  # a module's other statements, once
            seen.add((path, ""))
            pieces |= {f"{label(path)}::{_tree_text(n)}" for n in others}
            todo += [(path, None)]  # what those statements use
        nodes = others if name is None else defs.get(name, [])
        if name is not None and not nodes and name in imports:
            nodes = []  # a name this module only imports (a re-export): follow the import
            uses = {(name,)}
        else:
            uses = _used_names(nodes)
        pieces |= {f"{label(path)}::{name}::{_tree_text(n)}" for n in nodes if name is not None}
        # imports written inside the reached definitions bind names there too
        local: dict[str, tuple] = {}
        for node in nodes:
            for sub in ast.walk(node):
                if isinstance(sub, (ast.Import, ast.ImportFrom)):
                    local.update(_import_bindings(sub, _package_of(path), path))
        for used in uses:
            head = used[0]
            if head in defs and head != name and head not in local:
                todo.append((path, head))
            elif head in local or head in imports:
                kind, *target = local.get(head) or imports[head]
                if kind == "outside":
                    pieces.add(f"{label(path)}::import::{target[0]}")
                    continue
                if kind == "beside":  # a researcher's own module: followed as zoo's are
                    module, attribute = target
                    rest = list(used[1:])
                    if attribute is None:  # a module: its submodules, then a definition
                        while rest and _beside(path, f"{module}.{rest[0]}"):
                            module = f"{module}.{rest.pop(0)}"
                        attribute = rest[0] if rest else None
                    target_file = _beside(path, module)
                    if target_file is None:
                        continue
                    parts = _module_parts(str(target_file), target_file.stat().st_mtime_ns)
                    if attribute is None or (
                        attribute not in parts[0] and attribute not in parts[1]
                    ):
                        todo += [(target_file, n) for n in parts[0]] + [(target_file, None)]
                    else:
                        todo.append((target_file, attribute))
                    continue
                module, attribute = target
                rest = list(used[1:])
                if attribute is None:  # a module: resolve attributes to its definitions
                    while rest and _zoo_module_file(f"{module}.{rest[0]}"):
                        module = f"{module}.{rest.pop(0)}"
                    attribute = rest[0] if rest else None
                target_file = _zoo_module_file(module)
                if target_file is None:
                    continue
                target_file = target_file.resolve()
                if attribute is None:  # the module itself is used: all of it
                    parts = _module_parts(str(target_file), target_file.stat().st_mtime_ns)
                    todo += [(target_file, n) for n in parts[0]] + [(target_file, None)]
                else:
                    todo.append((target_file, attribute))
    return sorted(pieces)


def model_fingerprint(cls: type) -> str | None:
    """A model class's code fingerprint: of :func:`reachable_code`, or, for a class defined
    other than at a module's top level, of its file and the zoo modules it imports; None where
    Python keeps no source for it (a class typed into an interpreter)."""
    code = reachable_code(cls)
    if code is not None:
        return hashlib.sha256("\n".join(code).encode()).hexdigest()[:16]
    sources = model_source_files(cls)
    return code_fingerprint(*sources) if sources else None


def model_source_files(cls: type) -> list[Path]:
    """The file defining a model class and the zoo modules it imports: the model's source.
    Empty where Python keeps no file for it (a class typed into an interpreter)."""
    try:
        file = inspect.getsourcefile(cls)
    except (OSError, TypeError):
        file = None
    if file is None or not Path(file).is_file():
        return []
    return code_closure(Path(file).resolve())


def dataset_code(dataset: str | None) -> list[Path]:
    """The code that generates a mesh dataset (cloth simulation, CMU motion on the Anny body),
    which the evaluator loads by name, not by import; skeleton loaders are the evaluator's."""
    from zoo.benchmark import MESH_DATASETS

    loader = MESH_DATASETS.get(dataset or "")
    loader = loader[0] if isinstance(loader, tuple) else loader
    if not isinstance(loader, str):
        return []
    file = _zoo_module_file(loader.split(":")[0])
    return code_closure(file) if file is not None else []


def evaluation_code(model_class: type | None, dataset: str | None = None) -> dict[str, str | None]:
    """The ``code`` part of an identity: the evaluator's fingerprint (with the code that
    generates ``dataset``, a mesh dataset) and the model's (None where its source cannot be
    read, a class typed into an interpreter: such a result is never taken for another)."""
    files = sorted(set(code_closure(EVALUATOR)) | set(dataset_code(dataset)))
    code: dict[str, str | None] = {"evaluator": code_fingerprint(*files)}
    if model_class is not None:
        code["model"] = model_fingerprint(model_class)
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
    """One field in which two identities differ: its text (``field: stored X, now Y``) is what
    messages print; ``field`` and ``comparable`` are what code decides on."""

    field: str
    comparable: bool  # False: no result can be its twin (a model whose source cannot be read)

    def __new__(cls, field: str, text: str, comparable: bool = True) -> Difference:
        difference = super().__new__(cls, f"{field}: {text}")
        difference.field, difference.comparable = field, comparable
        return difference

    def __reduce__(self):  # copy and pickle keep the field and the flag
        return (Difference, (self.field, self[len(self.field) + 2 :], self.comparable))


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
        return [Difference("identity", "none recorded (written by an older zoo)")]
    out: list[Difference] = []
    if (new.get("code") or {}).get("model", "") is None:
        out.append(
            Difference(
                "code.model",
                "the model's source cannot be read, so no result is its twin",
                comparable=False,
            )
        )

    def walk(a, b, path):
        if isinstance(a, dict) and isinstance(b, dict):
            for key in sorted(set(a) | set(b), key=str):
                walk(a.get(key), b.get(key), f"{path}.{key}" if path else str(key))
        elif a != b:
            out.append(Difference(path, f"stored {_short(a)}, now {_short(b)}"))

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


# ---- a stored row's provenance ----------------------------------------------------------------


def stored_provenance(folder: Path) -> dict:
    import json

    return json.loads((folder / "protocol.json").read_text()).get("provenance", {})


def recorded_registry(folder: Path) -> str | None:
    provenance = stored_provenance(folder)
    identity = provenance.get("identity") or {}
    return (identity.get("model") or {}).get("registry") or provenance.get("registry")


def refuse_foreign_registry(folder: Path, loaded, label: str) -> None:
    """A stored row of this label made with another registry's model is the user's: never
    replaced by a rebuild that does not load that registry."""
    from zoo.io import registry_record, repo_relative

    recorded = recorded_registry(folder)
    # rows recorded before registry_record named an outside registry by its absolute path
    if recorded is not None and recorded not in (
        registry_record(loaded.entry.source),
        repo_relative(loaded.entry.source),
    ):
        raise StoreError(
            f"{folder}: row {label!r} was evaluated with registry {recorded}, which "
            f"this run does not load (its {label!r} comes from "
            f"{registry_record(loaded.entry.source)}); nothing was changed: pass "
            f"--registry with that file, or remove the row deliberately with --drop "
            f"{label}"
        )
