#!/usr/bin/env python
"""Benchmark the synthetic generator (frames/s, depth only and with RGB) and the reader
(frames/s to open a recording and load poses + every depth frame).

    LP_NUM_THREADS=1 taskset -c 0 .venv/bin/python tools/bench_synth.py --frames 3000 --rgb-frames 300
    LP_NUM_THREADS=1 .venv/bin/python tools/bench_synth.py --frames 600 --rgb-frames 200 --parallel 2

Wall-clock and CPU seconds (the process's, all threads) are both printed: on a shared machine the
CPU figure is the one that says what one core does (run it under ``taskset -c 0`` for one core;
``LP_NUM_THREADS=1`` gives Mesa's software rasteriser one thread). The PV colour stage alone is
the difference between a run with RGB and a depth-only run of the same frames (same seed), per
renderer (``--renderers``, default both: ``gl`` the rasteriser, ``raycast`` the reference).
Also prints the never-visible share of true intervals of the depth-only recording.

``--parallel N`` adds the device world with RGB in N worker processes at once (one recording each,
seeds ``seed`` .. ``seed + N - 1``): the wall frames/s of all N together, what a benchmark set of
several recordings gets from N cores (the generator renders one recording in one process). Run it
without ``taskset -c 0``, or the workers share one core.
"""

from __future__ import annotations

import argparse
import multiprocessing
import shutil
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import benchdoc

from egograph.core.config import load_config
from egograph.core.resources import synth_config
from egograph.io.recording import Recording
from egograph.synth.config import SynthConfig
from egograph.synth.generate import generate
from egograph.synth.truth import never_visible_intervals

REPO = Path(__file__).resolve().parents[1]


def timed_generate(out: Path, config: str, overrides: list[str], seed: int) -> tuple[int, float, float]:
    """One recording generated in this process -> (frames, wall seconds, this process's CPU seconds);
    the recording is removed afterwards."""
    cfg = load_config(SynthConfig, config, overrides)
    c = time.process_time()
    r = generate(out, cfg, seed=seed, progress=False)
    cpu = time.process_time() - c
    shutil.rmtree(out, ignore_errors=True)
    return r.frames, r.seconds, cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default=str(synth_config("svoe")))
    ap.add_argument("--frames", type=int, default=3000, help="frames of the depth-only run")
    ap.add_argument("--rgb-frames", type=int, default=300, help="frames of the run with RGB (0 to skip)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--keep", type=Path, help="keep the depth-only recording here")
    ap.add_argument("--renderers", nargs="+", default=["gl", "raycast"], choices=["gl", "raycast"],
                    help="PV renderers to time in the runs with RGB")
    ap.add_argument("--device-config", default=str(synth_config("device-svoe")),
                    help="device-world config timed with RGB beside the legacy world's runs ('' to skip): the "
                         "same frames and seed, photographic surfaces and the PV camera model")
    ap.add_argument("--parallel", type=int, default=0, metavar="N",
                    help="also the device world with RGB in N worker processes at once, one recording each (0: skip)")
    benchdoc.add_arguments(ap, __file__)
    args = ap.parse_args()
    benchdoc.start(__file__, args)

    tmp = Path(tempfile.mkdtemp(prefix="bench_synth_"))
    rows = []
    try:
        cfg = load_config(SynthConfig, args.config, [f"frames={args.frames}", "pv.rgb=false"])
        out = args.keep or tmp / "depth"
        c = time.process_time()
        r = generate(out, cfg, seed=args.seed, progress=True)
        rows.append(("generate, depth only", r.frames, r.seconds, time.process_time() - c))
        never, total = never_visible_intervals(out)
        t, c = time.perf_counter(), time.process_time()
        rec = Recording.open(out)
        n = sum(rec.depth_raw(i) is not None for i in range(len(rec)))
        rows.append(("read poses + all depth frames", n, time.perf_counter() - t, time.process_time() - c))
        pv_rows = []
        if args.rgb_frames:
            cfg = load_config(SynthConfig, args.config, [f"frames={args.rgb_frames}", "pv.rgb=false"])
            c = time.process_time()
            r = generate(tmp / "rgb_base", cfg, seed=args.seed, progress=True)
            base = (r.seconds, time.process_time() - c)
            rows.append(("generate, depth only (RGB's frames)", r.frames, *base))
            for ren in args.renderers:
                cfg = load_config(SynthConfig, args.config, [f"frames={args.rgb_frames}", "pv.rgb=true",
                                                             f"pv.renderer={ren}"])
                c = time.process_time()
                r = generate(tmp / f"rgb_{ren}", cfg, seed=args.seed, progress=True)
                cpu = time.process_time() - c
                rows.append((f"generate, with RGB ({ren})", r.frames, r.seconds, cpu))
                pv_rows.append((f"PV colour alone ({ren}: render + PNG)", r.frames, r.seconds - base[0], cpu - base[1]))
                shutil.rmtree(tmp / f"rgb_{ren}", ignore_errors=True)
            if args.device_config:
                for rgb in (False, True):
                    cfg = load_config(SynthConfig, args.device_config, [f"frames={args.rgb_frames}", f"pv.rgb={str(rgb).lower()}"])
                    c = time.process_time()
                    r = generate(tmp / "rgb_device", cfg, seed=args.seed, progress=True)
                    cpu = time.process_time() - c
                    if not rgb:
                        dev_base = (r.seconds, cpu)
                        rows.append(("generate, device world, depth only", r.frames, r.seconds, cpu))
                    else:
                        rows.append(("generate, device world, with RGB", r.frames, r.seconds, cpu))
                        pv_rows.append(("PV colour alone (device world: render + camera + PNG)", r.frames,
                                        r.seconds - dev_base[0], cpu - dev_base[1]))
                    shutil.rmtree(tmp / "rgb_device", ignore_errors=True)
                if args.parallel > 0:
                    over = [f"frames={args.rgb_frames}", "pv.rgb=true"]
                    jobs = [(tmp / f"par{k}", args.device_config, over, args.seed + k) for k in range(args.parallel)]
                    t = time.perf_counter()
                    with ProcessPoolExecutor(args.parallel, mp_context=multiprocessing.get_context("spawn")) as pool:
                        got = list(pool.map(timed_generate, *zip(*jobs)))
                    wall = time.perf_counter() - t
                    # wall: from the pool's start to the last recording's end (worker start-up included)
                    rows.append((f"generate, device world, with RGB, {args.parallel} recordings in "
                                 f"{args.parallel} processes at once", sum(g[0] for g in got), wall,
                                 sum(g[2] for g in got)))
        rows += pv_rows
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print()
    benchdoc.table("Generator and reader speed",
                   ["stage", "frames", "seconds", "frames/s", "CPU s", "frames/CPU-s"],
                   [[name, n, s, n / max(s, 1e-9), cpu, n / max(cpu, 1e-9)] for name, n, s, cpu in rows],
                   ["", "d", ".1f", ".1f", ".1f", ".1f"],
                   note=f"Seed {args.seed}; CPU seconds are the process's (all threads; in the row of several "
                        "processes, theirs summed); the PV colour rows are the difference from a depth-only run of "
                        "the same frames.")
    benchdoc.text(f"true intervals never a quarter visible (intervals_never_visible): {never}/{total}"
                  f" ({100 * never / max(total, 1):.0f} %)")
    if args.frames:
        per = rows[0][2] / rows[0][1]
        benchdoc.text(f"projected 3000-frame depth-only recording: {per * 3000:.0f} s")
    benchdoc.finish()


if __name__ == "__main__":
    main()
