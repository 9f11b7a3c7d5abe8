"""What code does, as a short hash that does not depend on where the code lives.

A fingerprint hashes syntax trees (docstrings, comments and formatting left out) in which every
reference to a definition of the zoo, or of a researcher's module beside a model file, is
written as that definition's name and a digest of its own text, never as the module that holds
it, and in which imports of those modules are left out. So renaming a module, moving a
definition to another file or reordering definitions changes no fingerprint, while a changed
body, constant, base class or import from outside the zoo does. Two uses: the definitions a
model class reaches (:func:`model_fingerprint`) and whole modules with the zoo modules they
import (:func:`code_fingerprint`, the evaluator's). Which code a result's identity covers is
the store's policy (:mod:`zoo.store.identity`).
"""

from __future__ import annotations

import ast
import functools
import hashlib
import inspect
import json
import os
import re
import shutil
import sys
import time
from collections import Counter
from functools import cache
from pathlib import Path
from typing import Any

from zoo.core.io import atomic_write_json
from zoo.paths import REPO_ROOT
from zoo.store.layout import StoreError

# A string naming a zoo definition by its module, as a benchmark names its loader
# ("zoo.data.cloth:cloth_dataset"): a reference like an import, normalised like one.
_NAMED_DEFINITION = re.compile(r"zoo(?:\.\w+)+:\w+")
_UNWRITTEN_FIELDS = frozenset({"kind", "type_comment"})


def _tree_text(node, rewrite=None) -> str:
    """A syntax tree as text: node types and field values, docstrings and empty fields left
    out (so the text is the same on every Python version that parses the file alike).
    ``rewrite(node)``: a node written in that one's place as it is, or None to write the node
    and go on into its fields (written in one pass: no copy of the tree is changed); asked of
    every node but a name's context (``Load()``, ``Store()``, ``Del()``), written as it is."""
    if isinstance(node, ast.AST):
        if rewrite is not None and (new := rewrite(node)) is not None:
            return _tree_text(new)
        fields = []
        for name in node._fields:
            value = getattr(node, name, None)
            if value is None or name in _UNWRITTEN_FIELDS:
                continue
            if type(value) is list:
                if name == "body" and _is_docstring(value, rewrite):
                    value = value[1:]
                if not value:
                    continue
                text = _tree_text(value, rewrite)
            elif isinstance(value, ast.expr_context):  # no fields; every name has one
                text = f"{type(value).__name__}()"
            elif isinstance(value, ast.AST):
                text = _tree_text(value, rewrite)
            else:
                text = repr(value)
            fields.append(f"{name}={text}")
        return f"{type(node).__name__}({','.join(fields)})"
    if isinstance(node, list):
        return "[" + ",".join([_tree_text(v, rewrite) for v in node]) + "]"
    return repr(node)


def _is_docstring(body: list, rewrite=None) -> bool:
    first = body[0] if body else None
    return (
        isinstance(first, ast.Expr)
        and isinstance(first.value, ast.Constant)
        and isinstance(first.value.value, str)
        and (rewrite is None or rewrite(first.value) is None)  # a string naming code is code
    )


def _digest(texts) -> str:
    return hashlib.sha256("\n".join(texts).encode()).hexdigest()[:16]


# ---- modules and what their imports bind -----------------------------------------------------


def zoo_module_file(module: str) -> Path | None:
    parts = module.split(".")
    if parts[0] != "zoo":
        return None
    for candidate in (
        REPO_ROOT.joinpath(*parts).with_suffix(".py"),
        REPO_ROOT.joinpath(*parts, "__init__.py"),
    ):
        if candidate.is_file():
            return candidate.resolve()
    return None


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


def _beside(path: Path | None, module: str) -> Path | None:
    """The file of ``module`` where it is a researcher's code that ``path``, a model file outside
    the zoo package, reaches: beside it (the registry puts its folder on ``sys.path``), or in a
    folder of ``sys.path`` that is neither the standard library nor installed packages (where a
    wrapper puts the authors' checkout). None for zoo's own files and for installed modules."""
    if path is None or not module or path.is_relative_to(REPO_ROOT / "zoo"):
        return None
    parts = module.split(".")
    for root in (path.parent, *_researcher_folders()):
        for candidate in (
            root.joinpath(*parts).with_suffix(".py"),
            root.joinpath(*parts, "__init__.py"),
        ):
            if candidate.is_file() and not candidate.resolve().is_relative_to(REPO_ROOT / "zoo"):
                return candidate.resolve()
    return None


