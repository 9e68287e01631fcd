"""Step ``evaluate``: a tracker's results against the recording's annotations, under the IT3DEgo
protocol (:mod:`egograph.eval.protocol`), with the interval-level scores.

Results are a :class:`~egograph.core.types.TrackResult` in memory or a results folder on disk.
When the results carry the tracker's own position intervals (the graph trackers'), those are
scored as they are; otherwise intervals are derived from the per-frame predictions (runs of
frames at one position, 1 cm tolerance), as for any tracker in the reference format.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from egograph.core.types import TrackResult
from egograph.eval.intervals import PredictedInterval
from egograph.eval.loader import FramePredictions, evaluate_loaded, load_sequence
from egograph.eval.report import EvalReport
from egograph.io.recording import Recording
from egograph.steps.recording import require_annotations


def frame_predictions(per_frame: dict, timestamps) -> FramePredictions:
    """``ts -> instance -> xyz`` for every PV frame from in-memory predictions (last one wins, as
    when the same lines are read from a file)."""
    out = FramePredictions()
    for ts in sorted(int(t) for t in timestamps):
        frame = {}
        for p in per_frame.get(ts, ()):
            frame[p.instance] = np.asarray(p.xyz, dtype=np.float64)
        out[ts] = frame
    return out


def predicted_intervals(intervals) -> list[PredictedInterval]:
    return [PredictedInterval(iv.instance, int(iv.t_start), int(iv.t_end), tuple(float(v) for v in iv.xyz))
            for iv in intervals]


def evaluate(rec: Recording, results: str | Path | TrackResult, name: str | None = None) -> EvalReport:
    """IT3DEgo metrics of one tracker's results on ``rec`` -> :class:`EvalReport` (one sequence)."""
    ann = require_annotations(rec, "labels.csv, 3d_center_annot.txt")
    if isinstance(results, TrackResult):
        result = results
        seq = load_sequence(rec.seq_dir / "pv_pose.json", ann / "3d_center_annot.txt", None, ann / "labels.csv")
        seq.predictions = frame_predictions(result.per_frame, seq.timestamps)
    else:
        from egograph.steps.track import read_result

        seq = load_sequence(rec.seq_dir / "pv_pose.json", ann / "3d_center_annot.txt", results, ann / "labels.csv")
        result = read_result(results, rec)
    if result.intervals is not None:
        seq.intervals = predicted_intervals(result.intervals)
    counts, intervals = evaluate_loaded(seq)
    report = EvalReport()
    report.add(name or rec.name, counts, intervals, seq.labels, seq.predictions.frames_without_file)
    return report
