"""``egograph smooth``: another tracker's per-frame 3D results turned into intervals by the graph.

Each per-frame prediction ``instance x y z score`` (reference results format, world frame,
metres) becomes an observation seen from that frame's PV camera centre, and the graph
tracker runs on them unchanged: chunks, switchable breaks, stands and carries, intervals.
This is the "+graph" row beside the paper's "+KF": the same input, a different smoother.

Scores are kept, but every prediction is used (the other tracker already thresholded its
detections). Trackers that repeat a remembered position on every frame feed the graph the
same point many times; the robust centre is unaffected, and the break placement reads the
time of the first prediction at a new place.
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


def smooth_predictions(rec, per_frame: Mapping[int, Sequence[Prediction]], cfg, causal: bool = False,
                       progress: bool = False):
    """Another tracker's per-frame predictions on recording ``rec`` -> the graph's
    :class:`~egograph.core.types.TrackResult`. Every prediction is used (``score_threshold``
    0: the other tracker already thresholded its detections) and there are no alias candidates."""
    from egograph.track.graph import graph_tracker

    obs = predictions_to_observations(per_frame, rec.timestamps, rec.pv_poses, rec.pv_valid)
    g = dataclasses.replace(cfg, score_threshold=0.0, alias_rounds=0,  # and its own calibration of confidence
                            answers=dataclasses.replace(cfg.answers, offline_calibration=cfg.answers.smooth_calibration,
                                                        noisy_offline_calibration=cfg.answers.noisy_smooth_calibration,
                                                        offline_kinds=cfg.answers.smooth_kinds,
                                                        noisy_offline_kinds=cfg.answers.noisy_smooth_kinds))
    return graph_tracker(obs, rec.timestamps, g, causal=causal, progress=progress)
