#!/usr/bin/env python
"""Joint mode (``egograph track --tracker graph --joint-poses``) on the benchmark set.

    .venv/bin/python tools/bench_joint.py [--seeds 1 2 3 4 5] [--set joint.noise_scale=1]
    .venv/bin/python tools/bench_joint.py --synth-set pose_error.drift_trans=... # a harder pose setting

Per cached benchmark recording (egograph.synth.benchset) and detection set, with the same robust
observations as tools/bench_trackers.py, four pose sources for the offline graph tracker:

* ``reported``: the recording's poses;
* ``refined``: ``egograph refine`` (``cfg.refine``: HoloLens model + mesh ICP by default);
* ``joint``: the same refinement factors plus the landmarks of the stands the tracker found
  (``--joint-poses``), then the tracker again;
* ``joint, no mesh``: HoloLens model + landmarks only (what the objects alone contribute).

Reports ATE (unaligned and SE(3)-aligned) of the PV poses against synth_gt, the tracker's
P/R at 0.25 m (pooled counts) and the time per stage. Observations for the refined rows are
the reported-pose observations moved by each frame's world correction (what lifting with
those poses gives: world = AHAT point · AHAT pose, and the AHAT pose moves with the PV pose).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import benchdoc
import numpy as np

from egograph.core.config import load_config
from egograph.core.resources import default_config
from egograph.eval.metrics import IntervalTally, gt_intervals
from egograph.eval.report import EvalReport
from egograph.io.poses import read_pose_json
from egograph.poses.evaluate import evaluate_trajectory
from egograph.poses.refine import refinement_factors, world_corrections
from egograph.steps.evaluate import evaluate
from egograph.steps.joint import track_joint as track_graph_joint
from egograph.steps.recording import open_recording
from egograph.steps.settings import EgographConfig
from egograph.steps.track import write_results
from egograph.synth.benchset import add_world_argument, benchmark_set, cached_observations, world_config
from egograph.track.joint import joint_poses, move_observations, with_joint_poses
from egograph.track.registry import graph_with_scene as track_graph

REPO = Path(__file__).resolve().parents[1]
DEFAULT_CACHE = REPO / ".cache" / "bench"
ROWS = ("reported", "refined", "joint", "joint, no mesh")


def score(reports: dict, tallies: dict, det_set: str, name: str, rec, res: Path, per_frame: dict,
          observable: list) -> None:
    """Write one row's results to ``res``, evaluate them, and tally the true intervals recovered."""
    write_results(res, rec, per_frame)
    full = evaluate(rec, res)
    reports[det_set].setdefault(name, EvalReport())
    reports[det_set][name].add(res.parent.name, next(iter(full.sequences.values())).result, full.intervals, None)
    tallies.setdefault((det_set, name), IntervalTally()).add(observable, res, rec.timestamps)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--frames", type=int, default=3000)
    add_world_argument(ap)
    ap.add_argument("--synth-set", dest="synth_overrides", action="append", default=[],
                    help="generator override for the benchmark set (a separate cached set)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="pipeline override")
    ap.add_argument("--out", type=Path, default=REPO / ".cache" / "bench_joint")
    benchdoc.add_arguments(ap, __file__)
    args = ap.parse_args()
    benchdoc.start(__file__, args)
    cfg = load_config(EgographConfig, default_config(), args.overrides)
    cfg_nomesh = load_config(EgographConfig, default_config(), [*args.overrides, "refine.mesh=false"])
    roots = benchmark_set(args.seeds, args.frames, config=world_config(args.world), overrides=args.synth_overrides,
                          cache=DEFAULT_CACHE, progress=False)
    reports: dict[str, dict] = {"svoe": {}, "mvpe": {}}   # score(): EvalReport per row
    tallies: dict[tuple[str, str], IntervalTally] = {}     # ... and the true intervals recovered
    ate: dict[tuple[str, str], list] = {}
    secs: dict[str, float] = {}

    def timed(name: str, t0: float) -> None:
        secs[name] = secs.get(name, 0.0) + time.perf_counter() - t0

    for seed, root in zip(args.seeds, roots):
        rec = open_recording(root, cfg)
        _, gt, _ = read_pose_json(rec.synth_gt_dir / "pv_pose.json")
        t0 = time.perf_counter()
        factors = {"joint": refinement_factors(rec, cfg.refine, confirm_jumps_now=False)}
        timed("refinement factors (mesh ICP)", t0)
        t0 = time.perf_counter()
        factors["joint, no mesh"] = refinement_factors(rec, cfg_nomesh.refine, confirm_jumps_now=False)
        timed("refinement factors (HoloLens only)", t0)
        t0 = time.perf_counter()
        # no stands: exactly ``egograph refine`` (solve, jump test, solve again)
        refined = joint_poses(rec, [], cfg.refine, cfg.graph.noise, cfg.joint, factors=factors["joint"])
        timed("refine solve", t0)
        ate.setdefault(("reported", "-"), []).append(evaluate_trajectory(rec.pv_poses, gt))
        ate.setdefault(("refined", "-"), []).append(evaluate_trajectory(refined.pv_poses, gt))
        line = [f"seed {seed}: ATE reported {100 * ate[('reported', '-')][-1].ate_rmse_m:.2f} cm",
                f"refined {100 * ate[('refined', '-')][-1].ate_rmse_m:.2f}"]
        for det_set in ("svoe", "mvpe"):
            cfg.lift.mode = "robust"
            obs, _ = cached_observations(rec, det_set, cfg)  # shared with tools/bench_trackers.py
            out = args.out / root.name
            everything = gt_intervals(rec)  # interval recall over all true intervals

            def tally(row: str, per_frame: dict) -> None:
                res = out / f"{det_set}_{row.replace(', ', '_').replace(' ', '_')}"
                score(reports, tallies, det_set, row, rec, res, per_frame, everything)

            t0 = time.perf_counter()
            tally("reported", track_graph(rec, obs, cfg).per_frame)
            timed("graph", t0)
            moved = move_observations(obs, world_corrections(rec, refined.pv_poses))
            tally("refined", track_graph(with_joint_poses(rec, refined), moved, cfg).per_frame)
            for row, c in (("joint", cfg), ("joint, no mesh", cfg_nomesh)):
                t0 = time.perf_counter()
                result, jp = track_graph_joint(rec, obs, c, factors=factors[row])
                timed(f"{row}: graph + joint solve + graph", t0)
                tally(row, result.per_frame)
                e = evaluate_trajectory(jp.pv_poses, gt)
                ate.setdefault((row, det_set), []).append(e)
                line.append(f"{row} ({det_set}) {100 * e.ate_rmse_m:.2f} [{jp.report['stands']} stands, "
                            f"{jp.report['detection_factors']} factors]")
        print("; ".join(line), flush=True)

    def mean_ate(key) -> list:
        es = ate[key]
        return [100 * np.mean([e.ate_rmse_m for e in es]), 100 * np.mean([e.ate_rmse_aligned_m for e in es]),
                np.mean([e.ate_rmse_m for e in es]) / np.mean([e.ate_rmse_m for e in ate[('reported', '-')]])]

    print()
    rows = []
    for row in ROWS:
        for det_set in ("svoe", "mvpe"):
            c, t = reports[det_set][row].total, tallies[(det_set, row)]
            k = list(c.thresholds).index(0.25)
            key = (row, det_set) if (row, det_set) in ate else (row, "-")
            rows.append([row, det_set, *mean_ate(key), 100 * c.precision[k], 100 * c.recall[k],
                         [t.obs_recovered, t.obs_true]])
    benchdoc.table("Joint mode: PV pose error and the graph tracker per pose source",
                   ["poses", "det. set", "ATE (cm)", "ATE aligned (cm)", "ATE ratio", "P@0.25", "R@0.25", "intervals"],
                   rows, ["", "", ".2f", ".2f", ".2f", ".1f", ".1f", "{0}/{1}"],
                   note=f"Benchmark set: {len(roots)} recordings x {args.frames} frames (seeds "
                        f"{', '.join(map(str, args.seeds))}); ATE of the PV poses (mean over recordings; ratio "
                        "against reported), graph tracker P/R at 0.25 m (pooled), true intervals recovered.")
    benchdoc.text("time (s, whole set): " + ", ".join(f"{k} {v:.1f}" for k, v in secs.items()))
    benchdoc.finish()


if __name__ == "__main__":
    main()
