"""``egograph`` command line: one sub-command per use, each a thin shell over a step of
:mod:`egograph.steps`.

    egograph synth OUT --config synth/svoe --seed 1 --frames 3000
    egograph info REC
    egograph lift REC --detections svoe --out OBS.npz
    egograph detect REC --enroll svoe|mvpe --out DIR [--encoder FILE.onnx] [--proposals NAME] [--guide RESULTS]
                    [--adapt RESULTS]
    egograph track REC --tracker graph|graph-causal|memory|kf --detections svoe --out RESULTS
    egograph regt REC --out DIR
    egograph smooth REC RESULTS --out RESULTS_SMOOTHED
    egograph eval REC RESULTS [--json OUT]
    egograph compare REC RESULTS_A RESULTS_B ... [--out DIR]
    egograph refine REC --out DIR
    egograph eval-poses REC [POSES]
    egograph demo [OUT]
    egograph run DATASET --out RUNS [--stages ...] [--trackers ...] [--workers N | --scheduler ADDRESS]
    egograph plot REC RESULTS [RESULTS2 ...] [--names a,b] [--detections svoe] [--out DIR]
    egograph export REC RESULTS [--out DIR] [--rrd]
    egograph sot REC --out DETS [--method csrt|kcf]
    egograph eval-2d REC DETECTIONS [DETECTIONS2 ...] [--json OUT]

Bad input ends with one line naming the file (and line, or the config key) and exit code 2.
"""

from __future__ import annotations

import argparse
import errno
import json
import os
import sys
import textwrap
import time
import warnings
from importlib import resources
from pathlib import Path

from egograph import __version__
from egograph.cli.common import (
    DEFAULT_CONFIG,
    SYNTH_CONFIG,
    _add_config_args,
    _add_rec_args,
    _console,
    _show_config,
    pipeline_config,
    print_intervals,
    why_no_intervals,
)
from egograph.core.config import load_config
from egograph.core.errors import ConfigError, EgographError, InputError


def _open(args, cfg):
    from egograph.cli.common import open_rec

    return open_rec(args, cfg)


def _add_poses_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--poses", type=Path, help="use refined poses (a folder from `egograph refine`) instead of the "
                                              "recording's")


def _add_lift_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--lift", choices=["reference", "robust"],
                   help="lifting mode (default from config lift.mode: robust); reference = the IT3DEgo notebook's rule")


def _add_joint_args(p: argparse.ArgumentParser, default_out: str) -> None:
    p.add_argument("--joint-poses", action="store_true",
                   help="joint mode: solve the PV poses together with the still objects' landmarks and the "
                        "refinement factors (refine.* config), then estimate again with the corrected poses")
    p.add_argument("--poses-out", type=Path, help=f"joint mode: where to write the solved poses (default {default_out})")


def _add_quiet(p: argparse.ArgumentParser) -> None:
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def _add_overwrite(p: argparse.ArgumentParser) -> None:
    p.add_argument("--overwrite", action="store_true",
                   help="run again even when the output already holds this exact run (same inputs and configuration)")


def _evaluate_if_asked(con, args, rec, result) -> None:
    """``--eval``: the IT3DEgo metrics of the result just made (in memory, intervals as they are)."""
    if args.eval and rec.annotation_dir is not None:
        from egograph.steps.evaluate import evaluate

        evaluate(rec, result).print(con)


def _write_joint(con, rec, jp, cfg, out: Path) -> None:
    """Joint mode: write the solved poses in the ``refine`` format and say how far they moved."""
    from egograph.steps.joint import write_joint_poses

    write_joint_poses(rec, jp, cfg, out)
    _print_joint(con, jp, out)


def _print_joint(con, jp, out: Path) -> None:
    ch = jp.report["change"]
    con.print(f"joint poses: {jp.report['stands']} stands, {jp.report['detection_factors']} detection factors; poses "
              f"moved {1000 * ch.get('trans_rms_m', 0):.1f} mm / {ch.get('rot_rms_deg', 0):.3f} deg RMS -> {out}")


def _sibling(path: Path, suffix: str) -> Path:
    path = Path(path)
    return path.with_name(path.name + suffix)


# ------------------------------------------------------------------ sub-commands

def synth_config(args):
    from egograph.synth.config import SynthConfig

    overrides = list(args.overrides)
    if getattr(args, "frames", None) is not None:
        overrides.append(f"frames={args.frames}")
    return load_config(SynthConfig, args.config, overrides)


