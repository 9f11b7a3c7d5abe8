"""Code named by a data file: a registry entry's class, a benchmark's loader.

A definition is named ``path/to/file.py:name`` (a path relative to the file that names it, run as
Python runs a script, so the files beside it import by their names) or ``package.module:name``
(also ``package.module.name``, as registry entries name classes).
"""

# zoo: computes no number

from __future__ import annotations
import __future__

import ast
import importlib
import importlib.util
import inspect
import sys
import traceback
from pathlib import Path
from typing import Any

from zoo.core.errors import ZooError


class DefinitionError(ZooError, ValueError):
    """The named code cannot be loaded; the message says why, without naming the data file
    (its reader adds that)."""


def load_definition(spec: str, base: Path, kind: str = "class") -> Any:
    """The object ``spec`` names; ``base``: the folder a file path is relative to; ``kind``
    ("class", "function" or "skeleton"): what the messages call it."""
    try:
        if ".py:" in spec or spec.endswith(".py"):
            file_part, name = spec.rsplit(":", 1) if ":" in spec else (spec, "")
            file = (base / file_part).resolve()
            if not file.is_file():
                raise DefinitionError(f"{kind} file {file} does not exist")
            module, where = _run_file(file, kind), file
        else:
            module_name, name = spec.rsplit(":" if ":" in spec else ".", 1)
            module, where = importlib.import_module(module_name), f"module {module_name}"
        if not name or not hasattr(module, name):
            defined = sorted(
                n
                for n, value in vars(module).items()
                if not n.startswith("_") and _is_kind(value, kind, module.__name__)
            )
            raise DefinitionError(
                f"{where} defines no {kind} {name!r}; it defines "
                f"{', '.join(defined) or f'no {kind}'}"
            )
        return getattr(module, name)
    except SyntaxError as e:  # the file's own line, not a traceback through the loader
        raise DefinitionError(
            f"cannot load {kind} {spec!r}: {e.filename}, line {e.lineno}: {e.msg}"
        ) from e
    except (ImportError, AttributeError, ValueError) as e:
        if isinstance(e, DefinitionError):
            raise
        raise DefinitionError(f"cannot load {kind} {spec!r} ({e})") from e


def _is_kind(value: Any, kind: str, module: str) -> bool:
    """Whether ``value``, found in ``module``, is a ``kind`` defined there (a class, a
    function, or else a value: a skeleton, a constant)."""
    if kind in ("class", "function"):
        wanted = isinstance(value, type) if kind == "class" else inspect.isfunction(value)
        return wanted and getattr(value, "__module__", None) == module
    feature = isinstance(value, __future__._Feature)  # from __future__ import annotations
    return not (callable(value) or inspect.ismodule(value) or feature)


def _run_file(file: Path, kind: str):
    module_name = f"zoo_user_{abs(hash(str(file)))}"
    module = sys.modules.get(module_name)
    if module is not None:
        return module
    _check_siblings(file, kind)
    if str(file.parent) not in sys.path:
        sys.path.insert(0, str(file.parent))
    spec = importlib.util.spec_from_file_location(module_name, file)
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException as e:
        del sys.modules[module_name]  # a half-run file is not loaded
        said = (SyntaxError, ImportError, AttributeError, ValueError)
        if not isinstance(e, Exception) or isinstance(e, said):
            raise  # said in one line by load_definition (an interrupt: as it is)
        # the file's own fault as it ran (a NameError, a KeyError): its line, not a traceback
        frames = [f for f in traceback.extract_tb(e.__traceback__) if f.filename == str(file)]
        line = f", line {frames[-1].lineno}" if frames else ""
        raise DefinitionError(f"{file}{line}: running it raised {type(e).__name__}: {e}") from e
    return module


def _check_siblings(file: Path, kind: str) -> None:
    """Refuse a file that imports a module of its folder that Python would not import from
    there: one of that name is loaded already from elsewhere (another registry's folder, or an
    installed package), so it would run other code than its folder's, which a row's identity
    covers."""
    try:
        tree = ast.parse(file.read_text())
    except (OSError, SyntaxError, ValueError):
        return  # running the file says what is wrong with it
    imported = {
        a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names
    }
    imported |= {
        n.module.split(".")[0]
        for n in ast.walk(tree)
        if isinstance(n, ast.ImportFrom) and n.module and not n.level
    }
    siblings = [p for p in file.parent.glob("*.py") if p != file and p.stem in imported]
    siblings += [p.parent for p in file.parent.glob("*/__init__.py") if p.parent.name in imported]
    for sibling in siblings:
        loaded = sys.modules.get(sibling.stem if sibling.suffix == ".py" else sibling.name)
        origin = getattr(loaded, "__file__", None)
        expected = sibling if sibling.suffix == ".py" else sibling / "__init__.py"
        if origin and Path(origin).resolve() != expected.resolve():
            raise DefinitionError(
                f"{expected} would not be what its {kind} file imports: a module "
                f"{loaded.__name__!r} is loaded already from {origin}; rename one of them"
            )
