"""The ``reference`` lifting mode: the public IT3DEgo reference code's single-pixel rule, reproduced exactly.

Every AHAT pixel is turned into a camera point (raw 0 gives the point 0, and it is *not*
removed), all 262k points are pushed through the static rig chain into the PV image, the
integer pixel each lands on (truncation, last write wins) gets the point, and a box takes the
valid pixel closest (L1, in crop-local integers) to its centre, all from the box corners
truncated to integers; boxes starting in the top-left corner (``int(x1) <= 1 and int(y1) <= 1``)
are dropped, as the reference code drops them. No unwrapping, so anything
farther than the alias distance (1.055 m) comes out about 1 m (or 2 m...) too close to the
camera.

Frames and units: AHAT camera (x right, y down, z forward), metres; PV image pixels (1280x720,
pixel ``i`` covers ``[i, i+1)``). Driven by :func:`egograph.geometry.lift.lift_recording`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from egograph.geometry.hl2ss import ahat_ray_norms, ahat_to_pv_image_static, ahat_xy1


@dataclass
class ReferenceSetup:
    """Per-recording inputs of the reference rule."""

    xy1: np.ndarray                  # (H, W, 3) float64 AHAT rays [uv2xy, 1]
    norms: np.ndarray                # (H, W) float64 ‖[uv2xy, 1]‖
    scale: float                     # raw-to-mm scale (scale.bin)
    depth_factor: float              # raw AHAT unit
    ahat_to_pv_image: np.ndarray     # 4x4 row vectors through the static rig (whatever the config says)
    pv_shape: tuple[int, int]        # PV image rows, columns


def reference_setup(rec) -> ReferenceSetup:
    """The recording's rays and static AHAT -> PV image chain, as the reference code uses them."""
    uv2xy = np.asarray(rec.ahat.uv2xy)
    return ReferenceSetup(
        xy1=ahat_xy1(uv2xy).astype(np.float64), norms=ahat_ray_norms(uv2xy.astype(np.float64)),
        scale=float(rec.ahat.scale), depth_factor=float(rec.depth_factor),
        ahat_to_pv_image=ahat_to_pv_image_static(rec.ahat.extrinsics, rec.pv.extrinsics, rec.pv.intrinsics),
        pv_shape=rec.pv.shape)


def reference_frame_map(setup: ReferenceSetup, raw: np.ndarray) -> np.ndarray:
    """One frame's PV map of AHAT camera points (:func:`reference_depth_map`) from its raw depth."""
    return reference_depth_map(raw, setup.xy1, setup.norms, setup.scale, setup.depth_factor,
                               setup.ahat_to_pv_image, setup.pv_shape)


def reference_depth_map(raw: np.ndarray, xy1: np.ndarray, norms: np.ndarray, scale: float, depth_factor: float,
                        ahat_to_pv_image: np.ndarray, pv_shape: tuple[int, int]) -> np.ndarray:
    """The reference code's AHAT -> PV registration: (rows, cols, 3) float32 map of AHAT camera points.

    Every pixel, raw 0 included (its point is 0 and it still overwrites whatever landed on
    its PV pixel before), is projected with ``ahat_to_pv_image``; the PV pixel is the
    truncated ``uv``; with several points per pixel the last one written wins.
    """
    h, w = pv_shape
    z = raw / (norms * scale / depth_factor)
    xyz = (xy1 * z[..., None]).reshape(-1, 3)
    xyz1 = np.concatenate([xyz, np.ones((len(xyz), 1))], axis=1)
    p = xyz1 @ ahat_to_pv_image
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = p[:, :2] / p[:, 2:3]
        u = uv[:, 0].astype(int)  # truncation towards zero, as the reference code
        v = uv[:, 1].astype(int)
    # per column: the same test as isfinite(uv).all(axis=1), without a slow reduction over an axis of 2
    keep = (u >= 0) & (u < w) & (v >= 0) & (v < h) & np.isfinite(uv[:, 0]) & np.isfinite(uv[:, 1])
    out = np.zeros((h, w, 3), np.float32)
    out[v[keep], u[keep]] = xyz[keep]
    return out


def reference_box(box: Sequence[float]) -> tuple[int, int, int, int] | None:
    """The box as the reference code holds it: each corner truncated towards zero (``int(float(s))``
    when it reads the association file), or None when the reference code drops it — its border
    rule drops every box with ``int(x1) <= 1 and int(y1) <= 1`` (a proposal starting in the image's
    top-left corner, which SAM returns for whole-image masks). PV pixels."""
    x1, y1, x2, y2 = (int(float(v)) for v in box)
    if x1 <= 1 and y1 <= 1:
        return None
    return x1, y1, x2, y2


def reference_pick(depth_map: np.ndarray, box: Sequence[int]) -> tuple[np.ndarray, int] | None:
    """The reference code's choice of one AHAT point for an integer box (x1, y1, x2, y2) as
    :func:`reference_box` gives it, PV pixels.

    In the crop ``map[y1:y2, x1:x2]`` (Python slicing, as the reference code's, also for a corner
    outside the image), among pixels with non-zero z, the first (row-major) minimising
    ``|row - int((y2-y1)/2)| + |col - int((x2-x1)/2)|`` (crop-local). The centre is taken from the
    truncated corners: on a fractional box that is the reference's pixel, where halving the float
    size can pick its neighbour. Returns (AHAT camera point (3,), pixels with depth in the crop),
    or None.
    """
    x1, y1, x2, y2 = (int(v) for v in box)
    crop = depth_map[y1:y2, x1:x2]
    rows, cols = np.nonzero(crop[..., 2] != 0)
    if len(rows) == 0:
        return None
    dist = np.abs(rows - int((y2 - y1) / 2)) + np.abs(cols - int((x2 - x1) / 2))
    j = int(np.argmin(dist))
    return crop[rows[j], cols[j]].astype(np.float64), len(rows)
