#!/usr/bin/env python
"""Benchmark ``egograph run``: the same dataset with 2 local Dask workers against 1.

    .venv/bin/python tools/bench_run.py                       # 4 sequences x 3000 frames
    .venv/bin/python tools/bench_run.py --sequences 4 --frames 300 --trackers memory,kf,graph
    .venv/bin/python tools/bench_run.py --kill-after 0.5          # also: SIGKILL the whole run half way, re-run

Generates N synthetic sequences (``synth/svoe``, seeds 1..N, depth only; kept in ``--workdir``
and not generated again), then runs ``egograph run`` on them once with ``--workers 1`` and once
with ``--workers 2``, each into a fresh RUNS folder (nothing reused), and prints the wall time of
each, their ratio, the sum of the tasks' own wall and CPU seconds (``run.json``; CPU above wall
means a task used more than one core), the sum of task seconds over the wall time (how many
workers were busy on average), and whether both summaries are the same bytes.

With ``--kill-after F`` a third run (2 workers) is killed with SIGKILL, process group and all
(scheduler, workers, nanny), after F times the 2-worker wall time, then run again with the same
command: the tool prints how many finished step outputs the second run did again (a cache folder
whose inode or mtime changed: must be 0), and whether its summary equals the uninterrupted run's.

What limits the ratio on a 2-core machine: two single-threaded workers are at most 2x one, less
the time the cluster takes to start and each worker process to import GTSAM and Open3D, the tail
where one worker has nothing left to run (few, long tasks: a sequence's lift is the longest, and
its tracks wait for it), and threads beyond Dask's one per worker: Open3D (ray casting against the
mesh in the lift and the graph's negative evidence) runs on TBB, which uses every core whatever
OMP_NUM_THREADS says (Dask sets that and the BLAS ones to 1 in its workers), so one worker already
uses more than one core part of the time; GTSAM's wheel here is built without TBB (one thread).
Memory: each worker holds one sequence's observations and depth evidence, a few hundred MB at 3000
frames; 2 workers need twice that.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import benchdoc

import egograph

PACKAGE_ROOT = Path(egograph.__file__).resolve().parents[1]
RUN = "import sys; from egograph.cli.main import main; sys.exit(main(sys.argv[1:]))"


def make_dataset(root: Path, n: int, frames: int, config: str) -> Path:
    from egograph.core.config import load_config
    from egograph.core.resources import config_argument
    from egograph.steps.synth import synth
    from egograph.synth.config import SynthConfig

    ds = root / f"dataset-{n}x{frames}"
    for seed in range(1, n + 1):
        cfg = load_config(SynthConfig, config_argument(config), [f"frames={frames}", "pv.rgb=false"])
        t = time.perf_counter()
        r = synth(ds / f"seq{seed:02d}", cfg, seed=seed, progress=False)
        if r is not None:
            print(f"generated seq{seed:02d} ({frames} frames) in {time.perf_counter() - t:.0f} s", flush=True)
    return ds


def run(ds: Path, runs: Path, workers: int, stages: str, trackers: str) -> tuple[float, dict]:
    shutil.rmtree(runs, ignore_errors=True)
    cmd, env = _command(ds, runs, workers, stages, trackers)
    t = time.perf_counter()
    p = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if p.returncode != 0:
        sys.exit(f"egograph run --workers {workers} exited {p.returncode}:\n{p.stdout[-2000:]}\n{p.stderr[-2000:]}")
    tasks = json.loads((runs / "latest" / "run.json").read_text())["tasks"]
    return wall, {"task_seconds": sum(t["seconds"] or 0 for t in tasks.values()),
                  "task_cpu": sum(t.get("cpu_seconds") or 0 for t in tasks.values()),
                  "summary": (runs / "latest" / "summary.json").read_bytes()}


def _command(ds: Path, runs: Path, workers: int, stages: str, trackers: str) -> tuple[list[str], dict]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(PACKAGE_ROOT), os.environ.get("PYTHONPATH", "")])}
    return [sys.executable, "-c", RUN, "run", str(ds), "--out", str(runs), "--workers", str(workers),
            "--stages", stages, "--trackers", trackers, "--quiet"], env


def _cache_stamps(runs: Path) -> dict[str, tuple[int, int]]:
    """Finished step outputs (``RUNS/cache/<seq>/<stage>-<key>``, folders and ``.npz`` files) -> (inode, mtime ns)."""
    out = {}
    for p in sorted((runs / "cache").glob("*/*")):
        if not p.name.startswith("."):
            st = p.stat()
            out[str(p.relative_to(runs))] = (st.st_ino, st.st_mtime_ns)
    return out


def kill_and_resume(ds: Path, runs: Path, after_s: float, stages: str, trackers: str) -> dict:
    """Run with 2 workers, SIGKILL the whole process group after ``after_s`` seconds, run again."""
    import signal

    shutil.rmtree(runs, ignore_errors=True)
    cmd, env = _command(ds, runs, 2, stages, trackers)
    p = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        p.wait(timeout=after_s)
        finished_early = True
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
        finished_early = False
    time.sleep(1.0)  # let the killed workers' processes go
    before = _cache_stamps(runs)
    t = time.perf_counter()
    q = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if q.returncode != 0:
        sys.exit(f"egograph run after the kill exited {q.returncode}:\n{q.stdout[-2000:]}\n{q.stderr[-2000:]}")
    after = _cache_stamps(runs)
    redone = [k for k, v in before.items() if after.get(k) != v]
    return {"finished_before_kill": finished_early, "steps_done_before_kill": len(before), "steps_in_all": len(after),
            "redone": redone, "resume_wall": wall, "summary": (runs / "latest" / "summary.json").read_bytes()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sequences", type=int, default=4)
    ap.add_argument("--frames", type=int, default=3000, help="frames per sequence (default 3000)")
    ap.add_argument("--config", default="synth/svoe", help="synthetic-recording config (default synth/svoe)")
    ap.add_argument("--stages", default="lift,track,eval")
    ap.add_argument("--trackers", default="memory,kf,graph")
    ap.add_argument("--workdir", type=Path, help="where the dataset and runs go (default: a temporary folder, "
                                                 "removed at the end)")
    ap.add_argument("--kill-after", type=float, metavar="F",
                    help="also kill a 2-worker run after F x its uninterrupted wall time and run it again")
    benchdoc.add_arguments(ap, __file__)
    args = ap.parse_args()
    benchdoc.start(__file__, args)
    work = args.workdir or Path(tempfile.mkdtemp(prefix="bench_run_"))
    try:
        ds = make_dataset(work, args.sequences, args.frames, args.config)
        rows = {}
        for workers in (1, 2):
            wall, info = run(ds, work / f"runs-w{workers}", workers, args.stages, args.trackers)
            rows[workers] = (wall, info)
            print(f"--workers {workers}: {wall:.1f} s wall", flush=True)
        killed = None
        if args.kill_after is not None:
            killed = kill_and_resume(ds, work / "runs-killed", args.kill_after * rows[2][0], args.stages,
                                     args.trackers)
    finally:
        if args.workdir is None:
            shutil.rmtree(work, ignore_errors=True)
    print()
    benchdoc.table("egograph run: 1 and 2 local Dask workers",
                   ["workers", "wall s", "task s", "task CPU s", "busy workers"],
                   [[workers, wall, info["task_seconds"], info["task_cpu"], info["task_seconds"] / wall]
                    for workers, (wall, info) in rows.items()], ["d", ".1f", ".1f", ".1f", ".2f"],
                   note=f"{args.sequences} sequences x {args.frames} frames, stages {args.stages}, trackers "
                        f"{args.trackers}; {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} at the end.")
    (w1, i1), (w2, i2) = rows[1], rows[2]
    benchdoc.text(f"speed-up 2 workers / 1: {w1 / w2:.2f}x; summaries identical: {i1['summary'] == i2['summary']}")
    if killed is not None:
        k = killed
        benchdoc.text(f"killed after {args.kill_after * w2:.1f} s ({'it had already finished' if k['finished_before_kill'] else 'SIGKILL'}): "
                      f"{k['steps_done_before_kill']}/{k['steps_in_all']} step outputs finished before the kill; "
                      f"re-run {k['resume_wall']:.1f} s; finished steps done again: {len(k['redone'])} {k['redone'][:3]}; "
                      f"summary equals the uninterrupted run's: {k['summary'] == i2['summary']}")
    benchdoc.finish()


if __name__ == "__main__":
    main()
