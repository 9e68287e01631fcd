"""The IT3DEgo baselines: memory (last position) and the constant-velocity Kalman filter."""

from __future__ import annotations

import numpy as np
import pytest

from egograph.core.config import describe, load_config
from egograph.geometry.observations import Observations
from egograph.io.detections import read_results_dir, write_results_dir
from egograph.track.baselines import TRACKERS, kalman_tracker, memory_tracker
from egograph.track.config import BaselineConfig

T0 = 133_456_789_012_345_678  # an 18-digit HoloLens timestamp (100 ns ticks)
FRAME = 333_333               # 30 fps in ticks
CFG = BaselineConfig()


def make_obs(ts, instance, world, score=None) -> Observations:
    """Observations from columns; ``world`` rows of NaN are unlifted detections."""
    ts = np.asarray(ts, np.int64)
    m = len(ts)
    world = np.asarray(world, np.float64).reshape(m, 3)
    score = np.full(m, 0.9, np.float32) if score is None else np.asarray(score, np.float32)
    lifted = np.isfinite(world).all(axis=1)
    return Observations(
        timestamps=ts,
        frame=np.arange(m, dtype=np.int32),
        instance=np.asarray(instance, np.int32),
        score=score,
        box=np.zeros((m, 4), np.float32),
        world=world,
        camera=np.zeros((m, 3)),
        range_m=np.ones(m, np.float32),
        candidates=world[:, None, :].copy(),
        chosen=np.where(lifted, 0, -1).astype(np.int8),
        n_pixels=np.ones(m, np.int32),
    )


def stamps(n: int) -> np.ndarray:
    return T0 + FRAME * np.arange(n, dtype=np.int64)


def seconds(ts) -> np.ndarray:
    return (np.asarray(ts, np.int64) - T0) / 1e7


def track(out, ts, instance=0) -> np.ndarray:
    """(n, 3) output positions of ``instance`` at ``ts`` (each frame must have one)."""
    rows = []
    for t in ts:
        (p,) = [p for p in out[int(t)] if p.instance == instance]
        rows.append(p.xyz)
    return np.array(rows)


def as_table(out) -> dict[int, list[tuple]]:
    return {ts: [(p.instance, p.xyz, p.score) for p in preds] for ts, preds in out.items()}


# --------------------------------------------------------------------------- config and registry


def test_config_knobs_documented_and_loadable():
    rows = {key: doc for key, _, doc in describe(BaselineConfig())}
    assert set(rows) == {
        "score_threshold", "kf_reset_distance_m", "kf_process_noise", "kf_measurement_noise_m",
        "kf_initial_velocity_std",
    }
    assert all(rows.values())
    assert CFG.score_threshold == 0.6 and CFG.kf_reset_distance_m == 0.15
    cfg = load_config(BaselineConfig, overrides=["kf_reset_distance_m=0.3"])
    assert cfg.kf_reset_distance_m == 0.3


def test_registry():
    assert TRACKERS == {"memory": memory_tracker, "kf": kalman_tracker}


# --------------------------------------------------------------------------- memory baseline


def test_memory_keeps_last_position_and_lists_all_seen_instances():
    ts = stamps(5)
    obs = make_obs(
        [ts[1], ts[2], ts[3]],
        [0, 1, 0],
        [[1, 2, 3], [4, 5, 6], [7, 8, 9]],
        [0.7, 0.8, 0.95],
    )
    out = memory_tracker(obs, ts, CFG)
    assert list(out) == [int(t) for t in ts]
    assert as_table(out) == {
        int(ts[0]): [],
        int(ts[1]): [(0, (1.0, 2.0, 3.0), 0.7)],
        int(ts[2]): [(0, (1.0, 2.0, 3.0), 0.7), (1, (4.0, 5.0, 6.0), 0.8)],
        int(ts[3]): [(0, (7.0, 8.0, 9.0), 0.95), (1, (4.0, 5.0, 6.0), 0.8)],
        int(ts[4]): [(0, (7.0, 8.0, 9.0), 0.95), (1, (4.0, 5.0, 6.0), 0.8)],
    }


def test_memory_threshold_is_inclusive():
    ts = stamps(3)
    obs = make_obs([ts[0], ts[1], ts[2]], [0, 0, 0], [[1, 0, 0], [2, 0, 0], [3, 0, 0]], [0.6, 0.59, 0.5999])
    out = memory_tracker(obs, ts, CFG)
    assert [track(out, [t])[0, 0] for t in ts] == [1.0, 1.0, 1.0]
    assert out[int(ts[0])][0].score == 0.6  # written back as "0.6", not float32 noise
    # the threshold is a knob
    out = memory_tracker(obs, ts, BaselineConfig(score_threshold=0.59))
    assert track(out, ts)[:, 0].tolist() == [1.0, 2.0, 3.0]


