"""Segments of an instance's chain (step 7 of :mod:`egograph.track.graph`).

A segment is a run of chunks whose switches stay on. Its robust centre (world, metres) and
marginal covariance (m^2) come from one landmark solved over its detections (GTSAM, robust); it
is a *stand* when its inliers explain it and it does not move with the head (an object in hand)
or hang in mid-air. Segments found the places of :mod:`egograph.track.places`; the chain's stands
are what the detection noise-scale fit reads (:mod:`egograph.track.noise_scale`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import gtsam
import numpy as np

from egograph.core.types import PositionInterval
from egograph.track.chain import L, solve_lm
from egograph.track.config import GraphConfig
from egograph.track.detection_factor import detection_covariances, detection_factors, lengths, mahalanobis2

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
    covariance: np.ndarray | None  # 3x3 marginal covariance, m^2 (without the floor); None when not asked for
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
    camera: np.ndarray | None = None  # offline: per observation depth-camera centre, metres
    range_m: np.ndarray | None = None  # offline: per observation range from the depth camera, metres
    candidates: np.ndarray | None = None  # offline: per observation alias candidates (M, C, 3), metres
    score: np.ndarray | None = None   # offline: per observation matcher score
    chain_segments: list | None = None  # offline: every segment of the chain, made (before any is dropped)
    places: list | None = None        # offline: the instance's places (egograph.track.places.Place)
    runs: list | None = None          # offline: the place chain's runs (egograph.track.places.PlaceRun)
    point_factors: list | None = None  # offline: every row's detection factor for robust points (segments.point_factors)
    answers: tuple | None = None      # offline: every frame's answer, (xyz (T, 3), raw confidence (T,), kind (T,)) (track.answers)


# --------------------------------------------------------------------------- stands


def point_factors(world: np.ndarray, cov: np.ndarray, cfg: GraphConfig) -> list:
    """The detection factor of every row on the one landmark of :func:`robust_point`. Made once for
    an instance's detections, it serves each of its segments and places (a long recording pools
    thousands of detections into a place, again at every merge)."""
    return detection_factors(np.full(len(world), L(0)), world, cov, cfg.noise)


def _point_graph(world: np.ndarray, cov: np.ndarray, cfg: GraphConfig, factors: list | None):
    graph = gtsam.NonlinearFactorGraph()
    for factor in point_factors(world, cov, cfg) if factors is None else factors:
        graph.add(factor)
    return graph


def robust_point(world: np.ndarray, cov: np.ndarray, cfg: GraphConfig, start: np.ndarray | None = None,
                 marginal: bool = True, factors: list | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """One landmark from many detections: robust LM solve from ``start`` (default the median) and
    its marginal covariance (m^2; None without ``marginal``, :func:`point_covariance` gives it
    later). ``factors``: the rows' :func:`point_factors`, when made already."""
    graph = _point_graph(world, cov, cfg, factors)
    values = gtsam.Values()
    values.insert(L(0), gtsam.Point3(*(np.median(world, axis=0) if start is None else start)))
    result = solve_lm(graph, values, cfg.max_iterations)
    xyz = np.asarray(result.atPoint3(L(0)), dtype=float)
    return xyz, (_marginal(graph, result, world, cov) if marginal else None)


def point_covariance(world: np.ndarray, cov: np.ndarray, xyz: np.ndarray, cfg: GraphConfig,
                     factors: list | None = None) -> np.ndarray:
    """The marginal covariance (m^2) that :func:`robust_point` of these rows reports at its
    solution ``xyz``, the same bits."""
    values = gtsam.Values()
    values.insert(L(0), gtsam.Point3(*xyz))
    return _marginal(_point_graph(world, cov, cfg, factors), values, world, cov)


def _marginal(graph, values, world: np.ndarray, cov: np.ndarray) -> np.ndarray:
    try:
        covariance = gtsam.Marginals(graph, values).marginalCovariance(L(0))
    except RuntimeError:  # every detection down-weighted to nothing: fall back to the sample spread
        covariance = np.cov(world.T) + 1e-6 * np.eye(3) if len(world) > 1 else cov[0]
    return np.asarray(covariance)


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
                 range_m: np.ndarray | None = None, marginal: bool = True, factors: list | None = None) -> Segment:
    """Robust centre of the detections ``rows`` (from ``start``, default their median) and whether
    they show a stand: enough inliers, a large enough inlier share, and not moving along with the
    camera (``camera`` given). Without ``marginal`` the segment's covariance is None. ``factors``:
    :func:`point_factors` of every row of ``world``, when made already."""
    xyz, c = robust_point(world[rows], cov[rows], cfg, start, marginal,
                          None if factors is None else [factors[j] for j in rows.tolist()])
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


def median0(x: np.ndarray) -> np.ndarray:
    """``np.median(x, axis=0)``, the same bits (an even count takes the mean of the two middle
    values), by one sort: the online hand test takes five medians of a few dozen rows per near
    detection, and ``np.median``'s general machinery costs several times the sort."""
    s = np.sort(x, axis=0)
    n = len(s)
    if n == 0 or np.isnan(s[-1]).any():  # NaN sorts last; np.median answers NaN
        return np.median(x, axis=0)
    h = n // 2
    return s[h] if n % 2 else (s[h - 1] + s[h]) / 2


def moves_with_camera(world: np.ndarray, camera: np.ndarray, range_m: np.ndarray, cfg: GraphConfig,
                      margin: float = 1.0) -> bool:
    """An object in hand is near the head (median range <= ``carry_range_m``) and keeps its
    offset to it while both move through the room: its world points spread (median, metres)
    more than ``carry_spread_m`` and more than ``margin`` times its head-relative offsets do."""
    if median0(range_m) > cfg.carry_range_m:
        return False
    spread_world = median0(lengths(world - median0(world)))
    rel = world - camera
    spread_rel = median0(lengths(rel - median0(rel)))
    return bool(spread_world > cfg.carry_spread_m and spread_world > margin * spread_rel)


def segments_from_switches(chunk: np.ndarray, switches: np.ndarray, break_below: float) -> list[np.ndarray]:
    """Row indices of each run of chunks joined by switches >= ``break_below``."""
    starts = np.concatenate([[0], np.flatnonzero(switches < break_below) + 1])
    seg_of_chunk = np.searchsorted(starts, np.arange(len(switches) + 1), "right") - 1
    seg_of_row = seg_of_chunk[chunk]
    return [np.flatnonzero(seg_of_row == g) for g in range(len(starts))]


# --------------------------------------------------------------------------- in hand


def held_in_mid_air(seg: Segment, range_m: np.ndarray, cfg: GraphConfig, support: SupportFn | None) -> bool:
    """A hand holding an object still looks like a stand in the world; but it is seen only from
    close by (median range <= ``carry_range_m``) and nothing in the scene mesh holds it up. Both
    must hold: HoloLens meshes have holes, and objects are looked at closely before a pick-up."""
    if support is None or np.median(range_m[seg.rows]) > cfg.carry_range_m:
        return False
    return not support(seg.xyz)
