"""``egograph refine`` and ``egograph eval-poses``: pose-graph refinement of the HoloLens poses and
pose evaluation (ATE/RPE).

    egograph refine REC --out DIR [--set refine.mesh=false ...]
    egograph eval-poses REC [POSES] [--reference FILE] [--json OUT] [--plot OUT.png]

``POSES`` is a folder holding ``pv_pose.json`` (as ``egograph refine`` writes) or a TUM
file; without it the recording's own poses are evaluated. The reference is ``synth_gt/``
when the recording has one, else ``--reference`` (a folder with ``pv_pose.json`` or a TUM file).
"""

from __future__ import annotations

import json
from pathlib import Path


def add_parsers(sub, add_config_args, add_rec_args, default_config: Path) -> None:
    """Add the ``refine`` and ``eval-poses`` sub-commands (the helpers come from ``egograph.cli``)."""
    s = sub.add_parser("refine", help="refine the HoloLens poses with a pose graph (HoloLens + KISS-ICP + mesh ICP "
                                      "[+ COLMAP]); writes pv_pose.json, depth_ahat_pose.json, TUM files, a report")
    add_rec_args(s)
    s.add_argument("--out", required=True, type=Path, help="output folder (never the recording itself)")
    s.add_argument("--quiet", action="store_true", help="no progress bars")
    s.add_argument("--overwrite", action="store_true", help="refine again even when OUT already holds this exact run")
    add_config_args(s, default_config)
    s.set_defaults(func=cmd_refine)

    s = sub.add_parser("eval-poses", help="ATE/RPE of poses against synth_gt/ or a reference trajectory")
    add_rec_args(s)
    s.add_argument("poses", nargs="?", type=Path, help="folder with pv_pose.json, or a TUM file (default: the "
                                                      "recording's own poses)")
    s.add_argument("--reference", type=Path, help="reference: folder with pv_pose.json or a TUM file (default: synth_gt/)")
    s.add_argument("--rpe-delta", type=int, default=1, help="RPE frame distance (default 1)")
    s.add_argument("--json", type=Path, help="write the figures as JSON")
    s.add_argument("--plot", type=Path, help="PNG of the position error over time")
    add_config_args(s, default_config)
    s.set_defaults(func=cmd_eval_poses)


def _config(args):
    from egograph.cli.common import pipeline_config

    return pipeline_config(args)


def _open(args, cfg):
    from egograph.io.recording import Recording

    # frames with an invalid pose are refined around (never an error here)
    return Recording.open(args.rec, sequence=args.sequence, calibration=args.calibration, annotations=args.annotations,
                          invalid_poses="skip" if cfg.io.invalid_poses == "error" else cfg.io.invalid_poses,
                          depth_factor=cfg.io.depth_factor or None, strict=cfg.io.strict,
                          depth_sync_ms=cfg.io.depth_sync_ms)


def cmd_refine(args) -> int:
    from egograph.cli.common import _console
    from egograph.steps.refine import refine

    cfg = _config(args)
    rec = _open(args, cfg)
    result, extra = refine(rec, cfg, args.out, overwrite=args.overwrite, progress=not args.quiet)
    if result is None:
        _console().print(f"{args.out} already holds this refinement (same recording and refine.* configuration); "
                         f"--overwrite refines again")
        return 0
    _summary(result, extra, Path(args.out))
    return 0


def _summary(result, extra: dict, out: Path) -> None:
    from rich.table import Table

    from egograph.cli.common import _console

    con = _console()
    t = Table(title=f"refined poses -> {out}")
    t.add_column("stage")
    t.add_column("seconds", justify="right")
    t.add_column("factors", justify="right")
    for k, v in result.stage_seconds.items():
        t.add_row(k, f"{v:.2f}", str(result.factor_counts.get(k, "")))
    for k, v in result.factor_counts.items():
        if k not in result.stage_seconds:
            t.add_row(k, "", str(v))
    con.print(t)
    ch = result.change
    if ch.get("n"):
        con.print(f"moved the PV poses by {ch['trans_rms_m'] * 1000:.1f} mm rms (max {ch['trans_max_m'] * 1000:.1f}), "
                  f"{ch['rot_rms_deg']:.3f} deg rms (max {ch['rot_max_deg']:.3f})")
    if "eval_refined" in extra:
        a, b = extra["eval_reported"], extra["eval_refined"]
        con.print(f"vs synth_gt: ATE {a['ate_rmse_m'] * 100:.2f} -> {b['ate_rmse_m'] * 100:.2f} cm "
                  f"(aligned {a['ate_rmse_aligned_m'] * 100:.2f} -> {b['ate_rmse_aligned_m'] * 100:.2f}), "
                  f"RPE {a['rpe_trans_m'] * 1000:.2f} -> {b['rpe_trans_m'] * 1000:.2f} mm, "
                  f"{a['rpe_rot_deg']:.3f} -> {b['rpe_rot_deg']:.3f} deg")