def cmd_synth(args) -> int:
    from egograph.steps.synth import synth

    cfg = synth_config(args)
    if args.redetect:
        from egograph.synth.generate import redetect

        counts = redetect(args.out, cfg)
        _console().print(f"re-simulated detections in {args.out}: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
        return 0
    r = synth(args.out, cfg, seed=args.seed, overwrite=args.overwrite, progress=not args.quiet)
    if r is None:
        _console().print(f"{args.out} already holds this recording (seed {args.seed}, same configuration); "
                         f"--overwrite generates it again")
    else:
        _console().print(f"wrote {r.root} ({r.frames} frames, {len(r.instances)} instances, {r.n_moves} moves, "
                         f"{r.n_intervals} stationary intervals) in {r.seconds:.1f} s ({r.fps_generation:.1f} frames/s)")
    if not args.quiet:
        cmd_info(argparse.Namespace(rec=args.out, sequence=None, calibration=None, annotations=None, json=None,
                                    config=DEFAULT_CONFIG, overrides=[], refine_calibration=None))
    return 0


def cmd_info(args) -> int:
    from egograph.steps.info import print_summary, summarize
    from egograph.steps.recording import open_recording

    cfg = pipeline_config(args)
    rec = open_recording(args.rec, cfg, calibration=args.calibration, annotations=args.annotations,
                         sequence=args.sequence, score_calibration=True)
    s = summarize(rec, cfg=cfg)
    print_summary(s, _console())
    if getattr(args, "refine_calibration", None):
        from egograph.steps.calibration import refine_calibration_folder

        r = refine_calibration_folder(rec, cfg, args.refine_calibration, frames=args.refine_frames,
                                      overwrite=args.overwrite)
        if r is None:
            _console().print(f"{args.refine_calibration} already holds this refinement; --overwrite fits again")
        else:
            _console().print(f"refined calibration -> {args.refine_calibration}: fit {r.before.score:.2f} -> "
                             f"{r.after.score:.2f} px; AHAT camera turned {r.to_json()['rotation_angle_deg']:.2f} deg, "
                             f"moved {1000 * r.to_json()['translation_norm_m']:.1f} mm, time offset "
                             f"{r.time_offset_ms:.1f} ms ({r.evaluations} evaluations)")
    if args.json:
        from egograph.io.atomic import atomic_write_text

        atomic_write_text(args.json, json.dumps(s, indent=1))
    return 0


def cmd_lift(args) -> int:
    from egograph.steps.lift import lift

    cfg = pipeline_config(args)
    rec = _open(args, cfg)
    t0 = time.perf_counter()
    obs, report = lift(rec, args.detections, cfg, args.out, overwrite=args.overwrite, progress=not args.quiet)
    dt = time.perf_counter() - t0
    if args.lifted_dir:
        from egograph.geometry.lift import write_lifted_dir

        write_lifted_dir(args.lifted_dir, obs, rec.timestamps)
    con = _console()
    if report is None:
        con.print(f"{args.out} already holds these observations (same detections, poses and lift configuration); "
                  f"--overwrite lifts again")
        return 0
    con.print(f"lifted {int(obs.valid.sum())} of {len(obs)} detections ({cfg.lift.mode} mode) in {dt:.1f} s -> {args.out}")
    con.print(report.summary())
    return 0


def cmd_detect(args) -> int:
    from egograph.steps.detect import detect, guides_from_results

    cfg = pipeline_config(args)
    rec = _open(args, cfg)
    guide = None
    if args.guide is not None:
        if cfg.frontend.guidance_radius_px <= 0:
            raise ConfigError("--guide needs frontend.guidance_radius_px > 0 (0 turns 3D guidance off)")
        guide = guides_from_results(rec, args.guide)
    adapt = args.adapt
    if args.adapt_detections is not None:
        from egograph.steps.adapt import teacher_from_results

        if args.adapt is None:
            raise ConfigError("--adapt-detections needs --adapt RESULTS")
        adapt = teacher_from_results(rec, args.adapt, args.adapt_detections)
    report = detect(rec, args.enroll, cfg, args.out, encoder=args.encoder, proposals=args.proposals,
                    guide_world=guide, adapt=adapt, overwrite=args.overwrite, progress=not args.quiet)
    con = _console()
    if report is None:
        con.print(f"{args.out} already holds these detections (same recording, enrollment, encoder and frontend "
                  f"configuration); --overwrite detects again")
        return 0
    con.print(f"detections ({args.enroll}) -> {args.out}")
    con.print(report.summary())
    hint = track_hint(args, cfg)
    if hint:
        import shlex

        con.print(f"track them with: egograph track {shlex.quote(str(args.rec))} --tracker graph --detections "
                  f"{shlex.quote(str(args.out))} {hint} --out RESULTS", soft_wrap=True)
    return 0


def track_hint(args, cfg) -> str:
    """The configuration arguments to track ``egograph detect``'s detections with, or '' when the
    defaults fit: MVPE's clutter stands need the graph knobs of the packaged frontend-mvpe file, and
    verified detections carry a probability, which the trackers' score_threshold (the paper's 0.6 on
    a cosine) must not cut above the detector's own operating point (frontend.verify_threshold)."""
    from egograph.core.resources import packaged_configs, resolve_config
    from egograph.steps.settings import EgographConfig

    names = {resolve_config(n).resolve(): n for n in packaged_configs()}
    name = "frontend-mvpe" if args.enroll == "mvpe" else names.get(Path(args.config).resolve(), str(args.config))
    parts = [] if name == "default" else ["--config", name]
    t = cfg.frontend.verify_threshold
    verified = cfg.frontend.verify in ("all", args.enroll)
    if verified and load_config(EgographConfig, resolve_config(name)).graph.score_threshold > t:
        parts += ["--set", f"graph.score_threshold={t:g}"]
    return " ".join(parts)


def cmd_track(args) -> int:
    from egograph.geometry.observations import Observations
    from egograph.steps.track import track
    from egograph.track.registry import INTERVAL_TRACKERS, get_tracker

    cfg = pipeline_config(args)
    get_tracker(args.tracker)
    if args.joint_poses and args.tracker != "graph":
        raise ConfigError(f"--joint-poses needs --tracker graph (offline), not {args.tracker}")
    if args.lag is not None:
        if args.tracker != "graph-causal":
            raise ConfigError(f"--lag needs --tracker graph-causal, not {args.tracker}")
        if not 0 <= args.lag < float("inf"):
            raise ConfigError(f"--lag {args.lag}: seconds, >= 0 and finite")
        cfg.graph.lag_s = float(args.lag)
    _min_confidence(args, cfg)
    rec = _open(args, cfg)
    con = _console()
    t0 = time.perf_counter()
    if args.observations:
        from egograph.steps.outputs import check_belongs

        obs = Observations.load(args.observations)
        check_belongs(rec, (obs.provenance or {}).get("recording"), args.observations, "observations")
    else:
        from egograph.steps.lift import lift

        obs, report = lift(rec, args.detections, cfg, progress=not args.quiet)
        con.print(report.summary())
    t1 = time.perf_counter()
    jp = None
    if args.joint_poses:
        from egograph.steps import outputs
        from egograph.steps.joint import track_joint
        from egograph.steps.track import write_result

        result, jp = track_joint(rec, obs, cfg, progress=not args.quiet)
        record = outputs.run_record("track", cfg, {"tracker": "graph (joint poses)",
                                                   "recording": outputs.recording_digest(rec)})
        write_result(args.out, rec, result, record, cfg)
    else:
        result = track(rec, args.tracker, obs, cfg, args.out, overwrite=args.overwrite, progress=not args.quiet)
    t2 = time.perf_counter()
    con.print(f"{args.tracker}: {result.n_predictions} predictions over {len(rec)} frames -> {args.out} "
              f"(lift {t1 - t0:.1f} s, track {t2 - t1:.2f} s)")
    if result.intervals is not None:
        from egograph.steps.recording import labels

        print_intervals(con, result.intervals, rec, result.metadata, labels(rec))
        if not result.intervals:
            con.print(f"[yellow]no position interval found: {why_no_intervals(obs, rec, cfg.graph)}")
        if args.intervals:
            from egograph.track.intervals import write_intervals_json

            write_intervals_json(args.intervals, result.intervals, result.metadata, timestamps=rec.timestamps,
                                 labels=labels(rec), sequence=rec.name)
        con.print(f"intervals -> {Path(args.out) / 'intervals.json'}")
    elif args.tracker in INTERVAL_TRACKERS:
        con.print("[yellow]the tracker returned no intervals")
    if jp is not None:
        _write_joint(con, rec, jp, cfg, args.poses_out or _sibling(args.out, ".poses"))
    _evaluate_if_asked(con, args, rec, result)
    return 0


def cmd_regt(args) -> int:
    from egograph.steps.regt import regt

    cfg = pipeline_config(args)
    rec = _open(args, cfg)
    r = regt(rec, cfg, args.out, joint=args.joint_poses, progress=not args.quiet)
    con = _console()
    con.print(r.lift_report.summary())
    print(r.audit)
    con.print(f"re-estimated {sum(e.xyz is not None for e in r.estimates)} of {len(r.estimates)} intervals -> "
              f"{args.out}/3d_center_annot.txt, regt.json (covariances), audit.md")
    if r.joint is not None:
        _write_joint(con, rec, r.joint, cfg, args.poses_out or Path(args.out) / "poses")
    return 0


def _min_confidence(args, cfg) -> None:
    """--min-confidence: the operating point of the graph trackers (graph.answers.min_confidence and
    causal_min_confidence)."""
    if getattr(args, "min_confidence", None) is None:
        return
    if not 0.0 <= args.min_confidence <= 1.0:
        raise ConfigError(f"--min-confidence {args.min_confidence}: a probability, 0-1")
    cfg.graph.answers.min_confidence = float(args.min_confidence)
    cfg.graph.answers.causal_min_confidence = float(args.min_confidence)


def cmd_smooth(args) -> int:
    from egograph.steps.recording import labels
    from egograph.steps.smooth import smooth

    cfg = pipeline_config(args)
    _min_confidence(args, cfg)
    rec = _open(args, cfg)
    result = smooth(rec, args.results, cfg, args.out, causal=args.causal, overwrite=args.overwrite,
                    progress=not args.quiet)
    con = _console()
    print_intervals(con, result.intervals, rec, result.metadata, labels(rec))
    if args.intervals:
        from egograph.track.intervals import write_intervals_json

        write_intervals_json(args.intervals, result.intervals, result.metadata, timestamps=rec.timestamps,
                             labels=labels(rec), sequence=rec.name)
    con.print(f"smoothed {result.metadata.get('n_observations', 'the')} predictions of {args.results} -> {args.out}")
    _evaluate_if_asked(con, args, rec, result)
    return 0


def cmd_eval(args) -> int:
    from egograph.steps.evaluate import evaluate

    cfg = pipeline_config(args)
    rec = _open(args, cfg)
    report = evaluate(rec, args.results, strict=args.strict or cfg.io.strict)
    con = _console()
    if args.format in ("table", "yaml"):
        report.print(con, per_instance=args.per_instance)
    else:
        from egograph.eval.report import render_report

        print(render_report(report, args.format))
    if args.json:
        report.write_json(args.json)
    if args.markdown:
        report.write_markdown(args.markdown)
    if args.csv:
        report.write_csv(args.csv)
    if args.plot:
        from egograph.eval.report import plot_pr

        plot_pr({Path(args.results).name: report}, args.plot)
    return 0


def cmd_compare(args) -> int:
    from egograph.eval.report import comparison_table, plot_pr, print_comparison, render_comparison
    from egograph.io.atomic import atomic_dir
    from egograph.steps import outputs
    from egograph.steps.evaluate import evaluate

    cfg = pipeline_config(args)
    rec = _open(args, cfg)
    names = args.names.split(",") if args.names else [Path(r).name for r in args.results]
    if len(names) != len(args.results) or len(set(names)) != len(names):
        raise ConfigError("--names must give one distinct name per results folder")
    reports = {n: evaluate(rec, r) for n, r in zip(names, args.results)}
    baseline = args.baseline if args.baseline in reports else None
    md, csv = comparison_table(reports, baseline=baseline)
    if args.format in ("table", "yaml"):
        print_comparison(reports, baseline, _console())
    else:
        print(render_comparison(reports, baseline, args.format))
    if args.out:
        record = outputs.run_record("compare", cfg, {"recording": outputs.recording_digest(rec),
                                                     "results": dict(zip(names, map(str, args.results)))})
        with atomic_dir(args.out) as tmp:
            (tmp / "comparison.md").write_text(md)
            (tmp / "comparison.csv").write_text(csv)
            (tmp / "comparison.json").write_text(json.dumps({n: r.to_json_dict() for n, r in reports.items()},
                                                            indent=1))
            plot_pr(reports, tmp / "comparison.png")
            outputs.write_run_files(tmp, record, cfg)
        _console().print(f"wrote {args.out}/comparison.{{md,csv,json,png}}")
    return 0


def cmd_demo(args) -> int:
    """The main job on the embedded default: generate a recording with device-like PV frames,
    detect the instances in them (``egograph detect``; ``--simulated``: the simulated detections
    instead), lift, track (the paper's baselines and the factor-graph tracker), show the graph's
    position intervals, evaluate, draw every tracker's results; the last line printed is the path
    of the pictures' index.html (how long it takes: ``DEMO_TIMES``)."""
    import tempfile

    from egograph.core.resources import packaged_config_or_error
    from egograph.eval.report import print_comparison
    from egograph.steps.evaluate import evaluate
    from egograph.steps.info import print_summary, summarize
    from egograph.steps.lift import lift
    from egograph.steps.plot import INDEX_FILE
    from egograph.steps.plot import plot as plot_step
    from egograph.steps.recording import labels, open_recording
    from egograph.steps.settings import EgographConfig
    from egograph.steps.synth import synth
    from egograph.steps.track import track
    from egograph.synth.config import SynthConfig

    con = _console()
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="egograph-demo-"))
    pixels = not args.simulated
    # From pixels: the device world's PV frames (photographic objects, exposure, noise, blur, hands),
    # found by `egograph detect`. Simulated: the legacy world's detection sets, no RGB (the
    # tracker-only benchmark's input).
    synth_cfg = packaged_config_or_error("synth/device-svoe") if pixels else SYNTH_CONFIG
    scfg = load_config(SynthConfig, synth_cfg, [f"frames={args.frames}", f"pv.rgb={'true' if pixels else 'false'}",
                                                *args.overrides])
    rec_dir = out / "recording"
    con.rule("1. synthetic recording" + (" (device-like PV frames)" if pixels else " (simulated detections)"))
    r = synth(rec_dir, scfg, seed=args.seed, overwrite=args.regenerate)
    if r is not None:
        con.print(f"generated {r.frames} frames in {r.seconds:.1f} s ({r.fps_generation:.1f} frames/s)")
    cfg = load_config(EgographConfig, DEFAULT_CONFIG)
    rec = open_recording(rec_dir, cfg)
    print_summary(summarize(rec), con, inputs=False)  # `egograph info` also lists every input found
    # detection set -> (what lift reads: the set's name or a detections folder, the tracking config)
    inputs = {det_set: (det_set, DEFAULT_CONFIG) for det_set in ("svoe", "mvpe")}
    if pixels:
        con.rule("2. detect: the instances found in the PV frames (egograph detect)")
        inputs = demo_detect(con, rec, out / "detections")
    reports = {}
    graph_runs = {}
    results = {}  # row name -> results folder, for the pictures
    for det_set, (spec, config) in list(inputs.items()):
        cfg = load_config(EgographConfig, config)
        lifted = {}
        for mode in ("reference", "robust"):
            cfg.lift.mode = mode
            con.rule(f"{3 if pixels else 2}. {det_set.upper()}: lift ({mode}) and track")
            try:
                lifted[mode] = lift(rec, spec, cfg, out / "observations" / f"{det_set}_{mode}.npz")
            except InputError as err:
                # a short recording's few detections may all lie where the AHAT sees nothing: the
                # set is said so and left out, as one in which detect found nothing
                con.print(f"{det_set.upper()}: none of its detections could be lifted to 3D ({mode} lifting: "
                          f"{err.message}); its trackers are not run", soft_wrap=True)
                lifted = None
                break
            rep = lifted[mode][1]
            if rep is not None:  # the headline; `egograph lift` prints why each skipped box was skipped
                con.print(rep.summary().splitlines()[0])
        if lifted is None:
            del inputs[det_set]
            continue
        answered = 0
        for mode, (obs, _) in lifted.items():
            cfg.lift.mode = mode
            # The paper's pipeline is kf on reference lifting; the graph runs on robust lifting.
            trackers = ("memory", "kf") if mode == "reference" else ("memory", "kf", "graph", "graph-causal")
            for tracker in trackers:
                res = out / "results" / f"{det_set}_{tracker}_{mode}"
                result = track(rec, tracker, obs, cfg, res)
                answered += result.n_predictions
                if result.intervals is not None:
                    graph_runs[(det_set, tracker)] = result
                reports[f"{det_set} {tracker} ({mode} lift)"] = evaluate(rec, result)
                results[f"{det_set} {tracker} ({mode} lift)"] = res
        if not answered:
            # scores and pictures of no answer say nothing (a short recording whose few detections
            # all score below the threshold): the set is said so and left out, as an unlifted one
            obs = lifted["robust"][0]
            n_above = int((obs.score >= cfg.track.score_threshold).sum())
            con.print(f"{det_set.upper()}: no tracker answered any PV frame ({n_above} "
                      f"of its {len(obs)} lifted detections score at least track.score_threshold "
                      f"{cfg.track.score_threshold:g}); it is left out of the evaluation and the pictures", soft_wrap=True)
            for store in (reports, results):
                for key in [k for k in store if k.startswith(f"{det_set} ")]:
                    del store[key]
            for key in [k for k in graph_runs if k[0] == det_set]:
                del graph_runs[key]
            del inputs[det_set]
    if not reports:
        raise EgographError("the demo found no instance in any PV frame that could be lifted to 3D and tracked, "
                            "so there is nothing to score: see the " + ("detect, " if pixels else "") + "lift and "
                            "track lines above; a longer recording (--frames) or another --seed has more"
                            + ("; `egograph demo --simulated` tracks the simulated detections" if pixels else ""))
    step = 4 if pixels else 3
    primary = scfg.detections.primary if (scfg.detections.primary, "graph") in graph_runs else \
        next(k for k, t in graph_runs if t == "graph")
    con.rule(f"{step}. position intervals (graph, {primary.upper()})")
    g = graph_runs[(primary, "graph")]
    print_intervals(con, g.intervals, rec, g.metadata, labels(rec))
    con.rule(f"{step + 1}. IT3DEgo evaluation (all frames)" + (", on egograph detect's detections" if pixels else ""))
    for det_set in inputs:
        sub = {k: v for k, v in reports.items() if k.startswith(det_set)}
        con.print(f"[bold]{det_set.upper()}[/bold] (ratios against the published pipeline: kf on reference lifting)")
        print_comparison({k.split(" ", 1)[1]: v for k, v in sub.items()}, "kf (reference lift)", con)
        con.print("intervals recovered: " + ", ".join(
            f"{k.split(' ', 1)[1]} {v.intervals.n_recovered}/{v.intervals.n_true}" for k, v in sub.items()))
        print_dominance(con, det_set, sub)
        print_curves(con, det_set, sub)
    con.rule(f"{step + 2}. pictures (egograph plot)")
    pictures = plot_step(rec, list(results.values()), out / "plots", load_config(EgographConfig, DEFAULT_CONFIG),
                         names=list(results))
    con.print(f"outputs under {out}; {len(pictures.images)} pictures of {len(results)} trackers' results "
              f"(timelines, top-down maps, error and P/R against threshold) in {pictures.folder}; open:",
              soft_wrap=True)
    print((out / "plots" / INDEX_FILE).resolve(), flush=True)
    return 0


