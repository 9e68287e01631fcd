"""The causal graph tracker: iSAM2 grows one instance's landmark chain one observed frame at a time.

A frame's report uses only the observations of earlier frames (one frame of latency, no
look-ahead); the trailing segment is tested like an offline stand
(:mod:`egograph.track.segments`). World frame, metres; PV frame indices and ticks.
"""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np

from egograph.core.types import PositionInterval
from egograph.core.units import TICKS_PER_SECOND
from egograph.geometry.observations import Observations
from egograph.track.chain import L, S, add_break_factors, chunk_index
from egograph.track.config import GraphConfig
from egograph.track.detection_factor import add_detection_factors, detection_covariances, mahalanobis2
from egograph.track.segments import (
    InstanceSolution,
    NegativeFn,
    Segment,
    SupportFn,
    held_in_mid_air,
    is_stand,
    moves_with_camera,
    stand_confidence,
    with_floor,
)
from egograph.track.switchable import dcs_phi, dcs_switch_value


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
            confidence=stand_confidence(seg, len(seg.rows), cfg), first_seen=int(t_frames[inl_frames.min()]),
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
