"""Which data files a block of code opens (:func:`recording_files_read`), through Python's
audit hook: what a model's constructor reads (an author's ``.pth`` loaded in a wrapper's
``__init__``) is part of what its results depend on, though it is neither code nor a
hyper-parameter. Code (``.py``, compiled modules), installed libraries, the interpreter's own
files and the system's pseudo-files are not data and are left out.
"""

from __future__ import annotations

import os
import site
import stat
import sys
import sysconfig
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from functools import cache
from pathlib import Path

_CODE_SUFFIXES = frozenset({".py", ".pyc", ".pyi", ".pyd", ".so", ".dylib", ".dll"})
_PSEUDO = ("/proc/", "/sys/", "/dev/")
_recorders: list[tuple[int, set[str]]] = []  # (thread, files opened) of each open recording
_lock = threading.Lock()
_installed = False


def _on_audit(event: str, args: tuple) -> None:
    if event != "open" or not _recorders or not args:
        return
    path = args[0]
    mode = args[1] if len(args) > 1 else None
    flags = args[2] if len(args) > 2 else None  # os.open: (path, None, flags)
    if isinstance(mode, str) and any(c in mode for c in "wax+"):
        return  # written, not read
    if isinstance(flags, int) and flags & (os.O_WRONLY | os.O_RDWR):
        return
    if not isinstance(path, (str, bytes, os.PathLike)):
        return  # a file descriptor: opened before, by name
    thread = threading.get_ident()
    for owner, files in tuple(_recorders):
        if owner == thread:  # resolved now: the block may change folder before it ends
            files.add(os.path.abspath(os.fsdecode(path)))


@cache
def library_folders() -> tuple[Path, ...]:
    """Folders of the interpreter and of installed packages (this environment's)."""
    folders = {Path(p) for p in sysconfig.get_paths().values()}
    folders |= {Path(p) for p in site.getsitepackages()}
    folders |= {Path(p) for p in (sys.prefix, sys.base_prefix, sys.exec_prefix)}
    user = site.getusersitepackages()
    if isinstance(user, str):
        folders.add(Path(user))
    return tuple(sorted({f.resolve() for f in folders}))


@cache
def _machine_folders() -> tuple[Path, ...]:
    """Where libraries keep what belongs to this machine, never to a model: caches, settings."""
    home = Path.home()
    cache_home = Path(os.environ.get("XDG_CACHE_HOME") or home / ".cache")
    config_home = Path(os.environ.get("XDG_CONFIG_HOME") or home / ".config")
    return (cache_home, config_home, Path("/etc"))


def is_data_file(path: str | Path, code_folders: tuple[Path, ...] = ()) -> bool:
    """Whether an opened file is data a computation read: a regular file, not code, not in an
    installed library or the interpreter, not under ``code_folders`` (the zoo's own code)."""
    text = str(path)
    if text.startswith(_PSEUDO) or Path(text).suffix in _CODE_SUFFIXES:
        return False
    if any(Path(text).is_relative_to(f) for f in _machine_folders()):
        return False  # a library's cache or settings (matplotlib's font list): this machine's
    try:
        if not stat.S_ISREG(os.stat(text).st_mode):
            return False
    except OSError:
        return False
    resolved = Path(text).resolve()
    return not any(resolved.is_relative_to(f) for f in (*library_folders(), *code_folders))


@contextmanager
def recording_files_read(code_folders: tuple[Path, ...] = ()) -> Iterator[set[Path]]:
    """The data files (:func:`is_data_file`) this thread opens for reading inside the block,
    resolved, in the set it yields (filled when the block ends)."""
    global _installed
    with _lock:
        if not _installed:  # an audit hook cannot be removed: one, idle without a recording
            sys.addaudithook(_on_audit)
            _installed = True
    opened: set[str] = set()
    entry = (threading.get_ident(), opened)
    _recorders.append(entry)
    found: set[Path] = set()
    try:
        yield found
    finally:
        # this recording's own entry (a nested one holds an equal tuple until both are filled)
        del _recorders[next(i for i, e in enumerate(_recorders) if e is entry)]
        found |= {Path(p).resolve() for p in tuple(opened) if is_data_file(p, code_folders)}
