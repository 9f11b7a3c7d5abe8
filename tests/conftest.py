"""Shared fixtures: tiny datasets written in the exact on-disk formats."""

import os
import sys

# Compiled bytecode is kept even where PYTHONDONTWRITEBYTECODE is set: both xdist workers and
# every command a test runs in a subprocess would otherwise compile the same modules (torch's
# among them) again, seconds of CPU each. Python checks each cached file against its source;
# git ignores __pycache__. Set here, before the imports below and before the workers start.
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
sys.dont_write_bytecode = False
# One thread per pytest-xdist worker, the workers sharing the machine's cores: numpy's and
# scipy's BLAS read this before they load (below), and so does every command a test runs.
if os.environ.get("PYTEST_XDIST_WORKER"):
    for threads in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(threads, "1")

import fcntl  # noqa: E402
import functools  # noqa: E402
import gc  # noqa: E402
import io  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

if os.environ.get("PYTEST_XDIST_WORKER"):  # xdist's controller runs no test: no torch there
    import torch

    torch.set_num_threads(1)

# A full collection walks every object the imported libraries keep (torch's, pandas',
# matplotlib's), and the tests leave little cyclic garbage: full collections a tenth as often.
gc.set_threshold(700, 10, 100)

REPO = Path(__file__).resolve().parents[1]
CMU_DATA = REPO.parent / "shared" / "data" / "cmu_mocap"

# Joint 5's exp-map columns in a CMU file: 3 (root position) + 3 * 5.
JOINT5 = 3 + 3 * 5
LEAF_OFFSET = 1.11249 * 70  # joint 6's bone length (mm): the only joint that joint 5 moves


# A file's text by its angles: many tests write the same motion, formatted once.
_CMU_TEXT: dict[bytes, str] = {}


def write_cmu_file(path: Path, angles: np.ndarray) -> Path:
    """A CMU exp-map file whose only motion is joint 5 rotating about x by ``angles``."""
    angles = np.asarray(angles, dtype=np.float64)
    text = _CMU_TEXT.get(angles.tobytes())
    if text is None:
        frames = np.zeros((len(angles), 117))
        frames[:, :3] = [1.0, 2.0, 3.0]  # root position: never applied
        frames[:, JOINT5] = angles
        buffer = io.StringIO()
        np.savetxt(buffer, frames, delimiter=",", fmt="%.10f")
        text = _CMU_TEXT.setdefault(angles.tobytes(), buffer.getvalue())
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


@pytest.fixture
def swinging_cmu(tmp_path) -> tuple[Path, float]:
    """A CMU data root with one test file: joint 5 turns by ``omega`` rad per source frame."""
    omega = 0.01
    write_cmu_file(tmp_path / "cmu" / "test" / "walking" / "walking_1.txt", omega * np.arange(200))
    return tmp_path / "cmu", omega


class Pristine:
    """A folder built once per test process by ``build(folder)`` (a board, a trained run), on
    the first :meth:`restore`, and put back as first built for each test after, so that
    end-to-end tests share one build rather than each making its own. Restored at the path it
    was built at: what a build writes records paths (a checkpoint its registry file). A build
    that failed fails each test after with its error, unrepeated."""

    def __init__(self, folder: Path, build: Callable[[Path], object]) -> None:
        self.folder, self._build = folder, build
        self._copy = folder.with_name(f"{folder.name}.pristine")
        self._failed: BaseException | None = None

    def restore(self) -> Path:
        """The folder as it was built, whatever an earlier test did to it."""
        if self._failed is not None:
            raise RuntimeError(f"{self.folder}: its build failed") from self._failed
        if self.folder.exists():
            shutil.rmtree(self.folder)
        if not self._copy.is_dir():
            try:
                self._build(self.folder)
            except BaseException as e:
                self._failed = e
                raise
            partial = self._copy.with_name(f"{self._copy.name}.partial")
            shutil.copytree(self.folder, partial, symlinks=True)
            partial.rename(self._copy)  # whole or absent
            return self.folder
        shutil.copytree(self._copy, self.folder, symlinks=True)
        return self.folder


# A plot's digest (the Drawn-From text it keeps: zoo.report.outputs.plot_digests) names its
# bytes: the zoo copies a plot whose digest a table's previous folder holds rather than draw it
# again. The tests apply that rule across their folders and runs: each plot is drawn once, kept
# under cache/ (git ignores it) by its digest, and copied from there by every test and run after.
DRAWN_PLOTS = REPO / "cache" / "drawn-plots"
# Kept plots no run has used for this long are removed: each change to a plot's code or data
# leaves its old bytes under a digest nothing asks for again.
_KEPT_PLOT_DAYS = 14
_PNG_END = b"IEND\xaeB`\x82"  # a PNG's last chunk: a file cut short is drawn again


