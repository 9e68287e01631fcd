"""Issue 40's fault classes, each made and checked in-process: the exit code, one line naming the
cause, and every input and earlier output byte-identical afterwards (nothing left beside them).

1. the output policy (an output may only be absent, empty, or an earlier egograph output of the
   same kind; never an input, inside one, a file for a folder, a special file, a link);
2. inputs of another recording (results, observations) refused naming both recordings;
3. input checks (duplicate JSON keys, frame numbers for ticks, repeated detection lines, config
   numbers, YAML aliases, extrinsics in another axis convention, the depth unit, PV frame size);
4. faults of the machine (read-only, full disk, mount point, long names, standard output) and
   signals (SIGTERM, SIGHUP, a Ctrl-C a library swallowed).
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import time
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import make_recording

from egograph.cli import main

FRAMES = 40


def link_tree(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, copy_function=os.link, symlinks=True)
    return dst


def snapshot(root: Path) -> dict:
    """Every entry under ``root``: bytes of files, link targets, kinds of the rest (never followed)."""
    out = {}
    for dirpath, dirs, files in os.walk(root):
        for n in dirs + files:
            p = Path(dirpath) / n
            rel = str(p.relative_to(root))
            if p.is_symlink():
                out[rel] = "-> " + os.readlink(p)
            elif p.is_file():
                out[rel] = p.read_bytes()
            else:
                out[rel] = "dir" if p.is_dir() else "special"
    return out


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """Two recordings (A, B), observations and memory-tracker results of each, a plot of A's."""
    d = tmp_path_factory.mktemp("policy")
    for name, seed in (("recA", 7), ("recB", 8)):
        make_recording(d / name, seed, "pv.rgb=false", f"frames={FRAMES}")
    with _quiet():
        for r in "AB":
            assert main(["lift", str(d / f"rec{r}"), "--detections", "svoe", "--quiet", "--out",
                         str(d / f"obs{r}.npz")]) == 0
            assert main(["track", str(d / f"rec{r}"), "--tracker", "memory", "--quiet", "--observations",
                         str(d / f"obs{r}.npz"), "--out", str(d / f"res{r}")]) == 0
        assert main(["plot", str(d / "recA"), str(d / "resA"), "--out", str(d / "plotsA")]) == 0
    (d / "mine").mkdir()
    (d / "mine" / "thesis.txt").write_text("not egograph's\n")
    (d / "notes.txt").write_text("the user's\n")
    return d


class _quiet:
    def __enter__(self):
        import warnings

        self._w = warnings.catch_warnings()
        self._w.__enter__()
        warnings.simplefilter("ignore")

    def __exit__(self, *exc):
        self._w.__exit__(*exc)


@pytest.fixture
def case(base, tmp_path, capsys, monkeypatch):
    """A hard-linked copy of the base (corruptions replace files, never edit them), entered as the
    working folder; ``run(argv)`` -> (exit code, stderr lines, entries changed or added)."""
    d = link_tree(base, tmp_path / "case")
    monkeypatch.chdir(d)

    class Case:
        root = d

        def run(self, argv, allowed=()):
            capsys.readouterr()
            before = snapshot(d)
            with warnings.catch_warnings(record=True) as seen:  # pytest would take them from stderr
                code = main([str(a) for a in argv])
            after = snapshot(d)
            err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
            err += [f"egograph: warning: {w.message}" for w in seen]
            changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k)
                             and not any(k == a or k.startswith(a + "/") for a in allowed))
            return code, err, changed

    return Case()


def refused(result, *words):
    """Exit 2, one error line naming every word, nothing changed."""
    code, err, changed = result
    assert code == 2, err
    errors = [ln for ln in err if ln.startswith("egograph: error:")]
    assert len(errors) == 1 and len(err) == len(errors) + sum(ln.startswith("egograph: warning:") for ln in err), err
    assert all(w.lower() in errors[0].lower() for w in words), errors[0]
    assert changed == [], changed
    return errors[0]


TRACK = ["track", "recA", "--tracker", "memory", "--quiet", "--observations", "obsA.npz"]


# --------------------------------------------------------------------------- 1. the output policy


