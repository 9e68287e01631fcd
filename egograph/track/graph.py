"""The factor-graph tracker: landmarks per chunk, switchable motion breaks, places, the place chain.

Per instance (camera poses fixed, so instances are independent graphs until their places meet):

1. *Observations*: lifted detections (world frame, metres) with score >= ``score_threshold``.
2. *Chunks*: the instance's timeline is cut on a fixed grid of ``chunk_s`` seconds; each
   non-empty chunk k gets a landmark ``L_k`` (Point3).
3. *Detection factors*: a robust, range-dependent ``PriorFactorPoint3`` per observation
   (:mod:`egograph.track.detection_factor`).
4. *Motion breaks*: consecutive landmarks are joined by a switchable zero-motion factor
   (:mod:`egograph.track.switchable`), or its DCS closed form (``switches: dcs``).
5. *Solve*: batch Levenberg-Marquardt (GTSAM), with the AHAT alias re-chosen per observation
   and the graph solved again; the detection noise scale is fitted from the chain's stands
   (:mod:`egograph.track.noise_scale`) and everything solved again until it settles.
6. *Segments*: runs of chunks whose switches stay on (:mod:`egograph.track.segments`).
7. *Places* (:mod:`egograph.track.places`): every segment at one location pooled across the
   whole recording and re-solved as one landmark (so sparse or broken evidence adds up), with a
   surface under it unless well supported; a place another instance holds with more support at
   the same time is that instance's (a look-alike).
8. *Place chain*: a hidden Markov chain over the PV frames (standing at a place, carried,
   standing where it was never seen) with robust detection likelihoods (false matches persist at
   look-alikes' and clutter's places) and pick-up / carry / put-down rates; its most probable
   state sequence says where the instance stands at every frame, and the posterior of each run
   its confidence.
9. *Intervals*: each run at a place is a :class:`~egograph.core.types.PositionInterval` at the
   place's centre, covariance the GTSAM marginal plus ``covariance_floor_m`` squared, cut where
   depth shows the place empty (negative evidence, :mod:`egograph.track.negative`); a run unseen
   after a carry is an interval where the hand last held the object; nothing while carried. An
   instance's first interval reaches back to the first frame when the chain starts at its place
   (``backfilled``).

``graph-causal`` runs the same place chain online (:mod:`egograph.track.online`, replayed by
:mod:`egograph.track.causal`). Modules: :mod:`egograph.track.chain` (steps 2-5),
:mod:`egograph.track.segments` (6), :mod:`egograph.track.places` (7-8); this one runs them per
instance over a recording (:func:`graph_tracker`).
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from egograph.core.types import PositionInterval, TrackResult
from egograph.core.units import TICKS_PER_SECOND
from egograph.geometry.observations import Observations
from egograph.track.answers import confidences, gc_paused, offline_answers, operating_point, predictions
from egograph.track.causal import causal_tracker
from egograph.track.chain import chunk_index, solve_instance_offline
from egograph.track.config import GraphConfig
from egograph.track.detection_factor import detection_covariances
from egograph.track.intervals import per_frame_predictions
from egograph.track.noise_scale import refit, stand_residuals
from egograph.track.places import (
    candidate_covariances,
    candidate_places,
    chance_of_place,
    carried_rows,
    claim_places,
    place_chain_states,
    place_reality,
)
from egograph.track.segments import (
    InstanceSolution,
    NegativeFn,
    SupportFn,
    held_in_mid_air,
    make_segment,
    point_factors,
    segments_from_switches,
    with_floor,
)


def _track_instance_offline(instance: int, obs: Observations, t_frames: np.ndarray, cfg: GraphConfig,
                            support: SupportFn | None = None) -> InstanceSolution:
    """Offline chain solve of one instance's observations (already filtered and time-sorted): the
    segments of the chain (``solution.chain_segments``) and its stands (``solution.segments``, what
    the detection noise-scale fit reads). Places and intervals come later, across instances
    (:func:`_place_intervals`).

    Each noise-scale round solves from the chunk medians again, not from the last round's solution:
    the answer is then that of the reported scale alone (the same as a run at that fixed scale), and
    a start from a solution at a larger scale kept some of its smoothness (on 6 device-world tuning
    recordings it cost MVPE 2.1 points of R@0.25, for 0.3 s less at 10,000 frames)."""
    if len(obs) == 0:
        return InstanceSolution(instance, [])
    t_s = (obs.timestamps - t_frames[0]) / TICKS_PER_SECOND
    chunk = chunk_index(t_s, cfg.chunk_s)
    cov = detection_covariances(obs.world, obs.camera, cfg.noise)
    cands = obs.candidates if cfg.alias_rounds > 0 and obs.candidates.shape[1] > 1 else None
    world, _, switches = solve_instance_offline(obs.world, cov, cands, chunk, cfg)
    if cands is not None:
        cov = detection_covariances(world, obs.camera, cfg.noise)
    rows_of = segments_from_switches(chunk, switches, cfg.break_below)
    # every row's robust-point factor made once, for its segment and later its places; no marginal
    # covariance for a chain segment, which nothing reads (places compute their own). A start from
    # the chain's landmarks instead of the median took 60 % fewer iterations but moved a place on
    # one of 16 recordings (a robust centre is not convex): not taken.
    factors = point_factors(world, cov, cfg)
    segs = [make_segment(rows, world, cov, cfg, camera=obs.camera, range_m=obs.range_m, marginal=False,
                         factors=factors) for rows in rows_of]
    for seg in segs:
        seg.stationary = seg.stationary and not held_in_mid_air(seg, obs.range_m, cfg, support)
    sol = InstanceSolution(instance, [], switches, len(obs), int(chunk.max()) + 1)
    sol.segments = [seg for seg in segs if seg.stationary]
    sol.world, sol.cov, sol.frames = world, cov, obs.frame.astype(np.int64)
    sol.camera, sol.range_m, sol.chain_segments, sol.score = obs.camera, obs.range_m, segs, obs.score
    sol.candidates = obs.candidates if obs.candidates.shape[1] > 1 else world[:, None, :]
    sol.point_factors = factors
    return sol


def _fps(t_frames: np.ndarray) -> float:
    """Frame rate of the PV timestamps (ticks), 30 when it cannot be told."""
    if len(t_frames) < 2 or t_frames[-1] <= t_frames[0]:
        return 30.0
    return (len(t_frames) - 1) / ((t_frames[-1] - t_frames[0]) / TICKS_PER_SECOND)


def _hand_position(sol: InstanceSolution, before: int, cfg: GraphConfig) -> np.ndarray | None:
    """Where the hand last held the object before frame ``before``: the median of the last three
    detections within ``carry_range_m`` of the camera (world, metres), or None."""
    near = np.flatnonzero((sol.range_m <= cfg.carry_range_m) & (sol.frames < before))
    return np.median(sol.world[near[-3:]], axis=0) if len(near) else None


def _place_intervals(sol: InstanceSolution, runs, t_frames: np.ndarray, cfg: GraphConfig,
                     negative: NegativeFn | None, reality: list[float]) -> list[PositionInterval]:
    """The place chain's runs as position intervals: a run at a place is an interval there (cut
    where depth shows the place empty after its last detection in the run), its confidence the
    run's posterior times the place's reality (:func:`egograph.track.places.place_reality`); a run
    UNSEEN after a carry is an interval where the hand last held the object; carries report
    nothing."""
    out: list[PositionInterval] = []
    for g, run in enumerate(runs):
        nxt = runs[g + 1] if g + 1 < len(runs) else None
        ended_by = "end" if nxt is None else ("detection" if nxt.place >= 0 else "carried")
        start, end = run.start, run.end
        if run.place >= 0:
            place = sol.places[run.place]
            mine = place.frames[(place.frames >= start) & (place.frames <= end)]
            first = int(mine.min()) if len(mine) else None
            last = int(mine.max()) if len(mine) else start - 1
            if negative is not None and last < end:
                gone = negative(sol.instance, place.xyz, last + 1, end + 1)
                if gone is not None and gone > start:
                    end, ended_by = gone - 1, "negative"
                elif gone is not None:
                    continue  # seen empty from the start of the run on: nothing to report
            xyz, cov = place.xyz, with_floor(place.covariance, cfg)
            n_obs = len(mine)
            seen = (first if first is not None else int(place.frames[np.argmin(np.abs(place.frames - start))]),
                    last if first is not None else int(place.frames[np.argmin(np.abs(place.frames - end))]))
            extra = {"start_frame": start, "end_frame": end, "place": run.place, "place_inliers": place.n_inliers,
                     "place_reality": round(reality[run.place], 4)}
            backfilled = start == 0 and (first is None or first > 0)
            confidence = run.confidence * reality[run.place]
        elif run.place == -2:
            hand = _hand_position(sol, start, cfg)
            if hand is None:
                continue
            xyz, cov = hand, (cfg.put_down_sigma_m**2 + cfg.covariance_floor_m**2) * np.eye(3)
            n_obs, seen, backfilled = 0, (start, start), False
            extra = {"start_frame": start, "end_frame": end, "unseen": True}
            confidence = run.confidence * 0.5  # where the hand last held it: near, not at, the place
        else:
            continue
        out.append(PositionInterval(
            instance=int(sol.instance), t_start=int(t_frames[start]), t_end=int(t_frames[end]),
            xyz=tuple(float(v) for v in xyz), covariance=np.asarray(cov).tolist(), n_observations=int(n_obs),
            confidence=float(confidence), first_seen=int(t_frames[seen[0]]), last_seen=int(t_frames[seen[1]]),
            backfilled=bool(backfilled), ended_by=ended_by, extra=extra,
        ))
    return out


def _places_and_chains(solutions: list[InstanceSolution], t_frames: np.ndarray, cfg: GraphConfig,
                       negative: NegativeFn | None, support: SupportFn | None) -> int:
    """Every instance's places, claimed across instances, and its place chain as intervals
    (:mod:`egograph.track.places`); fills ``sol.places``, ``sol.segments`` (the places as stands)
    and ``sol.intervals``. Returns the number of places another instance claimed."""
    found = {}
    for sol in solutions:
        if sol.world is None:
            continue
        found[sol.instance] = candidate_places(sol.chain_segments, sol.world, sol.cov, sol.camera, sol.range_m,
                                               sol.frames, cfg, support, sol.point_factors)
    kept = claim_places(found, cfg.exclusion_radius_m)
    reality = place_reality(kept, {s.instance: np.asarray(s.score, float) for s in solutions if s.world is not None})
    for sol in solutions:  # and not a coincidence of scattered false matches
        if sol.world is not None:
            reality[sol.instance] = [r * (1.0 - chance_of_place(p, sol.cov, len(sol.world), cfg))
                                     for r, p in zip(reality[sol.instance], kept[sol.instance])]
    fps = _fps(t_frames)
    for sol in solutions:
        if sol.world is None:
            continue
        sol.places = kept[sol.instance]
        others = [p for j, ps in found.items() if j != sol.instance for p in ps]
        runs, path, post = place_chain_states(
            sol.places, others, sol.candidates, candidate_covariances(sol.candidates, sol.camera, cfg), sol.score,
            sol.frames, carried_rows([seg.rows for seg in sol.chain_segments], sol.world, sol.camera, sol.range_m, cfg),
            len(t_frames), cfg, fps)
        sol.segments, sol.runs = [p.as_segment() for p in sol.places], runs
        sol.intervals = _place_intervals(sol, runs, t_frames, cfg, negative, reality[sol.instance])
        if cfg.answers.every_frame:
            sol.answers = offline_answers(sol, path, post, reality[sol.instance], len(t_frames), cfg)
    return sum(len(found[i]) - len(kept[i]) for i in found)


def _select_instance_rows(obs: Observations, instance: int, threshold: float) -> Observations:
    score = np.asarray(obs.score, dtype=np.float32)
    mask = (obs.instance == instance) & obs.valid & (score >= np.float32(threshold))
    sub = obs.select(mask)
    order = np.argsort(sub.timestamps, kind="stable")
    return sub.select(order)


def _frames_and_ids(obs: Observations, timestamps: Sequence[int],
                    instances: Sequence[int] | None = None) -> tuple[np.ndarray, list[int]]:
    """(the sorted PV frame ticks, the instances to track: ``instances`` or every one observed)."""
    t_frames = np.asarray(sorted(int(t) for t in timestamps), dtype=np.int64)
    return t_frames, (sorted({int(i) for i in obs.instance}) if instances is None else list(instances))


def _solve_offline(obs: Observations, ids: list[int], t_frames: np.ndarray, cfg: GraphConfig, negative, support,
                   progress: bool) -> tuple[list[InstanceSolution], list[float]]:
    """Every instance of ``ids`` solved offline on its rows of ``obs`` above graph.score_threshold
    -> (solutions in the order of ``ids``, the detection noise scale of each solve).

    With ``cfg.noise.auto_scale`` the first solve uses ``auto_start``; the scale is then estimated
    from the solve's own stands (:mod:`egograph.track.noise_scale`) and everything solved again,
    until the estimate moves by less than 5 % or after ``auto_rounds`` re-solves; the solutions
    returned are those of the last scale. Without it, one solve at ``scale``.
    """
    subs = [(inst, _select_instance_rows(obs, inst, cfg.score_threshold)) for inst in ids]
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
            solutions.append(_track_instance_offline(inst, sub, t_frames, c, support))
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


def offline_noise_scale(obs: Observations, timestamps: Sequence[int], cfg: GraphConfig) -> tuple[float, int]:
    """The detection noise scale (graph.noise) the offline graph fits on ``obs``, and the number of
    stand residuals of its last solve that the fit read (:func:`_solve_offline`; no places, chains or
    answers: what ``egograph smooth`` needs to pick its calibration, egograph.track.smooth)."""
    t_frames, ids = _frames_and_ids(obs, timestamps)
    solutions, scales = _solve_offline(obs, ids, t_frames, cfg, None, None, False)
    return scales[-1], len(stand_residuals(solutions))


def graph_tracker(obs: Observations, timestamps: Sequence[int], cfg: GraphConfig, *, causal: bool = False,
                  negative: NegativeFn | None = None, support: SupportFn | None = None,
                  instances: Sequence[int] | None = None, lag_s: float | None = None,
                  progress: bool = False, calibration_scale: float | None = None) -> TrackResult:
    """Run the graph tracker over a recording's observations.

    ``timestamps``: the PV frames (ticks); observations must sit on them (``obs.frame`` is
    the index into the sorted timestamps). ``negative``: optional negative-evidence test
    (:class:`egograph.track.negative.NegativeEvidence`); ``support``: optional test that a
    stand rests on the scene (``NegativeEvidence.supported``). Returns intervals, the per-frame
    predictions in the reference format and metadata for the output JSON. ``causal``: frame by
    frame through :class:`egograph.track.online.OnlineTracker`, each answer using the frames up
    to ``lag_s`` seconds after it (default ``cfg.lag_s``). ``calibration_scale``: the detection noise
    scale that picks the calibration of the offline answers (``graph.answers.noisy_scale``; default
    the scale fitted here; ``egograph smooth`` passes that of the distinct sightings).
    """
    t_frames, ids = _frames_and_ids(obs, timestamps, instances)
    if causal:
        return _causal_result(obs, t_frames, cfg, ids, lag_s, negative, support)
    solutions, scales = _solve_offline(obs, ids, t_frames, cfg, negative, support, progress)
    cfg = dataclasses.replace(cfg, noise=dataclasses.replace(cfg.noise, scale=scales[-1]))
    n_excluded = _places_and_chains(solutions, t_frames, cfg, negative, support)
    if calibration_scale is None:
        calibration_scale = scales[-1]
    intervals = sorted((iv for s in solutions for iv in s.intervals), key=lambda iv: (iv.instance, iv.t_start))
    answers = None
    if not cfg.answers.every_frame:
        pieces = [p for s in solutions for p in (s.pieces if s.pieces is not None else s.intervals)]
        per_frame = per_frame_predictions(pieces, t_frames)
    else:  # every frame answered, calibrated; the files hold the operating point
        with gc_paused():
            answers = {t: [] for t in t_frames.tolist()}
            for s in solutions:
                if s.answers is not None:
                    xyz, raw, kind = s.answers
                    predictions(s.instance, xyz, confidences(raw, kind, cfg.answers, "offline", calibration_scale),
                                t_frames, answers)
            if ids != sorted(ids):  # the solutions come in the order of ``instances``
                answers = {t: sorted(p, key=lambda q: q.instance) for t, p in answers.items()}
            per_frame = operating_point(answers, cfg.answers)
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
        "n_places": int(sum(len(s.places or ()) for s in solutions)),
        "n_places_claimed": n_excluded,
        "noise_scale": scales[-1],
        "noise_scale_rounds": scales,
        "calibration_scale": calibration_scale,
    }
    if answers is not None:
        metadata["min_confidence"] = cfg.answers.min_confidence
    return TrackResult(per_frame=per_frame, intervals=intervals, metadata=metadata, solutions=solutions,
                       answers=answers)


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
        "n_places": int(sum(len(s.places or []) for s in solutions)),
        "noise_scale": scales[-1],
        "noise_scale_rounds": scales,
    }
    answers = None
    if cfg.answers.every_frame:  # every frame answered, calibrated; the files hold the operating point
        answers = {t: sorted(p, key=lambda q: q.instance) for t, p in per_frame.items()}
        per_frame = operating_point(answers, cfg.answers, causal=True)
        metadata["min_confidence"] = cfg.answers.causal_min_confidence
    return TrackResult(per_frame=per_frame, intervals=intervals, metadata=metadata, solutions=solutions,
                       answers=answers)
