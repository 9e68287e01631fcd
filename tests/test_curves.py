"""Precision-recall curves over confidence, average precision and calibration, against curves
computed by hand (egograph.eval.curves)."""

import numpy as np
import pytest

from egograph.eval.curves import ScoredAnswers, average_precision, pr_curve, pr_curves, reliability, score_answers
from egograph.eval.protocol import GtInterval, evaluate_sequence

TS = [0, 1, 2, 3, 4]
GT = [GtInterval(0, 0, 3, (0.0, 0.0, 0.0))]          # instance 0 stands at the origin over frames 0-3
TAUS = (0.25, 1.0)


def _answers():
    # frame -> instance -> (xyz, confidence); frames 1 and 2 tie at 0.8; frame 4 has no GT interval
    return {0: {0: ((0.1, 0, 0), 0.9)}, 1: {0: ((0.5, 0, 0), 0.8)}, 2: {0: ((0, 0, 0), 0.8)},
            4: {0: ((0, 0, 0), 0.3)}}


def test_curve_with_ties_by_hand():
    sa = score_answers(TS, GT, _answers(), TAUS)
    assert sa.n_gt == 4
    c = pr_curve(sa, 0.25)
    # 0.9: 1 TP of 1 answer; 0.8 (both tied answers at once): 2 of 3; 0.3: 2 of 4
    np.testing.assert_allclose(c.confidence, [0.9, 0.8, 0.3])
    np.testing.assert_allclose(c.precision, [1.0, 2 / 3, 0.5])
    np.testing.assert_allclose(c.recall, [0.25, 0.5, 0.5])
    assert c.ap == pytest.approx(0.25 * 1.0 + 0.25 * 2 / 3)
    c1 = pr_curve(sa, 1.0)
    np.testing.assert_allclose(c1.precision, [1.0, 1.0, 0.75])
    np.testing.assert_allclose(c1.recall, [0.25, 0.75, 0.75])
    assert c1.ap == pytest.approx(0.75)
    # the lowest threshold is the reference evaluator's operating point of every answer
    ref = evaluate_sequence(TS, GT, {t: {i: xyz for i, (xyz, _) in f.items()} for t, f in _answers().items()},
                            thresholds=TAUS).total
    for tau, curve in pr_curves(sa).items():
        k = TAUS.index(tau)
        assert curve.precision[-1] == pytest.approx(ref.precision[k])
        assert curve.recall[-1] == pytest.approx(ref.recall[k])
    # operating points and passing a baseline's point
    assert c.at(0.85) == (1.0, 0.25)
    assert c.at(0.5) == pytest.approx((2 / 3, 0.5))
    assert c.at(0.95) == (0.0, 0.0)
    assert c.passes(0.6, 0.5) and not c.passes(0.7, 0.5) and c.passes(1.0, 0.25) and not c.passes(0.1, 0.6)


def test_no_answers_and_one_answer():
    none = pr_curve(score_answers(TS, GT, {}, TAUS), 0.25)
    assert none.ap == 0.0 and len(none.precision) == 0 and none.n_gt == 4
    assert none.passes(0.5, 0.0) and not none.passes(0.0, 0.01)
    assert reliability(score_answers(TS, GT, {}, TAUS)).ece == 0.0
    one = pr_curve(score_answers(TS, GT, {2: {0: ((0, 0.1, 0), 0.4)}}, TAUS), 0.25)
    np.testing.assert_allclose([one.precision[0], one.recall[0], one.ap], [1.0, 0.25, 0.25])
    wrong = pr_curve(score_answers(TS, GT, {4: {0: ((0, 0, 0), 0.4)}}, TAUS), 0.25)
    np.testing.assert_allclose([wrong.precision[0], wrong.recall[0], wrong.ap], [0.0, 0.0, 0.0])


def test_average_precision_interpolates_all_points():
    # precision rises after a dip: the envelope takes the later, higher precision
    assert average_precision([1.0, 0.5, 0.8], [0.2, 0.4, 0.8]) == pytest.approx(0.2 * 1.0 + 0.2 * 0.8 + 0.4 * 0.8)


def test_two_overlapping_gt_intervals_count_twice():
    gt = GT + [GtInterval(0, 2, 4, (0.0, 0.0, 0.0))]
    sa = score_answers(TS, gt, _answers(), TAUS)
    assert sa.n_gt == 7
    assert sa.tp[:, 0].tolist() == [1, 0, 2, 1]


def test_reliability_table_by_hand():
    r = reliability(score_answers(TS, GT, _answers(), TAUS), 0.25)
    assert r.count.tolist() == [0, 0, 0, 1, 0, 0, 0, 0, 1 + 1, 1]
    assert r.share[9] == 1.0 and r.share[8] == 0.5 and r.share[3] == 0.0 and np.isnan(r.share[0])
    assert r.ece == pytest.approx((1 * 0.1 + 2 * 0.3 + 1 * 0.3) / 4)


def test_pooling_adds_answers_and_gt():
    a = score_answers(TS, GT, _answers(), TAUS)
    both = a + a
    assert both.n_gt == 8 and len(both.score) == 8
    assert pr_curve(both, 0.25).ap == pytest.approx(pr_curve(a, 0.25).ap)
    assert len(a.above(0.8).score) == 3
    with pytest.raises(ValueError):
        a + ScoredAnswers((0.5,))