def _beside_namespace(path: Path | None, module: str) -> bool:
    """Whether ``module`` is a namespace package of a researcher's (a folder with no
    ``__init__.py``, as many research checkouts have) where :func:`_beside` looks: ``from
    parts import layers`` then reaches ``parts/layers.py``. Not where a regular module of that
    name is importable (an installed ``datasets`` wins over a data folder of that name, as in
    Python's own import)."""
    if path is None or not module or path.is_relative_to(REPO_ROOT / "zoo"):
        return False
    parts = module.split(".")
    if _regular_module(parts[0]):
        return False
    return any(
        root.joinpath(*parts).is_dir()
        and not root.joinpath(*parts).resolve().is_relative_to(REPO_ROOT / "zoo")
        for root in (path.parent, *_researcher_folders())
    )


def _regular_module(name: str) -> bool:
    """Whether a top-level module or package with a file of its own is importable by ``name``."""
    import importlib.machinery

    try:
        spec = importlib.machinery.PathFinder.find_spec(name)
    except (ImportError, ValueError):
        return False
    return spec is not None and spec.origin not in (None, "namespace")


def _researcher_folders() -> list[Path]:
    import sys

    return list(_researcher_folders_of(tuple(sys.path)))


@cache
def _researcher_folders_of(path: tuple[str, ...]) -> tuple[Path, ...]:
    """The folders of ``sys.path`` (as it is now: after a wrapper has added its own) that hold
    neither the standard library nor installed packages, nor the zoo's own code."""
    from zoo.core.files_read import library_folders

    installed = library_folders()
    folders = []
    for entry in path:
        folder = Path(entry or ".").resolve()
        if not folder.is_dir() or folder == REPO_ROOT or folder in folders:
            continue
        if any(folder == p or folder.is_relative_to(p) for p in installed):
            continue
        if _holds_installed(str(folder), folder.stat().st_mtime_ns):
            continue
        folders.append(folder)
    libraries = _named_by_path_files(path)
    return tuple(f for f in folders if f not in libraries)


@cache
def _holds_installed(folder: str, mtime_ns: int) -> bool:
    """Whether a folder is where packages are installed: it holds a ``*.dist-info`` or
    ``*.egg-info`` (what pip and setuptools write) or a ``.pth`` file (what ``site`` reads),
    as another environment's site-packages added with ``site.addsitedir`` does. Such a folder
    is a library, never a researcher's code (walking it would fingerprint all of torch)."""
    try:
        with os.scandir(folder) as entries:
            return any(
                e.name.endswith((".dist-info", ".egg-info"))
                or (e.name.endswith(".pth") and _is_path_file(e.path))
                for e in entries
            )
    except OSError:
        return False


def _is_path_file(file: str) -> bool:
    """A ``.pth`` of ``site`` (lines of text naming folders), not a ``.pth`` of weights (a
    zip or pickle of tensors, which a researcher's checkout may keep beside its code)."""
    lines = _site_lines(file)
    folder = Path(file).parent
    # what site reads: folders that exist, or import lines; a git-lfs pointer is neither
    return bool(lines) and all(
        line.startswith(("import ", "import\t")) or (folder / line).is_dir() for line in lines
    )


def _site_lines(file: str | Path) -> list[str]:
    """A ``.pth`` file's lines as ``site`` reads them (no blank or comment line); none for a
    file that is not text."""
    try:
        with open(file, "rb") as f:
            head = f.read(4096)
        lines = [line.strip() for line in head.decode("utf-8").splitlines()]
    except (OSError, UnicodeDecodeError):
        return []
    return [line for line in lines if line and not line.startswith("#")]


def _named_by_path_files(path: tuple[str, ...]) -> frozenset[Path]:
    """Folders that a ``.pth`` file in an installed-packages folder of ``path`` (``sys.path``)
    adds: libraries too (an editable install's source is named so, and so is the zoo's own)."""
    named = set()
    for entry in path:
        folder = Path(entry or ".")
        if not folder.is_dir() or not _holds_installed(str(folder), folder.stat().st_mtime_ns):
            continue
        for pth in folder.glob("*.pth"):
            for line in _site_lines(pth):
                if not line.startswith(("import ", "import\t")):
                    named.add((folder / line).resolve())
    return frozenset(named)


