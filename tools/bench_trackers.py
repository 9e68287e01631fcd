#!/usr/bin/env python
"""The tracker benchmark: every tracker on the same observations of the benchmark set,
SVOE and MVPE, both lifting modes, compared under the IT3DEgo protocol.

    .venv/bin/python tools/bench_trackers.py --seeds 1 2 3 4 5 --frames 3000 [--out DIR] [--world device legacy]

Builds (or reuses) the cached benchmark set (egograph.synth.benchset), lifts each detection set
with `reference` and `robust` lifting (observations cached beside the recordings), runs
`memory`, `kf`, `graph` (offline), `graph-causal`, the "+graph" smoothing of `memory` and
`kf` results, and an `oracle` row (true boxes lifted, true intervals), and prints one table
per setting in the layout of the paper's tables, with ratios against `kf` on `reference`
lifting (the published pipeline), then the interval-level scores and the graph's targets. Totals pool the
counts of all recordings, as the reference evaluator does over sequences. Also prints the
3D error of lifted true detections per lifting mode, lifting speed, and the calibration
bands of the synthetic front-end (memory + reference lifting).

``--world`` names the generator world of the set (default ``device``); with two (``--world device
legacy``) the same seeds are built and tracked in both, every table is of the first, and a last
table sets the calibration bands and the graph's targets of each world side by side (does a tracker's
figure depend on how the pixels look, when the detections are simulated?).
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
from egograph.eval.metrics import IntervalTally, dominance_misses, gt_intervals, observable_intervals, ratio, target_checks
from egograph.eval.report import EvalReport, comparison_json, comparison_table, plot_pr
from egograph.io.atomic import atomic_write_text
from egograph.poses.refine import apply_poses
from egograph.steps.evaluate import evaluate
from egograph.steps.recording import open_recording
from egograph.steps.settings import EgographConfig
from egograph.steps.track import track as _track_step
from egograph.steps.track import write_results
from egograph.synth.benchset import BENCH_WORLDS, ORACLE, benchmark_set, cached_observations, world_config
from egograph.synth.calibrate import BANDS, PAPER, band_values, bootstrap_se, pooled_values
from egograph.synth.oracle import oracle_tracker
from egograph.synth.truth import never_visible_intervals, synth_lift_errors
from egograph.track.registry import INTERVAL_TRACKERS as GRAPH_TRACKERS
from egograph.track.registry import graph_with_scene as track_graph
from egograph.track.smooth import smooth_predictions

REPO = Path(__file__).resolve().parents[1]
DEFAULT_CACHE = REPO / ".cache" / "bench"
TRACKERS = ("memory", "kf", "graph", "graph-causal")
SMOOTHED = ("memory", "kf")  # trackers whose per-frame output also gets the "+graph" smoothing row
MODES = ("reference", "robust")


def score(reports: dict, tallies: dict, det_set: str, name: str, rec, res: Path, per_frame: dict,
          observable: list, intervals: list | None) -> None:
    """Write one tracker's results to ``res``, evaluate them, and tally the interval-level extras."""
    write_results(res, rec, per_frame)
    full = evaluate(rec, res)
    reports[det_set].setdefault(name, EvalReport())
    reports[det_set][name].add(res.parent.name, next(iter(full.sequences.values())).result, full.intervals, None)
    tally = tallies.setdefault((det_set, name), IntervalTally())
    tally.add(observable, res, rec.timestamps, intervals, gt_intervals(rec) if intervals is not None else ())


