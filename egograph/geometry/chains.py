"""Per-frame sensor chains a lift works in: AHAT camera -> world, -> PV camera, -> PV image.

Row-vector 4x4 matrices (``p_out = p_in @ M``, metres; the PV image chain gives homogeneous
pixels), built from :mod:`egograph.geometry.hl2ss`. Shared by both lifting modes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from egograph.geometry.hl2ss import ahat_to_world_matrix, invert_rigid, pose_validity


@dataclass
class FrameChains:
    """One frame's matrices (row vectors): AHAT camera -> world, -> PV camera, -> PV image; PV camera -> AHAT camera."""

    ahat_to_world: np.ndarray
    ahat_to_pvcam: np.ndarray
    ahat_to_pvimg: np.ndarray
    pvcam_to_ahat: np.ndarray


def frame_chains(rec, i: int, posed: bool) -> FrameChains | None:
    """Frame ``i``'s chains, or None when a pose it needs is invalid.

    ``posed``: AHAT -> PV camera through the frame's depth and PV poses (follows head motion
    between the two capture times; needs both poses); otherwise through the static rig
    extrinsics (needs the depth pose only, for the world chain).
    """
    depth_pose = rec.depth_poses[i]
    if not (rec.depth_valid[i] and pose_validity(depth_pose)):
        return None
    to_world = ahat_to_world_matrix(rec.ahat.extrinsics, depth_pose)
    if posed:
        pv_pose = rec.pv_poses[i]
        if not (rec.pv_valid[i] and pose_validity(pv_pose)):
            return None
        to_pvcam = to_world @ invert_rigid(pv_pose)
    else:
        to_pvcam = invert_rigid(rec.ahat.extrinsics) @ np.asarray(rec.pv.extrinsics, dtype=np.float64)
    return FrameChains(to_world, to_pvcam, to_pvcam @ np.asarray(rec.pv.intrinsics, dtype=np.float64),
                       invert_rigid(to_pvcam))
