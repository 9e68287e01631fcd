"""Places pooled across motion breaks and the place chain (egograph.track.places)."""

from __future__ import annotations

import itertools

import gtsam
import numpy as np
import pytest

from egograph.track.config import GraphConfig
from egograph.track.detection_factor import detection_covariances
from egograph.track.places import (
    ANY_CARRY,
    UNSEEN_STATE,
    Place,
    candidate_places,
    claim_places,
    map_path,
    n_states,
    place_chain,
    posterior,
    stand_state,
    transitions,
    unseen_moves_at_crossing,
)
from egograph.track.segments import make_segment

CFG = GraphConfig(negative_evidence=False)


def random_chain(rng, t_len: int, s: int):
    log_e = rng.normal(0.0, 2.0, (t_len, s))
    a = rng.uniform(0.0, 1.0, (s, s)) + 8.0 * np.eye(s)
    a /= a.sum(axis=1, keepdims=True)
    prior = rng.uniform(0.1, 1.0, s)
    return log_e, np.log(a), np.log(prior / prior.sum())


def test_map_path_is_the_mpe_of_the_same_chain_as_a_gtsam_discrete_factor_graph():
    rng = np.random.default_rng(3)
    log_e, log_a, log_prior = random_chain(rng, 60, 6)
    graph = gtsam.DiscreteFactorGraph()
    keys = [(t, 6) for t in range(60)]
    graph.add(keys[0], list(np.exp(log_prior + log_e[0] - (log_prior + log_e[0]).max())))
    for t in range(1, 60):
        graph.add(keys[t], list(np.exp(log_e[t] - log_e[t].max())))
        # DecisionTreeFactor over (t-1, t): the first key varies slowest
        graph.add([keys[t - 1], keys[t]], list(np.exp(log_a).ravel()))
    mpe = graph.optimize()
    assert [mpe[t] for t in range(60)] == list(map_path(log_e, log_a, log_prior))


def test_posterior_equals_brute_force_enumeration():
    rng = np.random.default_rng(5)
    log_e, log_a, log_prior = random_chain(rng, 4, 3)
    joint = np.zeros((4, 3))
    for path in itertools.product(range(3), repeat=4):
        lp = log_prior[path[0]] + log_e[0, path[0]] + sum(log_a[path[t - 1], path[t]] + log_e[t, path[t]]
                                                          for t in range(1, 4))
        for t, s in enumerate(path):
            joint[t, s] += np.exp(lp)
    joint /= joint.sum(axis=1, keepdims=True)
    assert np.allclose(posterior(log_e, log_a, log_prior), joint, atol=1e-9)


@pytest.mark.parametrize("k", [0, 1, 3])
def test_transition_rows_are_probabilities(k):
    log_a, log_prior = transitions(k, CFG, 30.0)
    assert log_a.shape == (n_states(k), n_states(k))
    assert np.allclose(np.exp(log_a).sum(axis=1), 1.0) and np.isclose(np.exp(log_prior).sum(), 1.0)


def test_a_place_pools_visits_split_by_motion_breaks():
    """Two visits to one place, the chain broken between them (and by a stray match inside the
    first): one place holding every detection at it, centred within a centimetre."""
    rng = np.random.default_rng(0)
    place = np.array([1.0, 0.8, 2.0])
    world = np.concatenate([place + 0.01 * rng.standard_normal((6, 3)), [[3.0, 0.9, 0.5]],
                            place + 0.01 * rng.standard_normal((5, 3)), place + 0.01 * rng.standard_normal((8, 3))])
    camera = np.tile([0.0, 1.6, 0.0], (len(world), 1))
    cov = detection_covariances(world, camera, CFG.noise)
    segments = [make_segment(rows, world, cov, CFG)
                for rows in (np.arange(0, 6), np.array([6]), np.arange(7, 12), np.arange(12, 20))]
    places = candidate_places(segments, world, cov, camera, np.linalg.norm(world - camera, axis=1),
                              np.arange(len(world)) * 10, CFG)
    assert len(places) == 1
    assert places[0].n_inliers == 19 and np.linalg.norm(places[0].xyz - place) < 0.01


