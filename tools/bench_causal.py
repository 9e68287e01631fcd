#!/usr/bin/env python
"""The causal tracker's benchmark (issue 17): graph-causal against the online baselines, recall
against lag, and the online API's per-frame latency.

    .venv/bin/python tools/bench_causal.py --seeds 11 12 13 --frames 1000 [--cache DIR]
    .venv/bin/python tools/bench_causal.py --latency-only --stream-frames 50000

1. On cached synthetic benchmark recordings (egograph.synth.benchset; robust lifting, SVOE and
   MVPE), pooled P/R at every threshold and L2 for ``memory``, ``kf``, ``graph-causal`` (lag 0)
   and ``graph`` (offline), all on the same observations, and the issue's targets checked; and the
   ``causal ceiling``: the true centres from each instance's first detection on, the most recall
   any causal tracker can reach.
2. Recall at 0.25 m of graph-causal against lag (``--lags``, seconds) and offline.
3. Per-frame latency of :class:`egograph.track.online.OnlineTracker` on a synthetic stream of
   observations (no rendering) of ``--instances`` objects: median and p99 of ``step()`` over
   the stream, and flatness: median step time and resident memory in the first and last tenth
   of the stream. Use seeds apart from those the defaults were tuned on (1, 2, 3). A
   ``--latency-only`` run writes its own record (``docs/bench/bench_causal-latency.json``).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import benchdoc
import numpy as np

from egograph.core.config import load_config
from egograph.core.resources import default_config
from egograph.core.types import PositionInterval, TrackResult
from egograph.eval.metrics import gt_intervals
from egograph.eval.protocol import THRESHOLDS, Counts
from egograph.geometry.observations import Observations
from egograph.steps.evaluate import evaluate
from egograph.steps.recording import open_recording
from egograph.steps.settings import EgographConfig
from egograph.steps.track import track as track_step
from egograph.synth.benchset import add_world_argument, benchmark_set, cached_observations, world_config
from egograph.track.config import GraphConfig
from egograph.track.intervals import per_frame_predictions
from egograph.track.online import OnlineTracker
from egograph.track.registry import graph_with_scene

REPO = Path(__file__).resolve().parents[1]
TICKS = 10_000_000
FRAME_TICKS = 333_333  # 30 fps


def causal_ceiling(rec, obs, cfg) -> TrackResult:
    """The best any causal tracker could answer: every true interval's true centre on each of its
    frames from the instance's first usable detection on (nothing before it can be known)."""
    use = obs.valid & (obs.score >= np.float32(cfg.graph.score_threshold))
    ivs = []
    for g in gt_intervals(rec):
        m = use & (obs.instance == g.instance)
        first = int(obs.timestamps[m].min()) if m.any() else None
        if first is not None and first <= g.t_end:
            ivs.append(PositionInterval(g.instance, max(g.t_start, first), g.t_end, tuple(g.xyz),
                                        np.eye(3).tolist(), 1, 1.0))
    return TrackResult(per_frame=per_frame_predictions(ivs, np.asarray(rec.timestamps)), intervals=[],
                       metadata={"tracker": "causal ceiling"})


