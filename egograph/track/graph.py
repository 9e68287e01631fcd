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
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import gtsam
import numpy as np

from egograph.core.types import PositionInterval, TrackResult
from egograph.core.units import TICKS_PER_SECOND
from egograph.geometry.observations import Observations
from egograph.track.config import GraphConfig
from egograph.track.detection_factor import add_detection_factors, detection_covariances, mahalanobis2
from egograph.track.intervals import per_frame_predictions
from egograph.track.switchable import (
    dcs_between,
    dcs_phi,
    dcs_switch_value,
    switch_clipped,
    switch_prior,
    switchable_between,
)

NegativeFn = Callable[[int, np.ndarray, int, int], "int | None"]
"""``(instance, xyz, frame_from, frame_to) -> first frame index in [from, to) whose depth
shows the place empty, or None`` (:class:`egograph.track.negative.NegativeEvidence`)."""

SupportFn = Callable[[np.ndarray], bool]
"""``xyz -> whether the scene can hold an object resting there`` (a surface close below)."""




@dataclass
class Segment:
    """A run of chunks of one instance joined by switches that stayed on."""

    rows: np.ndarray            # indices into the instance's observation arrays
    xyz: np.ndarray             # robust centre, world, metres
    covariance: np.ndarray      # 3x3 marginal covariance, m^2 (without the floor)
    inliers: np.ndarray         # bool per row
    stationary: bool = False
    carried: bool = False        # not stationary, with detections at hand range: the object was moving

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())


@dataclass
class InstanceSolution:
    instance: int
    intervals: list[PositionInterval]
    switches: np.ndarray = field(default_factory=lambda: np.zeros(0))  # effective switch per chunk boundary
    n_observations: int = 0
    n_chunks: int = 0
    segments: list[Segment] = field(default_factory=list)  # offline: stands and carries, in time order
    world: np.ndarray | None = None   # per observation, after alias re-choice, metres
    cov: np.ndarray | None = None     # per observation detection covariance, m^2
    frames: np.ndarray | None = None  # per observation PV frame index
    pieces: list[PositionInterval] | None = None  # causal: every report with its own position




# --------------------------------------------------------------------------- graph pieces


def L(k: int) -> int:
    return gtsam.symbol("l", k)


def S(k: int) -> int:
    return gtsam.symbol("s", k)


def chunk_index(t_s: np.ndarray, chunk_s: float) -> np.ndarray:
    """Chunk id 0..C-1 per observation (times sorted, seconds) on a fixed grid from the first."""
    grid = np.floor((t_s - t_s[0]) / chunk_s).astype(np.int64)
    _, idx = np.unique(grid, return_inverse=True)
    return idx.astype(np.int64)


def chunk_medians(world: np.ndarray, chunk: np.ndarray, n: int) -> np.ndarray:
    out = np.empty((n, 3))
    order = np.argsort(chunk, kind="stable")
    bounds = np.searchsorted(chunk[order], np.arange(n + 1))
    for k in range(n):
        out[k] = np.median(world[order[bounds[k]:bounds[k + 1]]], axis=0)
    return out


def add_break_factors(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, k: int, cfg: GraphConfig,
                      kind: str | None = None) -> None:
    """Motion-break factor between landmarks k-1 and k (and the switch variable, if any).
    ``kind``: 'switchable' | 'dcs' | 'still' (a plain Gaussian zero-motion factor); default cfg.switches."""
    kind = kind or cfg.switches
    if kind == "switchable":
        graph.add(switchable_between(L(k - 1), L(k), S(k), cfg.still_sigma_m))
        graph.add(switch_prior(S(k), cfg.switch_sigma))
        values.insert(S(k), np.array([1.0]))
    elif kind == "dcs":
        graph.add(dcs_between(L(k - 1), L(k), cfg.still_sigma_m, dcs_phi(cfg.switch_sigma)))
    elif kind == "still":
        graph.add(gtsam.BetweenFactorPoint3(L(k - 1), L(k), gtsam.Point3(0, 0, 0),
                                            gtsam.noiseModel.Isotropic.Sigma(3, cfg.still_sigma_m)))
    else:
        raise ValueError(f"unknown switches {kind!r}: 'switchable' or 'dcs'")


