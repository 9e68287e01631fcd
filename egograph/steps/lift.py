"""Step ``lift``: 2D detections + AHAT depth + poses -> 3D observations (``.npz``)."""

from __future__ import annotations

from pathlib import Path

from egograph.core.config import to_dict
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
    dets = read_detection_dir(rec.detections_dir(str(spec)), rec.timestamps, box_format=cfg.io.box_format)
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
    obs.provenance = prov
    if out is not None:
        obs.save(out)
    return obs, report
