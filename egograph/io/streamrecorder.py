"""Microsoft HoloLens 2 StreamRecorder AHAT ray table (``Depth AHaT_lut.bin``) as an AhatCalibration.

The file is H x W x 3 little-endian float32, row-major (row v, column u, then x, y, z): the unit ray
of each pixel in the AHAT camera frame (x right, y down, z forward). A pixel without a ray has
z = 0; its x, y then hold the device's extrapolated z = 1 plane values (finite, not unit length).
hl2ss's ``uv2xy.bin`` is the same mapping on the z = 1 plane, so ``uv2xy = (x, y) / z`` where
z > 0 and ``(x, y)`` where z = 0; ``ray_valid`` is ``z > 0``.

The table carries no extrinsics, depth scale, alias distance or pinhole intrinsics: the caller
supplies the first three; the intrinsics and the undistort map are derived from the rays with the
hl2ss rules (:func:`egograph.io.calibration.bounding_pinhole`, ``undistort_map_from_rays``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from egograph.core.errors import InputError
from egograph.io.calibration import (
    AHAT_SHAPE,
    AhatCalibration,
    bounding_pinhole,
    undistort_map_from_rays,
)

UNIT_TOLERANCE = 1e-3
"""Largest | ‖ray‖ - 1 | accepted for a pixel with a ray (the real tables are within 2e-7)."""


def read_lut_rays(path: str | Path, shape: tuple[int, int] = AHAT_SHAPE) -> tuple[np.ndarray, np.ndarray]:
    """A StreamRecorder table -> (uv2xy (H, W, 2) float32 on the z = 1 plane, ray_valid (H, W) bool).

    InputError naming the file when it is missing, not H·W·3 float32 values, holds NaN/inf, has a
    ray of non-unit length, a ray pointing backwards (z < 0), or no ray at all.
    """
    path = Path(path)
    h, w = shape
    if not path.is_file():
        raise InputError(path, "StreamRecorder AHAT ray table missing")
    count = h * w * 3
    size = path.stat().st_size
    if size != count * 4:
        raise InputError(path, f"expected {h}x{w}x3 float32 rays ({count * 4} bytes), found {size} bytes")
    lut = np.fromfile(path, dtype="<f4").reshape(h, w, 3).astype(np.float64)
    if not np.isfinite(lut).all():
        bad = int((~np.isfinite(lut)).any(-1).sum())
        raise InputError(path, f"{bad} pixel(s) hold NaN or infinite values")
    z = lut[..., 2]
    if (z < 0).any():
        raise InputError(path, f"{int((z < 0).sum())} ray(s) point backwards (z < 0)")
    valid = z > 0
    if not valid.any():
        raise InputError(path, "no pixel has a ray (every z is 0)")
    norm_err = np.abs(np.linalg.norm(lut[valid], axis=-1) - 1.0)
    if norm_err.max() > UNIT_TOLERANCE:
        raise InputError(path, f"{int((norm_err > UNIT_TOLERANCE).sum())} ray(s) are not unit length "
                               f"(largest | |ray| - 1 | = {norm_err.max():.3g}); not a StreamRecorder table?")
    uv2xy = np.where(valid[..., None], lut[..., :2] / np.where(valid, z, 1.0)[..., None], lut[..., :2])
    return uv2xy.astype(np.float32), valid


def read_streamrecorder_lut(path: str | Path, extrinsics: np.ndarray, *, scale: float = 1000.0,
                            alias_mm: float = 1055.0, shape: tuple[int, int] = AHAT_SHAPE) -> AhatCalibration:
    """A StreamRecorder ``Depth AHaT_lut.bin`` -> the AhatCalibration an hl2ss folder gives.

    ``extrinsics``: (4, 4) rig node -> AHAT camera (row vectors, hl2ss form); ``scale``: raw units
    per metre of range as in ``scale.bin``; ``alias_mm``: wrap distance as in ``alias.bin`` (the
    defaults are current hl2ss firmware's). ``intrinsics`` is the hl2ss bounding pinhole of the rays,
    ``undistort_map`` the hl2ss-form map computed from the rays (about 1 s).
    """
    uv2xy, valid = read_lut_rays(path, shape)
    extrinsics = np.asarray(extrinsics, dtype=np.float64)
    if extrinsics.shape != (4, 4) or not np.isfinite(extrinsics).all():
        raise InputError(path, f"extrinsics for the table must be a finite 4x4 matrix (got shape {extrinsics.shape})")
    for name, value in (("scale", scale), ("alias_mm", alias_mm)):
        if not (np.isfinite(value) and value > 0):
            raise InputError(path, f"{name} for the table must be a positive number (got {value!r})")
    intrinsics = bounding_pinhole(uv2xy)
    return AhatCalibration(uv2xy=uv2xy, extrinsics=extrinsics, scale=float(scale), alias_mm=float(alias_mm),
                           intrinsics=intrinsics, undistort_map=undistort_map_from_rays(uv2xy, valid, intrinsics),
                           ray_valid=valid)
