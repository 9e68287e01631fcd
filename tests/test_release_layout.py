"""The IT3DEgo release layout as published (and as its notebooks lay it out), read without flags.

One small synthetic recording is laid out twice: as ``egograph synth`` writes it, and as the release
does (``raw_video_seqs/<seq>/``, ``Annotations/<seq with raw->annotation>/label.csv``, per-group
calibration folders, ``svoe.txt`` in its own tree, ``frame_<ts>.png`` frames, MVPE photos as
``<instance_name>/instance_image_*.jpg`` for all sequences, AHAT poses and frames keyed by their own
capture times, a few all-zero poses). ``info``, ``lift``, ``track`` and ``eval`` give the same numbers
on both. Then each input the release may lack is taken away in turn: a warning names what was
tried, and ``--strict`` exits 2 with one line naming it.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import make_recording

from egograph.cli import main
from egograph.core.units import TICKS_PER_SECOND

SEQ = "raw_video_05"          # number 5: calibrations_vid1_17 holds it
ZERO_PV = (3, 17, 40)         # frames whose reported PV pose is all zeros (hl2ss: not tracked)
ZERO_DEPTH = (5, 41)          # frames whose AHAT pose is all zeros
PV_IMAGES = (0, 10, 20)       # frames given a (dummy) PV image
AHAT_LAG_MS = 5.0             # AHAT capture time after PV (the synthetic lag), with +-1 ms jitter


@pytest.fixture(autouse=True)
def wide_console(monkeypatch):
    monkeypatch.setenv("COLUMNS", "400")  # rich wraps at 80 columns otherwise, splitting long paths


def _poses(path: Path) -> dict:
    return json.loads(path.read_text())


def _zero_poses(path: Path, frames) -> None:
    poses = _poses(path)
    keys = sorted(poses, key=int)
    for f in frames:
        poses[keys[f]] = np.zeros((4, 4)).tolist()
    path.write_text(json.dumps(poses))


@pytest.fixture(scope="module")
def original(tmp_path_factory) -> Path:
    """The synthetic layout, with the release's all-zero poses and a few PV images added."""
    root = make_recording(tmp_path_factory.mktemp("orig") / "rec", 7, "pv.rgb=false", "frames=60", f"sequence={SEQ}")
    seq = root / SEQ
    _zero_poses(seq / "pv_pose.json", ZERO_PV)
    _zero_poses(seq / "depth_ahat_pose.json", ZERO_DEPTH)
    keys = sorted(_poses(seq / "pv_pose.json"), key=int)
    for f in PV_IMAGES:
        cv2.imwrite(str(seq / "pv" / f"{keys[f]}.png"), np.full((8, 8, 3), 100, np.uint8))
    return root


