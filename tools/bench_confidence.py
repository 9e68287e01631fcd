#!/usr/bin/env python
"""Answers with a confidence: precision-recall curves over confidence, average precision, the
operating point and calibration, every egograph tracker against the baselines' points.

    .venv/bin/python tools/bench_confidence.py --seeds 301 302 303 --frames 900 [--json OUT]
    .venv/bin/python tools/bench_confidence.py --seeds 4 5 6 7 8 --frames 900 --fit   # tuning seeds only

Runs on the cached benchmark set (egograph.synth.benchset), SVOE and MVPE: `memory` and `kf` on
reference and robust lifting (the baselines: their operating points), and on robust lifting
`graph` (offline), `graph-causal` (at each --lags) and `memory+graph` (egograph smooth of memory's
results). Per set and threshold it prints each egograph tracker's AP (all-point interpolated),
whether its curve passes at or above every baseline's point, pooled and on every recording, the
IT3DEgo P and R at the default operating point (graph.answers.min_confidence) against the best
baseline, and the expected calibration error (at graph.answers.distance_m).

--fit (tuning seeds only): runs the graph trackers with the identity calibration, fits an
isotonic map from raw to calibrated confidence per tracker family (offline: graph;
causal: graph-causal; smooth), prints the knots for graph.answers.{offline,causal,smooth}_calibration and, for
a grid of operating points, whether P and R at every threshold reach every baseline's pooled.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from egograph.core.config import load_config
from egograph.core.resources import default_config, synth_config
from egograph.core.types import TrackResult
from egograph.eval.curves import ScoredAnswers, pr_curve, reliability
from egograph.eval.protocol import THRESHOLDS
from egograph.steps.evaluate import evaluate
from egograph.steps.recording import open_recording
from egograph.steps.settings import EgographConfig
from egograph.steps.track import track as track_step
from egograph.synth.benchset import benchmark_set, cached_observations
from egograph.track.answers import calibrated
from egograph.track.registry import graph_with_scene
from egograph.track.smooth import smooth_predictions

REPO = Path(__file__).resolve().parents[1]
BASELINES = ("memory", "kf")
IDENTITY = [[0.0, 0.0], [1.0, 1.0]]


def run_recording(root: Path, overrides: list[str], lags: list[float], identity: bool) -> dict:
    """{set: {tracker: ScoredAnswers}} of one recording (raw confidences with ``identity``)."""
    cfg = load_config(EgographConfig, default_config(), overrides)
    if identity:
        cfg.graph.answers.offline_calibration = IDENTITY
        cfg.graph.answers.causal_calibration = IDENTITY
        cfg.graph.answers.smooth_calibration = IDENTITY
    rec = open_recording(root, cfg)
    out: dict[str, dict[str, ScoredAnswers]] = {}
    timing = {}
    for det_set in ("svoe", "mvpe"):
        rows = out.setdefault(det_set, {})
        for mode in ("reference", "robust"):
            cfg.lift.mode = mode
            obs, _ = cached_observations(rec, det_set, cfg)
            for b in BASELINES:
                res = track_step(rec, b, obs, cfg)
                rows[f"{b} ({mode})"] = evaluate(rec, res).sequences[rec.name].answers
                if mode == "robust" and b == "memory":
                    t = time.perf_counter()
                    sm = smooth_predictions(rec, res.per_frame, cfg.graph)
                    timing["smooth"] = timing.get("smooth", 0) + time.perf_counter() - t
                    rows["memory+graph"] = evaluate(rec, sm).sequences[rec.name].answers
        t = time.perf_counter()
        g = graph_with_scene(rec, obs, cfg, causal=False)
        timing["graph"] = timing.get("graph", 0) + time.perf_counter() - t
        rows["graph"] = evaluate(rec, g).sequences[rec.name].answers
        for lag in lags:
            t = time.perf_counter()
            cfg.graph.lag_s = lag
            c = graph_with_scene(rec, obs, cfg, causal=True)
            timing[f"causal {lag:g}"] = timing.get(f"causal {lag:g}", 0) + time.perf_counter() - t
            rows[f"graph-causal lag {lag:g}"] = evaluate(rec, c).sequences[rec.name].answers
    print(f"{root.name}: " + ", ".join(f"{k} {v:.0f} s" for k, v in timing.items()), flush=True)
    return out


def family(name: str) -> str | None:
    if name.startswith("graph-causal"):
        return "causal"
    if name == "graph":
        return "offline"
    if name == "memory+graph":
        return "smooth"
    return None


def fit_isotonic(raw: np.ndarray, correct: np.ndarray, n_knots: int = 16) -> list[list[float]]:
    """Isotonic regression of ``correct`` on ``raw`` (pool-adjacent-violators), as at most
    ``n_knots`` [raw, calibrated] knots: each block of the fit is a knot at its answer-weighted mean
    raw value, and the two adjacent blocks whose values differ least (weighted by their answers) are
    merged until few enough remain; 0 and 1 pinned to the end values."""
    order = np.argsort(raw, kind="stable")
    x, y = np.asarray(raw, float)[order], np.asarray(correct, float)[order]
    blocks: list[list[float]] = []   # [sum of y, count, sum of x]
    for xi, yi in zip(x, y):         # pool adjacent violators (ties in x pooled first)
        if blocks and blocks[-1][2] / blocks[-1][1] == xi:
            blocks[-1][0] += yi
            blocks[-1][1] += 1
            blocks[-1][2] += xi
        else:
            blocks.append([yi, 1.0, xi])
        while len(blocks) > 1 and blocks[-2][0] / blocks[-2][1] >= blocks[-1][0] / blocks[-1][1]:
            a, n, sx = blocks.pop()
            blocks[-1][0] += a
            blocks[-1][1] += n
            blocks[-1][2] += sx
    while len(blocks) > n_knots - 2:
        cost = [min(b[1], c[1]) * (c[0] / c[1] - b[0] / b[1]) for b, c in zip(blocks, blocks[1:])]
        k = int(np.argmin(cost))
        b, c = blocks[k], blocks.pop(k + 1)
        b[0] += c[0]
        b[1] += c[1]
        b[2] += c[2]
    xs = [b[2] / b[1] for b in blocks]
    ys = [b[0] / b[1] for b in blocks]
    knots = [[0.0, ys[0]]] + [[x_, y_] for x_, y_ in zip(xs, ys)] + [[1.0, ys[-1]]]
    out: list[list[float]] = []
    for x_, y_ in knots:             # rounded for the config, raw strictly increasing
        x_, y_ = round(float(x_), 6), round(float(y_), 4)
        if out and x_ <= out[-1][0]:
            out[-1][1] = max(out[-1][1], y_)
            continue
        out.append([x_, max(y_, out[-1][1]) if out else y_])
    return out


def recalibrated(a: ScoredAnswers, knots) -> ScoredAnswers:
    return ScoredAnswers(a.thresholds, calibrated(a.score, knots), a.tp, a.n_gt)


def pooled(parts: list[dict], det_set: str, name: str) -> ScoredAnswers:
    return sum((p[det_set][name] for p in parts), ScoredAnswers(THRESHOLDS))


def point(a: ScoredAnswers, k: int, min_conf: float = -np.inf) -> tuple[float, float]:
    keep = a.score >= min_conf
    tp = a.tp[keep, k].sum()
    n = int(keep.sum())
    return (tp / n if n else 0.0), (tp / a.n_gt if a.n_gt else 0.0)


def report(parts: list[dict], seeds: list[int], min_conf: float, tau_cal: float) -> dict:
    """Print and return the curves' figures per set (pooled and per recording)."""
    out = {}
    for det_set in ("svoe", "mvpe"):
        names = list(parts[0][det_set])
        ours = [n for n in names if family(n)]
        bases = [n for n in names if not family(n)]
        print(f"\n## {det_set.upper()}  (AP %, all-point interpolated; 'passes': curve at or above every baseline's "
              f"point, pooled / recordings)")
        res = out.setdefault(det_set, {})
        for scope in ["pooled", *seeds]:
            sel = parts if scope == "pooled" else [parts[seeds.index(scope)]]
            base_pts = {b: [point(pooled(sel, det_set, b), k) for k in range(len(THRESHOLDS))] for b in bases}
            for n in ours:
                a = pooled(sel, det_set, n)
                row = res.setdefault(n, {}).setdefault(str(scope), {})
                row["ap"] = [round(pr_curve(a, t).ap * 100, 2) for t in THRESHOLDS]
                row["passes"] = [all(pr_curve(a, t).passes(*base_pts[b][k]) for b in bases)
                                 for k, t in enumerate(THRESHOLDS)]
                if scope == "pooled":
                    op = [point(a, k, min_conf) for k in range(len(THRESHOLDS))]
                    row["op_p"] = [round(100 * p, 2) for p, _ in op]
                    row["op_r"] = [round(100 * r, 2) for _, r in op]
                    row["op_dominates"] = [all(op[k][0] >= base_pts[b][k][0] - 1e-12 and op[k][1] >= base_pts[b][k][1]
                                               - 1e-12 for b in bases) for k in range(len(THRESHOLDS))]
                    rel = reliability(a, tau_cal)
                    row["ece"] = round(rel.ece, 4)
                    row["reliability"] = rel.to_json_dict()
            if scope == "pooled":
                for b in bases:
                    res.setdefault(b, {})["pooled"] = {"p": [round(100 * p, 2) for p, _ in base_pts[b]],
                                                       "r": [round(100 * r, 2) for _, r in base_pts[b]]}
        taus = " ".join(f"{t:>5g}" for t in THRESHOLDS)
        print(f"{'tracker':28s} AP@ {taus}   ECE   passes pooled | every recording")
        for n in ours:
            r = res[n]["pooled"]
            per = [all(res[n][str(s)]["passes"]) for s in seeds]
            print(f"{n:28s}     " + " ".join(f"{v:5.1f}" for v in r["ap"])
                  + f"  {r['ece']:.3f}  {'yes' if all(r['passes']) else 'NO ' + str(r['passes'])} | "
                  + ("yes" if all(per) else "NO on " + ", ".join(str(s) for s, ok in zip(seeds, per) if not ok)))
        print(f"{'baseline points (P/R %)':28s} " + "  ".join(f"@{t:g}" for t in THRESHOLDS))
        for b in bases:
            r = res[b]["pooled"]
            print(f"  {b:26s} " + "  ".join(f"{p:.1f}/{q:.1f}" for p, q in zip(r["p"], r["r"])))
        print(f"at the operating point (min_confidence {min_conf:g}), P/R %:")
        for n in ours:
            r = res[n]["pooled"]
            print(f"  {n:26s} " + "  ".join(f"{p:.1f}/{q:.1f}" for p, q in zip(r["op_p"], r["op_r"]))
                  + f"  >= every baseline: {'yes' if all(r['op_dominates']) else 'NO ' + str(r['op_dominates'])}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--frames", type=int, default=900)
    ap.add_argument("--lags", type=float, nargs="+", default=[0.0])
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="pipeline override")
    ap.add_argument("--cache", type=Path, default=REPO / ".cache" / "bench")
    ap.add_argument("--fit", action="store_true", help="fit the calibration and choose the operating point "
                                                       "(tuning seeds only)")
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args()
    if args.fit and any(s > 300 for s in args.seeds):
        ap.error("--fit on held-out seeds (301+): fit on tuning seeds only")
    roots = benchmark_set(args.seeds, args.frames, config=synth_config("svoe"), cache=args.cache, progress=False)
    parts = [run_recording(r, args.overrides, args.lags, args.fit) for r in roots]
    cfg = load_config(EgographConfig, default_config(), args.overrides)
    doc = {"seeds": args.seeds, "frames": args.frames, "lags": args.lags, "overrides": args.overrides}
    if args.fit:
        knots = {}
        for fam in ("offline", "causal", "smooth"):
            raw, ok = [], []
            for p in parts:
                for det_set in ("svoe", "mvpe"):
                    for n, a in p[det_set].items():
                        if family(n) == fam:
                            raw.append(a.score)
                            ok.append(a.tp[:, THRESHOLDS.index(cfg.graph.answers.distance_m)] > 0)
            knots[fam] = fit_isotonic(np.concatenate(raw), np.concatenate(ok).astype(float))
            print(f"graph.answers.{fam}_calibration: {json.dumps(knots[fam])}")
        for p in parts:
            for det_set in ("svoe", "mvpe"):
                for n in list(p[det_set]):
                    if family(n):
                        p[det_set][n] = recalibrated(p[det_set][n], knots[family(n)])
        doc["knots"] = knots
        grid = np.round(np.arange(0.05, 0.96, 0.05), 2)
        feasible = []
        for c in grid:
            ok = True
            for det_set in ("svoe", "mvpe"):
                names = list(parts[0][det_set])
                bases = [n for n in names if not family(n)]
                for n in (n for n in names if family(n)):
                    a = pooled(parts, det_set, n)
                    for k in range(len(THRESHOLDS)):
                        p, r = point(a, k, c)
                        ok &= all(p >= point(pooled(parts, det_set, b), k)[0] and r >= point(pooled(parts, det_set, b), k)[1]
                                  for b in bases)
            feasible.append(bool(ok))
        print("operating points where every egograph tracker's P and R >= every baseline's (pooled, both sets): "
              + (", ".join(f"{c:g}" for c, ok in zip(grid, feasible) if ok) or "none"))
        doc["feasible_min_confidence"] = [float(c) for c, ok in zip(grid, feasible) if ok]
    doc["sets"] = report(parts, args.seeds, cfg.graph.answers.min_confidence, cfg.graph.answers.distance_m)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=1) + "\n")


if __name__ == "__main__":
    main()
