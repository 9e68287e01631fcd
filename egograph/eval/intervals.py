"""Interval-level scores: are the true stationary intervals recovered, and when do moves happen?

A true GT interval is *recovered* when some predicted interval of the same
instance has its centre within :data:`RECOVER_RADIUS` (0.25 m) of the true
centre and a temporal IoU of at least :data:`RECOVER_TIOU` (0.5). The temporal
IoU is taken over PV frame index sets: an interval ``[t_start, t_end]`` (100 ns
ticks, inclusive) stands for the frames whose timestamps it covers.

A *true motion break* is the end of a GT interval that is followed by another
GT interval of the same instance; its *break-time error* is the distance in
seconds (ticks / 1e7) to the nearest predicted break of that instance (the end
of a predicted interval followed by another predicted interval of that
instance). Breaks of an instance without any predicted break have no error;
they are counted in ``n_breaks`` but not in ``break_errors_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np

from egograph.core.units import TICKS_PER_SECOND
from egograph.eval.protocol import GtInterval

RECOVER_RADIUS = 0.25  # metres
RECOVER_TIOU = 0.5  # temporal IoU over frame index sets


@dataclass(frozen=True)
class PredictedInterval(GtInterval):
    """A tracker's claim: ``instance`` stood at ``xyz`` (world, metres) over ``[t_start, t_end]`` (ticks, inclusive).

    The same record as a ground-truth interval (same validation), named for its role.
    """


@dataclass
class IntervalScore:
    """Additive interval-level tallies; ``break_errors_s`` in seconds.

    ``n_true`` counts GT intervals that cover at least one PV frame (the others
    cannot be matched in time and are left out, counted in ``n_empty``).
    """

    n_true: int = 0
    n_recovered: int = 0
    n_empty: int = 0
    n_breaks: int = 0
    break_errors_s: list[float] = field(default_factory=list)

    def __add__(self, other: IntervalScore) -> IntervalScore:
        if not isinstance(other, IntervalScore):
            return NotImplemented
        return IntervalScore(
            n_true=self.n_true + other.n_true,
            n_recovered=self.n_recovered + other.n_recovered,
            n_empty=self.n_empty + other.n_empty,
            n_breaks=self.n_breaks + other.n_breaks,
            break_errors_s=self.break_errors_s + other.break_errors_s,
        )

    def __radd__(self, other) -> IntervalScore:
        if isinstance(other, int) and other == 0:
            return self
        return self.__add__(other)

    @property
    def recovered_fraction(self) -> float:
        """n_recovered / n_true (0-1); 0.0 when ``n_true == 0``."""
        return self.n_recovered / self.n_true if self.n_true else 0.0

    @property
    def median_break_error_s(self) -> float | None:
        """Median break-time error (seconds) over breaks with a predicted break; None if there are none."""
        return float(np.median(self.break_errors_s)) if self.break_errors_s else None

    def to_dict(self) -> dict:
        return {
            "n_true": self.n_true,
            "n_recovered": self.n_recovered,
            "recovered_fraction": self.recovered_fraction,
            "n_empty": self.n_empty,
            "n_breaks": self.n_breaks,
            "n_breaks_with_prediction": len(self.break_errors_s),
            "median_break_error_s": self.median_break_error_s,
            "break_errors_s": [float(e) for e in self.break_errors_s],
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> IntervalScore:
        return cls(
            n_true=int(d["n_true"]),
            n_recovered=int(d["n_recovered"]),
            n_empty=int(d.get("n_empty", 0)),
            n_breaks=int(d["n_breaks"]),
            break_errors_s=[float(e) for e in d["break_errors_s"]],
        )


def _as_predicted(iv) -> PredictedInterval:
    if isinstance(iv, PredictedInterval):
        return iv
    instance, t_start, t_end, xyz = iv
    return PredictedInterval(instance, t_start, t_end, xyz)


def _frame_range(ts: np.ndarray, t_start: int, t_end: int) -> tuple[int, int]:
    """Half-open index range ``[lo, hi)`` of the sorted frames ``ts`` inside ``[t_start, t_end]``."""
    return int(np.searchsorted(ts, t_start, "left")), int(np.searchsorted(ts, t_end, "right"))


def _frame_ranges(ts: np.ndarray, intervals: Sequence) -> np.ndarray:
    """(M, 2) half-open frame index ranges of many intervals (vectorised :func:`_frame_range`)."""
    starts = np.array([iv.t_start for iv in intervals], dtype=np.int64)
    ends = np.array([iv.t_end for iv in intervals], dtype=np.int64)
    return np.stack([np.searchsorted(ts, starts, "left"), np.searchsorted(ts, ends, "right")], axis=1)


def _break_times(intervals: Sequence) -> list[int]:
    """Ends (ticks) of intervals followed by a later interval, for one instance's intervals."""
    rows = sorted(intervals, key=lambda iv: (iv.t_start, iv.t_end))
    return [iv.t_end for iv in rows[:-1]]


