#!/usr/bin/env python
"""Build (or reuse) the cached benchmark set (egograph.synth.benchset) and print its recordings.

    .venv/bin/python tools/benchset.py --seeds 1 2 3 4 5 --frames 3000 [--world legacy] [--set detections.svoe.detect_rate=0.5]
    .venv/bin/python tools/benchset.py --seeds 21 22 23 24 25 26 --frames 300 --rgb --jobs 2

The benchmark tools build the recordings they miss one after another. Built here first, ``--jobs N``
recordings at a time (each in a process of its own, on one thread), a set of several recordings
is ready in about 1/N of the time on N free cores, and every tool then finds it cached. Each
recording is the same bytes however it was built (its seed alone decides it). ``--rgb``: the
recordings with PV RGB that the front-end and pose-refinement benchmarks read
(``rgb_benchmark_set``).
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Sequence

from egograph.synth.benchset import add_world_argument, benchmark_set, rgb_benchmark_set, world_config

REPO = Path(__file__).resolve().parents[1]
DEFAULT_CACHE = REPO / ".cache" / "bench"
ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "LP_NUM_THREADS": "1"}
"""The environment of each process of a parallel build: one thread for BLAS, OpenMP and Mesa."""


def build(seeds: Sequence[int], frames: int, *, config: str | Path, cache: Path, overrides: Sequence[str] = (),
          rgb: bool = False, jobs: int = 1) -> list[Path]:
    """Roots of the recordings ``seeds`` (one per seed, in that order) of the synth ``config``, built
    ``jobs`` at a time in processes of their own when missing (``benchmark_set`` or, with ``rgb``,
    ``rgb_benchmark_set``)."""
    seeds = [int(s) for s in seeds]
    if jobs <= 1 or len(seeds) <= 1:
        return _build_one(seeds, frames, config, cache, tuple(overrides), rgb)
    # spawn, not fork: a forked child inherits the parent's OpenGL and thread-pool state. Each child
    # on one thread: a generator alone keeps about 1.7 cores busy (BLAS, OpenMP and Mesa's
    # rasteriser threads) for 10 % less wall time than on one, so jobs side by side would fight for
    # the cores. The environment is read when a child starts, before it imports numpy.
    saved = {k: os.environ.get(k) for k in ONE_THREAD}
    os.environ.update(ONE_THREAD)
    try:
        ctx = multiprocessing.get_context("spawn")
        n = len(seeds)
        with ProcessPoolExecutor(min(jobs, n), mp_context=ctx) as pool:
            parts = list(pool.map(_build_one, [[s] for s in seeds], [frames] * n, [config] * n, [cache] * n,
                                  [tuple(overrides)] * n, [rgb] * n))
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return [root for part in parts for root in part]


def _build_one(seeds: list[int], frames: int, config: str | Path, cache: Path, overrides: tuple[str, ...],
               rgb: bool) -> list[Path]:
    if rgb:
        return rgb_benchmark_set(seeds, frames, config=config, cache=cache, overrides=overrides)
    # one progress bar per process would interleave: only a sequential build shows it
    return benchmark_set(seeds, frames, config=config, cache=cache, overrides=overrides, progress=len(seeds) > 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="generator override")
    ap.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    ap.add_argument("--rgb", action="store_true", help="the recordings with PV RGB (front-end and refinement "
                                                       "benchmarks)")
    ap.add_argument("--jobs", type=int, default=1, help="recordings built at once, each in a process of its own on "
                                                        "one thread (at most one per free core)")
    add_world_argument(ap)
    a = ap.parse_args()
    if a.jobs < 1:
        ap.error(f"--jobs must be at least 1, got {a.jobs}")
    for r in build(a.seeds, a.frames, config=world_config(a.world), cache=a.cache, overrides=a.overrides, rgb=a.rgb,
                   jobs=a.jobs):
        print(r)


if __name__ == "__main__":
    main()
