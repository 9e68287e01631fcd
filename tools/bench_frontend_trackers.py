#!/usr/bin/env python
"""The trackers on the real front-end's detections (issue 16): ``egograph detect`` on RGB
benchmark recordings, then the paper's pipeline (memory + reference lifting) against egograph's
graph tracker (robust lifting) on the same detections, beside the simulated front-end's sets.

    .venv/bin/python tools/bench_frontend_trackers.py --seeds 21 22 --frames 600 [--cache DIR] [--config frontend-mvpe]
    .venv/bin/python tools/bench_frontend_trackers.py --seeds 27 28 --frames 1000 --sets mvpe --no-sot --no-guide \
        --config frontend-mvpe --adapt-rounds 2      # the tracker teaches the front-end, per round

Recordings come from egograph.synth.benchset.rgb_benchmark_set (PV RGB, cached) in the ``--world``
(``device``, the default: photographic surfaces, the PV camera, hands; ``legacy``: the world of the
records before issue 38, under the cache's top level as they always were); detection folders
are cached beside them (``detect`` skips work already done). Per detection source
(``simulated``: the recording's own set; ``detect``: egograph detect's output) and set (SVOE, MVPE):
the share of detections that are true (on the instance: IoU >= 0.3 with its true box or the
box centre inside it, where at least a quarter visible), then P@0.25, P@1.5, R@0.25, L2 pooled over the recordings as the reference
evaluator pools sequences, and the ratios graph / memory-reference (the issue asks at least 2.5x
P@0.25 and R@0.25 in SVOE, 1.4x in MVPE, at most half the L2).

``--adapt-rounds K`` (issue 30): round r detects again with ``adapt=`` the graph's results on round
r - 1's detections (:func:`egograph.steps.adapt.teacher_from_result`), then runs the same pipelines on
them; a round whose check says stop keeps the round before's detections, as ``egograph run`` does; the tables gain a row per round, and a per-round table adds the held-back check,
the fit and re-detect cost and the per-recording graph / paper L2 ratios (paper on the same
detections, and on the round-0 detections: the published pipeline does not adapt).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import benchdoc

from egograph.core.config import load_config
from egograph.core.errors import InputError
from egograph.core.resources import config_argument, default_config
from egograph.eval.protocol import THRESHOLDS, Counts
from egograph.geometry.observations import Observations
from egograph.frontend.adapt import Head
from egograph.steps.adapt import Adaptation, teacher_from_result
from egograph.steps.detect import carry_detections, detect, guides_from_predictions
from egograph.steps.evaluate import evaluate
from egograph.steps.lift import lift
from egograph.steps.recording import open_recording
from egograph.steps.settings import EgographConfig
from egograph.steps.sot import eval_2d, sot
from egograph.steps.track import track as track_step
from egograph.synth.benchset import BENCH_WORLDS, rgb_benchmark_set, set_dir, world_config
from egograph.synth.truth import detections_against_truth, own_column

REPO = Path(__file__).resolve().parents[1]
PIPELINES = (("memory + reference (paper)", "memory", "reference"),
             ("graph + robust", "graph", "robust"),
             ("graph-causal + robust", "graph-causal", "robust"))


def true_share(rec, det_dir) -> tuple[int, int]:
    """(true, all) detections: true when on the instance (at least a quarter visible) — IoU >= 0.3
    with its true box, or the box centre inside it (the simulated SVOE boxes scatter by a third of
    the box side, so IoU alone would call many of its true matches false)."""
    m = detections_against_truth(rec, det_dir)
    ok = (own_column(m, "visible") >= 0.25) & ((own_column(m, "iou") >= 0.3) | own_column(m, "centre_inside"))
    return int(ok.sum()), len(ok)


def detail_2d(rec, det_dir) -> tuple[int, int, int, list, list]:
    """(visible instance-frames, of them with a true detection, detections on another visible
    instance (a look-alike confusion), scores, labels) with the rule of :func:`true_share`; visible:
    at least a quarter visible with a true box. Scores are the files' similarity column, the labels
    whether each detection is on its instance (for the calibration error)."""
    import numpy as np

    from egograph.io.detections import read_detection_dir

    m = detections_against_truth(rec, det_dir)
    on_own = (own_column(m, "visible") >= 0.25) & ((own_column(m, "iou") >= 0.3) | own_column(m, "centre_inside"))
    on_any = ((m["visible"] >= 0.25) & ((m["iou"] >= 0.3) | m["centre_inside"])).any(axis=1)
    dets = read_detection_dir(det_dir, rec.timestamps)
    scores = [d.score for ts in rec.timestamps for d in dets[int(ts)]]
    with np.load(rec.synth_gt_dir / "instances.npz") as gt:
        vis = (gt["visible"] >= 0.25) & np.isfinite(gt["boxes"][..., 0])
    frame = np.repeat(np.arange(len(rec)), [len(dets[int(ts)]) for ts in rec.timestamps])
    pairs = {(int(f), int(k)) for f, k, ok in zip(frame, m["instance"], on_own) if ok}
    found = sum(1 for f, k in pairs if k < vis.shape[1] and vis[f, k])
    return int(vis.sum()), found, int((on_any & ~on_own).sum()), scores, on_own.tolist()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[21, 22])
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--cache", type=Path, default=REPO / ".cache" / "bench_fe")
    ap.add_argument("--sets", nargs="+", default=["svoe", "mvpe"], choices=["svoe", "mvpe"])
    ap.add_argument("--world", default="device", choices=BENCH_WORLDS,
                    help="generator world of the RGB recordings (default device; legacy: the records made before "
                         "issue 38)")
    ap.add_argument("--tag", default="", help="detection and observation folders under this sub-folder of the "
                                             "cache (front-end variants side by side)")
    ap.add_argument("--no-sot", action="store_true", help="leave out the SOT (CSRT) row")
    ap.add_argument("--no-guide", action="store_true", help="leave out the 3D guidance rows")
    ap.add_argument("--no-simulated", action="store_true", help="leave out the simulated front-end's rows")
    ap.add_argument("--no-causal", action="store_true", help="leave out graph-causal")
    ap.add_argument("--adapt-rounds", type=int, default=0, metavar="K",
                    help="rounds of the tracker teaching the front-end (egograph detect --adapt), each taught by "
                         "the graph's results on the round before")
    ap.add_argument("--variant", action="append", default=[], metavar="NAME:KEY=VALUE,...",
                    help="another front-end configuration detected and tracked in the same run, beside the "
                         "current one (repeatable), e.g. verify:frontend.verify=all")
    ap.add_argument("--config", type=config_argument, default=default_config(),
                    help="egograph configuration: a YAML file or a packaged name (e.g. frontend-mvpe; default: default)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="egograph configuration override (e.g. frontend.similarity_threshold=0.65)")
    benchdoc.add_arguments(ap, __file__)
    args = ap.parse_args()
    benchdoc.start(__file__, args)
    os.environ.setdefault("EGOGRAPH_CACHE", str(args.cache / "models"))

    roots = rgb_benchmark_set(args.seeds, args.frames, config=world_config(args.world), cache=args.cache)
    # derived folders (detections, observations, results) of another world's recordings kept apart
    world_dir = set_dir("", 0, (), args.world).parent  # "device" or "" (legacy: the folders it always had)
    base = load_config(EgographConfig, args.config, args.overrides)
    radius = base.frontend.guidance_radius_px
    import re

    variants = [(n, [kv for kv in re.split(r",(?![^\[]*\])", v) if kv]) for n, _, v in
                (x.partition(":") for x in args.variant)]
    vtime: dict = {}
    pooled: dict = {}
    shares: dict = {}
    two_d: dict = {}  # (source, set) -> list of Track2dScores, one per recording
    details: dict = {}  # (source, set) -> [visible, found, confusions, scores, labels, per recording]
    t_detect, frames = 0.0, 0
    per_rec: dict = {}     # (source, set, label) -> recording -> Counts
    rounds: dict = {}      # (source, set) -> recording -> {"holdback", "fit_s", "detect_s", "frames", "heads"}
    for root in roots:
        rec = open_recording(root, base)
        for det_set in args.sets:
            out = args.cache / "detect" / args.tag / world_dir / root.name / det_set
            t = time.perf_counter()
            if detect(rec, det_set, base, out, progress=True) is not None:  # None: cached, not timed
                t_detect += time.perf_counter() - t
                frames += len(rec)
            sources = [("simulated", det_set, rec.detections_dir(det_set)), ("detect", str(out), out)]
            for vname, vsets in variants:
                # another front-end configuration, detected on the same recording in this run
                vcfg = load_config(EgographConfig, args.config, [*args.overrides, *vsets])
                out_v = args.cache / "detect" / args.tag / world_dir / root.name / f"{det_set}_{vname}"
                t = time.perf_counter()
                rep_v = detect(rec, det_set, vcfg, out_v, progress=True)
                if rep_v is not None:
                    vtime.setdefault(vname, [0.0, 0])
                    vtime[vname][0] += time.perf_counter() - t
                    vtime[vname][1] += len(rec)
                    print(f"{root.name} {det_set} [{vname}]:\n{rep_v.summary()}", flush=True)
                sources.append((f"detect [{vname}]", str(out_v), out_v))
            if args.no_simulated:
                sources = sources[1:]
            if det_set == "svoe" and not args.no_sot:
                sot_dir = args.cache / "sot" / world_dir / root.name
                sot(rec, base, sot_dir, method="csrt", progress=False)
                sources.append(("SOT (CSRT)", str(sot_dir), sot_dir))
            k = 0
            while k < len(sources):
                source, spec, folder = sources[k]
                k += 1
                a, b = shares.get((source, det_set), (0, 0))
                tr, tot = true_share(rec, folder)
                shares[(source, det_set)] = (a + tr, b + tot)
                d2 = detail_2d(rec, folder)
                acc = details.setdefault((source, det_set), [0, 0, 0, [], [], {}])
                for j in range(3):
                    acc[j] += d2[j]
                acc[3] += d2[3]
                acc[4] += d2[4]
                acc[5][root.name] = (tr, tot, d2[1], d2[0], d2[2])
                two_d.setdefault((source, det_set), []).append(eval_2d(rec, folder, base))
                for label, tracker, mode in PIPELINES:
                    if source.startswith("SOT") and tracker != "memory":
                        continue  # the paper's SOT row: its boxes lifted and kept in memory
                    if args.no_causal and tracker == "graph-causal":
                        continue
                    vsets = dict(variants).get(source[8:-1], []) if source.startswith("detect [") else []
                    cfg = load_config(EgographConfig, args.config, [*args.overrides, *vsets, f"lift.mode={mode}"])
                    tag = source.split()[0].lower() + ("_g" if "guidance" in source else "")
                    if source.startswith("detect ["):
                        tag = "v_" + source[8:-1]
                    if source.startswith("detect + adapt"):
                        tag = "adapt_" + source.rsplit(" ", 1)[1]
                    try:
                        obs, _ = lift(rec, spec, cfg, args.cache / "obs" / args.tag / world_dir / root.name / f"{tag}_{det_set}_{mode}.npz",
                                      progress=False)
                    except InputError as e:  # nothing lifted: no predictions (every true frame a miss)
                        print(f"{root.name} {source} {det_set} {mode}: {e}", flush=True)
                        obs = Observations.empty()
                    # results folders kept (read back when the same observations and configuration come again)
                    kept = args.cache / "results" / args.tag / world_dir / root.name / f"{tag}_{det_set}_{mode}_{tracker}"
                    result = track_step(rec, tracker, obs, cfg, kept if len(obs) else None)
                    key = (source, det_set, label)
                    one = evaluate(rec, result).total
                    pooled[key] = pooled.get(key, Counts(THRESHOLDS)) + one
                    per_rec.setdefault(key, {})[root.name] = one
                    r = 0 if source == "detect" else int(source.rsplit("r", 1)[1]) if source.startswith("detect + adapt") else -1
                    if tracker == "graph" and 0 <= r < args.adapt_rounds:
                        # the graph's results on this round's detections teach the next round's head
                        out_a = args.cache / "detect" / args.tag / world_dir / root.name / f"{det_set}_adapt_r{r + 1}"
                        t = time.perf_counter()
                        rep = detect(rec, det_set, base, out_a, adapt=teacher_from_result(rec, result, folder),
                                     embeddings=args.cache / "detect" / args.tag / world_dir / root.name / f"{det_set}_proposals.npz",
                                     progress=False)
                        name = f"detect + adapt r{r + 1}"
                        dt = time.perf_counter() - t
                        ad = json.loads((out_a / "adapt.json").read_text())
                        rounds.setdefault((name, det_set), {})[root.name] = {
                            "holdback": ad["holdback_auc"], "fit_s": ad["seconds"]["crops"] + ad["seconds"]["background"]
                            + ad["seconds"]["fit"], "detect_s": dt if rep is not None else None, "frames": len(rec),
                            "stop": ad.get("stop"), "heads": sum(v["head"] for v in ad["instances"].values()),
                            "instances": len(ad["instances"])}
                        if rep is not None:
                            print(f"{root.name} {det_set} round {r + 1} ({dt:.1f} s):\n{rep.summary()}", flush=True)
                        if ad.get("stop"):   # as egograph run: iterating stopped, the round before's detections carried
                            carried = out_a.with_name(out_a.name + "_carried")
                            carry_detections(rec, Adaptation(Head(), ad), base, carried)
                            sources.append((name, str(carried), carried))
                        else:
                            sources.append((name, str(out_a), out_a))
                    if source == "detect" and tracker == "graph-causal" and radius > 0 and not args.no_guide:
                        # 3D guidance as in the paper: each frame's choice among the above-threshold
                        # proposals follows the causal tracker's estimate of the frame before
                        out_g = args.cache / "detect" / args.tag / world_dir / root.name / f"{det_set}_guided_{radius:g}px"
                        detect(rec, det_set, base, out_g, guide_world=guides_from_predictions(rec, result.per_frame),
                               progress=False)
                        sources.append(("detect + 3D guidance", str(out_g), out_g))
    speed = f"detect {frames / t_detect:.1f} frames/s over {frames} frames" if frames else "detections cached"
    for vname, (sec, n) in vtime.items():
        speed += f"; [{vname}] {n / sec:.1f} frames/s over {n} frames"
    print(f"\nRGB recordings ({args.world} world): seeds {', '.join(map(str, args.seeds))} x {args.frames} frames; {speed}\n")
    rows = []
    for (source, det_set, label), c in pooled.items():
        tr, tot = shares[(source, det_set)]
        rows.append([source, det_set, [tr, tot, 100 * tr / max(tot, 1)], label, 100 * c.precision[0],
                     100 * c.precision[-1], 100 * c.recall[0], 100 * c.recall[-1], c.l2_m if c.l2_n else "-"])
    benchdoc.table("Trackers on each detection source",
                   ["source", "set", "true / all detections", "tracker", "P@0.25", "P@1.5", "R@0.25", "R@1.5", "L2 (m)"],
                   rows, ["", "", "{0} / {1} ({2:.0f} %)", "", ".1f", ".1f", ".1f", ".1f", ".2f"],
                   note=f"RGB recordings ({args.world} world): seeds {', '.join(map(str, args.seeds))} x {args.frames} frames; {speed}.")
    from egograph.frontend.verify import expected_calibration_error

    rows = []
    for (source, det_set), (vis, found, conf, sc, lab, per) in details.items():
        tr, tot = shares[(source, det_set)]
        rows.append([source, det_set, [tr, tot, 100 * tr / max(tot, 1)], [found, vis, 100 * found / max(vis, 1)], conf,
                     expected_calibration_error(sc, lab),
                     "; ".join(f"{n}: {a}/{b}, found {c}/{d}, conf {e}" for n, (a, b, c, d, e) in per.items())])
    benchdoc.table("Detections against the generator's truth",
                   ["source", "set", "on the instance / emitted", "visible instance-frames found", "look-alike confusions",
                    "ECE of the score", "per recording"], rows,
                   ["", "", "{0} / {1} ({2:.1f} %)", "{0} / {1} ({2:.1f} %)", "d", ".3f", ""],
                   note="On the instance: at least a quarter visible, IoU >= 0.3 with its true box or the box centre "
                        "inside it; visible instance-frames: at least a quarter visible; confusions: detections on "
                        "another instance's box; ECE: the similarity column (a probability under verification) against "
                        "on-the-instance, 10 bins.")
    rows = []
    for (source, det_set), evals in two_d.items():
        n = sum(r.n for r in evals)
        mean = {a: sum(getattr(r, a) * r.n for r in evals if r.n) / max(n, 1) for a in ("auc", "precision_20px",
                                                                                          "norm_precision")}
        rows.append([source, det_set, mean["auc"], mean["precision_20px"], mean["norm_precision"],
                     [sum(r.n_detected for r in evals), n]])
    benchdoc.table("2D table against 2d_bbox_annot/", ["source", "set", "AUC", "P@20px", "P_norm", "pairs with a box"],
                   rows, ["", "", ".1f", ".1f", ".1f", "{0} / {1}"],
                   note="Pooled over the annotated pairs of every recording; a pair without a box counts as a miss.")
    rows = []
    for source in dict.fromkeys(k[0] for k in pooled if not k[0].startswith("SOT")):
        for det_set in args.sets:
            if (source, det_set, PIPELINES[1][0]) not in pooled:
                continue
            g, m = pooled[(source, det_set, PIPELINES[1][0])], pooled[(source, det_set, PIPELINES[0][0])]
            rows.append([source, det_set, g.precision[0] / max(m.precision[0], 1e-9),
                         g.recall[0] / max(m.recall[0], 1e-9), g.l2_m / max(m.l2_m, 1e-9)])
            if source.startswith("detect + adapt"):
                m0 = pooled[("detect", det_set, PIPELINES[0][0])]
                rows.append([f"{source} vs paper on round-0 detections", det_set,
                             g.precision[0] / max(m0.precision[0], 1e-9), g.recall[0] / max(m0.recall[0], 1e-9),
                             g.l2_m / max(m0.l2_m, 1e-9)])
    benchdoc.table("Ratios graph + robust / memory + reference", ["source", "set", "P@0.25", "R@0.25", "L2"], rows,
                   ["", "", "{:.2f}x", "{:.2f}x", "{:.2f}x"],
                   note="Target: SVOE >= 2.5x P and R at 0.25 m, MVPE >= 1.4x, L2 <= 0.5x.")
    if args.adapt_rounds:
        names = [r.name for r in roots]
        rows = []
        for source in dict.fromkeys(k[0] for k in pooled if k[0] == "detect" or k[0].startswith("detect + adapt")):
            for det_set in args.sets:
                g = per_rec.get((source, det_set, PIPELINES[1][0]), {})
                m = per_rec.get((source, det_set, PIPELINES[0][0]), {})
                m0 = per_rec.get(("detect", det_set, PIPELINES[0][0]), {})

                def ratio(n, base):
                    ok = n in g and n in base and g[n].l2_n and base[n].l2_n
                    return f"{g[n].l2_m / max(base[n].l2_m, 1e-9):.2f}x" if ok else "n/a"
                cells = [f"{ratio(n, m)} ({ratio(n, m0)})" for n in names]
                info = rounds.get((source, det_set), {})
                hb = [v["holdback"] for v in info.values() if v["holdback"] is not None]
                heads = f"{sum(v['heads'] for v in info.values())} / {sum(v['instances'] for v in info.values())}" \
                    if info else "-"
                fit = f"{sum(v['fit_s'] for v in info.values()) / len(info):.1f}" if info else "-"
                timed = [v for v in info.values() if v["detect_s"]]
                fps = f"{sum(v['frames'] for v in timed) / max(sum(v['detect_s'] for v in timed), 1e-9):.1f}" \
                    if timed else "cached"
                rows.append([source, det_set, *cells, f"{sum(hb) / len(hb):.3f}" if hb else "-", heads, fit, fps])
                for n, v in info.items():
                    if v.get("stop"):
                        benchdoc.text(f"{source} {det_set} {n}: the round's check says stop: {v['stop']}")
        benchdoc.table("Per round: graph / paper L2 per recording (paper on the same detections; in brackets on the "
                       "round-0 detections), held-back check, cost",
                       ["source", "set", *names, "held-back AUC", "heads", "fit s/rec", "detect frames/s"], rows)
    benchdoc.finish()


if __name__ == "__main__":
    main()
