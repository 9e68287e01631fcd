"""Step ``regt``: re-estimate the annotated 3D centres (``3d_center_annot.txt``) from the 2D box
annotations with the landmark solve, and audit the given centres against the re-estimates.

Output folder: ``3d_center_annot.txt`` (re-estimated, the annotation format), ``regt.json``
(covariances, m^2), ``audit.md``, ``config.yaml``, ``egograph.json``; one rename.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

from egograph.io.recording import Recording
from egograph.steps import outputs
from egograph.steps.recording import n_instances, require_annotations


@dataclass
class RegtResult:
    estimates: list            # egograph.track.regt.Reestimate per annotated interval
    audit: str                 # the audit as markdown
    lift_report: object = None
    joint: object = None       # JointPoses in joint mode


def regt(rec: Recording, cfg, out: str | Path | None = None, *, joint: bool = False, progress: bool = False
         ) -> RegtResult:
    """Re-estimated centres of every annotated interval of ``rec`` (``cfg.lift``, ``cfg.graph``,
    ``cfg.regt``; ``joint``: poses solved with one landmark per interval first)."""
    from egograph.geometry.lift import lift_recording
    from egograph.io.annotations import load_annotations
    from egograph.track.regt import audit_text, box_detections

    ann_dir = require_annotations(rec, "motion_state_annot.txt, 2d_bbox_annot/")
    ann = load_annotations(ann_dir, box_format=cfg.io.box_format)
    check_regt_inputs(rec, ann_dir, ann)
    obs, report = lift_recording(rec, box_detections(ann), cfg.lift, progress=progress, n_instances=n_instances(rec))
    est, jp = regt_estimates(rec, ann, obs, cfg, joint=joint, progress=progress)
    result = RegtResult(est, audit_text(est, cfg.regt), report, jp)
    if out is not None:
        write_regt(out, rec, result, cfg, joint)
    return result


def check_regt_inputs(rec: Recording, ann_dir: Path, ann) -> None:
    """What ``regt`` reads, before anything is lifted: InputError (naming the file) without a
    stationary interval (``motion_state_annot.txt``: nothing to re-estimate) or without a box
    annotation (``2d_bbox_annot/``: nothing to lift); a warning (under ``rec.strict`` an
    InputError) without a given centre (``3d_center_annot.txt`` missing or empty: nothing to audit)."""
    from egograph.core.errors import InputError
    from egograph.io.annotations import BBOX_DIR, CENTERS_FILE, MOTION_FILE
    from egograph.io.recording import report_problem

    if not ann.motion:
        what = "has no stationary interval" if (ann_dir / MOTION_FILE).exists() else "missing"
        raise InputError(ann_dir / MOTION_FILE, f"{what}: regt re-estimates the centre of each stationary "
                                                "interval (instance_id t_start t_end), so there is nothing to do")
    if not any(ann.boxes.values()):
        folder = ann_dir / BBOX_DIR
        what = "no box in any <instance_id>.txt" if folder.is_dir() else "folder missing"
        raise InputError(folder, f"{what}: regt lifts the annotated 2D boxes, so there is nothing to lift")
    centers = ann_dir / CENTERS_FILE
    if not ann.centers:
        what = "empty (no row)" if centers.exists() else "missing"
        report_problem(rec.strict, centers, f"{what}: the re-estimates are written, but there is no given centre "
                                            "to audit them against")


def regt_estimates(rec: Recording, ann, obs, cfg, joint: bool = False, progress: bool = False):
    """Re-estimated centres of the annotated intervals ``ann`` from lifted boxes ``obs`` ->
    ``(estimates, JointPoses | None)``; with ``joint`` the poses are first solved together with one
    landmark per interval (refinement factors + the boxes' inliers)."""
    from egograph.track.regt import reestimate_centres

    jp = None
    if joint:
        from egograph.steps.joint import regt_joint

        obs, jp = regt_joint(rec, ann, obs, cfg, progress=progress)
    return reestimate_centres(ann, obs, cfg.graph, cfg.regt), jp


def write_regt(out: str | Path, rec: Recording, result: RegtResult, cfg, joint: bool) -> Path:
    from egograph.io.annotations import centers_text
    from egograph.io.atomic import atomic_dir
    from egograph.track.regt import as_center_annotations

    record = outputs.run_record("regt", cfg, {"recording": outputs.recording_digest(rec), "joint": joint})
    with atomic_dir(out) as tmp:
        (tmp / "3d_center_annot.txt").write_text(centers_text(as_center_annotations(result.estimates)))
        (tmp / "regt.json").write_text(json.dumps({"audit_m": cfg.regt.audit_m, "audit_sigma": cfg.regt.audit_sigma,
                                                   "intervals": [asdict(e) for e in result.estimates]}, indent=1) + "\n")
        (tmp / "audit.md").write_text(result.audit)
        outputs.write_run_files(tmp, record, cfg)
    return Path(out)