def calibration_bands(per_set: dict[str, list]) -> tuple[list[str], bool | None]:
    """The simulated front-ends' calibration bands (egograph.synth.calibrate.BANDS) checked on memory +
    reference lifting: ``per_set`` maps a detection set to its recordings' counts
    (egograph.eval.protocol.Counts). -> (one line per band and the verdict, True / False; None when no
    set had memory on reference lifting, as in a ``--modes robust`` run: then nothing was checked, and
    the last line says so rather than that every band holds)."""
    lines, verdict = [], None
    for det_set, bands in BANDS.items():
        per = per_set.get(det_set)
        if not per:
            continue
        vals, se = pooled_values(per), bootstrap_se(per)
        for k, (lo, hi) in bands.items():
            ok = lo <= vals[k] <= hi
            verdict = ok if verdict is None else verdict and ok
            third = (hi - lo) / 6
            lines.append(f"{det_set} {k}: {vals[k]:.2f} ± {se[k]:.2f} in [{lo}, {hi}] {'OK' if ok else 'OUT'} (centre "
                         f"{(lo + hi) / 2:g}, paper {PAPER[det_set][k]:g}; standard error "
                         f"{'<=' if se[k] <= third else '>'} a third of the half-width, {third:.2f}; per recording "
                         f"{', '.join(f'{band_values(c)[k]:.2f}' for c in per)})")
    lines.append("\nall bands hold: " + (str(verdict) if verdict is not None else
                                         "not checked (no memory on reference lifting in this run: `--modes robust`)"))
    return lines, verdict


def print_graph_targets(reports: dict, tallies: dict) -> None:
    """The interval table and the issue's ratio targets for the graph tracker."""
    rows = []
    for det_set, reps in reports.items():
        for name, rep in reps.items():
            iv = rep.intervals
            t = tallies.get((det_set, name), IntervalTally())
            med = iv.median_break_error_s if iv else None
            rows.append([det_set, name, [iv.n_recovered, iv.n_true, 100 * iv.recovered_fraction],
                         [t.obs_recovered, t.obs_true, 100 * ratio(t.obs_recovered, t.obs_true)],
                         "-" if med is None else med, [np.mean(t.nees), len(t.nees)] if t.nees else "-",
                         t.far if t.nees else "-"])
    benchdoc.table("Intervals (pooled): true intervals recovered (centre within 0.25 m, temporal IoU >= 0.5)",
                   ["set", "tracker", "recovered / all", "recovered / observable", "median break error (s)",
                    "NEES mean (expected 3)", "intervals > 0.25 m off"], rows,
                   ["", "", "{0}/{1} ({2:.0f} %)", "{0}/{1} ({2:.0f} %)", ".2f", "{0:.2f} (n={1})", ""])
    benchdoc.table("Graph tracker targets (ratios measured in this run)",
                   ["set", "row", "against", "metric", "ratio", "target", "holds"],
                   [[c.det_set, c.row, c.against, c.metric, c.ratio, f"{c.op} {c.bound}", c.holds]
                    for c in target_checks(reports)], ["", "", "", "", ".2f", "", "yes|NO"])


def print_dominance(reports: dict) -> None:
    """Does each egograph tracker beat memory and kf (robust lift) at every threshold, P and R,
    with a lower L2? Offline graph: pooled and on every recording; graph-causal: pooled."""
    rows = []
    for det_set, reps in reports.items():
        base = {k: reps[f"{k} (robust lift)"] for k in ("memory", "kf") if f"{k} (robust lift)" in reps}
        for row, per_seq in (("graph", True), ("graph-causal", False)):
            ours = reps.get(f"{row} (robust lift)")
            if ours is None or not base:
                continue
            misses = dominance_misses(ours, base, per_sequence=per_seq)
            scopes = ["pooled", *ours.sequences] if per_seq else ["pooled"]
            for scope in scopes:
                mine = [m for m in misses if m.scope == scope]
                rows.append([det_set, row, scope, "yes" if not mine else "NO",
                             "; ".join(m.describe() for m in mine) or "-"])
    benchdoc.table("Dominance over memory and kf (robust lift): P and R at every threshold >=, L2 <",
                   ["set", "tracker", "scope", "dominates", "misses"], rows)


