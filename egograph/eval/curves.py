"""Precision-recall curves over confidence, average precision and calibration, on top of the IT3DEgo
counting (:mod:`egograph.eval.protocol`).

A tracker that answers every frame with a confidence (the fifth column of the per-frame files) is
scored as detection benchmarks score detectors: its answers are sorted by confidence, and as the
confidence threshold sweeps down, precision = TP / answers kept and recall = TP / GT pairs, with
TP, answers and GT pairs counted exactly as the reference evaluator counts them (an answer is a TP
at threshold tau for each GT interval of its instance that covers its frame with the answer within
tau metres; every answer counts once in the denominator of precision). At the lowest threshold the
curve ends at the reference evaluator's P and R of all the answers.

Answers of equal confidence enter together (one point per distinct confidence: ties are never
split). Average precision is the *all-point interpolated* area under the curve (PASCAL VOC 2010 on,
and COCO's without its 101-point sampling): the precision at recall r is the largest precision at
any recall >= r, integrated over the recall steps; recall never reached adds nothing. A curve
"passes" a point (P, R) when it has a point of recall >= R with precision >= P.

Calibration: the answers binned by confidence (``RELIABILITY_BINS`` equal bins over [0, 1]), per bin
the share of answers within tau of the truth (a TP at tau); the expected calibration error is the
answer-weighted mean of |share - mean confidence| over the bins.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np

from egograph.eval.protocol import THRESHOLDS, GtInterval, _distances

RELIABILITY_BINS = 10
"""Equal-width confidence bins of the reliability table and the expected calibration error."""

CALIBRATION_TAU = 0.25
"""Distance (metres) the graph trackers' confidence speaks of by default (``graph.answers.distance_m``)."""

_EPS = 1e-12


@dataclass
class ScoredAnswers:
    """Every answer of a tracker with its confidence and what the IT3DEgo counting makes of it.

    ``score`` (N,): the confidence of each (frame, instance) answer; ``tp`` (N, K) int: per threshold
    of ``thresholds`` (metres), how many GT intervals covering its frame it is within tau of (0, 1, or
    2 where two intervals of its instance overlap, as the reference counts); ``n_gt``: the (frame, GT
    interval) pairs of the sequences scored."""

    thresholds: tuple[float, ...] = THRESHOLDS
    score: np.ndarray = field(default_factory=lambda: np.zeros(0))
    tp: np.ndarray = None  # type: ignore[assignment]
    n_gt: int = 0

    def __post_init__(self) -> None:
        self.thresholds = tuple(float(t) for t in self.thresholds)
        self.score = np.asarray(self.score, dtype=np.float64).reshape(-1)
        k = len(self.thresholds)
        tp = np.zeros((len(self.score), k), np.int64) if self.tp is None else np.asarray(self.tp, np.int64)
        if tp.shape != (len(self.score), k):
            raise ValueError(f"tp must have shape ({len(self.score)}, {k}), got {tp.shape}")
        self.tp = tp

    def __add__(self, other: ScoredAnswers) -> ScoredAnswers:
        if other.thresholds != self.thresholds:
            raise ValueError(f"cannot pool answers scored at {self.thresholds} and {other.thresholds}")
        return ScoredAnswers(self.thresholds, np.concatenate([self.score, other.score]),
                             np.concatenate([self.tp, other.tp]), self.n_gt + other.n_gt)

    def __radd__(self, other):
        if isinstance(other, int) and other == 0:
            return self
        return self.__add__(other)

    def above(self, min_confidence: float) -> ScoredAnswers:
        """The answers of confidence >= ``min_confidence`` (an operating point)."""
        keep = self.score >= min_confidence
        return ScoredAnswers(self.thresholds, self.score[keep], self.tp[keep], self.n_gt)

    def tau_index(self, tau: float) -> int:
        for k, t in enumerate(self.thresholds):
            if abs(t - tau) <= 1e-9:
                return k
        raise ValueError(f"threshold {tau} not among {self.thresholds}")


def score_answers(timestamps: Sequence[int] | np.ndarray, gt: Iterable[GtInterval],
                  answers: Mapping[int, Mapping[int, tuple[Sequence[float], float]]],
                  thresholds: Sequence[float] = THRESHOLDS) -> ScoredAnswers:
    """Count each answer as the reference evaluator would. ``answers``: ``ts -> instance -> (xyz,
    confidence)`` (world frame, metres; keys that are not PV frames are ignored, as the reference
    never opens them)."""
    thresholds = tuple(float(t) for t in thresholds)
    ts = np.asarray([int(t) for t in timestamps], dtype=np.int64)
    index = {int(t): i for i, t in enumerate(ts)}
    rows = [(index[int(t)], int(inst), np.asarray(xyz, np.float64).reshape(3), float(s))
            for t, frame in answers.items() if int(t) in index for inst, (xyz, s) in frame.items()]
    n = len(rows)
    frame = np.array([r[0] for r in rows], np.int64)
    inst = np.array([r[1] for r in rows], np.int64)
    xyz = np.array([r[2] for r in rows], np.float64).reshape(n, 3)
    score = np.array([r[3] for r in rows], np.float64)
    tp = np.zeros((n, len(thresholds)), np.int64)
    n_gt = 0
    thr = np.asarray(thresholds)
    for g in gt:
        covered = (ts >= g.t_start) & (ts <= g.t_end)
        n_gt += int(covered.sum())
        hit = np.flatnonzero((inst == g.instance) & covered[frame] if n else np.zeros(0, bool))
        if len(hit):
            d = _distances(np.asarray(g.xyz, np.float64), xyz[hit], thresholds)
            tp[hit] += (d[:, None] <= thr[None, :]).astype(np.int64)
    return ScoredAnswers(thresholds, score, tp, n_gt)


