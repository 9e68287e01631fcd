"""Segments of an instance's chain and the intervals placed from them (steps 7-8 of :mod:`egograph.track.graph`).

A segment is a run of chunks whose switches stay on. Its robust centre (world, metres) and
marginal covariance (m^2) come from one landmark solved over its detections; it is a *stand*
when its inliers explain it and it does not move with the head, a *carry* when it is not and
was seen at hand range. Stands at one place separated only by weaker segments merge; a stand
inside another instance's better-supported interval is a look-alike confusion. Stands are
then placed in time (first supporting detection to the first evidence the object left).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import gtsam
import numpy as np

from egograph.core.types import PositionInterval
from egograph.core.units import TICKS_PER_SECOND
from egograph.track.chain import L, solve_lm
from egograph.track.config import GraphConfig
from egograph.track.detection_factor import add_detection_factors, detection_covariances, mahalanobis2

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


# --------------------------------------------------------------------------- stands


def _robust_point(world: np.ndarray, cov: np.ndarray, cfg: GraphConfig,
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
    xyz, c = _robust_point(world, detection_covariances(world, camera, cfg.noise), cfg)
    return xyz, with_floor(c, cfg)


def make_segment(rows: np.ndarray, world: np.ndarray, cov: np.ndarray, cfg: GraphConfig,
                 start: np.ndarray | None = None, camera: np.ndarray | None = None,
                 range_m: np.ndarray | None = None) -> Segment:
    """Robust centre of the detections ``rows`` and whether they show a stand: enough inliers,
    a large enough inlier share, and not moving along with the camera (``camera`` given)."""
    xyz, c = _robust_point(world[rows], cov[rows], cfg, start)
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


def segments_from_switches(chunk: np.ndarray, switches: np.ndarray, break_below: float) -> list[np.ndarray]:
    """Row indices of each run of chunks joined by switches >= ``break_below``."""
    starts = np.concatenate([[0], np.flatnonzero(switches < break_below) + 1])
    seg_of_chunk = np.searchsorted(starts, np.arange(len(switches) + 1), "right") - 1
    seg_of_row = seg_of_chunk[chunk]
    return [np.flatnonzero(seg_of_row == g) for g in range(len(starts))]


# --------------------------------------------------------------------------- carries


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


# --------------------------------------------------------------------------- merging and confusions


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
        rows = np.sort(np.concatenate([sa.rows, sb.rows]))
        merged = make_segment(rows, world, cov, cfg, start=(sa.xyz + sb.xyz) / 2)
        if merged.n_inliers < max(sa.n_inliers, sb.n_inliers):
            # the robust centre of every row went astray (false rows outnumber the stands' own):
            # place it by the two stands' inliers, and count inliers over every row from there
            core = np.sort(np.concatenate([sa.rows[sa.inliers], sb.rows[sb.inliers]]))
            xyz, c = _robust_point(world[core], cov[core], cfg, (sa.xyz + sb.xyz) / 2)
            merged = Segment(rows, xyz, c, mahalanobis2(world[rows], xyz, cov[rows]) <= cfg.inlier_chi2)
        merged.stationary = True
        segs = segs[:a] + [merged] + segs[b + 1:]
    return segs


def _claimed_by_others(seg: Segment, frames: np.ndarray, instance: int, intervals: Sequence[PositionInterval],
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
    """Drop every stand that another instance claims (:func:`_claimed_by_others`), re-merge and
    re-place the affected instances' intervals. Returns the number of stands dropped."""
    everyone = [iv for s in solutions for iv in s.intervals]
    dropped = 0
    for sol in solutions:
        if not sol.segments:
            continue
        keep = [seg for seg in sol.segments if not (
            seg.stationary and _claimed_by_others(seg, sol.frames, sol.instance, everyone, t_frames,
                                                 cfg.exclusion_radius_m))]
        if len(keep) == len(sol.segments):
            continue
        dropped += len(sol.segments) - len(keep)
        sol.segments = merge_segments(keep, sol.world, sol.cov, cfg, sol.instance, sol.frames, negative)
        sol.intervals = intervals_from_segments(sol.instance, sol.segments, t_frames, sol.frames, cfg,
                                                backfill_start=True, negative=negative)
    return dropped


# --------------------------------------------------------------------------- intervals


def stand_confidence(seg: Segment, n_rows: int, cfg: GraphConfig) -> float:
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
            confidence=stand_confidence(seg, len(seg.rows), cfg), first_seen=int(t_frames[first]),
            last_seen=int(t_frames[last]), backfilled=bool(prev is None and backfill_start and start < first),
            ended_by=ended_by, extra={"end_frame": end, "start_frame": start},
        ))
    # An end shortened by negative evidence leaves the frames after it to the next interval's start rule.
    return out