def run_recording(seed: int, root: Path, args) -> dict:
    """Every tracker, lifting mode and detection set on one benchmark recording -> the partial
    reports, tallies, lifting figures and timing of that recording (merged by :func:`merge`)."""
    cfg = load_config(EgographConfig, default_config(), args.overrides)
    reports: dict[str, dict[str, EvalReport]] = {s: {} for s in ("svoe", "mvpe")}
    tallies: dict[tuple[str, str], IntervalTally] = {}
    lift_stats: dict[tuple[str, str], dict] = {}
    timing: dict[str, float] = {}
    rec = open_recording(root, cfg)
    poses = Path(args.poses.format(seed=seed)) if args.poses else None
    if poses is not None:
        rec = apply_poses(rec, poses)
    seq = root.name
    oracle = None  # the same for both detection sets: made once per recording
    for det_set in ("svoe", "mvpe"):
        for mode in args.modes:
            cfg.lift.mode = mode
            t0 = time.perf_counter()
            obs, rep = cached_observations(rec, det_set, cfg, relift=args.relift)
            if rep is not None:  # lifted now, not read from the cache
                st = lift_stats.setdefault((det_set, mode), {"seconds": 0.0, "frames": 0, "dets": 0})
                st["seconds"] += rep.seconds - rep.setup_seconds
                st["frames"] += rep.n_frames
                st["dets"] += rep.n_detections
            err, true = synth_lift_errors(rec, obs, det_set)
            st = lift_stats.setdefault((det_set, mode), {"seconds": 0.0, "frames": 0, "dets": 0})
            st.setdefault("err", []).append(err[true & np.isfinite(err)])
            timing[f"lift {mode}"] = timing.get(f"lift {mode}", 0.0) + time.perf_counter() - t0
            observable = observable_intervals(gt_intervals(rec), obs, true, cfg.graph.score_threshold)
            for tracker in args.trackers:
                t1 = time.perf_counter()
                intervals = None
                if tracker in GRAPH_TRACKERS:
                    result = track_graph(rec, obs, cfg, causal=tracker == "graph-causal")
                    per_frame, intervals = result.per_frame, result.intervals
                else:
                    per_frame = _track_step(rec, tracker, obs, cfg).per_frame
                timing[f"track {tracker}"] = timing.get(f"track {tracker}", 0.0) + time.perf_counter() - t1
                name = f"{tracker} ({mode} lift)"
                res = args.out / seq / f"{det_set}_{tracker}_{mode}"
                score(reports, tallies, det_set, name, rec, res, per_frame, observable, intervals)
                if tracker in SMOOTHED and "graph" in args.trackers:
                    t1 = time.perf_counter()
                    sm = smooth_predictions(rec, per_frame, cfg.graph)  # the "+graph" row
                    timing[f"smooth {tracker}"] = timing.get(f"smooth {tracker}", 0.0) + time.perf_counter() - t1
                    score(reports, tallies, det_set, f"{tracker}+graph ({mode} lift)", rec,
                          args.out / seq / f"{det_set}_{tracker}+graph_{mode}", sm.per_frame, observable,
                          sm.intervals)
        if "oracle" in args.trackers_extra:
            t1 = time.perf_counter()
            if oracle is None:  # true boxes lifted with the last lifting mode's config
                true_boxes, _ = cached_observations(rec, ORACLE, cfg, relift=args.relift)
                oracle = oracle_tracker(rec, true_boxes, cfg.graph)
            timing["oracle"] = timing.get("oracle", 0.0) + time.perf_counter() - t1
            # observable intervals of the last lifting mode's observations of this set
            score(reports, tallies, det_set, "oracle (true boxes, true intervals)", rec,
                  args.out / seq / f"{det_set}_oracle", oracle.per_frame, observable, oracle.intervals)
    return {"reports": reports, "tallies": tallies, "lift_stats": lift_stats, "timing": timing}


