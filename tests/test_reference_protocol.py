"""repeat_last on the real CMU test files against an independent oracle of the official test code.

The oracle below follows the LTD / SPGSN CMU test pipeline step by step, written independently
of the zoo (plain numpy, one frame at a time): read the file, keep even frames, FK on each (the
official code runs FK on every source frame, then keeps the even ones: the same positions), cut
the windows (LTD's seeded 8 per file, or SPGSN's every window), write the predicted
joints into a copy of the ground truth, copy the duplicated joints, average the L2 error over
joints, then over windows, then over actions.
"""

import functools
from pathlib import Path

import numpy as np
import pytest

import zoo
from zoo import create_model
from zoo.data.skeleton import CMU
from zoo.protocol.benchmark import get_benchmark

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "cmu_mocap"
needs_cmu = pytest.mark.skipif(not DATA.is_dir(), reason=f"CMU data not found at {DATA}")
ACTIONS = [
    "basketball",
    "basketball_signal",
    "directing_traffic",
    "jumping",
    "running",
    "soccer",
    "walking",
    "washwindow",
]


def oracle_rotmat(r):
    theta = np.linalg.norm(r)
    r0 = r / (theta + np.finfo(np.float32).eps)
    k = np.array([[0, -r0[2], r0[1]], [r0[2], 0, -r0[0]], [-r0[1], r0[0], 0]])
    return np.eye(3) + np.sin(theta) * k + (1 - np.cos(theta)) * k @ k


def oracle_fk(frame):
    parents = CMU.parents
    n = len(parents)
    rot = [oracle_rotmat(frame[3 + 3 * i : 6 + 3 * i]) for i in range(n)]
    xyz = [CMU.offsets[i].copy() for i in range(n)]
    for i in range(1, n):
        if parents[i] > 0:
            rot[i] = rot[i] @ rot[parents[i]]
            xyz[i] = CMU.offsets[i] @ rot[parents[i]] + xyz[parents[i]]
    return np.stack(xyz)


@functools.cache
def oracle_positions(path):
    raw = np.loadtxt(path, delimiter=",")
    return np.stack([oracle_fk(f) for f in raw[range(0, len(raw), 2)]])


def oracle_windows(seq, sampler, t_in, t_out):
    n = len(seq)
    if sampler == "ltd8":
        rng = np.random.RandomState(1234567890)
        starts = []
        for _ in range(8):
            idx = rng.randint(0, n - 75)
            starts.append(idx + 50 - t_in)
        return np.stack([seq[s : s + t_in + t_out] for s in starts])
    fs = np.arange(0, n - (t_in + t_out) + 1)
    return seq[fs[:, None] + np.arange(t_in + t_out)]


def oracle_repeat_last(sampler, t_in=10, t_out=25):
    ignore = [0, 1, 2, 7, 8, 13, 16, 20, 29, 24, 27, 33, 36]
    used = np.setdiff1d(np.arange(38), ignore)
    per_action = {}
    for action in ACTIONS:
        folder = DATA / "test" / action
        if not folder.is_dir():
            continue
        errors_all, errors_used = [], []
        for path in sorted(folder.glob("*.txt")):
            windows = oracle_windows(oracle_positions(path), sampler, t_in, t_out)
            target = windows[:, t_in:]
            pred = target.copy()
            pred[:, :, used] = windows[:, t_in - 1 : t_in, used]
            pred[:, :, [16, 20, 29, 24, 27, 33, 36]] = pred[:, :, [15, 15, 15, 23, 23, 32, 32]]
            errors_all.append(np.linalg.norm(pred - target, axis=-1).mean(axis=-1))
            errors_used.append(
                np.linalg.norm(pred[:, :, used] - target[:, :, used], axis=-1).mean(axis=-1)
            )
        per_action[action] = (
            np.concatenate(errors_all).mean(0),
            np.concatenate(errors_used).mean(0),
        )
    return per_action


@needs_cmu
@pytest.mark.parametrize("sampler", ["ltd8", "all"])
def test_repeat_last_reproduces_official_test_code(sampler):
    expected = oracle_repeat_last(sampler)
    bench = get_benchmark("cmu")
    result = zoo.evaluate(
        create_model("repeat_last", benchmark=bench),
        bench,
        label="repeat_last",
        sampler=sampler,
        data_root=DATA,
    )
    df = result.frame
    assert set(df["action"]) == set(expected) | {"average"}
    checked = 0
    for joints, which in (("all38", 0), ("used25", 1)):
        average = np.mean([v[which] for v in expected.values()], axis=0)
        for action, per_frame in [
            *((a, v[which]) for a, v in expected.items()),
            ("average", average),
        ]:
            for averaging, values in (
                ("frame", per_frame),
                ("cumulative", np.cumsum(per_frame) / np.arange(1, 26)),
            ):
                rows = df[
                    (df.action == action) & (df.joints == joints) & (df.averaging == averaging)
                ].sort_values("frame")
                np.testing.assert_allclose(
                    rows["value"].to_numpy(),
                    values,
                    atol=0.01,
                    rtol=0,
                    err_msg=f"{sampler} {action} {joints} {averaging}",
                )
                checked += len(rows)
    assert checked == 2 * 2 * 25 * (len(expected) + 1)
    windows = result.protocol["windows_per_action"]
    if sampler == "ltd8":
        assert windows == {a: 8 for a in expected}
    else:
        assert sum(windows.values()) > 3000  # every window of the six test files


@needs_cmu
def test_official_scoring_is_about_1_3_times_smaller_than_the_25_joint_mean():
    bench = get_benchmark("cmu")
    df = zoo.evaluate(
        create_model("repeat_last", benchmark=bench),
        bench,
        label="repeat_last",
        sampler="ltd8",
        data_root=DATA,
    ).frame
    avg = df[(df.action == "average") & (df.averaging == "frame")]
    ratio = (
        avg[avg.joints == "used25"]["value"].to_numpy()
        / avg[avg.joints == "all38"]["value"].to_numpy()
    )
    assert np.all((ratio > 1.2) & (ratio < 1.4))
