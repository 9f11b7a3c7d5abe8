"""3DPW: sequence files written here in the exact format (Python pickles of dicts with
``jointPositions``), read by the restricted unpickler; the benchmark scores them as LTD / SPGSN
do (root-centred, 23 joints, 10 observed, 30 predicted, windows cut as if 50 were observed)."""

import os
import pickle

import numpy as np
import pytest

import zoo
from zoo import create_model
from zoo.data.expmap import DataFormatError
from zoo.data.threedpw import load_3dpw, read_3dpw_file
from zoo.data.windows import window_sampler
from zoo.protocol.benchmark import get_benchmark


def track(frames, speed_m=0.0, offset_m=(1.0, 2.0, 3.0)):
    """One actor's jointPositions (frames, 72) in metres: every joint at its own place, the
    whole body translated by ``offset_m`` (the world position 3DPW stores), and joint 5 moving
    along x at ``speed_m`` per frame."""
    joints = np.tile(np.arange(24, dtype=np.float64)[:, None] * 0.05, (frames, 1, 3))
    joints += np.asarray(offset_m)
    joints[:, 5, 0] += speed_m * np.arange(frames)
    return joints.reshape(frames, 72)


def write_sequence(path, tracks):
    """A 3DPW sequence file: the keys the dataset ships, jointPositions one array per actor."""
    path.parent.mkdir(parents=True, exist_ok=True)
    frames = len(tracks[0])
    data = {
        "sequence": path.stem,
        "genders": ["m"] * len(tracks),
        "betas": [np.zeros(10) for _ in tracks],
        "poses": [np.zeros((frames, 72)) for _ in tracks],
        "trans": [np.zeros((frames, 3)) for _ in tracks],
        "jointPositions": list(tracks),
        "cam_poses": np.tile(np.eye(4), (frames, 1, 1)),
        "campose_valid": [np.ones(frames) for _ in tracks],
        "img_frame_ids": np.arange(frames),
    }
    with open(path, "wb") as f:
        pickle.dump(data, f, protocol=2)
    return path


@pytest.fixture
def root(tmp_path):
    test = tmp_path / "3dpw" / "sequenceFiles" / "test"
    write_sequence(test / "downtown_walking_00.pkl", [track(100, 0.002), track(100, 0.004)])
    write_sequence(test / "office_phoneCall_00.pkl", [track(90, 0.001)])
    return tmp_path / "3dpw"


def test_every_actor_is_a_root_centred_sequence_in_mm(root):
    ds = load_3dpw(root, "test")
    assert [s.name for s in ds.sequences] == [
        "sequenceFiles/test/downtown_walking_00.pkl#0",
        "sequenceFiles/test/downtown_walking_00.pkl#1",
        "sequenceFiles/test/office_phoneCall_00.pkl#0",
    ]
    seq = ds.sequences[1]
    assert seq.positions.shape == (100, 24, 3) and ds.fps == 30.0 and seq.action == "all"
    assert np.abs(seq.positions[:, 0]).max() == 0  # root-centred
    np.testing.assert_allclose(seq.positions[0, 3], [150.0, 150.0, 150.0])  # mm, not metres
    np.testing.assert_allclose(np.diff(seq.positions[:, 5, 0]), 4.0)


def test_windows_are_cut_as_if_50_frames_were_observed():
    index = window_sampler("all50", [100, 79, 80], 10, 30)
    # LTD: every 80-frame window (50 + 30); the observed 10 are the last 10 of the 50
    assert index[:, 1].tolist() == list(range(40, 61)) + [40]
    assert index[:, 0].tolist() == [0] * 21 + [2]


def test_repeat_last_by_hand(root):
    bench = get_benchmark("3dpw")
    result = zoo.evaluate(
        create_model("repeat_last", benchmark=bench),
        bench,
        label="repeat_last",
        data_root=root,
    )
    frame = result.frame
    assert result.protocol["windows_per_action"] == {"all": 21 + 21 + 11}
    assert list(result.protocol["joint_protocols"]) == ["used23", "all24"]  # LTD scores 23
    used = frame[
        (frame.joints == "used23") & (frame.averaging == "frame") & (frame.action == "all")
    ].sort_values("frame")
    # only joint 5 moves; its speeds 2, 4 and 1 mm per frame, windows 21, 21 and 11
    speed = (21 * 2.0 + 21 * 4.0 + 11 * 1.0) / 53
    np.testing.assert_allclose(used["value"].to_numpy(), speed * np.arange(1, 31) / 23)
    assert used[used.frame == 30]["horizon_ms"].item() == 1000
    assert used[used.frame == 3]["horizon_ms"].item() == 100


class Payload:
    def __reduce__(self):
        return (os.system, ("touch pwned-by-pickle",))


def test_a_pickle_that_would_run_code_is_refused(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "evil.pkl"
    with open(path, "wb") as f:
        pickle.dump({"jointPositions": [Payload()]}, f, protocol=2)
    with pytest.raises(
        DataFormatError,
        match=r"evil\.pkl: refusing to load it: the pickle asks "
        r"for (posix|os|nt)\.system",
    ):
        read_3dpw_file(path)
    assert not (tmp_path / "pwned-by-pickle").exists()


def test_damaged_files_are_named(tmp_path):
    good = write_sequence(tmp_path / "a.pkl", [track(50)])
    (tmp_path / "cut.pkl").write_bytes(good.read_bytes()[:200])
    with pytest.raises(DataFormatError, match=r"cut\.pkl: not a readable 3DPW pickle"):
        read_3dpw_file(tmp_path / "cut.pkl")
    write_sequence(tmp_path / "shape.pkl", [np.zeros((50, 69))])
    with pytest.raises(
        DataFormatError,
        match=r"shape\.pkl: jointPositions\[0\] must be a "
        r"\(frames, 72\) array",
    ):
        read_3dpw_file(tmp_path / "shape.pkl")
    with open(tmp_path / "other.pkl", "wb") as f:
        pickle.dump([1, 2, 3], f, protocol=2)
    with pytest.raises(DataFormatError, match="a dict with 'jointPositions'"):
        read_3dpw_file(tmp_path / "other.pkl")


def test_missing_data_is_named(tmp_path):
    from zoo.core.errors import DataNotFoundError, ZooError

    with pytest.raises(DataNotFoundError, match="licensed per user"):
        load_3dpw(None)
    (tmp_path / "sequenceFiles" / "test").mkdir(parents=True)
    with pytest.raises(DataNotFoundError, match="no .pkl sequence file"):
        load_3dpw(tmp_path, "test")
    with pytest.raises(DataNotFoundError, match="no 3DPW split folder"):
        load_3dpw(tmp_path, "train")
    with pytest.raises(ZooError, match="3DPW split must be one of train, validation, test"):
        load_3dpw(tmp_path, "val")
