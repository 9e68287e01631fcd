"""The real AHAT lens from its ray table: field of view, focal length, pixel <-> camera point.

Image points are continuous: pixel (row i, column j) has its centre at (j + 0.5, i + 0.5), the
point ``uv2xy[i, j]`` was sampled at. Camera frame: x right, y down, z forward (metres).

What the real tables show (packaged hl2-a / hl2-b, see tests/test_real_calibration.py): an
equidistant-like fisheye, focal length about 254 / 253 px at the centre (px per unit of the z = 1
plane) falling to about 56 px per unit (225 px per radian) at 60 deg; rays exist up to 60 deg off
the axis, which reaches the image edges at the middle of each side: 118 deg across and down
through the optical centre. ``intrinsics.bin`` (fx 114) is not a fit: it is the pinhole that fits
the bounding box of every uv2xy value into 512 pixels (:func:`egograph.io.calibration.bounding_pinhole`),
and its undistort map resamples the raw image into that wide pinhole view.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from egograph.io.calibration import AhatCalibration, equidistant_model, pixels_to_rays, rays_to_pixels

CENTRAL_FIT_RADIUS_PX = 16.0
"""Pixel radius around the optical centre of the pinhole fit that gives the lens' central focal length."""


def optical_centre(calib: AhatCalibration) -> np.ndarray:
    """The image point (2,) whose ray is the optical axis (ray (0, 0)), continuous pixels."""
    return rays_to_pixels(np.zeros(2), calib.uv2xy, calib.valid_mask)


def _angle_deg(xy_a: np.ndarray, xy_b: np.ndarray) -> float:
    a, b = np.append(xy_a, 1.0), np.append(xy_b, 1.0)
    return float(np.degrees(np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0))))


def field_of_view_deg(calib: AhatCalibration) -> tuple[float, float]:
    """(across, down) in degrees: the angle between the outermost valid pixel centres' rays on the
    row and on the column through the optical centre."""
    xy = np.asarray(calib.uv2xy, dtype=np.float64)
    valid = calib.valid_mask
    j, i = (int(k) for k in np.floor(optical_centre(calib)))
    row, col = np.flatnonzero(valid[i]), np.flatnonzero(valid[:, j])
    return _angle_deg(xy[i, row[0]], xy[i, row[-1]]), _angle_deg(xy[col[0], j], xy[col[-1], j])


def max_ray_angle_deg(calib: AhatCalibration) -> float:
    """Largest angle (deg) between a valid ray and the optical axis."""
    xy = np.asarray(calib.uv2xy, dtype=np.float64)[calib.valid_mask]
    return float(np.degrees(np.arctan(np.linalg.norm(xy, axis=-1).max())))


def fit_pinhole(calib: AhatCalibration, radius_px: float | None = CENTRAL_FIT_RADIUS_PX) -> tuple[float, float, float, float]:
    """Least-squares pinhole ``u = fx · x + cx``, ``v = fy · y + cy`` (continuous pixels) over the valid
    pixels within ``radius_px`` of the optical centre (None: all valid pixels). Returns fx, fy, cx, cy.

    The fit depends strongly on the radius on a fisheye: 254 px within 16 px, 239 px within 128 px,
    182 px over the whole field (hl2-a); none of them is intrinsics.bin's 114 px.
    """
    xy = np.asarray(calib.uv2xy, dtype=np.float64)
    h, w = xy.shape[:2]
    vv, uu = np.mgrid[0:h, 0:w] + 0.5
    mask = calib.valid_mask.copy()
    if radius_px is not None:
        c = optical_centre(calib)
        mask &= np.hypot(uu - c[0], vv - c[1]) <= radius_px
    out = []
    for k, pix in ((0, uu), (1, vv)):
        design = np.stack([xy[..., k][mask], np.ones(int(mask.sum()))], axis=1)
        out.append(np.linalg.lstsq(design, pix[mask], rcond=None)[0])
    (fx, cx), (fy, cy) = out
    return float(fx), float(fy), float(cx), float(cy)


def pixel_to_camera(uv: np.ndarray, z: np.ndarray, calib: AhatCalibration) -> np.ndarray:
    """Continuous AHAT image points (..., 2) at depth ``z`` (metres along the axis) -> camera points (..., 3)."""
    xy = pixels_to_rays(uv, calib.uv2xy)
    z = np.asarray(z, dtype=np.float64)[..., None]
    return np.concatenate([xy * z, z], axis=-1)


