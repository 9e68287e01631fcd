"""The IT3DEgo paper's two baseline trackers: last-position memory and a Kalman filter.

Both read lifted 3D observations (:class:`~egograph.geometry.observations.Observations`,
world frame, metres) and return, for every PV frame timestamp (100 ns ticks), the
predictions to write with :func:`~egograph.io.detections.write_results_dir`.

Common input rules (those of the public reference code):

* frames are processed in numeric timestamp order;
* an observation is *accepted* when it was lifted (finite ``world``) and its score is
  at least ``score_threshold`` (cosine similarity, 0.6 in the paper);
* when one instance has several accepted observations in one frame, the last one in
  row (file) order wins;
* a frame lists every instance seen so far, and nothing for an instance before its
  first accepted observation.

Time between frames is taken from the timestamps (seconds = ticks / 1e7), so dropped
frames and irregular spacing are handled with the real interval, not an assumed 30 fps.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from egograph.core.types import Prediction
from egograph.core.units import TICKS_PER_SECOND
from egograph.geometry.observations import Observations
from egograph.track.config import BaselineConfig

# One frame's accepted measurements: instance -> (world position (3,) metres, score).
FrameMeasurements = dict[int, tuple[np.ndarray, float]]




# --------------------------------------------------------------------------- shared input handling


def _frame_times(timestamps: Sequence[int]) -> list[int]:
    """Unique PV frame timestamps (ticks) as Python ints, in numeric order."""
    return sorted({int(t) for t in timestamps})


def _accepted_measurements(obs: Observations, stamps: list[int], threshold: float) -> list[FrameMeasurements]:
    """Per frame of ``stamps``, the accepted measurements (last row of an instance wins).

    Observations at a timestamp that is not a PV frame are refused rather than dropped,
    as :func:`~egograph.io.detections.write_results_dir` refuses such predictions.
    """
    per_frame: list[FrameMeasurements] = [{} for _ in stamps]
    if len(obs) == 0:
        return per_frame
    # Compare in float32: scores are stored as float32, and float32(0.6) < 0.6 would
    # otherwise depend on how the threshold's decimal happens to round.
    score = np.asarray(obs.score, dtype=np.float32)
    accepted = obs.valid & (score >= np.float32(threshold))
    rows = np.flatnonzero(accepted)
    ts = np.asarray(obs.timestamps, dtype=np.int64)[rows]
    where = {t: k for k, t in enumerate(stamps)}
    stray = sorted({int(t) for t in ts} - where.keys())
    if stray:
        raise ValueError(f"observations at {len(stray)} timestamps that are not PV frames, e.g. {stray[0]}")
    # Rows stay in their original order, so a later row of the same instance and frame
    # overwrites an earlier one ("last in file order wins").
    for row, t in zip(rows, ts):
        per_frame[where[int(t)]][int(obs.instance[row])] = (
            np.asarray(obs.world[row], dtype=np.float64),
            _score_value(score[row]),
        )
    return per_frame


def _score_value(score: np.float32) -> float:
    """The shortest decimal that reads back to the same float32, as a float.

    Scores come from text at float32 precision; without this a file's ``0.6`` would be
    written back as ``0.6000000238418579``.
    """
    return float(np.format_float_positional(np.float32(score), unique=True, trim="-"))


def _predictions(positions: dict[int, np.ndarray], scores: dict[int, float]) -> list[Prediction]:
    """One :class:`Prediction` per instance, in instance order (deterministic files)."""
    return [Prediction(i, tuple(float(v) for v in positions[i]), scores[i]) for i in sorted(positions)]


# --------------------------------------------------------------------------- memory baseline


def memory_tracker(obs: Observations, timestamps: Sequence[int], cfg: BaselineConfig) -> dict[int, list[Prediction]]:
    """The paper's memory baseline: every instance stays where it was last seen.

    For each PV frame (timestamps in 100 ns ticks, numeric order) the accepted
    observations update ``memory[instance] = (world position, score)``; the frame then
    lists every instance seen so far at its remembered world position (metres) with
    the score of that observation. Every timestamp is a key of the result; frames
    before any accepted observation map to ``[]``.
    """
    stamps = _frame_times(timestamps)
    per_frame = _accepted_measurements(obs, stamps, cfg.score_threshold)
    positions: dict[int, np.ndarray] = {}
    scores: dict[int, float] = {}
    out: dict[int, list[Prediction]] = {}
    for ts, meas in zip(stamps, per_frame):
        for inst, (xyz, score) in meas.items():
            positions[inst] = xyz
            scores[inst] = score
        out[ts] = _predictions(positions, scores)
    return out


# --------------------------------------------------------------------------- Kalman filter baseline
#
# State x = [position (3), velocity (3)], world frame, metres and m/s; P its 6x6
# covariance. The three axes share one 2x2 (position, velocity) structure, so every
# matrix is a 2x2 block Kronecker-multiplied with the 3x3 identity.

_I3 = np.eye(3)
_H = np.hstack([_I3, np.zeros((3, 3))])  # measures the position part of the state


@dataclass
class _CVFilter:
    """One instance's constant-velocity filter."""

    x: np.ndarray  # (6,) position (m) and velocity (m/s), world frame
    P: np.ndarray  # (6, 6) covariance
    t: float       # time of the state, seconds
    score: float   # score of the last accepted measurement