def demo_detect(con, rec, out: Path) -> dict[str, tuple[Path, Path]]:
    """``egograph detect`` of both enrollments in ``rec``'s PV frames, into ``out/<set>``; prints each
    summary; the proposals' embeddings are kept in ``out/proposal_embeddings.npz`` for the second
    enrollment (and a rerun). -> set -> (its detections folder to lift, its tracking config), without
    the sets in which nothing was found (said so). Each set detects and tracks with its packaged
    front-end config: SVOE verified by local features (frontend-svoe: detector and trackers at one
    operating point), MVPE with the graph's stricter stands (frontend-mvpe), as `egograph detect`
    advises."""
    from egograph.core.resources import packaged_config_or_error
    from egograph.steps.detect import detect
    from egograph.steps.settings import EgographConfig

    inputs = {}
    for det_set in ("svoe", "mvpe"):
        config = packaged_config_or_error(f"frontend-{det_set}")
        # MVPE reads the proposals and embeddings SVOE's pass kept when both use one proposal source
        # (the key says; verification does not change them); by default they differ (SVOE adds the
        # mesh's objects, frontend.proposals) and MVPE encodes its own
        report = detect(rec, det_set, load_config(EgographConfig, config), out / det_set,
                        embeddings=out / "proposal_embeddings.npz")
        if report is None:
            con.print(f"{det_set.upper()}: {out / det_set} already holds these detections")
        else:
            con.print(f"[bold]{det_set.upper()}[/bold]: " + report.summary())
        if not any(f.stat().st_size for f in (out / det_set).glob("*.txt")):
            con.print(f"{det_set.upper()}: no instance found in any PV frame; its trackers are not run")
            continue
        inputs[det_set] = (out / det_set, config)
    return inputs