def _remove_plots_left_unused() -> None:
    import time

    oldest = time.time() - _KEPT_PLOT_DAYS * 86400
    for kept in DRAWN_PLOTS.glob("*/*"):
        try:
            if kept.stat().st_mtime < oldest:
                kept.unlink()
        except OSError:  # the other worker removed it first
            pass


_remove_plots_left_unused()


@functools.cache
def _drawing_environment() -> Path:
    """The folder of plots drawn here: a digest of what besides the product's digest sets a
    PNG's bytes (matplotlib's settings, the Pillow that encodes it), so that another
    environment draws its own."""
    import hashlib

    import matplotlib
    import pandas
    import PIL

    # the backend chosen so far is no drawing setting (save_figure draws with Agg)
    drawing = {k: v for k, v in matplotlib.rcParams.items() if not k.startswith("backend")}
    settings = repr(sorted(drawing.items())) + PIL.__version__
    # the figure is built from pandas' and numpy's results: an upgrade draws everything once
    settings += pandas.__version__ + np.__version__
    return DRAWN_PLOTS / hashlib.sha256(settings.encode()).hexdigest()[:16]


def _kept_plot_path(digest: str, tight: bool) -> Path:
    return _drawing_environment() / f"{digest}-{'tight' if tight else 'placed'}.png"


def _kept_plot(path: Path) -> bytes | None:
    """A kept plot's bytes, marked used now; None where there is none to use (missing, cut
    short, unreadable)."""
    try:
        os.utime(path)  # used now: not removed as left unused
        data = path.read_bytes()
    except OSError:
        return None
    return data if data.endswith(_PNG_END) else None


@pytest.fixture(autouse=True)
def _each_plot_drawn_once(monkeypatch):
    from zoo.core.io import atomic_path
    from zoo.report import outputs
    from zoo.stats import sensitivity

    draw = outputs.save_figure

    def save_figure(fig, path, drawn_from=None, *, tight=True):
        if drawn_from is None:
            return draw(fig, path, tight=tight)
        kept = _kept_plot_path(drawn_from, tight)
        data = _kept_plot(kept)
        if data is None:
            draw(fig, path, drawn_from, tight=tight)
            try:
                with atomic_path(kept) as tmp:
                    shutil.copyfile(path, tmp)
            except OSError:  # a folder not writable here: the plot is drawn again next time
                pass
            return
        import matplotlib.pyplot as plt

        plt.close(fig)  # as save_figure leaves it
        with atomic_path(path) as tmp:
            tmp.write_bytes(data)

    monkeypatch.setattr(outputs, "save_figure", save_figure)
    monkeypatch.setattr(sensitivity, "save_figure", save_figure)
    return save_figure


def _kept_plots_of(digests: dict[str, str]) -> dict[str, bytes] | None:
    """``{file: bytes}`` kept for every digest of ``digests`` (``{file: digest}``, plots placed
    by their caller), or None where any is to be drawn."""
    kept = {}
    for name, digest in digests.items():
        data = _kept_plot(_kept_plot_path(digest, tight=False))
        if data is None:
            return None
        kept[name] = data
    return kept


@pytest.fixture(autouse=True)
def _a_kept_plot_is_not_built(_each_plot_drawn_once, monkeypatch):
    """A table's plots whose bytes are all kept (:func:`_each_plot_drawn_once`) are written
    without building their figures: the digest covers the drawing code and its inputs, so the
    figure would be the one kept. A plot the table's previous folder holds is copied, as
    ``plot_average`` does; any plot to draw draws them all as ``plot_average`` does. A test
    that puts its own ``save_figure`` in place (to count or measure draws) gets
    ``plot_average`` as it is."""
    from zoo.core.io import atomic_path, figure_drawn_from
    from zoo.report import outputs

    draw = outputs.plot_average

    @functools.wraps(draw)  # the digest reads the drawing code's source: plot_average's
    def plot_average(frame, out_dir, title="", previous=None):
        if outputs.save_figure is not _each_plot_drawn_once:
            return draw(frame, out_dir, title, previous)
        digests = outputs.plot_digests(frame, title)
        if previous is not None and any(
            figure_drawn_from(Path(previous) / name) == digest for name, digest in digests.items()
        ):
            return draw(frame, out_dir, title, previous)
        kept = _kept_plots_of(digests)
        if kept is None:
            return draw(frame, out_dir, title, previous)
        written = []
        for name in outputs.plot_files(frame):
            with atomic_path(Path(out_dir) / name) as tmp:
                tmp.write_bytes(kept[name])
            written.append(Path(out_dir) / name)
        return written

    monkeypatch.setattr(outputs, "plot_average", plot_average)


