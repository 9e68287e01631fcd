"""Position intervals: per-frame predictions, JSON round trip, bad files; smoothing another tracker's results."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from egograph.core.errors import InputError
from egograph.core.types import PositionInterval, Prediction, predictions_of
from egograph.track.config import AnswersConfig, GraphConfig
from egograph.track.graph import graph_tracker
from egograph.track.intervals import per_frame_predictions, read_intervals_json, write_intervals_json
from egograph.track.smooth import distinct_sightings, predictions_to_observations, smooth_predictions

T0, FRAME = 133_400_000_000_000_000, 333_333
TS = T0 + FRAME * np.arange(100, dtype=np.int64)


def iv(instance, f0, f1, xyz=(1.0, 2.0, 3.0)) -> PositionInterval:
    return PositionInterval(instance, int(TS[f0]), int(TS[f1]), xyz, (0.01 * np.eye(3)).tolist(), 5, 0.8)


def test_per_frame_predictions_cover_exactly_the_interval_frames():
    out = per_frame_predictions([iv(0, 10, 19), iv(2, 15, 99, (0.5, 0.5, 0.5))], TS)
    assert len(out) == 100
    assert out[int(TS[9])] == []
    assert [p.instance for p in out[int(TS[10])]] == [0]
    assert [p.instance for p in out[int(TS[17])]] == [0, 2]
    assert [p.instance for p in out[int(TS[20])]] == [2]
    assert out[int(TS[12])][0] == Prediction(0, (1.0, 2.0, 3.0), 0.8)


def test_json_round_trip(tmp_path):
    rows = [iv(0, 0, 50), iv(1, 20, 99)]
    write_intervals_json(tmp_path / "i.json", rows, {"tracker": "graph"})
    back, meta = read_intervals_json(tmp_path / "i.json")
    assert meta == {"tracker": "graph"}
    assert [(r.instance, r.t_start, r.t_end, r.xyz) for r in back] == [(r.instance, r.t_start, r.t_end, r.xyz) for r in rows]
    assert back[0].sigma_m == pytest.approx(0.1)


def test_bad_interval_file_names_the_file_and_entry(tmp_path):
    p = tmp_path / "i.json"
    p.write_text('{"intervals": [{"instance": 0}]}')
    with pytest.raises(InputError, match=r"i\.json.*interval 0"):
        read_intervals_json(p)
    p.write_text("{not json")
    with pytest.raises(InputError, match=r"i\.json:1: not valid JSON"):
        read_intervals_json(p)


def test_smoothing_noisy_per_frame_results_gives_one_interval_per_stand():
    rng = np.random.default_rng(0)
    per_frame = {}
    for f, t in enumerate(TS):
        base = np.array([1.0, 0.9, 2.0]) if f < 60 else np.array([3.0, 0.8, 1.0])
        per_frame[int(t)] = [Prediction(0, tuple(base + 0.03 * rng.standard_normal(3)), 0.7)]
    poses = np.tile(np.eye(4), (100, 1, 1))
    obs = predictions_to_observations(per_frame, TS, poses, np.ones(100, bool))
    assert len(obs) == 100 and np.all(obs.score == 1)
    cfg = GraphConfig(score_threshold=0.0, alias_rounds=0, negative_evidence=False)
    res = graph_tracker(obs, TS, cfg)
    assert len(res.intervals) == 2
    a, b = res.intervals
    assert np.linalg.norm(np.subtract(a.xyz, [1.0, 0.9, 2.0])) < 0.02
    assert abs((a.t_end - T0) / FRAME - 59) <= 2 and abs((b.t_start - T0) / FRAME - 60) <= 2


def _memory_like(scatter_m: float, n: int = 900, every: int = 6, seed: int = 0) -> dict:
    """Per-frame results of a tracker that repeats its last sighting (the memory baseline): one object
    at a place, sighted every ``every`` frames with ``scatter_m`` metres of noise per axis."""
    rng = np.random.default_rng(seed)
    ts = T0 + FRAME * np.arange(n, dtype=np.int64)
    out, last = {}, None
    for f, t in enumerate(ts):
        if f % every == 0:
            last = tuple(np.array([1.0, 0.9, 2.0]) + scatter_m * rng.standard_normal(3))
        out[int(t)] = [Prediction(0, last, 0.7)]
    return out


@pytest.mark.parametrize("scatter_m, noisy", [(0.1, True), (0.005, False)])
def test_smoothing_a_tracker_that_repeats_its_sightings_calibrates_by_their_scatter(scatter_m, noisy):
    """The memory baseline's copies of its last sighting hold the fitted noise scale at its floor
    whatever the front-end; the answers' calibration is picked by the scale of the distinct
    sightings instead: widely scattered sightings take the noisy knots, tight ones the clean. The
    smoothing itself (the solve's scale, the intervals) is that of every prediction."""
    n = 1800
    per_frame = _memory_like(scatter_m, n, every=10)
    ts = np.array(sorted(per_frame), dtype=np.int64)
    rec = SimpleNamespace(timestamps=ts, pv_poses=np.tile(np.eye(4), (n, 1, 1)), pv_valid=np.ones(n, bool))
    obs = predictions_to_observations(per_frame, ts, rec.pv_poses, rec.pv_valid)
    assert len(distinct_sightings(obs)) == n // 10
    clean, noisy_conf = 0.2, 0.7   # every answer's confidence under each set of knots and kinds
    answers = dataclasses.replace(AnswersConfig(), smooth_calibration=[[0.0, clean], [1.0, clean]],
                                  noisy_smooth_calibration=[[0.0, noisy_conf], [1.0, noisy_conf]],
                                  smooth_kinds=[clean] * 5, noisy_smooth_kinds=[noisy_conf] * 5)
    cfg = GraphConfig(negative_evidence=False, answers=answers)
    res = smooth_predictions(rec, per_frame, cfg)
    assert res.metadata["noise_scale"] < cfg.answers.noisy_scale          # the copies' scale: the floor
    assert (res.metadata["calibration_scale"] >= cfg.answers.noisy_scale) == noisy
    scores = [p.score for t in ts for p in res.answers[int(t)]]
    assert len(scores) == n and np.allclose(scores, noisy_conf if noisy else clean)
    plain = graph_tracker(obs, ts, dataclasses.replace(cfg, score_threshold=0.0, alias_rounds=0))
    spans = [(i.t_start, i.t_end, i.xyz) for i in res.intervals]
    assert spans == [(i.t_start, i.t_end, i.xyz) for i in plain.intervals]


def test_predictions_made_at_once_equal_those_made_one_by_one():
    xyz = np.array([[1.0, 2.0, 3.0], [-0.5, 0.25, 1e-9], [4.0, 5.0, 6.0]])
    score = np.array([0.9, 0.0, 1.0], np.float32)
    many = predictions_of(np.int64(7), xyz, score)
    assert many == [Prediction(7, tuple(float(v) for v in row), float(s)) for row, s in zip(xyz, score)]
    assert all(type(p.instance) is int and type(p.score) is float and type(p.xyz[0]) is float for p in many)
    with pytest.raises(ValueError, match=r"row 1"):
        predictions_of(7, np.array([[1.0, 2.0, 3.0], [1.0, np.nan, 3.0]]), np.array([0.5, 0.5]))
    with pytest.raises(ValueError, match="negative"):
        predictions_of(-1, xyz, score)
