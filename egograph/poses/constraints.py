"""Pose constraints from the refinement sources, in one form the pose graph consumes.

Every constraint is on the **PV camera -> world** pose of a frame, as a GTSAM-style
column-vector 4x4 (``p_world = T @ [p; 1]``), with diagonal sigmas in GTSAM's Pose3 tangent
order ``[rx, ry, rz, tx, ty, tz]`` (radians, metres; body frame) and a Cauchy kernel width in
sigmas (0 = Gaussian).

Sources that measure another sensor (AHAT ICP) convert through the per-frame offset
``O_i = T_pv_i⁻¹ · T_ahat_i`` (AHAT camera -> PV camera at frame i), computed from the reported
poses: both reported poses carry the same head-tracking error, so the offset is exact up to
HoloLens short-term relative error, and it includes the head motion during the few
milliseconds between the PV and AHAT captures.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from egograph.geometry.hl2ss import invert_rigid


@dataclass
class Constraints:
    """A batch of constraints of one source and kind.

    ``kind == 'relative'``: ``T[k] = T_pv_i⁻¹ · T_pv_j`` for frames ``i[k] -> j[k]``.
    ``kind == 'absolute'``: ``T[k] = T_pv_i`` (PV camera -> world), ``j`` unused.
    The HoloLens model uses the same form on other variable families (``key_i``/``key_j``),
    see :func:`egograph.poses.refine.hololens_constraints`.
    """

    source: str                  # 'hololens', 'prior', 'icp', 'mesh', 'colmap'
    kind: str                    # 'relative' | 'absolute'
    i: np.ndarray                # (K,) int frame indices
    j: np.ndarray                # (K,) int frame indices (relative) or -1
    T: np.ndarray                # (K, 4, 4) column-vector transforms
    sigmas: np.ndarray           # (K, 6) [rx ry rz (rad) tx ty tz (m)]
    kernel: float                # robust kernel width in sigmas; 0 = Gaussian
    info: dict = field(default_factory=dict)
    key_i: str = "x"             # variable family of i ('x' PV pose, 'w' HoloLens world correction)
    key_j: str = "x"             # variable family of j
    estimator: str = "cauchy"    # 'cauchy' or 'gm' (Geman-McClure, bounded cost)
    information: np.ndarray | None = None   # (K, 6, 6) full information (replaces ``sigmas``), same order

    def __len__(self) -> int:
        return len(self.i)

    @classmethod
    def empty(cls, source: str, kind: str, kernel: float = 0.0, **info) -> "Constraints":
        return cls(source, kind, np.zeros(0, int), np.zeros(0, int), np.zeros((0, 4, 4)), np.zeros((0, 6)), kernel,
                   dict(info))


def sigmas(rot_deg: float, trans_m: float, n: int = 1) -> np.ndarray:
    """(n, 6) diagonal sigmas ``[rot rad x3, trans m x3]``."""
    return np.tile(np.r_[[np.radians(rot_deg)] * 3, [trans_m] * 3], (n, 1))


def pv_columns(rec) -> np.ndarray:
    """Reported PV camera -> world as column-vector 4x4 (N, 4, 4) (NaN where invalid)."""
    return np.swapaxes(rec.pv_poses, 1, 2)


def ahat_offsets(rec) -> np.ndarray:
    """Per-frame AHAT camera -> PV camera, column-vector (N, 4, 4): ``O_i = T_pv_i⁻¹ · T_ahat_i``.

    From the reported poses where both are valid; elsewhere the static rig offset
    ``(inv(ahat_ext) @ pv_ext)ᵀ`` (row-vector algebra: AHAT camera -> rig -> PV camera).
    """
    static = (invert_rigid(rec.ahat.extrinsics) @ rec.pv.extrinsics).T
    out = np.tile(static, (len(rec), 1, 1))
    both = rec.pv_valid & rec.depth_valid
    if both.any():
        ahat_row = invert_rigid(rec.ahat.extrinsics) @ rec.depth_poses[both]          # AHAT cam -> world
        rel_row = ahat_row @ invert_rigid(rec.pv_poses[both])                          # AHAT cam -> PV cam
        out[both] = np.swapaxes(rel_row, 1, 2)
    return out


def invert_columns(T: np.ndarray) -> np.ndarray:
    """Inverse of column-vector rigid transforms (..., 4, 4)."""
    return np.swapaxes(invert_rigid(np.swapaxes(T, -1, -2)), -1, -2)
