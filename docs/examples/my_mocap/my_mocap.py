"""A researcher's own motion capture as a zoo benchmark: BVH files and a text manifest.

The loader and skeleton the benchmark file names (``loader: my_mocap.py:load``,
``skeleton: my_mocap.py:SKELETON``). The loader is called as ``load(data_root, split,
actions=...)`` and returns a ``MotionDataset``: root-relative joint positions in millimetres,
one sequence per recording, on that skeleton (docs/adding-a-benchmark.md). Here: CMU's BVH
conversion, its ``MANIFEST.tsv`` describing each recording, 120 Hz taken down to 30 Hz, every
fifth trial of a subject held out for testing.
"""

import csv
import hashlib
from pathlib import Path

import numpy as np

from zoo.core.errors import DataNotFoundError
from zoo.data.bvh import CMU_BVH_JOINTS, forward_kinematics, read_bvh
from zoo.data.expmap import DataFormatError
from zoo.data.motion import MotionDataset, MotionSequence
from zoo.data.skeleton import Skeleton

ACTIONS = ("basketball", "dance", "playground", "run", "walk")
MM_PER_UNIT = 25.4 / 0.45  # CMU's length unit: 1/0.45 inch
SUBSAMPLE = 4  # 120 Hz -> 30 Hz
TEST_EVERY = 5  # trials NN_05, NN_10, ... are the test split
# The capture rig's 31 joints (CMU_BVH_JOINTS, in file order) and each one's parent; every file
# must have this hierarchy. The bone lengths come with each file (its OFFSETs), so the offsets
# here, which only exp-map forward kinematics reads, are zero.
SKELETON = Skeleton(
    name="cmu_bvh31",
    parents=(-1, 0, 1, 2, 3, 4, 0, 6, 7, 8, 9, 0, 11, 12, 13, 14, 15, 13, 17, 18, 19, 20, 21, 20)
    + (13, 24, 25, 26, 27, 28, 27),
    offsets=np.zeros((31, 3)),
    ignored=(0,),  # the root stays at the origin: nothing to predict
    copy_to=(),
    copy_from=(),
    official="used",
)


def action_of(description: str) -> str | None:
    """The action a recording shows: the first of ACTIONS its description's head names."""
    head = description.split(" - ")[0].lower()
    return next((a for a in ACTIONS if a in head), None)


def load(root, split, actions=ACTIONS):
    if root is None or not (Path(root) / "MANIFEST.tsv").is_file():
        raise DataNotFoundError(f"{root}: no MANIFEST.tsv here (give --data-root, the BVH folder)")
    if split not in ("train", "test"):
        raise ValueError(f"split must be train or test, got {split!r}")
    root = Path(root)
    with open(root / "MANIFEST.tsv", newline="") as f:
        rows = list(csv.DictReader(f, delimiter="\t"))
    sequences = []
    for row in rows:
        action, trial = action_of(row["description"]), int(Path(row["path"]).stem.split("_")[1])
        if action not in actions or (trial % TEST_EVERY == 0) != (split == "test"):
            continue
        path = root / row["path"]
        bvh = read_bvh(path, expected_joints=CMU_BVH_JOINTS)
        if bvh.parents != SKELETON.parents:
            raise DataFormatError(f"{path}: joints in another order than {SKELETON.name}'s")
        frames = slice(None, None, SUBSAMPLE)
        _, positions = forward_kinematics(bvh, bvh.local_rotations(frames))  # root at the origin
        sequences.append(
            MotionSequence(
                name=row["path"],
                action=action,
                positions=(positions * MM_PER_UNIT).astype(np.float32),
                fps=round(bvh.fps) / SUBSAMPLE,
                sha256=hashlib.sha256(path.read_bytes()).hexdigest(),
            )
        )
    if not sequences:
        raise DataNotFoundError(f"{root}: no recording of {', '.join(actions)} in split {split}")
    return MotionDataset(
        name="my_mocap",
        split=split,
        root=root,
        skeleton=SKELETON,
        sequences=sequences,
        actions_requested=tuple(actions),
        ltd_rule="per_file",
        source_fps=round(bvh.fps),
        subsample=SUBSAMPLE,
    )