@pytest.mark.parametrize("argv, words", [
    (TRACK + ["--out", "recA"], ("recA", "input")),
    (["lift", "recA", "--detections", "svoe", "--quiet", "--out", "recA/tiny_seq/pv_pose.json"], ("inside", "input")),
    (["plot", "recA", "resA", "--out", "resA"], ("is the input",)),
    (["export", "recA", "resA", "--out", "resA"], ("is the input",)),
    (["smooth", "recA", "resA", "--quiet", "--out", "resA"], ("is the input",)),
    (["compare", "recA", "resA", "resB", "--out", "resB"], ("is the input",)),
    (TRACK + ["--out", "."], ("holds the input",)),
    (["eval", "recA", "resA", "--json", "recA/recording.json"], ("inside the input",)),
    (TRACK + ["--out", "resN", "--intervals", "resA/intervals.json"], ("--intervals", "output of `egograph track`")),
    (TRACK + ["--out", "notes.txt"], ("existing file where an output folder goes",)),
    (["lift", "recA", "--detections", "svoe", "--quiet", "--out", "resA"], ("folder where an output file goes",)),
    (TRACK + ["--out", "mine"], ("did not make",)),
    (TRACK + ["--out", "plotsA"], ("egograph plot",)),
    (TRACK + ["--out", "notes.txt/res"], ("not a folder",)),
])
def test_an_output_the_policy_forbids_is_refused_and_nothing_changes(case, argv, words):
    refused(case.run(argv), *words)


def test_links_and_special_files_are_never_replaced(case):
    os.symlink("/dev/null", case.root / "dev.json")
    refused(case.run(["eval", "recA", "resA", "--json", "dev.json"]), "symbolic link")
    os.symlink("resA", case.root / "lnk")
    refused(case.run(TRACK + ["--out", "lnk"]), "symbolic link")
    os.mkfifo(case.root / "fifo")
    refused(case.run(["eval", "recA", "resA", "--json", "fifo"]), "special file", "FIFO")
    assert (case.root / "dev.json").is_symlink() and os.readlink(case.root / "dev.json") == "/dev/null"


def test_a_plot_of_nothing_keeps_the_earlier_pictures(case):
    (case.root / "empty").mkdir()
    refused(case.run(["plot", "recA", "empty", "--out", "plotsA"]), "no prediction", "plotsA")


def test_what_the_policy_allows_still_runs(case):
    # Its own earlier output; the same run gives the same bytes (the record names this command line).
    code, err, changed = case.run(TRACK + ["--out", "resA", "--overwrite"], allowed=("resA/egograph.json",))
    assert code == 0 and changed == [], (err, changed)
    (case.root / "empty_out").mkdir()
    code, err, changed = case.run(TRACK + ["--out", "empty_out"], allowed=("empty_out",))
    assert code == 0 and (case.root / "empty_out" / "egograph.json").is_file(), err
    code, err, _ = case.run(["eval", "recA", "resA", "--json", "notes.json"], allowed=("notes.json",))
    assert code == 0 and json.loads((case.root / "notes.json").read_text())


# --------------------------------------------------------------------------- 2. another recording


@pytest.mark.parametrize("argv", [
    ["eval", "recA", "resB"],
    ["smooth", "recA", "resB", "--quiet", "--out", "sm"],
    ["plot", "recA", "resB", "--out", "plN"],
    TRACK[:5] + ["--observations", "obsB.npz", "--out", "resN"],
])
def test_an_input_of_another_recording_is_refused_naming_both(case, argv):
    line = refused(case.run(argv), "recB", "recA", "made from recording")
    assert len(line) < 400


def test_results_without_a_record_are_read_with_a_note(case):
    (case.root / "resA" / "egograph.json").unlink()
    code, err, _ = case.run(["eval", "recA", "resA"])
    assert code == 0
    notes = [ln for ln in err if "without an egograph run record" in ln]
    assert len(notes) == 1 and "resA" in notes[0] and "recA" in notes[0], err


# --------------------------------------------------------------------------- 3. input checks


def _replace(p: Path, data: str | bytes) -> None:
    p.unlink()
    (p.write_text if isinstance(data, str) else p.write_bytes)(data)


def test_a_duplicate_json_key_is_refused_naming_key_and_file(case):
    p = case.root / "recA" / "tiny_seq" / "pv_pose.json"
    text = p.read_text().strip()
    key = text[1:].split(":", 1)[0]
    _replace(p, "{" + key + ": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]], " + text[1:])
    refused(case.run(["info", "recA"]), "pv_pose.json", key.strip('" '), "twice")