def score_intervals(
    gt: Iterable[GtInterval],
    predicted_intervals: Iterable,
    timestamps: Sequence[int] | np.ndarray,
    radius: float = RECOVER_RADIUS,
    min_tiou: float = RECOVER_TIOU,
) -> IntervalScore:
    """Interval-level tallies for one sequence (see module doc).

    ``predicted_intervals`` holds :class:`PredictedInterval` or
    ``(instance, t_start, t_end, xyz)`` tuples; ``timestamps`` are the PV
    frames (ticks); ``radius`` in metres.
    """
    ts = np.sort(np.asarray([int(t) for t in timestamps], dtype=np.int64))
    gt = list(gt)
    preds = [_as_predicted(iv) for iv in predicted_intervals]
    by_inst: dict[int, list[PredictedInterval]] = {}
    for iv in preds:
        by_inst.setdefault(iv.instance, []).append(iv)
    gt_by_inst: dict[int, list[GtInterval]] = {}
    for g in gt:
        gt_by_inst.setdefault(g.instance, []).append(g)

    spans = {inst: (_frame_ranges(ts, rows), np.array([p.xyz for p in rows], dtype=np.float64))
             for inst, rows in by_inst.items()}
    score = IntervalScore()
    for g in gt:
        lo, hi = _frame_range(ts, g.t_start, g.t_end)
        if hi <= lo:
            score.n_empty += 1
            continue
        score.n_true += 1
        if g.instance not in spans:
            continue
        rng, centres = spans[g.instance]
        inter = np.clip(np.minimum(rng[:, 1], hi) - np.maximum(rng[:, 0], lo), 0, None)
        union = (rng[:, 1] - rng[:, 0]) + (hi - lo) - inter
        tiou = inter / union  # union >= hi - lo > 0
        near = np.linalg.norm(centres - np.asarray(g.xyz), axis=1) <= radius
        if (near & (tiou >= min_tiou)).any():
            score.n_recovered += 1

    for inst, rows in gt_by_inst.items():
        true_breaks = _break_times(rows)
        score.n_breaks += len(true_breaks)
        pred_breaks = np.asarray(_break_times(by_inst.get(inst, [])), dtype=np.int64)
        if not len(pred_breaks):
            continue
        for tb in true_breaks:
            nearest = int(np.abs(pred_breaks - tb).min())  # exact int ticks
            score.break_errors_s.append(nearest / TICKS_PER_SECOND)
    return score


def interval_scores(
    gt: Iterable[GtInterval],
    predicted_intervals: Iterable,
    timestamps: Sequence[int] | np.ndarray,
    radius: float = RECOVER_RADIUS,
    min_tiou: float = RECOVER_TIOU,
) -> dict:
    """Interval-level score of one sequence as a dict: ``recovered_fraction`` (0-1),
    ``median_break_error_s`` (seconds, None without any predicted break) and the
    tallies behind them (see :class:`IntervalScore`)."""
    return score_intervals(gt, predicted_intervals, timestamps, radius, min_tiou).to_dict()


def intervals_from_predictions(
    timestamps: Sequence[int] | np.ndarray,
    predictions: Mapping[int, Mapping[int, Sequence[float]]],
    tol: float = 0.01,
) -> list[PredictedInterval]:
    """Derive predicted intervals from per-frame results ``ts -> instance -> xyz``.

    Per instance, walking the PV frames in time order, a run of consecutive
    frames joins one interval while the instance is predicted in every frame and
    each position is within ``tol`` metres of the run's first position. A frame
    without a prediction, or a jump beyond ``tol``, closes the run. The
    interval's ``xyz`` is the mean position of its frames; its ends are the
    first and last frame timestamps (ticks). Sorted by (instance, t_start).
    """
    ts = sorted(int(t) for t in timestamps)
    instances = sorted({int(i) for frame in predictions.values() for i in frame})
    out: list[PredictedInterval] = []
    for inst in instances:
        runs: list[list[tuple[int, tuple[float, float, float]]]] = []
        run: list[tuple[int, tuple[float, float, float]]] = []
        for t in ts:
            frame = predictions.get(t)
            xyz = None if frame is None else frame.get(inst)
            if xyz is None:
                if run:
                    runs.append(run)
                    run = []
                continue
            p = tuple(float(v) for v in xyz)
            if run and math.dist(p, run[0][1]) > tol:
                runs.append(run)
                run = []
            run.append((t, p))
        if run:
            runs.append(run)
        for r in runs:
            centre = tuple(math.fsum(p[j] for _, p in r) / len(r) for j in range(3))
            out.append(PredictedInterval(inst, r[0][0], r[-1][0], centre))
    return out
