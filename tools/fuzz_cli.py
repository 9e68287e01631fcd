"""Bad input through the installed ``egograph`` command, as a new user meets it: one small synthetic
recording, many corrupted copies of it, each run in a fresh ``egograph`` process over an earlier
good output; then killed runs and two runs racing for one output. Prints a table of the outcomes.

    .venv/bin/python tools/fuzz_cli.py                          # ~130 input cases, 20 kills, 10 races
    .venv/bin/python tools/fuzz_cli.py --kills 0 --races 0 --jobs 2 --work /tmp/fuzz --keep
    .venv/bin/python tools/fuzz_cli.py --only none --kills 0 --races 0 --classes all   # the classes only

Outcome of an input case (in this order):

- traceback: 'Traceback' in the output, an exit code other than 0/1/2, or exit 1 without the
  one line ``egograph: internal error: ... (full traceback in FILE ...)``;
- internal error: exit 1 with that line and its log (a bug, reported cleanly);
- output replaced: the run failed and the earlier good output at its --out changed;
- clean error: exit 2, one ``egograph: error:`` line, naming a path of the case;
- unclear error: exit 2 otherwise (more lines, or no path);
- warned and continued: exit 0 with an ``egograph: warning:`` line;
- noted on stdout only: exit 0 without a warning, a changed output, and the run's summary on
  stdout says what it skipped (e.g. the lift report's "missing or unreadable depth_ahat png");
- changed (valid input): exit 0, a changed output, and the "corruption" is valid input (an
  empty per-frame detection or result file: a frame with nothing in it);
- silent wrong result: exit 0 without a warning and an output that differs from the good run's
  (paths of the case replaced by the good run's before comparing);
- unaffected: exit 0 without a warning, the output as the good run's (the command does not read
  what was corrupted, or it does not change the result).

Kill trials: ``egograph track`` killed (SIGKILL) at seeded random moments of its run over an older
output; the output must be the whole old or the whole new one and the next run must succeed and
leave nothing else beside it. Race trials: two ``egograph track`` runs on one --out started
together; each ends 0 or 2 ("another egograph run is writing"), the output is complete.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

DEFAULT_EGOGRAPH = Path(sys.executable).with_name("egograph")
OUT_NAMES = {"info": "info.json", "lift": "obs.npz", "track": "results", "smooth": "smoothed", "regt": "regt",
             "eval": "eval.json", "compare": "comparison", "refine": "refined", "eval-poses": "poses.json"}
SKIP_IN_SIGNATURE = {"egograph.json", "config.yaml", "comparison.png", "report.md", "report.json"}
"""Output files that hold the command line or timings (they differ between any two runs)."""


# --------------------------------------------------------------------------- commands


def argv_of(command: str, rec: Path, res: Path, out: Path) -> list[str]:
    return {
        "info": ["info", str(rec), "--json", str(out)],
        "lift": ["lift", str(rec), "--detections", "svoe", "--quiet", "--out", str(out)],
        "track": ["track", str(rec), "--tracker", "memory", "--quiet", "--out", str(out)],
        "smooth": ["smooth", str(rec), str(res), "--quiet", "--out", str(out)],
        "regt": ["regt", str(rec), "--quiet", "--out", str(out)],
        "eval": ["eval", str(rec), str(res), "--json", str(out)],
        "compare": ["compare", str(rec), str(res), str(res), "--names", "a,b", "--out", str(out)],
        "refine": ["refine", str(rec), "--quiet", "--out", str(out), "--set", "refine.mesh_stride=20",
                   "--set", "refine.point_stride=12"],
        "eval-poses": ["eval-poses", str(rec), "--json", str(out)],
    }[command]


@dataclass
class Run:
    code: int
    out: str
    err: str
    seconds: float


def run(egograph: Path, argv: list[str], timeout: float = 600) -> Run:
    env = dict(os.environ, COLUMNS="400")  # rich wraps long paths at 80 columns otherwise
    t0 = time.monotonic()
    p = subprocess.run([str(egograph), *argv], capture_output=True, text=True, timeout=timeout, env=env)
    return Run(p.returncode, p.stdout, p.stderr, time.monotonic() - t0)


# --------------------------------------------------------------------------- corruptions


def seq(rec: Path) -> Path:
    return next(p for p in rec.iterdir() if (p / "pv_pose.json").exists() or (p / "depth_ahat").is_dir())


def ann(rec: Path) -> Path:
    return rec / "annotations" / seq(rec).name


def nonempty(files) -> Path:
    return next(f for f in sorted(files) if f.read_text().strip())


def detection_file(rec: Path) -> Path:
    return nonempty((rec / "detections" / seq(rec).name / "svoe").glob("*.txt"))


def depth_png(rec: Path) -> Path:
    """The depth frame of the first frame with an svoe detection (the lift reads it)."""
    return seq(rec) / "depth_ahat" / (detection_file(rec).stem + ".png")


FILES: dict[str, tuple[Callable[[Path, Path], Path], tuple[str, ...]]] = {
    # name: (where it is in a case (recording, results), the commands that read it)
    "pv_pose.json": (lambda r, s: seq(r) / "pv_pose.json", ("info", "track", "eval-poses")),
    "depth_ahat_pose.json": (lambda r, s: seq(r) / "depth_ahat_pose.json", ("lift", "refine")),
    "synth_gt pv_pose.json": (lambda r, s: r / "synth_gt" / seq(r).name / "pv_pose.json", ("eval-poses", "info")),
    "labels.csv": (lambda r, s: ann(r) / "labels.csv", ("eval", "info")),
    "motion_state_annot.txt": (lambda r, s: ann(r) / "motion_state_annot.txt", ("eval",)),
    "3d_center_annot.txt": (lambda r, s: ann(r) / "3d_center_annot.txt", ("eval", "regt")),
    "2d box annotation": (lambda r, s: next(iter(sorted((ann(r) / "2d_bbox_annot").glob("*.txt")))), ("regt",)),
    "detection file": (lambda r, s: detection_file(r), ("lift",)),
    "depth PNG": (lambda r, s: depth_png(r), ("lift",)),
    "ahat extrinsics.bin": (lambda r, s: r / "calibrations" / "rm_depth_ahat" / "extrinsics.bin", ("lift",)),
    "ahat alias.bin": (lambda r, s: r / "calibrations" / "rm_depth_ahat" / "alias.bin", ("lift",)),
    "ahat scale.bin": (lambda r, s: r / "calibrations" / "rm_depth_ahat" / "scale.bin", ("lift",)),
    "ahat uv2xy.bin": (lambda r, s: r / "calibrations" / "rm_depth_ahat" / "uv2xy.bin", ("lift", "refine")),
    "pv intrinsics.bin": (lambda r, s: r / "calibrations" / "personal_video" / "intrinsics.bin", ("lift",)),
    "pv extrinsics.bin": (lambda r, s: r / "calibrations" / "personal_video" / "extrinsics.bin", ("lift",)),
    "mesh scene.ply": (lambda r, s: seq(r) / "mesh" / "scene.ply", ("refine",)),
    "result file": (lambda r, s: nonempty(s.glob("*.txt")), ("eval", "smooth")),
    "results intervals.json": (lambda r, s: s / "intervals.json", ("eval",)),
}


def replace(path: Path, data: bytes | str) -> Path:
    """Write a file of a hard-linked copy without touching the inode it shares."""
    if path.is_dir():
        shutil.rmtree(path)
    path.unlink(missing_ok=True)
    (path.write_text if isinstance(data, str) else path.write_bytes)(data)
    return path


def m_missing(p: Path) -> Path:
    p.unlink()
    return p


def m_empty(p: Path) -> Path:
    return replace(p, b"")


def m_truncated(p: Path) -> Path:
    data = p.read_bytes()
    return replace(p, data[: max(1, len(data) // 2)])


def m_garbage(p: Path) -> Path:
    return replace(p, bytes(random.Random(p.name).randrange(128, 256) for _ in range(64)))


def m_folder(p: Path) -> Path:
    p.unlink()
    p.mkdir()
    return p


MUTATIONS = {"missing": m_missing, "empty": m_empty, "truncated": m_truncated, "not UTF-8": m_garbage,
             "a folder": m_folder}


def _cv2():
    import cv2

    return cv2


def rewrite_depth(rec: Path, convert) -> Path:
    cv2 = _cv2()
    files = sorted((seq(rec) / "depth_ahat").glob("*.png"))
    for f in files:
        raw = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        f.unlink()
        cv2.imwrite(str(f), convert(raw))
    return files[0].parent


def append(p: Path, text: str) -> Path:
    return replace(p, p.read_text() + text)


def timestamps(rec: Path) -> list[int]:
    return sorted(int(k) for k in json.loads((seq(rec) / "pv_pose.json").read_text()))


def _edit_poses(rec: Path, edit) -> Path:
    p = seq(rec) / "pv_pose.json"
    d = json.loads(p.read_text())
    return replace(p, json.dumps(edit(d)))


def _nan_pose(d):
    k = sorted(d, key=int)[len(d) // 2]
    d[k] = [[float("nan")] * 4] * 4
    return d


def _rename_detections(rec: Path, name) -> Path:
    folder = detection_file(rec).parent
    for f in folder.glob("*.txt"):
        f.rename(f.with_name(name(f.stem)))
    return folder


def _results_drop(res: Path, every: int) -> Path:
    for f in sorted(res.glob("*.txt"))[::every]:
        f.unlink()
    return res


def _empty_detections(rec: Path) -> Path:
    folder = detection_file(rec).parent
    for f in folder.glob("*.txt"):
        f.unlink()
    return folder


def _overlap_motion(rec: Path) -> Path:
    p = ann(rec) / "motion_state_annot.txt"
    inst, _, t1 = p.read_text().split()[:3]
    return append(p, f"{inst} {t1} {int(t1) + 1000}\n")  # shares its first tick with the first interval


SEMANTIC: list[tuple[str, tuple[str, ...], Callable[[Path, Path], object]]] = [
    # (name, commands, corruption(recording, results) -> culprit)
    ("pose not 4x4", ("track", "eval-poses"), lambda r, s: _edit_poses(r, lambda d: {k: v[:3] for k, v in d.items()})),
    ("one pose NaN", ("track", "refine"), lambda r, s: _edit_poses(r, _nan_pose)),
    ("all poses zero", ("track",), lambda r, s: _edit_poses(r, lambda d: {k: [[0.0] * 4] * 4 for k in d})),
    ("pose keys not integers", ("info",), lambda r, s: _edit_poses(r, lambda d: {f"t{k}": v for k, v in d.items()})),
    ("singular extrinsics", ("lift", "refine"),
     lambda r, s: replace(r / "calibrations" / "rm_depth_ahat" / "extrinsics.bin", np.zeros(16, "<f4").tobytes())),
    ("alias 0", ("lift", "refine"),
     lambda r, s: replace(r / "calibrations" / "rm_depth_ahat" / "alias.bin", np.zeros(1, "<f4").tobytes())),
    ("scale negative", ("lift",),
     lambda r, s: replace(r / "calibrations" / "rm_depth_ahat" / "scale.bin", np.full(1, -1, "<f4").tobytes())),
    ("calibration missing", ("lift", "refine", "info"), lambda r, s: shutil.rmtree(r / "calibrations")),
    ("depth 8-bit", ("lift", "refine"), lambda r, s: rewrite_depth(r, lambda a: np.clip(a, 0, 255).astype(np.uint8))),
    ("depth wrong size", ("lift", "refine"), lambda r, s: rewrite_depth(r, lambda a: a[:256, :256].copy())),
    ("depth folder missing", ("lift", "refine", "info"), lambda r, s: shutil.rmtree(seq(r) / "depth_ahat")),
    ("detections match no frame", ("lift",), lambda r, s: _rename_detections(r, lambda t: f"{int(t) + 7}.txt")),
    ("detections named frame_<ts>", ("lift",), lambda r, s: _rename_detections(r, lambda t: f"frame_{t}.txt")),
    ("detection folder empty", ("lift",), lambda r, s: _empty_detections(r)),
    ("detection score 1.5", ("lift",), lambda r, s: append(detection_file(r), "0 10 10 50 50 1.5\n")),
    ("detection instance 99", ("lift",), lambda r, s: append(detection_file(r), "99 10 10 50 50 0.5\n")),
    ("detection box inverted", ("lift",), lambda r, s: append(detection_file(r), "0 50 50 10 10 0.5\n")),
    ("labels duplicate", ("eval", "info"), lambda r, s: append(ann(r) / "labels.csv",
                                                               (ann(r) / "labels.csv").read_text().splitlines()[0] + "\n")),
    ("center instance 9", ("eval", "regt"),
     lambda r, s: append(ann(r) / "3d_center_annot.txt", f"{timestamps(r)[0]} {timestamps(r)[-1]} 9 0 0 0 0\n")),
    ("center end before start", ("eval",),
     lambda r, s: append(ann(r) / "3d_center_annot.txt", f"{timestamps(r)[-1]} {timestamps(r)[0]} 0 0 0 0 0\n")),
    ("motion instance 9", ("eval",),
     lambda r, s: append(ann(r) / "motion_state_annot.txt", f"9 {timestamps(r)[0]} {timestamps(r)[-1]}\n")),
    ("motion overlapping", ("eval", "info"), lambda r, s: _overlap_motion(r)),
    ("results folder empty", ("eval", "smooth", "compare"), lambda r, s: _results_drop(s, 1)),
    ("results folder half", ("eval", "smooth"), lambda r, s: _results_drop(s, 2)),
    ("results unknown instance", ("eval", "smooth"), lambda r, s: append(nonempty(s.glob("*.txt")), "9 0 0 0 1\n")),
    ("results NaN position", ("eval", "smooth"), lambda r, s: append(nonempty(s.glob("*.txt")), "0 nan 0 0 1\n")),
    ("results folder missing", ("eval",), lambda r, s: shutil.rmtree(s)),
]


# --------------------------------------------------------------------------- one case


@dataclass
class Case:
    name: str
    command: str
    corrupt: Callable[[Path, Path], object]
    valid: bool = False
    """The change is valid input (the output may change without a word)."""
    outcome: str = ""
    detail: str = ""
    seconds: float = 0.0


def link_tree(src: Path, dst: Path) -> None:
    shutil.copytree(src, dst, copy_function=os.link)


def place_good(good: Path, out: Path) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    (shutil.copytree if good.is_dir() else shutil.copy2)(good, out)


def tree_bytes(path: Path) -> dict[str, bytes]:
    if not path.exists():
        return {}
    if path.is_file():
        return {path.name: path.read_bytes()}
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def signature(out: Path, case_dir: Path) -> dict:
    """The output's content with the case's paths taken out (what the good run's must equal)."""
    sig = {}
    files = [out] if out.is_file() else sorted(p for p in out.rglob("*") if p.is_file()) if out.exists() else []
    for p in files:
        if p.name in SKIP_IN_SIGNATURE:
            continue
        if p.suffix == ".npz":
            with np.load(p, allow_pickle=False) as z:
                sig[p.name] = {k: z[k].tobytes() if z[k].dtype.kind not in "US" else
                               str(z[k]).replace(str(case_dir), "CASE") for k in z.files}
        else:
            sig[p.name] = p.read_bytes().replace(str(case_dir).encode(), b"CASE")
    return sig


ERROR = re.compile(r"^egograph: error: ")
INTERNAL = re.compile(r"^egograph: internal error: .*\(full traceback in (\S+); please report it\)$")


NOTED = re.compile(r"missing or unreadable|instances in labels\.csv|\b[1-9]\d* (?:of \d+ )?[\w ]*skipped")


def classify(r: Run, case_dir: Path, out: Path, before: dict, good_sig: dict, valid: bool) -> tuple[str, str]:
    lines = r.err.splitlines()
    first = next((ln for ln in lines if not ln.startswith("egograph: warning:")), lines[-1] if lines else "")
    if "Traceback" in r.out + r.err or r.code not in (0, 1, 2):
        return "traceback", f"exit {r.code}: {r.err.strip()[-200:]}"
    if r.code == 1:
        m = next((INTERNAL.match(ln) for ln in lines if INTERNAL.match(ln)), None)
        if m is None or not Path(m.group(1)).is_file():
            return "traceback", f"exit 1 without the log line: {r.err.strip()[-200:]}"
        return "internal error", first
    if tree_bytes(out) != before and r.code != 0:
        return "output replaced", first
    if r.code == 2:
        errors = [ln for ln in lines if ERROR.match(ln)]
        others = [ln for ln in lines if not ERROR.match(ln) and not ln.startswith("egograph: warning:")]
        if len(errors) == 1 and not others and str(case_dir) in errors[0]:
            return "clean error", errors[0]
        return "unclear error", " | ".join(lines)[:300]
    warned = [ln for ln in lines if ln.startswith("egograph: warning:")]
    if warned:
        return "warned and continued", warned[0]
    if signature(out, case_dir) != good_sig:
        summary = " ".join(r.out.split())
        if valid:
            return "changed (valid input)", ""
        if NOTED.search(summary):
            return "noted on stdout only", NOTED.search(summary).group(0)
        return "silent wrong result", summary[-200:]
    return "unaffected", ""


@dataclass
class Setup:
    egograph: Path
    work: Path
    rec: Path
    results: Path
    good: dict[str, Path] = field(default_factory=dict)
    good_sig: dict[str, dict] = field(default_factory=dict)


def prepare(egograph: Path, work: Path, frames: int, seed: int) -> Setup:
    """The recording, a graph tracker's results of it, and each command's good output, each made
    in a folder laid out as a case (recording, results, out) so outputs compare path for path."""
    rec = work / "base" / "rec"
    r = run(egograph, ["synth", str(rec), "--config", "synth/tiny", "--frames", str(frames), "--seed", str(seed),
                       "--set", "pv.rgb=false", "--quiet"])
    assert r.code == 0, r.err
    results = work / "base" / "results"
    r = run(egograph, ["track", str(rec), "--tracker", "graph", "--quiet", "--out", str(results)])
    assert r.code == 0, r.err
    s = Setup(egograph, work, rec, results)
    for command, name in OUT_NAMES.items():
        d = work / "good" / command
        link_tree(rec, d / "rec")
        link_tree(results, d / "results")
        out = d / "out" / name
        out.parent.mkdir(parents=True)
        r = run(egograph, argv_of(command, d / "rec", d / "results", out))
        assert r.code == 0, (command, r.err)
        s.good[command] = out
        s.good_sig[command] = signature(out, d)
    return s


def run_case(s: Setup, i: int, case: Case) -> Case:
    d = s.work / "cases" / f"{i:03d}"
    link_tree(s.rec, d / "rec")
    link_tree(s.results, d / "results")
    out = d / "out" / OUT_NAMES[case.command]
    place_good(s.good[case.command], out)
    before = tree_bytes(out)
    try:
        case.corrupt(d / "rec", d / "results")
    except Exception as exc:  # the corruption does not apply to this recording
        case.outcome, case.detail = "not applicable", f"{type(exc).__name__}: {exc}"
        return case
    r = run(s.egograph, argv_of(case.command, d / "rec", d / "results", out))
    case.seconds = r.seconds
    case.outcome, case.detail = classify(r, d, out, before, s.good_sig[case.command], case.valid)
    return case


def input_cases() -> list[Case]:
    cases = []
    for fname, (where, commands) in FILES.items():
        for mname, mutate in MUTATIONS.items():
            for command in commands[:2]:
                cases.append(Case(f"{fname}: {mname}", command,
                                  lambda r, s, where=where, mutate=mutate: mutate(where(r, s)),
                                  valid=mname == "empty" and fname in ("detection file", "result file")))
    for name, commands, corrupt in SEMANTIC:
        cases += [Case(name, command, corrupt) for command in commands]
    return cases


# --------------------------------------------------------------------------- kills and races


def folder_state(folder: Path) -> dict:
    state = {}
    for p in sorted(folder.iterdir()) if folder.is_dir() else []:
        data = p.read_bytes()
        if p.name == "egograph.json":
            body = json.loads(data)
            body.pop("command", None)
            data = json.dumps(body, sort_keys=True).encode()
        state[p.name] = data
    return state


def kill_trials(s: Setup, n: int, seed: int) -> dict[str, int]:
    """``track`` over an older output of another configuration, killed at seeded moments of its run."""
    d = s.work / "kills"
    out = d / "out" / "results"
    new = ["track", str(s.rec), "--tracker", "graph", "--quiet", "--out", str(out)]
    old = new + ["--set", "graph.covariance_floor_m=0.05"]
    assert run(s.egograph, old).code == 0
    old_state = folder_state(out)
    keep = d / "old"
    shutil.copytree(out, keep)
    t = run(s.egograph, new)
    assert t.code == 0, t.err
    new_state = folder_state(out)
    rng = random.Random(seed)
    counts = {"trials": 0, "old": 0, "new": 0, "finished": 0, "mixed or missing": 0, "next run failed": 0,
              "leftovers": 0}
    for _ in range(n):
        shutil.rmtree(out)
        shutil.copytree(keep, out)
        delay = rng.uniform(0.0, t.seconds)
        proc = subprocess.Popen([str(s.egograph), *new], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            proc.wait(timeout=delay)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGKILL)
        killed = proc.wait() == -signal.SIGKILL
        state = folder_state(out)
        counts["trials"] += 1
        if state not in (old_state, new_state):
            counts["mixed or missing"] += 1
        else:
            counts["old" if state == old_state and killed else "new" if killed else "finished"] += 1
        r = run(s.egograph, new + ["--overwrite"])
        if r.code != 0 or folder_state(out) != new_state:
            counts["next run failed"] += 1
        if sorted(os.listdir(out.parent)) != ["results"]:
            counts["leftovers"] += 1
    return counts


def race_trials(s: Setup, n: int) -> dict[str, int]:
    """Two ``track`` runs on one --out started together."""
    d = s.work / "races"
    counts = {"trials": 0, "one refused (busy)": 0, "both ran": 0, "bad exit or message": 0, "output incomplete": 0}
    env = dict(os.environ, COLUMNS="400")
    for i in range(n):
        out = d / f"{i:02d}" / "results"
        argv = [str(s.egograph), "track", str(s.rec), "--tracker", "memory", "--quiet", "--out", str(out)]
        procs = [subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
                 for _ in range(2)]
        ends = [(p.wait(), p.stderr.read()) for p in procs]
        counts["trials"] += 1
        codes = sorted(c for c, _ in ends)
        if codes == [0, 0]:
            counts["both ran"] += 1
        elif codes == [0, 2] and all("another egograph run is writing" in e for c, e in ends if c == 2):
            counts["one refused (busy)"] += 1
        else:
            counts["bad exit or message"] += 1
        if not (out / "egograph.json").is_file() or sorted(os.listdir(out.parent)) != ["results"]:
            counts["output incomplete"] += 1
    return counts


# --------------------------------------------------------------------------- main


ORDER = ["clean error", "warned and continued", "noted on stdout only", "unaffected", "changed (valid input)",
         "unclear error", "internal error", "traceback", "silent wrong result", "output replaced", "not applicable"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--egograph", type=Path, default=DEFAULT_EGOGRAPH, help="the installed command to run")
    ap.add_argument("--work", type=Path, help="working folder (default: a new temporary folder)")
    ap.add_argument("--keep", action="store_true", help="keep the working folder")
    ap.add_argument("--frames", type=int, default=40, help="frames of the synthetic recording (default 40)")
    ap.add_argument("--seed", type=int, default=7, help="seed of the recording and of the kill moments")
    ap.add_argument("--jobs", type=int, default=2, help="input cases run at once (default 2)")
    ap.add_argument("--kills", type=int, default=20, help="kill trials (default 20)")
    ap.add_argument("--races", type=int, default=10, help="race trials (default 10)")
    ap.add_argument("--only", help="run only the input cases whose name contains this")
    ap.add_argument("--verbose", action="store_true", help="print every case's outcome")
    ap.add_argument("--classes", choices=("first", "second", "all", "none"), default="all",
                    help="also the fault classes of tools/fault_classes.py (output policy, another recording, "
                         "input checks, machine faults, signals; 'second': the extra set; default all)")
    args = ap.parse_args(argv)
    work = args.work or Path(tempfile.mkdtemp(prefix="egograph-fuzz-"))
    if work.exists() and any(work.iterdir()):
        raise SystemExit(f"{work} is not empty")
    t0 = time.monotonic()
    s = prepare(args.egograph, work, args.frames, args.seed)
    print(f"prepared {s.rec} ({args.frames} frames) and the good outputs in {time.monotonic() - t0:.0f} s",
          flush=True)
    cases = [c for c in input_cases() if not args.only or args.only in c.name]
    with ThreadPoolExecutor(args.jobs) as pool:
        done = list(pool.map(lambda ic: run_case(s, *ic), enumerate(cases)))
    counts = {k: sum(c.outcome == k for c in done) for k in ORDER}
    tried = len(done) - counts["not applicable"]
    print(f"\ninput cases ({len(done)} made, {tried} tried, {sum(c.seconds for c in done):.0f} s of runs):")
    for k in ORDER:
        print(f"  {k:24s} {counts[k]:4d}")
    bad = {"unclear error", "internal error", "traceback", "silent wrong result", "output replaced", "not applicable",
           "noted on stdout only"}
    for c in done:
        if args.verbose or c.outcome in bad:
            print(f"  - [{c.outcome}] {c.command} / {c.name}: {c.detail}")
    if args.kills:
        k = kill_trials(s, args.kills, args.seed)
        print("\nkill trials (track, SIGKILL at a seeded moment of its run): "
              + ", ".join(f"{n} {v}" for n, v in k.items()))
    if args.races:
        r = race_trials(s, args.races)
        print("race trials (two track runs on one --out): " + ", ".join(f"{n} {v}" for n, v in r.items()))
    if args.classes != "none":
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from fault_classes import run_all

        print("\nfault classes (tools/fault_classes.py):")
        run_all(args.egograph, work / "classes", args.classes, args.jobs, args.verbose)
    print(f"\ntotal {time.monotonic() - t0:.0f} s; work folder {work}" + ("" if args.keep else " (removed)"))
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
