#!/usr/bin/env python
"""Answers with a confidence: precision-recall curves over confidence, average precision, the
operating point and calibration, every egograph tracker against the baselines' points.

    .venv/bin/python tools/bench_confidence.py --seeds 301 302 303 --frames 900 [--json-tag TAG]
    .venv/bin/python tools/bench_confidence.py --seeds $(seq 4 20) --frames 900 3000 --fit --json -   # tuning seeds only

Runs on the cached benchmark set (egograph.synth.benchset), SVOE and MVPE: `memory` and `kf` on
reference and robust lifting (the baselines: their operating points), and on robust lifting
`graph` (offline), `graph-causal` (at each --lags) and `memory+graph` (egograph smooth of memory's
results). Per set and threshold it prints each egograph tracker's AP (all-point interpolated),
whether its curve passes at or above every baseline's point, pooled and on every recording, the
IT3DEgo P and R at the default operating point (graph.answers.min_confidence) against the best
baseline, and the expected calibration error (at graph.answers.distance_m).

--fit (tuning seeds only): runs the graph trackers with a calibration that lets every answer's raw
confidence and kind be read back (FIT_KNOTS, FIT_KINDS), and fits, per tracker family (offline:
graph; causal: graph-causal; smooth) and front-end (clean or noisy: graph.answers.noisy_scale),
an isotonic map from raw to calibrated confidence of the stands (egograph.track.answers.isotonic_knots,
blocks of at least --min-share of the answers) and the share within graph.answers.distance_m of
each other kind of answer; prints them for graph.answers.{,noisy_}{offline,causal,smooth}_{calibration,kinds},
the in-sample reliability per kind and, for a grid of operating points, whether P and R at every
threshold reach every baseline's pooled.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
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
from egograph.track.answers import ANSWER_KINDS, STAND, calibrated, isotonic_knots
from egograph.track.registry import graph_with_scene
from egograph.track.smooth import smooth_predictions

REPO = Path(__file__).resolve().parents[1]
BASELINES = ("memory", "kf")
FIT_KNOTS = [[0.0, 0.0], [1.0, 0.5]]
"""--fit: a stand's confidence is half its raw value (raw = 2 x confidence, in [0, 0.5]) ..."""
FIT_KINDS = [0.6, 0.7, 0.8, 0.9, 0.95]
"""... and every other kind (unseen, hand, last, put_down, held) one of these, above every stand's."""
MIN_SHARE = {"offline": 0.3, "noisy_offline": 0.3, "causal": 0.02, "noisy_causal": 0.1, "smooth": 0.05,
             "noisy_smooth": 0.05}
"""--fit: per family and front-end, the smallest share of its stand answers one block of the isotonic
fit holds, chosen among 0.02, 0.05, 0.1, 0.2, 0.3 by the fit on all tuning recordings but one, how well
calibrated it was on the one left out (ECE at graph.answers.distance_m, pooled), among the shares whose
fit on all of them keeps at least two levels (one level ties every stand, and the curves lose the
ranking they are made of). Searched at stop 64 over the 34 tuning recordings (seeds 4-20 at 900 and
3000 frames): offline flat (0.008-0.009), 0.3 kept; noisy_offline best at 0.3 (0.017 against
0.021-0.033); causal best at 0.1-0.3 (0.006), but there one level (0.96 for every stand: AP@0.25 on
MVPE held out 77.3 -> 75.6), so 0.02 (0.017; 0.05: 0.018); noisy_causal best at 0.1 (0.034; 0.05:
0.035); smooth best at 0.3 (0.001), one level, so 0.05 (0.020; 0.02-0.2 the same knots);
noisy_smooth best at 0.05 (0.007). At stop 61, on 14 of them (4-8, 11, 12), noisy_offline had been
best at 0.2 (docs/experiments.md)."""


def decode(a: ScoredAnswers) -> tuple[np.ndarray, np.ndarray]:
    """(raw confidence, kind code) of answers scored with FIT_KNOTS and FIT_KINDS."""
    kind = np.full(len(a.score), STAND, np.int64)
    raw = np.clip(2.0 * a.score, 0.0, 1.0)
    for code, value in enumerate(FIT_KINDS, start=1):
        at = np.abs(a.score - value) < 1e-9
        kind[at] = code
        raw[at] = 0.0
    return raw, kind