def instance_graph(world: np.ndarray, cov: np.ndarray, chunk: np.ndarray, init: np.ndarray,
                   cfg: GraphConfig, kinds: Sequence[str] | None = None) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """One instance's graph: a landmark per chunk (initial ``init``), break factors between
    consecutive ones (``kinds[k-1]`` per boundary, default cfg.switches), detection factors."""
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for k, p in enumerate(init):
        values.insert(L(k), gtsam.Point3(*p))
        if k:
            add_break_factors(graph, values, k, cfg, None if kinds is None else kinds[k - 1])
    add_detection_factors(graph, np.array([L(int(c)) for c in chunk]), world, cov, cfg.noise)
    return graph, values


def solve_lm(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, max_iterations: int) -> gtsam.Values:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-6)
    params.setAbsoluteErrorTol(1e-9)
    return gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()


def switch_values(result: gtsam.Values | None, landmarks: np.ndarray, cfg: GraphConfig) -> np.ndarray:
    """Effective switch (0-1) per chunk boundary k-1 -> k, index k-1."""
    n = len(landmarks)
    if cfg.switches == "switchable":
        return np.array([switch_clipped(result, S(k)) for k in range(1, n)])
    phi = dcs_phi(cfg.switch_sigma)
    return np.array([dcs_switch_value(landmarks[k - 1], landmarks[k], cfg.still_sigma_m, phi) for k in range(1, n)])


def landmarks_of(result: gtsam.Values, n: int) -> np.ndarray:
    return np.array([np.asarray(result.atPoint3(L(k))) for k in range(n)]).reshape(n, 3)