def release_layout(src: Path, dst: Path) -> Path:
    """``src`` (synthetic layout) rewritten as the IT3DEgo release lays it out; returns the dataset root."""
    seq = dst / "raw_video_seqs" / SEQ
    shutil.copytree(src / SEQ, seq)
    # PV frames frame_<ts>.png; AHAT frames and poses keyed by the AHAT's own capture times.
    for f in sorted((seq / "pv").glob("*.png")):
        f.rename(f.with_name(f"frame_{f.name}"))
    rng = np.random.default_rng(3)
    poses = _poses(seq / "depth_ahat_pose.json")
    own = {}
    for k in sorted(poses, key=int):
        t = int(k) + int(round((AHAT_LAG_MS + rng.uniform(-1, 1)) * TICKS_PER_SECOND / 1000))
        own[str(t)] = poses[k]
        (seq / "depth_ahat" / f"{k}.png").rename(seq / "depth_ahat" / f"frame_{t}.png")
    (seq / "depth_ahat_pose.json").write_text(json.dumps(own))
    # Annotations/ capitalised, the notebook's folder name, label.csv; svoe.txt in its own tree.
    ann = dst / "Annotations" / SEQ.replace("raw", "annotation")
    shutil.copytree(src / "annotations" / SEQ, ann)
    (ann / "labels.csv").rename(ann / "label.csv")
    (dst / "enrollment" / "svoe" / SEQ).mkdir(parents=True)
    (ann / "svoe.txt").rename(dst / "enrollment" / "svoe" / SEQ / "svoe.txt")
    # MVPE photos for all sequences at the top level, <instance_name>/instance_image_<k>.jpg.
    for inst in sorted((src / "mvpe" / SEQ).iterdir()):
        out = dst / "MVPE" / inst.name
        out.mkdir(parents=True)
        for k, photo in enumerate(sorted(inst.glob("*.jpg")), start=1):
            shutil.copy(photo, out / f"instance_image_{k}.jpg")
    shutil.copytree(dst / "MVPE" / inst.name, dst / "MVPE" / "cup_of_another_sequence")
    # One calibration folder per group of recordings; the other group's differs (a wrong pick shows).
    shutil.copytree(src / "calibrations", dst / "calibrations" / "calibrations_vid1_17")
    other = dst / "calibrations" / "calibrations_vid18_50"
    shutil.copytree(src / "calibrations", other)
    ext = np.fromfile(other / "rm_depth_ahat" / "extrinsics.bin", "<f4").reshape(4, 4)
    ext[3, :3] += 0.3
    ext.astype("<f4").tofile(other / "rm_depth_ahat" / "extrinsics.bin")
    shutil.copytree(src / "detections", dst / "detections")  # egograph's own input, beside the data
    return dst


@pytest.fixture(scope="module")
def release(original, tmp_path_factory) -> Path:
    return release_layout(original, tmp_path_factory.mktemp("release") / "benchmark_data")


def run(argv: list[str], capsys, recwarn) -> tuple[int, str, str]:
    recwarn.clear()
    code = main(argv)
    cap = capsys.readouterr()
    return code, cap.out, cap.err + "".join(f"warning: {w.message}\n" for w in recwarn)


def _pipeline(root: Path, out: Path, capsys, recwarn) -> dict:
    """info, lift, track (kf and graph), eval on ``root`` without flags -> what they gave."""
    out.mkdir()
    got: dict = {"warnings": []}
    for argv in (["info", str(root), "--json", str(out / "info.json")],
                 ["lift", str(root), "--detections", "svoe", "--quiet", "--out", str(out / "obs.npz")],
                 ["track", str(root), "--tracker", "kf", "--quiet", "--out", str(out / "kf")],
                 ["track", str(root), "--tracker", "graph", "--quiet", "--out", str(out / "graph")],
                 ["eval", str(root), str(out / "kf"), "--json", str(out / "kf.json")],
                 ["eval", str(root), str(out / "graph"), "--json", str(out / "graph.json")]):
        code, _, err = run(argv, capsys, recwarn)
        assert code == 0, (argv, err)
        got["warnings"] += [line.split(": ", 2)[-1] for line in err.splitlines() if "warning" in line]
    got["info"] = json.loads((out / "info.json").read_text())
    got["obs"] = dict(np.load(out / "obs.npz", allow_pickle=False))
    for name in ("kf", "graph"):
        got[name] = json.loads((out / f"{name}.json").read_text())
    return got