def _dominance_why(ours, base: dict, misses: list) -> str:
    """A sentence from the counts on why a tracker misses a baseline: fewer frames answered
    (recall) and answers far off (L2)."""
    out = []
    recall = [m for m in misses if m.metric.startswith("R@")]
    if recall:
        name = recall[-1].against
        theirs = base[name].total
        out.append(f"at its operating point it answers {ours.n_pred} frames against {name}'s {theirs.n_pred} (answers "
                   f"below graph.answers.min_confidence are left out of the files: --min-confidence), and {name}'s "
                   "last-seen guess lands within the threshold on some of those frames")
    if any(m.metric == "L2" for m in misses):
        far = ours.l2_n - int(ours.tp[-1])
        out.append(f"its L2 is the mean error over the {ours.l2_n} frames it answers in a true interval, and {far} of "
                   f"them lie more than {ours.thresholds[-1]:g} m off (a stand at a look-alike's or a wrong place)")
    return "; ".join(out) or "precision below a baseline at a threshold: answers at a wrong place"


def print_dominance(con, det_set: str, reports: dict) -> None:
    """One line per egograph tracker: does it beat every baseline row (memory and kf, both
    liftings) at every threshold, P and R, with a lower L2? Where not, which figures lose."""
    from egograph.eval.metrics import dominance_misses

    base = {k.split(" ", 1)[1]: v for k, v in reports.items() if k.split(" ")[1] in ("memory", "kf")}
    for row in ("graph", "graph-causal"):
        ours = reports.get(f"{det_set} {row} (robust lift)")
        if ours is None:
            continue
        misses = dominance_misses(ours, base, per_sequence=False)
        if not misses:
            con.print(f"{row}: at least every baseline's P and R at every threshold, and a lower L2", soft_wrap=True)
        else:
            text = "; ".join(m.describe() for m in misses)
            con.print(f"{row}: below a baseline on this recording: {text}", soft_wrap=True)
            con.print(f"  why: {_dominance_why(ours.total, base, misses)}", soft_wrap=True)


