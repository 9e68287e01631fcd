"""Opening a recording with the pipeline configuration, and what the steps read from it."""

from __future__ import annotations

from pathlib import Path

from egograph.core.errors import InputError
from egograph.io.recording import Recording


def open_recording(path: str | Path, cfg, *, calibration: str | Path | None = None,
                   annotations: str | Path | None = None, sequence: str | None = None,
                   poses: str | Path | None = None) -> Recording:
    """The recording at ``path`` read with ``cfg.io``; ``poses``: a folder written by
    ``egograph refine`` whose poses replace the recording's."""
    rec = Recording.open(path, sequence=sequence, calibration=calibration, annotations=annotations,
                         invalid_poses=cfg.io.invalid_poses, depth_factor=cfg.io.depth_factor or None)
    if poses is not None:
        from egograph.poses.refine import apply_poses

        rec = apply_poses(rec, poses)
    return rec


def labels(rec: Recording) -> list[str] | None:
    """Instance names (index = id) from the recording's ``labels.csv``; None without annotations."""
    from egograph.io.annotations import read_labels

    if rec.annotation_dir is None:
        return None
    return read_labels(rec.annotation_dir / "labels.csv")


def n_instances(rec: Recording) -> int | None:
    names = labels(rec)
    return None if names is None else len(names)


def require_annotations(rec: Recording, what: str) -> Path:
    if rec.annotation_dir is None:
        raise InputError(rec.seq_dir, f"no annotations found ({what}); pass --annotations DIR")
    return rec.annotation_dir
