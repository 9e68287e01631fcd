"""HoloLens 2 (hl2ss) geometry conventions, as small vectorised functions.

Conventions (checked by round-trip tests in ``tests/test_geometry.py``):

* Points are homogeneous **row** vectors multiplied on the right: ``p_out = p_in @ M``;
  the translation of a 4x4 rigid transform is its last row.
* A stored pose maps the sensor's reference (rig node) to world; for the PV camera
  the stored pose maps the PV camera itself to world.
* ``extrinsics`` maps rig node -> camera, so camera -> rig node is ``inv(extrinsics)``.
* AHAT camera: x right, y down, z forward (metres). Pixel (u, v) -> ray ``[uv2xy, 1]``.
  The raw value is the range along the ray in units of ``depth_factor / scale`` metres
  (``depth_factor`` 4 in the hl2ss version IT3DEgo used, 1 in current hl2ss; ``scale``
  is ``scale.bin``, 1000), wrapping at the alias distance (``alias.bin``, mm).
* PV camera: x right, y up, looking down -z (metres). Its 4x4 ``intrinsics`` is
  ``[[-fx,0,0,0],[0,fy,0,0],[cx,cy,1,0],[0,0,0,1]]`` and ``uvw = xyz1 @ K[:, :3]``.
"""

from __future__ import annotations

import numpy as np

from egograph.io.poses import pose_validity  # noqa: F401  (hl2ss pose convention; defined with the pose reader)

INVALID_RAW = 0  # AHAT raw value of a pixel with no return


# ---------------------------------------------------------------- rigid transforms

def to_homogeneous(points: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 4) with a trailing 1."""
    points = np.asarray(points, dtype=np.float64)
    return np.concatenate([points, np.ones(points.shape[:-1] + (1,))], axis=-1)


def transform_points(points: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Apply a 4x4 row-vector transform to (..., 3) points: ``[p, 1] @ M``, returns (..., 3)."""
    points = np.asarray(points, dtype=np.float64)
    m = np.asarray(matrix, dtype=np.float64)
    return points @ m[:3, :3] + m[3, :3]


def invert_rigid(matrix: np.ndarray) -> np.ndarray:
    """Inverse of a rigid row-vector transform (or a stack of them, (..., 4, 4))."""
    m = np.asarray(matrix, dtype=np.float64)
    out = np.zeros_like(m)
    r = m[..., :3, :3]
    rt = np.swapaxes(r, -1, -2)
    out[..., :3, :3] = rt
    out[..., 3, :3] = -np.einsum("...j,...jk->...k", m[..., 3, :3], rt)
    out[..., 3, 3] = 1.0
    return out