def _transition(dt: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """State transition F and process noise Q over ``dt`` seconds.

    Q is the exact discretisation of white-noise acceleration with spectral density
    ``q`` (m^2/s^3); it composes, so predicting over dt1 then dt2 equals predicting
    over dt1 + dt2 — frame spacing does not change the model.
    """
    F = np.kron(np.array([[1.0, dt], [0.0, 1.0]]), _I3)
    Q = q * np.kron(np.array([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]]), _I3)
    return F, Q


def _start(z: np.ndarray, t: float, score: float, cfg: BaselineConfig) -> _CVFilter:
    """A filter at measurement ``z`` (metres) with zero velocity and the initial covariance."""
    P = np.kron(np.diag([cfg.kf_measurement_noise_m**2, cfg.kf_initial_velocity_std**2]), _I3)
    return _CVFilter(np.concatenate([z, np.zeros(3)]), P, t, score)


def _predict(f: _CVFilter, t: float, q: float) -> None:
    """Propagate ``f`` to time ``t`` (seconds) in place."""
    F, Q = _transition(t - f.t, q)
    f.x = F @ f.x
    f.P = F @ f.P @ F.T + Q
    f.t = t


def _update(f: _CVFilter, z: np.ndarray, sigma: float) -> None:
    """Fuse a 3D position measurement ``z`` (metres, per-axis std ``sigma``) in place."""
    R = sigma**2 * _I3
    S = _H @ f.P @ _H.T + R
    K = np.linalg.solve(S, _H @ f.P).T  # P H^T S^-1, with S and P symmetric
    f.x = f.x + K @ (z - _H @ f.x)
    # Joseph form keeps P symmetric positive definite over thousands of updates.
    A = np.eye(6) - K @ _H
    P = A @ f.P @ A.T + K @ R @ K.T
    f.P = 0.5 * (P + P.T)


def kalman_tracker(obs: Observations, timestamps: Sequence[int], cfg: BaselineConfig) -> dict[int, list[Prediction]]:
    """The paper's Kalman-filter baseline: one constant-velocity filter per instance.

    A filter starts at an instance's first accepted observation (zero velocity,
    initial covariance from ``kf_measurement_noise_m`` and ``kf_initial_velocity_std``).
    At every PV frame each started filter is predicted to the frame's time (seconds =
    ticks / 1e7, so irregular spacing uses the real interval). With an accepted
    measurement of the instance in that frame: if it lies more than
    ``kf_reset_distance_m`` from the predicted position the filter restarts at the
    measurement (the object was moved, or the old track was a false match), otherwise
    the measurement is fused.

    Output between measurements: the *prediction*. Every frame lists, for every
    started filter, its current position estimate — the posterior after the frame's
    update when there was a measurement, else the constant-velocity prediction to the
    frame's time. This is what "the KF predicts through gaps" means and what the
    paper's filter outputs (its current estimate). Holding the last posterior instead
    would make the filter a smoothed memory baseline and discard the velocity it
    estimated. The cost is drift: a residual velocity is extrapolated through the gap
    (e.g. 2 cm/s over a 10 s gap moves the output 20 cm); for the mostly stationary
    objects of IT3DEgo the estimated velocity decays towards zero while the object is
    observed at rest, which keeps that drift small.

    The score of a prediction is the score of the instance's last accepted
    measurement. Every timestamp is a key of the result; frames before an instance's
    first accepted observation have no prediction for it.
    """
    stamps = _frame_times(timestamps)
    per_frame = _accepted_measurements(obs, stamps, cfg.score_threshold)
    filters: dict[int, _CVFilter] = {}
    out: dict[int, list[Prediction]] = {}
    for ts, meas in zip(stamps, per_frame):
        # Seconds since the first frame: 18-digit tick counts divided directly would
        # keep only microsecond precision in a float64.
        t = (ts - stamps[0]) / TICKS_PER_SECOND
        for f in filters.values():
            _predict(f, t, cfg.kf_process_noise)
        for inst, (z, score) in meas.items():
            f = filters.get(inst)
            if f is None or np.linalg.norm(z - f.x[:3]) > cfg.kf_reset_distance_m:
                filters[inst] = _start(z, t, score, cfg)
            else:
                _update(f, z, cfg.kf_measurement_noise_m)
                f.score = score
        out[ts] = _predictions({i: f.x[:3] for i, f in filters.items()}, {i: f.score for i, f in filters.items()})
    return out


Tracker = Callable[[Observations, Sequence[int], BaselineConfig], dict[int, list[Prediction]]]

TRACKERS: dict[str, Tracker] = {"memory": memory_tracker, "kf": kalman_tracker}
