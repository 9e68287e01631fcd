#!/usr/bin/env python
"""Answers with a confidence: precision-recall curves over confidence, average precision, the
operating point and calibration, every egograph tracker against the baselines' points.

    .venv/bin/python tools/bench_confidence.py --seeds 301 302 303 --frames 900 [--json-tag TAG]
    .venv/bin/python tools/bench_confidence.py --seeds 4 5 6 7 8 --frames 900 --fit --json -   # tuning seeds only

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

import benchdoc
import numpy as np

from egograph.core.config import load_config
from egograph.core.resources import default_config
from egograph.core.types import TrackResult
from egograph.eval.curves import ScoredAnswers, pr_curve, reliability
from egograph.eval.protocol import THRESHOLDS
from egograph.steps.evaluate import evaluate
from egograph.steps.recording import open_recording
from egograph.steps.settings import EgographConfig
from egograph.steps.track import track as track_step
from egograph.synth.benchset import add_world_argument, benchmark_set, cached_observations, world_config
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
        for fam in ("offline", "causal", "smooth"):
            setattr(cfg.graph.answers, f"noisy_{fam}_calibration", IDENTITY)
    rec = open_recording(root, cfg)
    out: dict = {}
    scales: dict = {}
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
                    scales[(det_set, "memory+graph")] = sm.metadata["noise_scale"]
        t = time.perf_counter()
        g = graph_with_scene(rec, obs, cfg, causal=False)
        timing["graph"] = timing.get("graph", 0) + time.perf_counter() - t
        rows["graph"] = evaluate(rec, g).sequences[rec.name].answers
        scales[(det_set, "graph")] = g.metadata["noise_scale"]
        for lag in lags:
            t = time.perf_counter()
            cfg.graph.lag_s = lag
            c = graph_with_scene(rec, obs, cfg, causal=True)
            timing[f"causal {lag:g}"] = timing.get(f"causal {lag:g}", 0) + time.perf_counter() - t
            rows[f"graph-causal lag {lag:g}"] = evaluate(rec, c).sequences[rec.name].answers
            scales[(det_set, f"graph-causal lag {lag:g}")] = c.metadata["noise_scale"]
    print(f"{root.name}: " + ", ".join(f"{k} {v:.0f} s" for k, v in timing.items()) + "; noise scales: "
          + ", ".join(f"{k[0]} {k[1]} {v:.2f}" for k, v in scales.items()), flush=True)
    out["scales"] = scales
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


def report(parts: list[dict], seeds: list[int], min_conf: dict, tau_cal: float) -> dict:
    """Print and return the curves' figures per set (pooled and per recording)."""
    out = {}
    for det_set in ("svoe", "mvpe"):
        names = list(parts[0][det_set])
        ours = [n for n in names if family(n)]
        bases = [n for n in names if not family(n)]
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
                    op = [point(a, k, min_conf[family(n)]) for k in range(len(THRESHOLDS))]
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
        labels = [f"{t:g}" for t in THRESHOLDS]
        rows = []
        for n in ours:
            r = res[n]["pooled"]
            per = [all(res[n][str(s)]["passes"]) for s in seeds]
            rows.append([n, *r["ap"], r["ece"], "yes" if all(r["passes"]) else
                         "NO at " + ", ".join(l for l, ok in zip(labels, r["passes"]) if not ok),
                         "yes" if all(per) else "NO on " + "; ".join(
                             f"{s} at " + ",".join(l for l, ok in zip(labels, res[n][str(s)]["passes"]) if not ok)
                             for s, ok in zip(seeds, per) if not ok)])
        benchdoc.table(f"{det_set.upper()}: average precision over confidence (%, all-point interpolated), ECE at "
                       f"{tau_cal:g} m, and whether each curve passes at or above every baseline's point (memory, kf; "
                       "both liftings) at every threshold",
                       ["tracker", *[f"AP@{l}" for l in labels], "ECE", "passes (pooled)", "passes (every recording)"],
                       rows, ["", *[".1f"] * len(labels), ".3f", "", ""])
        benchdoc.table(f"{det_set.upper()}: the baselines' points and the egograph trackers at the default operating "
                       f"point (graph.answers.min_confidence {min_conf['offline']:g}, causal_min_confidence "
                       f"{min_conf['causal']:g}), P / R % (pooled)",
                       ["tracker", *[f"P/R@{l}" for l in labels], ">= every baseline"],
                       [[b, *[f"{p:.1f} / {q:.1f}" for p, q in zip(res[b]["pooled"]["p"], res[b]["pooled"]["r"])], "-"]
                        for b in bases]
                       + [[n, *[f"{p:.1f} / {q:.1f}" for p, q in zip(res[n]["pooled"]["op_p"], res[n]["pooled"]["op_r"])],
                           "yes" if all(res[n]["pooled"]["op_dominates"]) else
                           "NO at " + ", ".join(l for l, ok in zip(labels, res[n]["pooled"]["op_dominates"]) if not ok)]
                          for n in ours])
        for n in ours:
            rel = res[n]["pooled"]["reliability"]
            edges = rel["edges"]
            benchdoc.table(f"{det_set.upper()} {n}: reliability at {tau_cal:g} m (answers binned by confidence)",
                           ["confidence", "answers", "mean confidence", "share within"],
                           [[f"{edges[i]:.1f}-{edges[i + 1]:.1f}", rel["count"][i],
                             "-" if rel["confidence"][i] is None else f"{rel['confidence'][i]:.3f}",
                             "-" if rel["share"][i] is None else f"{rel['share'][i]:.3f}"]
                            for i in range(len(rel["count"])) if rel["count"][i]])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--frames", type=int, default=900)
    ap.add_argument("--lags", type=float, nargs="+", default=[0.0])
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="pipeline override")
    ap.add_argument("--cache", type=Path, default=REPO / ".cache" / "bench")
    add_world_argument(ap)
    ap.add_argument("--fit", action="store_true", help="fit the calibration and choose the operating point "
                                                       "(tuning seeds only)")
    ap.add_argument("--out", type=Path, help="also write every figure (curves' APs, reliability, knots) here as JSON")
    benchdoc.add_arguments(ap, __file__)
    args = ap.parse_args()
    benchdoc.start(__file__, args)
    if args.fit and any(s > 300 for s in args.seeds):
        ap.error("--fit on held-out seeds (301+): fit on tuning seeds only")
    roots = benchmark_set(args.seeds, args.frames, config=world_config(args.world), cache=args.cache, progress=False)
    parts = [run_recording(r, args.overrides, args.lags, args.fit) for r in roots]
    cfg = load_config(EgographConfig, default_config(), args.overrides)
    doc = {"seeds": args.seeds, "frames": args.frames, "lags": args.lags, "overrides": args.overrides}
    if args.fit:
        knots = {}
        split = cfg.graph.answers.noisy_scale
        for fam in ("offline", "causal", "smooth"):
            for noisy in (False, True):
                raw, ok = [], []
                for p in parts:
                    for det_set in ("svoe", "mvpe"):
                        for n, a in p[det_set].items():
                            if family(n) == fam and (p["scales"][(det_set, n)] >= split) == noisy:
                                raw.append(a.score)
                                ok.append(a.tp[:, THRESHOLDS.index(cfg.graph.answers.distance_m)] > 0)
                key = f"{'noisy_' if noisy else ''}{fam}_calibration"
                if not raw:
                    benchdoc.text(f"graph.answers.{key}: no tuning answers (kept)")
                    continue
                knots[key] = fit_isotonic(np.concatenate(raw), np.concatenate(ok).astype(float))
                benchdoc.text(f"graph.answers.{key}: {json.dumps(knots[key])}")
        for p in parts:
            for det_set in ("svoe", "mvpe"):
                for n in list(p[det_set]):
                    if family(n):
                        key = f"{'noisy_' if p['scales'][(det_set, n)] >= split else ''}{family(n)}_calibration"
                        if key in knots:
                            p[det_set][n] = recalibrated(p[det_set][n], knots[key])
        doc["knots"] = knots
        grid = np.round(np.arange(0.05, 0.96, 0.05), 2)
        feasible: dict[str, list[float]] = {}
        for n in (n for n in parts[0]["svoe"] if family(n)):
            ok_at = []
            for c in grid:
                ok = True
                for det_set in ("svoe", "mvpe"):
                    a = pooled(parts, det_set, n)
                    bases = [b for b in parts[0][det_set] if not family(b)]
                    for k in range(len(THRESHOLDS)):
                        p, r = point(a, k, c)
                        ok &= all(p >= point(pooled(parts, det_set, b), k)[0] - 1e-12
                                  and r >= point(pooled(parts, det_set, b), k)[1] - 1e-12 for b in bases)
                if ok:
                    ok_at.append(float(c))
            feasible[n] = ok_at
            benchdoc.text(f"{n}: operating points (min_confidence) where its P and R >= every baseline's at every "
                          f"threshold, pooled, both sets: {', '.join(f'{c:g}' for c in ok_at) or 'none'}")
        doc["feasible_min_confidence"] = feasible
    a = cfg.graph.answers
    doc["sets"] = report(parts, args.seeds, {"offline": a.min_confidence, "smooth": a.min_confidence,
                                             "causal": a.causal_min_confidence}, a.distance_m)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(doc, indent=1) + "\n")
    benchdoc.text(f"recordings: seeds {', '.join(map(str, args.seeds))} at {args.frames} frames; graph-causal lags "
                  f"{', '.join(f'{x:g}' for x in args.lags)} s")
    benchdoc.finish()


if __name__ == "__main__":
    main()
