"""Opening IT3DEgo recordings: layout lookup, numeric sorting, calibration, bad poses, missing depth."""

import json
import shutil

import numpy as np
import pytest

from egograph.core.errors import InputError
from egograph.io.calibration import find_calibration_dir, read_ahat_calibration
from egograph.io.recording import Recording, find_sequence_dir


def _mini_sequence(src_root, dst, keys=(100, 99, 1000)):
    """A hand-made sequence: three poses keyed out of lexical order, calibration two levels up."""
    seq = dst / "group_1_17" / "raw_seq_03"
    (seq / "depth_ahat").mkdir(parents=True)
    shutil.copytree(src_root / "calibrations", dst / "calibrations")
    pose = np.eye(4)
    poses = {}
    for n, k in enumerate(keys):
        p = pose.copy()
        p[3, :3] = [n, 0, 0]
        poses[str(k)] = p.tolist()
    (seq / "pv_pose.json").write_text(json.dumps(poses))
    (seq / "depth_ahat_pose.json").write_text(json.dumps(poses))
    return seq


def test_open_synthetic_root(tiny_rec):
    rec = Recording.open(tiny_rec)
    assert rec.name == "tiny_seq" and len(rec) == 240
    assert np.all(np.diff(rec.timestamps) > 0)
    assert rec.pv_valid.all() and rec.depth_valid.all()
    assert rec.ahat.uv2xy.shape == (512, 512, 2) and rec.ahat.alias_mm == pytest.approx(1055)
    assert rec.depth_factor == 4.0  # detected from the raw values (4 mm units)
    d = rec.depth_raw(10)
    assert d.shape == (512, 512) and d.dtype == np.uint16 and d.max() <= 264
    assert rec.rgb(0) is None  # the fixture is rendered without RGB
    assert rec.annotation_dir == tiny_rec / "annotations" / "tiny_seq"
    assert rec.mesh() is not None and len(rec.mesh().triangles) > 100
    assert rec.detections_dir("svoe").is_dir()
    # Opening the sequence folder itself gives the same recording.
    rec2 = Recording.open(tiny_rec / "tiny_seq")
    assert np.array_equal(rec2.timestamps, rec.timestamps)


def test_numeric_sort_and_calibration_found_above(tiny_rec, tmp_path):
    seq = _mini_sequence(tiny_rec, tmp_path)
    rec = Recording.open(seq)
    assert rec.timestamps.tolist() == [99, 100, 1000]
    assert rec.pv_poses[0, 3, 0] == 1.0  # key "99" was written second
    assert rec.calibration_dir == (tmp_path / "calibrations").resolve()
    assert find_calibration_dir(seq, tmp_path) == tmp_path / "calibrations"


def test_missing_depth_is_no_depth(tiny_rec, tmp_path):
    seq = _mini_sequence(tiny_rec, tmp_path)
    rec = Recording.open(seq, depth_factor=4.0)
    assert rec.depth_raw(0) is None
    (seq / "depth_ahat" / "100.png").write_bytes(b"not a png")
    with pytest.warns(UserWarning, match="100.png"):
        assert rec.depth_raw(1) is None


def test_nan_pose_reported_or_skipped(tiny_rec, tmp_path):
    seq = _mini_sequence(tiny_rec, tmp_path)
    poses = json.loads((seq / "pv_pose.json").read_text())
    poses["100"][0][0] = float("nan")
    poses["1000"] = np.zeros((4, 4)).tolist()  # hl2ss writes M[3,3] == 0 without tracking
    (seq / "pv_pose.json").write_text(json.dumps(poses).replace("NaN", "NaN"))
    with pytest.raises(InputError, match=r"pv_pose\.json.*2 invalid pose.*100, 1000"):
        Recording.open(seq)
    with pytest.warns(UserWarning, match="invalid"):
        rec = Recording.open(seq, invalid_poses="skip", depth_factor=4.0)
    assert rec.pv_valid.tolist() == [True, False, False]
    assert np.isnan(rec.pv_poses[1]).all()


def test_bad_files_name_the_file(tiny_rec, tmp_path):
    seq = _mini_sequence(tiny_rec, tmp_path)
    (seq / "pv_pose.json").write_text('{"1": [[1, 0, 0, 0], [0, 1, 0, 0]]}')
    with pytest.raises(InputError, match=r"pv_pose\.json: pose 1: expected 4x4"):
        Recording.open(seq)
    (seq / "pv_pose.json").write_text('{"1": [[1, 0, 0, 0],\n oops')
    with pytest.raises(InputError, match=r"pv_pose\.json:2: not valid JSON"):
        Recording.open(seq)
    alias = tmp_path / "calibrations" / "rm_depth_ahat" / "alias.bin"
    alias.write_bytes(b"\x00\x00")
    with pytest.raises(InputError, match=r"alias\.bin: expected 1 float32 values, found 0"):
        read_ahat_calibration(alias.parent)
    with pytest.raises(InputError, match="recording not found"):
        find_sequence_dir(tmp_path / "nope")