def test_a_look_alike_place_belongs_to_the_instance_with_more_support():
    here = np.array([1.0, 0.8, 2.0])
    strong = Place(here, 1e-4 * np.eye(3), np.arange(30), np.arange(30) * 10)
    weak = Place(here + 0.05, 1e-4 * np.eye(3), np.arange(5), np.arange(10, 15) * 10)
    elsewhere = Place(here + 2.0, 1e-4 * np.eye(3), np.arange(20), np.arange(20) * 10)
    kept = claim_places({0: [strong], 1: [weak, elsewhere]}, CFG.exclusion_radius_m)
    assert kept[0] == [strong] and kept[1] == [elsewhere]
    # no overlap in time: both stood there, one after the other
    later = Place(here + 0.05, 1e-4 * np.eye(3), np.arange(5), np.arange(400, 405) * 10)
    assert claim_places({0: [strong], 1: [later]}, CFG.exclusion_radius_m)[1] == [later]


def chain_runs(rows, n_frames=600):
    """Runs of the place chain of one instance whose detections are (frame, xyz, in_hand) rows."""
    frames = np.array([r[0] for r in rows])
    world = np.array([r[1] for r in rows], float)
    in_hand = np.array([r[2] for r in rows], bool)
    camera = np.tile([0.0, 1.6, 0.0], (len(rows), 1))
    cov = detection_covariances(world, camera, CFG.noise)
    places = []
    for xyz in {tuple(np.round(w, 1)) for w, h in zip(world, in_hand) if not h}:
        rows_at = np.flatnonzero(np.linalg.norm(world - xyz, axis=1) < 0.1)
        if len(rows_at) >= 3:
            places.append(Place(world[rows_at].mean(axis=0), 1e-4 * np.eye(3), rows_at, frames[rows_at]))
    places.sort(key=lambda p: p.span[0])
    runs = place_chain(places, [], world[:, None, :], cov[:, None], np.full(len(rows), 0.8), frames, in_hand,
                       n_frames, CFG, 30.0)
    return places, runs


def test_the_chain_keeps_a_place_through_stray_matches_and_moves_it_after_a_carry():
    a, b, stray = np.array([1.0, 0.8, 2.0]), np.array([3.0, 0.8, 0.5]), np.array([0.0, 0.9, 4.0])
    rows = [(f, a, False) for f in range(30, 300, 6)]
    rows += [(f, stray, False) for f in (100, 103)]          # two persistent false matches elsewhere
    rows += [(f, np.array([1.5, 1.2, 1.5]) + f * 1e-3, True) for f in range(300, 360, 3)]  # carried
    rows += [(f, b, False) for f in range(380, 600, 6)]
    places, runs = chain_runs(sorted(rows, key=lambda r: r[0]))
    kinds = [r.place for r in runs]
    at_a = [i for i, p in enumerate(places) if np.linalg.norm(p.xyz - a) < 0.05][0]
    at_b = [i for i, p in enumerate(places) if np.linalg.norm(p.xyz - b) < 0.05][0]
    assert kinds == [at_a, -1, at_b]
    assert runs[0].start == 0 and abs(runs[0].end - 300) <= 6 and abs(runs[2].start - 360) <= 21
    assert runs[0].confidence > 0.9 and runs[2].confidence > 0.9


def test_a_carry_that_ends_out_of_sight_is_unseen_not_back_at_its_start():
    a = np.array([1.0, 0.8, 2.0])
    rows = [(f, a, False) for f in range(30, 300, 6)]
    rows += [(f, np.array([1.5, 1.2, 1.5]) + f * 1e-3, True) for f in range(300, 360, 3)]
    _, runs = chain_runs(rows)
    assert [r.place for r in runs] == [0, -1, -2]
    assert UNSEEN_STATE != ANY_CARRY and stand_state(0) == 2


def test_the_posterior_survives_emissions_that_underflow_in_probabilities():
    """Frame 1's only reachable state is e^-800 as likely as an unreachable one: the scaled
    forward-backward underflows there, the log-space one does not, and the answer is certain."""
    with np.errstate(divide="ignore"):
        log_a, log_prior = np.log(np.array([[1.0, 0.0], [0.5, 0.5]])), np.log(np.array([1.0, 0.0]))
    log_e = np.zeros((5, 2))
    log_e[1] = [-800.0, 0.0]
    assert np.allclose(posterior(log_e, log_a, log_prior), [[1.0, 0.0]] * 5)
    assert list(map_path(log_e, log_a, log_prior)) == [0] * 5


