"""The CMU BVH folder's trials: reading its ``MANIFEST.tsv`` (or its ``data/*/*.bvh``), the
train/test split rule, and choosing the trials of a split.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from zoo.core.errors import DataNotFoundError
from zoo.data.expmap import DataFormatError
from zoo.data.motion import found_entries

TEST_EVERY = 5  # split rule: trial numbers divisible by 5 are test, the others train
SPLITS = ("train", "test")


@dataclass(frozen=True)
class Trial:
    """One CMU BVH trial: ``key`` like ``"02_01"`` (subject 02, trial 1)."""

    key: str
    path: Path
    relpath: str
    subject: str
    number: int
    description: str

    @property
    def split(self) -> str:
        return "test" if self.number % TEST_EVERY == 0 else "train"


SPLIT_RULE = (
    f"by trial: trial numbers divisible by {TEST_EVERY} (NN_05, NN_10, ...) are test, "
    f"all others train; subjects with fewer than {TEST_EVERY} trials are train only"
)


def _trial_from_path(path: Path, relpath: str, description: str, where: str) -> Trial:
    stem = path.stem
    parts = stem.split("_")
    if len(parts) != 2 or not all(p.isdigit() for p in parts):
        raise DataFormatError(
            f"{where}: BVH file name {path.name!r} is not SUBJECT_TRIAL.bvh (e.g. 02_01.bvh)"
        )
    return Trial(
        key=stem,
        path=path,
        relpath=relpath,
        subject=parts[0],
        number=int(parts[1]),
        description=description or f"subject {parts[0]}",
    )


def list_trials(bvh_root: str | Path) -> list[Trial]:
    """Trials under ``bvh_root`` from its ``MANIFEST.tsv`` (path, description columns) or, if
    there is none, every ``data/*/*.bvh``; descriptions fall back to the subject."""
    root = Path(bvh_root)
    if not root.is_dir():
        raise DataNotFoundError(
            f"{root}: CMU BVH folder not found (expected a folder like ../shared/data/cmu_bvh "
            f"with MANIFEST.tsv and data/NNN/NN_TT.bvh); {found_entries(root.parent, root.name)}"
        )
    manifest = root / "MANIFEST.tsv"
    trials: list[Trial] = []
    if manifest.is_file():
        lines = manifest.read_text().splitlines()
        if not lines:
            raise DataFormatError(f"{manifest}: empty manifest")
        header = lines[0].split("\t")
        for column in ("path", "description"):
            if column not in header:
                raise DataFormatError(
                    f"{manifest}, line 1: no {column!r} column in the header {header}"
                )
        ipath, idesc = header.index("path"), header.index("description")
        for lineno, line in enumerate(lines[1:], start=2):
            if not line.strip():
                continue
            fields = line.split("\t")
            if len(fields) != len(header):
                raise DataFormatError(
                    f"{manifest}, line {lineno}: {len(fields)} fields, the header has {len(header)}"
                )
            rel = fields[ipath]
            path = root / rel
            if not path.is_file():
                raise DataFormatError(f"{manifest}, line {lineno}: listed file {rel} is missing")
            trials.append(
                _trial_from_path(path, rel, fields[idesc].strip(), f"{manifest}, line {lineno}")
            )
    else:
        for path in sorted(root.glob("data/*/*.bvh")):
            trials.append(_trial_from_path(path, str(path.relative_to(root)), "", str(path)))
    if not trials:
        raise DataNotFoundError(
            f"{root}: no BVH trials (expected MANIFEST.tsv or data/NNN/NN_TT.bvh); "
            f"{found_entries(root, 'data')}"
        )
    keys = [t.key for t in trials]
    if len(set(keys)) != len(keys):
        dup = next(k for k in keys if keys.count(k) > 1)
        raise DataFormatError(f"{root}: trial {dup} is listed twice")
    return sorted(trials, key=lambda t: (t.subject, t.number))


def select_trials(
    bvh_root: str | Path, split: str, trials: Iterable[str] | None = None
) -> list[Trial]:
    """The trials of ``split``; ``trials`` (keys like ``"02_01"``) restricts them further."""
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    available = list_trials(bvh_root)
    if trials is None:
        return [t for t in available if t.split == split]
    by_key = {t.key: t for t in available}
    chosen = []
    for key in trials:
        key = Path(str(key)).stem
        if key not in by_key:
            raise ValueError(
                f"trials: {key!r} is not a trial under {bvh_root} (available: "
                f"{', '.join(sorted(by_key))})"
            )
        trial = by_key[key]
        if trial.split != split:
            raise ValueError(
                f"trials: {key!r} belongs to the {trial.split} split, not {split} "
                f"(split rule: {SPLIT_RULE})"
            )
        if trial not in chosen:
            chosen.append(trial)
    if not chosen:
        raise ValueError("trials: empty selection")
    return chosen