def run_recording(root: Path, overrides: list[str], lags: list[float], fit: bool) -> dict:
    """{set: {tracker: ScoredAnswers}} of one recording (with ``fit``: scored so that :func:`decode`
    reads back each answer's raw confidence and kind)."""
    cfg = load_config(EgographConfig, default_config(), overrides)
    if fit:
        for fam in ("offline", "causal", "smooth"):
            for noisy in ("", "noisy_"):
                setattr(cfg.graph.answers, f"{noisy}{fam}_calibration", FIT_KNOTS)
                setattr(cfg.graph.answers, f"{noisy}{fam}_kinds", FIT_KINDS)
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
                    # the scale that picked its calibration: that of memory's distinct sightings
                    scales[(det_set, "memory+graph")] = sm.metadata["calibration_scale"]
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


def fit_calibration(parts: list[dict], cfg, min_share: dict) -> tuple[dict, dict]:
    """Per tracker family and front-end (clean or noisy), the stands' isotonic knots and every
    other kind's share within ``graph.answers.distance_m`` -> ({knob: knots}, {knob: [4 shares]});
    a kind no tuning answer has gets the share of all the family's answers. Printed with the answers per kind."""
    knots, kinds, rows = {}, {}, []
    split = cfg.graph.answers.noisy_scale
    k_cal = THRESHOLDS.index(cfg.graph.answers.distance_m)
    for fam in ("offline", "causal", "smooth"):
        for noisy in (False, True):
            raw, kind, ok = [], [], []
            for p in parts:
                for det_set in ("svoe", "mvpe"):
                    for n, a in p[det_set].items():
                        if family(n) == fam and (p["scales"][(det_set, n)] >= split) == noisy:
                            r, k = decode(a)
                            raw.append(r)
                            kind.append(k)
                            ok.append((a.tp[:, k_cal] > 0).astype(float))
            name = f"{'noisy_' if noisy else ''}{fam}"
            if not raw:
                benchdoc.text(f"graph.answers.{name}_*: no tuning answers (kept)")
                continue
            raw, kind, ok = np.concatenate(raw), np.concatenate(kind), np.concatenate(ok)
            stand = kind == STAND
            if stand.any():
                knots[f"{name}_calibration"] = isotonic_knots(raw[stand], ok[stand], min_share=min_share[name])
                benchdoc.text(f"graph.answers.{name}_calibration: {json.dumps(knots[f'{name}_calibration'])}")
            shares = []  # a kind no tuning answer has: the share of all the family's answers
            for code, label in enumerate(ANSWER_KINDS):
                at = kind == code
                rows.append([name, label, int(at.sum()), f"{ok[at].mean():.3f}" if at.any() else "-"])
                if code:
                    shares.append(round(float(ok[at].mean() if at.any() else ok.mean()), 4))
            kinds[f"{name}_kinds"] = shares
            benchdoc.text(f"graph.answers.{name}_kinds: {json.dumps(shares)}")
    benchdoc.table(f"Tuning answers per tracker family, front-end and kind: how many, and the share within "
                   f"{cfg.graph.answers.distance_m:g} m", ["family", "kind", "answers", "share within"], rows)
    return knots, kinds


def recalibrated(a: ScoredAnswers, knots, kinds) -> ScoredAnswers:
    """Answers scored with FIT_KNOTS/FIT_KINDS, their confidence as ``knots`` and ``kinds`` give it."""
    raw, kind = decode(a)
    score = calibrated(raw, knots)
    for code, value in enumerate(kinds, start=1):
        score[kind == code] = value
    return ScoredAnswers(a.thresholds, score, a.tp, a.n_gt)


def pooled(parts: list[dict], det_set: str, name: str) -> ScoredAnswers:
    return sum((p[det_set][name] for p in parts), ScoredAnswers(THRESHOLDS))


def point(a: ScoredAnswers, k: int, min_conf: float = -np.inf) -> tuple[float, float]:
    keep = a.score >= min_conf
    tp = a.tp[keep, k].sum()
    n = int(keep.sum())
    return (tp / n if n else 0.0), (tp / a.n_gt if a.n_gt else 0.0)


def baseline_points(parts: list[dict]) -> dict:
    """{(set, threshold index): [(baseline, P, R), ...]}: every baseline's point, pooled over ``parts``."""
    points = {}
    for det_set in ("svoe", "mvpe"):
        for b in parts[0][det_set]:
            if family(b):   # an egograph tracker, not a baseline
                continue
            a = pooled(parts, det_set, b)
            for k in range(len(THRESHOLDS)):
                points.setdefault((det_set, k), []).append((b, *point(a, k)))
    return points


