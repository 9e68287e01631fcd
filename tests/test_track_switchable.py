"""Switchable motion-break factors: analytic Jacobians, and switches that turn off exactly where objects moved."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from egograph.track.switchable import (
    dcs_between,
    dcs_phi,
    dcs_switch_value,
    switch_clipped,
    switch_prior,
    switch_weight,
    switchable_between,
)

A, B, SW = gtsam.symbol("l", 0), gtsam.symbol("l", 1), gtsam.symbol("s", 1)


def _values(a, b, s) -> gtsam.Values:
    v = gtsam.Values()
    v.insert(A, gtsam.Point3(*a))
    v.insert(B, gtsam.Point3(*b))
    v.insert(SW, np.array([s]))
    return v


@pytest.mark.parametrize("s", [0.3, 0.75, 1.0])
def test_analytic_jacobians_match_finite_differences(s):
    f = switchable_between(A, B, SW, 0.05)
    a, b = np.array([0.1, 0.2, 0.3]), np.array([0.4, -0.1, 0.9])
    jac = f.linearize(_values(a, b, s))
    Ab, _ = jac.jacobian()  # whitened [dA dB ds]
    eps = 1e-6

    def err(a_, b_, s_):
        return f.whitenedError(_values(a_, b_, s_))

    num = np.zeros((3, 7))
    for j in range(3):
        d = np.zeros(3)
        d[j] = eps
        num[:, j] = (err(a + d, b, s) - err(a - d, b, s)) / (2 * eps)
        num[:, 3 + j] = (err(a, b + d, s) - err(a, b - d, s)) / (2 * eps)
    # one-sided at s = 1 (psi is clipped above 1): the derivative from below
    num[:, 6] = (err(a, b, s) - err(a, b, s - eps)) / eps
    assert np.allclose(Ab, num, atol=1e-5)


def test_switch_weight_clips():
    assert switch_weight(-0.2) == (0.0, 0.0)
    assert switch_weight(1.3) == (1.0, 0.0)
    assert switch_weight(0.4) == (0.4, 1.0)


def _two_landmarks(gap_m: float, kind: str, sigma_s: float = 0.5, still=0.05) -> tuple[np.ndarray, np.ndarray, float]:
    """Two landmarks held by tight priors ``gap_m`` apart, joined by a break factor."""
    g = gtsam.NonlinearFactorGraph()
    tight = gtsam.noiseModel.Isotropic.Sigma(3, 0.001)
    g.add(gtsam.PriorFactorPoint3(A, gtsam.Point3(0, 0, 0), tight))
    g.add(gtsam.PriorFactorPoint3(B, gtsam.Point3(gap_m, 0, 0), tight))
    v = gtsam.Values()
    v.insert(A, gtsam.Point3(0, 0, 0))
    v.insert(B, gtsam.Point3(gap_m, 0, 0))
    if kind == "switchable":
        g.add(switchable_between(A, B, SW, still))
        g.add(switch_prior(SW, sigma_s))
        v.insert(SW, np.array([1.0]))
    else:
        g.add(dcs_between(A, B, still, dcs_phi(sigma_s)))
    r = gtsam.LevenbergMarquardtOptimizer(g, v).optimize()
    a, b = np.asarray(r.atPoint3(A)), np.asarray(r.atPoint3(B))
    s = switch_clipped(r, SW) if kind == "switchable" else dcs_switch_value(a, b, still, dcs_phi(sigma_s))
    return a, b, s


def test_switch_stays_on_for_a_still_object_and_turns_off_for_a_move():
    _, _, s_still = _two_landmarks(0.01, "switchable")
    _, _, s_moved = _two_landmarks(1.0, "switchable")
    assert s_still > 0.9
    assert s_moved < 0.05


def test_break_threshold_follows_the_switch_prior():
    # With the landmarks held, s = 1 / (1 + d^2 sigma_s^2): s < 0.5 exactly when d > 1 / sigma_s,
    # i.e. the gap exceeds still_sigma / sigma_s = 0.05 / 0.5 = 0.1 m.
    _, _, below = _two_landmarks(0.09, "switchable")
    _, _, above = _two_landmarks(0.11, "switchable")
    assert below > 0.5 > above
    d = 0.2 / 0.05
    assert _two_landmarks(0.2, "switchable")[2] == pytest.approx(1 / (1 + d**2 * 0.25), abs=0.01)


def test_moved_landmarks_are_not_dragged_together():
    # Free landmarks with many detections each: the switch turns off and neither moves.
    g = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Isotropic.Sigma(3, 0.03)
    rng = np.random.default_rng(0)
    for key, centre in ((A, [0, 0, 0]), (B, [0.8, 0, 0])):
        for p in np.asarray(centre) + 0.02 * rng.standard_normal((20, 3)):
            g.add(gtsam.PriorFactorPoint3(key, gtsam.Point3(*p), noise))
    g.add(switchable_between(A, B, SW, 0.05))
    g.add(switch_prior(SW, 0.5))
    r = gtsam.LevenbergMarquardtOptimizer(g, _values([0, 0, 0], [0.8, 0, 0], 1.0)).optimize()
    assert np.linalg.norm(np.asarray(r.atPoint3(A))) < 0.02
    assert np.linalg.norm(np.asarray(r.atPoint3(B)) - [0.8, 0, 0]) < 0.02
    assert switch_clipped(r, SW) < 0.05


@pytest.mark.parametrize("gap", [0.02, 0.05, 0.09, 0.11, 0.3, 1.0])
def test_dcs_fast_path_agrees_on_breaks(gap):
    s1 = _two_landmarks(gap, "switchable")[2]
    s2 = _two_landmarks(gap, "dcs")[2]
    assert (s1 < 0.5) == (s2 < 0.5)


def test_dcs_switch_value_closed_form():
    assert dcs_switch_value([0, 0, 0], [0, 0, 0], 0.05, 4.0) == 1.0
    d2 = (0.3 / 0.05) ** 2
    assert dcs_switch_value([0, 0, 0], [0.3, 0, 0], 0.05, 4.0) == pytest.approx(8 / (4 + d2))


def test_dcs_switch_values_are_the_pairwise_values_bit_for_bit():
    from egograph.track.switchable import dcs_switch_values

    rng = np.random.default_rng(1)
    landmarks = rng.normal(size=(400, 3)) * rng.uniform(0, 0.3, (400, 1))
    want = [dcs_switch_value(landmarks[k - 1], landmarks[k], 0.05, 3.3) for k in range(1, 400)]
    assert dcs_switch_values(landmarks, 0.05, 3.3).tolist() == want
    assert dcs_switch_values(landmarks[:1], 0.05, 3.3).shape == (0,)