def rigid_from_rt(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Row-vector 4x4 from a column-convention rotation R (x' = R x) and translation t.

    ``[p, 1] @ M == R @ p + t``; i.e. ``M[:3, :3] = R.T`` and ``M[3, :3] = t``.
    """
    rotation = np.asarray(rotation, dtype=np.float64)
    translation = np.asarray(translation, dtype=np.float64)
    m = np.zeros(rotation.shape[:-2] + (4, 4))
    m[..., :3, :3] = np.swapaxes(rotation, -1, -2)
    m[..., 3, :3] = translation
    m[..., 3, 3] = 1.0
    return m


def camera_center(pose: np.ndarray) -> np.ndarray:
    """World position of a sensor (its origin) from its row-vector pose(s): the last row."""
    return np.asarray(pose, dtype=np.float64)[..., 3, :3]


# ---------------------------------------------------------------- AHAT depth

def ahat_xy1(uv2xy: np.ndarray) -> np.ndarray:
    """The AHAT ray ``[x, y, 1]`` per pixel, (..., 3), in ``uv2xy``'s dtype (camera frame, z = 1)."""
    uv2xy = np.asarray(uv2xy)
    return np.concatenate([uv2xy, np.ones(uv2xy.shape[:-1] + (1,), uv2xy.dtype)], axis=-1)


def ahat_ray_norms(uv2xy: np.ndarray) -> np.ndarray:
    """‖[x, y, 1]‖ per pixel, (H, W): the range/z ratio of each AHAT ray (computed in ``uv2xy``'s dtype)."""
    return np.sqrt(uv2xy[..., 0] ** 2 + uv2xy[..., 1] ** 2 + 1.0)


def ahat_unit_rays(uv2xy: np.ndarray) -> np.ndarray:
    """Unit ray directions per pixel, (..., 3) float64, AHAT camera frame: ``[x, y, 1] / ‖[x, y, 1]‖``.

    A raw reading times ``depth_factor / scale`` (metres of range) times this direction is the
    camera point. Not cached: about 25 ms for the 512x512 AHAT grid, once per lift or scene.
    """
    uv2xy = np.asarray(uv2xy, dtype=np.float64)
    return ahat_xy1(uv2xy) / ahat_ray_norms(uv2xy)[..., None]


def ahat_raw_to_range(raw: np.ndarray, scale: float, depth_factor: float) -> np.ndarray:
    """Raw AHAT values -> range along the ray (metres). 0 stays 0 (no return)."""
    return np.asarray(raw, dtype=np.float64) * (depth_factor / scale)


def ahat_range_to_raw(range_m: np.ndarray, scale: float, depth_factor: float) -> np.ndarray:
    """Range along the ray (metres, already wrapped) -> raw AHAT units (uint16, rounded)."""
    r = np.asarray(range_m)
    raw = np.rint(r * r.dtype.type(scale / depth_factor)) if r.dtype.kind == "f" else np.rint(r * (scale / depth_factor))
    return np.clip(raw, 0, np.iinfo(np.uint16).max).astype(np.uint16)


def ahat_raw_to_camera(raw: np.ndarray, uv2xy: np.ndarray, scale: float, depth_factor: float) -> np.ndarray:
    """AHAT raw depth (H, W) -> camera points (H, W, 3), metres; z = 0 where raw == 0.

    ``z = raw / (‖xy1‖ · scale / depth_factor)``; ``xyz = [x, y, 1] · z``.
    """
    xy1 = ahat_xy1(uv2xy)
    z = np.asarray(raw, dtype=np.float64) / (ahat_ray_norms(uv2xy) * (scale / depth_factor))
    return xy1 * z[..., None]


def wrap_range(range_m: np.ndarray, alias_m: float) -> np.ndarray:
    """The range the AHAT sensor reports for a true range: it wraps at the alias distance."""
    return np.mod(range_m, alias_m)


def alias_candidates(range_m: np.ndarray, alias_m: float, max_range_m: float) -> np.ndarray:
    """All true ranges compatible with a wrapped reading: ``r + k · alias`` ≤ ``max_range_m``.

    Returns (..., K) with NaN for candidates beyond ``max_range_m`` (K = max over inputs).
    """
    r = np.asarray(range_m, dtype=np.float64)
    k_max = int(np.floor(max_range_m / alias_m)) + 1
    cands = r[..., None] + alias_m * np.arange(k_max)
    return np.where(cands <= max_range_m, cands, np.nan)


def ahat_project(points_cam: np.ndarray, intrinsics: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """AHAT camera points (..., 3) -> pixel coordinates (..., 2) and z (metres, > 0 in front).

    Uses the pinhole ``intrinsics.bin`` (4x4 hl2ss form ``[[fx,0,0,0],[0,fy,0,0],[cx,cy,1,0],[0,0,0,1]]``)
    whose pixel centres sit at integer + 0.5 like ``uv2xy``.
    """
    p = np.asarray(points_cam, dtype=np.float64)
    uvw = p @ np.asarray(intrinsics, dtype=np.float64)[:3, :3]
    z = uvw[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = uvw[..., :2] / z[..., None]
    return uv, p[..., 2]


# ---------------------------------------------------------------- PV camera

def pv_project(points_cam: np.ndarray, intrinsics: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PV camera points (..., 3) -> pixels (..., 2) and depth in front of the camera (metres).

    The PV camera looks down -z, so the returned depth is ``-z`` (positive in front).
    """
    p = np.asarray(points_cam, dtype=np.float64)
    uvw = p @ np.asarray(intrinsics, dtype=np.float64)[:3, :3]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = uvw[..., :2] / uvw[..., 2:3]
    return uv, -p[..., 2]


def pv_unproject(uv: np.ndarray, depth: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """PV pixels (..., 2) at depth in front of the camera (metres) -> PV camera points (..., 3)."""
    k = np.asarray(intrinsics, dtype=np.float64)
    fx, fy, cx, cy = -k[0, 0], k[1, 1], k[2, 0], k[2, 1]
    uv = np.asarray(uv, dtype=np.float64)
    d = np.asarray(depth, dtype=np.float64)
    z = -d
    x = (uv[..., 0] - cx) * d / fx
    y = -(uv[..., 1] - cy) * d / fy
    return np.stack([x, y, z], axis=-1)


def pv_intrinsics_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """The hl2ss PV 4x4 intrinsics ``[[-fx,0,0,0],[0,fy,0,0],[cx,cy,1,0],[0,0,0,1]]``."""
    k = np.eye(4)
    k[0, 0], k[1, 1], k[2, 0], k[2, 1] = -fx, fy, cx, cy
    return k


def rm_intrinsics_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """The hl2ss research-mode 4x4 intrinsics ``[[fx,0,0,0],[0,fy,0,0],[cx,cy,1,0],[0,0,0,1]]``."""
    k = np.eye(4)
    k[0, 0], k[1, 1], k[2, 0], k[2, 1] = fx, fy, cx, cy
    return k


def pv_to_opencv(intrinsics: np.ndarray, pv_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """hl2ss PV intrinsics + pose -> OpenCV ``K`` (3x3) and camera-to-world (4x4, column vectors).

    OpenCV cameras look down +z with y down; the flip ``diag(1, -1, -1, 1)`` converts.
    """
    k = np.asarray(intrinsics, dtype=np.float64)
    k_cv = np.array([[-k[0, 0], 0, k[2, 0]], [0, k[1, 1], k[2, 1]], [0, 0, 1.0]])
    cam_to_world = np.asarray(pv_pose, dtype=np.float64).T @ np.diag([1.0, -1.0, -1.0, 1.0])
    return k_cv, cam_to_world


# ---------------------------------------------------------------- chains between sensors

def ahat_to_world_matrix(ahat_extrinsics: np.ndarray, depth_pose: np.ndarray) -> np.ndarray:
    """AHAT camera -> world: ``inv(ahat_extrinsics) @ depth_pose`` (row vectors)."""
    return invert_rigid(ahat_extrinsics) @ np.asarray(depth_pose, dtype=np.float64)


def world_to_pv_matrix(pv_pose: np.ndarray) -> np.ndarray:
    """World -> PV camera: ``inv(pv_pose)``."""
    return invert_rigid(pv_pose)


def ahat_to_pv_image_static(ahat_extrinsics: np.ndarray, pv_extrinsics: np.ndarray,
                            pv_intrinsics: np.ndarray) -> np.ndarray:
    """AHAT camera -> PV image through the static rig: ``inv(ahat_ext) @ pv_ext @ pv_K``.

    This is the mapping the IT3DEgo reference code uses; it ignores head motion
    between the AHAT and PV capture times.
    """
    return invert_rigid(ahat_extrinsics) @ np.asarray(pv_extrinsics, dtype=np.float64) @ \
        np.asarray(pv_intrinsics, dtype=np.float64)


def ahat_to_pv_image_posed(ahat_extrinsics: np.ndarray, depth_pose: np.ndarray, pv_pose: np.ndarray,
                           pv_intrinsics: np.ndarray) -> np.ndarray:
    """AHAT camera -> PV image through per-frame poses: ``inv(ahat_ext) @ depth_pose @ inv(pv_pose) @ pv_K``.

    Accounts for head motion between the two sensors' timestamps.
    """
    return ahat_to_world_matrix(ahat_extrinsics, depth_pose) @ invert_rigid(pv_pose) @ \
        np.asarray(pv_intrinsics, dtype=np.float64)


def project_homogeneous(points: np.ndarray, matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points (..., 3) through a 4x4 (or 4x3) projective row-vector matrix -> (uv, w)."""
    m = np.asarray(matrix, dtype=np.float64)
    uvw = to_homogeneous(points) @ m[:, :3]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = uvw[..., :2] / uvw[..., 2:3]
    return uv, uvw[..., 2]