def print_curves(con, det_set: str, reports: dict) -> None:
    """Per egograph tracker, AP per threshold over its answers' confidence (all-point interpolated),
    the baselines' points, and whether the curve passes at or above every baseline's point (at the
    baseline's recall, precision at least the baseline's)."""
    base = {k.split(" ", 1)[1]: v for k, v in reports.items() if k.split(" ")[1] in ("memory", "kf")}
    ours = {k.split(" ", 1)[1]: v for k, v in reports.items() if k.split(" ")[1].startswith("graph")}
    if not ours:
        return
    taus = next(iter(ours.values())).thresholds
    head = " ".join(f"{t:>5g}" for t in taus)
    con.print(f"average precision over confidence (%, all-point interpolated) at tau (m) {head}", soft_wrap=True)
    for name, rep in ours.items():
        curves = rep.curves()
        if not curves:
            continue
        con.print(f"  {name:30s} " + " ".join(f"{100 * curves[t].ap:5.1f}" for t in taus), soft_wrap=True)
    con.print("baselines' points, P/R %: " + "; ".join(
        f"{name} " + " ".join(f"{100 * p:.1f}/{100 * r:.1f}" for p, r in zip(rep.total.precision, rep.total.recall))
        for name, rep in base.items()), soft_wrap=True)
    for name, rep in ours.items():
        curves = rep.curves()
        if not curves:
            continue
        below = [f"{b} at {t:g} m (P/R {100 * brep.total.precision[k]:.1f}/{100 * brep.total.recall[k]:.1f})"
                 for k, t in enumerate(taus) for b, brep in base.items()
                 if not curves[t].passes(brep.total.precision[k], brep.total.recall[k])]
        con.print(f"{name}: curve at or above every baseline's point at every threshold" if not below else
                  f"{name}: curve below " + "; ".join(below), soft_wrap=True)


# ------------------------------------------------------------------ parser

# The measured times (the demo from pixels, SVOE verified, and the tests, from fresh clones on the
# project's 2-core machine with nothing else running) are data, not code: they live in demo_times.txt
# (package data), so that quoting a new measurement leaves the code's digest, which the benchmark
# records keep, unchanged. README.md quotes the same sentence (tests/test_demo.py checks).
DEMO_TIMES = " ".join(resources.files("egograph.cli").joinpath("demo_times.txt").read_text(encoding="utf-8").split())

DEMO_EPILOG = """\
Steps: 1. a synthetic recording in the device world (depth, poses, annotations, and PV frames that
look like the device's: photographic objects, exposure, noise, motion blur, hands); 2. egograph
detect finds the instances in those frames, SVOE (the box in one frame, its proposals verified by
local features: --config frontend-svoe) and MVPE (the instance photos); 3. per detection set with
detections, both lifting modes and every tracker (memory, kf; graph and graph-causal on robust
lifting); 4. the graph's position intervals; 5. the IT3DEgo evaluation, ratios against kf on
reference lifting; 6. egograph plot of every tracker's results. The last line printed is the path
of the pictures' index.html. With --simulated: the legacy world without RGB, its simulated SVOE and
MVPE detections tracked instead (the tracker-only benchmark's input), step 2 left out.

""" + textwrap.fill(DEMO_TIMES, 96)