# A CMU or H3.6M file's sequence by its bytes and how it is read: tests load the same texts
# (write_cmu_file's, the shared recordings) many times a process; each is parsed and carried
# through the forward kinematics once, and a fresh copy of its arrays given each time.
_SEQUENCES: dict[tuple, object] = {}


def _each_recording_read_once() -> None:
    import dataclasses
    import hashlib

    from zoo.data import motion

    load = motion._load_sequence

    @functools.wraps(load)
    def _load_sequence(path, root, action, skeleton, source_fps, subsample, subaction=1):
        try:
            digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
        except OSError:  # refused as the loader refuses it
            return load(path, root, action, skeleton, source_fps, subsample, subaction)
        key = (digest, skeleton.name, source_fps, subsample)
        if key not in _SEQUENCES:
            _SEQUENCES[key] = load(path, root, action, skeleton, source_fps, subsample, subaction)
        read = _SEQUENCES[key]
        return dataclasses.replace(
            read,
            name=Path(path).relative_to(root).as_posix(),
            action=action,
            subaction=subaction,
            positions=read.positions.copy(),
            angles=None if read.angles is None else read.angles.copy(),
        )

    motion._load_sequence = _load_sequence


@pytest.fixture(autouse=True, scope="session")
def _recordings_read_once_a_process():
    # a fixture, not done on import: xdist's controller imports this file and runs no test
    _each_recording_read_once()


def use_toy_loader(monkeypatch, loader: Callable) -> None:
    """Benchmark files whose loader is ``toy.py:...`` load ``loader``: a test's own data, built
    in the test, with no file of its own; every other benchmark loads as it does."""
    from zoo.protocol.benchmark import Benchmark

    own = Benchmark.loader_function
    monkeypatch.setattr(
        Benchmark,
        "loader_function",
        lambda self: loader if self.loader.startswith("toy.py:") else own(self),
    )


# The anny package's first build of the Anny body is long (docs/architecture.md, "Tests"), and
# cached for the machine (anny's cache folder: ANNY_CACHE_DIR, else ~/.cache/anny). The low
# body's build, the only one these tests load, ships in tests/data under the anny version that
# made it, as that anny names it, and is put in that cache where the cache has none and that
# version is installed: test_anny.py checks that anny loads it without building, and (slow)
# that a build here makes the same body.
ANNY_SHIPPED = REPO / "tests" / "data" / "anny-0.6.2"


def anny_cache_folder() -> Path:
    """anny's cache folder, as ``anny.paths`` reads it, without importing anny (seconds)."""
    return Path(os.environ.get("ANNY_CACHE_DIR", Path.home() / ".cache" / "anny"))


def seed_anny_cache(folder: Path) -> None:
    """Each shipped build put in anny's cache ``folder`` where it is missing, if the anny that
    made it is the one installed (atomically: the xdist workers may do it at once)."""
    import importlib.metadata

    from zoo.core.io import atomic_path

    try:
        installed = importlib.metadata.version("anny")
    except importlib.metadata.PackageNotFoundError:
        return
    if ANNY_SHIPPED.name != f"anny-{installed}":
        return
    for shipped in ANNY_SHIPPED.rglob("*.safetensors"):
        target = folder / shipped.relative_to(ANNY_SHIPPED)
        if target.exists():
            continue
        with atomic_path(target) as tmp:
            shutil.copyfile(shipped, tmp)


try:
    seed_anny_cache(anny_cache_folder())
except OSError:  # a read-only cache: anny builds the body as it would have
    pass

# If a body is built all the same (another anny, another topology), anny's tests run first, so
# that under worksteal (pyproject's addopts) the first worker's half starts with them and the
# other worker runs the rest meanwhile, and a load waits for one in progress (a lock for the
# machine, as the cache is) instead of building it again.
ANNY_FIRST = ("test_anny.py", "test_spectrhums_anchored.py")
_ANNY_LOCK = Path(tempfile.gettempdir()) / "zoo-tests-anny-body.lock"


def _one_anny_build_at_a_time() -> None:
    from zoo.data import anny as zoo_anny
    from zoo.data.anny import body

    build = body.load_anny_model

    @functools.wraps(build)
    def load_anny_model(*args, **kwargs):
        with open(_ANNY_LOCK, "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
            return build(*args, **kwargs)

    body.load_anny_model = zoo_anny.load_anny_model = load_anny_model


if os.environ.get("PYTEST_XDIST_WORKER"):
    _one_anny_build_at_a_time()


def pytest_collection_modifyitems(items) -> None:
    first = [item for item in items if item.path.name in ANNY_FIRST]
    items[:] = first + [item for item in items if item.path.name not in ANNY_FIRST]
