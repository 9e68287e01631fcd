"""``egograph smooth``: another tracker's per-frame 3D results turned into intervals by the graph.

Each per-frame prediction ``instance x y z score`` (reference results format, world frame,
metres) becomes an observation seen from that frame's PV camera centre, and the graph
tracker runs on them unchanged: chunks, switchable breaks, stands and carries, intervals.
This is the "+graph" row beside the paper's "+KF": the same input, a different smoother.

Scores are kept, but every prediction is used (the other tracker already thresholded its
detections). Trackers that repeat a remembered position on every frame feed the graph the
same point many times; the robust centre is unaffected, and the break placement reads the
time of the first prediction at a new place. The copies do hold the fitted noise scale at its
floor, so the answers' calibration is picked by the scale of the distinct sightings
(:func:`sightings_scale`).
"""

from __future__ import annotations

import dataclasses
from typing import Mapping, Sequence

import numpy as np

from egograph.core.types import Prediction
from egograph.geometry.hl2ss import camera_center
from egograph.geometry.observations import Observations


def predictions_to_observations(per_frame: Mapping[int, Sequence[Prediction]], timestamps: Sequence[int],
                                pv_poses: np.ndarray, pv_valid: np.ndarray) -> Observations:
    """Per-frame predictions (ticks -> predictions) -> :class:`Observations` (score 1,
    camera = PV camera centre of the frame; frames with an invalid pose are skipped)."""
    ts = np.asarray(sorted(int(t) for t in timestamps), dtype=np.int64)
    index = {int(t): i for i, t in enumerate(ts)}
    rows = [(index[int(t)], p) for t, preds in per_frame.items() if int(t) in index for p in preds]
    rows = [(i, p) for i, p in rows if pv_valid[i]]
    if not rows:
        return Observations.empty()
    frame = np.array([i for i, _ in rows], dtype=np.int32)
    world = np.array([p.xyz for _, p in rows], dtype=np.float64)
    cam = camera_center(np.asarray(pv_poses)[frame])
    m = len(rows)
    return Observations(
        timestamps=ts[frame], frame=frame, instance=np.array([p.instance for _, p in rows], dtype=np.int32),
        score=np.ones(m, np.float32), box=np.full((m, 4), np.nan, np.float32), world=world, camera=cam,
        range_m=np.linalg.norm(world - cam, axis=1).astype(np.float32), candidates=world[:, None, :].copy(),
        chosen=np.zeros(m, np.int8), n_pixels=np.zeros(m, np.int32),
    )


def distinct_sightings(obs: Observations) -> Observations:
    """The rows of ``obs`` whose position differs from the same instance's previous row (in frame
    order): a tracker's sightings, without the copies of a remembered one that it repeats."""
    order = np.lexsort((obs.frame, obs.instance))
    inst, xyz = obs.instance[order], obs.world[order]
    new = np.ones(len(order), bool)
    new[1:] = (inst[1:] != inst[:-1]) | np.any(xyz[1:] != xyz[:-1], axis=1)
    return obs.select(np.sort(order[new]))


def sightings_scale(obs: Observations, timestamps: Sequence[int], cfg) -> float | None:
    """The detection noise scale (graph.noise) the graph fits on the distinct sightings of
    ``obs`` (:func:`distinct_sightings`), or None when no position repeats, the fit is off or it had
    too few residuals to fit on.

    Why: it picks the calibration of the smoothed answers (``graph.answers.noisy_scale``). Fitted on
    every prediction, the memory baseline's copies of its last sighting, all at one distance from
    their stand's centre, fill the median of the residuals and hold the scale at its floor whatever
    the front-end: on the tuning recordings SVOE and MVPE alike fitted 0.5, so one calibration
    served answers that were right 41 % (SVOE) and 88 % (MVPE) of the time. The smoothing itself
    keeps the scale fitted on every prediction: solved at the sightings' scale, it lost precision
    and recall on tuning recordings 4-6 (SVOE P/R@0.25 40.6/34.2 -> 37.9/31.2)."""
    from egograph.track.graph import offline_noise_scale

    seen = distinct_sightings(obs)
    if not cfg.noise.auto_scale or len(seen) == len(obs) or len(seen) == 0:
        return None
    scale, n_residuals = offline_noise_scale(seen, timestamps, cfg)
    if n_residuals < cfg.noise.auto_min_residuals:
        return None   # (one position per stand, e.g. a tracker answering with intervals: nothing to fit)
    return scale


def smooth_predictions(rec, per_frame: Mapping[int, Sequence[Prediction]], cfg, causal: bool = False,
                       progress: bool = False):
    """Another tracker's per-frame predictions on recording ``rec`` -> the graph's
    :class:`~egograph.core.types.TrackResult`. Every prediction is used (``score_threshold``
    0: the other tracker already thresholded its detections) and there are no alias candidates.
    Offline, the answers' calibration is picked by the scale of the distinct sightings
    (:func:`sightings_scale`)."""
    from egograph.track.graph import graph_tracker

    obs = predictions_to_observations(per_frame, rec.timestamps, rec.pv_poses, rec.pv_valid)
    g = dataclasses.replace(cfg, score_threshold=0.0, alias_rounds=0,  # and its own calibration of confidence
                            answers=dataclasses.replace(cfg.answers, offline_calibration=cfg.answers.smooth_calibration,
                                                        noisy_offline_calibration=cfg.answers.noisy_smooth_calibration,
                                                        offline_kinds=cfg.answers.smooth_kinds,
                                                        noisy_offline_kinds=cfg.answers.noisy_smooth_kinds))
    if causal:
        return graph_tracker(obs, rec.timestamps, g, causal=True, progress=progress)
    return graph_tracker(obs, rec.timestamps, g, progress=progress,
                         calibration_scale=sightings_scale(obs, rec.timestamps, g))