def test_a_move_nobody_saw_happens_where_the_new_place_becomes_the_more_probable():
    """Seen at place 0 until frame 99, at place 1 from frame 400: every frame of the gap scores the
    same as the moment of the move, and the path moves where the posteriors cross (the middle,
    as the move is as likely at any frame), not where rounding put it."""
    cfg = GraphConfig(negative_evidence=False)
    log_a, log_prior = transitions(2, cfg, 30.0)
    log_e = np.zeros((500, n_states(2)))
    seen = np.zeros(500, bool)
    seen[:100:5] = seen[400::5] = True
    log_e[:100:5, stand_state(1)] = log_e[400::5, stand_state(0)] = -20.0
    log_e[seen, :2] = log_e[seen, 3::2] = -20.0      # neither carried nor at an unseen place
    post = posterior(log_e, log_a, log_prior)
    path = unseen_moves_at_crossing(map_path(log_e, log_a, log_prior), seen, post)
    moved = int(np.flatnonzero(path == stand_state(1))[0])
    assert set(path[:moved]) == {stand_state(0)} and set(path[moved:]) == {stand_state(1)}
    assert abs(moved - 248) <= 5
    assert post[moved - 1, stand_state(0)] >= post[moved - 1, stand_state(1)]
    assert post[moved, stand_state(1)] > post[moved, stand_state(0)]


def test_the_posterior_is_the_log_space_one_on_a_long_chain_with_forbidden_moves():
    rng = np.random.default_rng(4)
    t_len, s = 400, 7
    a = rng.dirichlet(np.ones(s) * 0.3, size=s)
    a[0, 3] = 0.0                                           # a forbidden transition
    with np.errstate(divide="ignore"):
        log_a = np.log(a / a.sum(axis=1, keepdims=True))
    log_e = np.where(rng.random((t_len, s)) < 0.1, rng.normal(-40, 20, (t_len, s)), 0.0)
    log_prior = np.log(rng.dirichlet(np.ones(s)))
    fwd = np.empty((t_len, s))
    bwd = np.zeros((t_len, s))
    fwd[0] = log_prior + log_e[0]
    for t in range(1, t_len):
        fwd[t] = np.logaddexp.reduce(fwd[t - 1][:, None] + log_a, axis=0) + log_e[t]
    for t in range(t_len - 2, -1, -1):
        bwd[t] = np.logaddexp.reduce(log_a + (log_e[t + 1] + bwd[t + 1])[None, :], axis=1)
    g = fwd + bwd
    slow = np.exp(g - np.logaddexp.reduce(g, axis=1)[:, None])
    fast = posterior(log_e, log_a, log_prior)
    assert np.allclose(fast, slow, atol=1e-9) and np.allclose(fast.sum(axis=1), 1.0)


def test_the_fast_geometry_helpers_give_numpys_bits():
    """The online tracker's closed-form Mahalanobis length and its one-sort median replace numpy's
    general routines on its hot path; answers must not move by a bit (the tracker's tie-breaks and
    records depend on them)."""
    from egograph.track.places import mahalanobis2_3d
    from egograph.track.segments import median0

    rng = np.random.default_rng(3)
    a = rng.normal(size=(40, 5, 3, 3))
    total = a @ np.swapaxes(a, -1, -2) + 0.1 * np.eye(3)
    d = rng.normal(size=(40, 5, 3))
    q, det = mahalanobis2_3d(d, total)
    assert q.shape == det.shape == (40, 5)
    np.testing.assert_allclose(q, np.einsum("...i,...i->...", d, np.linalg.solve(total, d[..., None])[..., 0]),
                               rtol=1e-9)
    np.testing.assert_allclose(det, np.linalg.det(total), rtol=1e-9)
    q1, _ = mahalanobis2_3d(d[:, :1], total[:1, :1])  # broadcast against one covariance
    np.testing.assert_allclose(q1[:, 0], np.einsum("mi,mi->m", d[:, 0], np.linalg.solve(total[0, 0], d[:, 0].T).T),
                               rtol=1e-9)
    for n in (1, 2, 7, 8, 33):
        for dtype in (np.float64, np.float32):
            x = rng.normal(size=(n, 3)).astype(dtype)
            x[n // 2] = x[0]  # ties
            for arr in (x, x[:, 0]):
                got, want = median0(arr), np.median(arr, axis=0)
                assert np.asarray(got).dtype == np.asarray(want).dtype
                assert np.array_equal(got, want)
    assert np.isnan(median0(np.array([1.0, np.nan, 2.0])))