def test_frame_numbers_for_timestamps_are_refused(case):
    p = case.root / "recA" / "tiny_seq" / "pv_pose.json"
    d = json.loads(p.read_text())
    _replace(p, json.dumps({str(i): d[k] for i, k in enumerate(sorted(d, key=int))}))
    refused(case.run(["info", "recA"]), "pv_pose.json", "not HoloLens 100 ns ticks")


def test_repeated_identical_detection_lines_count_once_with_one_warning(case):
    det = case.root / "recA" / "detections" / "tiny_seq" / "svoe"
    f = next(p for p in sorted(det.glob("*.txt")) if p.read_text().strip())
    good = main(["lift", "recA", "--detections", "svoe", "--quiet", "--out", "good.npz"])
    first = f.read_text().splitlines()[0]
    _replace(f, f.read_text() + f"{first}\n{first}\n")
    code, err, _ = case.run(["lift", "recA", "--detections", "svoe", "--quiet", "--out", "dup.npz"],
                            allowed=("dup.npz",))
    assert good == 0 and code == 0
    warned = [ln for ln in err if "repeated identical detection line" in ln]
    assert len(warned) == 1 and "2 repeated" in warned[0] and f.name in warned[0], err
    with np.load(case.root / "good.npz") as a, np.load(case.root / "dup.npz") as b:
        assert np.array_equal(a["world"], b["world"], equal_nan=True)


@pytest.mark.parametrize("override, words", [
    (["--set", "graph.covariance_floor_m=.inf"], ("graph.covariance_floor_m", "finite")),
    (["--set", "graph.max_iterations=1.0e+29"], ("graph.max_iterations", "at most")),
    (["--set", "graph.covariance_floor_m=[" + ",".join(["1"] * 5000) + "]"], ("graph.covariance_floor_m",)),
])
def test_config_numbers_must_be_finite_and_in_range(case, override, words):
    line = refused(case.run(TRACK + ["--out", "resN"] + override), *words)
    assert len(line) <= 400


def test_lag_must_be_finite(case):
    refused(case.run(["track", "recA", "--tracker", "graph-causal", "--lag", "inf", "--quiet", "--observations",
                      "obsA.npz", "--out", "resN"]), "--lag")


def test_a_yaml_alias_bomb_is_refused_at_once(case):
    rows = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    rows += [f"{b}: &{b} [{','.join(['*' + a] * 9)}]" for a, b in zip("abcdefgh", "bcdefghi")]
    (case.root / "bomb.yaml").write_text("\n".join(rows) + "\n")
    assert len((case.root / "bomb.yaml").read_bytes()) < 500
    line = refused(case.run(TRACK + ["--out", "resN", "--config", "bomb.yaml"]), "bomb.yaml", "aliases")
    assert len(line) < 300


def test_extrinsics_in_another_axis_convention_are_refused_naming_the_cause(case):
    ext = case.root / "recA" / "calibrations" / "rm_depth_ahat" / "extrinsics.bin"
    _replace(ext, np.diag([-1.0, 1.0, -1.0, 1.0]).astype("<f4").tobytes())
    refused(case.run(["lift", "recA", "--detections", "svoe", "--lift", "reference", "--quiet", "--out", "x.npz"]),
            "extrinsics.bin", "behind the PV camera", "axis convention")