def merge(part: dict, reports: dict, tallies: dict, lift_stats: dict, timing: dict) -> None:
    """Add one recording's :func:`run_recording` output to the set's totals."""
    for det_set, reps in part["reports"].items():
        for name, rep in reps.items():
            into = reports[det_set].setdefault(name, EvalReport())
            for seq_name, seq in rep.sequences.items():
                into.add(seq_name, seq.result, seq.intervals, seq.labels, seq.frames_without_file)
    for key, t in part["tallies"].items():
        tallies.setdefault(key, IntervalTally()).merge(t)
    for key, st in part["lift_stats"].items():
        into = lift_stats.setdefault(key, {"seconds": 0.0, "frames": 0, "dets": 0})
        for k in ("seconds", "frames", "dets"):
            into[k] += st[k]
        into.setdefault("err", []).extend(st.get("err", []))
    for k, v in part["timing"].items():
        timing[k] = timing.get(k, 0.0) + v


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--synth-set", dest="synth_overrides", action="append", default=[],
                    help="generator override for the benchmark set (e.g. detections.svoe.detect_rate=0.5)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="pipeline override")
    ap.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    ap.add_argument("--world", nargs="+", default=["device"], choices=BENCH_WORLDS,
                    help="generator world(s) of the benchmark set: device (the default: photographic surfaces, "
                         "the PV camera, hands) or legacy (the records made before issue 38); with two, the same "
                         "seeds in both, compared in the last table")
    ap.add_argument("--out", type=Path, default=REPO / ".cache" / "bench_trackers")
    ap.add_argument("--relift", action="store_true", help="ignore cached observations")
    ap.add_argument("--poses", help="refined poses per recording instead of the reported ones: a folder pattern "
                                    "with {seed}, e.g. .cache/bench/refined/f3000/seed{seed}/plus_mesh")
    ap.add_argument("--trackers", nargs="+", default=list(TRACKERS))
    ap.add_argument("--modes", nargs="+", default=list(MODES), help="lifting modes")
    ap.add_argument("--no-oracle", dest="trackers_extra", action="store_const", const=(), default=("oracle",),
                    help="skip the oracle row (true boxes lifted, true intervals)")
    ap.add_argument("--jobs", type=int, default=1, help="recordings run in this many worker processes at once")
    benchdoc.add_arguments(ap, __file__)
    args = ap.parse_args()
    benchdoc.start(__file__, args)

    worlds = list(dict.fromkeys(args.world))
    runs = {w: run_world(args, w, args.out if w == worlds[0] else args.out / w) for w in worlds}
    roots, reports, tallies, lift_stats, timing = runs[worlds[0]]
    args.out.mkdir(parents=True, exist_ok=True)
    benchdoc.text(f"Benchmark set ({worlds[0]} world): {len(roots)} synthetic recordings x {args.frames} frames (seeds "
                  f"{', '.join(map(str, args.seeds))}); counts pooled over the set.\n")
    for det_set, reps in reports.items():
        baseline = "kf (reference lift)" if "kf (reference lift)" in reps else None
        md, csv = comparison_table(reps, baseline=baseline)
        cmp = comparison_json(reps, baseline=baseline)
        benchdoc.table(det_set.upper(), ["tracker", *cmp["columns"]],
                       [[name, *row.values()] for name, row in cmp["trackers"].items()],
                       ["", *(".1f" if c[:2] in ("P@", "R@") and "/" not in c else ".2f" for c in cmp["columns"])])
        atomic_write_text(args.out / f"{det_set}.csv", csv)
        plot_pr(reps, args.out / f"{det_set}.png", title=f"{det_set.upper()} benchmark set")
        json.dump({k: v.to_json_dict() for k, v in reps.items()}, open(args.out / f"{det_set}.json", "w"), indent=1)

    rows = []
    for (det_set, mode), st in sorted(lift_stats.items()):
        e = np.concatenate(st["err"]) if st.get("err") else np.zeros(0)
        fps = st["frames"] / st["seconds"] if st["seconds"] else float("nan")
        dps = st["dets"] / st["seconds"] if st["seconds"] else float("nan")
        rows.append([det_set, mode, np.median(e), e.mean(), len(e), fps, dps])
    benchdoc.table("Lifting: 3D error of lifted true detections against synth_gt, and speed",
                   ["set", "mode", "median error (m)", "mean error (m)", "lifted true", "frames/s", "detections/s"],
                   rows, ["", "", ".3f", ".3f", "d", ".1f", ".1f"])
    for det_set in ("svoe", "mvpe") if len(args.modes) == 2 else ():
        ref = np.median(np.concatenate(lift_stats[(det_set, "reference")]["err"]))
        rob = np.median(np.concatenate(lift_stats[(det_set, "robust")]["err"]))
        benchdoc.text(f"{det_set}: reference / robust median lifting error = {ref / rob:.1f}x")
    print()
    print_graph_targets(reports, tallies)
    print_dominance(reports)
    benchdoc.text("\n### Calibration bands (memory + reference lifting, pooled over the set; ± bootstrap standard "
                  "error over recordings)\n")
    per_set = {det_set: [s.result.total for s in reports[det_set]["memory (reference lift)"].sequences.values()]
               for det_set in BANDS if "memory (reference lift)" in reports[det_set]}
    lines, _ = calibration_bands(per_set)
    for line in lines:
        benchdoc.text(line)
    never = [never_visible_intervals(root) for root in roots]
    n_never, n_all = sum(n for n, _ in never), sum(t for _, t in never)
    benchdoc.text(f"\ntrue intervals never a quarter visible (intervals_never_visible): {n_never}/{n_all} "
                  f"({100 * n_never / max(n_all, 1):.1f} %; per recording {', '.join(f'{n}/{t}' for n, t in never)})")
    benchdoc.text("\ntiming (s, whole set): " + ", ".join(f"{k} {v:.1f}" for k, v in timing.items()))
    if len(worlds) > 1:
        print_worlds({w: r[1] for w, r in runs.items()})
    benchdoc.finish()


