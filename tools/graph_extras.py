"""Benchmark pieces for the factor-graph tracker (used by bench_trackers.py): the oracle row,
"+graph" smoothing, interval scores on observable intervals, covariance honesty (NEES), and
the issue's target ratios.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from egograph.core.config import to_dict
from egograph.core.types import Box, Detection, PositionInterval
from egograph.eval.intervals import intervals_from_predictions, score_intervals
from egograph.eval.loader import load_gt_intervals, load_predictions
from egograph.eval.report import EvalReport
from egograph.geometry.lift import lift_recording, synth_lift_errors
from egograph.geometry.observations import Observations
from egograph.steps.pipeline import evaluate, write_results
from egograph.track.graph import fixed_interval_estimate
from egograph.track.intervals import per_frame_predictions
from egograph.track.smooth import smooth_predictions

NEES_MATCH_M = 0.25  # intervals farther than this from their GT are wrong places, not covariance failures


def gt_intervals(rec):
    return load_gt_intervals(rec.annotation_dir / "3d_center_annot.txt")


def observable_intervals(rec, obs: Observations, det_set: str, threshold: float, min_true: int = 3) -> list:
    """GT intervals with at least ``min_true`` lifted true detections scoring >= ``threshold``:
    the ones a detection-based tracker can recover at all."""
    _, true = synth_lift_errors(rec, obs, det_set)
    keep = true & obs.valid & (obs.score >= np.float32(threshold))
    out = []
    for g in gt_intervals(rec):
        m = keep & (obs.instance == g.instance) & (obs.timestamps >= g.t_start) & (obs.timestamps <= g.t_end)
        if m.sum() >= min_true:
            out.append(g)
    return out


def nees_values(intervals: list[PositionInterval], gt: list) -> tuple[list[float], int]:
    """Normalised estimation error squared of interval centres against the GT interval of the
    same instance they overlap most; also the number matched to a GT farther than NEES_MATCH_M."""
    vals, far = [], 0
    for iv in intervals:
        best, overlap = None, 0
        for g in gt:
            if g.instance != iv.instance:
                continue
            o = min(g.t_end, iv.t_end) - max(g.t_start, iv.t_start)
            if o > overlap:
                best, overlap = g, o
        if best is None:
            continue
        e = np.subtract(iv.xyz, best.xyz)
        if np.linalg.norm(e) > NEES_MATCH_M:
            far += 1
            continue
        vals.append(float(e @ np.linalg.solve(np.asarray(iv.covariance), e)))
    return vals, far


def score(reports: dict, extras: dict, det_set: str, name: str, rec, res: Path, per_frame: dict,
          observable: list, intervals: list | None) -> None:
    """Write one tracker's results, evaluate them, and tally the interval-level extras."""
    write_results(res, rec, per_frame)
    full = evaluate(rec, res)
    reports[det_set].setdefault(name, EvalReport())
    reports[det_set][name].add(res.parent.name, next(iter(full.sequences.values())).result, full.intervals, None)
    ts = np.asarray(rec.timestamps)
    preds = intervals_from_predictions(ts, load_predictions(res, ts))
    obs_score = score_intervals(observable, preds, ts)
    ex = extras.setdefault((det_set, name), {"obs_true": 0, "obs_recovered": 0, "nees": [], "far": 0})
    ex["obs_true"] += obs_score.n_true
    ex["obs_recovered"] += obs_score.n_recovered
    if intervals is not None:
        vals, far = nees_values(intervals, gt_intervals(rec))
        ex["nees"] += vals
        ex["far"] += far


def smooth_results(rec, per_frame: dict, cfg):
    """The "+graph" row: another tracker's per-frame output smoothed into intervals."""
    return smooth_predictions(rec, per_frame, cfg.graph)


_ORACLE: dict[str, tuple] = {}