def load_trajectory(path: Path, rec=None):
    """(timestamps, PV poses row-vector) from a folder with pv_pose.json or a TUM file."""
    from egograph.core.errors import InputError
    from egograph.io.poses import read_pose_json
    from egograph.poses.tum import read_tum

    path = Path(path)
    if path.is_dir():
        f = path / "pv_pose.json"
        if not f.is_file():
            raise InputError(path, "no pv_pose.json in this folder")
        ts, poses, ok = read_pose_json(f, "skip")
        poses[~ok] = float("nan")
        return ts, poses
    if not path.exists():
        raise InputError(path, "poses not found")
    if path.suffix == ".json":
        ts, poses, ok = read_pose_json(path, "skip")
        poses[~ok] = float("nan")
        return ts, poses
    return read_tum(path)


def cmd_eval_poses(args) -> int:
    import numpy as np

    from egograph.core.errors import InputError
    from egograph.io.atomic import atomic_write_text
    from egograph.poses.evaluate import ate_errors, evaluate_trajectory, match_timestamps, plot_errors

    cfg = _config(args)
    rec = _open(args, cfg)
    if args.reference is not None:
        ref_ts, ref = load_trajectory(args.reference)
        ref_name = str(args.reference)
    elif rec.synth_gt_dir is not None and (rec.synth_gt_dir / "pv_pose.json").is_file():
        ref_ts, ref = load_trajectory(rec.synth_gt_dir)
        ref_name = "synth_gt"
    else:
        raise InputError(rec.seq_dir, "no synth_gt/ for this recording: give --reference FILE (TUM or pv_pose.json folder)")
    if args.poses is not None:
        est_ts, est = load_trajectory(args.poses)
        est_name = str(args.poses)
    else:
        est_ts, est = rec.timestamps, np.where(rec.pv_valid[:, None, None], rec.pv_poses, np.nan)
        est_name = "reported"
    ts, e, r = match_timestamps(est_ts, est, ref_ts, ref, where=args.poses or rec.seq_dir)
    ev = evaluate_trajectory(e, r, args.rpe_delta)
    out = {"poses": est_name, "reference": ref_name, **ev.as_dict()}
    if args.json:
        atomic_write_text(args.json, json.dumps(out, indent=1))
    if args.plot:
        ok = np.isfinite(e).all(axis=(1, 2)) & np.isfinite(r).all(axis=(1, 2))
        err = np.full(len(ts), np.nan)
        err[ok] = ate_errors(e[ok], r[ok])
        curves = {est_name: err}
        if args.poses is not None:  # the recording's own poses for comparison
            _, rr, rref = match_timestamps(rec.timestamps, np.where(rec.pv_valid[:, None, None], rec.pv_poses, np.nan),
                                           ts, r, where=rec.seq_dir)
            ok2 = np.isfinite(rr).all(axis=(1, 2)) & np.isfinite(rref).all(axis=(1, 2))
            e2 = np.full(len(rr), np.nan)
            e2[ok2] = ate_errors(rr[ok2], rref[ok2])
            curves = {"reported": e2, **curves}
        plot_errors(args.plot, (ts - ts[0]) / 1e7, curves, f"position error vs {ref_name}")
    from egograph.cli.common import _console

    _console().print(f"{est_name} vs {ref_name} ({ev.n} frames): ATE {ev.ate_rmse_m * 100:.2f} cm "
                     f"(aligned {ev.ate_rmse_aligned_m * 100:.2f} cm, max {ev.ate_max_m * 100:.2f} cm), rotation "
                     f"{ev.rot_rmse_deg:.3f} deg rms, RPE({ev.rpe_delta} frame) {ev.rpe_trans_m * 1000:.2f} mm / "
                     f"{ev.rpe_rot_deg:.3f} deg")
    return 0
