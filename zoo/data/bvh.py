"""The BVH reader and BVH forward kinematics.

``read_bvh`` parses a file's HIERARCHY and MOTION parts and raises ``DataFormatError`` naming the
file and line of anything malformed; ``forward_kinematics`` and ``bone_directions`` follow the
format's conventions. The format, its conventions and the bones with no direction:
docs/datasets.md ("BVH files").
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import torch

from zoo.data.expmap import DataFormatError
from zoo.data.skeleton import kinematic_chain

ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
_AXIS = {"X": 0, "Y": 1, "Z": 2}
# The 31 joints of the CMU BVH conversion (MotionBuilder-friendly "mb2"), in file order.
CMU_BVH_JOINTS = (
    "Hips",
    "LHipJoint",
    "LeftUpLeg",
    "LeftLeg",
    "LeftFoot",
    "LeftToeBase",
    "RHipJoint",
    "RightUpLeg",
    "RightLeg",
    "RightFoot",
    "RightToeBase",
    "LowerBack",
    "Spine",
    "Spine1",
    "Neck",
    "Neck1",
    "Head",
    "LeftShoulder",
    "LeftArm",
    "LeftForeArm",
    "LeftHand",
    "LeftFingerBase",
    "LeftHandIndex1",
    "LThumb",
    "RightShoulder",
    "RightArm",
    "RightForeArm",
    "RightHand",
    "RightFingerBase",
    "RightHandIndex1",
    "RThumb",
)
# The lower body (hips and both legs): the first 11 joints in file order; the rest is upper body
# (SPGSN's two parts on this skeleton).
CMU_BVH_LOWER_BODY = CMU_BVH_JOINTS[: CMU_BVH_JOINTS.index("LowerBack")]
# Tail offsets shorter than this (in the file's units) give a bone no direction.
MIN_BONE_LENGTH = 1e-9


@dataclass(frozen=True)
class BVH:
    """A parsed BVH file: the skeleton in file (depth-first) order and its motion."""

    path: Path
    names: tuple[str, ...]
    parents: tuple[int, ...]  # -1 for the root
    offsets: np.ndarray  # (J, 3), float64, file units
    channels: tuple[tuple[str, ...], ...]  # per joint, in file order
    end_sites: dict[int, np.ndarray]  # joint index -> End Site offset (3,)
    frame_time: float  # seconds
    motion: np.ndarray  # (F, total channels), float64, file order

    @property
    def num_joints(self) -> int:
        return len(self.names)

    @property
    def num_frames(self) -> int:
        return len(self.motion)

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(
                f"{self.path}: no joint {name!r} (joints: {', '.join(self.names)})"
            ) from None

    @cached_property
    def channel_offsets(self) -> tuple[int, ...]:
        """Column of each joint's first channel in ``motion``."""
        starts, n = [], 0
        for ch in self.channels:
            starts.append(n)
            n += len(ch)
        return tuple(starts)

    @cached_property
    def children(self) -> tuple[tuple[int, ...], ...]:
        kids: list[list[int]] = [[] for _ in self.names]
        for j, p in enumerate(self.parents):
            if p >= 0:
                kids[p].append(j)
        return tuple(tuple(k) for k in kids)

    @cached_property
    def tail_offsets(self) -> np.ndarray:
        """(J, 3): each bone's tail relative to its joint, in the joint's local frame."""
        tails = np.zeros((self.num_joints, 3))
        for j in range(self.num_joints):
            if j in self.end_sites:
                tails[j] = self.end_sites[j]
            elif self.children[j]:
                tails[j] = self.offsets[list(self.children[j])].mean(axis=0)
        return tails

    @property
    def has_direction(self) -> np.ndarray:
        """(J,) bool: whether each joint's bone has a direction (a non-zero tail offset)."""
        return np.linalg.norm(self.tail_offsets, axis=1) > MIN_BONE_LENGTH

    def local_rotations(self, frames: slice | np.ndarray | None = None) -> np.ndarray:
        """(F, J, 3, 3) local rotation matrices from the rotation channels (identity if none)."""
        motion = self.motion if frames is None else self.motion[frames]
        out = np.broadcast_to(np.eye(3), (len(motion), self.num_joints, 3, 3)).copy()
        for j, (start, chans) in enumerate(zip(self.channel_offsets, self.channels)):
            rot = [(c[0], start + k) for k, c in enumerate(chans) if c in ROTATION_CHANNELS]
            if rot:
                axes = "".join(a for a, _ in rot)
                out[:, j] = euler_to_matrix(motion[:, [col for _, col in rot]], axes)
        return out

    def root_positions(self, frames: slice | np.ndarray | None = None) -> np.ndarray:
        """(F, 3) the root's position channels (zero where a channel is absent), file units."""
        motion = self.motion if frames is None else self.motion[frames]
        out = np.zeros((len(motion), 3))
        start = self.channel_offsets[0]
        for k, c in enumerate(self.channels[0]):
            if c in POSITION_CHANNELS:
                out[:, _AXIS[c[0]]] = motion[:, start + k]
        return out


