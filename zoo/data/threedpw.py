"""3DPW (von Marcard et al., ECCV 2018) as LTD and SPGSN use it: ``jointPositions``, SMPL's 24
joints at the recordings' 30 Hz, every actor of every sequence file, root-centred, in mm.

Layout: ``<root>/sequenceFiles/{train,validation,test}/<sequence>.pkl`` (or the split folders
directly under ``<root>``). 3DPW ships Python pickles, and a pickle may run any code while it
loads; these are read by :class:`ArraysOnlyUnpickler`, which rebuilds plain containers and
numpy arrays and refuses anything else, naming the file and what it asked for.

3DPW is licensed per user: it is never shipped, and the tests write small files in its exact
format. Every actor's track is one sequence named ``<file>#<actor>``; all share the action
``all`` (the literature averages over every window, not over activities).
"""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np

from zoo.core.errors import DataNotFoundError, ZooError
from zoo.core.io import sha256_file
from zoo.data.expmap import DataFormatError
from zoo.data.motion import MotionDataset, MotionSequence, _check_root, found_entries
from zoo.data.skeleton import THREEDPW

SPLITS = ("train", "validation", "test")
FPS = 30.0
ACTION = "all"
M_TO_MM = 1000.0

# What a 3DPW pickle needs to rebuild its numpy arrays (NumPy 1 and 2 module names); nothing
# else is ever imported or called.
_ALLOWED = {
    ("numpy.core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"),
    ("numpy._core.multiarray", "scalar"),
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
    # a protocol-2 pickle written by Python 3 rebuilds bytes with it (a pure function)
    ("_codecs", "encode"),
}


class ArraysOnlyUnpickler(pickle.Unpickler):
    """Rebuilds dicts, lists, tuples, strings, numbers and numpy arrays; any other global a
    pickle asks for (a function to call, a class to build) is refused."""

    def __init__(self, file, path: Path) -> None:
        super().__init__(file, encoding="latin1")  # 3DPW's pickles come from Python 2
        self.path = path

    def find_class(self, module: str, name: str):
        if (module, name) not in _ALLOWED:
            raise DataFormatError(
                f"{self.path}: refusing to load it: the pickle asks for "
                f"{module}.{name}, and a 3DPW file holds only containers and "
                f"numpy arrays (a pickle can run code while it loads)"
            )
        if module.startswith("numpy.core.") and int(np.__version__.split(".")[0]) >= 2:
            module = "numpy._core." + module[len("numpy.core.") :]  # NumPy 2's name for it
        return super().find_class(module, name)


def read_3dpw_file(path: str | Path) -> dict:
    path = Path(path)
    try:
        with open(path, "rb") as f:
            data = ArraysOnlyUnpickler(f, path).load()
    except DataFormatError:
        raise
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, IndexError) as e:
        raise DataFormatError(
            f"{path}: not a readable 3DPW pickle ({type(e).__name__}: {e})"
        ) from None
    if not isinstance(data, dict) or "jointPositions" not in data:
        raise DataFormatError(
            f"{path}: a 3DPW sequence file is a dict with 'jointPositions' "
            f"(one (frames, 72) array per actor); got "
            f"{sorted(data) if isinstance(data, dict) else type(data).__name__}"
        )
    tracks = data["jointPositions"]
    if not isinstance(tracks, (list, tuple)) or not tracks:
        raise DataFormatError(
            f"{path}: 'jointPositions' must be a non-empty list with one array per actor"
        )
    for actor, track in enumerate(tracks):
        if not isinstance(track, np.ndarray) or track.ndim != 2 or track.shape[1] != 72:
            raise DataFormatError(
                f"{path}: jointPositions[{actor}] must be a (frames, 72) "
                f"array (24 joints x 3, metres), got "
                f"{getattr(track, 'shape', type(track).__name__)}"
            )
        if not np.isfinite(track).all():
            raise DataFormatError(f"{path}: jointPositions[{actor}] holds non-finite values")
    return data


def load_3dpw(
    root: str | Path | None, split: str = "test", actions: tuple[str, ...] = (ACTION,)
) -> MotionDataset:
    """Every actor track of every sequence file of ``split`` (``train``, ``validation`` or
    ``test``), root-centred, mm, 30 Hz."""
    root = _check_root(
        root,
        "3DPW",
        "pass --data-root pointing at the 3DPW folder holding "
        "sequenceFiles/ (3DPW is licensed per user and not shipped)",
    )
    if split not in SPLITS:
        raise ZooError(f"3DPW split must be one of {', '.join(SPLITS)}, got {split!r}")
    folder = root / "sequenceFiles" / split
    folder = folder if folder.is_dir() else root / split
    if not folder.is_dir():
        parent = root / "sequenceFiles" if (root / "sequenceFiles").is_dir() else root
        raise DataNotFoundError(
            f"{root}: no 3DPW split folder sequenceFiles/{split}/ (nor {split}/); "
            f"{found_entries(parent, split)}"
        )
    files = sorted(folder.glob("*.pkl"))
    if not files:
        raise DataNotFoundError(f"{folder}: no .pkl sequence file")
    sequences = []
    for path in files:
        data = read_3dpw_file(path)
        digest = sha256_file(path)
        for actor, track in enumerate(data["jointPositions"]):
            joints = track.reshape(len(track), 24, 3) * M_TO_MM
            sequences.append(
                MotionSequence(
                    name=f"{path.relative_to(root).as_posix()}#{actor}",
                    action=ACTION,
                    positions=(joints - joints[:, :1]).astype(np.float32),
                    fps=FPS,
                    sha256=digest,
                )
            )
    return MotionDataset(
        name="3dpw",
        split=split,
        root=root,
        skeleton=THREEDPW,
        sequences=sequences,
        actions_requested=tuple(actions),
        ltd_rule="per_file",
        source_fps=FPS,
        subsample=1,
    )
