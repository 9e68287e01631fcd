#!/usr/bin/env python
"""Benchmark ``egograph run``: the same dataset with 2 local Dask workers against 1.

    .venv/bin/python tools/bench_run.py                       # 4 sequences x 3000 frames
    .venv/bin/python tools/bench_run.py --sequences 4 --frames 300 --trackers memory,kf,graph
    .venv/bin/python tools/bench_run.py --kill-after 0.5          # also: SIGKILL the whole run half way, re-run

Generates N synthetic sequences (``synth/svoe``, seeds 1..N, depth only, with PV RGB when
``--stages`` has detect; kept in ``--workdir`` and not generated again), then runs ``egograph
run`` on them with ``--workers 1`` and with ``--workers 2``, alternately, ``--repeat`` times
each, each run into a fresh RUNS folder (nothing reused), and prints the wall time of each, the
throughput, the sum of the tasks' own wall and CPU seconds (``run.json``; CPU above wall means a
task used more than one core), the sum of task seconds over the wall time (how many workers were
busy on average), each worker process's peak resident memory (``run.json``'s
``worker_max_rss_mb``), the bytes written per frame, whether every run's summary is the same
bytes, the speed-up of each round and their median (what the target reads: on a shared machine
one pair of runs moved by 0.1-0.2x from one regeneration to the next), and the first 1-worker
run's wall and CPU time per stage per frame. From those, ``--project R F W`` projects R
recordings of F frames on W workers.

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
Measured per thread at stop 65 (Intel Xeon), one worker's detect task: its own thread 30.2 s of CPU,
the worker's event loop 2.1 s, and 2.4 s in threads gone by the end of the task: detect decodes the
next PV image in a thread of its own while the frame's proposals and encoder run (TBB's threads, which
outlive a task, held under 0.01 s). So one worker takes about 1.1 cores, and two workers on two cores
find no core free for the extra tenth: task time 69 -> 80 s with the same CPU. The VM's two cores
themselves ran two CPU-bound processes 1.96-1.97x one.
Memory: each worker holds one sequence's observations and depth evidence, a few hundred MB at 3000
frames; 2 workers need twice that.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import benchdoc

import egograph

PACKAGE_ROOT = Path(egograph.__file__).resolve().parents[1]
RUN = "import sys; from egograph.cli.main import main; sys.exit(main(sys.argv[1:]))"


def _make_sequence(ds: Path, seed: int, frames: int, config: str, rgb: bool) -> str | None:
    from egograph.core.config import load_config
    from egograph.core.resources import config_argument
    from egograph.steps.synth import synth
    from egograph.synth.config import SynthConfig

    cfg = load_config(SynthConfig, config_argument(config), [f"frames={frames}", f"pv.rgb={str(rgb).lower()}"])
    t = time.perf_counter()
    r = synth(ds / f"seq{seed:02d}", cfg, seed=seed, progress=False)
    return None if r is None else f"generated seq{seed:02d} ({frames} frames) in {time.perf_counter() - t:.0f} s"


def make_dataset(root: Path, n: int, frames: int, config: str, rgb: bool = False, parallel: int = 1) -> Path:
    """Sequences seq01..seqNN (seeds 1..N) under ``root/dataset-NxF[-rgb]``, those already there kept;
    ``parallel`` processes at once (each sequence is one seed's bytes whichever process makes it)."""
    import concurrent.futures
    import contextlib

    ds = root / f"dataset-{n}x{frames}{'-rgb' if rgb else ''}"
    seeds = range(1, n + 1)
    args = ([ds] * n, seeds, [frames] * n, [config] * n, [rgb] * n)
    with contextlib.ExitStack() as stack:
        pool = stack.enter_context(concurrent.futures.ProcessPoolExecutor(parallel)) if parallel > 1 else None
        for msg in (pool.map if pool else map)(_make_sequence, *args):
            if msg:
                print(msg, flush=True)
    return ds


def run(ds: Path, runs: Path, workers: int, stages: str, trackers: str, detections: str) -> tuple[float, dict]:
    shutil.rmtree(runs, ignore_errors=True)
    cmd, env = _command(ds, runs, workers, stages, trackers, detections)
    t = time.perf_counter()
    p = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    run_json = runs / "latest" / "run.json"
    # exit 1 with run.json: some tasks failed (a short sequence with no detection to lift), the rest ran
    if p.returncode not in (0, 1) or not run_json.is_file():
        sys.exit(f"egograph run --workers {workers} exited {p.returncode}:\n{p.stdout[-2000:]}\n{p.stderr[-2000:]}")
    tasks = json.loads(run_json.read_text())["tasks"]
    return wall, {"failed": sorted(k for k, t in tasks.items() if t.get("status") != "ok"),
                  "task_seconds": sum(t["seconds"] or 0 for t in tasks.values()),
                  "task_cpu": sum(t.get("cpu_seconds") or 0 for t in tasks.values()),
                  "tasks": tasks, "bytes": folder_bytes(runs),
                  "summary": (runs / "latest" / "summary.json").read_bytes()}


def folder_bytes(root: Path) -> int:
    """Bytes of every file under ``root`` (links not followed: each output counted once)."""
    return sum(p.lstat().st_size for p in root.rglob("*") if p.is_file() and not p.is_symlink())


def stage_of(key: str) -> str:
    """A task key (``<stage>/<sequence>[/<tracker>]``) -> its stage column (``track/graph``)."""
    parts = key.split("/")
    return parts[0] if len(parts) == 2 else f"{parts[0]}/{parts[2]}"


def per_stage(tasks: dict) -> dict[str, dict]:
    """Stage -> summed wall and CPU seconds of its tasks and their count."""
    out: dict[str, dict] = {}
    for key, t in tasks.items():
        s = out.setdefault(stage_of(key), {"seconds": 0.0, "cpu": 0.0, "n": 0})
        s["seconds"] += t.get("seconds") or 0.0
        s["cpu"] += t.get("cpu_seconds") or 0.0
        s["n"] += 1
    return out


def peak_memory(tasks: dict) -> list[float]:
    """Each worker process's peak resident memory (MB), largest first (run.json's worker_max_rss_mb)."""
    peak: dict[int, float] = {}
    for t in tasks.values():
        pid, mb = t.get("worker_pid"), t.get("worker_max_rss_mb")
        if pid is not None and mb is not None:
            peak[pid] = max(peak.get(pid, 0.0), mb)
    return sorted(peak.values(), reverse=True)


def project(stage_seconds_per_frame: dict[str, float], deps: dict[str, str | None], recordings: int, frames: int,
            cores: int, startup_s: float) -> float:
    """Wall seconds of ``recordings`` x ``frames`` on ``cores`` single-threaded workers: every task's
    time the measured seconds per frame of its stage times ``frames`` (the stages scale linearly with
    length), each recording's tasks after the one they read, run by list scheduling (a free worker
    takes the ready task that waited longest, recordings in order), plus the cluster's start."""
    import heapq

    tasks = []   # (recording, stage)
    for r in range(recordings):
        for st in stage_seconds_per_frame:
            tasks.append((r, st))
    done_at: dict[tuple[int, str], float] = {}
    free = [0.0] * cores
    heapq.heapify(free)
    pending = list(tasks)
    while pending:
        t_free = heapq.heappop(free)
        ready = [(max(t_free, done_at.get((r, deps[st]), 0.0) if deps[st] else t_free), i)
                 for i, (r, st) in enumerate(pending)
                 if deps[st] is None or (r, deps[st]) in done_at]
        start, i = min(ready)
        r, st = pending.pop(i)
        done_at[(r, st)] = start + stage_seconds_per_frame[st] * frames
        heapq.heappush(free, done_at[(r, st)])
    return startup_s + max(done_at.values())


def _command(ds: Path, runs: Path, workers: int, stages: str, trackers: str,
             detections: str) -> tuple[list[str], dict]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(PACKAGE_ROOT), os.environ.get("PYTHONPATH", "")])}
    return [sys.executable, "-c", RUN, "run", str(ds), "--out", str(runs), "--workers", str(workers),
            "--stages", stages, "--trackers", trackers, "--detections", detections, "--quiet"], env


