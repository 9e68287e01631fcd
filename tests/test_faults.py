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


# --------------------------------------------------------------------------- what the CLI fuzz found (issue 13)


def test_pose_files_unreadable_in_any_way_are_refused_naming_the_file(tmp_path):
    from egograph.core.errors import InputError
    from egograph.io.poses import read_pose_json

    eye = "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]"
    cases = {"not_utf8": (b"\x89\xff{}", "not UTF-8"), "deep": (b"[" * 100_000, "nested too deeply"),
             "underscore_key": (f'{{"1_000": {eye}}}'.encode(), "not an integer timestamp"),
             "huge_int": (b'{"1": [[1' + b"0" * 400 + b',0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}',
                          "not a numeric 4x4 matrix")}
    for name, (data, words) in cases.items():
        p = tmp_path / name
        p.write_bytes(data)
        with pytest.raises(InputError, match=words) as exc:
            read_pose_json(p)
        assert exc.value.path == p, name
    folder = tmp_path / "folder.json"
    folder.mkdir()
    with pytest.raises(InputError, match="found a folder") as exc:
        read_pose_json(folder)
    assert exc.value.path == folder
    bom = tmp_path / "bom.json"  # written by Windows tools: read as the same poses
    bom.write_bytes(b"\xef\xbb\xbf" + f'{{"7": {eye}}}'.encode())
    ts, poses, valid = read_pose_json(bom)
    assert ts.tolist() == [7] and valid.all() and np.array_equal(poses[0], np.eye(4))


def _ply(tmp_path: Path, name: str, data: bytes) -> Path:
    p = tmp_path / name
    p.write_bytes(data)
    return p


def test_check_ply_refuses_truncated_and_broken_files_and_reads_good_ones(tmp_path):
    from egograph.core.errors import InputError
    from egograph.io.recording import check_ply

    header = (b"ply\nformat binary_little_endian 1.0\ncomment x\nelement vertex 4\nproperty float x\nproperty float y\n"
              b"property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n")
    verts = np.arange(12, dtype="<f4").tobytes()
    tri = bytes([3]) + np.array([0, 1, 2], "<i4").tobytes()
    quad = bytes([4]) + np.array([0, 1, 2, 3], "<i4").tobytes()
    good = {"triangles": header + verts + tri + tri, "mixed": header + verts + tri + quad,
            "big_endian": header.replace(b"little", b"big") + np.arange(12, dtype=">f4").tobytes()
            + bytes([3]) + np.array([0, 1, 2], ">i4").tobytes() + bytes([3]) + np.array([0, 1, 2], ">i4").tobytes(),
            "ascii": b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                     b"element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"}
    for name, data in good.items():
        assert check_ply(_ply(tmp_path, name, data)) == ({"vertex": 4, "face": 2} if name != "ascii" else
                                                         {"vertex": 3, "face": 1}), name
    bad = {"empty": (b"", "no 'ply' magic"), "garbage": (bytes(range(128, 200)), "no 'ply' magic"),
           "header_cut": (header[:60], "no end_header"),
           "in_vertices": (header + verts[:20], "4 vertex rows of 12 bytes need"),
           "last_face_short": (header + verts + tri + tri[:-1], "ends in face row 2 of 2"),
           "one_face_less": (header + verts + tri, "ends in face row 2 of 2"),
           "mixed_short": (header + verts + tri + quad[:-4], "ends in face row 2 of 2"),
           "bad_header_line": (header.replace(b"comment x", b"colour red"), "header line 3 is not PLY"),
           "ascii_short": (good["ascii"][:-8], "declares 4 rows, the file has 3 data lines")}
    for name, (data, words) in bad.items():
        p = _ply(tmp_path, name, data)
        with pytest.raises(InputError, match="unreadable PLY") as exc:
            check_ply(p)
        assert words in str(exc.value) and exc.value.path == p, (name, str(exc.value))
    (tmp_path / "dir.ply").mkdir()
    with pytest.raises(InputError, match="unreadable PLY: a folder"):
        check_ply(tmp_path / "dir.ply")


def _copy(small_rec: Path, tmp_path: Path) -> Path:
    root = tmp_path / "rec"
    shutil.copytree(small_rec, root)
    return root


