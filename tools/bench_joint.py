#!/usr/bin/env python
"""Joint mode (``egograph track --tracker graph --joint-poses``) on the benchmark set.

    .venv/bin/python tools/bench_joint.py [--seeds 1 2 3 4 5] [--set joint.noise_scale=1]
    .venv/bin/python tools/bench_joint.py --synth-set pose_error.drift_trans=... # a harder pose setting

Per cached benchmark recording (tools/benchset.py) and detection set, with the same robust
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
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_trackers import cache_key  # noqa: E402
from benchset import DEFAULT_CACHE, benchmark_set  # noqa: E402
from graph_extras import gt_intervals, score  # noqa: E402

from egograph.core.config import load_config  # noqa: E402
from egograph.geometry.observations import Observations  # noqa: E402
from egograph.io.poses import read_pose_json  # noqa: E402
from egograph.poses.evaluate import evaluate_trajectory  # noqa: E402
from egograph.poses.refine import refinement_factors, world_corrections  # noqa: E402
from egograph.steps.pipeline import lift, open_recording, track_graph, track_graph_joint  # noqa: E402
from egograph.steps.settings import EgographConfig  # noqa: E402
from egograph.track.joint import joint_poses, move_observations, with_joint_poses  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
ROWS = ("reported", "refined", "joint", "joint, no mesh")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--synth-set", dest="synth_overrides", action="append", default=[],
                    help="generator override for the benchmark set (a separate cached set)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="pipeline override")
    ap.add_argument("--out", type=Path, default=REPO / ".cache" / "bench_joint")
    args = ap.parse_args()
    cfg = load_config(EgographConfig, REPO / "configs" / "default.yaml", args.overrides)
    cfg_nomesh = load_config(EgographConfig, REPO / "configs" / "default.yaml", [*args.overrides, "refine.mesh=false"])
    roots = benchmark_set(args.seeds, args.frames, overrides=args.synth_overrides, cache=DEFAULT_CACHE,
                          progress=False)
    reports: dict[str, dict] = {"svoe": {}, "mvpe": {}}   # graph_extras.score: EvalReport per row
    extras: dict[tuple[str, str], dict] = {}               # ... and the true intervals recovered
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
            path = root / "observations" / f"{det_set}_robust_{cache_key(root, cfg)}.npz"
            if path.exists():
                obs = Observations.load(path)
            else:  # shared with tools/bench_trackers.py
                obs, _ = lift(rec, det_set, cfg, progress=False)
                obs.save(path)
            out = args.out / root.name
            everything = gt_intervals(rec)  # interval recall over all true intervals

            def tally(row: str, per_frame: dict) -> None:
                score(reports, extras, det_set, row, rec, out / f"{det_set}_{row.replace(', ', '_').replace(' ', '_')}",
                      per_frame, everything, None)

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

    def mean_ate(key) -> str:
        es = ate[key]
        return (f"{100 * np.mean([e.ate_rmse_m for e in es]):.2f} | {100 * np.mean([e.ate_rmse_aligned_m for e in es]):.2f} | "
                f"{np.mean([e.ate_rmse_m for e in es]) / np.mean([e.ate_rmse_m for e in ate[('reported', '-')]]):.2f}")

    print(f"\nBenchmark set: {len(roots)} recordings x {args.frames} frames (seeds {', '.join(map(str, args.seeds))}); "
          "ATE of the PV poses (mean over recordings; ratio against reported), graph tracker P/R at 0.25 m "
          "(pooled), true intervals recovered\n")
    print("| poses | det. set | ATE (cm) | ATE aligned (cm) | ATE ratio | P@0.25 | R@0.25 | intervals |")
    print("|---|---|---|---|---|---|---|---|")
    for row in ROWS:
        for det_set in ("svoe", "mvpe"):
            c, ex = reports[det_set][row].total, extras[(det_set, row)]
            k = list(c.thresholds).index(0.25)
            p, r = 100 * c.precision[k], 100 * c.recall[k]
            key = (row, det_set) if (row, det_set) in ate else (row, "-")
            print(f"| {row} | {det_set} | {mean_ate(key)} | {p:.1f} | {r:.1f} | {ex['obs_recovered']}/{ex['obs_true']} |")
    print("\ntime (s, whole set): " + ", ".join(f"{k} {v:.1f}" for k, v in secs.items()))


if __name__ == "__main__":
    main()