def oracle(rec, root: Path, cfg, det_set: str) -> tuple[dict, list[PositionInterval]]:
    """The ceiling: every true box (synth_gt, frames at least a quarter visible) lifted with the
    pipeline's lifting, each true interval's position solved from its own boxes (robust graph
    landmark); predicted over the whole true interval. Same for both detection sets."""
    key = str(root)
    if key not in _ORACLE:
        with np.load(rec.synth_gt_dir / "instances.npz") as d:
            boxes, visible = d["boxes"], d["visible"]
        dets: dict[int, list[Detection]] = {}
        ts = np.asarray(rec.timestamps)
        for f, i in zip(*np.nonzero((visible >= 0.25) & np.isfinite(boxes[..., 0]))):
            b = boxes[f, i]
            dets.setdefault(int(ts[f]), []).append(Detection(int(i), Box(*map(float, b)), 1.0))
        blob = json.dumps([to_dict(cfg.lift), to_dict(cfg.io)], sort_keys=True)
        path = root / "observations" / f"oracle_{hashlib.sha256(blob.encode()).hexdigest()[:12]}.npz"
        if path.exists():
            obs = Observations.load(path)
        else:
            obs, _ = lift_recording(rec, dets, cfg.lift, progress=False)
            obs.save(path)
        intervals = []
        for g in gt_intervals(rec):
            rows = np.flatnonzero(obs.valid & (obs.instance == g.instance) & (obs.timestamps >= g.t_start)
                                  & (obs.timestamps <= g.t_end))
            if not len(rows):
                continue
            xyz, c = fixed_interval_estimate(obs.world[rows], obs.camera[rows], cfg.graph)
            intervals.append(PositionInterval(g.instance, g.t_start, g.t_end, tuple(map(float, xyz)), c.tolist(),
                                              len(rows), 1.0))
        _ORACLE[key] = (per_frame_predictions(intervals, ts), intervals)
    return _ORACLE[key]


def _ratio(a: float, b: float) -> float:
    return a / b if b else float("nan")


def print_graph_targets(reports: dict, extras: dict) -> None:
    """The interval table and the issue's ratio targets for the graph tracker."""
    print("### Intervals (pooled): true intervals recovered (centre within 0.25 m, temporal IoU >= 0.5)\n")
    print("| set | tracker | recovered / all | recovered / observable | median break error (s) | "
          "NEES mean (expected 3) | intervals > 0.25 m off |")
    print("|---|---|---|---|---|---|---|")
    for det_set, reps in reports.items():
        for name, rep in reps.items():
            iv = rep.intervals
            ex = extras.get((det_set, name), {})
            nees = ex.get("nees", [])
            med = iv.median_break_error_s if iv else None
            print(f"| {det_set} | {name} | {iv.n_recovered}/{iv.n_true} ({100 * iv.recovered_fraction:.0f} %) | "
                  f"{ex.get('obs_recovered', 0)}/{ex.get('obs_true', 0)} "
                  f"({100 * _ratio(ex.get('obs_recovered', 0), ex.get('obs_true', 0)):.0f} %) | "
                  f"{'-' if med is None else f'{med:.2f}'} | "
                  f"{f'{np.mean(nees):.2f} (n={len(nees)})' if nees else '-'} | "
                  f"{ex.get('far', '-') if nees else '-'} |")
    print("\n### Graph tracker targets (ratios measured in this run)\n")
    targets = {  # (row, baseline, metric, op, bound) per set
        "svoe": [("graph", "kf (reference lift)", "P@0.25", ">=", 2.5), ("graph", "kf (reference lift)", "R@0.25", ">=", 2.5),
                 ("graph", "kf (reference lift)", "L2", "<=", 0.5), ("graph-causal", "kf (reference lift)", "P@0.25", ">=", 1.5),
                 ("graph", "kf (robust lift)", "P@0.25", ">=", 1.25), ("graph", "kf (robust lift)", "L2", "<=", 0.7)],
        "mvpe": [("graph", "kf (reference lift)", "P@0.25", ">=", 1.4), ("graph", "kf (reference lift)", "R@0.25", ">=", 1.4),
                 ("graph", "kf (reference lift)", "L2", "<=", 0.5),
                 ("graph", "kf (robust lift)", "P@0.25", ">=", 1.25), ("graph", "kf (robust lift)", "L2", "<=", 0.7)],
    }
    print("| set | row | against | metric | ratio | target | holds |")
    print("|---|---|---|---|---|---|---|")
    for det_set, rows in targets.items():
        reps = reports.get(det_set, {})
        for row, base, metric, op, bound in rows:
            a, b = reps.get(f"{row} (robust lift)"), reps.get(base)
            if a is None or b is None:
                continue
            va, vb = _metric(a.total, metric), _metric(b.total, metric)
            r = _ratio(va, vb)
            ok = r >= bound if op == ">=" else r <= bound
            print(f"| {det_set} | {row} | {base} | {metric} | {r:.2f} | {op} {bound} | {'yes' if ok else 'NO'} |")


def _metric(c, metric: str) -> float:
    if metric == "P@0.25":
        return c.precision[0]
    if metric == "R@0.25":
        return c.recall[0]
    return c.l2_m