def test_memory_last_observation_in_a_frame_wins():
    ts = stamps(2)
    obs = make_obs(
        [ts[0], ts[0], ts[0], ts[1]],
        [0, 1, 0, 1],
        [[1, 0, 0], [5, 0, 0], [2, 0, 0], [6, 0, 0]],
        [0.99, 0.9, 0.61, 0.9],
    )
    out = memory_tracker(obs, ts, CFG)
    assert as_table(out)[int(ts[0])] == [(0, (2.0, 0.0, 0.0), 0.61), (1, (5.0, 0.0, 0.0), 0.9)]
    # a rejected later row does not override an accepted earlier one
    obs = make_obs([ts[0], ts[0]], [0, 0], [[1, 0, 0], [2, 0, 0]], [0.9, 0.3])
    assert as_table(memory_tracker(obs, ts, CFG))[int(ts[0])] == [(0, (1.0, 0.0, 0.0), 0.9)]


def test_memory_ignores_unlifted_rows():
    ts = stamps(3)
    nan = [np.nan] * 3
    obs = make_obs([ts[0], ts[1], ts[2], ts[2]], [0, 0, 1, 0], [[1, 0, 0], nan, nan, [np.nan, 1, 1]], [0.9] * 4)
    out = memory_tracker(obs, ts, CFG)
    assert as_table(out) == {int(t): [(0, (1.0, 0.0, 0.0), 0.9)] for t in ts}


def test_every_timestamp_gets_an_entry_in_numeric_order():
    # 9_999_999_999 < 10_000_000_000 numerically but not lexically
    ts = [10_000_000_000, 9_999_999_999, 10_000_333_333, 9_999_999_999]
    obs = make_obs([10_000_000_000, 9_999_999_999], [0, 0], [[2, 0, 0], [1, 0, 0]])
    for tracker in TRACKERS.values():
        out = tracker(obs, ts, CFG)
        assert list(out) == [9_999_999_999, 10_000_000_000, 10_000_333_333]
        assert all(len(v) == 1 for v in out.values())
    empty = {int(t): [] for t in stamps(4)}
    for tracker in TRACKERS.values():
        assert tracker(Observations.empty(), stamps(4), CFG) == empty
        late = make_obs([stamps(4)[3]], [2], [[1, 1, 1]])
        out = tracker(late, stamps(4), CFG)
        assert [len(v) for v in out.values()] == [0, 0, 0, 1]


def test_observations_off_the_frame_grid_are_refused():
    obs = make_obs([T0 + 1], [0], [[1, 2, 3]])
    for tracker in TRACKERS.values():
        with pytest.raises(ValueError, match="not PV frames"):
            tracker(obs, stamps(3), CFG)


# --------------------------------------------------------------------------- Kalman filter


def test_kf_converges_on_noiseless_constant_velocity_track():
    ts = stamps(60)
    v = np.array([0.3, -0.1, 0.2])  # m/s
    truth = np.array([1.0, 1.5, 2.0]) + seconds(ts)[:, None] * v
    out = kalman_tracker(make_obs(ts, np.zeros(60), truth), ts, CFG)
    err = np.linalg.norm(track(out, ts) - truth, axis=1)
    assert err[0] == 0.0
    assert np.all(err[20:] < 1e-3)
    assert err[-1] < 1e-4


def test_kf_predicts_through_gaps_with_real_dt():
    # irregular spacing (dropped frames), then a 0.5 s gap with no detection
    ts = T0 + np.cumsum(np.tile([FRAME, 2 * FRAME, 5 * FRAME, FRAME], 15)).astype(np.int64)
    gap = ts[-1] + 5_000_000
    v = np.array([0.2, 0.0, -0.1])
    truth = np.array([0.5, 1.0, 1.5]) + seconds(ts)[:, None] * v
    out = kalman_tracker(make_obs(ts, np.zeros(len(ts)), truth), [*ts, gap], CFG)
    assert np.linalg.norm(track(out, ts[-20:]) - truth[-20:], axis=1).max() < 1e-3
    # the output between measurements is the constant-velocity prediction at the frame's time
    expected = truth[-1] + 0.5 * v
    assert np.linalg.norm(track(out, [gap])[0] - expected) < 1e-3
    assert out[int(gap)][0].score == 0.9


