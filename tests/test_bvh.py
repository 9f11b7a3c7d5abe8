import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from zoo.data.bvh import (
    BVH,
    CMU_BVH_JOINTS,
    bone_directions,
    euler_to_matrix,
    forward_kinematics,
    parse_bvh,
    read_bvh,
)
from zoo.data.expmap import DataFormatError
from zoo.paths import REPO_ROOT

CMU_BVH = REPO_ROOT.parent / "shared" / "data" / "cmu_bvh"

# A root with two children: an arm of two bones ending in an End Site, and a zero-offset joint.
TINY = """HIERARCHY
ROOT Hips
{
  OFFSET 1 2 3
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Arm
  {
    OFFSET 2 0 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    JOINT Hand
    {
      OFFSET 3 0 0
      CHANNELS 3 Zrotation Yrotation Xrotation
      End Site
      {
        OFFSET 1 0 0
      }
    }
  }
  JOINT Pivot
  {
    OFFSET 0 0 0
    CHANNELS 3 Xrotation Yrotation Zrotation
    End Site
    {
      OFFSET 0 0 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0083333
10 20 30 0 0 0 0 0 0 0 0 0 0 0 0
0 0 0 90 0 0 0 0 0 90 0 0 0 0 0
"""


def write(tmp_path, text, name="tiny.bvh"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_hierarchy_and_motion_of_a_small_file(tmp_path):
    bvh = read_bvh(write(tmp_path, TINY))
    assert bvh.names == ("Hips", "Arm", "Hand", "Pivot")
    assert bvh.parents == (-1, 0, 1, 0)
    np.testing.assert_array_equal(bvh.offsets, [[1, 2, 3], [2, 0, 0], [3, 0, 0], [0, 0, 0]])
    assert bvh.channels[0] == (
        "Xposition",
        "Yposition",
        "Zposition",
        "Zrotation",
        "Yrotation",
        "Xrotation",
    )
    assert bvh.channels[3] == ("Xrotation", "Yrotation", "Zrotation")
    assert sorted(bvh.end_sites) == [2, 3]
    np.testing.assert_array_equal(bvh.end_sites[2], [1, 0, 0])
    assert bvh.num_frames == 2 and bvh.frame_time == pytest.approx(0.0083333)
    assert bvh.motion.shape == (2, 15) and bvh.channel_offsets == (0, 6, 9, 12)
    np.testing.assert_array_equal(bvh.root_positions(), [[10, 20, 30], [0, 0, 0]])
    # Hips' tail is the mean of its children's offsets; Pivot's End Site is at the joint.
    np.testing.assert_allclose(bvh.tail_offsets[0], [1, 0, 0])
    assert bvh.has_direction.tolist() == [True, True, True, False]


def test_crlf_line_endings_read_the_same(tmp_path):
    a = read_bvh(write(tmp_path, TINY))
    b = read_bvh(write(tmp_path, TINY.replace("\n", "\r\n"), "crlf.bvh"))
    assert a.names == b.names
    np.testing.assert_array_equal(a.motion, b.motion)


@pytest.mark.parametrize("axes", ["ZYX", "XYZ", "YXZ"])
def test_euler_angles_are_intrinsic_in_channel_order(axes):
    angles = np.random.default_rng(0).uniform(-180, 180, size=(20, 3))
    expected = Rotation.from_euler(axes, angles, degrees=True).as_matrix()  # upper case: intrinsic
    np.testing.assert_allclose(euler_to_matrix(angles, axes), expected, atol=1e-12)
    # ZYX intrinsic is the product Rz Ry Rx.
    z, y, x = (euler_to_matrix(angles[:, [k]], a) for k, a in enumerate(axes))
    np.testing.assert_allclose(euler_to_matrix(angles, axes), z @ y @ x, atol=1e-12)


def test_forward_kinematics_by_hand(tmp_path):
    bvh = read_bvh(write(tmp_path, TINY))
    world, pos = forward_kinematics(bvh, bvh.local_rotations(), bvh.root_positions())
    # Frame 0: no rotation; positions are the root channels plus accumulated offsets.
    np.testing.assert_allclose(pos[0], [[11, 22, 33], [13, 22, 33], [16, 22, 33], [11, 22, 33]])
    # Frame 1: root at its offset, turned 90 degrees about Z: the arm lies along +y; the hand
    # turns 90 degrees more about Z, so its bone points along -x.
    np.testing.assert_allclose(pos[1], [[1, 2, 3], [1, 4, 3], [1, 7, 3], [1, 2, 3]], atol=1e-12)
    dirs = bone_directions(bvh, world)
    np.testing.assert_allclose(dirs[1, :3], [[0, 1, 0], [0, 1, 0], [-1, 0, 0]], atol=1e-12)
    assert np.isnan(dirs[:, 3]).all()


def test_expected_joint_set(tmp_path):
    path = write(tmp_path, TINY)
    read_bvh(path, expected_joints=["Hips", "Arm", "Hand", "Pivot"])
    with pytest.raises(
        DataFormatError,
        match=r"tiny.bvh: unexpected joint 'Pivot'; expected "
        r"the joint set \{Hips, Arm, Hand\}",
    ):
        read_bvh(path, expected_joints=["Hips", "Arm", "Hand"])
    with pytest.raises(DataFormatError, match=r"joint\(s\) 'Head' missing"):
        read_bvh(path, expected_joints=["Hips", "Arm", "Hand", "Pivot", "Head"])


@pytest.mark.parametrize(
    "old, new, message",
    [
        ("HIERARCHY", "HIERARCH", r"line 1: expected 'HIERARCHY'"),
        (
            "    OFFSET 2 0 0",
            "    OFFSET 2 0",
            r"line 8: OFFSET of joint 'Arm': expected 3 numbers, "
            r"found 2",
        ),
        ("    OFFSET 2 0 0", "    OFFSET 2 x 0", r"line 8: OFFSET of joint 'Arm': '2 x 0' are not"),
        (
            "CHANNELS 3 Xrotation Yrotation Zrotation",
            "CHANNELS 3 Xrotation Yrotation Wrotation",
            r"line 23: CHANNELS of joint 'Pivot': unknown channel 'Wrotation'",
        ),
        (
            "CHANNELS 3 Xrotation Yrotation Zrotation",
            "CHANNELS 4 Xrotation Yrotation Zrotation",
            r"line 23: CHANNELS of joint 'Pivot': the count says 4, 3 channel names follow",
        ),
        (
            "  JOINT Pivot\n  {",
            "  JOINT Pivot\n  (",
            r"line 21: expected '\{' of Pivot, found '\('",
        ),
        ("JOINT Pivot", "JOINT Arm", r"line 20: joint 'Arm' is defined twice"),
        ("      End Site", "      End Sight", r"line 14: unexpected 'End Sight' in joint 'Hand'"),
        ("MOTION", "MOTON", r"line 30: expected 'MOTION'"),
        ("Frames: 2", "Frames: two", r"line 31: frame count 'two' is not an integer"),
        ("Frame Time: 0.0083333", "Frame Time: 0", r"line 32: frame time must be positive"),
        ("Frames: 2", "Frames: 3", r"header says 3 frames, found 2 frame lines"),
        (
            "0 0 0 90 0 0 0 0 0 90 0 0 0 0 0",
            "0 0 0 90 0 0 0 0 0 90 0 0 0 0",
            r"line 34: expected 15 channel values \(the hierarchy's channels\), found 14",
        ),
        (
            "0 0 0 90 0 0 0 0 0 90 0 0 0 0 0",
            "0 0 0 90 0 0 0 0 0 90 0 abc 0 0 0",
            r"line 34, value 12: 'abc' is not a number",
        ),
        (
            "0 0 0 90 0 0 0 0 0 90 0 0 0 0 0",
            "0 0 0 90 0 0 0 0 0 90 0 nan 0 0 0",
            r"line 34, value 12: nan is not finite",
        ),
    ],
)
def test_malformed_files_name_file_and_line(tmp_path, old, new, message):
    assert old in TINY
    path = write(tmp_path, TINY.replace(old, new, 1), "bad.bvh")
    with pytest.raises(DataFormatError, match=r"bad\.bvh.*" + message):
        read_bvh(path)


def test_truncated_file_and_missing_file(tmp_path):
    cut = TINY[: TINY.index("  JOINT Pivot")]
    with pytest.raises(
        DataFormatError,
        match=r"cut\.bvh: file ends where the '\}' closing "
        r"joint 'Hips' was expected",
    ):
        read_bvh(write(tmp_path, cut, "cut.bvh"))
    with pytest.raises(DataFormatError, match=r"nothing\.bvh: cannot read BVH file"):
        read_bvh(tmp_path / "nothing.bvh")


def test_parse_bvh_needs_no_file():
    bvh = parse_bvh(TINY, "inline.bvh")
    assert isinstance(bvh, BVH) and bvh.num_joints == 4


needs_cmu = pytest.mark.skipif(not CMU_BVH.is_dir(), reason=f"CMU BVH data not found at {CMU_BVH}")


@needs_cmu
def test_a_real_cmu_trial():
    bvh = read_bvh(CMU_BVH / "data" / "009" / "09_03.bvh", expected_joints=CMU_BVH_JOINTS)
    assert bvh.names == CMU_BVH_JOINTS and bvh.num_frames == 129  # MANIFEST.tsv: 129 frames
    assert bvh.channels[0][:3] == ("Xposition", "Yposition", "Zposition")
    assert all(c[-3:] == ("Zrotation", "Yrotation", "Xrotation") for c in bvh.channels)
    assert bvh.fps == pytest.approx(120, rel=1e-4)
    world, pos = forward_kinematics(bvh, bvh.local_rotations(), bvh.root_positions())
    # Bone lengths are preserved by the motion, and the head is above the feet (Y up).
    for j, p in enumerate(bvh.parents):
        if p >= 0:
            np.testing.assert_allclose(
                np.linalg.norm(pos[:, j] - pos[:, p], axis=-1),
                np.linalg.norm(bvh.offsets[j]),
                atol=1e-9,
            )
    head, foot = bvh.index("Head"), bvh.index("LeftFoot")
    assert (pos[:, head, 1] > pos[:, foot, 1] + 10).all()
