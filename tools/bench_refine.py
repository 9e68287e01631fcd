"""Benchmark of the pose refinement (``egograph refine``) on the cached benchmark set.

Per recording and per source configuration (HoloLens only, +KISS-ICP, +mesh ICP, +COLMAP,
all): ATE (unaligned and SE(3)-aligned) and RPE of the refined PV poses against
``synth_gt/``, how far the poses moved, and the time per stage.

    .venv/bin/python tools/bench_refine.py --seeds 1 2 --frames 3000
    .venv/bin/python tools/bench_refine.py --seeds 1 --frames 3000 --no-error     # no-harm check
    .venv/bin/python tools/bench_refine.py --seeds 1 --frames 300 --rgb --rows colmap all   # COLMAP rows

The RGB set (``--rgb``) is cached separately (``.cache/bench_rgb/``) because the main set
has no PV images. Writes a JSON of every figure with ``--json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from egograph.core.resources import synth_config

REPO = Path(__file__).resolve().parents[1]
SYNTH_CONFIG = synth_config("svoe")
DEFAULT_CACHE = REPO / ".cache" / "bench"
RGB_CACHE = REPO / ".cache" / "bench_rgb"

ROWS = {
    "hololens": ["icp=false", "mesh=false", "colmap=false"],
    "+kiss": ["icp=true", "mesh=false", "colmap=false"],
    "+mesh": ["icp=false", "mesh=true", "colmap=false"],
    "+colmap": ["icp=false", "mesh=false", "colmap=true"],
    "all": ["icp=true", "mesh=true", "colmap=true"],
    "all-no-colmap": ["icp=true", "mesh=true", "colmap=false"],
    "mesh+colmap": ["icp=false", "mesh=true", "colmap=true"],
}


def run(root: Path, rows: list[str], extra: list[str], rpe_delta: int, out_dir: Path | None = None) -> list[dict]:
    from egograph.core.config import load_config
    from egograph.io.poses import read_pose_json
    from egograph.io.recording import Recording
    from egograph.poses.config import RefineConfig
    from egograph.poses.evaluate import evaluate_trajectory
    from egograph.poses.refine import refine_recording

    rec = Recording.open(root, invalid_poses="skip")
    _, gt, _ = read_pose_json(rec.synth_gt_dir / "pv_pose.json")
    out = [{"recording": str(root), "row": "reported", **evaluate_trajectory(rec.pv_poses, gt, rpe_delta).as_dict()}]
    for row in rows:
        cfg = load_config(RefineConfig, None, [*ROWS[row], *extra])
        t = time.perf_counter()
        r = refine_recording(rec, cfg, progress=False)
        total = time.perf_counter() - t
        e = evaluate_trajectory(r.pv_poses, gt, rpe_delta).as_dict()
        if out_dir is not None:
            from egograph.poses.refine import write_refined

            write_refined(r, Path(out_dir) / root.name / row.replace("+", "plus_"), rec, cfg,
                          {"eval_reported": out[0], "eval_refined": e})
        out.append({"recording": str(root), "row": row, **e, "seconds": total, "stages": r.stage_seconds,
                    "change": r.change, "factors": r.factor_counts,
                    "stats": {k: v for k, v in r.stats.items() if k != "solver"}})
        print(f"{root.name} {row:>14}: ATE {e['ate_rmse_m'] * 100:.2f} cm (aligned {e['ate_rmse_aligned_m'] * 100:.2f}), "
              f"RPE {e['rpe_trans_m'] * 1000:.2f} mm / {e['rpe_rot_deg']:.3f} deg, moved "
              f"{r.change.get('trans_rms_m', 0) * 1000:.1f} mm rms ({r.change.get('trans_max_m', 0) * 1000:.1f} max) / "
              f"{r.change.get('rot_rms_deg', 0):.3f} deg rms ({r.change.get('rot_max_deg', 0):.3f} max), "
              f"{total:.1f} s " + " ".join(f"{k}={v:.1f}" for k, v in r.stage_seconds.items()), flush=True)
    return out


def table(results: list[dict]) -> str:
    import numpy as np

    rows = []
    for name in dict.fromkeys(r["row"] for r in results):
        sel = [r for r in results if r["row"] == name]
        m = lambda k: float(np.mean([r[k] for r in sel]))  # noqa: E731
        ch = [r.get("change", {}) for r in sel]
        moved = (f"{np.mean([c.get('trans_rms_m', 0) for c in ch]) * 1000:.1f} / "
                 f"{np.mean([c.get('rot_rms_deg', 0) for c in ch]):.3f}") if name != "reported" else "-"
        secs = f"{m('seconds'):.0f}" if name != "reported" else "-"
        rows.append(f"| {name} | {m('ate_rmse_m') * 100:.2f} | {m('ate_rmse_aligned_m') * 100:.2f} | "
                    f"{m('rpe_trans_m') * 1000:.2f} | {m('rpe_rot_deg'):.3f} | {moved} | {secs} |")
    head = ("| poses | ATE (cm) | ATE aligned (cm) | RPE (mm) | RPE (deg) | moved rms (mm / deg) | seconds |\n"
            "|---|---|---|---|---|---|---|")
    return head + "\n" + "\n".join(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--rows", nargs="+", default=["hololens", "+kiss", "+mesh", "all-no-colmap"], choices=list(ROWS))
    ap.add_argument("--rgb", action="store_true", help="use the cached RGB set (needed by the COLMAP rows)")
    ap.add_argument("--no-error", action="store_true", help="no-harm check: the true poses as the reported ones "
                                                            "(same as pose_error.enabled=false, without regenerating)")
    ap.add_argument("--synth-set", dest="synth_overrides", action="append", default=[], help="generator override")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="refine.* override (without 'refine.')")
    ap.add_argument("--rpe-delta", type=int, default=1)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--out-dir", type=Path, help="also write each row's refined poses to OUT_DIR/<seed>/<row>/")
    a = ap.parse_args()
    syn = list(a.synth_overrides)
    from egograph.synth.benchset import benchmark_set, exact_poses_view, rgb_benchmark_set

    if a.rgb:
        roots = rgb_benchmark_set(a.seeds, a.frames, config=SYNTH_CONFIG, cache=RGB_CACHE, overrides=syn)
    else:
        roots = benchmark_set(a.seeds, a.frames, config=SYNTH_CONFIG, cache=DEFAULT_CACHE, overrides=syn)
    if a.no_error:
        roots = [exact_poses_view(r) for r in roots]
    results = []
    for root in roots:
        results += run(root, a.rows, a.overrides, a.rpe_delta, a.out_dir)
    print()
    print(table(results))
    if a.json:
        a.json.write_text(json.dumps(results, indent=1, default=str))


if __name__ == "__main__":
    main()