def _error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.startswith("egograph: error:")]
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.slow
def test_refine_and_info_name_a_truncated_mesh_unreadable(small_rec, tmp_path, capsys, recwarn):
    """Once: "mesh has no triangles" (Open3D read the truncated file as an empty mesh) and Open3D's
    own line on stderr; info counted the header's faces."""
    root = _copy(small_rec, tmp_path)
    mesh = seq(root) / "mesh" / "scene.ply"
    mesh.write_bytes(mesh.read_bytes()[:-5])  # the last face cut short
    out = tmp_path / "refined"
    code, _, err = run(["refine", str(root), "--quiet", "--out", str(out)], capsys, recwarn)
    assert code == 2 and not out.exists(), err
    line = _error_line(err)
    assert str(mesh) in line and "unreadable PLY: truncated" in line, line
    code, _, err = run(["info", str(root), "--json", str(tmp_path / "info.json")], capsys, recwarn)
    assert code == 0 and f"{mesh}: unreadable PLY" in err, err
    summary = json.loads((tmp_path / "info.json").read_text())
    assert summary["mesh_triangles"] is None
    assert any(i["what"] == "scene mesh" and i["problem"] for i in summary["inputs"])


def test_regt_without_labels_names_the_annotation_folder(small_rec, tmp_path, capsys, recwarn):
    root = _copy(small_rec, tmp_path)
    (ann_dir(root) / "labels.csv").unlink()
    code, _, err = run(["regt", str(root), "--quiet", "--out", str(tmp_path / "regt")], capsys, recwarn)
    assert code == 2
    line = _error_line(err)
    assert f"{ann_dir(root)}/{{labels.csv,label.csv}} (the folder is there, without a labels file)" in line, line


@pytest.mark.slow
@pytest.mark.parametrize("strict", [False, True])
def test_lift_counts_and_warns_pv_frames_without_a_detection_file(small_rec, tmp_path, capsys, recwarn, strict):
    root = _copy(small_rec, tmp_path)
    for f in det_files(root)[:7]:
        f.unlink()
    out = tmp_path / "obs.npz"
    code, stdout, err = run(["lift", str(root), "--detections", "svoe", "--quiet", "--out", str(out)]
                            + (["--strict"] if strict else []), capsys, recwarn)
    words = f"{det_dir(root)}: 7 of 60 PV frames have no detection file"
    if strict:
        assert code == 2 and words in _error_line(err) and not out.exists(), err
        return
    assert code == 0 and words in err, err
    assert f"PV frames without a detection file in {det_dir(root)}: 7 of 60" in " ".join(stdout.split())


@pytest.mark.slow
@pytest.mark.parametrize("case", ["centers_empty", "centers_missing", "motion_missing", "boxes_missing"])
def test_regt_says_what_it_lacks(small_rec, tmp_path, capsys, recwarn, case):
    root = _copy(small_rec, tmp_path)
    a = ann_dir(root)
    culprit = {"centers_empty": a / "3d_center_annot.txt", "centers_missing": a / "3d_center_annot.txt",
               "motion_missing": a / "motion_state_annot.txt", "boxes_missing": a / "2d_bbox_annot"}[case]
    if case == "centers_empty":
        culprit.write_text("")
    elif case == "boxes_missing":
        shutil.rmtree(culprit)
    else:
        culprit.unlink()
    out = tmp_path / "regt"
    code, _, err = run(["regt", str(root), "--quiet", "--out", str(out)], capsys, recwarn)
    if case.startswith("centers"):  # the re-estimates are still made; there is nothing to audit
        assert code == 0 and out.is_dir(), err
        assert f"{culprit}: {'empty' if case == 'centers_empty' else 'missing'}" in err, err
        assert "no given centre to audit them against" in err
        return
    assert code == 2 and not out.exists(), err
    assert f"egograph: error: {culprit}: " in _error_line(err)


def test_eval_refuses_an_empty_centre_file(small_rec, good_outputs, tmp_path, capsys, recwarn):
    """Once: "recovered 0/0" and exit 0."""
    root, out, results = setup_case(small_rec, good_outputs, tmp_path, "eval")
    before = tree_bytes(out)
    centers = ann_dir(root) / "3d_center_annot.txt"
    centers.write_text("# nothing annotated\n")
    code, _, err = run(command("eval", root, out, results), capsys, recwarn)
    assert code == 2 and tree_bytes(out) == before, err
    line = _error_line(err)
    assert str(centers) in line and "nothing to score against" in line, line