def _import_bindings(node, package: str, path: Path | None = None) -> dict[str, tuple]:
    """The names an import statement binds: ``("zoo", module, attribute or None)`` for a zoo
    module or one of its names, ``("beside", module, attribute or None)`` for a module beside a
    model file outside zoo (:func:`_beside`), ``("outside", text)`` for anything else."""
    bindings: dict[str, tuple] = {}
    if isinstance(node, ast.Import):
        for alias in node.names:
            top = alias.name.split(".")[0]
            named = alias.name if alias.asname else top
            if _beside(path, named) is not None or _beside_namespace(path, named):
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
    beside = not node.level and (_beside(path, base) is not None or _beside_namespace(path, base))
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
                if zoo_module_file(submodule)
                else ("zoo", base, alias.name)
            )
        else:
            bindings[bound] = ("outside", f"from {base} import {alias.name}")
    return bindings


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


@cache
def _syntax_tree(file: str, mtime_ns: int) -> ast.Module:
    """A file's syntax tree, parsed once for the file as it is; read, never changed (the
    import scan and the module's parts share it)."""
    return ast.parse(Path(file).read_text(), filename=file)


@cache
def _module_parts(path: str, mtime_ns: int, folder_mtime_ns: int, layout: tuple) -> tuple:
    """A module's top level: ``defs`` (name -> the statements that bind it: functions,
    classes, assignments), ``imports`` (name -> what :func:`_import_bindings` says it binds)
    and ``others`` (every other statement: it runs on import, whatever is reached). Kept for
    the file as it is, in its folder and the zoo's folders as they are (:func:`_layout`): what
    an import binds depends on which modules exist."""
    tree = _syntax_tree(path, mtime_ns)
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


def _parts(path: Path) -> tuple[dict, dict, list]:
    mtime, folder_mtime = path.stat().st_mtime_ns, path.parent.stat().st_mtime_ns
    # whatever is being computed depends on this file, and on its folder's modules, as they are
    _record({str(path): mtime, str(path.parent): folder_mtime})
    return _module_parts(str(path), mtime, folder_mtime, _current_layout())


def _module_file(kind: str, path: Path, module: str) -> Path | None:
    return _beside(path, module) if kind == "beside" else zoo_module_file(module)


def _resolve(path: Path, binding: tuple, rest: list[str], depth: int = 0):
    """Where a name bound by an import leads, with the attributes read from it (``rest``):
    ``(file, definition, attributes left)``, ``(file, None, [])`` for a module itself, or None
    for an import from outside (or a name no module defines). A name a module only re-exports
    is followed to where it is defined."""
    kind, *target = binding
    if kind == "outside":
        return None
    module, attribute = target
    rest = list(rest)
    if attribute is None:  # a module: its submodules, then one of its definitions
        while rest and _module_file(kind, path, f"{module}.{rest[0]}"):
            module = f"{module}.{rest.pop(0)}"
        attribute = rest.pop(0) if rest else None
    file = _module_file(kind, path, module)
    if file is None:
        return None
    if attribute is None:
        return file, None, []
    defs, imports, _ = _parts(file)
    if attribute not in defs and attribute in imports and depth < 20:
        found = _resolve(file, imports[attribute], [], depth + 1)
        return None if found is None else (found[0], found[1], rest)
    return file, attribute, rest


# ---- references written by name, not by place -----------------------------------------------


def _local_bindings(nodes: list, path: Path) -> dict[str, tuple]:
    """Imports written inside definitions bind names there too."""
    local: dict[str, tuple] = {}
    for node in nodes:
        for sub in _scan(node)[1]:
            local.update(_import_bindings(sub, _package_of(path), path))
    return local


def _shadowed(node) -> frozenset[str]:
    """Names a top-level statement binds inside itself (arguments, local variables), which
    its body reads as its own, not as the module's."""
    return _scan(node)[0]


