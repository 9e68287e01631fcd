"""Self-check of a refinement without ground truth, and the no-harm rule built on it.

Some mesh keyframes are held out of the solve (:func:`egograph.poses.mesh_icp.holdout_mask`).
Their AHAT points (camera frame, unwrapped once with the reported pose, so the same points are
compared) are put into the world with the input pose and with the refined pose, and their
distance to the HoloLens mesh is measured (truncated at ``selfcheck_truncate``: points off the
mesh — objects, people, holes — count as the truncation, whichever pose). A pose that is closer
to the truth puts the points closer to the mesh; a view that does not constrain a direction
(a lone plane) is blind to a change along it, which then counts as "no improvement shown".

Per segment of ``selfcheck_segment`` seconds the refined poses are kept only when the held-out
residual drops significantly (mean drop of the per-frame mean squared distance at least
``selfcheck_z`` standard errors above zero, and the RMS by at least ``selfcheck_min_gain``);
elsewhere the input poses are kept. Blending: inside a refined segment next to a kept one the
world correction is faded in over ``selfcheck_blend`` seconds (``Exp(α·Log(C))``), so there is
no step at the boundary; kept segments stay bit-identical to the input. Reported pose spikes
(:func:`egograph.poses.refine.initial_poses`) always take the refined pose: a 0.5 m jump between
neighbouring frames needs no ground truth to be called wrong.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from egograph.core.units import TICKS_PER_SECOND
from egograph.poses.config import RefineConfig


@dataclass
class Segment:
    """One keep-or-refine decision (times in seconds from the first frame)."""

    start_s: float
    end_s: float
    first: int                      # frame indices [first, last]
    last: int
    held_out: int                   # held-out keyframes with depth in the segment
    residual_input_m: float         # held-out truncated mesh-distance RMS at the input poses
    residual_refined_m: float       # ... at the refined poses
    t_stat: float                   # mean drop of the squared residual over its standard error
    poses: str                      # 'refined' | 'input'
    reason: str


def mesh_distances(scene, points_cam: np.ndarray, cam_to_world: np.ndarray) -> np.ndarray:
    """Distance (m) of camera-frame points to the mesh surface with the column 4x4 camera -> world pose."""
    import open3d as o3d

    pw = points_cam @ cam_to_world[:3, :3].T + cam_to_world[:3, 3]
    ans = scene.compute_closest_points(o3d.core.Tensor(pw.astype(np.float32)))
    return np.linalg.norm(pw - ans["points"].numpy().astype(np.float64), axis=1)


def holdout_residuals(points, scene, frames: np.ndarray, offsets: np.ndarray, pv_input: np.ndarray,
                      pv_refined: np.ndarray, truncate: float) -> tuple[np.ndarray, np.ndarray]:
    """Per held-out frame the mean squared truncated mesh distance (m²) of its AHAT points at the
    input and at the refined PV poses (column (N, 4, 4)); NaN without depth or poses.

    ``points``: :class:`egograph.poses.points.AhatPointSource`; ``offsets``: AHAT camera -> PV
    camera per frame (:func:`egograph.poses.constraints.ahat_offsets`).
    """
    before = np.full(len(frames), np.nan)
    after = np.full(len(frames), np.nan)
    for k, i in enumerate(frames):
        if not (np.isfinite(pv_input[i]).all() and np.isfinite(pv_refined[i]).all()):
            continue
        a_in = pv_input[i] @ offsets[i]
        pts = points.points(int(i), ahat_to_world=a_in.T)
        if pts is None or len(pts) < 50:
            continue
        before[k] = np.mean(np.minimum(mesh_distances(scene, pts, a_in), truncate) ** 2)
        after[k] = np.mean(np.minimum(mesh_distances(scene, pts, pv_refined[i] @ offsets[i]), truncate) ** 2)
    return before, after


def segment_bounds(times_s: np.ndarray, length_s: float) -> list[tuple[int, int]]:
    """Frame index ranges [first, last] of consecutive segments of ``length_s`` seconds; a last
    segment shorter than half a length joins the one before it."""
    if len(times_s) == 0:
        return []
    k = np.floor((times_s - times_s[0]) / length_s).astype(int)
    n = int(k.max()) + 1
    if n > 1 and times_s[-1] - (times_s[0] + (n - 1) * length_s) < 0.5 * length_s:
        k = np.minimum(k, n - 2)
    return [(int(np.flatnonzero(k == s)[0]), int(np.flatnonzero(k == s)[-1])) for s in np.unique(k)]


def decide_segments(times_s: np.ndarray, frames: np.ndarray, before: np.ndarray, after: np.ndarray,
                    cfg: RefineConfig) -> list[Segment]:
    """The keep-or-refine decision per segment from the held-out residuals (m², per held-out frame)."""
    out = []
    for first, last in segment_bounds(times_s, cfg.selfcheck_segment):
        sel = (frames >= first) & (frames <= last) & np.isfinite(before) & np.isfinite(after)
        n = int(sel.sum())
        rb = float(np.sqrt(np.mean(before[sel]))) if n else float("nan")
        ra = float(np.sqrt(np.mean(after[sel]))) if n else float("nan")
        t = float("nan")
        if n < cfg.selfcheck_min_frames:
            poses, why = "input", f"{n} held-out keyframe(s) with depth, fewer than {cfg.selfcheck_min_frames}"
        else:
            d = before[sel] - after[sel]
            sem = float(np.std(d, ddof=1) / np.sqrt(n))
            t = float(np.mean(d) / sem) if sem > 0 else (np.inf if np.mean(d) > 0 else 0.0)
            if t >= cfg.selfcheck_z and rb - ra >= cfg.selfcheck_min_gain:
                poses, why = "refined", f"held-out residual {rb * 1000:.1f} -> {ra * 1000:.1f} mm (t = {t:.1f})"
            elif rb - ra < cfg.selfcheck_min_gain:
                poses, why = "input", (f"held-out residual not lower by {cfg.selfcheck_min_gain * 1000:.1f} mm "
                                       f"({rb * 1000:.1f} -> {ra * 1000:.1f} mm)")
            else:
                poses, why = "input", f"drop not significant (t = {t:.1f} < {cfg.selfcheck_z})"
        out.append(Segment(float(times_s[first]), float(times_s[last]), first, last, n, rb, ra, t, poses, why))
    return out


def blend_weights(times_s: np.ndarray, segments: list[Segment], blend_s: float) -> np.ndarray:
    """Per frame the share α ∈ [0, 1] of the refinement's world correction applied: 0 in kept
    segments, 1 in refined ones, ramping up linearly over ``blend_s`` seconds from a kept neighbour."""
    refined = np.zeros(len(times_s), bool)
    for s in segments:
        refined[s.first:s.last + 1] = s.poses == "refined"
    if refined.all() or not refined.any() or blend_s <= 0:
        return refined.astype(float)
    kept_t = times_s[~refined]
    j = np.clip(np.searchsorted(kept_t, times_s), 1, len(kept_t) - 1) if len(kept_t) > 1 else np.zeros(len(times_s), int)
    gap = np.abs(times_s - kept_t[j])
    if len(kept_t) > 1:
        gap = np.minimum(gap, np.abs(times_s - kept_t[j - 1]))
    return np.where(refined, np.clip(gap / blend_s, 0.0, 1.0), 0.0)


def blend_poses(input_col: np.ndarray, refined_col: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """``Exp(α·Log(C)) · input`` with the world correction ``C = refined · input⁻¹`` (column (N, 4, 4));
    exactly the input at α = 0 and the refined pose at α = 1; NaN where either is missing."""
    import gtsam

    out = np.where((alpha >= 1.0)[:, None, None], refined_col, input_col).copy()
    for i in np.flatnonzero((alpha > 0) & (alpha < 1)):
        if not (np.isfinite(input_col[i]).all() and np.isfinite(refined_col[i]).all()):
            continue
        c = gtsam.Pose3(refined_col[i] @ np.linalg.inv(input_col[i]))
        out[i] = gtsam.Pose3.Expmap(alpha[i] * gtsam.Pose3.Logmap(c)).matrix() @ input_col[i]
    return out


def seconds(timestamps: np.ndarray) -> np.ndarray:
    """Seconds since the first frame."""
    ts = np.asarray(timestamps, dtype=np.int64)
    return (ts - ts[0]) / TICKS_PER_SECOND if len(ts) else np.zeros(0)