@dataclass
class PRCurve:
    """Precision and recall (fractions) as the confidence threshold sweeps down, one point per
    distinct confidence (``confidence``: the threshold of each point, decreasing); ``ap``: the
    all-point interpolated average precision (module doc); ``n_gt``, ``n_answers``."""

    tau: float
    confidence: np.ndarray
    precision: np.ndarray
    recall: np.ndarray
    ap: float
    n_gt: int
    n_answers: int

    def passes(self, precision: float, recall: float) -> bool:
        """Whether the curve has a point at recall >= ``recall`` with precision >= ``precision``
        (a point of recall 0 is passed by any curve)."""
        if recall <= _EPS:
            return True
        ok = self.recall >= recall - _EPS
        return bool(ok.any() and self.precision[ok].max() >= precision - _EPS)

    def at(self, min_confidence: float) -> tuple[float, float]:
        """(precision, recall) of the answers of confidence >= ``min_confidence`` ((0, 0) for none)."""
        ok = np.flatnonzero(self.confidence >= min_confidence)
        if not len(ok):
            return 0.0, 0.0
        return float(self.precision[ok[-1]]), float(self.recall[ok[-1]])

    def to_json_dict(self, digits: int = 4) -> dict:
        return {"tau": self.tau, "ap": round(self.ap, 6), "n_gt": self.n_gt, "n_answers": self.n_answers,
                "confidence": np.round(self.confidence, digits).tolist(),
                "precision": np.round(self.precision, digits).tolist(),
                "recall": np.round(self.recall, digits).tolist()}


def average_precision(precision: np.ndarray, recall: np.ndarray) -> float:
    """All-point interpolated AP of a curve whose points are in order of decreasing threshold
    (recall non-decreasing): sum over points of (r_i - r_{i-1}) * max_{j >= i} p_j, r_0 = 0."""
    p = np.asarray(precision, np.float64)
    r = np.asarray(recall, np.float64)
    if not len(p):
        return 0.0
    envelope = np.maximum.accumulate(p[::-1])[::-1]
    steps = np.diff(np.concatenate([[0.0], r]))
    return float(np.sum(steps * envelope))


def pr_curve(answers: ScoredAnswers, tau: float) -> PRCurve:
    """The precision-recall curve of ``answers`` at threshold ``tau`` (metres; one of theirs)."""
    k = answers.tau_index(tau)
    order = np.argsort(-answers.score, kind="stable")
    s = answers.score[order]
    tp = np.cumsum(answers.tp[order, k])
    n = np.arange(1, len(s) + 1)
    last = np.flatnonzero(np.append(s[1:] != s[:-1], True)) if len(s) else np.zeros(0, np.int64)  # end of each tie
    tp, n, conf = tp[last], n[last], s[last]
    precision = tp / np.maximum(n, 1)
    recall = tp / answers.n_gt if answers.n_gt else np.zeros(len(tp))
    return PRCurve(float(tau), conf, precision.astype(np.float64), recall.astype(np.float64),
                   average_precision(precision, recall), int(answers.n_gt), int(len(s)))


def pr_curves(answers: ScoredAnswers) -> dict[float, PRCurve]:
    """:func:`pr_curve` at every threshold of ``answers``."""
    return {t: pr_curve(answers, t) for t in answers.thresholds}


@dataclass
class Reliability:
    """The reliability table at ``tau``: per confidence bin (edges ``edges``), how many answers
    (``count``), their mean confidence (``confidence``) and the share within tau (``share``; NaN for
    an empty bin); ``ece``: the expected calibration error."""

    tau: float
    edges: np.ndarray
    count: np.ndarray
    confidence: np.ndarray
    share: np.ndarray
    ece: float

    def to_json_dict(self) -> dict:
        def clean(a):
            return [None if not np.isfinite(v) else round(float(v), 4) for v in a]

        return {"tau": self.tau, "edges": np.round(self.edges, 4).tolist(), "count": self.count.tolist(),
                "confidence": clean(self.confidence), "share": clean(self.share), "ece": round(self.ece, 6)}


def reliability(answers: ScoredAnswers, tau: float = CALIBRATION_TAU, bins: int = RELIABILITY_BINS) -> Reliability:
    """Answers binned by confidence (``bins`` equal bins over [0, 1]; 1.0 in the last): per bin the
    share of answers within ``tau`` (a TP at tau), and the expected calibration error (0 for no
    answers)."""
    k = answers.tau_index(tau)
    edges = np.linspace(0.0, 1.0, bins + 1)
    which = np.clip(np.floor(answers.score * bins).astype(np.int64), 0, bins - 1)  # 0.3 in [0.3, 0.4)
    correct = (answers.tp[:, k] > 0).astype(np.float64)
    count = np.bincount(which, minlength=bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        conf = np.bincount(which, answers.score, minlength=bins) / count
        share = np.bincount(which, correct, minlength=bins) / count
    n = count.sum()
    ece = float(np.nansum(count * np.abs(share - conf)) / n) if n else 0.0
    return Reliability(float(tau), edges, count, conf, share, ece)
