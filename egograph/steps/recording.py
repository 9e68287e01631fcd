"""Opening a recording with the pipeline configuration, and what the steps read from it."""

from __future__ import annotations

from pathlib import Path

from egograph.core.errors import InputError
from egograph.io.recording import Recording


def _open_with_fit(path, cfg, calibration, annotations, sequence, score_calibration: bool) -> Recording:
    """:meth:`Recording.open` with the calibration folder chosen by :func:`choose_calibration`; the
    fit of the candidates is kept as ``rec.calibration_fit``."""
    import warnings

    from egograph.io.calibration import calibration_choice
    from egograph.io.recording import find_sequence_dir
    from egograph.steps.calibration import choose_calibration

    io = cfg.io

    def read(calib):
        return Recording.open(path, sequence=sequence, calibration=calib, annotations=annotations,
                              invalid_poses=io.invalid_poses, depth_factor=io.depth_factor or None, strict=io.strict,
                              depth_sync_ms=io.depth_sync_ms, svoe_dir=io.svoe_dir or None, mvpe_dir=io.mvpe_dir or None)

    first = calibration
    if calibration is None and cfg.calib_fit.select:
        choice = calibration_choice(find_sequence_dir(path, sequence))
        if choice.by_number is None and len(choice.candidates) > 1:
            first = choice.candidates[0]   # the fit decides among them below
    rec = read(first)
    used, fit = choose_calibration(rec, cfg, explicit=calibration is not None, strict=io.strict,
                                   always_score=score_calibration)
    if used != rec.calibration_dir:
        with warnings.catch_warnings():   # what the first reading said about the recording holds
            warnings.simplefilter("ignore")
            rec = read(used)
    for lk in rec.lookups:
        if lk.what == "calibration" and fit.scores:
            s = fit.scores.get(used)
            lk.note = (f"fit {s.score:.2f} px (spread {s.spread:.2f}) on {fit.frames} frames" if s is not None else "")
            lk.note += "; chosen by fit over the folder named by number" if fit.switched else ""
            lk.problem = s is not None and not s.fits(cfg.calib_fit)
    rec.calibration_fit = fit
    return rec


def open_recording(path: str | Path, cfg, *, calibration: str | Path | None = None,
                   annotations: str | Path | None = None, sequence: str | None = None,
                   poses: str | Path | None = None, score_calibration: bool = False) -> Recording:
    """The recording at ``path`` read with ``cfg.io`` (pose policy, depth sync tolerance, strictness,
    enrollment folders) and the calibration folder that fits it (:mod:`egograph.steps.calibration`;
    ``score_calibration``: score the candidates even when there is one); ``poses``: a folder written
    by ``egograph refine`` whose poses replace the recording's."""
    rec = _open_with_fit(path, cfg, calibration, annotations, sequence, score_calibration)
    io = cfg.io
    # the unit checked on the mesh: a stated one always, one read from the values when they say 1 mm
    from egograph.geometry.depth_unit import settle_depth_unit

    settle_depth_unit(rec, stated=bool(io.depth_factor), strict=io.strict)
    if poses is not None:
        from egograph.poses.refine import apply_poses

        rec = apply_poses(rec, poses)
    return rec


def labels_path(rec: Recording) -> Path | None:
    """The recording's labels file (``labels.csv`` or ``label.csv``); None without annotations."""
    from egograph.io.annotations import find_labels_file

    return None if rec.annotation_dir is None else find_labels_file(rec.annotation_dir)


def labels(rec: Recording) -> list[str] | None:
    """Instance names (index = id) from the recording's labels file; None without annotations."""
    from egograph.io.annotations import read_labels

    path = labels_path(rec)
    return None if path is None else read_labels(path)


def n_instances(rec: Recording) -> int | None:
    names = labels(rec)
    return None if names is None else len(names)


def require_svoe(rec: Recording) -> Path:
    """The recording's ``svoe.txt`` (:func:`egograph.io.recording.locate_svoe`); InputError listing
    the paths tried when there is none."""
    from egograph.io.recording import locate_svoe

    look = locate_svoe(rec.seq_dir, rec.annotation_dir, rec.svoe_dir or None)
    if look.found is None:
        raise InputError(rec.seq_dir, "no SVOE enrollment (svoe.txt) found; tried " + ", ".join(look.tried[:6])
                         + "; set io.svoe_dir")
    return Path(look.found)


def require_annotations(rec: Recording, what: str) -> Path:
    if rec.annotation_dir is None:
        tried = next((lk.tried for lk in rec.lookups if lk.what == "annotations"), [])
        raise InputError(rec.seq_dir, f"no annotations found ({what}); tried {', '.join(tried[:6]) or 'nothing'}; "
                                      f"pass --annotations DIR")
    return rec.annotation_dir
