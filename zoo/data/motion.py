"""Skeleton motion datasets in the exp-map layout: CMU Mocap and Human3.6M.

Both adapters read with the one exp-map reader, run the one FK routine, halve the frame rate
(every second source frame, starting with the first) and expose sequences that
carry their action, file, hash and fps.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from zoo.core.errors import DataNotFoundError
from zoo.core.io import sha256_file
from zoo.data.expmap import (
    DataFormatError,
    expmap_angles,
    expmap_to_positions,
    read_expmap_file,
)
from zoo.data.skeleton import CMU, H36M, Skeleton

CMU_ACTIONS = (
    "basketball",
    "basketball_signal",
    "directing_traffic",
    "jumping",
    "running",
    "soccer",
    "walking",
    "washwindow",
)
# Folders of the CMU release (convSeq2Seq's, which LTD and PGBIG read) beside its 8 actions that
# the protocol never reads: skipped without a warning, still listed by `zoo data list`.
CMU_RELEASE_EXTRAS = ("walking_extra",)
H36M_ACTIONS = (
    "walking",
    "eating",
    "smoking",
    "discussion",
    "directions",
    "greeting",
    "phoning",
    "posing",
    "purchases",
    "sitting",
    "sittingdown",
    "takingphoto",
    "waiting",
    "walkingdog",
    "walkingtogether",
)
H36M_SPLITS = {"train": (1, 6, 7, 8, 9), "val": (11,), "test": (5,)}


@dataclass
class MotionSequence:
    """One recording: joint positions ``(T, J, 3)`` in mm at ``fps``, root-relative, and where
    the data has them the exp-map angles ``(T, J, 3)`` they were made from (joint 0's: the root
    rotation, which the positions never apply)."""

    name: str  # path relative to the data root, the sequence's identity in protocol records
    action: str
    positions: np.ndarray
    fps: float
    sha256: str
    subaction: int = 1  # H3.6M's two recordings per action; CMU files are independent
    angles: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.positions)


@dataclass
class MotionDataset:
    name: str
    split: str
    root: Path
    skeleton: Skeleton
    sequences: list[MotionSequence]
    actions_requested: tuple[str, ...]
    ltd_rule: str  # how `ltd8` groups windows: "per_file" (CMU) or "per_action_pair" (H3.6M)
    source_fps: float
    subsample: int = 2
    notes: list[str] = field(default_factory=list)

    @property
    def fps(self) -> float:
        return self.source_fps / self.subsample

    @property
    def actions_present(self) -> tuple[str, ...]:
        present = {s.action for s in self.sequences}
        return tuple(a for a in self.actions_requested if a in present)

    def files(self) -> list[dict]:
        return [
            {"file": s.name, "sha256": s.sha256, "frames": len(s), "fps": s.fps}
            for s in self.sequences
        ]


def _load_sequence(
    path: Path,
    root: Path,
    action: str,
    skeleton: Skeleton,
    source_fps: float,
    subsample: int,
    subaction: int = 1,
) -> MotionSequence:
    angles = expmap_angles(read_expmap_file(path, skeleton)[::subsample], skeleton)
    return MotionSequence(
        name=path.relative_to(root).as_posix(),
        action=action,
        positions=expmap_to_positions(angles, skeleton),
        fps=source_fps / subsample,
        sha256=sha256_file(path),
        subaction=subaction,
        angles=angles.astype(np.float32),
    )


def _check_root(root: str | Path | None, what: str, hint: str) -> Path:
    if root is None:
        raise DataNotFoundError(f"no data root given for {what}: {hint}")
    root = Path(root)
    if not root.is_dir():
        raise DataNotFoundError(
            f"data root {root} for {what} does not exist or is not a folder: {hint}"
        )
    return root


def found_entries(folder: Path, expected: str) -> str:
    """What ``folder`` holds, for an error that names ``expected`` among them: its entries, and
    the one that differs from ``expected`` only in case or is closest to it, if any."""
    import difflib

    names = sorted(p.name for p in folder.iterdir()) if folder.is_dir() else []
    if not names:
        return f"{folder} is empty" if folder.is_dir() else f"{folder} does not exist"
    near = [n for n in names if n.lower() == expected.lower()] or difflib.get_close_matches(
        expected, names, n=1, cutoff=0.75
    )
    hint = f"; is {near[0]!r} meant to be {expected!r}?" if near else ""
    shown = ", ".join(names[:12]) + (f" and {len(names) - 12} more" if len(names) > 12 else "")
    return f"found in {folder}: {shown}{hint}"


def declared_missing(root: Path) -> set[str]:
    """Paths (relative to ``root``) that a data root's ``MISSING.txt`` declares absent (lines
    ``MISSING <root name>/<path>``, as ``../shared/data/cmu_mocap`` has): a copy that lacks some
    files of the standard set says so, and the zoo then does not take their absence for a
    misnamed folder."""
    path = root / "MISSING.txt"
    if not path.is_file():
        return set()
    out = set()
    for line in path.read_text().splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[0] == "MISSING":
            out.add(parts[1].removeprefix(f"{root.name}/"))
    return out


_WARNED: set[str] = set()


def _warn_once(text: str) -> None:
    """A warning about the data, on stderr, once per process (a run loads a root repeatedly)."""
    if text not in _WARNED:
        _WARNED.add(text)
        print(f"warning: {text}", file=sys.stderr)


def check_cmu_root(root: Path, split: str, actions: tuple[str, ...]) -> None:
    """Before anything is loaded, every action of the benchmark against ``<root>/<split>``:
    its folder is there, or the data root declares its files missing (``MISSING.txt``). An
    action without either, where the split holds a folder that looks like its name (another
    case, a near spelling), is an error naming the folder expected and the folders found;
    with nothing like it in its place, a warning (the action is scored without: partial copies
    are common). A folder that is no action is a warning too (its files are not read), unless
    the release ships it (``CMU_RELEASE_EXTRAS``)."""
    split_dir = root / split
    declared = declared_missing(root)
    extra = sorted(
        p.name
        for p in split_dir.iterdir()
        if p.is_dir() and p.name not in actions and p.name not in CMU_RELEASE_EXTRAS
    )
    absent = [
        a
        for a in actions
        if not (split_dir / a).is_dir() and not any(p.startswith(f"{split}/{a}/") for p in declared)
    ]  # neither there nor declared missing by this copy
    # an absent action that a stray folder looks like (another case, a near spelling)
    misnamed = [a for a in absent if "meant to be" in found_entries(split_dir, a)]
    if misnamed:
        action, others = misnamed[0], [a for a in absent if a != misnamed[0]]
        raise DataNotFoundError(
            f"{split_dir / action}: no folder for action {action!r} of the benchmark (expected "
            f"{split}/{action}/{action}_<n>.txt); {found_entries(split_dir, action)}; name the "
            f"folder {action!r}, or list its files in {root / 'MISSING.txt'} if this copy "
            f"lacks them" + (f" (absent too: {', '.join(others)})" if others else "")
        )
    if absent:
        _warn_once(
            f"{split_dir}: no folder for action(s) {', '.join(absent)} of the benchmark "
            f"(expected {split}/<action>/<action>_<n>.txt): scored without them (list their "
            f"files in {root / 'MISSING.txt'} to say this copy lacks them)"
        )
    if extra:
        _warn_once(
            f"{split_dir}: folder(s) {', '.join(extra)} are no action of the benchmark "
            f"({', '.join(actions)}); their files are not read"
        )


def cmu_skipped(root: Path, split: str, actions: tuple[str, ...] = CMU_ACTIONS) -> list[str]:
    """What :func:`load_cmu` passes over in ``<root>/<split>``: files of an action folder that
    are not ``<action>_<n>.txt``, and folders that are not among ``actions``."""
    split_dir = Path(root) / split
    if not split_dir.is_dir():
        return []
    skipped = []
    for action in actions:
        folder = split_dir / action
        if not folder.is_dir():
            continue
        files = set(folder.glob(f"{action}_*.txt"))
        others = sorted(p.name for p in folder.iterdir() if p not in files)
        if others:
            skipped.append(
                f"{folder.relative_to(root)}: skipped {', '.join(others)} (not {action}_<n>.txt)"
            )
    unknown = sorted(p.name for p in split_dir.iterdir() if p.name not in actions)
    if unknown:
        skipped.append(
            f"{split_dir.relative_to(root)}: skipped {', '.join(unknown)} (not among "
            f"the benchmark's actions {', '.join(actions)})"
        )
    return skipped


def load_cmu(
    root: str | Path | None, split: str = "test", actions: tuple[str, ...] = CMU_ACTIONS
) -> MotionDataset:
    """CMU Mocap in the convSeq2Seq/LTD layout ``<root>/<split>/<action>/<action>_<n>.txt``.

    Globs the files that exist (some of the standard set are missing); an action folder that is
    absent means the action is absent, but a folder that exists and holds no file is an error.
    """
    root = _check_root(
        root,
        "CMU Mocap (exp-map layout)",
        "pass --data-root pointing at the folder holding train/ and test/ "
        "(this project's copy is ../shared/data/cmu_mocap)",
    )
    if split not in ("train", "test"):
        raise ValueError(f"CMU split must be 'train' or 'test', got {split!r}")
    split_dir = root / split
    if not split_dir.is_dir():
        raise DataNotFoundError(
            f"{split_dir}: CMU split folder missing (expected "
            f"<data-root>/{split}/<action>/<action>_<n>.txt)"
        )
    check_cmu_root(root, split, tuple(actions))
    sequences, notes = [], []
    for action in actions:
        folder = split_dir / action
        if not folder.is_dir():
            notes.append(f"action {action}: no folder {folder.relative_to(root)} (MISSING.txt)")
            continue
        files = sorted(folder.glob(f"{action}_*.txt"), key=_file_number)
        if not files:
            raise DataFormatError(f"{folder}: action folder holds no {action}_<n>.txt file")
        # The field treats these files as 50 Hz, so 25 Hz after halving.
        sequences += [_load_sequence(f, root, action, CMU, 50.0, 2) for f in files]
    if not sequences:
        raise DataFormatError(f"{split_dir}: none of the actions {', '.join(actions)} has a file")
    # Files passed over are listed by `zoo data list` and `zoo data describe` (absent actions
    # are a protocol fact, recorded in actions_present), not printed by every load.
    return MotionDataset(
        name="cmu_mocap",
        split=split,
        root=root,
        skeleton=CMU,
        sequences=sequences,
        actions_requested=tuple(actions),
        ltd_rule="per_file",
        source_fps=50.0,
        notes=notes + cmu_skipped(root, split, actions),
    )


def load_h36m(
    root: str | Path | None, split: str = "test", actions: tuple[str, ...] = H36M_ACTIONS
) -> MotionDataset:
    """Human3.6M exp-map files ``<root>/S<k>/<action>_<1|2>.txt`` (50 Hz, halved to 25 Hz).

    Splits follow the literature: train S1 S6 S7 S8 S9, val S11, test S5.
    """
    root = _check_root(
        root,
        "Human3.6M (exp-map layout)",
        "pass --data-root pointing at the folder holding S1 ... S11 "
        "(Human3.6M is licensed per user and not shipped)",
    )
    if split not in H36M_SPLITS:
        raise ValueError(f"Human3.6M split must be one of {sorted(H36M_SPLITS)}, got {split!r}")
    sequences, notes = [], []
    for subject in H36M_SPLITS[split]:
        subject_dir = root / f"S{subject}"
        if not subject_dir.is_dir():
            raise DataNotFoundError(
                f"{subject_dir}: subject folder of split {split!r} missing; "
                f"{found_entries(root, subject_dir.name)}"
            )
        for action in actions:
            for sub in (1, 2):
                path = subject_dir / f"{action}_{sub}.txt"
                if not path.is_file():
                    raise DataNotFoundError(
                        f"{path}: Human3.6M file of action {action!r} missing (each action has "
                        f"sub-actions 1 and 2); {found_entries(subject_dir, path.name)}"
                    )
                sequences.append(_load_sequence(path, root, action, H36M, 50.0, 2, sub))
    return MotionDataset(
        name="h36m",
        split=split,
        root=root,
        skeleton=H36M,
        sequences=sequences,
        actions_requested=tuple(actions),
        ltd_rule="per_action_pair",
        source_fps=50.0,
        notes=notes,
    )


def _file_number(path: Path) -> tuple[int, str]:
    stem = path.stem.rsplit("_", 1)[-1]
    return (int(stem), path.name) if stem.isdigit() else (1 << 30, path.name)
