"""The factor-graph tracker: landmarks per chunk, switchable motion breaks, intervals with covariance.

Per instance (camera poses fixed, so instances are independent graphs):

1. *Observations*: lifted detections (world frame, metres) with score >= ``score_threshold``.
2. *Chunks*: the instance's timeline is cut on a fixed grid of ``chunk_s`` seconds; each
   non-empty chunk k gets a landmark ``L_k`` (Point3).
3. *Detection factors*: a robust, range-dependent ``PriorFactorPoint3`` per observation
   (:mod:`egograph.track.detection_factor`).
4. *Motion breaks*: consecutive landmarks are joined by a switchable zero-motion factor
   (:mod:`egograph.track.switchable`), or its DCS closed form (``switches: dcs``).
5. *Solve*: batch Levenberg-Marquardt (offline) or iSAM2 chunk by chunk (causal: a
   frame's prediction uses only observations up to that frame).
6. *Alias*: after a first solve each observation takes the AHAT alias candidate nearest
   its landmark, and the graph is solved again.
7. *Segments*: runs of chunks whose switches stay on. A segment whose robust centre
   explains most of its observations (inlier share) with enough of them is *stationary*;
   the rest (carried objects, scattered false matches) are *dynamic* and predict nothing.
   Stationary segments at the same place (within ``merge_radius_m``) separated only by
   weaker segments merge: the weaker ones were false matches.
8. *Intervals*: each stationary segment is re-solved as one landmark; its covariance is
   the GTSAM marginal plus ``covariance_floor_m`` squared (errors shared by all its
   observations: pose drift, surface-to-centre bias). Time extent policy:

   * an interval lasts from its first supporting detection until the first evidence that
     the object left: a detection elsewhere, or negative evidence
     (:mod:`egograph.track.negative`): the place in view, depth showing it empty;
   * after a carried (dynamic) stretch, the new interval starts right after the last
     carried detection (the object was put down then), at most ``backfill_max_s`` early;
   * offline only, an instance's first interval is back-filled to the recording's first
     frame (marked ``backfilled`` in the output).

Modules: :mod:`egograph.track.chain` (steps 2-6: keys, chunks, the chain's graph and its offline
solve), :mod:`egograph.track.segments` (steps 7-8: stands, carries, merging, confusions,
intervals), :mod:`egograph.track.online` (the iSAM2 solve, frame by frame; :mod:`egograph.track.causal`
replays a recording through it); this one runs them per instance
over a recording (:func:`graph_tracker`).
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from egograph.core.types import TrackResult
from egograph.core.units import TICKS_PER_SECOND
from egograph.geometry.observations import Observations
from egograph.track.causal import causal_tracker
from egograph.track.chain import chunk_index, solve_instance_offline
from egograph.track.config import GraphConfig
from egograph.track.detection_factor import detection_covariances
from egograph.track.intervals import per_frame_predictions
from egograph.track.noise_scale import refit, stand_residuals
from egograph.track.segments import (
    InstanceSolution,
    NegativeFn,
    SupportFn,
    classify_moving,
    drop_unrelated_carries,
    exclude_confusions,
    held_in_mid_air,
    intervals_from_segments,
    make_segment,
    merge_segments,
    segments_from_switches,
)


def _track_instance_offline(instance: int, obs: Observations, t_frames: np.ndarray, cfg: GraphConfig,
                            negative: NegativeFn | None = None, support: SupportFn | None = None) -> InstanceSolution:
    """Offline solve of one instance's observations (already filtered and time-sorted):
    segments (``solution.segments``) and the intervals placed from them."""
    if len(obs) == 0:
        return InstanceSolution(instance, [])
    t_s = (obs.timestamps - t_frames[0]) / TICKS_PER_SECOND
    chunk = chunk_index(t_s, cfg.chunk_s)
    cov = detection_covariances(obs.world, obs.camera, cfg.noise)
    cands = obs.candidates if cfg.alias_rounds > 0 and obs.candidates.shape[1] > 1 else None
    world, _, switches = solve_instance_offline(obs.world, cov, cands, chunk, cfg)
    if cands is not None:
        cov = detection_covariances(world, obs.camera, cfg.noise)
    segs = [make_segment(rows, world, cov, cfg, camera=obs.camera, range_m=obs.range_m)
            for rows in segments_from_switches(chunk, switches, cfg.break_below)]
    for seg in segs:
        seg.stationary = seg.stationary and not held_in_mid_air(seg, obs.range_m, cfg, support)
    frames = obs.frame.astype(np.int64)
    segs = drop_unrelated_carries(classify_moving(segs, obs.range_m, cfg), world, cfg)
    segs = merge_segments(segs, world, cov, cfg, instance, frames, negative)
    sol = InstanceSolution(instance, [], switches, len(obs), int(chunk.max()) + 1)
    sol.segments, sol.world, sol.cov, sol.frames = segs, world, cov, frames
    sol.intervals = intervals_from_segments(instance, segs, t_frames, sol.frames, cfg, backfill_start=True,
                                            negative=negative)
    return sol


def _select_instance_rows(obs: Observations, instance: int, threshold: float) -> Observations:
    score = np.asarray(obs.score, dtype=np.float32)
    mask = (obs.instance == instance) & obs.valid & (score >= np.float32(threshold))
    sub = obs.select(mask)
    order = np.argsort(sub.timestamps, kind="stable")
    return sub.select(order)


def _solve_offline(subs, t_frames: np.ndarray, cfg: GraphConfig, negative, support,
                   progress: bool) -> tuple[list[InstanceSolution], list[float]]:
    """Every instance solved offline -> (solutions, the detection noise scale of each solve).

    With ``cfg.noise.auto_scale`` the first solve uses ``auto_start``; the scale is then estimated
    from the solve's own stands (:mod:`egograph.track.noise_scale`) and everything solved again,
    until the estimate moves by less than 5 % or after ``auto_rounds`` re-solves; the solutions
    returned are those of the last scale. Without it, one solve at ``scale``.
    """
    noise = cfg.noise
    scales = [float(noise.auto_start if noise.auto_scale else noise.scale)]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(subs), desc="graph", unit="instance")
    while True:
        c = dataclasses.replace(cfg, noise=dataclasses.replace(noise, scale=scales[-1]))
        solutions = []
        for inst, sub in subs:
            solutions.append(_track_instance_offline(inst, sub, t_frames, c, negative, support))
            if bar is not None:
                bar.update()
        if not noise.auto_scale or len(scales) > noise.auto_rounds:
            break
        new = refit(stand_residuals(solutions), scales[-1], noise, cfg.inlier_chi2)
        if new is None:
            break
        scales.append(new)
        if bar is not None:
            bar.reset()
    if bar is not None:
        bar.close()
    return solutions, scales


def graph_tracker(obs: Observations, timestamps: Sequence[int], cfg: GraphConfig, *, causal: bool = False,
                  negative: NegativeFn | None = None, support: SupportFn | None = None,
                  instances: Sequence[int] | None = None, lag_s: float | None = None,
                  progress: bool = False) -> TrackResult:
    """Run the graph tracker over a recording's observations.

    ``timestamps``: the PV frames (ticks); observations must sit on them (``obs.frame`` is
    the index into the sorted timestamps). ``negative``: optional negative-evidence test
    (:class:`egograph.track.negative.NegativeEvidence`); ``support``: optional test that a
    stand rests on the scene (``NegativeEvidence.supported``). Returns intervals, the per-frame
    predictions in the reference format and metadata for the output JSON. ``causal``: frame by
    frame through :class:`egograph.track.online.OnlineTracker`, each answer using the frames up
    to ``lag_s`` seconds after it (default ``cfg.lag_s``).
    """
    t_frames = np.asarray(sorted(int(t) for t in timestamps), dtype=np.int64)
    ids = sorted({int(i) for i in obs.instance}) if instances is None else list(instances)
    if causal:
        return _causal_result(obs, t_frames, cfg, ids, lag_s, negative, support)
    subs = [(inst, _select_instance_rows(obs, inst, cfg.score_threshold)) for inst in ids]
    solutions, scales = _solve_offline(subs, t_frames, cfg, negative, support, progress)
    cfg = dataclasses.replace(cfg, noise=dataclasses.replace(cfg.noise, scale=scales[-1]))
    n_excluded = 0
    if not causal and cfg.exclusion_radius_m > 0:
        n_excluded = exclude_confusions(solutions, t_frames, cfg, negative)
    intervals = sorted((iv for s in solutions for iv in s.intervals), key=lambda iv: (iv.instance, iv.t_start))
    pieces = [p for s in solutions for p in (s.pieces if s.pieces is not None else s.intervals)]
    per_frame = per_frame_predictions(pieces, t_frames)
    metadata = {
        "tracker": "graph-causal" if causal else "graph",
        "backfilled": (not causal),
        "backfill_note": ("offline: an instance's first interval is extended back to the first frame of the "
                          "recording (intervals with backfilled=true)") if not causal else "causal: no back-fill",
        "switches": cfg.switches,
        "negative_evidence": negative is not None,
        "support_test": support is not None,
        "n_observations": int(sum(s.n_observations for s in solutions)),
        "n_chunks": int(sum(s.n_chunks for s in solutions)),
        "n_stands_excluded": n_excluded,
        "noise_scale": scales[-1],
        "noise_scale_rounds": scales,
    }
    return TrackResult(per_frame=per_frame, intervals=intervals, metadata=metadata, solutions=solutions)


def _causal_result(obs: Observations, t_frames: np.ndarray, cfg: GraphConfig, ids: list[int], lag_s: float | None,
                   negative: NegativeFn | None, support: SupportFn | None) -> TrackResult:
    """The causal/lagged mode of :func:`graph_tracker` (:mod:`egograph.track.causal`)."""
    lag = cfg.lag_s if lag_s is None else float(lag_s)
    per_frame, intervals, solutions, scales = causal_tracker(obs, t_frames, cfg, ids, lag_s=lag, negative=negative,
                                                             support=support)
    metadata = {
        "tracker": "graph-causal",
        "lag_s": lag,
        "backfilled": False,
        "backfill_note": "causal: no back-fill" if lag == 0 else
                         f"lagged: answers revised with the evidence of up to {lag:g} s later",
        "switches": cfg.switches,
        "negative_evidence": negative is not None,
        "support_test": support is not None,
        "n_observations": int(sum(s.n_observations for s in solutions)),
        "n_chunks": int(sum(s.n_chunks for s in solutions)),
        "n_stands_excluded": 0,
        "noise_scale": scales[-1],
        "noise_scale_rounds": scales,
    }
    return TrackResult(per_frame=per_frame, intervals=intervals, metadata=metadata, solutions=solutions)