def _cache_stamps(runs: Path) -> dict[str, tuple[int, int]]:
    """Finished step outputs (``RUNS/cache/<seq>/<stage>-<key>``, folders and ``.npz`` files) -> (inode, mtime ns)."""
    out = {}
    for p in sorted((runs / "cache").glob("*/*")):
        if not p.name.startswith("."):
            st = p.stat()
            out[str(p.relative_to(runs))] = (st.st_ino, st.st_mtime_ns)
    return out


def kill_and_resume(ds: Path, runs: Path, after_s: float, stages: str, trackers: str, detections: str) -> dict:
    """Run with 2 workers, SIGKILL the whole process group after ``after_s`` seconds, run again."""
    import signal

    shutil.rmtree(runs, ignore_errors=True)
    cmd, env = _command(ds, runs, 2, stages, trackers, detections)
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
    if q.returncode not in (0, 1) or not (runs / "latest" / "run.json").is_file():
        sys.exit(f"egograph run after the kill exited {q.returncode}:\n{q.stdout[-2000:]}\n{q.stderr[-2000:]}")
    after = _cache_stamps(runs)
    redone = [k for k, v in before.items() if after.get(k) != v]
    return {"finished_before_kill": finished_early, "steps_done_before_kill": len(before), "steps_in_all": len(after),
            "redone": redone, "resume_wall": wall, "summary": (runs / "latest" / "summary.json").read_bytes()}


