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
    switchable_closed,
    switchable_closed_values,
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


@pytest.mark.parametrize("gap_sigmas", [0.0, 0.5, 1.9, 2.0, 2.1, 5.0, 40.0])
def test_closed_form_costs_what_the_switched_factor_costs_at_its_best_switch(gap_sigmas):
    # Geman-McClure of width 1/sigma_s on the gap = the switched factor plus its prior at s* (and s*
    # is that pair's minimum over s): the same objective over the landmarks.
    still, sigma_s = 0.05, 0.5
    a, b = np.array([0.3, -0.2, 1.0]), np.array([0.3, -0.2, 1.0]) + gap_sigmas * still * np.array([0.6, 0.0, 0.8])
    s_star = float(switchable_closed_values(np.array([a, b]), still, sigma_s)[0])
    assert s_star == pytest.approx(1 / (1 + gap_sigmas**2 * sigma_s**2))

    def switched(s):
        v = _values(a, b, s)
        return switchable_between(A, B, SW, still).error(v) + switch_prior(SW, sigma_s).error(v)

    closed = switchable_closed(A, B, still, sigma_s).error(_values(a, b, 1.0))
    assert closed == pytest.approx(switched(s_star), rel=1e-12, abs=1e-15)
    for other in (s_star - 0.01, s_star + 0.01):
        if 0.0 <= other <= 1.0:
            assert switched(other) > switched(s_star)


def test_closed_form_solve_finds_the_switched_solve_or_a_lower_cost():
    # A chain of 30 landmarks with a 0.3 m move and a 2 cm one: both solves break at the same
    # boundary and agree on the landmarks; with explicit switches LM can stall a switch at exactly 1
    # (where the clip's slope ends), so the closed form's cost is never higher.
    rng = np.random.default_rng(0)
    n, still, sigma_s = 30, 0.05, 0.5
    truth = np.zeros((n, 3))
    truth[12:] += [0.3, 0.0, 0.0]
    truth[20:] += [0.0, 0.02, 0.0]
    dets = truth[:, None, :] + 0.02 * rng.standard_normal((n, 5, 3))
    init = truth + 0.01 * rng.standard_normal((n, 3))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(200)
    params.setRelativeErrorTol(1e-12)
    out = {}
    for form in ("explicit", "closed"):
        g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for k in range(n):
            v.insert(gtsam.symbol("l", k), gtsam.Point3(*init[k]))
            for p in dets[k]:
                g.add(gtsam.PriorFactorPoint3(gtsam.symbol("l", k), gtsam.Point3(*p), gtsam.noiseModel.Isotropic.Sigma(3, 0.02)))
            if k and form == "explicit":
                g.add(switchable_between(gtsam.symbol("l", k - 1), gtsam.symbol("l", k), gtsam.symbol("s", k), still))
                g.add(switch_prior(gtsam.symbol("s", k), sigma_s))
                v.insert(gtsam.symbol("s", k), np.array([1.0]))
            elif k:
                g.add(switchable_closed(gtsam.symbol("l", k - 1), gtsam.symbol("l", k), still, sigma_s))
        r = gtsam.LevenbergMarquardtOptimizer(g, v, params).optimize()
        lm = np.array([np.asarray(r.atPoint3(gtsam.symbol("l", k))) for k in range(n)])
        sw = (np.array([switch_clipped(r, gtsam.symbol("s", k)) for k in range(1, n)]) if form == "explicit"
              else switchable_closed_values(lm, still, sigma_s))
        out[form] = lm, sw, g.error(r)
    (l_e, s_e, e_e), (l_c, s_c, e_c) = out["explicit"], out["closed"]
    assert np.flatnonzero(s_e < 0.5).tolist() == np.flatnonzero(s_c < 0.5).tolist() == [11]
    assert np.abs(l_e - l_c).max() < 1e-3
    assert e_c <= e_e + 1e-9
