"""Killed runs: ``egograph track`` and ``egograph refine`` killed (SIGKILL) at moments spread over
their measured run time and over their measured write, each time over an older output, leave
either the whole old output or the whole new one; the next run succeeds and cleans up.

Each killed run is a fresh interpreter. Most of a fresh run is importing Open3D and GTSAM, and a
kill there touches nothing, so the clock of a killed run starts once its interpreter has imported
them (a worker that imports, says so, and waits for its go); the next worker is started, and
imports, while the last kill is checked. 10 kills per command, 20 in all; the following run of
each kill runs in this process (another pid, imports warm)."""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from egograph.cli import main

pytestmark = [pytest.mark.slow, pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs SIGKILL")]

WORKER = """
import os, sys
from egograph.cli import main
import egograph.cli.poses, egograph.steps.lift, egograph.steps.refine, egograph.steps.track
import egograph.poses.refine, egograph.track.graph, gtsam, open3d  # what a run imports, before its clock starts
print("ready", flush=True)
sys.stdin.readline()
sys.stdout = open(os.devnull, "w")
sys.exit(main(sys.argv[1:]))
"""
OVER_RUN = 5
"""Kills per command at delays spread over the whole run (most land before the write)."""
OVER_WRITE = 5
"""Kills per command while its temporary folder exists: at offsets spread over the building of the
new folder, and two after the swap (while the swapped-out old folder is removed)."""
POLL_S = 0.0003


@dataclass
class Job:
    """A command run over an older output of the same command (another configuration)."""
    out: Path
    new: list[str]
    old: list[str]
    old_copy: Path
    old_state: dict = field(default_factory=dict)
    new_state: dict = field(default_factory=dict)
    outcomes: list[str] = field(default_factory=list)
    spare: subprocess.Popen | None = None
    """The next worker, importing while the last kill is checked."""


def start(job: Job) -> subprocess.Popen:
    """A run of ``job.new`` in a fresh interpreter whose clock starts now: the worker started
    before (or one started here) has done its imports and is told to go."""
    if job.spare is None:
        prepare_next(job)
    proc, job.spare = job.spare, None
    assert proc.stdout.readline() == "ready\n", proc.communicate()[1]
    proc.stdout.close()  # the worker prints the run's output to /dev/null
    proc.stdin.write("go\n")
    proc.stdin.close()
    return proc


def prepare_next(job: Job) -> None:
    job.spare = subprocess.Popen([sys.executable, "-c", WORKER, *job.new], stdin=subprocess.PIPE,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def stop_spare(job: Job) -> None:
    if job.spare is not None:
        job.spare.kill()
        job.spare.wait()
        job.spare = None


def run_here(argv: list[str]) -> None:
    """Run the CLI in this process (quiet): a following run, cheap once the imports are warm."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
        assert main(argv) == 0, err.getvalue()


def without_timings(body):
    """A JSON value minus the wall-clock timings refine's report holds."""
    if isinstance(body, dict):
        return {k: without_timings(v) for k, v in body.items() if k not in ("stage_seconds", "seconds")}
    if isinstance(body, list):
        return [without_timings(v) for v in body]
    return body


def snapshot(folder: Path) -> dict:
    """Every entry of an output folder, hidden ones too, with its content; minus what differs from
    run to run of the same configuration: the command line and refine's stage timings."""
    state = {}
    for p in sorted(folder.iterdir()):
        assert p.is_file(), p
        data = p.read_bytes()
        if p.name in ("egograph.json", "report.json"):
            body = without_timings(json.loads(data))
            body.pop("command", None)
            state[p.name] = body
        elif p.name == "report.md":
            state[p.name] = re.sub(rb"(?m)^(\| \w+ \|) [0-9]+\.[0-9]+ \|$", rb"\1 - |", data)
        else:
            state[p.name] = data
    return state


def reset(job: Job) -> None:
    shutil.rmtree(job.out)
    shutil.copytree(job.old_copy, job.out)


def own_temporary(proc: subprocess.Popen, out: Path) -> bool:
    prefix = f".{out.name}.{proc.pid}."
    return any(n.startswith(prefix) for n in os.listdir(out.parent))


def swapped(out: Path, before: int) -> bool:
    """Whether the folder at ``out`` is no longer the one with inode ``before``."""
    with contextlib.suppress(FileNotFoundError):
        return os.stat(out).st_ino != before
    return False


def wait_until(proc: subprocess.Popen, event, timeout: float = 300.0) -> bool:
    """Poll until ``event()`` (True) or the run's end (False)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if event():
            return True
        if proc.poll() is not None:
            return False
        time.sleep(POLL_S)
    raise AssertionError("the run neither wrote nor ended")


def measure(job: Job) -> tuple[float, float, float]:
    """One complete new run in a fresh process: its duration, and how long its temporary existed
    before and after the swap (building the new folder; removing the swapped-out old one), s."""
    before = os.stat(job.out).st_ino
    proc = start(job)
    t0 = time.monotonic()
    assert wait_until(proc, lambda: own_temporary(proc, job.out))
    seen = time.monotonic()
    assert wait_until(proc, lambda: swapped(job.out, before))
    swap = time.monotonic()
    wait_until(proc, lambda: not own_temporary(proc, job.out))
    gone = time.monotonic()
    err = proc.stderr.read()
    proc.wait(timeout=300)
    assert proc.returncode == 0, err
    return time.monotonic() - t0, swap - seen, gone - swap


def kill_once(job: Job, moment: str, delay: float, event: str | None = None) -> str:
    """Kill a new run ``delay`` s after its start (imports done), or after ``event`` (its temporary appeared; the
    swap); check what it left and that a following run succeeds and leaves nothing else."""
    reset(job)
    before = os.stat(job.out).st_ino
    proc = start(job)
    happened = {None: lambda: False, "temporary": lambda: own_temporary(proc, job.out),
                "swap": lambda: swapped(job.out, before)}[event]
    if event is None or wait_until(proc, happened):
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=delay)
    killed = proc.poll() is None
    if killed:
        proc.send_signal(signal.SIGKILL)
    proc.wait()  # reaped: its pid is no longer alive
    proc.stderr.close()
    prepare_next(job)  # imports while this kill is checked
    assert killed or proc.returncode == 0
    assert job.out.is_dir(), f"killed {moment}: no output left at all"
    state = snapshot(job.out)
    assert state in (job.old_state, job.new_state), f"killed {moment}: a mixed or partial output"
    outcome = ("old" if state == job.old_state else "new") if killed else "finished"
    leftovers = sorted(n for n in os.listdir(job.out.parent) if n != job.out.name)
    if any(n.endswith(".tmp") for n in leftovers):
        outcome += "+tmp"
    run_here(job.new + ["--overwrite"])
    assert snapshot(job.out) == job.new_state
    assert os.listdir(job.out.parent) == [job.out.name], f"killed {moment}: left {leftovers}"
    job.outcomes.append(outcome)
    return outcome


def kill_everywhere(job: Job, name: str) -> None:
    run_here(job.old)
    job.old_state = snapshot(job.out)
    shutil.copytree(job.out, job.old_copy)
    try:
        kills(job, name)
    finally:
        stop_spare(job)


def kills(job: Job, name: str) -> None:
    duration, build, cleanup = measure(job)
    job.new_state = snapshot(job.out)
    assert job.new_state != job.old_state
    for i in range(OVER_RUN):
        delay = duration * (i + 0.5) / OVER_RUN
        kill_once(job, f"{delay:.2f} s after the start", delay)
    for i in range(OVER_WRITE - 2):
        delay = build * i / (OVER_WRITE - 2)
        kill_once(job, f"{delay * 1000:.1f} ms into the write", delay, "temporary")
    for delay in (0.0, cleanup / 2):
        kill_once(job, f"{delay * 1000:.1f} ms after the swap", delay, "swap")
    counts = {k: job.outcomes.count(k) for k in sorted(set(job.outcomes))}
    print(f"\n{name}: run {duration:.2f} s after the imports, write {build * 1000:.1f} ms + {cleanup * 1000:.1f} ms removing "
          f"the old; {len(job.outcomes)} kills: {counts}")
    assert any(o.endswith("+tmp") for o in job.outcomes), "no kill landed in the write"


@pytest.fixture(scope="module")
def observations(tiny_rec, tmp_path_factory) -> Path:
    obs = tmp_path_factory.mktemp("kill_obs") / "obs.npz"
    run_here(["lift", str(tiny_rec), "--detections", "mvpe", "--out", str(obs), "--quiet"])
    return obs


def test_a_killed_track_leaves_the_old_or_the_new_results(tiny_rec, observations, tmp_path):
    out = tmp_path / "out" / "RESULTS"
    new = ["track", str(tiny_rec), "--tracker", "graph", "--observations", str(observations), "--out", str(out),
           "--quiet"]
    kill_everywhere(Job(out, new, new + ["--set", "graph.covariance_floor_m=0.05"], tmp_path / "old"), "track")


def test_a_killed_refine_leaves_the_old_or_the_new_poses(tiny_rec, tmp_path):
    out = tmp_path / "out" / "REFINED"
    new = ["refine", str(tiny_rec), "--out", str(out), "--quiet", "--set", "refine.mesh=false"]
    kill_everywhere(Job(out, new, new + ["--set", "refine.drift_trans=0.004"], tmp_path / "old"), "refine")