def _tracker_help() -> str:
    from egograph.track.registry import DESCRIPTIONS

    return "; ".join(f"{k}: {v}" for k, v in DESCRIPTIONS.items())


def build_parser() -> argparse.ArgumentParser:
    from egograph.track.registry import TRACKERS

    p = argparse.ArgumentParser(prog="egograph", description="Offline factor-graph tracking of object instances in "
                                "egocentric HoloLens 2 recordings (IT3DEgo layout).")
    p.add_argument("--version", action="version", version=f"egograph {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser("synth", help="generate a synthetic recording in the IT3DEgo layout (truth in synth_gt/)")
    s.add_argument("out", type=Path, help="output folder (replaced as a whole when the recording is complete)")
    s.add_argument("--seed", type=int, default=1, help="seed of every random choice (default 1)")
    s.add_argument("--frames", type=int, help="number of PV frames at 30 fps (default from the config)")
    _add_quiet(s)
    _add_overwrite(s)
    s.add_argument("--redetect", action="store_true",
                   help="only re-simulate the detection sets of an existing recording OUT with this config's front-ends")
    _add_config_args(s, SYNTH_CONFIG)
    s.set_defaults(func=cmd_synth, config_kind="synth")

    s = sub.add_parser("info", help="summarise a recording (frames, instances, intervals, calibration fit, pose "
                                    "error vs synth_gt)")
    _add_rec_args(s)
    s.add_argument("--json", type=Path, help="also write the summary as JSON")
    s.add_argument("--refine-calibration", type=Path, metavar="OUT",
                   help="fit the AHAT-PV extrinsic rotation/translation and the AHAT time offset of the calibration "
                        "used to the sequence's frames; write it to OUT as a calibration folder (with fit.json: "
                        "the change, the score before and after)")
    s.add_argument("--refine-frames", type=int, default=200, metavar="N",
                   help="--refine-calibration: PV frames sampled (default 200; of an injected 2 deg / 3 cm / 40 ms, 100 "
                        "left 0.06 deg / 0.7 mm and 200 0.07 deg / 0.9 mm on a synthetic recording, seed 5)")
    _add_overwrite(s)
    _add_config_args(s, DEFAULT_CONFIG)
    s.set_defaults(func=cmd_info)

    s = sub.add_parser("lift", help="lift 2D detections to 3D observations")
    _add_rec_args(s)
    _add_poses_arg(s)
    s.add_argument("--detections", required=True, help="folder of per-frame detection files, or a set name (svoe, mvpe)")
    s.add_argument("--out", required=True, type=Path, help="observations file (.npz, with its provenance)")
    _add_lift_arg(s)
    s.add_argument("--lifted-dir", type=Path, help="also write per-frame lifted points (instance x y z score)")
    _add_quiet(s)
    _add_overwrite(s)
    _add_config_args(s, DEFAULT_CONFIG)
    s.set_defaults(func=cmd_lift)

    s = sub.add_parser("detect", help="detect the enrolled instances in the PV frames (proposals + ONNX encoder); "
                                      "writes one detection file per PV frame for --detections DIR")
    _add_rec_args(s)
    _add_poses_arg(s)
    s.add_argument("--enroll", required=True, choices=["svoe", "mvpe"],
                   help="enrollment: svoe (the box in svoe.txt) or mvpe (the instance photos)")
    s.add_argument("--out", required=True, type=Path, help="detections folder: <ts>.txt per PV frame "
                                                           "(instance x1 y1 x2 y2 det_conf similarity)")
    s.add_argument("--encoder", help="ONNX image encoder (default frontend.encoder; empty: the embedded "
                                     "EfficientNet-lite0)")
    s.add_argument("--proposals", help="geometry, mesh, image, several joined by + (geometry+mesh+image) or an ONNX mask model "
                                       "(default frontend.proposals; for --enroll mvpe frontend.mvpe_proposals)")
    s.add_argument("--guide", type=Path, metavar="RESULTS",
                   help="3D guidance: a results folder of egograph track; in each frame, per instance, the "
                        "above-threshold proposal nearest the projection of its previous frame's prediction "
                        "(within frontend.guidance_radius_px) instead of the most similar one")
    s.add_argument("--adapt", type=Path, metavar="RESULTS",
                   help="the tracker teaches the front-end: a results folder of egograph track --tracker graph "
                        "(or an adapt folder of egograph run); per instance a head learned from its confident "
                        "stands scores the proposals, the cosine as a prior (knobs: section adapt)")
    s.add_argument("--adapt-detections", type=Path, metavar="DIR",
                   help="the detections the --adapt results were tracked from (default: the folder their run "
                        "record names)")
    _add_quiet(s)
    _add_overwrite(s)
    _add_config_args(s, DEFAULT_CONFIG)
    s.set_defaults(func=cmd_detect)

    s = sub.add_parser("track", help="track instances; writes a results folder (per-frame files, intervals.json)")
    _add_rec_args(s)
    _add_poses_arg(s)
    s.add_argument("--tracker", required=True, choices=list(TRACKERS), metavar="{" + ",".join(TRACKERS) + "}",
                   help=_tracker_help())
    s.add_argument("--lag", type=float, metavar="S", help="graph-causal: a frame's answer may use the frames up to "
                                                          "S seconds after it (graph.lag_s; default 0, causal)")
    s.add_argument("--min-confidence", type=float, metavar="C",
                   help="graph trackers: the operating point; the per-frame files hold the answers of confidence >= C "
                        "(answers.tsv every answer; graph.answers.min_confidence, causal_min_confidence)")
    s.add_argument("--intervals", type=Path, help="interval trackers: also write the intervals JSON here "
                                                  "(it is always in RESULTS/intervals.json)")
    s.add_argument("--detections", default="svoe", help="folder of per-frame detection files, or a set name "
                                                        "(svoe, mvpe; default svoe)")
    s.add_argument("--observations", type=Path, help="use lifted observations (.npz from `egograph lift`) instead")
    s.add_argument("--out", required=True, type=Path,
                   help="results folder: <ts>.txt per PV frame (instance x y z score), intervals.json, "
                        "config.yaml, egograph.json")
    _add_lift_arg(s)
    s.add_argument("--eval", action="store_true", help="evaluate the results against the annotations")
    _add_joint_args(s, "RESULTS.poses")
    _add_quiet(s)
    _add_overwrite(s)
    _add_config_args(s, DEFAULT_CONFIG)
    s.set_defaults(func=cmd_track)

    s = sub.add_parser("regt", help="re-estimate the annotated 3D centres from the 2D box annotations; audit them")
    _add_rec_args(s)
    _add_poses_arg(s)
    s.add_argument("--out", required=True, type=Path,
                   help="folder for 3d_center_annot.txt (re-estimated), regt.json (covariances) and audit.md")
    _add_lift_arg(s)
    _add_joint_args(s, "OUT/poses")
    _add_quiet(s)
    _add_config_args(s, DEFAULT_CONFIG)
    s.set_defaults(func=cmd_regt)

    s = sub.add_parser("smooth", help="turn another tracker's per-frame results into intervals with the graph")
    _add_rec_args(s)
    s.add_argument("results", type=Path, help="results folder in the reference format (instance x y z score)")
    s.add_argument("--out", required=True, type=Path, help="smoothed results folder (with intervals.json)")
    s.add_argument("--intervals", type=Path, help="also write the intervals JSON here")
    s.add_argument("--causal", action="store_true", help="causal (iSAM2) instead of offline")
    s.add_argument("--min-confidence", type=float, metavar="C",
                   help="graph trackers: the operating point; the per-frame files hold the answers of confidence >= C "
                        "(answers.tsv every answer; graph.answers.min_confidence, causal_min_confidence)")
    s.add_argument("--eval", action="store_true", help="evaluate the smoothed results against the annotations")
    _add_quiet(s)
    _add_overwrite(s)
    _add_config_args(s, DEFAULT_CONFIG)
    s.set_defaults(func=cmd_smooth)

    s = sub.add_parser("eval", help="IT3DEgo metrics of a results folder")
    _add_rec_args(s)
    s.add_argument("results", type=Path, help="results folder (one <ts>.txt per PV frame; intervals.json scored "
                                              "as it is when present)")
    s.add_argument("--json", type=Path, help="write the metrics as JSON")
    s.add_argument("--markdown", type=Path, help="write the metrics as a markdown table")
    s.add_argument("--csv", type=Path, help="write the metrics as CSV")
    s.add_argument("--plot", type=Path, help="PNG of precision/recall against threshold")
    s.add_argument("--per-instance", action="store_true", help="also a table per instance")
    # --strict (from _add_rec_args) also refuses results with PV frames without a file, lines for unknown
    # instances, two lines for one instance in a frame, or files for no PV frame (default: count them and warn)
    s.add_argument("--format", choices=("table", "md", "csv", "json", "yaml"), default="table",
                   help="how to print: a table sized to the terminal, or every column as md, csv or json "
                        "(yaml: with --show-config)")
    _add_config_args(s, DEFAULT_CONFIG)
    s.set_defaults(func=cmd_eval)

    s = sub.add_parser("compare", help="several results folders against one ground truth, in the paper's table layout")
    _add_rec_args(s)
    s.add_argument("results", nargs="+", type=Path, help="results folders")
    s.add_argument("--names", help="comma-separated row names (default: folder names)")
    s.add_argument("--baseline", default="kf", help="row to give ratios against (default: kf, when present)")
    s.add_argument("--out", type=Path, help="folder for comparison.{md,csv,json,png}")
    s.add_argument("--format", choices=("table", "md", "csv", "json", "yaml"), default="table",
                   help="how to print the comparison: tables sized to the terminal, or every column as md (the "
                        "paper's layout), csv or json (yaml: with --show-config)")
    _add_config_args(s, DEFAULT_CONFIG)
    s.set_defaults(func=cmd_compare)

    s = sub.add_parser("demo", help="generate a synthetic recording, lift, track (baselines and graph), evaluate, "
                                    "draw the results", epilog=DEMO_EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    s.add_argument("out", nargs="?", help="output folder (default: a new temporary folder)")
    s.add_argument("--frames", type=int, default=900, help="length of the recording, PV frames (default 900)")
    s.add_argument("--seed", type=int, default=1, help="seed of the recording (default 1)")
    s.add_argument("--regenerate", action="store_true", help="generate the recording again even if OUT has it")
    s.add_argument("--simulated", action="store_true",
                   help="track the recording's simulated detections (the legacy world, no RGB, no egograph detect: "
                        "the tracker-only benchmark's input) instead of what egograph detect finds in device-like "
                        "PV frames")
    s.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a synthetic-recording knob")
    s.set_defaults(func=cmd_demo)

    from egograph.cli import poses as cli_poses

    cli_poses.add_parsers(sub, _add_config_args, _add_rec_args, DEFAULT_CONFIG)
    from egograph.cli import run as cli_run

    cli_run.add_parser(sub, _add_config_args, DEFAULT_CONFIG)
    from egograph.cli import plot as cli_plot

    cli_plot.add_parser(sub, _add_config_args, _add_rec_args, DEFAULT_CONFIG)
    from egograph.cli import export as cli_export

    cli_export.add_parser(sub, _add_config_args, _add_rec_args, DEFAULT_CONFIG)
    from egograph.cli import tracking2d as cli_tracking2d

    cli_tracking2d.add_parsers(sub, _add_config_args, _add_rec_args, DEFAULT_CONFIG)
    return p


def _config_only(argv: list[str]) -> int | None:
    """``egograph CMD --show-config [--config F] [--set K=V] [--format yaml]``: print the
    configuration without needing the command's other arguments; None when not asked for."""
    if "--show-config" not in argv or not argv or argv[0].startswith("-"):
        return None
    cmd = argv[0]
    p = argparse.ArgumentParser(prog=f"egograph {cmd}", add_help=False)
    p.add_argument("--format", dest="config_format", default="table")
    _add_config_args(p, SYNTH_CONFIG if cmd == "synth" else DEFAULT_CONFIG)
    p.add_argument("--frames", type=int)
    p.add_argument("--lift", choices=["reference", "robust"])
    args, _ = p.parse_known_args(argv[1:])
    cfg = synth_config(args) if cmd == "synth" else pipeline_config(args)
    _show_config(cfg, "yaml" if args.config_format == "yaml" else "table")
    return 0


def main(argv: list[str] | None = None) -> int:
    from egograph.core import signals

    argv = list(sys.argv[1:] if argv is None else argv)
    warnings.simplefilter("default")
    warnings.formatwarning = _one_line_warning
    previous = signals.install()
    try:
        return _flush_stdout(_main(argv))
    except BrokenPipeError:
        return _broken_pipe()
    except OSError as exc:
        if exc.errno in _STDOUT_ERRNOS and getattr(exc, "egograph_stdout", False):
            print(f"egograph: error: standard output: {exc.strerror}", file=sys.stderr)
            return 2
        raise
    finally:
        signals.restore(previous)


_STDOUT_ERRNOS = {errno.ENOSPC, errno.EBADF, errno.EIO, errno.EDQUOT, errno.EFBIG}


def _flush_stdout(code: int) -> int:
    """Flush standard output now, so a full or closed one is an error of this run, not a message
    at interpreter exit."""
    try:
        if sys.stdout is not None:
            sys.stdout.flush()
    except BrokenPipeError:
        raise
    except OSError as exc:
        exc.egograph_stdout = True
        raise
    return code


def _broken_pipe() -> int:
    """The reader of standard output went away (``| head``): stop quietly, as command-line tools do
    (exit 141: a process ended by SIGPIPE)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, AttributeError, ValueError):
        pass
    return 128 + 13


def _stdout_usable() -> str | None:
    """Why standard output cannot take the run's summary (closed), or None."""
    if sys.stdout is None:  # Python's stdout when descriptor 1 was closed at start
        return "closed"
    try:
        fd = sys.stdout.fileno()
    except Exception:  # a replaced stdout without a descriptor (a capture): usable
        return None
    try:
        os.fstat(fd)
    except OSError:
        return "closed"
    return None


def _main(argv: list[str]) -> int:
    from egograph.core import signals

    args = None
    try:
        shown = _config_only(argv)
        if shown is not None:
            return shown
        try:
            args = build_parser().parse_args(argv)
        except SystemExit as exc:  # usage errors (argparse printed them), --help, --version
            return int(exc.code or 0) if not isinstance(exc.code, str) else 2
        why = _stdout_usable()
        if why is not None:
            print(f"egograph: error: standard output is {why}; the run's summary would be lost "
                  "(redirect it to a file or /dev/null)", file=sys.stderr)
            return 2
        from egograph.cli.common import check_output_policy

        check_output_policy(args)
        out = getattr(args, "out", None)
        if out is None:
            return int(args.func(args) or 0)
        from egograph.io.atomic import output_lock

        with output_lock(out):  # a second run on the same --out fails at its start, not after its work
            return int(args.func(args) or 0)
    except EgographError as exc:
        print(f"egograph: error: {_one_line(str(exc))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("egograph: interrupted (SIGINT); nothing was replaced", file=sys.stderr)
        return 130
    except signals.Stopped as exc:
        print(f"egograph: stopped by {exc}; nothing was replaced", file=sys.stderr)
        return signals.exit_code(exc.signum)
    except BrokenPipeError:
        raise
    except OSError as exc:
        from egograph.io.outpolicy import MACHINE_ERRNOS, machine_fault_text

        if exc.errno not in MACHINE_ERRNOS:
            return _internal_error(argv, args)
        if _is_stdout_error(exc):
            exc.egograph_stdout = True
            raise
        print(f"egograph: error: {_one_line(machine_fault_text(exc))}", file=sys.stderr)
        return 2
    except MemoryError:
        print("egograph: error: out of memory", file=sys.stderr)
        return 2
    except Exception:  # a bug, not bad input: one line here, the traceback in a log file
        return _internal_error(argv, args)


def _is_stdout_error(exc: OSError) -> bool:
    """An OSError of writing standard output has no file name (rich and print raise it bare)."""
    return exc.filename is None and exc.errno in _STDOUT_ERRNOS


def _one_line(text: str, limit: int = 2000) -> str:
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _internal_error(argv: list[str], args) -> int:
    exc = sys.exc_info()[1]
    log = _write_crash_log(argv, args)
    where = f"full traceback in {log}" if log is not None else "no log could be written"
    print(f"egograph: internal error: {type(exc).__name__}: {' '.join(str(exc).split())[:300]} "
          f"({where}; please report it)", file=sys.stderr)
    return 1


def _one_line_warning(message, category, filename, lineno, line=None) -> str:
    """Warnings as one line a person reads (``egograph: warning: ...``), without the source line."""
    return f"egograph: warning: {message}\n"


def _write_crash_log(argv: list[str], args) -> Path | None:
    """The traceback of an unexpected exception in a new file of its own: beside the run's output
    (``--out``'s folder when it exists) or in a private folder (``$XDG_STATE_HOME/egograph`` or
    ``~/.local/state/egograph``, mode 0700, refused when it is a link or another user's). The file
    is created exclusively (``O_EXCL``), never following a link, mode 0600, under a random name: a
    link planted in a shared folder cannot redirect it. None when no place could take it."""
    import tempfile
    import traceback

    from egograph.steps.outputs import command_line

    out = getattr(args, "out", None) if args is not None else None
    text = f"egograph {__version__}\n{command_line(['egograph', *argv])}\n\n{traceback.format_exc()}"
    prefix = f"egograph-error-{getattr(args, 'command', None) or 'run'}-"
    for folder in ([Path(out).absolute().parent] if out else []) + [_private_folder()]:
        if folder is None or not folder.is_dir() or folder.is_symlink():
            continue
        try:
            fd, name = tempfile.mkstemp(prefix=prefix, suffix=".log", dir=folder)  # O_EXCL | O_NOFOLLOW, 0600
            with os.fdopen(fd, "w") as fh:
                fh.write(text)
            return Path(name)
        except OSError:
            continue
    return None


def _private_folder() -> Path | None:
    """``$XDG_STATE_HOME/egograph`` (default ``~/.local/state/egograph``), made 0700; None when it
    is a link, not ours, or open to others."""
    import stat

    base = os.environ.get("XDG_STATE_HOME") or os.path.join(os.path.expanduser("~"), ".local", "state")
    folder = Path(base) / "egograph"
    try:
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)
        st = os.lstat(folder)
    except OSError:
        return None
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o077:
        return None
    return folder


if __name__ == "__main__":
    sys.exit(main())
