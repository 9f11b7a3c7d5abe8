"""The Human3.6M adapter on files the test writes in the exact exp-map layout (99 per line)."""

import numpy as np
import pytest

import zoo
from zoo import create_model
from zoo.core.errors import DataNotFoundError
from zoo.data.expmap import DataFormatError
from zoo.data.motion import load_h36m
from zoo.data.windows import window_sampler
from zoo.protocol.benchmark import get_benchmark

ACTIONS = ("walking", "eating")


def write_h36m(root, subject=5, frames=(400, 500), bone_angle=0.02):
    for action in ACTIONS:
        for sub, n in zip((1, 2), frames):
            data = np.zeros((n, 99))
            # joint 3 (right knee, parent 2) turns about x: only the joints below it move
            data[:, 3 + 3 * 3] = bone_angle * np.arange(n)
            path = root / f"S{subject}" / f"{action}_{sub}.txt"
            path.parent.mkdir(parents=True, exist_ok=True)
            np.savetxt(path, data, delimiter=",", fmt="%.8f")
    return root


def test_loads_halves_and_keeps_subactions(tmp_path):
    ds = load_h36m(write_h36m(tmp_path), "test", actions=ACTIONS)
    assert [(s.name, len(s), s.subaction) for s in ds.sequences] == [
        ("S5/walking_1.txt", 200, 1),
        ("S5/walking_2.txt", 250, 2),
        ("S5/eating_1.txt", 200, 1),
        ("S5/eating_2.txt", 250, 2),
    ]
    assert ds.sequences[0].positions.shape == (200, 32, 3) and ds.fps == 25


def test_ltd8_rule_draws_per_action_over_both_subactions(tmp_path):
    lengths, groups, subs = [200, 250, 200, 250], ["w", "w", "e", "e"], [1, 2, 1, 2]
    index = window_sampler("ltd8", lengths, 10, 25, "per_action_pair", groups, subs)
    rng = np.random.RandomState(1234567890)
    expected = []
    for _ in range(4):
        expected.append((0, rng.randint(16, 200 - 150) + 40))
        expected.append((1, rng.randint(16, 250 - 150) + 40))
    expected = sorted(expected, key=lambda r: r[0])  # sub-action 1's windows, then 2's
    assert index[:8].tolist() == [list(r) for r in expected]
    assert index[8:, 0].tolist() == [2] * 4 + [3] * 4  # a fresh generator per action
    assert index[8:, 1].tolist() == index[:8, 1].tolist()
    assert len(window_sampler("rand256", lengths, 10, 25, "per_action_pair", groups, subs)) == 512


def test_repeat_last_runs_on_h36m_with_32_joint_scoring(tmp_path):
    root = write_h36m(tmp_path)
    bench = get_benchmark("h36m")
    dataset = load_h36m(root, "test", actions=ACTIONS)
    result = zoo.evaluate(
        create_model("repeat_last", benchmark=bench), bench, label="rl", dataset=dataset
    )
    assert set(result.frame.joints) == {"all32", "used22"}
    assert result.protocol["windows_per_action"] == {"walking": 8, "eating": 8}
    df = result.frame[(result.frame.action == "average") & (result.frame.averaging == "frame")]
    # Only the right leg below the knee moves (joints 4, 5 and their copies): errors grow.
    assert np.all(np.diff(df[df.joints == "all32"].sort_values("frame")["value"]) > 0)


def test_missing_subject_or_file_is_named(tmp_path):
    with pytest.raises(DataNotFoundError, match="S5: subject folder of split 'test' missing"):
        load_h36m(tmp_path, "test")
    write_h36m(tmp_path)
    (tmp_path / "S5" / "eating_2.txt").unlink()
    with pytest.raises(
        DataNotFoundError,
        match="eating_2.txt: Human3.6M file of action 'eating' missing.*found in .*eating_1.txt",
    ):
        load_h36m(tmp_path, "test", actions=ACTIONS)
    bad = tmp_path / "S5" / "walking_1.txt"
    bad.write_text("1,2,3\n")
    with pytest.raises(DataFormatError, match="walking_1.txt, line 1: expected 99"):
        load_h36m(tmp_path, "test", actions=("walking",))
