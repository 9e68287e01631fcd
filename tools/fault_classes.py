"""The fault classes of issue 40 through the installed ``egograph`` command: outputs that would
destroy data, inputs of another recording, input checks, faults of the machine, signals. Each
case runs in a fresh folder holding two small recordings (A, B), earlier good outputs of A
(results, observations, plots, an eval JSON) and of B; every file there before the run must be
byte-identical after it unless the case expects a new output, and nothing may be left beside
(no lock, no temporary).

    .venv/bin/python tools/fault_classes.py [--work DIR] [--keep] [--set first|second|all] [--verbose]

Used by ``tools/fuzz_cli.py --classes``. Outcome of a case:

- as expected: the exit code the case expects (2 for a refusal, 0 for a warning or a run that may
  go on, 130/143/129 for signals, 141 for a broken pipe), one ``egograph: error:`` line naming
  the cause (or the expected warning), everything that was there byte-identical, nothing left;
- silent wrong: exit 0 without the expected refusal or warning;
- output lost: a file that was there before changed or disappeared (not an expected output);
- internal error: exit 1 (or a traceback);
- left behind: a lock, temporary or other new file beside the outputs after a refused run;
- unclear: the expected exit code but not one line naming the cause, or another exit code.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

DEFAULT_EGOGRAPH = Path(sys.executable).with_name("egograph")
REFUSE, WARN, OK = "refuse", "warn", "ok"


@dataclass
class Case:
    cls: str
    name: str
    argv: list[str] | Callable[[Path], list[str]]
    expect: str = REFUSE          # refuse | warn | ok | a number (exit code of a signal)
    words: tuple[str, ...] = ()   # what the one line must contain (any of them, case-insensitive)
    prep: Callable[[Path], None] | None = None
    changes: tuple[str, ...] = ()  # paths (relative) that may change (the expected output)
    stdout: str | None = None     # "closed" | "full" | "pipe"
    send: tuple[int, str] | None = None  # (signal, when: "lock" | "import")
    set: str = "first"
    outcome: str = ""
    detail: str = ""


# --------------------------------------------------------------------------- the base


def sh(egograph: Path, cwd: Path, *argv: str) -> None:
    r = subprocess.run([str(egograph), *argv], cwd=cwd, capture_output=True, text=True)
    assert r.returncode == 0, (argv, r.stderr)


def prepare(egograph: Path, base: Path) -> None:
    """Two recordings and good outputs (relative paths: the runs happen inside the case folder)."""
    base.mkdir(parents=True)
    for name, seed in (("recA", 7), ("recB", 8)):
        sh(egograph, base, "synth", name, "--config", "synth/tiny", "--frames", "40", "--seed", str(seed),
           "--set", "pv.rgb=false", "--quiet")
    for r in ("A", "B"):
        sh(egograph, base, "lift", f"rec{r}", "--detections", "svoe", "--quiet", "--out", f"obs{r}.npz")
        sh(egograph, base, "track", f"rec{r}", "--tracker", "graph", "--quiet", "--out", f"res{r}")
    sh(egograph, base, "eval", "recA", "resA", "--json", "evalA.json")
    sh(egograph, base, "plot", "recA", "resA", "--out", "plotsA")
    (base / "mine").mkdir()
    (base / "mine" / "thesis.txt").write_text("a folder egograph did not make\n")
    (base / "notes.txt").write_text("a file of the user\n")


def tree(path: Path) -> dict[str, bytes | str]:
    """Every entry under ``path`` (links as their target, never followed)."""
    out = {}
    for root, dirs, files in os.walk(path):
        for n in dirs + files:
            p = Path(root) / n
            rel = str(p.relative_to(path))
            if p.is_symlink():
                out[rel] = "-> " + os.readlink(p)
            elif p.is_file():
                out[rel] = p.read_bytes()
            elif p.is_dir():
                out[rel] = "dir"
            else:
                out[rel] = "special"
    return out


# --------------------------------------------------------------------------- the cases


def _write(rel: str, text: str):
    def prep(d: Path) -> None:
        p = d / rel
        p.unlink(missing_ok=True)
        p.write_text(text)
    return prep


def _edit(rel: str, edit: Callable[[str], str]):
    def prep(d: Path) -> None:
        p = d / rel
        text = edit(p.read_text())
        p.unlink()
        p.write_text(text)
    return prep


def _symlink(rel: str, target: str):
    def prep(d: Path) -> None:
        os.symlink(target, d / rel)
    return prep


def _dup_key(text: str) -> str:
    """pv_pose.json with its first key given twice (the first copy zeroed)."""
    body = text.strip()[1:]
    key = body.split(":", 1)[0]
    return "{" + key + ": " + "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]], " + body


def _frame_numbers(text: str) -> str:
    import json

    d = json.loads(text)
    return json.dumps({str(i): d[k] for i, k in enumerate(sorted(d, key=int))})


def _unwrapped_4mm(d: Path) -> None:
    """recA's depth in 4 mm units that never wrap (the mesh's ranges along every AHAT ray)."""
    import cv2
    import numpy as np
    import open3d as o3d

    from egograph.geometry.hl2ss import ahat_to_world_matrix, ahat_unit_rays
    from egograph.io.recording import Recording

    rec = Recording.open(d / "recA", depth_factor=4.0)
    rays = ahat_unit_rays(rec.ahat.uv2xy).astype(np.float32).reshape(-1, 3)
    scene = rec.mesh_scene()
    for i in range(len(rec)):
        p = rec.depth_path(i)
        if not p.is_file() or not rec.depth_valid[i]:
            continue
        raw = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        m = ahat_to_world_matrix(rec.ahat.extrinsics, rec.depth_poses[i])
        r = np.empty((len(rays), 6), np.float32)
        r[:, :3] = m[3, :3]
        r[:, 3:] = rays @ m[:3, :3].astype(np.float32)
        t = scene.cast_rays(o3d.core.Tensor(r))["t_hit"].numpy().reshape(raw.shape)
        p.unlink()
        cv2.imwrite(str(p), np.where((raw > 0) & np.isfinite(t), np.rint(t * 250), 0).astype(np.uint16))


def _repeat_lines(d: Path) -> None:
    det = d / "recA" / "detections" / "tiny_seq" / "svoe"
    f = next(p for p in sorted(det.glob("*.txt")) if p.read_text().strip())
    line = f.read_text().splitlines()[0]
    text = f.read_text() + (line + "\n") * 5
    f.unlink()
    f.write_text(text)


def _empty_results(d: Path) -> None:
    (d / "empty").mkdir()


def _ro_mount(d: Path) -> None:
    (d / "ro").mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(d / "ro")], check=True)


def _full_mount(d: Path) -> None:
    (d / "full").mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(d / "full")], check=True)


def _mount_point(d: Path) -> None:
    (d / "mnt").mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(d / "mnt")], check=True)
    (d / "mnt" / "egograph.json").write_text('{"step": "track", "fingerprint": "0"}\n')


def _umount_all(d: Path) -> None:
    for name in ("ro", "full", "mnt"):
        if os.path.ismount(d / name):
            subprocess.run(["umount", str(d / name)], check=False)


BOMB = ('a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n'
        'b: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a]\nc: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b]\n'
        'd: &d [*c,*c,*c,*c,*c,*c,*c,*c,*c]\ne: &e [*d,*d,*d,*d,*d,*d,*d,*d,*d]\n'
        'f: &f [*e,*e,*e,*e,*e,*e,*e,*e,*e]\ng: &g [*f,*f,*f,*f,*f,*f,*f,*f,*f]\n'
        'h: &h [*g,*g,*g,*g,*g,*g,*g,*g,*g]\ni: &i [*h,*h,*h,*h,*h,*h,*h,*h,*h]\n')

TRACK = ["track", "recA", "--tracker", "memory", "--quiet"]
LONG = "x" * 300


def cases() -> list[Case]:
    c = [
        # 1. output policy
        Case("output", "track --out the recording", TRACK + ["--out", "recA"], words=("input",)),
        Case("output", "lift --out a file inside the recording",
             ["lift", "recA", "--detections", "svoe", "--quiet", "--out", "recA/tiny_seq/pv_pose.json"],
             words=("input",)),
        Case("output", "plot --out the results", ["plot", "recA", "resA", "--out", "resA"], words=("input",)),
        Case("output", "export --out the results", ["export", "recA", "resA", "--out", "resA"], words=("input",)),
        Case("output", "track --out an existing file", TRACK + ["--out", "notes.txt"], words=("file",)),
        Case("output", "eval --json a link to a device", ["eval", "recA", "resA", "--json", "dev.json"],
             prep=_symlink("dev.json", "/dev/null"), words=("link", "special")),
        Case("output", "plot of an empty results folder over good plots",
             ["plot", "recA", "empty", "--out", "plotsA"], prep=_empty_results, words=("empty", "no result")),
        Case("output", "track --out a folder egograph did not make", TRACK + ["--out", "mine"],
             words=("did not make", "not an egograph")),
        Case("output", "lift --out an existing folder",
             ["lift", "recA", "--detections", "svoe", "--quiet", "--out", "resA"], words=("folder",)),
        Case("output", "track --out the folder holding the recording", TRACK + ["--out", "."], words=("input",)),
        Case("output", "eval --json a file inside the recording",
             ["eval", "recA", "resA", "--json", "recA/recording.json"], words=("input",)),
        # 2. inputs of another recording
        Case("provenance", "eval on another recording's results", ["eval", "recA", "resB"], words=("recording",)),
        Case("provenance", "smooth on another recording's results",
             ["smooth", "recA", "resB", "--quiet", "--out", "sm"], words=("recording",)),
        Case("provenance", "track --observations of another recording",
             TRACK + ["--observations", "obsB.npz", "--out", "resN"], words=("recording",)),
        Case("provenance", "plot of another recording's results", ["plot", "recA", "resB", "--out", "plN"],
             words=("recording",)),
        # 3. input checks
        Case("input", "duplicate key in pv_pose.json", ["info", "recA"],
             prep=_edit("recA/tiny_seq/pv_pose.json", _dup_key), words=("twice",)),
        Case("input", "frame numbers for timestamps", ["info", "recA"],
             prep=_edit("recA/tiny_seq/pv_pose.json", _frame_numbers), words=("tick", "timestamp")),
        Case("input", "identical detection lines repeated", TRACK + ["--out", "resN"], expect=WARN,
             prep=_repeat_lines, words=("repeated", "identical"), changes=("resN",)),
        Case("input", "covariance_floor_m .inf",
             TRACK + ["--out", "resN", "--set", "graph.covariance_floor_m=.inf"], words=("covariance_floor_m",)),
        Case("input", "max_iterations 1e29", TRACK + ["--out", "resN", "--set", "graph.max_iterations=1e29"],
             words=("max_iterations",)),
        Case("input", "--lag inf", ["track", "recA", "--tracker", "graph-causal", "--lag", "inf", "--quiet",
                                    "--out", "resN"], words=("lag",)),
        Case("input", "467-byte YAML alias bomb", TRACK + ["--out", "resN", "--config", "bomb.yaml"],
             prep=_write("bomb.yaml", BOMB), words=("alias",)),
        Case("input", "AHAT extrinsics in another axis convention, reference lift",
             ["lift", "recA", "--detections", "svoe", "--lift", "reference", "--quiet", "--out", "obsN.npz"],
             prep=lambda d: _replace_bytes(d / "recA/calibrations/rm_depth_ahat/extrinsics.bin", _turned()),
             words=("behind", "axis")),
        Case("input", "4 mm depth that never wraps", ["lift", "recA", "--detections", "svoe", "--lift", "reference",
                                                      "--quiet", "--out", "obsN.npz"], expect=WARN,
             prep=_unwrapped_4mm, words=("4 mm",), changes=("obsN.npz",)),
        # 4. the machine
        Case("machine", "output on a read-only filesystem", TRACK + ["--out", "ro/res"], prep=_ro_mount,
             words=("read-only",)),
        Case("machine", "disk full", ["track", "recA", "--tracker", "graph", "--quiet", "--out", "full/res"],
             prep=_full_mount, words=("no space",)),
        Case("machine", "output is a mount point", TRACK + ["--out", "mnt"], prep=_mount_point,
             words=("mount point",)),
        Case("machine", "output name too long", TRACK + ["--out", LONG], words=("too long",)),
        Case("machine", "stdout closed", ["info", "recA"], stdout="closed", words=("standard output",)),
        Case("machine", "stdout full", ["info", "recA"], stdout="full", words=("standard output",)),
        Case("machine", "stdout a closed pipe", ["info", "recA"], stdout="pipe", expect="141"),
        Case("machine", "SIGTERM while tracking", ["track", "recA", "--tracker", "graph", "--quiet", "--out",
                                                   "resA", "--overwrite"], expect="143", send=(signal.SIGTERM, "lock")),
        Case("machine", "SIGHUP while tracking", ["track", "recA", "--tracker", "graph", "--quiet", "--out",
                                                  "resA", "--overwrite"], expect="129", send=(signal.SIGHUP, "lock")),
        Case("machine", "SIGINT while importing", ["track", "recA", "--tracker", "graph", "--quiet", "--out",
                                                   "resA", "--overwrite"], expect="130", send=(signal.SIGINT, "import")),
    ]
    c += [
        # the second set: fault kinds beyond the list
        Case("second", "--out whose folder is a file", TRACK + ["--out", "notes.txt/res"], words=("not a folder",)),
        Case("second", "--out a link to a folder", TRACK + ["--out", "lnk"], prep=_symlink("lnk", "resA"),
             words=("link",)),
        Case("second", "eval --json a FIFO", ["eval", "recA", "resA", "--json", "fifo"],
             prep=lambda d: os.mkfifo(d / "fifo"), words=("special",)),
        Case("second", "smooth --out its input results", ["smooth", "recA", "resA", "--quiet", "--out", "resA"],
             words=("input",)),
        Case("second", "compare --out one of the results", ["compare", "recA", "resA", "resB", "--out", "resB"],
             words=("input",)),
        Case("second", "track --intervals into the input results",
             TRACK + ["--observations", "obsA.npz", "--out", "resN", "--intervals", "resA/intervals.json"],
             words=("inside",)),
        Case("second", "eval --json the config file", ["eval", "recA", "resA", "--config", "c.yaml", "--json",
                                                       "c.yaml"], prep=_write("c.yaml", "{}\n"), words=("input",)),
        Case("second", "lift --out an observations file of another step", ["lift", "recA", "--detections", "svoe",
                                                                          "--quiet", "--out", "notes.npz"],
             prep=_write("notes.npz", "not a zip\n"), words=("egograph",)),
        Case("second", "track --out a plots folder", TRACK + ["--out", "plotsA"], words=("plot",)),
        Case("second", "covariance_floor_m NaN", TRACK + ["--out", "resN", "--set", "graph.covariance_floor_m=nan"],
             words=("covariance_floor_m",)),
        Case("second", "--lag -1", ["track", "recA", "--tracker", "graph-causal", "--lag", "-1", "--quiet",
                                    "--out", "resN"], words=("lag",)),
        Case("second", "eval on results of another sequence name", ["eval", "recA", "resX"],
             prep=lambda d: _renamed_results(d), words=("recording", "sequence")),
        Case("second", "config file is a folder", TRACK + ["--out", "resN", "--config", "resA"], words=("resA",)),
        Case("second", "an output name with a newline", TRACK + ["--out", "a\nb"], expect=OK, changes=("a\nb",)),
    ]
    for k in c[-14:]:
        k.set = "second"
    return c


def _replace_bytes(p: Path, data: bytes) -> None:
    p.unlink()
    p.write_bytes(data)


def _turned() -> bytes:
    import numpy as np

    return np.diag([-1.0, 1.0, -1.0, 1.0]).astype("<f4").tobytes()  # turned 180 degrees about y


def _renamed_results(d: Path) -> None:
    import json

    shutil.copytree(d / "resA", d / "resX", copy_function=shutil.copy2)
    p = d / "resX" / "egograph.json"
    rec = json.loads(p.read_text())
    rec["inputs"]["recording"]["sequence"] = "other_seq"
    p.write_text(json.dumps(rec, indent=1))


# --------------------------------------------------------------------------- one case


def run_case(egograph: Path, base: Path, work: Path, i: int, case: Case) -> Case:
    d = work / f"{i:03d}"
    shutil.copytree(base, d, symlinks=True)
    try:
        if case.prep:
            case.prep(d)
        before = tree(d)
        code, err, seconds = _run(egograph, d, case)
        after = tree(d)
        case.outcome, case.detail = classify(case, code, err, before, after)
    finally:
        _umount_all(d)
    return case


def _run(egograph: Path, d: Path, case: Case):
    env = dict(os.environ, COLUMNS="400")
    argv = [str(egograph), *(case.argv(d) if callable(case.argv) else case.argv)]
    t0 = time.monotonic()
    if case.stdout == "closed":
        p = subprocess.run(argv, cwd=d, stdout=None, stderr=subprocess.PIPE, text=True, env=env,
                           preexec_fn=lambda: os.close(1))
        return p.returncode, p.stderr, time.monotonic() - t0
    if case.stdout == "full":
        with open("/dev/full", "w") as full:
            p = subprocess.run(argv, cwd=d, stdout=full, stderr=subprocess.PIPE, text=True, env=env)
        return p.returncode, p.stderr, time.monotonic() - t0
    if case.stdout == "pipe":
        r, w = os.pipe()
        os.close(r)  # the reader is gone before the first line
        p = subprocess.run(argv, cwd=d, stdout=w, stderr=subprocess.PIPE, text=True, env=env)
        os.close(w)
        return p.returncode, p.stderr, time.monotonic() - t0
    if case.send:
        sig, when = case.send
        # A shell without job control starts background commands with SIGINT ignored, and the
        # ignore is inherited: give the run the default disposition, as a terminal would.
        p = subprocess.Popen(argv, cwd=d, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        if when == "lock":  # the run holds its output's lock: it is past its imports, at work
            while p.poll() is None and not any(d.glob(".*.lock")):
                time.sleep(0.005)
            time.sleep(0.5)
        else:
            time.sleep(0.25)
        p.send_signal(sig)
        _, err = p.communicate()
        return p.returncode, err, time.monotonic() - t0
    p = subprocess.run(argv, cwd=d, capture_output=True, text=True, env=env)
    return p.returncode, p.stderr, time.monotonic() - t0


def classify(case: Case, code: int, err: str, before: dict, after: dict) -> tuple[str, str]:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("egograph: error:")]
    warned = [ln for ln in lines if ln.startswith("egograph: warning:")]
    first = (errors or lines or [""])[0][:240]
    changed = [k for k, v in before.items() if after.get(k) != v and not _expected(k, case)]
    new = [k for k in after if k not in before and not _expected(k, case)]
    if "Traceback" in err or code == 1 or code < 0:
        return "internal error", f"exit {code}: {first}"
    if changed:
        return "output lost", f"exit {code}: {', '.join(changed[:3])} changed ({first})"
    named = lambda ln: any(w.lower() in ln.lower() for w in case.words) if case.words else True  # noqa: E731
    if case.expect == REFUSE:
        if code == 0:
            return "silent wrong", f"exit 0; {warned[0][:200] if warned else 'no warning'}"
        if new:
            return "left behind", ", ".join(new[:3])
        if code == 2 and len(errors) == 1 and len(lines) - len(warned) == 1 and named(errors[0]) \
                and len(errors[0]) <= 400:
            return "as expected", errors[0][:200]
        return "unclear", f"exit {code}: {' | '.join(lines)[:240]}"
    if case.expect == WARN:
        if code == 0 and any(named(w) for w in warned):
            return "as expected", next(w for w in warned if named(w))[:200]
        if code == 0:
            return "silent wrong", "no warning"
        return "unclear", f"exit {code}: {first}"
    if case.expect == OK:
        return ("as expected", "") if code == 0 else ("unclear", f"exit {code}: {first}")
    want = int(case.expect)
    if new:
        return "left behind", ", ".join(new[:3])
    if code == want and (want == 141 and not errors or want != 141):
        return "as expected", f"exit {code}"
    if code == 0:
        return "silent wrong", "exit 0: the run went on"
    return "unclear", f"exit {code} (want {want}): {first}"


def _expected(rel: str, case: Case) -> bool:
    return any(rel == c or rel.startswith(c + "/") for c in case.changes)


ORDER = ["as expected", "silent wrong", "output lost", "internal error", "left behind", "unclear"]


def run_all(egograph: Path, work: Path, which: str = "all", jobs: int = 2, verbose: bool = False,
            only: str | None = None) -> dict:
    base = work / "base"
    t0 = time.monotonic()
    prepare(egograph, base)
    print(f"prepared the base in {time.monotonic() - t0:.0f} s", flush=True)
    todo = [k for k in cases() if which in ("all", k.set) and (not only or only in k.name)]
    with ThreadPoolExecutor(jobs) as pool:
        done = list(pool.map(lambda ic: run_case(egograph, base, work / "cases", *ic), enumerate(todo)))
    table = {}
    for s in ("first", "second"):
        sub = [k for k in done if k.set == s]
        if not sub:
            continue
        counts = {o: sum(k.outcome == o for k in sub) for o in ORDER}
        table[s] = counts
        print(f"\n{s} set ({len(sub)} cases): " + ", ".join(f"{o} {n}" for o, n in counts.items()))
        for k in sub:
            if verbose or k.outcome != "as expected":
                print(f"  - [{k.outcome}] {k.cls} / {k.name}: {k.detail}")
    return table


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--egograph", type=Path, default=DEFAULT_EGOGRAPH)
    ap.add_argument("--work", type=Path)
    ap.add_argument("--keep", action="store_true")
    ap.add_argument("--set", dest="which", choices=("first", "second", "all"), default="all")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--verbose", action="store_true")
    ap.add_argument("--only", help="only the cases whose name contains this")
    args = ap.parse_args(argv)
    work = args.work or Path(tempfile.mkdtemp(prefix="egograph-classes-"))
    try:
        run_all(args.egograph, work, args.which, args.jobs, args.verbose, args.only)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