@pytest.mark.parametrize("case", ["labels_missing", "depth_missing"])
def test_info_warns_about_missing_inputs_and_strict_refuses(small_rec, tmp_path, capsys, recwarn, case):
    root = _copy(small_rec, tmp_path)
    if case == "labels_missing":
        (ann_dir(root) / "labels.csv").unlink()
        culprit, words = seq(root), f"{ann_dir(root)}/{{labels.csv,label.csv}} (the folder is there"
    else:
        culprit, words = seq(root) / "depth_ahat", "no AHAT depth frame for any PV frame: folder missing"
        shutil.rmtree(culprit)
    code, _, err = run(["info", str(root)], capsys, recwarn)
    assert code == 0 and f"{culprit}: " in err and words in err, err
    code, _, err = run(["info", str(root), "--strict"], capsys, recwarn)
    assert code == 2
    line = _error_line(err)
    assert str(culprit) in line and words in line, line


@pytest.mark.slow
def test_lift_warns_about_detections_beyond_the_labels(small_rec, tmp_path, capsys, recwarn):
    """Once only in the lift report on stdout ("1 unknown_instance")."""
    root = _copy(small_rec, tmp_path)
    f = first_nonempty_det(root)
    append(f, "99 10 10 50 50 0.5\n")
    argv = ["lift", str(root), "--detections", "svoe", "--quiet", "--out", str(tmp_path / "obs.npz")]
    code, stdout, err = run(argv, capsys, recwarn)
    assert code == 0 and f"{f}: instance id 99 beyond the 5 labels of labels.csv; 1 detection(s)" in err, err
    assert "1  unknown_instance" in stdout
    code, _, err = run(argv + ["--strict", "--overwrite"], capsys, recwarn)
    assert code == 2 and str(f) in _error_line(err)


@pytest.mark.slow
def test_refine_refuses_singular_rig_and_warns_without_mesh(small_rec, tmp_path, capsys, recwarn):
    """Once: refine with an all-zero AHAT extrinsics.bin moved nothing and said nothing; without
    mesh/ it ran without its mesh factors and said nothing."""
    root = _copy(small_rec, tmp_path)
    ext = root / "calibrations" / "rm_depth_ahat" / "extrinsics.bin"
    ext.write_bytes(np.zeros(16, "<f4").tobytes())
    out = tmp_path / "refined"
    code, _, err = run(["refine", str(root), "--quiet", "--out", str(out)], capsys, recwarn)
    assert code == 2 and not out.exists(), err
    line = _error_line(err)
    assert str(ext) in line and "not a rigid transform" in line, line

    root = _copy(small_rec, tmp_path / "b")
    shutil.rmtree(seq(root) / "mesh")
    code, _, err = run(["refine", str(root), "--quiet", "--strict", "--out", str(out)], capsys, recwarn)
    assert code == 2 and not out.exists() and "no scene mesh" in _error_line(err), err


@pytest.mark.parametrize("kind", ["folder", "list", "not_utf8", "row_not_object"])
def test_unreadable_intervals_and_tum_files_are_named(tmp_path, kind):
    """Once: a folder, a JSON list or a non-object row in intervals.json, and a non-UTF-8 or folder
    TUM file, were internal errors (exit 1)."""
    from egograph.core.errors import InputError
    from egograph.poses.tum import read_tum
    from egograph.track.intervals import read_intervals_json

    p = tmp_path / "intervals.json"
    if kind == "folder":
        p.mkdir()
    elif kind == "list":
        p.write_text("[1, 2]")
    elif kind == "not_utf8":
        p.write_bytes(b"\x89\xff\xfe")
    else:
        p.write_text('{"intervals": [3]}')
    with pytest.raises(InputError) as exc:
        read_intervals_json(p)
    assert exc.value.path == p
    if kind in ("folder", "not_utf8"):
        with pytest.raises(InputError) as exc:
            read_tum(p)
        assert exc.value.path == p
