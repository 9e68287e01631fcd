"""The answers' confidence: the calibration fit (isotonic knots) and its application per tracker
family, front-end (clean or noisy detection noise scale) and answer kind, as the answers carry it."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from egograph.core.config import load_config
from egograph.core.errors import ConfigError
from egograph.core.resources import default_config
from egograph.steps.settings import EgographConfig
from egograph.track.answers import (ANSWER_KINDS, HAND, HELD, LAST, PUT_DOWN, STAND, UNSEEN, calibrated, confidences,
                                    held_rows, isotonic_knots, support_ranges)
from egograph.track.config import AnswersConfig, GraphConfig


def test_isotonic_knots_by_hand():
    # pool-adjacent-violators: 0 | (1, 0) -> 0.5 | 1; each block a knot at its mean raw value
    assert isotonic_knots([0.1, 0.2, 0.3, 0.4], [0, 1, 0, 1]) == [[0.0, 0.0], [0.1, 0.0], [0.25, 0.5], [0.4, 1.0],
                                                                  [1.0, 1.0]]
    # blocks of fewer than min_share of the answers are merged into a neighbour: a single answer
    # per block of 4 with min_share 0.3 pools everything
    assert isotonic_knots([0.1, 0.2, 0.3, 0.4], [0, 1, 0, 1], min_share=0.3) == [[0.0, 0.5], [0.25, 0.5],
                                                                                 [1.0, 0.5]]
    # ties in raw are one block (a constant raw value is one calibrated value)
    assert isotonic_knots([0.5, 0.5, 0.5, 0.5], [1, 1, 0, 0]) == [[0.0, 0.5], [0.5, 0.5], [1.0, 0.5]]
    with pytest.raises(ValueError):
        isotonic_knots([], [])


def test_fitted_knots_are_monotone_calibrated_and_round_trip_through_the_config():
    rng = np.random.default_rng(41)
    raw = rng.uniform(size=20000)
    right = (rng.uniform(size=raw.size) < raw ** 2).astype(float)  # right with probability raw^2
    knots = isotonic_knots(raw, right, min_share=0.02)
    k = np.asarray(knots)
    assert len(knots) <= 16 and np.all(np.diff(k[:, 0]) > 0) and np.all(np.diff(k[:, 1]) >= 0)
    assert k[0, 0] == 0.0 and k[-1, 0] == 1.0
    conf = calibrated(raw, knots)
    # calibrated: within each tenth of confidence the share right matches the confidence
    bins = np.minimum((conf * 10).astype(int), 9)
    for b in np.unique(bins):
        at = bins == b
        if at.sum() > 500:
            assert abs(right[at].mean() - conf[at].mean()) < 0.05
    assert np.allclose(calibrated(raw, knots), raw ** 2, atol=0.08)
    # a fitted calibration is a valid knob value and reads back unchanged
    cfg = load_config(EgographConfig, default_config(), [f"graph.answers.offline_calibration={json.dumps(knots)}",
                                                         "graph.answers.noisy_causal_kinds=[0.1, 0.2, 0.3, 0.4, 0.5]"])
    assert cfg.graph.answers.offline_calibration == knots
    assert cfg.graph.answers.noisy_causal_kinds == [0.1, 0.2, 0.3, 0.4, 0.5]
    with pytest.raises(ConfigError):  # a kind's confidence is a probability, one per kind after the stand
        load_config(EgographConfig, default_config(), ["graph.answers.offline_kinds=[0.1, 0.2, 1.3, 0.4, 0.5]"])
    with pytest.raises(ConfigError):
        load_config(EgographConfig, default_config(), ["graph.answers.offline_kinds=[0.1, 0.2, 0.3, 0.4]"])


def test_confidence_per_family_front_end_and_kind():
    a = AnswersConfig(offline_calibration=[[0.0, 0.0], [1.0, 0.5]], noisy_offline_calibration=[[0.0, 0.2], [1.0, 0.4]],
                      offline_kinds=[0.61, 0.62, 0.63, 0.64, 0.65], noisy_offline_kinds=[0.71, 0.72, 0.73, 0.74, 0.75],
                      causal_kinds=[0.81, 0.82, 0.83, 0.84, 0.85])
    raw = np.array([0.0, 0.5, 1.0, 0.5, 0.5, 0.5, 0.5, 0.5])
    kind = np.array([STAND, STAND, STAND, UNSEEN, HAND, LAST, PUT_DOWN, HELD])
    assert ANSWER_KINDS[STAND] == "stand" and ANSWER_KINDS[HELD] == "held" and len(ANSWER_KINDS) == 6
    assert np.allclose(confidences(raw, kind, a, "offline", 1.0), [0.0, 0.25, 0.5, 0.61, 0.62, 0.63, 0.64, 0.65])
    assert np.allclose(confidences(raw, kind, a, "offline", a.noisy_scale),
                       [0.2, 0.3, 0.4, 0.71, 0.72, 0.73, 0.74, 0.75])
    assert np.allclose(confidences(raw, kind, a, "causal", 0.5)[3:], [0.81, 0.82, 0.83, 0.84, 0.85])


def test_support_range_is_the_median_range_of_the_detections_near_the_answer():
    world = np.array([[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [2, 0, 0], [2.1, 0, 0], [0.05, 0, 0]], float)
    rng = np.array([0.3, 0.4, 1.2, 1.0, 0.9, np.nan])
    # row 0: rows 0, 1, 2 and 5 lie within 0.25 m (5's range unknown): median of 0.3, 0.4, 1.2
    # row 3: rows 3, 4: (1.0 + 0.9) / 2; row 1: rows 0, 1, 2, 5 again; a block of one row at a time
    assert np.allclose(support_ranges(world, rng, np.array([0, 3, 1]), 0.25, block=1), [0.4, 0.95, 0.4])
    assert np.isnan(support_ranges(world[5:], rng[5:], np.array([0]), 0.25))[0]
    cfg = AnswersConfig()
    assert held_rows(world, rng, np.array([0, 3]), cfg).tolist() == [True, False]
    assert held_rows(world, rng, np.array([0, 3]), dataclasses.replace(cfg, held_range_m=0.0)).tolist() == \
        [False, False]


def test_an_instance_without_places_answers_held_where_it_was_only_seen_in_hand():
    """No place: every frame answers the nearest detection in time, of kind LAST, or HELD where the
    detections around that one were seen from under held_range_m (the object in the hand)."""
    from types import SimpleNamespace

    from egograph.track.answers import offline_answers

    world = np.array([[1.0, 0, 0], [1.02, 0, 0], [3.0, 0, 0], [3.01, 0, 0]])
    sol = SimpleNamespace(world=world, frames=np.array([10, 20, 60, 70]), range_m=np.array([0.3, 0.35, 1.5, 1.4]),
                          places=[], intervals=[])
    xyz, raw, kind = offline_answers(sol, None, None, [], 100, GraphConfig())
    assert (kind[:41] == HELD).all() and (kind[41:] == LAST).all() and np.allclose(xyz[80], world[3])
    sol.range_m = None   # no ranges (another tracker's answers): nothing is known to be held
    assert (offline_answers(sol, None, None, [], 100, GraphConfig())[2] == LAST).all()


def _scenario(causal: bool):
    """The trackers' tests' recordings: a stand at A, a carry, a stand at B (offline:
    tests/test_track_graph.py's; causal: tests/test_track_online.py's, whose carry is in hand)."""
    if causal:
        import test_track_online as t
    else:
        import test_track_graph as t
    return t


@pytest.mark.parametrize("causal", [False, True])
def test_the_answers_carry_each_kinds_configured_confidence(causal):
    """What the answers (answers.tsv) carry: a carried frame's answer the hand's configured
    confidence, the stands their calibrated raw value, of the family and front-end in use."""
    from egograph.track.graph import graph_tracker

    tg = _scenario(causal)
    kinds = [0.41, 0.42, 0.43, 0.44, 0.45]
    fam = "causal" if causal else "offline"
    answers = dataclasses.replace(AnswersConfig(), **{f"{fam}_kinds": kinds, f"noisy_{fam}_kinds": kinds})
    res = graph_tracker(tg.make_obs(tg.scenario()), tg.stamps(), GraphConfig(negative_evidence=False, answers=answers),
                        causal=causal)
    score = {int((t - tg.T0) // tg.FRAME): [p.score for p in preds] for t, preds in res.answers.items()}
    carried = [score[f][0] for f in range(tg.CARRY[0] + 20, tg.CARRY[1] - 5)]
    assert carried and np.mean(np.isclose(carried, 0.42)) >= 0.8
    stands = [score[f][0] for f in range(100, tg.CARRY[0] - 30)]
    assert not np.isin(np.round(stands, 6), kinds).any()
    knots = answers.knots(fam, res.metadata["noise_scale"])
    assert min(stands) >= min(k[1] for k in knots) and max(stands) <= max(k[1] for k in knots)
    # the per-frame files hold the operating point of those confidences
    floor = answers.causal_min_confidence if causal else answers.min_confidence
    assert res.per_frame == {t: [p for p in v if p.score >= floor] for t, v in res.answers.items()}
