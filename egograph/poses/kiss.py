"""KISS-ICP odometry on AHAT point clouds as relative pose constraints.

KISS-ICP registers each (mesh-unwrapped or near-range) AHAT cloud to its local voxel map.
Its constant-velocity prediction is replaced by the HoloLens relative motion between the
two processed frames (``last_delta`` before each ``register_frame``), which is far better
on fast head turns; KISS-ICP then corrects it (a relocalisation jump of the HoloLens shows
up as a disagreement). Consecutive processed frames give relative-pose factors, converted
from the AHAT camera to the PV camera with the per-frame offsets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from egograph.core.resources import require
from egograph.core.units import TICKS_PER_SECOND
from egograph.poses.config import RefineConfig
from egograph.poses.constraints import Constraints, ahat_offsets, invert_columns, pv_columns, sigmas
from egograph.poses.mesh_icp import within
from egograph.poses.points import AhatPointSource


@dataclass
class KissStats:
    frames: int = 0
    registered: int = 0
    skipped: int = 0         # no depth, no pose or too few points
    resets: int = 0          # odometry restarted after a gap or a rejected result
    rejected: int = 0        # results too far from the HoloLens prediction
    fast: int = 0            # links dropped for fast head motion


def make_kiss(cfg: RefineConfig):
    require("kiss_icp", "icp", "refine.icp=true")
    from kiss_icp.config import KISSConfig
    from kiss_icp.config.config import AdaptiveThresholdConfig, DataConfig, MappingConfig, RegistrationConfig
    from kiss_icp.kiss_icp import KissICP

    kc = KISSConfig(data=DataConfig(max_range=cfg.max_range, min_range=cfg.min_range, deskew=False),
                    mapping=MappingConfig(voxel_size=cfg.icp_voxel),
                    registration=RegistrationConfig(max_num_iterations=cfg.icp_max_iterations, max_num_threads=1),
                    adaptive_threshold=AdaptiveThresholdConfig(fixed_threshold=cfg.icp_threshold))
    return KissICP(kc)


def orthonormal(T: np.ndarray) -> np.ndarray:
    """Nearest rigid transform (SVD on the rotation): KISS-ICP's Sophus rejects rotations off by 1e-9."""
    T = np.array(T, dtype=np.float64)
    u, _, vt = np.linalg.svd(T[:3, :3])
    r = u @ vt
    if np.linalg.det(r) < 0:
        u[:, -1] *= -1
        r = u @ vt
    T[:3, :3] = r
    T[3] = [0, 0, 0, 1]
    return T


def plausible(delta: np.ndarray, max_trans: float = 0.15, max_rot_deg: float = 30.0) -> bool:
    """A frame-to-frame motion a head can make (used to trust the HoloLens prediction)."""
    return within(delta, max_trans, max_rot_deg)


def kiss_constraints(rec, cfg: RefineConfig, points: AhatPointSource, pv_estimate: np.ndarray | None = None,
                     progress: bool = False) -> tuple[Constraints, KissStats]:
    """Relative PV-pose constraints between consecutive processed frames (every ``icp_stride``-th).

    ``pv_estimate``: (N, 4, 4) column PV camera -> world poses giving the motion prediction
    and the unwrapping pose (default: reported).
    """
    from tqdm import tqdm

    stats = KissStats()
    offsets = ahat_offsets(rec)
    pv = pv_columns(rec) if pv_estimate is None else pv_estimate
    ahat = pv @ offsets                                   # AHAT camera -> world (column)
    kiss = None
    prev = None                                           # (frame, estimated AHAT pose, kiss pose)
    out_i, out_j, out_T = [], [], []
    frames = range(0, len(rec), cfg.icp_stride)
    for i in tqdm(frames, desc="KISS-ICP", unit="frame", disable=not progress, leave=False):
        stats.frames += 1
        if not (rec.pv_valid[i] and np.isfinite(ahat[i]).all()):
            stats.skipped += 1
            continue
        pts = points.points(i, ahat_to_world=ahat[i].T)
        if pts is None or len(pts) < cfg.icp_min_points:
            stats.skipped += 1
            continue
        if kiss is None or prev is None or i - prev[0] > 3 * cfg.icp_stride:
            if kiss is not None:
                stats.resets += 1
            kiss = make_kiss(cfg)
            # odometry frame = world at the first frame: register there (builds the local map)
            kiss.last_pose = orthonormal(ahat[i])
            kiss.register_frame(pts, np.array([]))
            kiss.last_pose = orthonormal(ahat[i])
            kiss.last_delta = np.eye(4)
            prev = (i, ahat[i], kiss.last_pose.copy())
            stats.registered += 1
            continue
        delta = invert_columns(prev[1]) @ ahat[i]
        if plausible(delta):
            kiss.last_delta = orthonormal(delta)              # HoloLens motion as the prediction
        guess = kiss.last_pose @ kiss.last_delta
        kiss.register_frame(pts, np.array([]))
        cur = kiss.last_pose.copy()
        if not within(invert_columns(guess) @ cur, *cfg.icp_max_correction):
            stats.rejected += 1
            kiss, prev = None, None                            # restart at the next frame
            continue
        z = invert_columns(prev[2]) @ cur                      # AHAT_i -> AHAT_j, measured
        a, b = prev[0], i
        dt = max((rec.timestamps[b] - rec.timestamps[a]) / TICKS_PER_SECOND, 1e-3)
        prev = (i, ahat[i], cur)
        stats.registered += 1
        if not within(delta, np.inf, cfg.icp_max_turn_rate * dt):
            stats.fast += 1
            continue
        out_i.append(a)
        out_j.append(b)
        out_T.append(offsets[a] @ z @ invert_columns(offsets[b]))
    n = len(out_i)
    return Constraints("icp", "relative", np.array(out_i, int), np.array(out_j, int), np.array(out_T).reshape(n, 4, 4),
                       sigmas(cfg.icp_sigma_rot, cfg.icp_sigma_trans, n), cfg.icp_kernel,
                       {"stats": stats.__dict__}), stats
