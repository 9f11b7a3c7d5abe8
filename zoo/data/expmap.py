"""The one reader of exponential-map text files (CMU and Human3.6M layouts).

One frame per line, comma separated: root position (3) then 3 numbers per joint.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import NoReturn

import numpy as np
import torch

from zoo.core.errors import ZooError
from zoo.data.skeleton import Skeleton, forward_kinematics


class DataFormatError(ZooError, ValueError):
    """A data file does not have the expected format; the message names file, line and field."""


def read_expmap_file(path: str | Path, skeleton: Skeleton) -> np.ndarray:
    """Frames ``(F, 3 + 3J)`` as float64; any malformed line is an error naming file and line."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise DataFormatError(f"{path}: cannot read exp-map file ({e.strerror})") from e
    except UnicodeDecodeError as e:
        raise DataFormatError(
            f"{path}: not a text file (byte {e.start} is not UTF-8); an "
            f"exp-map file holds comma-separated numbers"
        ) from None
    frames = _parsed(text, skeleton.num_channels)
    if frames is None:  # reading line by line names the line numpy's reader stopped at
        frames = _frames_by_line(path, text, skeleton)
    bad_rows, bad_cols = np.nonzero(~np.isfinite(frames))
    if bad_rows.size:
        numbered = [n for n, line in enumerate(text.splitlines(), start=1) if line.strip()]
        raise DataFormatError(
            f"{path}, line {numbered[bad_rows[0]]}, column {bad_cols[0] + 1}: "
            f"value {frames[bad_rows[0], bad_cols[0]]} is not finite"
        )
    return frames


def _parsed(text: str, channels: int) -> np.ndarray | None:
    """The frames as numpy's C reader parses them (Python's ``float`` bits, docs/architecture.md
    measures the speed), or None where a line is not ``channels`` numbers (or is blank but for
    spaces, which the reader refuses and the file format allows)."""
    if not text.strip():
        return None
    try:
        frames = np.loadtxt(
            io.StringIO(text), delimiter=",", dtype=np.float64, ndmin=2, comments=None
        )
    except ValueError:
        return None
    return frames if frames.shape[1] == channels else None


def _frames_by_line(path: Path, text: str, skeleton: Skeleton) -> np.ndarray:
    lines = [(n, line) for n, line in enumerate(text.splitlines(), start=1) if line.strip()]
    if not lines:
        raise DataFormatError(f"{path}: file holds no frames")
    try:
        frames = np.array([line.split(",") for _, line in lines], dtype=np.float64)
        if frames.ndim == 2 and frames.shape[1] == skeleton.num_channels:
            return frames
    except ValueError:
        pass
    _raise_first_bad_line(path, lines, skeleton)


def expmap_angles(frames: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """Each joint's exp-map ``(F, J, 3)`` of exp-map frames ``(F, 3 + 3J)`` (the root position
    dropped)."""
    return frames[:, 3:].reshape(len(frames), skeleton.num_joints, 3)


def expmap_to_positions(angles: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """Joint positions ``(F, J, 3)`` in mm (float32) of exp-map angles ``(F, J, 3)``
    (:func:`expmap_angles`)."""
    return forward_kinematics(torch.from_numpy(angles), skeleton).numpy().astype(np.float32)


def _raise_first_bad_line(path: Path, lines: list[tuple[int, str]], skeleton: Skeleton) -> NoReturn:
    expected = skeleton.num_channels
    for lineno, line in lines:
        fields = line.split(",")
        if len(fields) != expected:
            raise DataFormatError(
                f"{path}, line {lineno}: expected {expected} comma-separated values "
                f"(root position + 3 x {skeleton.num_joints} joints of {skeleton.name}), "
                f"found {len(fields)}"
            )
        for column, value in enumerate(fields, start=1):
            try:
                float(value)
            except ValueError:
                raise DataFormatError(
                    f"{path}, line {lineno}, column {column}: {value.strip()!r} is not a number"
                ) from None
    raise DataFormatError(f"{path}: could not parse as exp-map frames")  # not reached in practice
