"""Benchmark metrics (egograph.eval.metrics) on hand-made inputs with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from egograph.core.types import PositionInterval
from egograph.eval.metrics import nees_values, observable_intervals, ratio, target_checks
from egograph.eval.protocol import GtInterval
from egograph.geometry.observations import Observations


def interval(instance, t0, t1, xyz, sigmas=(0.1, 0.1, 0.1)):
    return PositionInterval(instance, t0, t1, tuple(xyz), np.diag(np.square(sigmas)).tolist(), 5, 1.0)


def observations(rows) -> Observations:
    """Rows of (timestamp ticks, instance, score, lifted): one observation each at the origin
    (NaN when not lifted)."""
    n = len(rows)
    ts = np.array([r[0] for r in rows], np.int64)
    world = np.array([[0.0, 0.0, 0.0] if r[3] else [np.nan] * 3 for r in rows]).reshape(n, 3)
    return Observations(ts, np.arange(n, dtype=np.int32), np.array([r[1] for r in rows], np.int32),
                        np.array([r[2] for r in rows], np.float32), np.zeros((n, 4), np.float32), world,
                        np.zeros((n, 3)), np.ones(n, np.float32), world[:, None, :].copy(),
                        np.zeros(n, np.int8), np.full(n, 10, np.int32))


def test_nees_of_known_errors():
    gt = [GtInterval(0, 0, 100, (0.0, 0.0, 0.0)), GtInterval(0, 101, 200, (1.0, 0.0, 0.0)),
          GtInterval(1, 0, 200, (0.0, 1.0, 0.0))]
    ivs = [
        interval(0, 0, 90, (0.1, 0.0, 0.0)),                      # e = 1 sigma in x: NEES 1
        interval(0, 80, 200, (1.0, 0.1, 0.05), (0.2, 0.1, 0.05)),  # overlaps the second GT most: 0 + 1 + 1
        interval(1, 0, 200, (0.0, 1.3, 0.0)),                     # 0.3 m off: counted as far, no value
        interval(2, 0, 200, (0.0, 0.0, 0.0)),                     # no GT of that instance: skipped
        interval(0, 300, 400, (0.0, 0.0, 0.0)),                   # overlaps no GT: skipped
    ]
    vals, far = nees_values(ivs, gt)
    assert vals == pytest.approx([1.0, 2.0])
    assert far == 1


def test_nees_uses_the_full_covariance():
    cov = [[0.02, 0.01, 0.0], [0.01, 0.02, 0.0], [0.0, 0.0, 0.01]]
    iv = PositionInterval(0, 0, 10, (0.1, 0.1, 0.0), cov, 3, 1.0)
    e = np.array([0.1, 0.1, 0.0])
    vals, far = nees_values([iv], [GtInterval(0, 0, 10, (0.0, 0.0, 0.0))])
    assert vals == pytest.approx([e @ np.linalg.solve(np.array(cov), e)])  # 2/3, not the diagonal's 1.0
    assert vals[0] == pytest.approx(2 / 3) and far == 0


def test_observable_intervals_count_lifted_true_detections_above_the_threshold():
    gt = [GtInterval(0, 0, 100, (0, 0, 0)), GtInterval(0, 101, 200, (1, 0, 0)), GtInterval(1, 0, 200, (0, 1, 0))]
    rows = [
        (10, 0, 0.9, True), (20, 0, 0.6, True), (100, 0, 0.7, True),  # three for the first interval (ends inclusive)
        (110, 0, 0.9, True), (120, 0, 0.9, True), (130, 0, 0.5, True),  # second: one below the threshold
        (140, 0, 0.9, False),                                           # ... one not lifted
        (10, 1, 0.9, True), (20, 1, 0.9, True), (30, 1, 0.9, True),     # third: one of them false (mask)
    ]
    obs = observations(rows)
    true = np.ones(len(rows), bool)
    true[9] = False
    assert observable_intervals(gt, obs, true, 0.6) == [gt[0]]
    assert observable_intervals(gt, obs, np.ones(len(rows), bool), 0.6) == [gt[0], gt[2]]
    assert observable_intervals(gt, obs, np.ones(len(rows), bool), 0.5) == gt
    assert observable_intervals(gt, obs, true, 0.6, min_true=4) == []
    with pytest.raises(ValueError):
        observable_intervals(gt, obs, true[:-1], 0.6)


def test_ratio_and_target_checks():
    assert ratio(3, 2) == 1.5 and np.isnan(ratio(1, 0))
    assert target_checks({}) == []  # no rows: nothing to check


def _report(per_seq: dict[str, tuple[list, list, float]]):
    """An EvalReport whose sequences have the given (tp, fp, l2) at two thresholds (10 GT frames)."""
    from egograph.eval.protocol import Counts, SequenceResult
    from egograph.eval.report import EvalReport

    rep = EvalReport(thresholds=(0.25, 1.5))
    for name, (tp, fp, l2) in per_seq.items():
        n = 10
        c = Counts((0.25, 1.5), tp=tp, fp=fp, fn=[n - t for t in tp], n_gt=n, n_pred=tp[0] + fp[0],
                   l2_sum=l2 * n, l2_n=n)
        rep.add(name, SequenceResult(c))
    return rep


def test_dominance_misses_name_the_recording_threshold_and_baseline():
    from egograph.eval.metrics import dominance_misses

    ours = _report({"a": ([8, 9], [2, 1], 0.1), "b": ([3, 9], [7, 1], 0.2)})
    theirs = _report({"a": ([5, 8], [5, 2], 0.5), "b": ([4, 7], [6, 3], 0.6)})
    misses = dominance_misses(ours, {"memory": theirs})
    # pooled 11/20 against 9/20 at 0.25 m: dominates; recording b loses P and R at 0.25 m only
    assert {(m.scope, m.against, m.metric) for m in misses} == {("b", "memory", "P@0.25"), ("b", "memory", "R@0.25")}
    assert dominance_misses(ours, {"memory": theirs}, per_sequence=False) == []
    worse_l2 = _report({"a": ([8, 9], [2, 1], 0.9), "b": ([4, 9], [6, 1], 0.9)})
    assert [m.metric for m in dominance_misses(worse_l2, {"kf": theirs}, per_sequence=False)] == ["L2"]
