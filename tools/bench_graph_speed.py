#!/usr/bin/env python
"""Speed of the graph tracker's offline solve against recording length (1k, 10k, 50k frames).

    .venv/bin/python tools/bench_graph_speed.py [--frames 1000 10000 50000] [--set detections]

Long recordings are made by laying the cached benchmark observations (tools/benchset.py,
robust lifting, 8 instances, 3000 frames each) end to end in time, seed after seed, so the
detection statistics are those of the benchmark. Timed: `graph_tracker` offline (chunking,
graph building, Levenberg-Marquardt per instance, segments, interval re-solves with
marginals), without negative evidence (which reads depth frames and is timed by the
tracker benchmark); both motion-break factors (switchable CustomFactor, DCS); the `kf`
baseline on the same observations as a same-run reference.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_trackers import REPO, cache_key  # noqa: E402
from benchset import DEFAULT_CACHE  # noqa: E402

from egograph.core.config import load_config  # noqa: E402
from egograph.geometry.observations import Observations  # noqa: E402
from egograph.steps.settings import EgographConfig  # noqa: E402
from egograph.track.baselines import kalman_tracker  # noqa: E402
from egograph.track.config import (
    BaselineConfig,  # noqa: E402
    GraphConfig,  # noqa: E402
)
from egograph.track.graph import graph_tracker  # noqa: E402

T0 = 133_400_000_000_000_000
FRAME = 333_333


def long_stream(n_frames: int, det_set: str, cache: Path) -> tuple[Observations, np.ndarray]:
    """Benchmark observations laid end to end to ``n_frames`` frames (ticks on a 30 fps grid)."""
    parts, offset, k = [], 0, 0
    cfg = load_config(EgographConfig, REPO / "configs" / "default.yaml")
    cfg.lift.mode = "robust"
    files = []
    for seed in range(1, 6):
        root = cache / "f3000" / f"seed{seed}"
        path = root / "observations" / f"{det_set}_robust_{cache_key(root, cfg)}.npz" if root.is_dir() else None
        if path is not None and path.exists():  # reported poses, the default config
            files.append(path)
    if not files:
        raise SystemExit(f"no cached robust observations under {cache}; run tools/bench_trackers.py first")
    while offset < n_frames:
        obs = Observations.load(files[k % len(files)])
        obs = obs.select(obs.frame < n_frames - offset)
        obs.frame = obs.frame + offset
        obs.timestamps = T0 + FRAME * obs.frame.astype(np.int64)
        parts.append(obs)
        offset += 3000
        k += 1
    return Observations.concatenate(parts), T0 + FRAME * np.arange(n_frames, dtype=np.int64)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, nargs="+", default=[1000, 10000, 50000])
    ap.add_argument("--set", dest="det_set", default="mvpe", help="detection set (mvpe has the most detections)")
    ap.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    ap.add_argument("--repeat", type=int, default=2, help="best of N runs per size")
    args = ap.parse_args()
    print("| frames | instances | observations | graph switchable (s) | graph dcs (s) | kf (s) | "
          "switchable s per 1k frames | intervals |")
    print("|---|---|---|---|---|---|---|---|")
    rows = []
    for n in args.frames:
        obs, ts = long_stream(n, args.det_set, args.cache)
        times = {}
        for name, fn in (("switchable", lambda: graph_tracker(obs, ts, GraphConfig(negative_evidence=False))),
                         ("dcs", lambda: graph_tracker(obs, ts, GraphConfig(negative_evidence=False, switches="dcs"))),
                         ("kf", lambda: kalman_tracker(obs, ts, BaselineConfig()))):
            best = float("inf")
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                out = fn()
                best = min(best, time.perf_counter() - t0)
            times[name] = best
            if name == "switchable":
                n_iv = len(out.intervals)
        rows.append((n, times["switchable"]))
        print(f"| {n} | {len(np.unique(obs.instance))} | {len(obs)} | {times['switchable']:.2f} | {times['dcs']:.2f} | "
              f"{times['kf']:.2f} | {1000 * times['switchable'] / n:.3f} | {n_iv} |", flush=True)
    if len(rows) >= 2:
        (n0, t0), (n1, t1) = rows[0], rows[-1]
        print(f"\ngrowth {n0} -> {n1} frames: time x{t1 / t0:.1f} for length x{n1 / n0:.0f} "
              f"(exponent {np.log(t1 / t0) / np.log(n1 / n0):.2f}; 1 = linear)")


if __name__ == "__main__":
    main()