@pytest.mark.slow
def test_4mm_depth_that_never_wraps_is_read_as_4mm_from_the_mesh(case):
    """Depth in 4 mm units whose ranges never wrap reads like 1 mm values; the mesh decides."""
    import open3d as o3d

    from egograph.geometry.hl2ss import ahat_to_world_matrix, ahat_unit_rays
    from egograph.io.recording import Recording

    good = main(["lift", "recA", "--detections", "svoe", "--lift", "reference", "--quiet", "--out", "good.npz"])
    rec = Recording.open(case.root / "recA")
    rays = ahat_unit_rays(rec.ahat.uv2xy).astype(np.float32).reshape(-1, 3)
    for i in range(len(rec)):
        p = rec.depth_path(i)
        if not p.is_file() or not rec.depth_valid[i]:
            continue
        raw = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        m = ahat_to_world_matrix(rec.ahat.extrinsics, rec.depth_poses[i])
        r = np.empty((len(rays), 6), np.float32)
        r[:, :3], r[:, 3:] = m[3, :3], rays @ m[:3, :3].astype(np.float32)
        t = rec.mesh_scene().cast_rays(o3d.core.Tensor(r))["t_hit"].numpy().reshape(raw.shape)
        p.unlink()
        cv2.imwrite(str(p), np.where((raw > 0) & np.isfinite(t), np.rint(t * 250), 0).astype(np.uint16))
    assert Recording.open(case.root / "recA").depth_factor == 1.0  # what the values alone say
    code, err, _ = case.run(["lift", "recA", "--detections", "svoe", "--lift", "reference", "--quiet", "--out",
                             "n.npz"], allowed=("n.npz",))
    assert good == 0 and code == 0
    assert any("4 mm units, from the mesh" in ln for ln in err), err
    # Read as 1 mm, every point would lie at a quarter of its range; read as 4 mm it lies where the
    # mesh is along the box's ray (the room's surface behind the object: up to a few dm off).
    assert main(["lift", "recA", "--detections", "svoe", "--lift", "reference", "--quiet", "--out", "one.npz",
                 "--set", "io.depth_factor=1"]) == 0
    with np.load(case.root / "good.npz") as a, np.load(case.root / "n.npz") as b, np.load(case.root / "one.npz") as c:
        ok = np.isfinite(a["world"]).all(1) & np.isfinite(b["world"]).all(1) & np.isfinite(c["world"]).all(1)
        off = [np.median(np.linalg.norm(a["world"][ok] - x["world"][ok], axis=1)) for x in (b, c)]
        ratio = np.median(b["range_m"][ok] / c["range_m"][ok])
        assert ok.sum() >= 5 and off[0] < 0.3 and off[0] < off[1] and 3.5 < ratio < 5, (off, ratio)


