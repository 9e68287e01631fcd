"""tools/ece_spread.py: the pooled ECE of a subset of recordings from their reliability tables."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))

from ece_spread import bin_sums, pooled_ece, subset_eces  # noqa: E402

from egograph.eval.curves import ScoredAnswers, reliability  # noqa: E402
from egograph.eval.protocol import THRESHOLDS  # noqa: E402


def answers(score, within) -> ScoredAnswers:
    """Answers with these confidences, a TP at every threshold where ``within``."""
    tp = np.repeat(np.asarray(within, np.int64)[:, None], len(THRESHOLDS), axis=1)
    return ScoredAnswers(score=np.asarray(score, np.float64), tp=tp, n_gt=len(score))


def test_pooled_ece_of_two_recordings_equals_the_reliability_of_their_answers_pooled():
    # recording a: over-confident in the 0.8 bin; recording b: under-confident there, and an empty bin of a's
    a = answers([0.85, 0.85, 0.85, 0.85, 0.15], [1, 1, 0, 0, 0])
    b = answers([0.82, 0.82, 0.55], [1, 1, 1])
    both = answers(np.r_[a.score, b.score], np.r_[a.tp[:, 0], b.tp[:, 0]])
    sums = [bin_sums(reliability(a)), bin_sums(reliability(b))]
    assert pooled_ece(sums) == pytest.approx(reliability(both).ece, abs=1e-12)
    # by hand: bin 0.1: |0.15 - 0| = 0.15; bin 0.5: |0.55 - 1| = 0.45; bin 0.8: |4 x 0.85 + 2 x 0.82 - 4| = 1.04
    assert pooled_ece(sums) == pytest.approx((0.15 + 0.45 + 1.04) / 8)
    # each alone is worse calibrated than the two pooled: a's over- and b's under-confidence in the
    # 0.8 bin cancel in part (a: (0.15 + |3.4 - 2|) / 5; b: (0.45 + |1.64 - 2|) / 3)
    assert pooled_ece(sums[:1]) == pytest.approx(1.55 / 5) and pooled_ece(sums[1:]) == pytest.approx(0.81 / 3)
    assert pooled_ece(sums) < min(pooled_ece(sums[:1]), pooled_ece(sums[1:]))


def test_no_answers_is_zero_and_subsets_are_every_combination_or_a_seeded_draw():
    empty = bin_sums(reliability(answers([], [])))
    assert pooled_ece([empty]) == 0.0
    sums = [bin_sums(reliability(answers([0.9] * 4, [1] * k + [0] * (4 - k)))) for k in range(5)]
    every = subset_eces(sums, 2, max_subsets=100, seed=0)
    assert len(every) == 10   # C(5, 2)
    # a pair (i, j within of 4 each), 8 answers at 0.9: |0.9 - (i + j) / 8|; worst (0, 1), best (3, 4)
    assert every.max() == pytest.approx(0.9 - 1 / 8) and every.min() == pytest.approx(0.9 - 7 / 8)
    drawn = subset_eces(sums, 2, max_subsets=4, seed=7)
    assert len(drawn) == 4 and np.array_equal(drawn, subset_eces(sums, 2, max_subsets=4, seed=7))
    with pytest.raises(SystemExit, match="--subset 6: only 5 recordings"):
        subset_eces(sums, 6, max_subsets=100, seed=0)
