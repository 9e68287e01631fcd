"""Faulty inputs through the command line: refused input and input with nothing usable exit 2
naming the file (an earlier good output in the same place stays byte-identical); partly unusable
input runs, says what was skipped and warns (exit 0).

Each case edits a copy of one small synthetic recording and runs ``egograph`` in-process. The
warnings a command line run prints on stderr are recorded by pytest here, so "stderr" below is
the captured stderr plus the recorded warnings' text.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import make_recording, sequence_dir

from egograph.cli import main

# --------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def small_rec(tmp_path_factory) -> Path:
    """A 60-frame synthetic recording (depth, poses, annotations, detections; no RGB)."""
    return make_recording(tmp_path_factory.mktemp("faults") / "rec", 7, "pv.rgb=false", "frames=60")


@pytest.fixture(scope="module")
def good_outputs(small_rec, tmp_path_factory) -> dict[str, Path]:
    """Outputs of good runs on the recording: a results folder (``track``), metrics (``eval --json``),
    a summary (``info --json``); each case starts its --out from a copy of one of them."""
    d = tmp_path_factory.mktemp("good")
    out = {"track": d / "results", "eval": d / "eval.json", "info": d / "info.json", "lift": d / "obs.npz"}
    assert main(["track", str(small_rec), "--tracker", "memory", "--quiet", "--out", str(out["track"])]) == 0
    assert main(["lift", str(small_rec), "--detections", "svoe", "--quiet", "--out", str(out["lift"])]) == 0
    assert main(["eval", str(small_rec), str(out["track"]), "--json", str(out["eval"])]) == 0
    assert main(["info", str(small_rec), "--json", str(out["info"])]) == 0
    return out


@pytest.fixture(autouse=True)
def wide_console(monkeypatch):
    monkeypatch.setenv("COLUMNS", "400")  # rich wraps at 80 columns otherwise, splitting long paths


# --------------------------------------------------------------------------- editing a copy

def seq(root: Path) -> Path:
    return sequence_dir(root)


def det_dir(root: Path) -> Path:
    return root / "detections" / seq(root).name / "svoe"


def ann_dir(root: Path) -> Path:
    return root / "annotations" / seq(root).name


def det_files(root: Path) -> list[Path]:
    return sorted(det_dir(root).glob("*.txt"))


def first_nonempty_det(root: Path) -> Path:
    return next(f for f in det_files(root) if f.read_text().strip())


def timestamps(root: Path) -> list[int]:
    return sorted(int(k) for k in json.loads((seq(root) / "pv_pose.json").read_text()))


def append(path: Path, text: str) -> None:
    path.write_text(path.read_text() + text)


def rename_all(root: Path, name) -> Path:
    for f in det_files(root):
        f.rename(f.with_name(name(int(f.stem))))
    return det_dir(root)


def rewrite_depth(root: Path, convert) -> Path:
    files = sorted((seq(root) / "depth_ahat").glob("*.png"))
    for f in files:
        raw = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(f), convert(raw))
    return files[0].parent


def no_depth_pose(root):
    (seq(root) / "depth_ahat_pose.json").unlink()
    return seq(root) / "depth_ahat_pose.json"


def zero_extrinsics(root):
    p = root / "calibrations" / "rm_depth_ahat" / "extrinsics.bin"
    p.write_bytes(np.zeros(16, "<f4").tobytes())
    return p


def misnamed_detections(root):
    return rename_all(root, lambda ts: f"frame_{ts}.txt")


def foreign_timestamps(root):
    return rename_all(root, lambda ts: f"{ts + 7}.txt")


def empty_detection_folder(root):
    for f in det_files(root):
        f.unlink()
    return det_dir(root)


def depth_8bit_gray(root):
    return rewrite_depth(root, lambda raw: np.clip(raw, 0, 255).astype(np.uint8))


def one_depth_8bit(root):
    """Only the depth frame of a frame with detections that opening the recording does not sample
    (it samples 5 evenly spaced frames to detect the raw unit): refused when the lift reads it."""
    ts = timestamps(root)
    sampled = {ts[i] for i in np.linspace(0, len(ts) - 1, 5).astype(int)}
    t = next(int(f.stem) for f in det_files(root) if f.read_text().strip() and int(f.stem) not in sampled)
    f = seq(root) / "depth_ahat" / f"{t}.png"
    cv2.imwrite(str(f), np.clip(cv2.imread(str(f), cv2.IMREAD_UNCHANGED), 0, 255).astype(np.uint8))
    return f


def depth_8bit_rgb(root):
    return rewrite_depth(root, lambda raw: np.repeat(np.clip(raw, 0, 255).astype(np.uint8)[..., None], 3, -1))


def depth_wrong_size(root):
    return rewrite_depth(root, lambda raw: raw[:256, :256].copy())


def score_out_of_range(root):
    f = first_nonempty_det(root)
    append(f, "0 10 10 50 50 1.5\n")
    return f


def det_conf_out_of_range(root):
    f = first_nonempty_det(root)
    append(f, "0 10 10 50 50 7 0.9\n")
    return f


def duplicate_label(root):
    p = ann_dir(root) / "labels.csv"
    append(p, p.read_text().splitlines()[0] + "\n")
    return p


def overlapping_motion(root):
    p = ann_dir(root) / "motion_state_annot.txt"
    inst, t0, t1 = p.read_text().split()[:3]
    append(p, f"{inst} {t1} {int(t1) + 1000}\n")  # shares its first tick with the first interval
    return p


def center_unknown_instance(root):
    p = ann_dir(root) / "3d_center_annot.txt"
    ts = timestamps(root)
    append(p, f"{ts[0]} {ts[-1]} 9 0 0 0 0\n")
    return p


def center_duplicate(root):
    p = ann_dir(root) / "3d_center_annot.txt"
    t0, t1, inst = p.read_text().split()[:3]
    append(p, f"{t0} {t1} {inst} 0 0 0 0\n")  # the same instance somewhere else at the same time
    return p


# Partly unusable input: the run goes on and says what it skipped.

def stray_detection_files(root):
    ts = timestamps(root)
    shutil.copy(first_nonempty_det(root), det_dir(root) / f"{ts[-1] + 12345}.txt")
    (det_dir(root) / "notes.txt").write_text("not a detection file\n")
    return det_dir(root)


def frames_without_depth_pose(root):
    p = seq(root) / "depth_ahat_pose.json"
    poses = json.loads(p.read_text())
    for k in sorted(poses, key=int)[:10]:
        del poses[k]
    p.write_text(json.dumps(poses))
    return p


# --------------------------------------------------------------------------- results folders (eval)

def results_copy(root: Path, good: Path) -> Path:
    res = root.parent / "results"
    shutil.copytree(good, res)
    return res


def half_results(res: Path) -> Path:
    for f in sorted(res.glob("*.txt"))[::2]:
        f.unlink()
    return res


def empty_results(res: Path) -> Path:
    for f in res.glob("*.txt"):
        f.unlink()
    return res


def first_nonempty_result(res: Path) -> Path:
    return next(f for f in sorted(res.glob("*.txt")) if f.read_text().strip())


def unknown_instance_result(res: Path) -> Path:
    f = first_nonempty_result(res)
    append(f, "9 0 0 0 1\n")
    return f


def repeated_instance_result(res: Path) -> Path:
    f = first_nonempty_result(res)
    inst = f.read_text().split()[0]
    append(f, f"{inst} 0 0 0 1\n")
    return f


def stray_result_file(res: Path) -> Path:
    f = res / "7.txt"
    f.write_text("0 0 0 0 1\n")
    return f


# --------------------------------------------------------------------------- running a case

def run(argv: list[str], capsys, recwarn) -> tuple[int, str, str]:
    code = main(argv)
    cap = capsys.readouterr()
    err = cap.err + "".join(f"{w.filename}:{w.lineno}: {w.category.__name__}: {w.message}\n" for w in recwarn)
    return code, cap.out, err


def command(kind: str, root: Path, out: Path, results: Path | None = None) -> list[str]:
    if kind == "track":
        return ["track", str(root), "--tracker", "memory", "--quiet", "--out", str(out)]
    if kind == "lift":
        return ["lift", str(root), "--detections", "svoe", "--quiet", "--out", str(out)]
    if kind == "eval":
        return ["eval", str(root), str(results), "--json", str(out)]
    return ["info", str(root), "--json", str(out)]


def tree_bytes(path: Path) -> dict[str, bytes]:
    if path.is_file():
        return {path.name: path.read_bytes()}
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def setup_case(small_rec: Path, good_outputs: dict, tmp_path: Path, kind: str) -> tuple[Path, Path, Path | None]:
    """A copy of the recording, its --out holding the good output of ``kind``, and for eval a
    copy of the good results folder."""
    root = tmp_path / "rec"
    shutil.copytree(small_rec, root)
    good = good_outputs[kind]
    out = tmp_path / "out" / good.name
    out.parent.mkdir()
    (shutil.copytree if good.is_dir() else shutil.copy)(good, out)
    results = results_copy(root, good_outputs["track"]) if kind == "eval" else None
    return root, out, results


REFUSED = [
    # (fault, command, words the message must hold)
    (no_depth_pose, "track", "missing: no AHAT pose for any PV frame"),
    (no_depth_pose, "lift", "missing: no AHAT pose for any PV frame"),
    (zero_extrinsics, "track", "not a rigid transform"),
    (misnamed_detections, "track", "no detection file names a PV frame: expected <ts>.txt"),
    (foreign_timestamps, "track", "no detection file names a PV frame"),
    (empty_detection_folder, "track", "no detection files"),
    (depth_8bit_gray, "track", "uint8 pixels"),
    (one_depth_8bit, "track", "uint8 pixels"),
    (depth_8bit_rgb, "track", "3 channels"),
    (depth_wrong_size, "track", "256x256 pixels"),
    (score_out_of_range, "track", "score 1.5 outside [-1, 1]"),
    (det_conf_out_of_range, "track", "det_conf 7 outside [0, 1]"),
    (duplicate_label, "track", "also on line 1"),
    (overlapping_motion, "info", "overlaps"),
    (center_unknown_instance, "eval", "instance id 9 out of range"),
    (center_duplicate, "eval", "also on line 1"),
]


@pytest.mark.slow
@pytest.mark.parametrize(("fault", "kind", "words"), REFUSED, ids=[f"{c[0].__name__}-{c[1]}" for c in REFUSED])
def test_refused_input_exits_2_and_keeps_the_earlier_output(small_rec, good_outputs, tmp_path, capsys, recwarn,
                                                             fault, kind, words):
    root, out, results = setup_case(small_rec, good_outputs, tmp_path, kind)
    before = tree_bytes(out)
    culprit = fault(root)
    code, _, err = run(command(kind, root, out, results), capsys, recwarn)
    assert code == 2, err
    line = next(ln for ln in err.splitlines() if ln.startswith("egograph: error:"))
    assert str(culprit) in line and words in line, line
    assert tree_bytes(out) == before


PARTIAL = [
    # (fault, command, where the notice is, words it must hold)
    (stray_detection_files, "track", "err", "2 of 62 detection files skipped"),
    (stray_detection_files, "track", "out", "not_pv_frame"),
    (frames_without_depth_pose, "track", "out", "PV frames without a valid pose in depth_ahat_pose.json: 10 of 60"),
]


@pytest.mark.slow
@pytest.mark.parametrize(("fault", "kind", "where", "words"), PARTIAL,
                         ids=[f"{c[0].__name__}-{c[2]}" for c in PARTIAL])
def test_partly_unusable_input_runs_and_says_so(small_rec, good_outputs, tmp_path, capsys, recwarn,
                                                fault, kind, where, words):
    root, out, results = setup_case(small_rec, good_outputs, tmp_path, kind)
    culprit = fault(root)
    code, stdout, err = run(command(kind, root, out, results), capsys, recwarn)
    assert code == 0, err
    text = err if where == "err" else stdout
    assert words in text, text
    if where == "err":
        assert str(culprit) in text


RESULT_FAULTS = [
    # (fault, words of the warning); each is an error under strict
    (half_results, "30 of 60 PV frames have no result file"),
    (empty_results, "60 of 60 PV frames have no result file"),
    (unknown_instance_result, "instance id 9 out of range"),
    (repeated_instance_result, "two results for one instance in one frame"),
    (stray_result_file, "timestamp is not a PV frame"),
]


@pytest.mark.slow
@pytest.mark.parametrize(("fault", "words"), RESULT_FAULTS, ids=[c[0].__name__ for c in RESULT_FAULTS])
def test_eval_counts_unusable_results_and_strict_refuses(small_rec, good_outputs, tmp_path, capsys, recwarn,
                                                         fault, words):
    from egograph.core.errors import InputError
    from egograph.io.recording import Recording
    from egograph.steps.evaluate import evaluate

    root, out, results = setup_case(small_rec, good_outputs, tmp_path, "eval")
    culprit = fault(results)
    code, _, err = run(command("eval", root, out, results), capsys, recwarn)
    assert code == 0, err
    assert words in err and str(culprit) in err, err
    with pytest.raises(InputError, match=words) as exc:
        evaluate(Recording.open(root), results, strict=True)
    assert exc.value.path == culprit


def test_unknown_and_repeated_result_lines_do_not_count(small_rec, good_outputs, tmp_path):
    """Lines ignored by eval leave the metrics as they were."""
    from egograph.io.recording import Recording
    from egograph.steps.evaluate import evaluate

    root, _, results = setup_case(small_rec, good_outputs, tmp_path, "eval")
    rec = Recording.open(root)
    before = evaluate(rec, results).to_json_dict()
    f = first_nonempty_result(results)
    append(f, "9 0 0 0 1\n" + f.read_text())  # an unknown id, then every line again
    with pytest.warns(UserWarning):
        after = evaluate(rec, results).to_json_dict()
    assert after == before


# --------------------------------------------------------------------------- inputs that once ended in a traceback


def _drop_pv_pose(root: Path, keep: int | None = None) -> None:
    """Remove one PV frame's pose (``keep``: keep only the first ``keep`` frames of both pose files)."""
    for name in ("pv_pose.json",) if keep is None else ("pv_pose.json", "depth_ahat_pose.json"):
        p = seq(root) / name
        d = json.loads(p.read_text())
        keys = sorted(d, key=int)
        d = {k: d[k] for k in keys[:keep]} if keep is not None else {k: v for k, v in d.items() if k != keys[10]}
        p.write_text(json.dumps(d))


