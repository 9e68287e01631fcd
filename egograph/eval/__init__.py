"""IT3DEgo evaluation: the reference per-frame counting, interval scores, reports."""

from egograph.eval.intervals import (
    IntervalScore,
    PredictedInterval,
    interval_scores,
    intervals_from_predictions,
    score_intervals,
)
from egograph.eval.loader import load_gt_intervals, load_predictions, load_sequence
from egograph.eval.protocol import THRESHOLDS, Counts, GtInterval, SequenceResult, evaluate_sequence
from egograph.eval.report import EvalReport, comparison_table, plot_pr

__all__ = [
    "THRESHOLDS",
    "Counts",
    "EvalReport",
    "GtInterval",
    "IntervalScore",
    "PredictedInterval",
    "SequenceResult",
    "comparison_table",
    "evaluate_sequence",
    "interval_scores",
    "load_gt_intervals",
    "load_predictions",
    "load_sequence",
    "intervals_from_predictions",
    "plot_pr",
    "score_intervals",
]
