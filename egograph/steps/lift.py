"""Step ``lift``: 2D detections + AHAT depth + poses -> 3D observations (``.npz``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from egograph.core.config import to_dict
from egograph.core.errors import InputError
from egograph.geometry.observations import Observations
from egograph.io.detections import read_detection_dir
from egograph.io.recording import Recording, report_problem
from egograph.steps import outputs
from egograph.steps.recording import n_instances


def load_detections(rec: Recording, spec: str | Path, cfg) -> dict:
    """Per-frame detections from a folder or a set name the recording carries (``svoe``, ``mvpe``).

    The reference writes a file for every PV frame, empty without detections: PV frames without a
    file are read as frames without detections, warned about with their count (refused under
    ``rec.strict``) and counted in the lift report."""
    folder = rec.detections_dir(str(spec))
    if folder is not None and (Path(folder) / outputs.RUN_FILE).is_file():  # made by egograph detect / sot
        outputs.check_results_belong(rec, folder, "detections")
    dets = read_detection_dir(folder, rec.timestamps, box_format=cfg.io.box_format)
    warn_missing_detection_files(rec, dets.scan)
    return dets


def warn_missing_detection_files(rec: Recording, scan) -> None:
    """A warning (``rec.strict``: InputError) naming the folder when PV frames have no detection file."""
    if scan is not None and scan.missing:
        report_problem(rec.strict, scan.folder, f"{len(scan.missing)} of {len(rec)} PV frames have no detection "
                                                f"file (e.g. {scan.missing[0]}.txt; tried <ts>.txt for each PV "
                                                "timestamp); read as frames without detections")


def warn_unknown_instances(rec: Recording, dets: dict, n: int | None) -> None:
    """A warning (``rec.strict``: InputError) naming the first file when detections carry instance
    ids beyond the ``n`` labels: the lift skips them (``unknown_instance`` in its report)."""
    if n is None:
        return
    bad = [(ts, d.instance) for ts, frame in dets.items() for d in frame if d.instance >= n]
    if bad:
        ts, inst = bad[0]
        scan = getattr(dets, "scan", None)
        where = scan.matched[ts] if scan is not None and ts in scan.matched else rec.seq_dir
        report_problem(rec.strict, where, f"instance id {inst} beyond the {n} labels of labels.csv; {len(bad)} "
                                          f"detection(s) with such ids skipped")


def provenance(rec: Recording, spec: str | Path, cfg) -> dict:
    """What a set of observations depends on: the recording and its poses (refined poses differ),
    the detections (folder digest), the lifting knobs that change results and the io knobs."""
    det_dir = rec.detections_dir(str(spec))
    return {"recording": outputs.recording_digest(rec),
            "detections": {"spec": str(spec), "digest": outputs.folder_digest(det_dir)},
            "lift": cfg.lift.result_knobs(), "io": to_dict(cfg.io)}


MIN_VIEW_CHECK = 5
"""Lifted points needed before :func:`check_in_pv_view` judges (fewer prove nothing)."""

MAX_OUT_OF_VIEW = 0.5
"""The largest fraction of lifted points that may fall behind the PV camera or outside its image."""


def check_in_pv_view(rec: Recording, obs: Observations) -> None:
    """Refuse a lift whose points mostly fall behind the PV camera or outside its image: every box
    was seen in the PV image, so its lifted point must project back into it. The usual cause is a
    rig extrinsics file in another axis convention (e.g. identity for a depth camera that shares
    the PV camera), which mirrors every point behind the camera."""
    from egograph.geometry.hl2ss import pv_project

    ok = obs.valid & rec.pv_valid[obs.frame]
    n = int(ok.sum())
    if n < MIN_VIEW_CHECK:
        return
    world = np.concatenate([obs.world[ok], np.ones((n, 1))], axis=1)
    to_cam = np.linalg.inv(rec.pv_poses[obs.frame[ok]])  # PV camera -> world (row vectors), inverted
    cam = np.einsum("ni,nij->nj", world, to_cam)[:, :3]
    uv, depth = pv_project(cam, rec.pv.intrinsics)
    rows, cols = (int(v) for v in rec.pv.shape)
    behind = ~(depth > 0)
    outside = ~behind & ~((uv[:, 0] >= -0.25 * cols) & (uv[:, 0] <= 1.25 * cols)
                          & (uv[:, 1] >= -0.25 * rows) & (uv[:, 1] <= 1.25 * rows))
    bad = int(behind.sum() + outside.sum())
    if bad > MAX_OUT_OF_VIEW * n:
        ext = rec.calibration_dir / "rm_depth_ahat" / "extrinsics.bin"
        raise InputError(ext, f"{bad} of {n} lifted points fall behind the PV camera ({int(behind.sum())}) or "
                              f"outside its view ({int(outside.sum())}), though every box was seen in it: the AHAT "
                              "extrinsics likely use another axis convention (expected rig node -> AHAT camera, "
                              "row vectors, the camera looking down +z, as hl2ss writes them)")


def lift(rec: Recording, spec: str | Path, cfg, out: str | Path | None = None, *, overwrite: bool = False,
         progress: bool = True):
    """Detections ``spec`` of ``rec`` lifted with ``cfg.lift`` -> ``(Observations, LiftReport | None)``.

    With ``out``, the observations are saved there with their provenance; when ``out`` already holds
    observations of the same provenance and ``overwrite`` is False they are read back (report None).
    Input with nothing to lift (no detection file for any PV frame, rig extrinsics that are not
    rigid, no detection lifted) raises :class:`~egograph.core.errors.InputError` before anything
    is written; skipped files and frames are in the report.
    """
    from egograph.geometry.lift import lift_recording

    prov = provenance(rec, spec, cfg)
    if out is not None and not overwrite and Path(out).is_file() and Observations.read_provenance(out) == prov:
        return Observations.load(out), None
    dets = load_detections(rec, spec, cfg)
    n = n_instances(rec)
    warn_unknown_instances(rec, dets, n)
    obs, report = lift_recording(rec, dets, cfg.lift, progress=progress, n_instances=n)
    check_in_pv_view(rec, obs)
    obs.provenance = prov
    if out is not None:
        obs.save(out)
    return obs, report
