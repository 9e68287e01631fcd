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
    # The default skips them (as the reference code does), warning with the count; 'error' and
    # strict refuse, naming the file and the first timestamps.
    for kwargs in ({"invalid_poses": "error"}, {"strict": True}):
        with pytest.raises(InputError, match=r"pv_pose\.json.*2 of 3 invalid pose.*1 all-zero.*100, 1000"):
            Recording.open(seq, **kwargs)
    with pytest.warns(UserWarning, match=r"2 of 3 invalid pose.*skipped"):
        rec = Recording.open(seq, depth_factor=4.0)
    assert rec.pv_valid.tolist() == [True, False, False]
    assert np.isnan(rec.pv_poses[1]).all()
    assert next(lk for lk in rec.lookups if lk.what == "PV poses").note == "2 of 3 invalid (skipped)"


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


def test_nearest_within_joins_by_time_not_key():
    from egograph.io.recording import nearest_within

    pv = np.array([0, 333_333, 666_667, 1_000_000])            # 30 Hz, ticks
    ahat = np.array([50_000, 272_222, 494_444, 716_667, 1_400_000])  # 45 Hz-ish, 5 ms after PV
    assert nearest_within(pv, ahat, 150_000).tolist() == [0, 1, 3, -1]
    assert nearest_within(pv, pv, 0).tolist() == [0, 1, 2, 3]  # equal keys always match
    assert nearest_within(pv, np.array([], np.int64), 10).tolist() == [-1, -1, -1, -1]
    assert nearest_within(np.array([10]), np.array([0, 20]), 10).tolist() == [0]  # a tie: the earlier


def test_frame_files_read_both_namings(tmp_path):
    from egograph.io.recording import FrameFiles

    for name in ("frame_133400700001666667.png", "133400700002000000.png", "133400700002000000.PNG.txt",
                 "notes.txt", "frame_133400700002000000.png"):
        (tmp_path / name).write_bytes(b"")
    ff = FrameFiles.scan(tmp_path)
    assert ff.files == {133400700001666667: "frame_133400700001666667.png",
                        133400700002000000: "133400700002000000.png"}  # <ts>.png wins over frame_<ts>.png
    assert ff.other == 2 and "frame_<ts>.png" in ff.patterns()


def test_calibration_groups(tmp_path):
    """The release's one calibration folder per group of recordings: the group whose name's range
    holds the sequence number is taken; none or several -> an error naming them."""
    for group in ("calibrations_vid1_17", "calibrations_vid18_50"):
        (tmp_path / "calibrations" / group / "rm_depth_ahat").mkdir(parents=True)
    for seq, want in (("raw_video_03", "calibrations_vid1_17"), ("raw_video_18", "calibrations_vid18_50")):
        d = tmp_path / "raw_video_seqs" / seq
        d.mkdir(parents=True)
        assert find_calibration_dir(d).name == want
    d = tmp_path / "raw_video_seqs" / "raw_video_77"
    d.mkdir()
    with pytest.raises(InputError, match=r"2 calibration folders .*calibrations_vid18_50, calibrations_vid1_17.*number \(77\).*--calibration"):
        find_calibration_dir(d)
    assert find_calibration_dir(d, tmp_path / "calibrations" / "calibrations_vid1_17").name == "calibrations_vid1_17"
    # a single group folder beside the sequences is taken whatever its name
    lone = tmp_path / "lone"
    (lone / "calibrations_all" / "rm_depth_ahat").mkdir(parents=True)
    (lone / "seq_9").mkdir()
    assert find_calibration_dir(lone / "seq_9").name == "calibrations_all"
    with pytest.raises(InputError, match="tried .*calibrations"):
        find_calibration_dir(tmp_path / "raw_video_seqs" / "raw_video_03", tmp_path / "nothing")
