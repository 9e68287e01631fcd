"""``egograph`` command line: one sub-command per use.

    egograph synth OUT --config configs/synth/svoe.yaml --seed 1 --frames 3000
    egograph info REC
    egograph lift REC --detections svoe --out OBS.npz
    egograph track REC --tracker graph|graph-causal|memory|kf --detections svoe --out RESULTS
    egograph regt REC --out DIR
    egograph smooth REC RESULTS --out RESULTS_SMOOTHED
    egograph eval REC RESULTS [--json OUT]
    egograph compare REC RESULTS_A RESULTS_B ... [--out DIR]
    egograph demo [OUT]

Bad input ends with one line naming the file (and line) and exit code 2.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

from egograph.cli.common import DEFAULT_CONFIG, REPO, _add_config_args, _add_rec_args, _console, _show_config
from egograph.core.config import load_config
from egograph.core.errors import ConfigError


def _pipeline_config(args):
    from egograph.steps.settings import EgographConfig

    return load_config(EgographConfig, args.config, args.overrides)


def _lifting_config(args):
    """Pipeline config with ``--lift`` applied; None after ``--show-config`` printed it."""
    cfg = _pipeline_config(args)
    if args.lift:
        cfg.lift.mode = args.lift
    if args.show_config:
        _show_config(cfg)
        return None
    return cfg




def _open(args, cfg):
    from egograph.steps.pipeline import open_recording

    rec = open_recording(args.rec, cfg, calibration=args.calibration, annotations=args.annotations,
                         sequence=args.sequence)
    if getattr(args, "poses", None):
        from egograph.poses.refine import apply_poses

        rec = apply_poses(rec, args.poses)
    return rec


def _add_poses_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--poses", type=Path, help="use refined poses (a folder from `egograph refine`) instead of the "
                                              "recording's")


def _add_joint_args(p: argparse.ArgumentParser, default_out: str) -> None:
    p.add_argument("--joint-poses", action="store_true",
                   help="joint mode: solve the PV poses together with the still objects' landmarks and the "
                        "refinement factors (refine.* config), then estimate again with the corrected poses")
    p.add_argument("--poses-out", type=Path, help=f"joint mode: where to write the solved poses (default {default_out})")


def _write_joint_poses(con, rec, jp, cfg, out: Path) -> None:
    from egograph.poses.refine import write_refined

    write_refined(jp.poses, out, rec, cfg.refine, {"mode": "joint (poses + object landmarks)", "joint": cfg.joint})
    ch = jp.report["change"]
    con.print(f"joint poses: {jp.report['stands']} stands, {jp.report['detection_factors']} detection factors; poses "
              f"moved {1000 * ch.get('trans_rms_m', 0):.1f} mm / {ch.get('rot_rms_deg', 0):.3f} deg RMS -> {out}")


# ------------------------------------------------------------------ sub-commands

def cmd_synth(args) -> int:
    from egograph.synth.config import SynthConfig
    from egograph.synth.generate import generate

    overrides = list(args.overrides)
    if args.frames is not None:
        overrides.append(f"frames={args.frames}")
    cfg = load_config(SynthConfig, args.config, overrides)
    if args.show_config:
        _show_config(cfg)
        return 0
    if args.redetect:
        from egograph.synth.generate import redetect

        counts = redetect(args.out, cfg)
        _console().print(f"re-simulated detections in {args.out}: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
        return 0
    r = generate(args.out, cfg, seed=args.seed, progress=not args.quiet)
    _console().print(f"wrote {r.root} ({r.frames} frames, {len(r.instances)} instances, {r.n_moves} moves, "
                     f"{r.n_intervals} stationary intervals) in {r.seconds:.1f} s ({r.fps_generation:.1f} frames/s)")
    if not args.quiet:
        cmd_info(argparse.Namespace(rec=args.out, sequence=None, calibration=None, annotations=None, json=None,
                                    config=DEFAULT_CONFIG, overrides=[], show_config=False))
    return 0


def cmd_info(args) -> int:
    from egograph.steps.info import print_summary, summarize

    cfg = _pipeline_config(args)
    rec = _open(args, cfg)
    s = summarize(rec)
    print_summary(s, _console())
    if args.json:
        from egograph.io.atomic import atomic_write_text

        atomic_write_text(args.json, json.dumps(s, indent=1))
    return 0


def cmd_lift(args) -> int:
    from egograph.steps.pipeline import lift

    cfg = _lifting_config(args)
    if cfg is None:
        return 0
    rec = _open(args, cfg)
    t0 = time.perf_counter()
    obs, report = lift(rec, args.detections, cfg, progress=not args.quiet)
    dt = time.perf_counter() - t0
    obs.save(args.out)
    if args.lifted_dir:
        from egograph.geometry.lift import write_lifted_dir

        write_lifted_dir(args.lifted_dir, obs, rec.timestamps)
    con = _console()
    con.print(f"lifted {int(obs.valid.sum())} of {len(obs)} detections ({cfg.lift.mode} mode) in {dt:.1f} s -> {args.out}")
    con.print(report.summary())
    return 0


def cmd_track(args) -> int:
    from egograph.geometry.observations import Observations
    from egograph.steps.pipeline import (
        GRAPH_TRACKERS,
        evaluate,
        lift,
        track,
        track_graph,
        tracker_names,
        write_results,
    )

    cfg = _lifting_config(args)
    if cfg is None:
        return 0
    if args.tracker not in tracker_names():
        raise ConfigError(f"--tracker {args.tracker}: unknown; available: {', '.join(tracker_names())}")
    rec = _open(args, cfg)
    con = _console()
    t0 = time.perf_counter()
    if args.observations:
        obs = Observations.load(args.observations)
    else:
        obs, report = lift(rec, args.detections, cfg, progress=not args.quiet)
        con.print(report.summary())
    t1 = time.perf_counter()
    intervals_path = jp = None
    if args.joint_poses and args.tracker != "graph":
        raise ConfigError(f"--joint-poses needs --tracker graph (offline), not {args.tracker}")
    if args.joint_poses:
        from egograph.steps.pipeline import track_graph_joint

        result, jp = track_graph_joint(rec, obs, cfg, progress=not args.quiet)
        per_frame = result.per_frame
        intervals_path = args.intervals or _sibling(args.out, ".intervals.json")
    elif args.tracker in GRAPH_TRACKERS:
        result = track_graph(rec, obs, cfg, causal=args.tracker == "graph-causal", progress=not args.quiet)
        per_frame = result.per_frame
        intervals_path = args.intervals or _sibling(args.out, ".intervals.json")
    else:
        per_frame = track(rec, args.tracker, obs, cfg)
    t2 = time.perf_counter()
    write_results(args.out, rec, per_frame)
    n_pred = sum(len(v) for v in per_frame.values())
    con.print(f"{args.tracker}: {n_pred} predictions over {len(rec)} frames -> {args.out} "
              f"(lift {t1 - t0:.1f} s, track {t2 - t1:.2f} s)")
    if intervals_path is not None:
        from egograph.track.intervals import write_intervals_json

        write_intervals_json(intervals_path, result.intervals, result.metadata)
        _print_intervals(con, result.intervals, rec, result.metadata)
        con.print(f"intervals -> {intervals_path}")
    if jp is not None:
        _write_joint_poses(con, rec, jp, cfg, args.poses_out or _sibling(args.out, ".poses"))
    if args.eval and rec.annotation_dir is not None:
        evaluate(rec, args.out).print(con)
    return 0


def _sibling(path: Path, suffix: str) -> Path:
    path = Path(path)
    return path.with_name(path.name + suffix)


def _print_intervals(con, intervals, rec, metadata: dict) -> None:
    from rich.table import Table

    t0 = int(rec.timestamps[0])
    t = Table(title=f"position intervals ({metadata.get('tracker')}): {len(intervals)}")
    for col in ("instance", "from (s)", "to (s)", "x", "y", "z", "sigma (cm)", "detections", "confidence", "ended by"):
        t.add_column(col, justify="right")
    for iv in intervals:
        t.add_row(str(iv.instance), f"{(iv.t_start - t0) / 1e7:.1f}" + ("*" if iv.backfilled else ""),
                  f"{(iv.t_end - t0) / 1e7:.1f}", *(f"{v:.2f}" for v in iv.xyz), f"{100 * iv.sigma_m:.1f}",
                  str(iv.n_observations), f"{iv.confidence:.2f}", iv.ended_by)
    con.print(t)
    if metadata.get("backfilled"):
        con.print("* back-filled to the first frame (offline mode: before its first detection an instance is "
                  "reported at its first interval)")


def cmd_regt(args) -> int:
    from egograph.core.errors import InputError
    from egograph.geometry.lift import lift_recording
    from egograph.io.annotations import load_annotations, write_centers
    from egograph.io.atomic import atomic_write_text
    from egograph.steps.pipeline import n_instances, regt_estimates
    from egograph.track.regt import as_center_annotations, audit_text, box_detections

    cfg = _lifting_config(args)
    if cfg is None:
        return 0
    regt = cfg.regt
    rec = _open(args, cfg)
    if rec.annotation_dir is None:
        raise InputError(rec.seq_dir, "no annotations found (motion_state_annot.txt, 2d_bbox_annot/); pass --annotations DIR")
    ann = load_annotations(rec.annotation_dir, box_format=cfg.io.box_format)
    obs, report = lift_recording(rec, box_detections(ann), cfg.lift, progress=not args.quiet,
                                 n_instances=n_instances(rec))
    est, jp = regt_estimates(rec, ann, obs, cfg, joint=args.joint_poses, progress=not args.quiet)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_centers(out / "3d_center_annot.txt", as_center_annotations(est))
    from dataclasses import asdict

    atomic_write_text(out / "regt.json", json.dumps({"audit_m": regt.audit_m, "audit_sigma": regt.audit_sigma,
                                                      "intervals": [asdict(e) for e in est]}, indent=1) + "\n")
    text = audit_text(est, regt)
    atomic_write_text(out / "audit.md", text)
    con = _console()
    con.print(report.summary())
    print(text)
    con.print(f"re-estimated {sum(e.xyz is not None for e in est)} of {len(est)} intervals -> {out}/3d_center_annot.txt, "
              f"regt.json (covariances), audit.md")
    if jp is not None:
        _write_joint_poses(con, rec, jp, cfg, args.poses_out or out / "poses")
    return 0


def cmd_smooth(args) -> int:
    from egograph.io.detections import read_results_dir
    from egograph.steps.pipeline import write_results
    from egograph.track.intervals import write_intervals_json
    from egograph.track.smooth import smooth_predictions

    cfg = _pipeline_config(args)
    if args.show_config:
        _show_config(cfg.graph)
        return 0
    rec = _open(args, cfg)
    per_frame = read_results_dir(args.results, rec.timestamps)
    result = smooth_predictions(rec, per_frame, cfg.graph, causal=args.causal, progress=not args.quiet)
    result.metadata["smoothed"] = str(args.results)
    write_results(args.out, rec, result.per_frame)
    ipath = args.intervals or _sibling(args.out, ".intervals.json")
    write_intervals_json(ipath, result.intervals, result.metadata)
    con = _console()
    _print_intervals(con, result.intervals, rec, result.metadata)
    con.print(f"smoothed {result.metadata['n_observations']} predictions of {args.results} -> {args.out}, "
              f"intervals -> {ipath}")
    if args.eval and rec.annotation_dir is not None:
        from egograph.steps.pipeline import evaluate

        evaluate(rec, args.out).print(con)
    return 0


def cmd_eval(args) -> int:
    from egograph.steps.pipeline import evaluate

    cfg = _pipeline_config(args)
    rec = _open(args, cfg)
    report = evaluate(rec, args.results)
    report.print(_console(), per_instance=args.per_instance)
    if report.frames_without_file:
        _console().print(f"[yellow]{report.frames_without_file} frames had no results file (counted as no prediction)")
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
    from egograph.eval.report import comparison_table, plot_pr
    from egograph.io.atomic import atomic_write_text
    from egograph.steps.pipeline import evaluate

    cfg = _pipeline_config(args)
    rec = _open(args, cfg)
    names = args.names.split(",") if args.names else [Path(r).name for r in args.results]
    if len(names) != len(args.results) or len(set(names)) != len(names):
        raise ConfigError("--names must give one distinct name per results folder")
    reports = {n: evaluate(rec, r) for n, r in zip(names, args.results)}
    baseline = args.baseline if args.baseline in reports else None
    md, csv = comparison_table(reports, baseline=baseline)
    print(md)
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(out / "comparison.md", md)
        atomic_write_text(out / "comparison.csv", csv)
        atomic_write_text(out / "comparison.json", json.dumps({n: r.to_json_dict() for n, r in reports.items()}, indent=1))
        plot_pr(reports, out / "comparison.png")
        _console().print(f"wrote {out}/comparison.{{md,csv,json,png}}")
    return 0


def cmd_demo(args) -> int:
    """The main job on the embedded default: generate, lift, track (the paper's baselines and the
    factor-graph tracker), show the graph's position intervals, evaluate."""
    import tempfile

    from egograph.eval.report import comparison_table
    from egograph.steps.pipeline import GRAPH_TRACKERS, evaluate, lift, track, track_graph, write_results
    from egograph.synth.config import SynthConfig
    from egograph.synth.generate import generate
    from egograph.track.intervals import write_intervals_json

    con = _console()
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="egograph-demo-"))
    scfg = load_config(SynthConfig, REPO / "configs" / "synth" / "svoe.yaml",
                       [f"frames={args.frames}", "pv.rgb=false", *args.overrides])
    rec_dir = out / "recording"
    if not (rec_dir / "recording.json").exists() or args.regenerate:
        con.rule("1. synthetic recording")
        r = generate(rec_dir, scfg, seed=args.seed)
        con.print(f"generated {r.frames} frames in {r.seconds:.1f} s ({r.fps_generation:.1f} frames/s)")
    cmd_info(argparse.Namespace(rec=rec_dir, sequence=None, calibration=None, annotations=None, json=None,
                                config=DEFAULT_CONFIG, overrides=[], show_config=False))
    from egograph.steps.pipeline import open_recording
    from egograph.steps.settings import EgographConfig

    cfg = load_config(EgographConfig, DEFAULT_CONFIG)

    rec = open_recording(rec_dir, cfg)
    reports = {}
    graph_runs = {}
    for det_set in ("svoe", "mvpe"):
        for mode in ("reference", "robust"):
            cfg.lift.mode = mode
            con.rule(f"2. {det_set.upper()}: lift ({mode}) and track")
            obs, rep = lift(rec, det_set, cfg)
            con.print(rep.summary())
            # The paper's pipeline is kf on reference lifting; the graph runs on robust lifting.
            trackers = ("memory", "kf") if mode == "reference" else ("memory", "kf", "graph", "graph-causal")
            for tracker in trackers:
                res = out / "results" / f"{det_set}_{tracker}_{mode}"
                if tracker in GRAPH_TRACKERS:
                    result = track_graph(rec, obs, cfg, causal=tracker == "graph-causal")
                    write_results(res, rec, result.per_frame)
                    write_intervals_json(_sibling(res, ".intervals.json"), result.intervals, result.metadata)
                    graph_runs[(det_set, tracker)] = result
                else:
                    write_results(res, rec, track(rec, tracker, obs, cfg))
                reports[f"{det_set} {tracker} ({mode} lift)"] = evaluate(rec, res)
    primary = scfg.detections.primary
    con.rule(f"3. position intervals (graph, {primary.upper()})")
    _print_intervals(con, graph_runs[(primary, "graph")].intervals, rec, graph_runs[(primary, "graph")].metadata)
    con.rule("4. IT3DEgo evaluation (all frames)")
    for det_set in ("svoe", "mvpe"):
        sub = {k: v for k, v in reports.items() if k.startswith(det_set)}
        md, _ = comparison_table(sub, baseline=f"{det_set} kf (reference lift)")
        con.print(f"[bold]{det_set.upper()}[/bold] (ratios against the published pipeline: kf on reference lifting)")
        print(md)
        con.print("intervals recovered: " + ", ".join(
            f"{k.split(' ', 1)[1]} {v.intervals.n_recovered}/{v.intervals.n_true}" for k, v in sub.items()))
    con.print(f"outputs under {out}")
    return 0