def test_kf_smooths_stationary_noise():
    rng = np.random.default_rng(1)
    n = 600
    ts = stamps(n)
    centre = np.array([1.0, 1.5, 2.0])
    # per-axis sigma 5 cm (3D RMS 8.7 cm): the 0.15 m reset fires on the noise tail,
    # which limits the gain; and 3D RMS 5 cm, where resets are rare.
    for sigma, ratio in [(0.05, 0.8), (0.05 / np.sqrt(3), 0.5)]:
        z = centre + rng.normal(0.0, sigma, (n, 3))
        out = kalman_tracker(make_obs(ts, np.zeros(n), z), ts, CFG)
        rms_est = np.sqrt(np.mean(np.sum((track(out, ts)[30:] - centre) ** 2, axis=1)))
        rms_raw = np.sqrt(np.mean(np.sum((z[30:] - centre) ** 2, axis=1)))
        assert rms_est < ratio * rms_raw


def test_kf_resets_on_a_large_jump():
    n = 40
    ts = stamps(n + 1)
    t = seconds(ts[:n])
    pos = np.array([0.0, 1.0, 0.0]) + t[:, None] * np.array([0.1, 0.0, 0.0])
    pos[30:] = [2.0, 1.0, 0.5]  # moved by more than 1 m
    out = kalman_tracker(make_obs(ts[:n], np.zeros(n), pos), ts, CFG)
    est = track(out, ts)
    assert np.array_equal(est[30], pos[30])           # at once, exactly at the measurement
    assert np.allclose(est[31:n], pos[30], atol=1e-9)  # restarted with zero velocity
    assert np.allclose(est[n], pos[30], atol=1e-9)     # and predicts it stays


def test_kf_small_step_is_fused_not_reset():
    n = 150
    ts = stamps(n)
    pos = np.tile([1.0, 1.0, 1.0], (n, 1))
    pos[40:, 0] += 0.1  # below the 0.15 m reset distance
    out = kalman_tracker(make_obs(ts, np.zeros(n), pos), ts, CFG)
    est = track(out, ts)
    assert 1.0 < est[40, 0] < 1.09  # partially moved: an update, not a restart
    assert abs(est[-1, 0] - 1.1) < 5e-3  # and it gets there
    # with a smaller reset distance the same step restarts the filter
    out = kalman_tracker(make_obs(ts, np.zeros(n), pos), ts, BaselineConfig(kf_reset_distance_m=0.05))
    assert track(out, [ts[40]])[0, 0] == 1.1


def test_kf_instances_are_independent_and_score_is_last_accepted():
    ts = stamps(4)
    obs = make_obs(
        [ts[0], ts[1], ts[1], ts[2]],
        [0, 1, 0, 0],
        [[0, 0, 0], [5, 5, 5], [0.01, 0, 0], [0.02, 0, 0]],
        [0.7, 0.8, 0.9, 0.3],  # the last one is rejected
    )
    out = kalman_tracker(obs, ts, CFG)
    assert [len(out[int(t)]) for t in ts] == [1, 2, 2, 2]
    assert [p.score for p in out[int(ts[3])]] == [0.9, 0.8]
    assert track(out, [ts[3]], instance=1)[0].tolist() == [5.0, 5.0, 5.0]


# --------------------------------------------------------------------------- both


def noisy_two_instance_obs(seed: int = 3):
    rng = np.random.default_rng(seed)
    ts = stamps(90)
    keep = rng.random((90, 2)) < 0.6
    rows = [(t, i) for t, k in zip(ts, keep) for i in (0, 1) if k[i]]
    world = np.array([[i, 1.0, 2.0] for _, i in rows]) + rng.normal(0, 0.03, (len(rows), 3))
    world[rng.random(len(rows)) < 0.1] = np.nan
    score = rng.uniform(0.4, 1.0, len(rows))
    return ts, make_obs([r[0] for r in rows], [r[1] for r in rows], world, score)


@pytest.mark.parametrize("name", sorted(TRACKERS))
def test_results_round_trip_through_files(tmp_path, name):
    ts, obs = noisy_two_instance_obs()
    out = TRACKERS[name](obs, ts, CFG)
    write_results_dir(tmp_path / name, out, ts)
    assert len(list((tmp_path / name).iterdir())) == len(ts)
    assert read_results_dir(tmp_path / name, ts) == out


@pytest.mark.parametrize("name", sorted(TRACKERS))
def test_deterministic_and_independent_of_row_order_across_frames(name):
    ts, obs = noisy_two_instance_obs()
    first = TRACKERS[name](obs, ts, CFG)
    assert TRACKERS[name](obs, ts, CFG) == first
    # frames given in reverse order, rows within a frame kept in order: same result
    by_frame = np.lexsort((np.arange(len(obs)), -obs.timestamps))
    assert TRACKERS[name](obs.select(by_frame), ts, CFG) == first