@cache
def _scan(node) -> tuple[frozenset[str], tuple]:
    """One walk of a top-level statement of a kept syntax tree (:func:`_syntax_tree`, never
    changed): the names it binds inside itself (:func:`_shadowed`) and the imports in it."""
    names: set[str] = set()
    imports = []
    own = (
        set(_bound_names_of(node))
        if isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign))
        else set()
    )
    for sub in ast.walk(node):
        if isinstance(sub, ast.arg):
            names.add(sub.arg)
        elif isinstance(sub, ast.Name) and isinstance(sub.ctx, (ast.Store, ast.Del)):
            names.add(sub.id)
        elif isinstance(sub, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and (
            sub is not node
        ):
            names.add(sub.name)
        elif isinstance(sub, (ast.Import, ast.ImportFrom)):
            imports.append(sub)
    return frozenset(names - own), tuple(imports)


def _bound_names_of(node) -> list[str]:
    targets = node.targets if isinstance(node, ast.Assign) else [node.target]
    return [n for t in targets for n in _bound_names(t)]


class _ByName:
    """Writes a statement's every reference to a definition (of its own module, or reached
    through an import of a zoo module or one beside a model file) as ``token(file, name)``,
    and imports of such modules as ``pass``: :meth:`rewrite`, for :func:`_tree_text`."""

    def __init__(self, path: Path, names: dict[str, tuple], defs: dict, shadowed: frozenset, token):
        self.path, self.names, self.defs, self.shadowed = path, names, defs, shadowed
        self.token = token

    def _lookup(self, name: str, rest: list[str]):
        if name in self.shadowed:
            return None
        if name in self.names:
            return _resolve(self.path, self.names[name], rest)
        if name in self.defs:
            return self.path, name, rest
        return None

    def rewrite(self, node):
        """The node written in ``node``'s place, or None where it stays (its fields written)."""
        kind = type(node)  # the parser makes no subclasses of these
        if kind is ast.Name:
            found = self._lookup(node.id, []) if type(node.ctx) is ast.Load else None
            return None if found is None else ast.Name(id=self.token(*found[:2]), ctx=node.ctx)
        if kind is ast.Attribute:
            return self._attribute(node)
        if kind is ast.Constant:
            return self._constant(node)
        if kind is ast.Import or kind is ast.ImportFrom:
            bindings = _import_bindings(node, _package_of(self.path), self.path)
            return None if all(b[0] == "outside" for b in bindings.values()) else ast.Pass()
        return None

    def _attribute(self, node):
        chain, base = [node.attr], node.value
        while isinstance(base, ast.Attribute):
            chain.insert(0, base.attr)
            base = base.value
        if type(base) is not ast.Name or type(node.ctx) is not ast.Load:
            return None
        found = self._lookup(base.id, chain)
        if found is None:
            return None
        file, name, rest = found
        out: ast.expr = ast.Name(id=self.token(file, name), ctx=ast.Load())
        for attribute in rest:
            out = ast.Attribute(value=out, attr=attribute, ctx=ast.Load())
        return out

    @staticmethod
    def _constant(node):
        # by its name alone: what a string names is loaded on demand, and its code is counted
        # where it is loaded (zoo.store.identity.dataset_code), not wherever it is named
        if isinstance(node.value, str) and _NAMED_DEFINITION.fullmatch(node.value):
            module, name = node.value.split(":")
            if zoo_module_file(module) is not None:
                return ast.Name(id=f"@{name}", ctx=ast.Load())
        return None


def _text_by_name(path: Path, node, level: int) -> str:
    """A statement's text with its references written by name: ``@name`` (level 1), or
    ``@name#digest`` with the digest of that definition's level-1 text (level 2), so that two
    definitions of one name in different modules are told apart."""
    defs, imports, _ = _parts(path)
    names = {**imports, **_local_bindings([node], path)}

    def token(file: Path, name: str | None) -> str:
        if name is None:
            return "@module"
        if level == 1 or name not in _parts(file)[0]:
            return f"@{name}"
        return f"@{name}#{_definition_digest(file, name)}"

    return _tree_text(node, _ByName(path, names, defs, _shadowed(node), token).rewrite)


def _definition_digest(file: Path, name: str) -> str:
    return _kept(
        ("digest", str(file), name),
        lambda: _digest(_text_by_name(file, n, 1) for n in _parts(file)[0][name])[:8],
    )


# Results kept for the rest of the process while nothing they were computed from has changed:
# each is stored with the files and folders read to compute it (mtimes as read) and the zoo's
# folder layout; a result used inside another's computation passes what it read on to it.
_KEPT: dict[tuple, tuple[Any, dict[str, int], tuple]] = {}
_frames: list[tuple[dict[str, int], tuple]] = []  # (read so far, layout) of each computation


def _layout() -> tuple:
    """Every folder of the zoo package with its mtime: a module added, removed or renamed
    anywhere in it changes what an import of a zoo module binds."""
    folders = [str(REPO_ROOT / "zoo")]
    for folder, subfolders, _ in os.walk(folders[0]):
        # not __pycache__: Python writes compiled files there as modules load, which moves no
        # import; os.walk lists folders only (a glob would stat every file). A link to a folder
        # is listed, with its target's mtime, but not walked into (a link may loop)
        subfolders[:] = sorted(f for f in subfolders if f != "__pycache__")
        folders += [os.path.join(folder, f) for f in subfolders]
    return tuple((f, os.stat(f).st_mtime_ns) for f in folders)


_scopes: list[tuple] = []  # the layout read once at a public entry point, for all it calls


def _current_layout() -> tuple:
    if _frames:
        return _frames[0][1]
    return _scopes[-1] if _scopes else _layout()


def _one_layout(function):
    """``function`` reads the zoo's folder layout once per call, not once per file it parses."""

    @functools.wraps(function)
    def scoped(*args, **kwargs):
        _scopes.append(_current_layout())
        try:
            return function(*args, **kwargs)
        finally:
            _scopes.pop()

    return scoped


def _record(read: dict[str, int]) -> None:
    for frame_read, _ in _frames:
        frame_read.update(read)


def _unchanged(read: dict[str, int]) -> bool:
    try:
        return all(Path(f).stat().st_mtime_ns == mtime for f, mtime in read.items())
    except OSError:
        return False


def _kept(key: tuple, compute):
    """``compute()``, or its value kept from an earlier call, in this process or, for the zoo's
    own code, another (:func:`_stored`), while nothing it read changed."""
    layout = _current_layout()
    kept = _KEPT.get(key)
    if kept is None or kept[2] != layout or not _unchanged(kept[1]):
        kept = _stored(key, layout)
    if kept is not None:
        _KEPT[key] = kept
        _record(kept[1])
        return kept[0]
    _frames.append(({}, layout))
    try:
        value = compute()
    finally:
        read, _ = _frames.pop()
    _record(read)
    _KEPT[key] = (value, read, layout)
    _store(key, value, read, layout)
    return value


# Kept results are also stored on disk (under the zoo's cache folder, git ignores it) where
# everything they read is the zoo's own code, so each command and test process does not parse
# and walk the evaluator's modules again. A process trusts its own reads by mtime; another
# process's only while every file and folder read (the zoo's layout's included) has the same
# mtime, size, inode and ctime as when it was stored (a copy that keeps mtimes, cp -p or
# rsync -a, makes a new ctime, which no tool sets). One folder per version of this module and of
# Python, whose syntax trees the texts are made of (the text-writing code lives here for that).
# Code outside the zoo is resolved through sys.path, which another process may not share: its
# results are kept in memory only.
_STORED_UNUSED_DAYS = 14  # a folder of another version no process used for this long goes
_VALUE_KINDS = {"str": str, "tuple": tuple, "frozenset": frozenset}


@cache
def _store_version() -> str:
    version = f"{Path(__file__).read_bytes()!r}{sys.version_info[:2]}"
    return hashlib.sha256(version.encode()).hexdigest()[:16]


def _store_folder() -> Path:
    from zoo.data.mesh import cache_root  # the cache folder's one home (ZOO_CACHE_DIR)

    return cache_root() / "fingerprints" / _store_version()


def _store_file(key: tuple) -> Path:
    name = hashlib.sha256(json.dumps(list(key)).encode()).hexdigest()[:32]
    return _store_folder() / f"{name}.json"


def _signature(path: str) -> list[int]:
    stat = os.stat(path)
    return [stat.st_mtime_ns, stat.st_size, stat.st_ino, stat.st_ctime_ns]


@cache
def _as_stored(folders: tuple[tuple, ...]) -> bool:
    """Whether the zoo's folders have the signatures a stored result recorded (every result
    stored by one process records the same: checked once)."""
    try:
        return all(_signature(folder) == list(signature) for folder, *signature in folders)
    except OSError:
        return False


def _stored(key: tuple, layout: tuple) -> tuple | None:
    """A result another process stored (:func:`_store`) as ``(value, read, layout)``, where
    the zoo's layout is ``layout`` and every file and folder it read is as it was; None where
    there is none to use (never stored, unreadable, another key, anything changed)."""
    try:
        stored = json.loads(_store_file(key).read_text())
        if stored["key"] != list(key):
            return None
        # the layout is the folders' mtimes, the first of each signature
        if tuple((folder, signature[0]) for folder, signature in stored["folders"]) != layout:
            return None
        if not _as_stored(tuple((f, *signature) for f, signature in stored["folders"])):
            return None
        if any(_signature(path) != signature for path, signature in stored["read"].items()):
            return None
        value = _VALUE_KINDS[stored["kind"]](stored["value"])
        read = {path: signature[0] for path, signature in stored["read"].items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError, IndexError):
        return None
    _mark_store_used()
    return value, read, layout


def _store(key: tuple, value, read: dict[str, int], layout: tuple) -> None:
    kind = type(value).__name__
    zoo = REPO_ROOT / "zoo"
    if kind not in _VALUE_KINDS or not all(Path(p).is_relative_to(zoo) for p in [*read, key[1]]):
        return
    try:
        signed = {path: _signature(path) for path in read}
        folders = [(folder, _signature(folder)) for folder, _ in layout]
        # what was read must still be what it was: an edit since is never stored under it
        if any(signed[path][0] != mtime for path, mtime in read.items()) or any(
            signature[0] != mtime for (_, signature), (_, mtime) in zip(folders, layout)
        ):
            return
        stored = {
            "key": list(key),
            "kind": kind,
            "value": sorted(value) if kind == "frozenset" else value,
            "read": signed,  # each file and folder read, as signed (its mtime first)
            "folders": folders,  # the zoo's layout, likewise
        }
        atomic_write_json(_store_file(key), stored)
    except OSError:  # a cache folder not writable here: kept in memory only
        return
    _mark_store_used()


@cache
def _mark_store_used() -> None:
    """This version's folder used now (its mtime), once a process; the other versions' folders
    no process used for :data:`_STORED_UNUSED_DAYS` removed."""
    folder = _store_folder()
    oldest = time.time() - _STORED_UNUSED_DAYS * 86400
    try:
        os.utime(folder)
        others = [f for f in folder.parent.iterdir() if f != folder]
    except OSError:
        return
    for other in others:
        try:
            if other.stat().st_mtime < oldest:
                shutil.rmtree(other)
        except OSError:  # another process removed it first
            pass


def module_pieces(path: Path) -> set[str]:
    """A whole module as location-free pieces: each definition by name, each other statement,
    each import from outside the zoo. Kept for the rest of the process while neither the module
    nor any file or folder its pieces were resolved through, nor the zoo's folder layout,
    changes (a rebuild asks for the evaluator's pieces once per row)."""
    path = path.resolve()

    def compute() -> frozenset[str]:
        defs, imports, others = _parts(path)
        pieces = {
            f"{name}::{_text_by_name(path, node, 2)}"
            for name, nodes in defs.items()
            for node in nodes
        }
        pieces |= {f"::{_text_by_name(path, node, 2)}" for node in others}
        pieces |= {f"import::{b[1]}" for b in imports.values() if b[0] == "outside"}
        return frozenset(pieces)

    return set(_kept(("pieces", str(path)), compute))


@_one_layout
def code_fingerprint(*files: str | Path) -> str:
    """What the code of whole modules does: a hash of their pieces (:func:`module_pieces`),
    so neither their file names nor the order of their definitions count."""
    pieces: set[str] = set()
    for file in files:
        path = Path(file)
        pieces |= module_pieces(path if path.is_absolute() else REPO_ROOT / path)
    return _digest(sorted(pieces))


def _imported_files(path: Path) -> set[Path]:
    """The zoo modules a file imports, at module level or inside functions, absolute or
    relative (``from zoo.models import dct`` names the module ``zoo.models.dct``)."""
    try:
        mtime_ns = path.stat().st_mtime_ns
    except OSError:
        return set()
    return set(_imported_module_files(str(path), mtime_ns, _current_layout()))


@cache
def _imported_module_files(file: str, mtime_ns: int, layout: tuple) -> frozenset[Path]:
    # kept for the zoo's folders as they are: which names are modules depends on what exists
    found = {zoo_module_file(n) for n in _imported_names(file, mtime_ns)}
    return frozenset(f for f in found if f is not None)


@cache
def _imported_names(file: str, mtime_ns: int) -> tuple[str, ...]:
    """Every module name a file's imports could name (its parse kept for the file as it is)."""
    path = Path(file)
    try:
        tree = _syntax_tree(file, mtime_ns)
    except (OSError, SyntaxError):
        return ()
    package = _package_of(path)
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = _import_base(node, package)
            names += [base, *(f"{base}.{a.name}" for a in node.names)]
    return tuple(names)


# The line by which a zoo module that only presents, stores or moves results says it cannot
# change a number: a comment, so that no fingerprint moves with it.
COMPUTES_NO_NUMBER = "# zoo: computes no number"


@cache
def _computes_no_number(file: str, mtime_ns: int) -> bool:
    with open(file, encoding="utf-8") as f:
        return any(line.rstrip() == COMPUTES_NO_NUMBER for line in f)


@_one_layout
def code_closure(*files: str | Path, computing_only: bool = False) -> list[Path]:
    """``files`` and every zoo module they import, transitively (sorted); with
    ``computing_only``, less the modules that say they compute no number
    (:data:`COMPUTES_NO_NUMBER`) and what is reached only through them."""
    todo = [Path(f) if Path(f).is_absolute() else (REPO_ROOT / f) for f in files]
    seen: set[Path] = set()
    while todo:
        path = todo.pop().resolve()
        if path in seen:
            continue
        if computing_only and _computes_no_number(str(path), path.stat().st_mtime_ns):
            continue
        seen.add(path)
        todo += sorted(_imported_files(path) - seen)
    return sorted(seen)


# ---- a model's own code: the definitions its class reaches --------------------------------


def _used_names(nodes: list) -> set[tuple[str, ...]]:
    """Every name the statements use, with the attributes read from it (``a.b.c`` gives
    ``("a", "b", "c")``, a bare ``a`` gives ``("a",)``)."""
    used: set[tuple[str, ...]] = set()
    inner: set[int] = set()  # a name or chain read only for an attribute of it: not used whole
    for node in nodes:
        for sub in ast.walk(node):  # outer attributes before the chains inside them
            if isinstance(sub, ast.Attribute) and id(sub) not in inner:
                chain, base = [sub.attr], sub.value
                while isinstance(base, ast.Attribute):
                    inner.add(id(base))
                    chain.insert(0, base.attr)
                    base = base.value
                if isinstance(base, ast.Name):
                    used.add((base.id, *chain))
                    inner.add(id(base))
            elif isinstance(sub, ast.Name) and id(sub) not in inner:
                used.add((sub.id,))
    return used


@_one_layout
def reachable_code(cls: type) -> list[str] | None:
    """What a model class's results depend on in code, as ``where::name::text`` pieces: its own
    definition and every zoo definition it reaches by name (functions, classes, constants;
    through imports across zoo modules and modules beside a model file, base classes
    included), the imports from outside zoo that those use, and the other top-level statements
    of every module reached. A second class in the same file is not among them; a changed
    helper, constant, base class or import is. None where Python keeps no source for the
    class, or it is not defined at a module's top level."""
    try:
        file = inspect.getsourcefile(cls)
    except (OSError, TypeError):
        return None
    if file is None or not Path(file).is_file():
        return None
    return _reachable(Path(file).resolve(), cls.__name__)


def _reachable(start: Path, name: str) -> list[str] | None:
    """:func:`reachable_code` of the top-level definition ``name`` of ``start``; None where it
    defines no such name."""
    if name not in _parts(start)[0]:
        return None
    # kept like a module's pieces: a rebuild asks for each row's model, many rows a model
    return list(_kept(("reachable", str(start), name), lambda: _reached(start, name)))


def _placeless_digest(pieces: list[str]) -> str:
    """A fingerprint of code pieces without the places they were found in."""
    return _digest(sorted({piece.split("::", 1)[1] for piece in pieces}))


def _reached(start: Path, class_name: str) -> tuple[str, ...]:
    def label(path: Path) -> str:
        return str(path.relative_to(REPO_ROOT)) if path.is_relative_to(REPO_ROOT) else path.name

    pieces: set[str] = set()
    seen: set[tuple[Path, str | None]] = set()
    todo: list[tuple[Path, str | None]] = [(start, class_name)]
    walk = _Walk(f"{label(start)}:{class_name}")
    while todo:
        path, name = todo.pop()
        if (path, name) in seen:
            continue
        seen.add((path, name))
        walk.visit(path)
        defs, imports, others = _parts(path)
        if (path, "") not in seen:  # a module's other statements, once
            seen.add((path, ""))
            pieces |= {f"{label(path)}::::{_text_by_name(path, n, 2)}" for n in others}
            todo += [(path, None)]  # what those statements use
        nodes = others if name is None else defs.get(name, [])
        if name is not None and not nodes and name in imports:
            uses = {(name,)}  # a name this module only imports (a re-export): follow it
        else:
            uses = _used_names(nodes)
        pieces |= {f"{label(path)}::{name}::{_text_by_name(path, n, 2)}" for n in nodes if name}
        local = _local_bindings(nodes, path)
        for used in uses:
            head = used[0]
            if head in defs and head != name and head not in local:
                todo.append((path, head))
            elif head in local or head in imports:
                binding = local.get(head) or imports[head]
                if binding[0] == "outside":
                    pieces.add(f"{label(path)}::import::{binding[1]}")
                    continue
                found = _resolve(path, binding, list(used[1:]))
                if found is None:
                    continue
                target, attribute, _ = found
                target_defs = _parts(target)[0]
                if attribute is None or attribute not in target_defs:
                    # the module itself is used, or a name it does not define: all of it
                    todo += [(target, n) for n in target_defs] + [(target, None)]
                else:
                    todo.append((target, attribute))
    return tuple(sorted(pieces))


class FingerprintError(StoreError):
    pass


class _Walk:
    """The files a model's code walk reaches, bounded: it says what it is doing once it takes
    longer than a few seconds, and past ``MAX_FILES`` researcher files it stops, naming the
    folders that brought them in (a library reached as code: install it, or mark it one)."""

    MAX_FILES = 2000
    QUIET_SECONDS = 5.0

    def __init__(self, what: str) -> None:
        self.what, self.files, self.started, self.told = what, set(), time.monotonic(), False

    def visit(self, path: Path) -> None:
        if path in self.files or path.is_relative_to(REPO_ROOT):
            return
        self.files.add(path)
        if not self.told and time.monotonic() - self.started > self.QUIET_SECONDS:
            self.told = True
            print(
                f"zoo: fingerprinting the code of {self.what}: {len(self.files)} files outside "
                "the zoo so far",
                file=sys.stderr,
            )
        if len(self.files) > self.MAX_FILES:
            folders = Counter(f.parent for f in self.files).most_common(3)
            raise FingerprintError(
                f"the code of {self.what} reaches more than {self.MAX_FILES} files outside the "
                f"zoo (most from {', '.join(str(f) for f, _ in folders)}): a library is being "
                "read as a researcher's code; install the author's dependencies with pip (or "
                "pip install --target DIR and PYTHONPATH=DIR), see docs/adding-a-model.md"
            )


@_one_layout
def model_fingerprint(cls: type) -> str | None:
    """A model class's code fingerprint: of :func:`reachable_code` without the places its
    pieces were found in, or, for a class defined other than at a module's top level, of its
    file and the zoo modules it imports; None where Python keeps no source for it (a class
    typed into an interpreter)."""
    code = reachable_code(cls)
    if code is not None:
        return _placeless_digest(code)
    sources = model_source_files(cls)
    return code_fingerprint(*sources) if sources else None


@_one_layout
def definition_fingerprint(file: Path, name: str) -> str | None:
    """The fingerprint of the top-level definition ``name`` of ``file`` (a benchmark's own
    loader or skeleton), taken as :func:`model_fingerprint` takes a class's: what it reaches by
    name, modules beside it included. None where ``file`` does not define ``name``."""
    file = Path(file).resolve()
    pieces = _reachable(file, name) if file.is_file() else None
    return _placeless_digest(pieces) if pieces is not None else None


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