@pytest.mark.parametrize("case", ["info_pv_frame_without_pose", "refine_pv_frame_without_pose", "refine_one_frame",
                                  "alias_zero", "synth_one_frame"])
def test_former_tracebacks_end_cleanly(small_rec, tmp_path, capsys, case):
    rec = tmp_path / "rec"
    shutil.copytree(small_rec, rec)
    out = tmp_path / "out"
    if case == "info_pv_frame_without_pose":
        _drop_pv_pose(rec)
        code, want = main(["info", str(rec)]), 0
    elif case == "refine_pv_frame_without_pose":
        _drop_pv_pose(rec)
        code, want = main(["refine", str(rec), "--out", str(out), "--quiet", "--set", "refine.mesh=false"]), 0
    elif case == "refine_one_frame":
        _drop_pv_pose(rec, keep=1)
        code, want = main(["refine", str(rec), "--out", str(out), "--quiet", "--set", "refine.mesh=false"]), 2
    elif case == "alias_zero":
        np.float32(0).tofile(rec / "calibrations" / "rm_depth_ahat" / "alias.bin")
        code, want = main(["track", str(rec), "--tracker", "kf", "--out", str(out), "--quiet"]), 2
    else:
        code, want = main(["synth", str(out), "--config", "synth/tiny", "--frames", "1", "--quiet"]), 2
    err = capsys.readouterr().err
    assert code == want, err
    assert "Traceback" not in err and "internal error" not in err
    if want == 2:
        lines = [line for line in err.splitlines() if line.startswith("egograph: error:")]
        assert len(lines) == 1 and not out.exists()
        assert {"refine_one_frame": "pv_pose.json", "alias_zero": "alias.bin", "synth_one_frame": "frames"}[case] in lines[0]
