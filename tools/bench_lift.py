#!/usr/bin/env python
"""Benchmark lifting (robust vs reference mode) on synthetic SVOE recordings without RGB.

For every seed it generates (or reuses from the cache) a recording, lifts one detection
set with both modes, and prints the 3D error of the lifted TRUE detections against
``synth_gt`` (median, mean, 90th percentile; resting vs carried objects; both modes also with
the true poses, i.e. the lifting error alone), and the speed of each mode in the same
run: frames/s and detections/s of the lifting loop (set-up excluded: rays, open3d import,
mesh ray-casting scene), next to the floor of reading the same depth frames (PNG decode
only, on one thread and on ``lift.decode_threads`` threads). Both modes decode the next depth
frames on those threads (2 by default) while lifting the current one. Speeds depend on what
else runs on the machine: run it alone.

    .venv/bin/python tools/bench_lift.py --frames 1500 --seeds 1 2
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import benchdoc
import numpy as np

from egograph.geometry.config import LiftConfig
from egograph.geometry.lift import lift_recording
from egograph.io.detections import read_detection_dir
from egograph.io.poses import read_pose_json
from egograph.io.recording import Recording
from egograph.synth.benchset import add_world_argument, benchmark_set, world_config
from egograph.synth.truth import synth_lift_errors

REPO = Path(__file__).resolve().parents[1]


def recording(cache: Path, frames: int, seed: int, world: str = "device") -> Path:
    """The cached SVOE recording of ``frames`` frames for ``seed`` in the benchmark ``world``
    (egograph.synth.benchset: generated when missing, detections re-simulated when the front-end changed)."""
    return benchmark_set([seed], frames, config=world_config(world), cache=cache, progress=True)[0]


def decode_seconds(rec: Recording, frames: list[int], threads: int = 1) -> float:
    """Wall time to read (PNG-decode) the depth frames on ``threads`` threads (warm the file
    cache first: see the caller)."""
    t = time.perf_counter()
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for _ in pool.map(rec.depth_raw, frames):
            pass
    return time.perf_counter() - t


def row_stats(rec: Recording, obs, det_set: str) -> dict[str, np.ndarray]:
    """Per observation row: error to the true centre (m), is-true, lifted, object carried (moving)."""
    err, true = synth_lift_errors(rec, obs, det_set)
    with np.load(rec.synth_gt_dir / "instances.npz") as data:
        moving = data["moving"][obs.frame, obs.instance]
    return {"err": err, "true": true, "valid": obs.valid, "moving": moving}


ERROR_COLUMNS = ["mode", "lifted / true", "median", "mean", "p90", "med rest", "carried (count)"]
ERROR_FORMATS = ["", "{0}/{1}", ".3f", ".3f", ".3f", ".3f", "{0:.3f} ({1})"]


def error_line(name: str, rows: dict[str, np.ndarray], mask: np.ndarray) -> list:
    """One row of an error table (ERROR_COLUMNS): metres; carried = object in hand."""
    e, mv = rows["err"][mask], rows["moving"][mask]
    rest = np.median(e[~mv]) if (~mv).any() else float("nan")
    car = np.median(e[mv]) if mv.any() else float("nan")
    return [name, [mask.sum(), rows["true"].sum()], np.median(e), e.mean(), np.percentile(e, 90), rest,
            [car, mv.sum()]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1500, help="frames per recording (30 fps)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--cache", type=Path, default=REPO / ".cache" / "bench_lift",
                    help="where generated recordings are kept and reused")
    ap.add_argument("--set", dest="det_set", default="svoe", help="detection set to lift (svoe or mvpe)")
    add_world_argument(ap)
    benchdoc.add_arguments(ap, __file__)
    args = ap.parse_args()
    benchdoc.start(__file__, args)

    modes = {"robust": LiftConfig(), "reference": LiftConfig(mode="reference"),
             "robust, true poses": LiftConfig(), "reference, true poses": LiftConfig(mode="reference")}
    rows: dict[str, list[dict]] = {m: [] for m in modes}
    speed = {m: {"loop_s": 0.0, "setup_s": 0.0, "frames": 0, "dets": 0} for m in modes}
    threads = LiftConfig().decode_threads
    floor_s, floor_frames, floor_mt_s = 0.0, 0, 0.0
    for seed in args.seeds:
        root = recording(args.cache, args.frames, seed, args.world)
        rec = Recording.open(root)
        dets = read_detection_dir(rec.detections_dir(args.det_set), rec.timestamps)
        frames = [rec.index_of(t) for t, d in dets.items() if d]
        for i in frames:  # one warm-up pass, so both timings read from the file cache
            rec.depth_raw(i)
        floor_s += decode_seconds(rec, frames)
        floor_mt_s += decode_seconds(rec, frames, threads)
        floor_frames += len(frames)
        for name, cfg in modes.items():
            if name == "robust, true poses":  # the last two: this overwrites the reported poses of the Recording
                _, pv, _ = read_pose_json(rec.synth_gt_dir / "pv_pose.json")
                _, dp, _ = read_pose_json(rec.synth_gt_dir / "depth_ahat_pose.json")
                rec.pv_poses[:], rec.depth_poses[:] = pv, dp
            obs, rep = lift_recording(rec, dets, cfg, progress=False)
            rows[name].append(row_stats(rec, obs, args.det_set))
            sp = speed[name]
            sp["loop_s"] += rep.seconds - rep.setup_seconds
            sp["setup_s"] += rep.setup_seconds
            sp["frames"] += rep.n_frames
            sp["dets"] += rep.n_detections
            print(f"seed {seed} {name}: {rep.summary()}", flush=True)
    # Rows line up across modes: every mode keeps one row per detection at a known frame.
    cat = {m: {k: np.concatenate([r[k] for r in rs]) for k in rs[0]} for m, rs in rows.items()}
    rob, ref = cat["robust"], cat["reference"]

    print(f"\n{len(args.seeds)} recording(s) x {args.frames} frames, detection set {args.det_set}\n")
    benchdoc.table(f"{args.det_set.upper()}: 3D error of lifted true detections vs synth_gt (m)", ERROR_COLUMNS,
                   [error_line(name, r, r["true"] & r["valid"]) for name, r in cat.items()], ERROR_FORMATS,
                   note=f"{len(args.seeds)} recording(s) x {args.frames} frames (seeds {', '.join(map(str, args.seeds))}); "
                        "carried = object in hand (median error, count); \"true poses\" = the lifting error alone.")
    common_rows, ratios = [], []
    for suffix in ("", ", true poses"):
        rob_s, ref_s = cat["robust" + suffix], cat["reference" + suffix]
        common = rob_s["true"] & rob_s["valid"] & ref_s["valid"]
        common_rows += [error_line("robust" + suffix, rob_s, common), error_line("reference" + suffix, ref_s, common)]
        e_rob, e_ref = rob_s["err"][common], ref_s["err"][common]
        ratios.append(f"reference / robust{suffix}: median x{np.median(e_ref) / np.median(e_rob):.1f}, "
                      f"mean x{e_ref.mean() / e_rob.mean():.1f}")
    benchdoc.table(f"{args.det_set.upper()}: on the true detections both modes lift (m)", ERROR_COLUMNS, common_rows,
                   ERROR_FORMATS, note="; ".join(ratios))
    only_ref = rob["true"] & ~rob["valid"] & ref["valid"]
    e_only = np.median(ref["err"][only_ref]) if only_ref.any() else float("nan")
    benchdoc.text(f"true detections robust mode does not lift: {(rob['true'] & ~rob['valid']).sum()} (reference lifts "
                  f"{only_ref.sum()} of them, median error {e_only:.2f} m)")
    print()
    speed_rows = []
    for name in ("robust", "reference"):
        a = speed[name]
        speed_rows.append([name, a["frames"] / a["loop_s"], a["dets"] / a["loop_s"], 1000 * a["loop_s"] / a["frames"],
                           a["setup_s"]])
    speed_rows.append(["PNG decode only", floor_frames / floor_s, "", 1000 * floor_s / floor_frames, ""])
    speed_rows.append([f"PNG decode, {threads} threads", floor_frames / floor_mt_s, "",
                       1000 * floor_mt_s / floor_frames, ""])
    r, f = speed["robust"], speed["reference"]
    ratio = (f["loop_s"] / f["frames"]) / (r["loop_s"] / r["frames"])
    cap = (f["loop_s"] / f["frames"]) / (floor_mt_s / floor_frames)
    benchdoc.table(f"{args.det_set.upper()}: lifting speed (lifting loop; set-up excluded, shown apart)",
                   ["mode", "frames/s", "dets/s", "ms/frame", "set-up s"], speed_rows,
                   ["", ".1f", ".1f", ".2f", ".2f"],
                   note=f"robust is x{ratio:.1f} faster per frame than reference (lift.decode_threads={threads}); "
                        f"decoding alone on {threads} threads takes "
                        f"{100 * (floor_mt_s / floor_frames) / (r['loop_s'] / r['frames']):.0f}% of robust's time per "
                        f"frame, so no lifting that decodes every depth frame can be more than x{cap:.1f} faster than "
                        "reference here")
    benchdoc.finish()


if __name__ == "__main__":
    main()