# ------------------------------------------------------------------ parser

def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="egograph", description="Offline factor-graph tracking of object instances in "
                                "egocentric HoloLens 2 recordings (IT3DEgo layout).")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("synth", help="generate a synthetic recording in the IT3DEgo layout (truth in synth_gt/)")
    s.add_argument("out", type=Path)
    s.add_argument("--seed", type=int, default=1)
    s.add_argument("--frames", type=int)
    s.add_argument("--quiet", action="store_true")
    s.add_argument("--redetect", action="store_true",
                   help="only re-simulate the detection sets of an existing recording OUT with this config's front-ends")
    _add_config_args(s, REPO / "configs" / "synth" / "svoe.yaml")
    s.set_defaults(func=cmd_synth)

    s = sub.add_parser("info", help="summarise a recording (frames, instances, intervals, pose error vs synth_gt)")
    _add_rec_args(s)
    s.add_argument("--json", type=Path, help="also write the summary as JSON")
    _add_config_args(s, DEFAULT_CONFIG)
    s.set_defaults(func=cmd_info)

    s = sub.add_parser("lift", help="lift 2D detections to 3D observations")
    _add_rec_args(s)
    _add_poses_arg(s)
    s.add_argument("--detections", required=True, help="folder of per-frame detection files, or a set name (svoe, mvpe)")
    s.add_argument("--out", required=True, type=Path, help="observations file (.npz)")
    s.add_argument("--lift", choices=["reference", "robust"], help="lifting mode (default from config: robust)")
    s.add_argument("--lifted-dir", type=Path, help="also write per-frame lifted points (instance x y z score)")
    s.add_argument("--quiet", action="store_true")
    _add_config_args(s, DEFAULT_CONFIG)
    s.set_defaults(func=cmd_lift)

    s = sub.add_parser("track", help="track instances; writes per-frame results (instance x y z score)")
    _add_rec_args(s)
    _add_poses_arg(s)
    s.add_argument("--tracker", required=True, help="graph | graph-causal | memory | kf")
    s.add_argument("--intervals", type=Path, help="graph trackers: intervals JSON (default: RESULTS.intervals.json)")
    s.add_argument("--detections", default="svoe", help="folder of per-frame detection files, or a set name (svoe, mvpe)")
    s.add_argument("--observations", type=Path, help="use lifted observations (.npz from `egograph lift`) instead")
    s.add_argument("--out", required=True, type=Path, help="results folder (one file per PV frame)")
    s.add_argument("--lift", choices=["reference", "robust"])
    s.add_argument("--eval", action="store_true", help="evaluate the results against the annotations")
    _add_joint_args(s, "RESULTS.poses")
    s.add_argument("--quiet", action="store_true")
    _add_config_args(s, DEFAULT_CONFIG)
    s.set_defaults(func=cmd_track)

    s = sub.add_parser("regt", help="re-estimate the annotated 3D centres from the 2D box annotations; audit them")
    _add_rec_args(s)
    _add_poses_arg(s)
    s.add_argument("--out", required=True, type=Path,
                   help="folder for 3d_center_annot.txt (re-estimated), regt.json (covariances) and audit.md")
    s.add_argument("--lift", choices=["reference", "robust"])
    _add_joint_args(s, "OUT/poses")
    s.add_argument("--quiet", action="store_true")
    _add_config_args(s, DEFAULT_CONFIG)
    s.set_defaults(func=cmd_regt)

    s = sub.add_parser("smooth", help="turn another tracker's per-frame results into intervals with the graph")
    _add_rec_args(s)
    s.add_argument("results", type=Path, help="results folder in the reference format (instance x y z score)")
    s.add_argument("--out", required=True, type=Path, help="smoothed results folder")
    s.add_argument("--intervals", type=Path, help="intervals JSON (default: OUT.intervals.json)")
    s.add_argument("--causal", action="store_true", help="causal (iSAM2) instead of offline")
    s.add_argument("--eval", action="store_true")
    s.add_argument("--quiet", action="store_true")
    _add_config_args(s, DEFAULT_CONFIG)
    s.set_defaults(func=cmd_smooth)

    s = sub.add_parser("eval", help="IT3DEgo metrics of a results folder")
    _add_rec_args(s)
    s.add_argument("results", type=Path)
    s.add_argument("--json", type=Path)
    s.add_argument("--markdown", type=Path)
    s.add_argument("--csv", type=Path)
    s.add_argument("--plot", type=Path, help="PNG of precision/recall against threshold")
    s.add_argument("--per-instance", action="store_true")
    _add_config_args(s, DEFAULT_CONFIG)
    s.set_defaults(func=cmd_eval)

    s = sub.add_parser("compare", help="several results folders against one ground truth, in the paper's table layout")
    _add_rec_args(s)
    s.add_argument("results", nargs="+", type=Path)
    s.add_argument("--names", help="comma-separated row names (default: folder names)")
    s.add_argument("--baseline", default="kf", help="row to give ratios against (default: kf, when present)")
    s.add_argument("--out", type=Path)
    _add_config_args(s, DEFAULT_CONFIG)
    s.set_defaults(func=cmd_compare)

    s = sub.add_parser("demo", help="generate a synthetic recording, lift, track (baselines and graph), evaluate")
    s.add_argument("out", nargs="?", help="output folder (default: a new temporary folder)")
    s.add_argument("--frames", type=int, default=900)
    s.add_argument("--seed", type=int, default=1)
    s.add_argument("--regenerate", action="store_true")
    s.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a synthetic-recording knob")
    s.set_defaults(func=cmd_demo)

    from egograph.cli import poses as cli_poses

    cli_poses.add_parsers(sub, _add_config_args, _add_rec_args, DEFAULT_CONFIG)
    return p


def main(argv: list[str] | None = None) -> int:
    from egograph.core.errors import InputError

    args = build_parser().parse_args(argv)
    warnings.simplefilter("default")
    try:
        return int(args.func(args) or 0)
    except (InputError, ConfigError) as exc:
        print(f"egograph: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