def accuracy(seeds, frames, cache, lags, overrides, plot: Path | None = None,
             set_overrides: dict[str, list[str]] | None = None, world: str = "device") -> None:
    roots = benchmark_set(seeds, frames, config=world_config(world), cache=cache, progress=False)
    cfg = load_config(EgographConfig, default_config(), overrides)
    cfg.lift.mode = "robust"
    # per detection set: the same overrides plus that set's own (e.g. its front-end's noise scale)
    cfg_of = {}
    for d in ("svoe", "mvpe"):
        cfg_of[d] = load_config(EgographConfig, default_config(), overrides + (set_overrides or {}).get(d, []))
        cfg_of[d].lift.mode = "robust"
    names = ["memory", "kf", "graph-causal", *[f"graph-causal lag {s:g} s" for s in lags if s > 0], "graph (offline)",
             "causal ceiling"]
    pooled = {(d, n): Counts(THRESHOLDS) for d in ("svoe", "mvpe") for n in names}
    seconds = {n: 0.0 for n in names}
    per_seed = {}  # (set, tracker, seed) -> counts
    for root in roots:
        rec = open_recording(root, cfg)
        for det_set in ("svoe", "mvpe"):
            obs, _ = cached_observations(rec, det_set, cfg)
            cfg_set = cfg_of[det_set]
            for name in names:
                t = time.perf_counter()
                if name in ("memory", "kf"):
                    result = track_step(rec, name, obs, cfg_set)
                elif name == "graph (offline)":
                    result = graph_with_scene(rec, obs, cfg_set, causal=False)
                elif name == "causal ceiling":
                    result = causal_ceiling(rec, obs, cfg_set)
                else:
                    lag = float(name.split()[2]) if "lag" in name else 0.0
                    c = dataclasses.replace(cfg_set, graph=dataclasses.replace(cfg_set.graph, lag_s=lag))
                    result = graph_with_scene(rec, obs, c, causal=True)
                seconds[name] += time.perf_counter() - t
                counts = evaluate(rec, result).total
                per_seed[(det_set, name, root.name)] = counts
                pooled[(det_set, name)] = pooled[(det_set, name)] + counts
    th = [f"P@{t:g}" for t in THRESHOLDS] + [f"R@{t:g}" for t in THRESHOLDS]
    benchdoc.table("Causal and offline trackers, every threshold", ["set", "tracker", *th, "L2 (m)"],
                   [[d, n, *(100 * c.precision), *(100 * c.recall), c.l2_m] for (d, n), c in pooled.items()],
                   ["", "", *[".1f"] * len(th), ".3f"],
                   note=f"Benchmark recordings: seeds {', '.join(map(str, seeds))} x {frames} frames, robust lifting, "
                        "pooled.")
    benchdoc.text("Targets (issue 29; graph-causal at lag 0):\n")
    for d in ("svoe", "mvpe"):
        g, m, k = (pooled[(d, n)] for n in ("graph-causal", "memory", "kf"))
        for base, b in (("memory", m), ("kf", k)):
            pr = bool(np.all(g.precision >= b.precision) and np.all(g.recall >= b.recall))
            benchdoc.text(f"- {d}: P and R >= {base} at every threshold: {pr}; L2 < {base}: {g.l2_m < b.l2_m} "
                          f"({g.l2_m:.3f} against {b.l2_m:.3f} m)")
        ceiling = pooled[(d, "causal ceiling")].recall[0]
        if d == "mvpe":
            benchdoc.text(f"- {d}: R@0.25 / causal ceiling = {g.recall[0] / max(ceiling, 1e-9):.3f} (target >= 0.95; "
                          f"{100 * g.recall[0]:.1f} against {100 * ceiling:.1f}); P@0.25 = {100 * g.precision[0]:.1f} % "
                          "(target >= 95)")
        else:
            benchdoc.text(f"- {d}: R@0.25 {100 * g.recall[0]:.1f} against memory's {100 * m.recall[0]:.1f} (target >=); "
                          f"P@0.25 {100 * g.precision[0]:.1f} against memory's {100 * m.precision[0]:.1f} + 20 "
                          f"(target >=: {100 * g.precision[0] >= 100 * m.precision[0] + 20})")
    for d in ("svoe", "mvpe"):
        offline = pooled[(d, "graph (offline)")].recall[0]
        reach = [s for s, n in zip([0.0, *[x for x in lags if x > 0]], names[2:-2])
                 if pooled[(d, n)].recall[0] >= 0.95 * offline]
        benchdoc.text(f"- {d}: the lag at which graph-causal reaches 95 % of offline R@0.25 ({100 * 0.95 * offline:.1f}): "
                      + (f"{reach[0]:g} s" if reach else f"beyond {max(lags):g} s"))
    print()
    benchdoc.table("Per seed (P@0.25 / R@0.25 / R@1.5, %)", ["set", "tracker", *(r.name for r in roots)],
                   [[d, n, *([100 * c.precision[0], 100 * c.recall[0], 100 * c.recall[-1]]
                             for c in (per_seed[(d, n, r.name)] for r in roots))]
                    for d in ("svoe", "mvpe") for n in ("memory", "kf", "graph-causal", "graph (offline)")],
                   ["", "", *["{0:.1f} / {1:.1f} / {2:.1f}"] * len(roots)])
    benchdoc.table("Recall at 0.25 m against lag",
                   ["set", *(n.replace("graph-causal ", "").replace("graph-causal", "lag 0 s") for n in names[2:])],
                   [[d, *(100 * pooled[(d, n)].recall[0] for n in names[2:])] for d in ("svoe", "mvpe")],
                   ["", *[".1f"] * len(names[2:])])
    benchdoc.table("P@0.25, R@0.25 and L2 against lag",
                   ["set", "lag", "P@0.25", "R@0.25", "L2 (m)"],
                   [[d, n.replace("graph-causal ", "").replace("graph-causal", "lag 0 s").replace("graph ", ""),
                     100 * pooled[(d, n)].precision[0], 100 * pooled[(d, n)].recall[0], pooled[(d, n)].l2_m]
                    for d in ("svoe", "mvpe") for n in names[2:-1]],
                   ["", "", ".1f", ".1f", ".3f"])
    if plot is not None:
        plot_lag(plot, lags, {d: [pooled[(d, n)].recall[0] for n in names[2:-1]] for d in ("svoe", "mvpe")},
                 {d: pooled[(d, "memory")].recall[0] for d in ("svoe", "mvpe")}, seeds, frames)
    benchdoc.text("Tracking seconds (all recordings, both sets): "
                  + ", ".join(f"{n} {s:.1f}" for n, s in seconds.items()))


