"""Thin loaders from the IT3DEgo files to the in-memory inputs of :mod:`egograph.eval.protocol`.

* ``3d_center_annot.txt`` -> :class:`GtInterval` list, read as strictly as ``egograph info``
  reads it (:func:`~egograph.io.annotations.read_centers`: ids below the number of labels,
  no two rows of one instance for the same interval);
* ``results/<seq>/<model>/<ts>.txt`` (``instance x y z score``, world, metres)
  -> ``ts -> instance -> xyz``; when a file has several lines for one instance
  the last one wins (as the reference's dict assignment does); a frame without
  a file has no predictions and is counted in ``missing``; lines for an instance id
  beyond the labels are ignored; each of those, the overridden lines and the files that
  name no PV frame are listed in ``ignored`` (:class:`IgnoredInput`);
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
from egograph.io.detections import read_results_lines, scan_frame_dir
from egograph.io.poses import read_pose_json

IGNORED_REASONS = {
    "unknown_instance": "result line for an instance id beyond labels.csv",
    "repeated_instance": "a second result line for an instance in one frame (the last one is used)",
    "not_pv_frame": "result file for a timestamp that is not a PV frame",
    "misnamed": "file not named <ts>.txt",
}


@dataclass(frozen=True)
class IgnoredInput:
    """A result line (or a whole file, ``line`` None) the evaluation did not use, and why
    (an :data:`IGNORED_REASONS` key)."""

    reason: str
    path: Path
    line: int | None
    message: str

    def error(self) -> InputError:
        return InputError(self.path, self.message, self.line)


class FramePredictions(dict):
    """``ts -> {instance: xyz (3,) float64}`` for every requested PV frame, plus
    ``missing``: the timestamps (ticks) that had no results file, and ``ignored``: the
    lines and files not used (:class:`IgnoredInput`)."""

    def __init__(self, *args, missing: Sequence[int] = (), ignored: Sequence[IgnoredInput] = (), **kwargs):
        super().__init__(*args, **kwargs)
        self.missing: list[int] = list(missing)
        self.ignored: list[IgnoredInput] = list(ignored)

    @property
    def frames_without_file(self) -> int:
        return len(self.missing)

    def ignored_counts(self) -> dict[str, int]:
        """Reason -> number of ignored lines (files, for the file reasons)."""
        out: dict[str, int] = {}
        for item in self.ignored:
            out[item.reason] = out.get(item.reason, 0) + 1
        return out


def load_gt_intervals(path: str | Path, num_instances: int | None = None) -> list[GtInterval]:
    """GT intervals from ``3d_center_annot.txt`` (ticks inclusive, world metres), sorted by (instance, t_start).

    ``num_instances`` (the labels' count) bounds the ids, as :func:`~egograph.io.annotations.load_annotations` does.
    """
    return [GtInterval(c.instance, c.t_start, c.t_end, c.xyz) for c in read_centers(path, num_instances)]


def load_predictions(results_dir: str | Path, timestamps: Iterable[int],
                     num_instances: int | None = None) -> FramePredictions:
    """Per-frame predictions ``ts -> instance -> xyz`` of one tracker on one sequence.

    Every timestamp is a key. A frame whose ``<ts>.txt`` is missing has no
    predictions; those timestamps are listed in the result's ``missing``. With
    ``num_instances``, lines for larger ids are dropped; they, lines overridden by a later one
    for the same instance and files naming no PV frame are listed in ``ignored``.
    Malformed files raise :class:`InputError` naming file and line.
    """
    results_dir = Path(results_dir)
    stamps = sorted({int(t) for t in timestamps})
    scan = scan_frame_dir(results_dir, stamps)
    ignored = [IgnoredInput("not_pv_frame", f, None, "timestamp is not a PV frame of the recording")
               for f in scan.not_pv_frame]
    ignored += [IgnoredInput("misnamed", f, None, "file name must be <ts>.txt with ts a PV timestamp")
                for f in scan.misnamed]
    out = FramePredictions(missing=scan.missing)
    for ts in stamps:
        frame: dict[int, np.ndarray] = {}
        path = scan.matched.get(ts)
        line_of: dict[int, int] = {}
        for n, p in read_results_lines(path) if path is not None else ():
            if num_instances is not None and p.instance >= num_instances:
                ignored.append(IgnoredInput("unknown_instance", path, n, f"instance id {p.instance} out of range: "
                                                                         f"labels.csv has {num_instances} labels"))
                continue
            if p.instance in line_of:
                ignored.append(IgnoredInput("repeated_instance", path, n,
                                            f"instance {p.instance} also on line {line_of[p.instance]} (two results "
                                            f"for one instance in one frame; the later line is used)"))
            line_of[p.instance] = n
            frame[p.instance] = np.asarray(p.xyz, dtype=np.float64)  # last line wins
        out[ts] = frame
    out.ignored = ignored
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
    (``results_dir`` None: no predictions yet, for results held in memory). With ``labels_path``,
    ids in the GT beyond the labels are an InputError and result lines for them are ignored
    (listed in ``predictions.ignored``)."""
    ts, centers = load_camera_centers(pv_pose_path)
    labels = None
    if labels_path is not None:
        if not Path(labels_path).is_file():
            raise InputError(labels_path, "labels file not found")
        labels = read_labels(labels_path)
    n = None if labels is None else len(labels)
    gt = load_gt_intervals(center_annot_path, n)
    preds = load_predictions(results_dir, ts, n) if results_dir is not None else FramePredictions()
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
