"""Atomic file writes and provenance: nothing half-written is ever left behind."""

# zoo: computes no number

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import subprocess
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import yaml

from zoo.core.errors import ZooError
from zoo.core.version import __version__
from zoo.paths import REPO_ROOT


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; it replaces ``path`` only if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


class FolderBusyError(ZooError, RuntimeError):
    pass


@contextmanager
def folder_lock(path: str | Path) -> Iterator[None]:
    """Hold ``.<name>.lock`` beside ``path`` while writing it; a second writer is refused at
    once, naming the folder (two runs writing one folder would mix their files)."""
    import fcntl

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lock = path.parent / f".{path.name}.lock"
    with open(lock, "a") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise FolderBusyError(
                f"{path}: another zoo process is writing this folder (lock "
                f"{lock}); wait for it, or write elsewhere with --out"
            ) from None
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


# A folder the zoo wrote (zoo eval, zoo leaderboard) holds one of these; only such a folder,
# or an empty one, is ever replaced.
RESULT_MARKERS = ("results.csv", "protocol.json")


def check_output_folder(path: str | Path, markers: tuple[str, ...] = RESULT_MARKERS) -> None:
    """Refuse, before any work, an output folder that cannot be written or that is not the
    zoo's to replace (a file, or a folder of other things, holding none of ``markers``: never
    deleted)."""
    path = Path(path)
    if path.exists():
        if not path.is_dir():
            raise OutputError(
                f"--out {path}: exists and is not a folder; choose a new or empty folder"
            )
        if any(path.iterdir()) and not any((path / m).is_file() for m in markers):
            raise OutputError(
                f"--out {path}: a folder of other files, not one the zoo wrote "
                f"(no {' or '.join(markers)}); it would be replaced "
                f"whole, so choose a new or empty folder"
            )
    check_writable(path.parent, what=f"--out {path}")


def check_writable(folder: str | Path, what: str | None = None) -> None:
    """Refuse a folder that cannot be created or written in, before any work."""
    folder = Path(folder)
    parent = next((p for p in [folder, *folder.parents] if p.exists()), None)
    try:  # really try: permissions alone do not tell (root, read-only or virtual file systems)
        if parent is None or not parent.is_dir():
            raise OSError(f"{parent} is not a folder")
        os.rmdir(tempfile.mkdtemp(prefix=".zoo-write-test-", dir=parent))
    except OSError as e:
        raise OutputError(
            f"{what or folder}: cannot be written ({parent}: {e.strerror or e})"
        ) from None


class OutputError(ZooError, ValueError):
    pass


@contextmanager
def replace_folder(
    path: str | Path,
    lock: bool = True,
    checked: bool = False,
    markers: tuple[str, ...] = RESULT_MARKERS,
) -> Iterator[Path]:
    """Yield an empty sibling folder to fill; on success it replaces ``path`` as a whole (the
    old folder is renamed away first, then removed), so readers see the old folder or the new
    one, never a mix; on failure or interruption it is removed and ``path`` is untouched.
    ``lock=False``: the caller already holds :func:`folder_lock` of ``path``; ``checked``: the
    caller carries everything of ``path`` it keeps into the new folder itself (a table);
    ``markers``: the files by which a folder of ours is known (:func:`check_output_folder`)."""
    import shutil
    from contextlib import nullcontext

    path = Path(path)
    if not checked:
        check_output_folder(path, markers)
    path.parent.mkdir(parents=True, exist_ok=True)
    with folder_lock(path) if lock else nullcontext():
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
        try:
            yield tmp
            os.chmod(tmp, 0o777 & ~_umask())
            old = None
            if path.exists():
                old = Path(
                    tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent)
                )
                os.replace(path, old / path.name)
            os.replace(tmp, path)
            if old is not None:
                shutil.rmtree(old)
        finally:
            if tmp.exists():
                shutil.rmtree(tmp)


def repo_relative(path: str | Path) -> str:
    """``path`` relative to the repository when inside it (stored records name no machine's
    folders), else absolute."""
    path = Path(path).resolve()
    return str(path.relative_to(REPO_ROOT) if path.is_relative_to(REPO_ROOT) else path)


def registry_record(path: str | Path) -> str:
    """How a result names the registry file of its model: relative to the repository inside
    it; outside, ``outside:<file name>``, so a result shared from one machine names none of its
    folders (and a registry moved between folders keeps its results)."""
    path = Path(path).resolve()
    return (
        str(path.relative_to(REPO_ROOT))
        if path.is_relative_to(REPO_ROOT)
        else f"outside:{path.name}"
    )