def plot_lag(path: Path, lags, recall: dict, memory: dict, seeds, frames) -> None:
    """Recall at 0.25 m against lag (seconds; offline drawn at the right end), one line per set,
    memory's recall as a dashed reference."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xs = [s for s in lags if s > 0]
    x = [0.0, *xs]
    off = 1.5 * max(x) if max(x) > 0 else 1.0
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for (d, r), colour in zip(recall.items(), ("#0072B2", "#D55E00")):
        ax.plot(x, [100 * v for v in r[:-1]], "o-", color=colour, label=f"{d.upper()} graph-causal")
        ax.plot([x[-1], off], [100 * r[-2], 100 * r[-1]], ":", color=colour)
        ax.plot([off], [100 * r[-1]], "s", color=colour, label=f"{d.upper()} offline")
        ax.axhline(100 * memory[d], color=colour, ls="--", lw=0.8, label=f"{d.upper()} memory (lag 0)")
    ax.set_xticks([*x, off], [f"{v:g}" for v in x] + ["offline"])
    ax.set_xlabel("lag (s): the answer for frame t uses frames up to t + lag")
    ax.set_ylabel("recall at 0.25 m (%)")
    ax.set_title(f"What latency buys: seeds {', '.join(map(str, seeds))} x {frames} frames, robust lifting")
    ax.grid(alpha=0.3)
    ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata={"Software": None})
    plt.close(fig)
    print(f"\nwrote {path}")


# --------------------------------------------------------------------------- latency


def synthetic_stream(n_frames: int, n_instances: int, seed: int):
    """Per frame, the lifted observations of ``n_instances`` objects (no rendering): each stands
    at a place, is seen on about a third of the frames with 2 cm noise from a wandering wearer,
    gets a false match on 3 % of its detections, and is carried to a new place every ~40 s."""
    rng = np.random.default_rng(seed)
    place = rng.uniform([0, 0.5, 0], [5, 1.2, 5], (n_instances, 3))
    carry_until = np.full(n_instances, -1)
    for f in range(n_frames):
        t = f / 30.0
        cam = np.array([2.5 + 2 * np.sin(t / 7), 1.6, 2.5 + 2 * np.cos(t / 9)])
        rows = []
        for i in range(n_instances):
            if carry_until[i] < f and rng.random() < 1 / 1200:
                carry_until[i] = f + 60
                place[i] = rng.uniform([0, 0.5, 0], [5, 1.2, 5])
            if carry_until[i] >= f:
                p = cam + [0.3, -0.4, 0.2] + 0.01 * rng.standard_normal(3)
            elif rng.random() < 0.33:
                p = place[i] + 0.02 * rng.standard_normal(3)
                if rng.random() < 0.03:
                    p = rng.uniform([0, 0, 0], [5, 2, 5])
            else:
                continue
            rows.append((i, p))
        yield f, cam, rows


def stream_observations(f: int, ts: int, cam: np.ndarray, rows) -> Observations:
    m = len(rows)
    world = np.array([p for _, p in rows], dtype=np.float64).reshape(m, 3)
    camera = np.repeat(cam[None], m, axis=0)
    return Observations(
        timestamps=np.full(m, ts, np.int64), frame=np.full(m, f, np.int32),
        instance=np.array([i for i, _ in rows], np.int32), score=np.full(m, 0.8, np.float32),
        box=np.zeros((m, 4), np.float32), world=world, camera=camera,
        range_m=np.linalg.norm(world - camera, axis=1).astype(np.float32), candidates=world[:, None, :].copy(),
        chosen=np.zeros(m, np.int8), n_pixels=np.full(m, 10, np.int32))


def rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * 4096 / 1e6


def latency(n_frames: int, n_instances: int, seed: int) -> None:
    cfg = GraphConfig(negative_evidence=False)
    t0 = 133_400_000_000_000_000
    trk = OnlineTracker(cfg, t0)
    dt = np.empty(n_frames)
    cpu = np.empty(n_frames)
    rss = np.empty(n_frames)
    for f, cam, rows in synthetic_stream(n_frames, n_instances, seed):
        ts = t0 + f * FRAME_TICKS
        obs = stream_observations(f, ts, cam, rows) if rows else None
        a, c = time.perf_counter(), time.process_time()
        trk.step(f, ts, obs)
        trk.collect()
        dt[f], cpu[f] = time.perf_counter() - a, time.process_time() - c
        if f % 100 == 0:
            rss[f] = rss_mb()
    tenth = max(n_frames // 10, 1)
    first, last = dt[:tenth], dt[-tenth:]
    rss_first = rss[:tenth:100].mean() if tenth >= 100 else rss[0]
    rss_last = rss[n_frames - tenth::100][rss[n_frames - tenth::100] > 0].mean() if tenth >= 100 else rss[0]
    load = open("/proc/loadavg").read().split()[0]
    print()
    benchdoc.table("Online API latency per frame (step() + collect())",
                   ["frames", "median (ms)", "p99 (ms)", "max (ms)", "RSS (MB)"],
                   [["all", 1e3 * np.median(dt), 1e3 * np.percentile(dt, 99), 1e3 * dt.max(), ""],
                    ["first tenth", 1e3 * np.median(first), 1e3 * np.percentile(first, 99), 1e3 * first.max(), rss_first],
                    ["last tenth", 1e3 * np.median(last), 1e3 * np.percentile(last, 99), 1e3 * last.max(), rss_last],
                    ["all, CPU time (process_time)", 1e3 * np.median(cpu), 1e3 * np.percentile(cpu, 99), 1e3 * cpu.max(),
                     ""]],
                   ["", ".2f", ".2f", ".1f", ".0f"],
                   note=f"Load average {load} on {os.cpu_count()} cores: {n_instances} instances, {n_frames} frames of "
                        f"synthetic observations (seed {seed}).")
    benchdoc.text(f"Targets: median <= 5 ms: {np.median(dt) <= 5e-3}; p99 <= 50 ms: {np.percentile(dt, 99) <= 50e-3}; "
                  f"last/first tenth median time {np.median(last) / np.median(first):.2f}x, RSS "
                  f"+{rss_last - rss_first:.0f} MB")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[11, 12, 13])
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--cache", type=Path, default=REPO / ".cache" / "bench")
    add_world_argument(ap)
    ap.add_argument("--lags", type=float, nargs="+", default=[0, 1, 2, 5, 10, 30])
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="pipeline override")
    for d in ("svoe", "mvpe"):
        ap.add_argument(f"--set-{d}", dest=f"overrides_{d}", action="append", default=[],
                        help=f"pipeline override for the {d.upper()} observations only, e.g. graph.noise.scale=X: "
                             "the scale the offline tracker fits on that front-end, for the causal mode")
    ap.add_argument("--stream-frames", type=int, default=50_000)
    ap.add_argument("--instances", type=int, default=8)
    ap.add_argument("--latency-only", action="store_true")
    ap.add_argument("--no-latency", action="store_true")
    ap.add_argument("--plot", type=Path, help="PNG of recall at 0.25 m against lag")
    benchdoc.add_arguments(ap, __file__)
    args = ap.parse_args()
    if args.latency_only and not args.json and not args.json_tag:
        args.json_tag = "latency"  # its own record: the accuracy record stays as it was
    benchdoc.start(__file__, args)
    if not args.latency_only:
        accuracy(args.seeds, args.frames, args.cache, args.lags, args.overrides, args.plot,
                 {"svoe": args.overrides_svoe, "mvpe": args.overrides_mvpe}, world=args.world)
    if not args.no_latency:
        latency(args.stream_frames, args.instances, seed=7)
    benchdoc.finish()


if __name__ == "__main__":
    main()