@pytest.mark.slow
def test_release_layout_gives_the_same_numbers(original, release, tmp_path, capsys, recwarn):
    a = _pipeline(original, tmp_path / "a", capsys, recwarn)
    b = _pipeline(release, tmp_path / "b", capsys, recwarn)
    ia, ib = a["info"], b["info"]
    for key in ("frames", "invalid_pv_poses", "invalid_depth_poses", "depth_factor", "depth_valid_share", "instances",
                "intervals", "box_annotations", "svoe_enrolled", "mvpe_photos", "detections", "pv_frames_on_disk",
                "depth_frames_on_disk"):
        assert ia[key] == ib[key], key
    assert ib["invalid_pv_poses"] == len(ZERO_PV)
    assert ib["invalid_depth_poses"] == len(ZERO_DEPTH)
    assert ib["svoe_enrolled"] > 0 and ib["pv_frames_on_disk"] == len(PV_IMAGES)
    assert "cup_of_another_sequence" not in ib["mvpe_photos"] and set(ib["mvpe_photos"]) == set(ib["instances"])
    where = {i["what"]: i for i in ib["inputs"]}
    assert Path(where["calibration"]["found"]).name == "calibrations_vid1_17"
    assert Path(where["annotations"]["found"]).parent.name == "Annotations"
    assert Path(where["SVOE enrollment"]["found"]).parts[-3:] == ("svoe", SEQ, "svoe.txt")
    assert Path(where["MVPE photos"]["found"]).name == "MVPE"
    assert "60 of 60 PV frames joined within 15 ms" in where["AHAT poses"]["note"]
    assert "60 of 60" in where["AHAT frames"]["note"] and "frame_<ts>.png" in where["AHAT frames"]["note"]
    assert all(i["found"] for i in ib["inputs"]), ib["inputs"]
    # The same observations (lift), and the same metrics (track + eval) with kf and the graph.
    arrays = set(a["obs"]) - {"provenance"}
    assert arrays == set(b["obs"]) - {"provenance"} and {"world", "frame", "instance"} <= arrays
    for key in sorted(arrays):
        np.testing.assert_array_equal(a["obs"][key], b["obs"][key], err_msg=key)
    assert np.isfinite(a["obs"]["world"]).all(axis=1).sum() > 10  # something was lifted
    for name in ("kf", "graph"):
        assert a[name] == b[name], name
    # Both layouts warn about the zeroed poses only; the release layout adds nothing to that.
    assert any("invalid pose" in w for w in b["warnings"])
    def gist(warnings: list[str]) -> set[str]:  # without the path and the timestamps (AHAT's are its own)
        return {re.sub(r"\d{10,}", "<ts>", w.split(": ", 1)[-1]) for w in warnings}

    assert gist(b["warnings"]) == gist(a["warnings"])


# --------------------------------------------------------------------------- each input taken away


def _seq(root: Path) -> Path:
    return root / "raw_video_seqs" / SEQ


def no_labels(root: Path) -> tuple[Path, str]:
    (root / "Annotations" / SEQ.replace("raw", "annotation") / "label.csv").unlink()
    return _seq(root), "label.csv"


def no_svoe(root: Path) -> tuple[Path, str]:
    shutil.rmtree(root / "enrollment")
    return _seq(root), "svoe.txt"


def no_mvpe(root: Path) -> tuple[Path, str]:
    shutil.rmtree(root / "MVPE")
    return _seq(root), "<instance_name>/*.jpg"


def depth_frames_unnamed(root: Path) -> tuple[Path, str]:
    for k, f in enumerate(sorted((_seq(root) / "depth_ahat").glob("*.png"))):
        f.rename(f.with_name(f"depth_{k:04d}.png"))  # a frame counter, not a timestamp
    return _seq(root) / "depth_ahat", "frame_<ts>.png"


def depth_poses_off(root: Path) -> tuple[Path, str]:
    p = _seq(root) / "depth_ahat_pose.json"
    poses = _poses(p)
    # Keyed by another clock (1000 s off). A constant offset under one PV period would join AHAT
    # poses to the wrong PV frame: the tolerance cannot tell, the offsets in `info` show it.
    p.write_text(json.dumps({str(int(k) + 1000 * TICKS_PER_SECOND): v for k, v in poses.items()}))
    return p, "60 of 60 PV frames have no AHAT pose within 15 ms"


def some_depth_frames_missing(root: Path) -> tuple[Path, str]:
    for f in sorted((_seq(root) / "depth_ahat").glob("*.png"))[:6]:
        f.unlink()
    return _seq(root) / "depth_ahat", "6 of 60 PV frames have no AHAT depth frame"


def zero_poses(root: Path) -> tuple[Path, str]:
    return _seq(root) / "pv_pose.json", "3 of 60 invalid pose(s)"


