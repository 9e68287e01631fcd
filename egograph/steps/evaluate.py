"""Step ``evaluate``: a tracker's results against the recording's annotations, under the IT3DEgo
protocol (:mod:`egograph.eval.protocol`), with the interval-level scores.

Results are a :class:`~egograph.core.types.TrackResult` in memory or a results folder on disk.
When the results carry the tracker's own position intervals (the graph trackers'), those are
scored as they are; otherwise intervals are derived from the per-frame predictions (runs of
frames at one position, 1 cm tolerance), as for any tracker in the reference format.

A results folder is read against the recording: frames without a result file count as frames
without predictions, lines for an instance id beyond ``labels.csv`` are ignored, of two lines for
one instance in one frame the later is used, files that name no PV frame are ignored. Each of
these is counted and warned about (one warning per kind, naming the first file and line); with
``strict`` the first of them is an :class:`~egograph.core.errors.InputError` instead.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from egograph.core.errors import InputError
from egograph.core.types import TrackResult
from egograph.eval.curves import ScoredAnswers, score_answers
from egograph.eval.intervals import PredictedInterval
from egograph.eval.loader import IGNORED_REASONS, FramePredictions, evaluate_loaded, load_sequence
from egograph.eval.report import EvalReport
from egograph.io.recording import Recording
from egograph.steps import outputs
from egograph.steps.recording import labels_path, require_annotations


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


def check_predictions(results_dir: str | Path, preds: FramePredictions, strict: bool = False) -> list[str]:
    """What of a results folder was not used (see the module doc), one line per kind; with
    ``strict``, InputError for the first frame without a file or the first ignored line/file."""
    results_dir = Path(results_dir)
    n_frames = len(preds)
    lines = []
    if preds.missing:
        msg = (f"{len(preds.missing)} of {n_frames} PV frames have no result file (e.g. {preds.missing[0]}.txt); "
               f"counted as frames without predictions")
        if strict:
            raise InputError(results_dir, msg)
        lines.append(f"{results_dir}: {msg}")
    counts = preds.ignored_counts()
    for reason in IGNORED_REASONS:
        items = [i for i in preds.ignored if i.reason == reason]
        if not items:
            continue
        if strict:
            raise items[0].error()
        what = "file" if reason in ("not_pv_frame", "misnamed") else "line"
        n = counts[reason]
        lines.append(f"{n} result {what}{'s' if n > 1 else ''} ignored ({IGNORED_REASONS[reason]}); "
                     f"first: {items[0].error()}")
    return lines


def evaluate(rec: Recording, results: str | Path | TrackResult, name: str | None = None, *,
             strict: bool = False) -> EvalReport:
    """IT3DEgo metrics of one tracker's results on ``rec`` -> :class:`EvalReport` (one sequence).

    A results folder's frames without a file and ignored lines are warned about, or with
    ``strict`` refused (InputError), before anything is scored.
    """
    ann = require_annotations(rec, "labels.csv, 3d_center_annot.txt")
    centers = ann / "3d_center_annot.txt"
    if not isinstance(results, TrackResult) and Path(results).is_dir():
        outputs.check_results_belong(rec, results)
    if isinstance(results, TrackResult):
        result = results
        seq = load_sequence(rec.seq_dir / "pv_pose.json", centers, None, labels_path(rec))
        seq.predictions = frame_predictions(result.per_frame, seq.timestamps)
    else:
        seq = load_sequence(rec.seq_dir / "pv_pose.json", centers, results, labels_path(rec))
    if not seq.gt:  # every score would be 0 of 0
        raise InputError(centers, "no annotated interval (t_start t_end instance_id x y z location_id): nothing "
                                  "to score against")
    if not isinstance(results, TrackResult):
        from egograph.steps.track import read_result

        for line in check_predictions(results, seq.predictions, strict):
            warnings.warn(line, stacklevel=2)
        result = read_result(results, rec)
    if result.intervals is not None:
        seq.intervals = predicted_intervals(result.intervals)
    counts, intervals = evaluate_loaded(seq)
    report = EvalReport()
    report.add(name or rec.name, counts, intervals, seq.labels, seq.predictions.frames_without_file,
               scored_answers(result.answers if result.answers is not None else result.per_frame, seq))
    return report


def scored_answers(answers: dict, seq) -> ScoredAnswers:
    """Every answer (``ts -> [Prediction]``; of one instance in one frame the later wins, as the
    reference reads a file) counted against ``seq``'s GT intervals (:mod:`egograph.eval.curves`).
    A tracker without an answers file is scored on its per-frame files, their fifth column its
    confidence."""
    frames = {}
    n = len(seq.labels) if seq.labels is not None else None
    for ts, preds in answers.items():
        frame = {}
        for p in preds:
            if n is None or p.instance < n:  # as the evaluator ignores lines for ids beyond labels.csv
                frame[p.instance] = (p.xyz, p.score)
        frames[int(ts)] = frame
    return score_answers(seq.timestamps, seq.gt, frames)
