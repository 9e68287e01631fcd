"""Step ``lift``: 2D detections + AHAT depth + poses -> 3D observations (``.npz``)."""

from __future__ import annotations

from pathlib import Path

from egograph.core.config import to_dict
from egograph.geometry.observations import Observations
from egograph.io.detections import read_detection_dir
from egograph.io.recording import Recording
from egograph.steps import outputs
from egograph.steps.recording import n_instances


def load_detections(rec: Recording, spec: str | Path, cfg) -> dict:
    """Per-frame detections from a folder or a set name the recording carries (``svoe``, ``mvpe``)."""
    return read_detection_dir(rec.detections_dir(str(spec)), rec.timestamps, box_format=cfg.io.box_format)


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
    obs, report = lift_recording(rec, dets, cfg.lift, progress=progress, n_instances=n_instances(rec))
    obs.provenance = prov
    if out is not None:
        obs.save(out)
    return obs, report