def camera_to_pixel(points: np.ndarray, calib: AhatCalibration) -> np.ndarray:
    """AHAT camera points (..., 3) -> continuous image points (..., 2) through the real rays
    (the inverse of :func:`pixel_to_camera`); NaN behind the camera or where no pixel has that ray.

    Unlike :func:`egograph.geometry.hl2ss.ahat_project` with ``intrinsics.bin`` (a wide pinhole, off by
    up to 86 px on the real lenses) this lands on the pixel whose ray holds the point.
    """
    p = np.asarray(points, dtype=np.float64)
    z = p[..., 2:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = np.where(z > 0, p[..., :2] / z, np.nan)
    return rays_to_pixels(xy, calib.uv2xy, calib.valid_mask)


LOOKUP_STEP_PX = 4.0
"""Grid spacing of :class:`PixelLookup`, pixels of the equidistant model: the map from it to the real
pixels is smooth (the lens' departure from equidistance), so bilinear interpolation between nodes
this far apart stays within 0.02 px of :func:`camera_to_pixel` (tests/test_real_calibration.py)."""


@dataclass
class PixelLookup:
    """Camera point -> AHAT pixel for one calibration at the cost of a pinhole projection: the real
    pixels tabulated on a grid over the equidistant model's image plane (:func:`pixel_lookup`).

    :func:`camera_to_pixel` solves each point by Newton's method on the ray table; trackers project
    a landmark into thousands of frames, one at a time, and need this instead."""

    centre: np.ndarray   # (2,) continuous pixel of the optical axis (equidistant model)
    f_px_per_rad: float  # equidistant model's pixels per radian off the axis
    origin: float        # equidistant coordinate (px from the centre) of grid index 0, both axes
    step: float          # grid spacing, px
    grid: np.ndarray     # (G, G, 2) continuous pixel per node; NaN where the node's ray has no pixel

    def project(self, points: np.ndarray) -> np.ndarray:
        """AHAT camera points (N, 3) (x right, y down, z forward, metres) -> continuous pixels (N, 2);
        NaN behind the camera, outside the field or next to its rim."""
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        r_xy = np.hypot(p[:, 0], p[:, 1])
        theta = np.arctan2(r_xy, p[:, 2])
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(r_xy > 0, self.f_px_per_rad * theta / r_xy, 0.0)
        e = p[:, :2] * scale[:, None]
        g = (e - self.origin) / self.step
        n = self.grid.shape[0]
        k0 = np.floor(g).astype(np.int64)
        inside = (k0 >= 0).all(1) & (k0 < n - 1).all(1) & (p[:, 2] > 0)
        k0 = np.clip(k0, 0, n - 2)
        t = g - k0
        j, i = k0[:, 0], k0[:, 1]
        tu, tv = t[:, :1], t[:, 1:]
        out = ((1 - tv) * ((1 - tu) * self.grid[i, j] + tu * self.grid[i, j + 1])
               + tv * ((1 - tu) * self.grid[i + 1, j] + tu * self.grid[i + 1, j + 1]))
        out[~inside] = np.nan
        return out


    def project_one(self, point) -> tuple[float, float] | None:
        """One camera point (3,) -> continuous pixel (u, v), or None; :meth:`project` without numpy's
        per-call overhead (a landmark tested in one frame at a time)."""
        x, y, z = float(point[0]), float(point[1]), float(point[2])
        if z <= 0:
            return None
        r_xy = math.hypot(x, y)
        scale = self.f_px_per_rad * math.atan2(r_xy, z) / r_xy if r_xy > 0 else 0.0
        gu, gv = (x * scale - self.origin) / self.step, (y * scale - self.origin) / self.step
        j, i = math.floor(gu), math.floor(gv)
        n = self.grid.shape[0]
        if not (0 <= j < n - 1 and 0 <= i < n - 1):
            return None
        tu, tv = gu - j, gv - i
        q = self.grid[i:i + 2, j:j + 2]
        u = (1 - tv) * ((1 - tu) * q[0, 0, 0] + tu * q[0, 1, 0]) + tv * ((1 - tu) * q[1, 0, 0] + tu * q[1, 1, 0])
        v = (1 - tv) * ((1 - tu) * q[0, 0, 1] + tu * q[0, 1, 1]) + tv * ((1 - tu) * q[1, 0, 1] + tu * q[1, 1, 1])
        if not (math.isfinite(u) and math.isfinite(v)):
            return None
        return float(u), float(v)


def pixel_lookup(calib: AhatCalibration, step_px: float = LOOKUP_STEP_PX) -> PixelLookup:
    """The :class:`PixelLookup` of a calibration: built on the first call (about 0.5 s for 512 x 512
    rays), then kept in ``calib.derived``."""
    key = ("pixel_lookup", float(step_px))
    if key not in calib.derived:
        calib.derived[key] = _build_lookup(calib, step_px)
    return calib.derived[key]


def _build_lookup(calib: AhatCalibration, step_px: float) -> PixelLookup:
    table = np.asarray(calib.uv2xy, dtype=np.float64)
    centre, f = equidistant_model(table, calib.valid_mask)
    # the field reaches at most 90 deg off the axis: f · pi / 2 px from the centre
    half = step_px * np.ceil(f * np.pi / 2 / step_px)
    axis = np.arange(-half, half + step_px / 2, step_px)
    eu, ev = np.meshgrid(axis, axis)
    e = np.stack([eu, ev], -1).reshape(-1, 2)
    theta = np.linalg.norm(e, axis=1) / f
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = np.where((theta < np.pi / 2 - 1e-6)[:, None],
                      e * (np.tan(theta) / np.where(theta > 0, theta * f, 1.0))[:, None], np.nan)
    xy[theta == 0] = 0.0
    pix = rays_to_pixels(xy, table, calib.valid_mask)
    return PixelLookup(centre=centre, f_px_per_rad=f, origin=float(-half), step=float(step_px),
                       grid=pix.reshape(len(axis), len(axis), 2))


def undistort_map_error_px(calib: AhatCalibration, max_angle_deg: float = 58.0) -> tuple[float, int]:
    """How well ``calib.undistort_map`` agrees with the rays and intrinsics: the largest distance (raw
    pixels) between ``uv2xy`` sampled at ``undistort_map[i, j]`` mapped back through the rays and the
    stored point, over pinhole pixels whose ray lies within ``max_angle_deg``; and how many of those
    the map marks as without a pixel (``(W - 0.5, H - 0.5)``).

    The hl2ss map: entry [i, j] is the raw image point (continuous, centre + 0.5) of the pinhole ray
    ``((j - cx) / fx, (i - cy) / fy)`` of pixel index (j, i); ``cv2.remap(raw, map - 0.5, ...)``.
    """
    k = np.asarray(calib.intrinsics, dtype=np.float64)
    h, w = calib.shape
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([(uu - k[2, 0]) / k[0, 0], (vv - k[2, 1]) / k[1, 1]], -1)
    inside = np.degrees(np.arctan(np.linalg.norm(rays, axis=-1))) <= max_angle_deg
    um = np.asarray(calib.undistort_map, dtype=np.float64)
    missing = inside & np.all(um == [w - 0.5, h - 0.5], axis=-1)
    use = inside & ~missing
    mine = rays_to_pixels(rays[use], calib.uv2xy, calib.valid_mask)
    err = np.linalg.norm(mine - um[use], axis=-1)
    return (float(np.nanmax(err)) if np.isfinite(err).any() else float("inf")), int(missing.sum())


@dataclass
class AhatModelSummary:
    """What ``egograph info`` reports about the AHAT lens (degrees, continuous pixels)."""

    fov_across_deg: float
    fov_down_deg: float
    max_ray_angle_deg: float
    focal_px: tuple[float, float]             # central pinhole fit (fx, fy), px per unit of the z = 1 plane
    principal_point_px: tuple[float, float]   # optical centre (ray (0, 0))
    intrinsics_focal_px: tuple[float, float]  # intrinsics.bin fx, fy (bounding pinhole, not the lens)
    pixels_without_ray: int

    def to_dict(self) -> dict:
        return asdict(self)


def ahat_model_summary(calib: AhatCalibration) -> AhatModelSummary:
    """Field of view, central focal length and principal point of an AHAT calibration (about 0.3 s)."""
    across, down = field_of_view_deg(calib)
    fx, fy, _, _ = fit_pinhole(calib)
    c = optical_centre(calib)
    k = np.asarray(calib.intrinsics, dtype=np.float64)
    return AhatModelSummary(
        fov_across_deg=round(across, 2), fov_down_deg=round(down, 2),
        max_ray_angle_deg=round(max_ray_angle_deg(calib), 2),
        focal_px=(round(fx, 2), round(fy, 2)), principal_point_px=(round(float(c[0]), 2), round(float(c[1]), 2)),
        intrinsics_focal_px=(round(float(k[0, 0]), 2), round(float(k[1, 1]), 2)),
        pixels_without_ray=int((~calib.valid_mask).sum()),
    )