def test_pv_frames_of_another_size_are_rescaled_with_a_warning_or_refused(tiny_rgb_rec, tmp_path):
    from egograph.core.errors import InputError
    from egograph.io.recording import Recording

    rec_dir = shutil.copytree(tiny_rgb_rec, tmp_path / "rec", copy_function=os.link)
    rec = Recording.open(rec_dir)
    rows, cols = rec.pv.shape
    full = rec.rgb(0)
    p = rec.pv_path(0)
    img = cv2.imread(str(p), cv2.IMREAD_COLOR)
    _replace(p, b"")
    cv2.imwrite(str(p), cv2.resize(img, (cols // 2, rows // 2), interpolation=cv2.INTER_AREA))
    with pytest.warns(UserWarning, match=r"PV frames are \d+x\d+ pixels, the PV calibration .*rescaled"):
        half = rec.rgb(0)
    assert half.shape == full.shape and np.abs(half.astype(int) - full.astype(int)).mean() < 8
    _replace(p, b"")
    cv2.imwrite(str(p), img[:, : cols // 2])
    with pytest.raises(InputError, match="another aspect ratio"):
        rec.rgb(0)


# --------------------------------------------------------------------------- 4. the machine, signals


def test_a_read_only_output_folder_is_one_line(case, monkeypatch):
    import egograph.io.atomic as atomic

    def read_only(lock):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(lock))

    monkeypatch.setattr(atomic, "_open_lock", read_only)
    refused(case.run(TRACK + ["--out", "resA", "--overwrite"]), "read-only", ".resA.lock")


def _failing_open(monkeypatch, after: int, fail):
    """``open`` of the folder writer (:func:`egograph.io.textio.write_text_dir`) that writes ``after``
    files, then calls ``fail(path)``: the disk fills or a signal arrives in the middle of a folder."""
    import egograph.io.textio as textio

    calls = []

    def opener(path, *args, **kwargs):
        calls.append(path)
        if len(calls) > after:
            fail(path)
        return open(path, *args, **kwargs)

    monkeypatch.setattr(textio, "open", opener, raising=False)
    return calls


def test_a_full_disk_while_writing_keeps_the_old_output_and_leaves_nothing(case, monkeypatch):
    def full(path):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    calls = _failing_open(monkeypatch, 3, full)
    line = refused(case.run(TRACK + ["--out", "resA", "--overwrite"]), "no space left")
    assert len(calls) == 4 and Path(calls[-1]).name in line


def test_a_mount_point_and_a_long_name_are_one_line(case):
    mounts = [p for p in ("/dev/shm", "/proc", "/sys", "/dev") if os.path.ismount(p)]
    if mounts:
        refused(case.run(TRACK + ["--out", mounts[0]]), "mount point")
    refused(case.run(TRACK + ["--out", "x" * 300]), "too long")


class _Stdout:
    def __init__(self, exc):
        self.exc = exc

    def write(self, text):
        raise self.exc

    def flush(self):
        raise self.exc

    def fileno(self):
        raise OSError("no descriptor")

    isatty = lambda self: False  # noqa: E731


@pytest.mark.parametrize("stdout, code, words", [
    (None, 2, ("standard output is closed",)),
    (_Stdout(OSError(errno.ENOSPC, "No space left on device")), 2, ("standard output", "no space")),
    (_Stdout(BrokenPipeError(errno.EPIPE, "Broken pipe")), 141, ()),
])
def test_a_closed_full_or_broken_standard_output(case, monkeypatch, stdout, code, words):
    monkeypatch.setattr("sys.stdout", stdout)
    got, err, changed = case.run(["info", "recA"])
    assert got == code and changed == [], err
    if words:
        assert len(err) == 1 and all(w in err[0].lower() for w in words), err
    else:
        assert err == []  # a reader that went away: quiet


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGHUP, 129)])
def test_a_signal_while_writing_leaves_the_old_output_and_no_lock_or_temporary(case, monkeypatch, sig, code):
    def killed(path):
        os.kill(os.getpid(), sig)
        time.sleep(1)  # the handler raises here

    _failing_open(monkeypatch, 3, killed)
    # under nohup the suite starts with SIGHUP ignored, and egograph rightly keeps an ignored signal
    # ignored: the hangup tested here is the one a terminal sends, so the default disposition is restored
    before = signal.signal(sig, signal.SIG_DFL)
    try:
        got, err, changed = case.run(TRACK + ["--out", "resA", "--overwrite"])
    finally:
        signal.signal(sig, before)
    assert got == code and changed == [], (err, changed)
    assert len(err) == 1 and signal.Signals(sig).name in err[0]


def test_a_ctrl_c_swallowed_by_a_library_import_stops_the_run(case, monkeypatch):
    """Open3D turns a Ctrl-C during its import into ImportError("initialization failed")."""
    from egograph.io.recording import Recording

    def swallowed(self):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1)
        except KeyboardInterrupt:
            raise ImportError("initialization failed") from None

    monkeypatch.setattr(Recording, "mesh_scene", swallowed)
    # A background job of a shell without job control inherits SIGINT ignored: as from a terminal here.
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        got, err, changed = case.run(["track", "recA", "--tracker", "memory", "--quiet", "--out", "resA",
                                      "--overwrite"])
    finally:
        signal.signal(signal.SIGINT, before)
    assert got == 130 and changed == [], (err, changed)


def test_a_stated_depth_unit_is_checked_on_the_mesh(tiny_rec):
    """io.depth_factor stated against the evidence (the synthetic AHAT writes 4 mm units): a warning
    that names the knob and both units, an error with --strict; the right unit passes silently."""
    import warnings

    from egograph.core.config import load_config
    from egograph.core.errors import InputError
    from egograph.core.resources import default_config
    from egograph.steps.recording import open_recording
    from egograph.steps.settings import EgographConfig

    def cfg(*sets):
        return load_config(EgographConfig, default_config(), list(sets))

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert open_recording(tiny_rec, cfg("io.depth_factor=1")).depth_factor == 1.0
    said = [str(w.message) for w in caught if "io.depth_factor states" in str(w.message)]
    assert len(said) == 1 and "supports 4 mm" in said[0] and "4x off" in said[0], said
    with pytest.raises(InputError, match="io.depth_factor states raw depth in 1 mm"):
        open_recording(tiny_rec, cfg("io.depth_factor=1", "io.strict=true"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        open_recording(tiny_rec, cfg("io.depth_factor=4", "io.strict=true"))
    assert not [w for w in caught if "depth_factor" in str(w.message)]