def positive_int(text: str) -> int:
    """argparse type: an integer of at least 1 (``--repeat 0`` would time nothing)."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text} is not a positive integer")
    return value


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sequences", type=int, default=4)
    ap.add_argument("--frames", type=int, default=3000, help="frames per sequence (default 3000)")
    ap.add_argument("--config", default="synth/svoe", help="synthetic-recording config (default synth/svoe)")
    ap.add_argument("--stages", default="lift,track,eval", help="with detect, the sequences are made with PV RGB")
    ap.add_argument("--trackers", default="memory,kf,graph")
    ap.add_argument("--parallel", type=int, default=1,
                    help="generate the sequences in this many processes (the runs are timed after, alone)")
    ap.add_argument("--detections", default="mvpe", choices=["svoe", "mvpe"],
                    help="the detection set (with detect: the enrollment; mvpe matches the instance photos, which "
                         "every recording has; svoe needs each instance's box in svoe.txt)")
    ap.add_argument("--workdir", type=Path, help="where the dataset and runs go (default: a temporary folder, "
                                                 "removed at the end)")
    ap.add_argument("--kill-after", type=float, metavar="F",
                    help="also kill a 2-worker run after F x its uninterrupted wall time and run it again")
    ap.add_argument("--repeat", type=positive_int, default=3,
                    help="rounds of a 1-worker and a 2-worker run, alternating; the speed-up is their median")
    ap.add_argument("--project", type=int, nargs=3, default=[50, 10000, 16], metavar=("RECORDINGS", "FRAMES", "CORES"),
                    help="project the wall time of this many recordings of this many frames on a cluster of this "
                         "many single-threaded workers from the measured per-stage costs (default 50 10000 16)")
    benchdoc.add_arguments(ap, __file__)
    args = ap.parse_args()
    bench = benchdoc.start(__file__, args)
    work = args.workdir or Path(tempfile.mkdtemp(prefix="bench_run_"))
    stages = [s.strip() for s in args.stages.split(",")]
    try:
        t = time.perf_counter()
        ds = make_dataset(work, args.sequences, args.frames, args.config, rgb="detect" in stages,
                          parallel=args.parallel)
        t_synth = time.perf_counter() - t
        rounds = []   # per round {workers: (wall, info)}; alternating, so slow spells of the machine hit both
        for k in range(args.repeat):
            rows = {}
            for workers in (1, 2):
                wall, info = run(ds, work / f"runs-w{workers}", workers, args.stages, args.trackers, args.detections)
                rows[workers] = (wall, info)
                print(f"round {k + 1}, --workers {workers}: {wall:.1f} s wall", flush=True)
            rounds.append(rows)
        rows = rounds[0]
        killed = None
        if args.kill_after is not None:
            killed = kill_and_resume(ds, work / "runs-killed", args.kill_after * rows[2][0], args.stages,
                                     args.trackers, args.detections)
    finally:
        if args.workdir is None:
            shutil.rmtree(work, ignore_errors=True)
    print()
    n_frames = args.sequences * args.frames
    load = os.getloadavg()
    benchdoc.table("egograph run: 1 and 2 local Dask workers",
                   ["round", "workers", "wall s", "frames/s", "task s", "task CPU s", "busy workers",
                    "peak MB per worker", "bytes written per frame"],
                   [[k + 1, workers, wall, n_frames / wall, info["task_seconds"], info["task_cpu"],
                     info["task_seconds"] / wall, " / ".join(f"{m:.0f}" for m in peak_memory(info["tasks"])) or "n/a",
                     info["bytes"] / n_frames]
                    for k, r in enumerate(rounds) for workers, (wall, info) in r.items()],
                   ["d", "d", ".1f", ".2f", ".1f", ".1f", ".2f", "", ".0f"],
                   note=f"{args.sequences} sequences x {args.frames} frames, stages {args.stages}, detections "
                        f"{args.detections}, trackers {args.trackers}; {os.cpu_count()} CPUs shared with other work: "
                        "load average "
                        f"{bench.machine['load_average'][0]:.1f} at the start, {load[0]:.1f} at the end (a load above "
                        "the 2 cores leaves each worker a fraction of one: the 2-worker figure is a floor). Generating "
                        f"the sequences took {t_synth:.0f} s (not in the runs; 0 when cached).")
    (w1, i1), (w2, i2) = rows[1], rows[2]
    for k, r in enumerate(rounds):
        for workers, (_, info) in r.items():
            if info["failed"]:
                benchdoc.text(f"round {k + 1}, --workers {workers}: {len(info['failed'])} tasks did not end ok "
                              f"(failed, or skipped after one that failed): {', '.join(info['failed'][:6])}")
    ratios = [r[1][0] / r[2][0] for r in rounds]
    speedup = statistics.median(ratios)
    same = all(r[w][1]["summary"] == i1["summary"] for r in rounds for w in (1, 2))
    benchdoc.text(f"speed-up 2 workers / 1: {speedup:.2f}x, the median of {len(rounds)} rounds "
                  f"({', '.join(f'{x:.2f}x' for x in ratios)}; target >= 1.7x: "
                  f"{'met' if speedup >= 1.7 else 'NOT met'}); summaries identical: {same}")
    st1 = per_stage(i1["tasks"])
    benchdoc.table("Per stage, 1 worker: seconds per frame",
                   ["stage", "tasks", "wall ms/frame", "CPU ms/frame", "share of task time"],
                   [[name, v["n"], 1e3 * v["seconds"] / n_frames, 1e3 * v["cpu"] / n_frames,
                     v["seconds"] / max(i1["task_seconds"], 1e-9)] for name, v in st1.items()],
                   ["", "d", ".1f", ".1f", ".0%"],
                   note="Wall and CPU time of the stage's tasks (the worker process, every thread) over all frames "
                        "of all sequences; CPU above wall means a task used more than one core.")
    if killed is not None:
        k = killed
        how = "it had already finished" if k["finished_before_kill"] else "SIGKILL"
        benchdoc.text(f"killed after {args.kill_after * w2:.1f} s ({how}): "
                      f"{k['steps_done_before_kill']}/{k['steps_in_all']} step outputs finished before the kill; "
                      f"re-run {k['resume_wall']:.1f} s; finished steps done again: {len(k['redone'])} "
                      f"{k['redone'][:3]}; "
                      f"summary equals the uninterrupted run's: {k['summary'] == i2['summary']}")
    recordings, frames, cores = args.project
    deps = {name: None for name in st1}
    for name in st1:
        stage, _, tracker = name.partition("/")
        deps[name] = {"lift": "detect" if "detect" in st1 else None, "track": "lift",
                      "eval": f"track/{tracker}"}.get(stage)
        if deps[name] is not None and deps[name] not in st1:
            deps[name] = None
    # A task on a worker of its own takes about its CPU time (each stage runs one thread but for
    # Open3D's ray casts in the lift, where CPU above wall makes this an upper bound); the wall time
    # measured here is that stretched by the other work on this shared machine.
    per_frame = {name: max(v["cpu"], 1e-9) / n_frames for name, v in st1.items()}   # a task on F frames: F times this
    per_frame_wall = {name: v["seconds"] / n_frames for name, v in st1.items()}
    startup = max(0.0, w1 - i1["task_seconds"])
    wall = project(per_frame, deps, recordings, frames, cores, startup)
    wall_as_measured = project(per_frame_wall, deps, recordings, frames, cores, startup)
    cpu_h = sum(v["cpu"] for v in st1.values()) / n_frames * recordings * frames / 3600
    benchdoc.text(f"projection: {recordings} recordings x {frames} frames on {cores} single-threaded workers of this "
                  f"machine's speed: {wall / 3600:.1f} h wall ({cpu_h:.1f} CPU h; stages {args.stages}; each task "
                  f"its stage's measured CPU seconds per frame times the length, list-scheduled per recording after "
                  f"the stage it reads, plus {startup:.0f} s of cluster start and overhead measured here); goal <= "
                  f"12 h: {'met' if wall <= 12 * 3600 else 'NOT met'}. With the wall seconds per frame as measured on "
                  f"this loaded machine instead: {wall_as_measured / 3600:.1f} h")
    bench.data.update({"per_stage_1_worker": st1, "per_stage_2_workers": per_stage(i2["tasks"]),
                       "peak_mb": {str(w): peak_memory(i["tasks"]) for w, (_, i) in rows.items()},
                       "projection": {"recordings": recordings, "frames": frames, "cores": cores, "wall_s": wall,
                                      "wall_s_from_measured_wall": wall_as_measured, "cpu_h": cpu_h,
                                      "cpu_seconds_per_frame": per_frame}})
    benchdoc.finish()


if __name__ == "__main__":
    main()