def nearest_candidates(candidates: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Per row, the alias candidate (NaN-padded (M, K, 3)) nearest ``target`` (M, 3)."""
    d = np.linalg.norm(candidates - target[:, None, :], axis=2)
    d = np.where(np.isfinite(d), d, np.inf)
    best = np.argmin(d, axis=1)
    return candidates[np.arange(len(candidates)), best]


def robust_point(world: np.ndarray, cov: np.ndarray, cfg: GraphConfig,
                 start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One landmark from many detections: robust LM solve and its marginal covariance (m^2)."""
    graph = gtsam.NonlinearFactorGraph()
    add_detection_factors(graph, np.full(len(world), L(0)), world, cov, cfg.noise)
    values = gtsam.Values()
    values.insert(L(0), gtsam.Point3(*(np.median(world, axis=0) if start is None else start)))
    result = solve_lm(graph, values, cfg.max_iterations)
    xyz = np.asarray(result.atPoint3(L(0)), dtype=float)
    try:
        covariance = gtsam.Marginals(graph, result).marginalCovariance(L(0))
    except RuntimeError:  # every detection down-weighted to nothing: fall back to the sample spread
        covariance = np.cov(world.T) + 1e-6 * np.eye(3) if len(world) > 1 else cov[0]
    return xyz, np.asarray(covariance)


def with_floor(covariance: np.ndarray, cfg: GraphConfig) -> np.ndarray:
    """A stand's reported covariance: its marginal plus ``covariance_floor_m`` squared (m^2)."""
    return np.asarray(covariance) + cfg.covariance_floor_m**2 * np.eye(3)


def fixed_interval_estimate(world: np.ndarray, camera: np.ndarray, cfg: GraphConfig) -> tuple[np.ndarray, np.ndarray]:
    """Position (metres) and reported covariance (m^2) of one interval fixed in time, from its
    detections ``world`` seen from ``camera`` (world frame): ``regt`` and the benchmark oracle."""
    xyz, c = robust_point(world, detection_covariances(world, camera, cfg.noise), cfg)
    return xyz, with_floor(c, cfg)


def make_segment(rows: np.ndarray, world: np.ndarray, cov: np.ndarray, cfg: GraphConfig,
                 start: np.ndarray | None = None, camera: np.ndarray | None = None,
                 range_m: np.ndarray | None = None) -> Segment:
    """Robust centre of the detections ``rows`` and whether they show a stand: enough inliers,
    a large enough inlier share, and not moving along with the camera (``camera`` given)."""
    xyz, c = robust_point(world[rows], cov[rows], cfg, start)
    inl = mahalanobis2(world[rows], xyz, cov[rows]) <= cfg.inlier_chi2
    seg = Segment(rows, xyz, c, inl)
    in_hand = camera is not None and range_m is not None and moves_with_camera(
        world[rows], camera[rows], range_m[rows], cfg)
    seg.stationary = is_stand(seg, in_hand, cfg)
    return seg


def is_stand(seg: Segment, in_hand: bool, cfg: GraphConfig) -> bool:
    """Enough inliers, a large enough inlier share, and not an object moving with the head."""
    return (seg.n_inliers >= cfg.min_observations and seg.n_inliers >= cfg.min_inlier_share * len(seg.rows)
            and not in_hand)


def moves_with_camera(world: np.ndarray, camera: np.ndarray, range_m: np.ndarray, cfg: GraphConfig) -> bool:
    """An object in hand is near the head (median range <= ``carry_range_m``) and keeps its
    offset to it while both move through the room: its world points spread (median, metres)
    more than ``carry_spread_m`` and more than its head-relative offsets do."""
    if np.median(range_m) > cfg.carry_range_m:
        return False
    spread_world = np.median(np.linalg.norm(world - np.median(world, axis=0), axis=1))
    rel = world - camera
    spread_rel = np.median(np.linalg.norm(rel - np.median(rel, axis=0), axis=1))
    return bool(spread_world > cfg.carry_spread_m and spread_world > spread_rel)


def drop_unrelated_carries(segs: list[Segment], world: np.ndarray, cfg: GraphConfig) -> list[Segment]:
    """A carry starts where the object stood (the pick-up) or ends where it next stands (the
    put-down). The carried segments between two stands form one carry: it is kept when its
    first detection lies within ``pickup_radius_m`` of the stand before it, or its last within
    that of the stand after it; a carry near neither is a look-alike being carried: dropped."""
    out: list[Segment] = []
    run: list[Segment] = []

    def flush(nxt: Segment | None) -> None:
        if run:
            prev = next((seg for seg in reversed(out) if seg.stationary), None)
            first, last = world[run[0].rows[0]], world[run[-1].rows[-1]]
            near_prev = prev is not None and np.linalg.norm(first - prev.xyz) <= cfg.pickup_radius_m
            near_next = nxt is not None and np.linalg.norm(last - nxt.xyz) <= cfg.pickup_radius_m
            if near_prev or near_next:
                out.extend(run)
            run.clear()

    for seg in segs:
        if seg.stationary:
            flush(seg)
            out.append(seg)
        else:
            run.append(seg)
    flush(None)
    return out


def held_in_mid_air(seg: Segment, range_m: np.ndarray, cfg: GraphConfig, support: SupportFn | None) -> bool:
    """A hand holding an object still looks like a stand in the world; but it is seen only from
    close by (median range <= ``carry_range_m``) and nothing in the scene mesh holds it up. Both
    must hold: HoloLens meshes have holes, and objects are looked at closely before a pick-up."""
    if support is None or np.median(range_m[seg.rows]) > cfg.carry_range_m:
        return False
    return not support(seg.xyz)


def classify_moving(segs: list[Segment], range_m: np.ndarray, cfg: GraphConfig) -> list[Segment]:
    """Mark carries among the non-stationary segments and drop the rest (scattered false
    matches: they neither hold a place nor show the object moving)."""
    out = []
    for seg in segs:
        if not seg.stationary:
            seg.carried = int((range_m[seg.rows] <= cfg.carry_range_m).sum()) >= cfg.min_carry_observations
            if not seg.carried:
                continue
        out.append(seg)
    return out


def _merge_pair(segs: list[Segment], radius_m: float, apart: Callable[[Segment, Segment], bool]) -> tuple[int, int] | None:
    """First pair (a, b) of stationary segments at the same place whose in-between
    stationary segments are all weaker (fewer inliers) than both, and not kept ``apart``."""
    stat = [i for i, s in enumerate(segs) if s.stationary]
    for j, a in enumerate(stat):
        for b in stat[j + 1:]:
            sa, sb = segs[a], segs[b]
            if np.linalg.norm(sa.xyz - sb.xyz) <= radius_m:
                if apart(sa, sb):
                    break
                return a, b
            if sb.n_inliers >= sa.n_inliers:
                break  # a stronger stand in between: the object really moved
    return None


def merge_segments(segs: list[Segment], world: np.ndarray, cov: np.ndarray, cfg: GraphConfig,
                   instance: int = -1, frames: np.ndarray | None = None,
                   negative: NegativeFn | None = None) -> list[Segment]:
    """Merge stationary segments at the same place (within ``merge_radius_m``) when every
    stationary segment between them is weaker: those were false matches (a look-alike seen, or
    carried nearby, while the object stood still), or the object was put back where it stood
    (then the frames in hand are reported too: the price of not splitting a stand at every
    look-alike). With negative evidence, two stands between which the place was seen empty
    stay apart (that switch is off)."""
    def apart(sa: Segment, sb: Segment) -> bool:
        if negative is None or frames is None:
            return False
        last = int(frames[sa.rows[sa.inliers]].max())
        first = int(frames[sb.rows[sb.inliers]].min())
        return first > last + 1 and negative(instance, (sa.xyz + sb.xyz) / 2, last + 1, first) is not None

    while (pair := _merge_pair(segs, cfg.merge_radius_m, apart)) is not None:
        a, b = pair
        sa, sb = segs[a], segs[b]
        merged = make_segment(np.sort(np.concatenate([sa.rows, sb.rows])), world, cov, cfg,
                              start=(sa.xyz + sb.xyz) / 2)
        merged.stationary = True
        segs = segs[:a] + [merged] + segs[b + 1:]
    return segs


# --------------------------------------------------------------------------- per instance


def _solve_chain(world, cov, chunk, init, cfg: GraphConfig) -> tuple[np.ndarray, np.ndarray]:
    """Landmarks and effective switches of one chain. With switchable factors and
    ``dcs_prepass``, a DCS solve (all C++) first finds the boundaries that are clearly still
    (implied switch >= ``prepass_keep``); those get a plain zero-motion factor, every other
    boundary an explicit switch, and the switchable solve starts from the DCS landmarks."""
    n = len(init)
    if cfg.switches == "switchable" and cfg.dcs_prepass and n > 1:
        graph, values = instance_graph(world, cov, chunk, init, cfg, ["dcs"] * (n - 1))
        dcs = dataclasses.replace(cfg, switches="dcs")
        landmarks = landmarks_of(solve_lm(graph, values, cfg.max_iterations), n)
        implied = switch_values(None, landmarks, dcs)
        sw = np.ones(n - 1)
        # Each candidate break is decided in a local window of the chain (a switch only couples
        # its neighbours), which keeps the Python CustomFactors in small graphs: GTSAM's cost
        # per CustomFactor call grows with the size of the graph it sits in.
        windows = _candidate_windows(np.flatnonzero(implied < cfg.prepass_keep) + 1, n, cfg.prepass_window)
        for lo, hi, own_lo, own_hi in _window_pieces(windows, cfg.prepass_max_window, cfg.prepass_window):
            rows = (chunk >= lo) & (chunk < hi)
            kinds = ["still" if implied[k - 1] >= cfg.prepass_keep else "switchable" for k in range(lo + 1, hi)]
            graph, values = instance_graph(world[rows], cov[rows], chunk[rows] - lo, landmarks[lo:hi], cfg, kinds)
            result = solve_lm(graph, values, cfg.max_iterations)
            landmarks[own_lo:own_hi] = landmarks_of(result, hi - lo)[own_lo - lo:own_hi - lo]
            for k in range(max(own_lo, lo + 1), own_hi):
                if kinds[k - lo - 1] == "switchable":
                    sw[k - 1] = switch_clipped(result, S(k - lo))
        return landmarks, sw
    graph, values = instance_graph(world, cov, chunk, init, cfg)
    result = solve_lm(graph, values, cfg.max_iterations)
    landmarks = landmarks_of(result, n)
    return landmarks, switch_values(result, landmarks, cfg)


def _candidate_windows(boundaries: np.ndarray, n: int, pad: int) -> list[tuple[int, int]]:
    """Chunk ranges [lo, hi) reaching ``pad`` chunks either side of each candidate boundary
    (boundary k joins chunks k-1 and k), overlapping ranges merged."""
    out: list[list[int]] = []
    for k in boundaries:
        lo, hi = max(0, int(k) - pad), min(n, int(k) + pad)
        if out and lo <= out[-1][1]:
            out[-1][1] = max(out[-1][1], hi)
        else:
            out.append([lo, hi])
    return [(lo, hi) for lo, hi in out]


def _window_pieces(windows: list[tuple[int, int]], max_len: int, pad: int) -> list[tuple[int, int, int, int]]:
    """Each window [lo, hi) cut into overlapping pieces of at most ``max_len`` chunks: (piece_lo,
    piece_hi, own_lo, own_hi). A piece decides only the chunks [own_lo, own_hi) and the
    boundaries in (own_lo, own_hi) (also own_lo, except at the window's start), at least ``pad``
    chunks from a cut, so each decision sees ``pad`` chunks of context either side as in an
    uncut window; the owned ranges partition the window."""
    out = []
    step = max(1, max_len - 2 * pad)
    for lo, hi in windows:
        if max_len <= 2 * pad or hi - lo <= max_len:
            out.append((lo, hi, lo, hi))
            continue
        s = lo
        while True:
            e = min(s + max_len, hi)
            own_lo = lo if s == lo else s + pad
            own_hi = hi if e == hi else e - pad
            out.append((s, e, own_lo, own_hi))
            if e == hi:
                break
            s += step
    return out


def _solve_instance_offline(world, cov, candidates, chunk, cfg: GraphConfig):
    n = int(chunk.max()) + 1
    init = chunk_medians(world, chunk, n)
    for round_ in range(max(0, cfg.alias_rounds) + 1):
        landmarks, switches = _solve_chain(world, cov, chunk, init, cfg)
        if round_ == cfg.alias_rounds or candidates is None:
            break
        better = nearest_candidates(candidates, landmarks[chunk])
        if np.allclose(better, world, equal_nan=True):
            break
        world = better
        init = landmarks
    return world, landmarks, switches


def segments_from_switches(chunk: np.ndarray, switches: np.ndarray, break_below: float) -> list[np.ndarray]:
    """Row indices of each run of chunks joined by switches >= ``break_below``."""
    starts = np.concatenate([[0], np.flatnonzero(switches < break_below) + 1])
    seg_of_chunk = np.searchsorted(starts, np.arange(len(switches) + 1), "right") - 1
    seg_of_row = seg_of_chunk[chunk]
    return [np.flatnonzero(seg_of_row == g) for g in range(len(starts))]


def _confidence(seg: Segment, n_rows: int, cfg: GraphConfig) -> float:
    share = seg.n_inliers / max(n_rows, 1)
    return float(share * (1.0 - math.exp(-seg.n_inliers / cfg.confidence_scale)))


def intervals_from_segments(instance: int, segs: list[Segment], t_frames: np.ndarray, frame_of_row: np.ndarray,
                            cfg: GraphConfig, backfill_start: bool, negative: NegativeFn | None) -> list[PositionInterval]:
    """Place stationary segments in time (module doc, step 8). ``t_frames``: PV frame ticks (sorted)."""
    out: list[PositionInterval] = []
    n_frames = len(t_frames)
    fps = (n_frames - 1) / max((t_frames[-1] - t_frames[0]) / TICKS_PER_SECOND, 1e-9) if n_frames > 1 else 30.0
    backfill = int(round(cfg.backfill_max_s * fps))
    for g, seg in enumerate(segs):
        if not seg.stationary:
            continue
        inl_frames = frame_of_row[seg.rows[seg.inliers]]
        first, last = int(inl_frames.min()), int(inl_frames.max())
        # Start: the end of the previous interval, or right after the previous (carried) segment's
        # last detection, or the recording's start for an instance's first interval (offline).
        prev = segs[g - 1] if g else None
        if prev is None:
            start = 0 if backfill_start else first
        elif out and prev.stationary:
            start = first  # the previous interval runs up to this one
        else:
            start = max(int(frame_of_row[prev.rows].max()) + 1, first - backfill)
            if out:
                start = max(start, out[-1].extra["end_frame"] + 1)
        # End: the frame before the next segment's first detection, or the recording's end.
        nxt = segs[g + 1] if g + 1 < len(segs) else None
        end = int(frame_of_row[nxt.rows].min()) - 1 if nxt is not None else n_frames - 1
        ended_by = "detection" if nxt is not None else "end"
        if negative is not None and end > last:
            gone = negative(instance, seg.xyz, last + 1, end + 1)
            if gone is not None:
                end, ended_by = gone - 1, "negative"
        end = max(end, last)
        cov = with_floor(seg.covariance, cfg)
        out.append(PositionInterval(
            instance=int(instance), t_start=int(t_frames[start]), t_end=int(t_frames[end]),
            xyz=tuple(float(v) for v in seg.xyz), covariance=cov.tolist(), n_observations=seg.n_inliers,
            confidence=_confidence(seg, len(seg.rows), cfg), first_seen=int(t_frames[first]),
            last_seen=int(t_frames[last]), backfilled=bool(prev is None and backfill_start and start < first),
            ended_by=ended_by, extra={"end_frame": end, "start_frame": start},
        ))
    # An end shortened by negative evidence leaves the frames after it to the next interval's start rule.
    return out


def track_instance_offline(instance: int, obs: Observations, t_frames: np.ndarray, cfg: GraphConfig,
                           negative: NegativeFn | None = None, support: SupportFn | None = None) -> InstanceSolution:
    """Offline solve of one instance's observations (already filtered and time-sorted):
    segments (``solution.segments``) and the intervals placed from them."""
    if len(obs) == 0:
        return InstanceSolution(instance, [])
    t_s = (obs.timestamps - t_frames[0]) / TICKS_PER_SECOND
    chunk = chunk_index(t_s, cfg.chunk_s)
    cov = detection_covariances(obs.world, obs.camera, cfg.noise)
    cands = obs.candidates if cfg.alias_rounds > 0 and obs.candidates.shape[1] > 1 else None
    world, _, switches = _solve_instance_offline(obs.world, cov, cands, chunk, cfg)
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


def claimed_by_others(seg: Segment, frames: np.ndarray, instance: int, intervals: Sequence[PositionInterval],
                      t_frames: np.ndarray, radius_m: float) -> bool:
    """Two objects cannot stand in one place: a stand of ``instance`` inside another instance's
    better-supported interval, at the same time and within ``radius_m``, is a look-alike confusion."""
    f = frames[seg.rows[seg.inliers]]
    t0, t1 = int(t_frames[f.min()]), int(t_frames[f.max()])
    for iv in intervals:
        if (iv.instance != instance and iv.t_start <= t1 and iv.t_end >= t0 and iv.n_observations > seg.n_inliers
                and np.linalg.norm(np.asarray(iv.xyz) - seg.xyz) <= radius_m):
            return True
    return False


def exclude_confusions(solutions: list[InstanceSolution], t_frames: np.ndarray, cfg: GraphConfig,
                       negative: NegativeFn | None) -> int:
    """Drop every stand that another instance claims (:func:`claimed_by_others`), re-merge and
    re-place the affected instances' intervals. Returns the number of stands dropped."""
    everyone = [iv for s in solutions for iv in s.intervals]
    dropped = 0
    for sol in solutions:
        if not sol.segments:
            continue
        keep = [seg for seg in sol.segments if not (
            seg.stationary and claimed_by_others(seg, sol.frames, sol.instance, everyone, t_frames,
                                                 cfg.exclusion_radius_m))]
        if len(keep) == len(sol.segments):
            continue
        dropped += len(sol.segments) - len(keep)
        sol.segments = merge_segments(keep, sol.world, sol.cov, cfg, sol.instance, sol.frames, negative)
        sol.intervals = intervals_from_segments(sol.instance, sol.segments, t_frames, sol.frames, cfg,
                                                backfill_start=True, negative=negative)
    return dropped


# --------------------------------------------------------------------------- causal (iSAM2)


def track_instance_causal(instance: int, obs: Observations, t_frames: np.ndarray, cfg: GraphConfig,
                          negative: NegativeFn | None = None, support: SupportFn | None = None) -> InstanceSolution:
    """Causal solve: iSAM2 grows the graph one observed frame at a time; a frame's report
    uses only the observations of earlier frames (one frame of latency, no look-ahead).

    After each update the *trailing segment* (chunks back to the last switch that is off)
    is tested like an offline segment, around iSAM2's estimate of the newest landmark:
    enough inliers, a large enough inlier share, not moving with the head. If it passes,
    the instance is reported there from the next frame on; otherwise (moving, or a new
    place not yet confirmed) nothing is reported. Reports of one stand form one interval
    in the JSON (its last estimate); the per-frame results keep every report's position.
    """
    if len(obs) == 0:
        return InstanceSolution(instance, [])
    t_s = (obs.timestamps - t_frames[0]) / TICKS_PER_SECOND
    chunk = chunk_index(t_s, cfg.chunk_s)
    world = obs.world
    cov = detection_covariances(world, obs.camera, cfg.noise)
    info = np.linalg.inv(cov)
    frames = obs.frame.astype(np.int64)
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(0.01)
    isam = gtsam.ISAM2(params)
    cuts = np.flatnonzero(np.diff(frames)) + 1
    groups = np.split(np.arange(len(frames)), cuts)
    seg_first_row = 0
    reports: list[tuple[int, Segment | None, int]] = []  # (first frame it applies to, stand, segment start row)
    switches: list[float] = []
    seen_chunks = -1
    for rows in groups:
        k = int(chunk[rows[0]])
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        if k > seen_chunks:
            values.insert(L(k), gtsam.Point3(*np.median(world[rows], axis=0)))
            if k:
                add_break_factors(graph, values, k, cfg)
            seen_chunks = k
        add_detection_factors(graph, np.full(len(rows), L(k)), world[rows], cov[rows], cfg.noise)
        isam.update(graph, values)
        here = np.asarray(isam.calculateEstimatePoint3(L(k)), dtype=float)
        if k:
            if cfg.switches == "switchable":
                sw = min(1.0, max(0.0, float(isam.calculateEstimateVector(S(k))[0])))
            else:
                sw = dcs_switch_value(np.asarray(isam.calculateEstimatePoint3(L(k - 1))), here,
                                      cfg.still_sigma_m, dcs_phi(cfg.switch_sigma))
            if sw < cfg.break_below:
                seg_first_row = max(seg_first_row, int(np.searchsorted(chunk, k)))
            if rows[0] == np.searchsorted(chunk, k):
                switches.append(sw)
        seg_rows = np.arange(seg_first_row, rows[-1] + 1)
        seg = _stand_around(here, seg_rows, world, cov, info, obs, cfg)
        seg.stationary = seg.stationary and not held_in_mid_air(seg, obs.range_m, cfg, support)
        reports.append((int(frames[rows[-1]]) + 1, seg if seg.stationary else None, seg_first_row))
    pieces = _causal_pieces(instance, reports, frames, t_frames, cfg, negative)
    sol = InstanceSolution(instance, _join_pieces(pieces), np.array(switches), len(obs), int(chunk.max()) + 1)
    sol.pieces = pieces
    return sol


def _stand_around(xyz: np.ndarray, rows: np.ndarray, world: np.ndarray, cov: np.ndarray, info: np.ndarray,
                  obs: Observations, cfg: GraphConfig) -> Segment:
    """The offline stand test around a given centre without a robust re-solve (cheap enough per
    frame): the centre becomes the information-weighted mean of the segment's inliers around
    ``xyz`` (iSAM2's newest landmark), its covariance the inverse of their summed information."""
    inl = mahalanobis2(world[rows], xyz, cov[rows]) <= cfg.inlier_chi2
    c = cov[rows[0]]
    for _ in range(2):
        if not inl.any():
            break
        c = np.linalg.inv(info[rows[inl]].sum(axis=0))
        xyz = c @ np.einsum("mij,mj->i", info[rows[inl]], world[rows[inl]])
        inl = mahalanobis2(world[rows], xyz, cov[rows]) <= cfg.inlier_chi2
    seg = Segment(rows, xyz, c, inl)
    seg.stationary = is_stand(seg, moves_with_camera(world[rows], obs.camera[rows], obs.range_m[rows], cfg), cfg)
    return seg


def _causal_pieces(instance: int, reports: list, frames: np.ndarray, t_frames: np.ndarray, cfg: GraphConfig,
                   negative: NegativeFn | None) -> list[PositionInterval]:
    """One piece per report: its stand over the frames from the report's first frame to the
    frame before the next report (cut short by negative evidence seen up to that frame)."""
    out: list[PositionInterval] = []
    n_frames = len(t_frames)
    for j, (f0, seg, seg_start) in enumerate(reports):
        if seg is None or f0 >= n_frames:
            continue
        f1 = min(reports[j + 1][0] - 1 if j + 1 < len(reports) else n_frames - 1, n_frames - 1)
        ended_by = "detection" if j + 1 < len(reports) else "end"
        inl_frames = frames[seg.rows[seg.inliers]]
        if negative is not None:
            gone = negative(instance, seg.xyz, max(f0, int(inl_frames.max()) + 1), f1 + 1)
            if gone is not None:
                f1, ended_by = gone - 1, "negative"
        if f1 < f0:
            continue
        c = with_floor(seg.covariance, cfg)
        out.append(PositionInterval(
            instance=int(instance), t_start=int(t_frames[f0]), t_end=int(t_frames[f1]),
            xyz=tuple(float(v) for v in seg.xyz), covariance=c.tolist(), n_observations=seg.n_inliers,
            confidence=_confidence(seg, len(seg.rows), cfg), first_seen=int(t_frames[inl_frames.min()]),
            last_seen=int(t_frames[inl_frames.max()]), ended_by=ended_by,
            extra={"start_frame": f0, "end_frame": f1, "segment_start_row": seg_start},
        ))
    return out


def _join_pieces(pieces: list[PositionInterval]) -> list[PositionInterval]:
    """Consecutive pieces of one stand (same segment start, no gap) -> one interval at the last estimate."""
    out: list[PositionInterval] = []
    for p in pieces:
        last = out[-1] if out else None
        if (last is not None and last.extra["segment_start_row"] == p.extra["segment_start_row"]
                and p.extra["start_frame"] == last.extra["end_frame"] + 1 and last.ended_by != "negative"):
            out[-1] = dataclasses.replace(p, t_start=last.t_start, extra={**p.extra, "start_frame": last.extra["start_frame"]})
        else:
            out.append(p)
    return out


# --------------------------------------------------------------------------- whole recording


def select_instance_rows(obs: Observations, instance: int, threshold: float) -> Observations:
    score = np.asarray(obs.score, dtype=np.float32)
    mask = (obs.instance == instance) & obs.valid & (score >= np.float32(threshold))
    sub = obs.select(mask)
    order = np.argsort(sub.timestamps, kind="stable")
    return sub.select(order)


def graph_tracker(obs: Observations, timestamps: Sequence[int], cfg: GraphConfig, *, causal: bool = False,
                  negative: NegativeFn | None = None, support: SupportFn | None = None,
                  instances: Sequence[int] | None = None,
                  progress: bool = False) -> TrackResult:
    """Run the graph tracker over a recording's observations.

    ``timestamps``: the PV frames (ticks); observations must sit on them (``obs.frame`` is
    the index into the sorted timestamps). ``negative``: optional negative-evidence test
    (:class:`egograph.track.negative.NegativeEvidence`); ``support``: optional test that a
    stand rests on the scene (``NegativeEvidence.supported``). Returns intervals, the per-frame
    predictions in the reference format and metadata for the output JSON.
    """
    t_frames = np.asarray(sorted(int(t) for t in timestamps), dtype=np.int64)
    ids = sorted({int(i) for i in obs.instance}) if instances is None else list(instances)
    solve = track_instance_causal if causal else track_instance_offline
    solutions = []
    it = ids
    if progress:
        from tqdm import tqdm

        it = tqdm(ids, desc="graph" + (" (causal)" if causal else ""), unit="instance")
    for inst in it:
        sub = select_instance_rows(obs, inst, cfg.score_threshold)
        solutions.append(solve(inst, sub, t_frames, cfg, negative, support))
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
    }
    return TrackResult(per_frame=per_frame, intervals=intervals, metadata=metadata, solutions=solutions)