def sha256_file(path: str | Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: str | Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def atomic_write_json(path: str | Path, data: Any) -> None:
    atomic_write_text(path, json.dumps(data, indent=2, sort_keys=False) + "\n")


def canonical_json(data: Any) -> str:
    return json.dumps(data, sort_keys=True, separators=(",", ":"))


@functools.cache
def code_version() -> str:
    """The package version plus the git commit of the source tree (``+dirty`` if modified), asked
    of git once per process: the code a process runs is the code it imported, and a rebuild that
    rewrites tracked ``results/`` files would otherwise call its own later rows dirty."""

    try:
        commit = subprocess.run(
            ["git", "-C", str(REPO_ROOT), "describe", "--always", "--dirty", "--abbrev=12"],
            capture_output=True,
            text=True,
            timeout=10,
        )
        if commit.returncode == 0 and commit.stdout.strip():
            return f"{__version__}+g{commit.stdout.strip()}"
    except (OSError, subprocess.SubprocessError):
        pass
    return __version__


# The PNG text field where a figure keeps the digest of what it was drawn from.
DRAWN_FROM = "Drawn-From"


def save_figure(
    fig, path: str | Path, drawn_from: str | None = None, *, tight: bool = True
) -> None:
    """A matplotlib figure as PNG, atomically; the figure is closed. ``drawn_from``: a digest of
    everything the figure shows, kept in the PNG (:func:`figure_drawn_from`), so that a figure
    asked for again from the same inputs is copied instead of drawn. ``tight``: laid out by
    matplotlib's ``tight_layout`` (False: the caller placed the axes)."""
    import matplotlib.pyplot as plt

    if tight:
        fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110, metadata={DRAWN_FROM: drawn_from or None})
    plt.close(fig)


def figure_drawn_from(path: str | Path) -> str | None:
    """The ``drawn_from`` digest a PNG of :func:`save_figure` keeps; None for a PNG without one,
    or a missing or unreadable file (which is then drawn again)."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as image:
            return getattr(image, "text", {}).get(DRAWN_FROM)
    except (OSError, UnidentifiedImageError, SyntaxError, ValueError):
        return None


def progress_bar(iterable=None, **options):
    """A tqdm progress bar on stderr, shown only to a person watching: where stderr is no
    terminal (a log file, a pipe, CI) it stays off, as it does with ``disable=True``."""
    from tqdm import tqdm

    return tqdm(iterable, **{**options, "disable": True if options.get("disable") else None})


def json_number(x) -> float | None:
    """A JSON number to 7 significant digits (what differs past them is CPU rounding, and a
    rebuild on another CPU then rewrites no file); None for a missing or non-finite value."""
    return float(f"{x:.7g}") if x is not None and math.isfinite(x) else None


def _refusing_repeated_keys(loader: type) -> type:
    """``loader`` refusing a mapping that writes a key twice, which YAML allows and reads as the
    last value: a field written twice in a registry or benchmark file is a mistake, not an
    override. Each mapping is checked once, as written: merging (``<<: *anchor``) rewrites a
    merged mapping's keys in place, and a key it overrides is then listed twice."""

    class Loader(loader):
        def flatten_mapping(self, node):
            checked = self.__dict__.setdefault("_checked_mappings", set())
            if id(node) not in checked:  # before its merges are expanded into it
                checked.add(id(node))
                seen = set()
                for key_node, _ in node.value:
                    if not isinstance(key_node, yaml.ScalarNode) or key_node.tag.endswith(":merge"):
                        continue
                    key = self.construct_object(key_node)
                    if key in seen:
                        raise yaml.constructor.ConstructorError(
                            None, None, f"key {key!r} is written twice", key_node.start_mark
                        )
                    seen.add(key)
            super().flatten_mapping(node)

    return Loader


_SAFE_LOADER = _refusing_repeated_keys(yaml.SafeLoader)
# libyaml's parser where PyYAML was built with it (its wheels are): the same safe constructor,
# about ten times faster on the registry and published.yaml, which every rebuild reads.
_YAML_LOADER = _refusing_repeated_keys(getattr(yaml, "CSafeLoader", yaml.SafeLoader))


def load_yaml(text: str) -> Any:
    """YAML text as plain data, as ``yaml.safe_load`` reads it (raises ``yaml.YAMLError``)."""
    try:
        return yaml.load(text, Loader=_YAML_LOADER)  # noqa: S506 - a safe loader
    except yaml.YAMLError:
        if not hasattr(yaml, "CSafeLoader"):
            raise
        # the pure-Python parser's message quotes the line and points at the character
        return yaml.load(text, Loader=_SAFE_LOADER)  # noqa: S506


def yaml_problem(error: yaml.YAMLError) -> str:
    """A YAML error in one line, where and what (PyYAML's message spans several lines, quoting
    the text and a caret under it)."""
    mark = getattr(error, "problem_mark", None)
    words = [getattr(error, "context", None), getattr(error, "problem", None)]
    said = str(error).splitlines() or [type(error).__name__]
    what = ", ".join(w for w in words if w) or said[0]
    return f"line {mark.line + 1}, column {mark.column + 1}: {what}" if mark else what