def _repair_poses(root: Path) -> None:
    """Replace the all-zero poses by the frame before's, so that the fault at hand is the only one."""
    for name in ("pv_pose.json", "depth_ahat_pose.json"):
        poses = _poses(_seq(root) / name)
        keys = sorted(poses, key=int)
        for prev, k in zip(keys, keys[1:]):
            if not np.any(poses[k]):
                poses[k] = poses[prev]
        (_seq(root) / name).write_text(json.dumps(poses))


MISSING = [no_labels, no_svoe, no_mvpe, depth_frames_unnamed, depth_poses_off, some_depth_frames_missing, zero_poses]


@pytest.mark.parametrize("fault", MISSING, ids=[f.__name__ for f in MISSING])
def test_missing_input_warns_what_was_tried_and_strict_refuses(release, tmp_path, capsys, recwarn, fault):
    root = tmp_path / "data"
    shutil.copytree(release, root, symlinks=True)
    if fault is not zero_poses:
        _repair_poses(root)
    culprit, words = fault(root)
    code, _, err = run(["info", str(root), "--json", str(tmp_path / "info.json")], capsys, recwarn)
    assert code == 0, err
    line = next((w for w in err.splitlines() if words in w), None)
    assert line is not None and str(culprit) in line, err
    if fault is not zero_poses:
        assert "tried" in line, line
    code, _, err = run(["info", str(root), "--strict"], capsys, recwarn)
    assert code == 2, err
    errors = [e for e in err.splitlines() if e.startswith("egograph: error:")]
    assert len(errors) == 1 and str(culprit) in errors[0] and words in errors[0], err
    assert "Traceback" not in err


def test_info_lists_found_and_not_found(release, tmp_path, capsys, recwarn):
    root = tmp_path / "data"
    shutil.copytree(release, root, symlinks=True)
    no_svoe(root)
    code, out, _ = run(["info", str(root), "--json", str(tmp_path / "info.json")], capsys, recwarn)
    assert code == 0
    inputs = {i["what"]: i for i in json.loads((tmp_path / "info.json").read_text())["inputs"]}
    assert inputs["SVOE enrollment"]["found"] is None and inputs["SVOE enrollment"]["problem"]
    assert any(t.endswith(f"*/*/{SEQ}/svoe.txt") for t in inputs["SVOE enrollment"]["tried"])
    assert inputs["annotations"]["found"] and not inputs["annotations"]["problem"]
    assert "inputs: found / not found" in out and "not found; tried" in out and "SVOE enrollment" in out


def test_calibration_group_by_sequence_number(release, tmp_path, capsys, recwarn):
    """Two groups and a sequence number neither covers: by number alone (calib_fit.select=false) one
    line naming both, exit 2; with the fit, the best-fitting one is used with a warning naming both;
    --calibration picks one."""
    root = tmp_path / "data"
    shutil.copytree(release, root, symlinks=True)
    cal = root / "calibrations"
    (cal / "calibrations_vid1_17").rename(cal / "calibrations_vid6_17")
    code, _, err = run(["info", str(root), "--set", "calib_fit.select=false"], capsys, recwarn)
    assert code == 2
    assert "calibrations_vid18_50" in err and "calibrations_vid6_17" in err and "--calibration" in err
    code, _, err = run(["info", str(root)], capsys, recwarn)
    assert code == 0, err
    assert "no calibration folder is named for this sequence; using the best-fitting" in err
    assert "calibrations_vid18_50" in err and "calibrations_vid6_17" in err
    code, _, err = run(["info", str(root), "--calibration", str(cal / "calibrations_vid6_17")], capsys, recwarn)
    assert code == 0, err


def test_dataset_root_with_several_sequences_asks_for_one(release, tmp_path, capsys, recwarn):
    root = tmp_path / "data"
    shutil.copytree(release, root, symlinks=True)
    shutil.copytree(_seq(root), root / "raw_video_seqs" / "raw_video_06")
    code, _, err = run(["info", str(root)], capsys, recwarn)
    assert code == 2 and "holds 2 sequences" in err and "--sequence" in err
    code, _, err = run(["info", str(root), "--sequence", SEQ], capsys, recwarn)
    assert code == 0, err