def run_world(args, world: str, out: Path) -> tuple:
    """The benchmark set of ``args.seeds`` in ``world`` built (or read from the cache) and every
    recording run (:func:`run_recording`, results under ``out``) -> (roots, reports, tallies,
    lift_stats, timing), merged in seed order."""
    roots = benchmark_set(args.seeds, args.frames, config=world_config(world), overrides=args.synth_overrides,
                          cache=args.cache)
    reports: dict[str, dict[str, EvalReport]] = {s: {} for s in ("svoe", "mvpe")}
    tallies: dict[tuple[str, str], IntervalTally] = {}
    lift_stats: dict[tuple[str, str], dict] = {}
    timing: dict[str, float] = {}
    jobs = [(seed, root, argparse.Namespace(**{**vars(args), "out": out})) for seed, root in zip(args.seeds, roots)]
    if args.jobs > 1:  # recordings are independent: each in a worker process, merged in seed order
        with ProcessPoolExecutor(args.jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            parts = list(pool.map(run_recording, *zip(*jobs)))
    else:
        parts = [run_recording(*job) for job in jobs]
    for part in parts:
        merge(part, reports, tallies, lift_stats, timing)
    return roots, reports, tallies, lift_stats, timing


def print_worlds(reports: dict[str, dict]) -> None:
    """Per world (same seeds, same run): the calibration bands of memory + reference lifting and the
    graph's target ratios, side by side."""
    worlds = list(reports)
    rows = []
    for det_set, bands in BANDS.items():
        per_world = {}
        for w in worlds:
            reps = reports[w][det_set]
            if "memory (reference lift)" in reps:
                per = [s.result.total for s in reps["memory (reference lift)"].sequences.values()]
                per_world[w] = (pooled_values(per), bootstrap_se(per))
        for k, (lo, hi) in bands.items() if per_world else ():
            cells = []
            for w in worlds:
                v, se = per_world.get(w, (None, None))
                cells.append("-" if v is None else f"{v[k]:.2f} ± {se[k]:.2f} {'OK' if lo <= v[k] <= hi else 'OUT'}")
            rows.append([det_set, f"memory + reference {k}", f"[{lo}, {hi}]", *cells])
    checks = {w: {(c.det_set, c.row, c.against, c.metric): c for c in target_checks(reports[w])} for w in worlds}
    for key in dict.fromkeys(k for w in worlds for k in checks[w]):
        c0 = next(checks[w][key] for w in worlds if key in checks[w])
        rows.append([c0.det_set, f"{c0.row} / {c0.against} {c0.metric}", f"{c0.op} {c0.bound}",
                     *(f"{checks[w][key].ratio:.2f} {'holds' if checks[w][key].holds else 'NO'}"
                       if key in checks[w] else "-" for w in worlds)])
    benchdoc.table("Worlds side by side (same seeds, same run): calibration bands (pooled ± bootstrap standard error "
                   "over recordings) and the graph's targets", ["set", "figure", "band / target", *worlds], rows)


if __name__ == "__main__":
    main()
