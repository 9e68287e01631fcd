"""Step ``refine``: the HoloLens poses refined with a pose graph (``cfg.refine``), written as
``pv_pose.json``, ``depth_ahat_pose.json``, TUM files, ``pv_position_covariance.json`` (per-frame
world-frame position covariance, m², with ``refine.covariance``), ``report.json``/``report.md`` (with
the self-check: per segment whether the refined or the input poses were kept, and why),
``config.yaml`` and ``egograph.json`` in one folder (one rename)."""

from __future__ import annotations

from pathlib import Path

from egograph.core.config import to_dict
from egograph.core.errors import ConfigError, InputError
from egograph.io.recording import Recording, report_problem
from egograph.steps import outputs


def check_output(rec: Recording, out: Path) -> None:
    o, seq = Path(out).resolve(), rec.seq_dir.resolve()
    if o == seq or o in seq.parents:
        raise InputError(out, "refusing to overwrite the input recording; choose another --out folder")


def refine(rec: Recording, cfg, out: str | Path | None = None, *, overwrite: bool = False, progress: bool = False):
    """Refined poses of ``rec`` -> ``(RefineResult, extra)``; ``extra`` holds the pose errors
    against ``synth_gt/`` before and after, when the recording has them. With ``out`` the folder is
    written; an ``out`` already holding this exact run is left as it is (``RefineResult`` None)."""
    import warnings

    from egograph.poses.refine import refine_recording, write_refined

    cfg.refine.check()
    usable = int((rec.pv_valid & rec.depth_valid).sum())
    if usable < 3:
        raise InputError(rec.seq_dir / "pv_pose.json", f"refine needs at least 3 frames with valid PV and AHAT poses; "
                                                       f"found {usable} of {len(rec)}")
    if cfg.refine.mesh or cfg.refine.icp:
        from egograph.geometry.lift import check_rig

        check_rig(rec)  # AHAT points reach the world through the rig extrinsics: not rigid -> nothing to align
    if cfg.refine.mesh and not rec.mesh_paths():
        # without the HoloLens mesh its ICP factors are missing: the poses move by the error model only
        report_problem(getattr(rec, "strict", False), rec.seq_dir / "mesh",
                       "no scene mesh (tried mesh/*.ply, *.obj, *.stl, *.off): refine.mesh constraints skipped")
    record = outputs.run_record("refine", cfg, {"recording": outputs.recording_digest(rec)},
                                depends_on={"refine": to_dict(cfg.refine)})
    if out is not None:
        check_output(rec, Path(out))
        if outputs.up_to_date(out, record, overwrite):
            return None, {}
    if cfg.refine.colmap and not any(rec.pv_path(i).is_file() for i in range(0, len(rec), max(1, len(rec) // 10))):
        raise ConfigError(f"refine.colmap=true needs PV images ({rec.seq_dir / 'pv'}/<ts>.png); none found")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # missing/unreadable depth frames are counted, not printed
        result = refine_recording(rec, cfg.refine, progress=progress)
    import numpy as np

    from egograph.core.units import TICKS_PER_SECOND
    from egograph.poses.metrics import pose_differences
    from egograph.poses.stretches import largest_move, stretch_bounds, stretch_rows

    extra = {}
    err_in = err_out = None
    if rec.synth_gt_dir is not None and (rec.synth_gt_dir / "pv_pose.json").is_file():
        from egograph.io.poses import read_pose_json
        from egograph.poses.evaluate import evaluate_trajectory

        gt_ts, gt, _ = read_pose_json(rec.synth_gt_dir / "pv_pose.json")
        _, i, j = np.intersect1d(rec.timestamps, gt_ts, return_indices=True)  # frames both have
        extra["eval_reported"] = evaluate_trajectory(rec.pv_poses[i], gt[j]).as_dict()
        extra["eval_refined"] = evaluate_trajectory(result.pv_poses[i], gt[j]).as_dict()
        err_in, err_out = np.full(len(rec), np.nan), np.full(len(rec), np.nan)
        err_in[i] = pose_differences(rec.pv_poses[i], gt[j])[0]
        err_out[i] = pose_differences(result.pv_poses[i], gt[j])[0]
    # which sources constrained which stretch, what moved most and why (report.md)
    ts_s = (rec.timestamps - rec.timestamps[0]) / TICKS_PER_SECOND
    moved = pose_differences(result.pv_poses, rec.pv_poses)[0]
    keyframes = result.stats.get("mesh_keyframes") or []
    jumps = (result.stats.get("jumps") or {}).get("frames") or []
    bounds = stretch_bounds(len(rec), ts_s, result.selfcheck, cfg.refine.selfcheck_segment)
    extra["stretches"] = stretch_rows(ts_s, bounds, moved, keyframes, jumps, err_in, err_out)
    extra["largest_move"] = largest_move(ts_s, moved, keyframes, jumps)
    if out is not None:
        write_refined(result, out, rec, cfg.refine, extra, run_files=outputs.run_files(record, cfg))
    return result, extra
