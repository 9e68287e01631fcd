"""Opening a recording with the pipeline configuration, and what the steps read from it."""

from __future__ import annotations

from pathlib import Path

from egograph.core.errors import InputError
from egograph.io.recording import Recording


def open_recording(path: str | Path, cfg, *, calibration: str | Path | None = None,
                   annotations: str | Path | None = None, sequence: str | None = None,
                   poses: str | Path | None = None) -> Recording:
    """The recording at ``path`` read with ``cfg.io`` (pose policy, depth sync tolerance, strictness,
    enrollment folders); ``poses``: a folder written by ``egograph refine`` whose poses replace the
    recording's."""
    io = cfg.io
    rec = Recording.open(path, sequence=sequence, calibration=calibration, annotations=annotations,
                         invalid_poses=io.invalid_poses, depth_factor=io.depth_factor or None, strict=io.strict,
                         depth_sync_ms=io.depth_sync_ms, svoe_dir=io.svoe_dir or None, mvpe_dir=io.mvpe_dir or None)
    if not io.depth_factor:  # the unit read from the values: checked on the mesh when they say 1 mm
        from egograph.geometry.depth_unit import settle_depth_unit

        settle_depth_unit(rec, stated=False)
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