def euler_to_matrix(angles_deg: np.ndarray, axes: str) -> np.ndarray:
    """``(..., 3, 3)`` for intrinsic rotations about ``axes`` (e.g. ``"ZYX"``): ``R = R1 R2 R3``.

    ``angles_deg (..., len(axes))`` in degrees, applied in the order the axes are listed.
    """
    angles = np.deg2rad(np.asarray(angles_deg, dtype=np.float64))
    out = np.broadcast_to(np.eye(3), angles.shape[:-1] + (3, 3)).copy()
    for k, axis in enumerate(axes):
        out = out @ axis_rotation(angles[..., k], axis)
    return out


def axis_rotation(angle_rad: np.ndarray, axis: str) -> np.ndarray:
    """``(..., 3, 3)`` rotation by ``angle_rad`` about the coordinate axis ``X``, ``Y`` or ``Z``."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    i = _AXIS[axis.upper()]
    j, k = (i + 1) % 3, (i + 2) % 3
    r = np.zeros(np.shape(angle_rad) + (3, 3))
    r[..., i, i] = 1.0
    r[..., j, j] = c
    r[..., k, k] = c
    r[..., j, k] = -s
    r[..., k, j] = s
    return r


def forward_kinematics(
    bvh: BVH, local_rotations: np.ndarray, root_positions: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """World rotations ``(F, J, 3, 3)`` and joint positions ``(F, J, 3)`` (file units).

    ``local_rotations (F, J, 3, 3)`` (e.g. ``bvh.local_rotations()``, possibly edited, such as
    the root's set to identity); ``root_positions (F, 3)`` or None for a root at its offset.
    """
    local_rotations = np.asarray(local_rotations, dtype=np.float64)
    if local_rotations.ndim != 4 or local_rotations.shape[1:] != (bvh.num_joints, 3, 3):
        raise ValueError(
            f"{bvh.path}: local rotations must be (F, {bvh.num_joints}, 3, 3), got "
            f"{local_rotations.shape}"
        )
    # File order is depth-first: parents come first, as kinematic_chain needs.
    world, positions = kinematic_chain(
        list(bvh.parents),
        torch.from_numpy(local_rotations),
        torch.from_numpy(np.asarray(bvh.offsets, dtype=np.float64)),
        None if root_positions is None else torch.as_tensor(root_positions, dtype=torch.float64),
    )
    return world.numpy(), positions.numpy()


def bone_directions(bvh: BVH, world_rotations: np.ndarray) -> np.ndarray:
    """Unit bone directions ``(F, J, 3)`` in world axes; NaN rows for bones with no direction."""
    tails = bvh.tail_offsets
    vec = np.einsum("fjab,jb->fja", world_rotations, tails)
    out = np.full_like(vec, np.nan)
    ok = bvh.has_direction
    out[:, ok] = vec[:, ok] / np.linalg.norm(vec[:, ok], axis=-1, keepdims=True)
    return out


# ---- reading -------------------------------------------------------------------------------------


def read_bvh(path: str | Path, expected_joints: Iterable[str] | None = None) -> BVH:
    """Parse a BVH file; malformed input raises ``DataFormatError`` naming file and line.

    ``expected_joints``: if given, the file's joint names must be exactly this set.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise DataFormatError(f"{path}: cannot read BVH file ({e.strerror})") from e
    except UnicodeDecodeError as e:
        raise DataFormatError(f"{path}: not a text file ({e.reason})") from e
    return parse_bvh(text, path, expected_joints)


def parse_bvh(
    text: str, path: str | Path = "<bvh>", expected_joints: Iterable[str] | None = None
) -> BVH:
    """Parse BVH ``text``; ``path`` names the source in error messages."""
    path = Path(path)
    lines = text.splitlines()
    parser = _HierarchyParser(path, lines)
    names, parents, offsets, channels, end_sites, motion_line = parser.parse()
    if expected_joints is not None:
        _check_joint_set(path, names, expected_joints)
    frame_time, motion = _parse_motion(path, lines, motion_line, sum(len(c) for c in channels))
    return BVH(
        path=path,
        names=tuple(names),
        parents=tuple(parents),
        offsets=np.asarray(offsets, dtype=np.float64).reshape(-1, 3),
        channels=tuple(tuple(c) for c in channels),
        end_sites=end_sites,
        frame_time=frame_time,
        motion=motion,
    )


def _check_joint_set(path: Path, names: list[str], expected: Iterable[str]) -> None:
    expected = list(expected)
    expected_set = set(expected)
    listing = ", ".join(expected)
    for name in names:
        if name not in expected_set:
            raise DataFormatError(
                f"{path}: unexpected joint {name!r}; expected the joint set {{{listing}}}"
            )
    missing = [n for n in expected if n not in set(names)]
    if missing:
        raise DataFormatError(
            f"{path}: joint(s) {', '.join(map(repr, missing))} missing; "
            f"expected the joint set {{{listing}}}"
        )


class _HierarchyParser:
    """Line-based recursive parser of the HIERARCHY part."""

    def __init__(self, path: Path, lines: list[str]) -> None:
        self.path = path
        self.lines = lines
        self.i = 0  # index of the next line to read
        self.names: list[str] = []
        self.parents: list[int] = []
        self.offsets: list[list[float]] = []
        self.channels: list[list[str]] = []
        self.end_sites: dict[int, np.ndarray] = {}

    def error(self, message: str, lineno: int | None = None) -> DataFormatError:
        lineno = self.i if lineno is None else lineno
        return DataFormatError(f"{self.path}, line {lineno}: {message}")

    def next_tokens(self, what: str) -> tuple[int, list[str]]:
        """The next non-blank line's tokens and its 1-based number."""
        while self.i < len(self.lines):
            self.i += 1
            tokens = self.lines[self.i - 1].split()
            if tokens:
                return self.i, tokens
        raise DataFormatError(
            f"{self.path}: file ends where {what} was expected (after line {len(self.lines)})"
        )

    def parse(self):
        lineno, tokens = self.next_tokens("HIERARCHY")
        if tokens != ["HIERARCHY"]:
            raise self.error(f"expected 'HIERARCHY', found {' '.join(tokens)!r}", lineno)
        lineno, tokens = self.next_tokens("ROOT")
        if tokens[0] != "ROOT" or len(tokens) != 2:
            raise self.error(f"expected 'ROOT <name>', found {' '.join(tokens)!r}", lineno)
        self.joint(tokens[1], -1, lineno)
        lineno, tokens = self.next_tokens("MOTION")
        if tokens != ["MOTION"]:
            raise self.error(
                f"expected 'MOTION' after the hierarchy (one ROOT only), found "
                f"{' '.join(tokens)!r}",
                lineno,
            )
        return self.names, self.parents, self.offsets, self.channels, self.end_sites, lineno

    def joint(self, name: str, parent: int, lineno: int) -> None:
        if name in self.names:
            raise self.error(f"joint {name!r} is defined twice", lineno)
        index = len(self.names)
        self.names.append(name)
        self.parents.append(parent)
        self.offsets.append([])
        self.channels.append([])
        self.expect_brace("{", name)
        offset_seen = channels_seen = False
        while True:
            lineno, tokens = self.next_tokens(f"the '}}' closing joint {name!r}")
            key = tokens[0]
            if key == "}":
                if len(tokens) != 1:
                    raise self.error(f"unexpected text after '}}': {' '.join(tokens[1:])!r}")
                break
            if key == "OFFSET":
                if offset_seen:
                    raise self.error(f"joint {name!r} has a second OFFSET")
                self.offsets[index] = self.numbers(tokens, f"OFFSET of joint {name!r}")
                offset_seen = True
            elif key == "CHANNELS":
                if channels_seen:
                    raise self.error(f"joint {name!r} has a second CHANNELS line")
                self.channels[index] = self.channel_list(tokens, name)
                channels_seen = True
            elif key == "JOINT":
                if len(tokens) != 2:
                    raise self.error(f"expected 'JOINT <name>', found {' '.join(tokens)!r}")
                if not offset_seen:
                    raise self.error(f"joint {name!r} has no OFFSET before its first child")
                self.joint(tokens[1], index, lineno)
            elif key == "End" and tokens[1:] == ["Site"]:
                if index in self.end_sites:
                    raise self.error(f"joint {name!r} has a second End Site")
                self.end_sites[index] = self.end_site(name)
            else:
                raise self.error(
                    f"unexpected {' '.join(tokens)!r} in joint {name!r} (expected "
                    f"OFFSET, CHANNELS, JOINT, End Site or '}}')"
                )
        if not offset_seen:
            raise self.error(f"joint {name!r} has no OFFSET", lineno)
        if not channels_seen:
            raise self.error(f"joint {name!r} has no CHANNELS", lineno)

    def end_site(self, name: str) -> np.ndarray:
        self.expect_brace("{", f"End Site of {name!r}")
        lineno, tokens = self.next_tokens(f"the OFFSET of the End Site of {name!r}")
        if tokens[0] != "OFFSET":
            raise self.error(
                f"expected the OFFSET of the End Site of {name!r}, found {' '.join(tokens)!r}"
            )
        offset = self.numbers(tokens, f"OFFSET of the End Site of {name!r}")
        self.expect_brace("}", f"End Site of {name!r}")
        return np.asarray(offset, dtype=np.float64)

    def expect_brace(self, brace: str, what: str) -> None:
        lineno, tokens = self.next_tokens(f"'{brace}' of {what}")
        if tokens != [brace]:
            raise self.error(f"expected '{brace}' of {what}, found {' '.join(tokens)!r}")

    def numbers(self, tokens: list[str], what: str) -> list[float]:
        if len(tokens) != 4:
            raise self.error(f"{what}: expected 3 numbers, found {len(tokens) - 1}")
        try:
            values = [float(t) for t in tokens[1:]]
        except ValueError:
            raise self.error(f"{what}: {' '.join(tokens[1:])!r} are not 3 numbers") from None
        if not np.isfinite(values).all():
            raise self.error(f"{what}: values {tokens[1:]} are not finite")
        return values

    def channel_list(self, tokens: list[str], name: str) -> list[str]:
        try:
            count = int(tokens[1])
        except (IndexError, ValueError):
            raise self.error(
                f"CHANNELS of joint {name!r}: expected a channel count, found "
                f"{' '.join(tokens[1:])!r}"
            ) from None
        chans = tokens[2:]
        if len(chans) != count:
            raise self.error(
                f"CHANNELS of joint {name!r}: the count says {count}, "
                f"{len(chans)} channel names follow"
            )
        allowed = ROTATION_CHANNELS + POSITION_CHANNELS
        for c in chans:
            if c not in allowed:
                raise self.error(
                    f"CHANNELS of joint {name!r}: unknown channel {c!r} "
                    f"(allowed: {', '.join(allowed)})"
                )
        if len(set(chans)) != len(chans):
            raise self.error(f"CHANNELS of joint {name!r}: a channel is repeated in {chans}")
        return chans


def _parse_motion(
    path: Path, lines: list[str], motion_line: int, num_channels: int
) -> tuple[float, np.ndarray]:
    i = motion_line  # 0-based index of the line after MOTION

    def header(key: str) -> tuple[int, str]:
        nonlocal i
        while i < len(lines) and not lines[i].strip():
            i += 1
        if i >= len(lines):
            raise DataFormatError(f"{path}: file ends where '{key}' was expected")
        line = lines[i].strip()
        i += 1
        if not line.startswith(key):
            raise DataFormatError(f"{path}, line {i}: expected '{key} <value>', found {line!r}")
        return i, line[len(key) :].strip()

    lineno, value = header("Frames:")
    try:
        num_frames = int(value)
    except ValueError:
        raise DataFormatError(
            f"{path}, line {lineno}: frame count {value!r} is not an integer"
        ) from None
    if num_frames < 0:
        raise DataFormatError(f"{path}, line {lineno}: negative frame count {num_frames}")
    lineno, value = header("Frame Time:")
    try:
        frame_time = float(value)
    except ValueError:
        raise DataFormatError(
            f"{path}, line {lineno}: frame time {value!r} is not a number"
        ) from None
    if not np.isfinite(frame_time) or frame_time <= 0:
        raise DataFormatError(
            f"{path}, line {lineno}: frame time must be positive, got {frame_time}"
        )
    rows = [(n, line) for n, line in enumerate(lines[i:], start=i + 1) if line.strip()]
    if len(rows) != num_frames:
        where = f"line {rows[num_frames][0]}" if len(rows) > num_frames else "the end"
        raise DataFormatError(
            f"{path}: header says {num_frames} frames, found {len(rows)} frame "
            f"lines (mismatch at {where})"
        )
    if num_frames == 0:
        return frame_time, np.zeros((0, num_channels))
    try:  # fast path: one parse of all values
        flat = np.array(" ".join(line for _, line in rows).split(), dtype=np.float64)
        ok = flat.size == num_frames * num_channels
    except ValueError:
        ok = False
    if ok:
        motion = flat.reshape(num_frames, num_channels)
        ok = all(len(line.split()) == num_channels for _, line in rows)
    if not ok:
        for lineno, line in rows:
            fields = line.split()
            if len(fields) != num_channels:
                raise DataFormatError(
                    f"{path}, line {lineno}: expected {num_channels} channel "
                    f"values (the hierarchy's channels), found {len(fields)}"
                )
            for column, field_ in enumerate(fields, start=1):
                try:
                    float(field_)
                except ValueError:
                    raise DataFormatError(
                        f"{path}, line {lineno}, value {column}: {field_!r} is not a number"
                    ) from None
        raise DataFormatError(f"{path}: could not parse the motion")  # not reached
    bad_rows, bad_cols = np.nonzero(~np.isfinite(motion))
    if bad_rows.size:
        raise DataFormatError(
            f"{path}, line {rows[bad_rows[0]][0]}, value {bad_cols[0] + 1}: "
            f"{motion[bad_rows[0], bad_cols[0]]} is not finite"
        )
    return frame_time, motion
