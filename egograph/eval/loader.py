"""Thin loaders from the IT3DEgo files to the in-memory inputs of :mod:`egograph.eval.protocol`.

* ``3d_center_annot.txt`` -> :class:`GtInterval` list;
* ``results/<seq>/<model>/<ts>.txt`` (``instance x y z score``, world, metres)
  -> ``ts -> instance -> xyz``; when a file has several lines for one instance
  the last one wins (as the reference's dict assignment does); a frame without
  a file has no predictions and is counted in ``missing``;
* ``pv_pose.json`` -> timestamps (ticks, numeric order) and PV camera centres
  (NaN rows where the pose is invalid).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from egograph.core.errors import InputError
from egograph.eval.intervals import IntervalScore, PredictedInterval, intervals_from_predictions, score_intervals
from egograph.eval.protocol import THRESHOLDS, GtInterval, SequenceResult, evaluate_sequence
from egograph.geometry.hl2ss import camera_center
from egograph.io.annotations import LABELS_FILE, read_centers, read_labels
from egograph.io.detections import read_results_dir
from egograph.io.poses import read_pose_json
from egograph.io.textio import listed_files


class FramePredictions(dict):
    """``ts -> {instance: xyz (3,) float64}`` for every requested PV frame, plus
    ``missing``: the timestamps (ticks) that had no results file."""

    def __init__(self, *args, missing: Sequence[int] = (), **kwargs):
        super().__init__(*args, **kwargs)
        self.missing: list[int] = list(missing)

    @property
    def frames_without_file(self) -> int:
        return len(self.missing)


def load_gt_intervals(path: str | Path) -> list[GtInterval]:
    """GT intervals from ``3d_center_annot.txt`` (ticks inclusive, world metres), sorted by (instance, t_start)."""
    return [GtInterval(c.instance, c.t_start, c.t_end, c.xyz) for c in read_centers(path)]


def load_predictions(results_dir: str | Path, timestamps: Iterable[int]) -> FramePredictions:
    """Per-frame predictions ``ts -> instance -> xyz`` of one tracker on one sequence.

    Every timestamp is a key. A frame whose ``<ts>.txt`` is missing has no
    predictions; those timestamps are listed in the result's ``missing``.
    Malformed files raise :class:`InputError` naming file and line.
    """
    results_dir = Path(results_dir)
    stamps = sorted({int(t) for t in timestamps})
    names = {p.name for p in listed_files(results_dir, "results")}
    missing = [t for t in stamps if f"{t}.txt" not in names]
    rows = read_results_dir(results_dir, stamps)
    out = FramePredictions(missing=missing)
    for ts in stamps:
        frame: dict[int, np.ndarray] = {}
        for p in rows.get(ts, ()):
            frame[p.instance] = np.asarray(p.xyz, dtype=np.float64)  # last line wins
        out[ts] = frame
    return out


def load_camera_centers(pv_pose_path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps int64 (N,) in numeric order, PV camera centres (N, 3) metres, NaN where the pose is invalid).

    Every key of ``pv_pose.json`` is a frame, valid pose or not (the reference counts them all).
    """
    ts, poses, valid = read_pose_json(pv_pose_path, invalid="skip")
    centers = camera_center(poses)
    centers[~valid] = np.nan
    return ts, centers


def load_labels(annotation_dir: str | Path) -> list[str] | None:
    """Instance names from ``labels.csv`` (index = id), or None if the file is absent."""
    path = Path(annotation_dir) / LABELS_FILE
    return read_labels(path) if path.is_file() else None


@dataclass
class LoadedSequence:
    """Everything needed to evaluate one tracker on one sequence."""

    timestamps: np.ndarray
    camera_centers: np.ndarray
    gt: list[GtInterval]
    predictions: FramePredictions
    labels: list[str] | None = None
    intervals: list[PredictedInterval] | None = field(default=None)


def load_sequence(
    pv_pose_path: str | Path,
    center_annot_path: str | Path,
    results_dir: str | Path | None,
    labels_path: str | Path | None = None,
) -> LoadedSequence:
    """Read the pose file, the GT centres and one tracker's per-frame results of a sequence
    (``results_dir`` None: no predictions yet, for results held in memory)."""
    ts, centers = load_camera_centers(pv_pose_path)
    gt = load_gt_intervals(center_annot_path)
    preds = load_predictions(results_dir, ts) if results_dir is not None else FramePredictions()
    labels = None
    if labels_path is not None:
        if not Path(labels_path).is_file():
            raise InputError(labels_path, "labels file not found")
        labels = read_labels(labels_path)
    return LoadedSequence(ts, centers, gt, preds, labels)


def evaluate_loaded(
    seq: LoadedSequence, thresholds: Sequence[float] = THRESHOLDS, tol: float = 0.01
) -> tuple[SequenceResult, IntervalScore]:
    """Counts and interval score of a loaded sequence. Predicted intervals are
    ``seq.intervals`` when given, else derived from the per-frame results (``tol`` metres)."""
    result = evaluate_sequence(seq.timestamps, seq.gt, seq.predictions, seq.camera_centers, thresholds)
    intervals = seq.intervals
    if intervals is None:
        intervals = intervals_from_predictions(seq.timestamps, seq.predictions, tol)
    return result, score_intervals(seq.gt, intervals, seq.timestamps)