def margin(ours: dict, bases: dict, min_conf: float) -> tuple[float, str]:
    """A tracker's smallest margin over every baseline's point at operating point ``min_conf``: the
    minimum over SVOE and MVPE, every threshold and every baseline of its P and R minus the
    baseline's (fractions; >= 0: at or above every point), and where it binds. ``ours``: the
    tracker's pooled answers per set; ``bases``: :func:`baseline_points`."""
    worst, where = np.inf, ""
    for (det_set, k), points in bases.items():
        p, r = point(ours[det_set], k, min_conf)
        for b, pb, rb in points:
            for what, d in (("P", p - pb), ("R", r - rb)):
                if d < worst:
                    worst, where = float(d), f"{det_set.upper()} {what}@{THRESHOLDS[k]:g} vs {b}"
    return worst, where


def widest(margins: dict, names: list[str], grid: np.ndarray) -> float:
    """The operating point of ``grid`` where the smallest of ``names``' margins is widest."""
    return float(grid[int(np.argmax([min(margins[n][i][0] for n in names) for i in range(len(grid))]))])


def report(parts: list[dict], seeds: list, min_conf: dict, tau_cal: float) -> dict:
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
                row["ece"] = round(reliability(a, tau_cal).ece, 4)
                if scope == "pooled":
                    op = [point(a, k, min_conf[family(n)]) for k in range(len(THRESHOLDS))]
                    row["op_p"] = [round(100 * p, 2) for p, _ in op]
                    row["op_r"] = [round(100 * r, 2) for _, r in op]
                    row["op_dominates"] = [all(op[k][0] >= base_pts[b][k][0] - 1e-12 and op[k][1] >= base_pts[b][k][1]
                                               - 1e-12 for b in bases) for k in range(len(THRESHOLDS))]
                    row["reliability"] = reliability(a, tau_cal).to_json_dict()
            if scope == "pooled":
                for b in bases:
                    res.setdefault(b, {})["pooled"] = {"p": [round(100 * p, 2) for p, _ in base_pts[b]],
                                                       "r": [round(100 * r, 2) for _, r in base_pts[b]]}
        labels = [f"{t:g}" for t in THRESHOLDS]
        rows = []
        for n in ours:
            r = res[n]["pooled"]
            per = [all(res[n][str(s)]["passes"]) for s in seeds]
            eces = [res[n][str(s)]["ece"] for s in seeds]
            rows.append([n, *r["ap"], r["ece"], f"{min(eces):.3f}-{max(eces):.3f}", "yes" if all(r["passes"]) else
                         "NO at " + ", ".join(l for l, ok in zip(labels, r["passes"]) if not ok),
                         "yes" if all(per) else "NO on " + "; ".join(
                             f"{s} at " + ",".join(l for l, ok in zip(labels, res[n][str(s)]["passes"]) if not ok)
                             for s, ok in zip(seeds, per) if not ok)])
        benchdoc.table(f"{det_set.upper()}: average precision over confidence (%, all-point interpolated), ECE at "
                       f"{tau_cal:g} m (pooled, and its range over the recordings), and whether each curve passes at "
                       "or above every baseline's point (memory, kf; both liftings) at every threshold",
                       ["tracker", *[f"AP@{l}" for l in labels], "ECE", "ECE per recording", "passes (pooled)",
                        "passes (every recording)"],
                       rows, ["", *[".1f"] * len(labels), ".3f", "", "", ""])
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
    ap.add_argument("--frames", type=int, nargs="+", default=[900],
                    help="recording length(s): every seed at each (a recording is then named seed@frames)")
    ap.add_argument("--lags", type=float, nargs="+", default=[0.0])
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="pipeline override")
    ap.add_argument("--cache", type=Path, default=REPO / ".cache" / "bench")
    add_world_argument(ap)
    ap.add_argument("--fit", action="store_true", help="fit the calibration and choose the operating point "
                                                       "(tuning seeds only)")
    ap.add_argument("--min-share", nargs="+", default=[], metavar="NAME=SHARE",
                    help="--fit: each block of the stands' isotonic fit of NAME (offline, noisy_offline, causal, ...) "
                         "holds at least this share of its answers (default MIN_SHARE)")
    ap.add_argument("--out", type=Path, help="also write every figure (curves' APs, reliability, knots) here as JSON")
    ap.add_argument("--jobs", type=int, default=1, help="recordings run in this many worker processes at once (the "
                                                        "figures do not depend on it)")
    benchdoc.add_arguments(ap, __file__)
    args = ap.parse_args()
    benchdoc.start(__file__, args)
    if args.fit and any(s > 300 for s in args.seeds):
        ap.error("--fit on held-out seeds (301+): fit on tuning seeds only")
    roots = [r for f in args.frames
             for r in benchmark_set(args.seeds, f, config=world_config(args.world), cache=args.cache, progress=False)]
    # one length: recordings named by seed (the records' keys as before); several: seed@frames
    names = list(args.seeds) if len(args.frames) == 1 else [f"{s}@{f}" for f in args.frames for s in args.seeds]
    frames = args.frames[0] if len(args.frames) == 1 else args.frames
    if args.jobs > 1:  # recordings are independent: each in a worker process, pooled in their order
        with ProcessPoolExecutor(args.jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            n = len(roots)
            parts = list(pool.map(run_recording, roots, [args.overrides] * n, [args.lags] * n, [args.fit] * n))
    else:
        parts = [run_recording(r, args.overrides, args.lags, args.fit) for r in roots]
    cfg = load_config(EgographConfig, default_config(), args.overrides)
    doc = {"seeds": args.seeds, "frames": frames, "lags": args.lags, "overrides": args.overrides}
    if args.fit:
        shares = dict(MIN_SHARE)
        for item in args.min_share:
            name, _, value = item.partition("=")
            if name not in shares or not value:
                ap.error(f"--min-share {item}: NAME=SHARE with NAME one of {', '.join(shares)}")
            shares[name] = float(value)
        knots, kinds = fit_calibration(parts, cfg, shares)
        for p in parts:
            for det_set in ("svoe", "mvpe"):
                for n in list(p[det_set]):
                    if family(n):
                        key = f"{'noisy_' if p['scales'][(det_set, n)] >= cfg.graph.answers.noisy_scale else ''}{family(n)}"
                        p[det_set][n] = recalibrated(p[det_set][n], knots.get(f"{key}_calibration", FIT_KNOTS),
                                                     kinds.get(f"{key}_kinds", FIT_KINDS))
        doc["kinds"] = kinds
        doc["knots"] = knots
        grid = np.round(np.concatenate([np.arange(0.0, 0.05, 0.01), np.arange(0.05, 0.96, 0.05)]), 2)
        ours = [n for n in parts[0]["svoe"] if family(n)]
        bases = baseline_points(parts)
        margins = {}
        for n in ours:
            answers = {det_set: pooled(parts, det_set, n) for det_set in ("svoe", "mvpe")}
            margins[n] = [margin(answers, bases, float(c)) for c in grid]
        feasible = {n: [float(c) for c, (m, _) in zip(grid, margins[n]) if m >= -1e-10] for n in ours}
        for n in ours:
            benchdoc.text(f"{n}: operating points (min_confidence) where its P and R >= every baseline's at every "
                          f"threshold, pooled, both sets: {', '.join(f'{c:g}' for c in feasible[n]) or 'none'}")
        benchdoc.table("Operating point: each egograph tracker's smallest margin over the baselines' points (min over "
                       "SVOE and MVPE, every threshold, every baseline, of P and R minus the baseline's, percentage "
                       "points, pooled) at each min_confidence, and where it binds; graph.answers.min_confidence is "
                       "chosen where the smaller of graph's and memory+graph's margins is widest, causal_min_confidence "
                       "where graph-causal's is",
                       ["min_confidence"] + [f"{n} {w}" for n in ours for w in ("margin", "binds at")],
                       [[float(c)] + [x for n in ours for x in (round(100 * margins[n][i][0], 2), margins[n][i][1])]
                        for i, c in enumerate(grid)])
        best = {"min_confidence": widest(margins, [n for n in ours if family(n) in ("offline", "smooth")], grid)}
        causal = [n for n in ours if family(n) == "causal"]
        if causal:
            best["causal_min_confidence"] = widest(margins, causal, grid)
        benchdoc.text("widest margins: " + ", ".join(f"graph.answers.{k} {v:g}" for k, v in best.items()))
        doc["widest_margin_min_confidence"] = best
        doc["feasible_min_confidence"] = feasible
    a = cfg.graph.answers
    doc["sets"] = report(parts, names, {"offline": a.min_confidence, "smooth": a.min_confidence,
                                             "causal": a.causal_min_confidence}, a.distance_m)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(doc, indent=1) + "\n")
    benchdoc.text(f"recordings: seeds {', '.join(map(str, args.seeds))} at {' and '.join(map(str, args.frames))} "
                  f"frames; graph-causal lags "
                  f"{', '.join(f'{x:g}' for x in args.lags)} s")
    benchdoc.finish()


if __name__ == "__main__":
    main()
