"""The detection noise scale the offline tracker fits from its own stands (egograph.track.noise_scale)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_track_graph import A, B, CARRY, N, make_obs, stamps

from egograph.track.config import GraphConfig
from egograph.track.graph import graph_tracker
from egograph.track.noise_scale import chi2_cdf, chi2_ppf, fit_scale_ratio, truncated_median


def test_chi2_with_three_degrees_of_freedom():
    # table values of chi-squared with 3 dof
    for x, p in ((0.5844, 0.10), (2.3660, 0.50), (7.8147, 0.95), (11.3449, 0.99)):
        assert chi2_cdf(x) == pytest.approx(p, abs=1e-4)
        assert chi2_ppf(p) == pytest.approx(x, rel=1e-3)
    assert truncated_median(1.0, 1e9) == pytest.approx(2.3660, rel=1e-3)


def test_the_inverses_solve_to_near_machine_precision():
    # chi2_ppf (Newton inside a bracket) and fit_scale_ratio (false position) replace bisections;
    # the online tracker calls them on every noise-scale refit and rounds the scale to 4 digits
    for p in np.linspace(1e-6, 1 - 1e-9, 400):
        assert chi2_cdf(chi2_ppf(p)) == pytest.approx(p, rel=1e-10, abs=1e-15)
    gate = GraphConfig().inlier_chi2
    for r in (0.07, 0.4, 1.0, 2.5, 14.0):
        target = truncated_median(r, gate)
        d2 = np.full(5, target)  # residuals whose median is exactly the model's at r
        assert fit_scale_ratio(d2, gate) == pytest.approx(r, rel=1e-9)
    assert fit_scale_ratio(np.full(5, gate), gate, hi=20.0) == 20.0  # no ratio in range explains it: clipped


@pytest.mark.parametrize("r", [0.5, 1.0, 3.0])
def test_the_fit_recovers_the_ratio_from_residuals_cut_at_the_gate(r):
    gate = GraphConfig().inlier_chi2
    d2 = r * r * np.random.default_rng(1).chisquare(3, 20000)
    d2 = d2[d2 <= gate]  # only inliers are seen
    assert fit_scale_ratio(d2, gate) == pytest.approx(r, rel=0.05)


def noisy_scenario(sigma_m: float, seed: int = 0) -> list:
    """Instance 0 stands at A, is carried to B, stands at B; every 3rd frame a detection whose
    lifted point scatters isotropically by ``sigma_m`` (no look-alike)."""
    rng = np.random.default_rng(seed)
    rows = []
    for f in range(30, N, 3):
        if CARRY[0] <= f < CARRY[1]:
            continue
        p = A if f < CARRY[0] else B
        rows.append((f, 0, p + sigma_m * rng.standard_normal(3), 0.7))
    return rows


def frames_right(res, ts, radius_m: float = 0.15) -> float:
    """Share of the stand frames (outside 1 s around the carry) predicted within ``radius_m``."""
    right = total = 0
    for f in range(N):
        if CARRY[0] - 30 <= f < CARRY[1] + 30:
            continue
        truth = A if f < CARRY[0] else B
        preds = res.per_frame.get(int(ts[f]), [])
        total += 1
        right += any(np.linalg.norm(np.array(p.xyz) - truth) < radius_m for p in preds)
    return right / total


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_noisy_front_end_gets_a_wider_scale_and_its_stands_back(seed):
    """Lifted points scattering by 0.15 m (2-4x the default sigmas at these ranges): with the
    default sigmas the gate rejects most of them (the place chain still finds both places, from
    their cores); the fitted scale takes them in, and the covariances cover the error."""
    obs, ts = make_obs(noisy_scenario(0.15, seed)), stamps()
    fixed = graph_tracker(obs, ts, GraphConfig(negative_evidence=False, noise=dataclasses.replace(
        GraphConfig().noise, auto_scale=False)))
    auto = graph_tracker(obs, ts, GraphConfig(negative_evidence=False))
    assert fixed.metadata["noise_scale"] == 1.0 and auto.metadata["noise_scale"] > 2.0
    assert frames_right(auto, ts) > 0.97
    assert frames_right(fixed, ts) <= frames_right(auto, ts)
    assert sum(iv.n_observations for iv in fixed.intervals) < 0.5 * sum(iv.n_observations for iv in auto.intervals)
    for iv in auto.intervals:
        truth = A if np.linalg.norm(np.array(iv.xyz) - A) < np.linalg.norm(np.array(iv.xyz) - B) else B
        d = np.array(iv.xyz) - truth
        assert d @ np.linalg.solve(np.asarray(iv.covariance), d) < 11.34  # within the 99 % ellipsoid


def test_a_precise_front_end_keeps_its_intervals():
    """2 cm scatter: the fit shrinks the sigmas and the intervals are those of the default ones."""
    obs, ts = make_obs(noisy_scenario(0.02)), stamps()
    auto = graph_tracker(obs, ts, GraphConfig(negative_evidence=False))
    fixed = graph_tracker(obs, ts, GraphConfig(negative_evidence=False, noise=dataclasses.replace(
        GraphConfig().noise, auto_scale=False)))
    assert auto.metadata["noise_scale"] < 1.0
    assert len(auto.intervals) == len(fixed.intervals) == 2
    for a, f in zip(auto.intervals, fixed.intervals):
        assert np.linalg.norm(np.subtract(a.xyz, f.xyz)) < 0.01
        assert abs(a.t_start - f.t_start) <= 30 * 333_333 and abs(a.t_end - f.t_end) <= 30 * 333_333


@pytest.mark.parametrize("seed", [0, 1])
def test_the_causal_mode_fits_the_scale_as_it_goes(seed):
    """Online (graph.noise.online_auto): the scale is fitted from the stands confirmed so far. With
    0.15 m scatter it stays wide and more stand frames are right than with the default sigmas; with
    2 cm it shrinks below 1."""
    ts = stamps()
    fixed_noise = dataclasses.replace(GraphConfig().noise, online_auto=False)
    noisy = make_obs(noisy_scenario(0.15, seed))
    auto = graph_tracker(noisy, ts, GraphConfig(negative_evidence=False), causal=True)
    fixed = graph_tracker(noisy, ts, GraphConfig(negative_evidence=False, noise=fixed_noise), causal=True)
    assert fixed.metadata["noise_scale_rounds"] == [1.0]
    assert auto.metadata["noise_scale_rounds"][0] == GraphConfig().noise.auto_start
    assert auto.metadata["noise_scale"] > 1.5
    assert frames_right(auto, ts) > frames_right(fixed, ts) + 0.1
    precise = graph_tracker(make_obs(noisy_scenario(0.02, seed)), ts, GraphConfig(negative_evidence=False), causal=True)
    assert len(precise.metadata["noise_scale_rounds"]) > 1 and precise.metadata["noise_scale"] < 1.0
