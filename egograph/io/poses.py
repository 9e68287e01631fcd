"""Per-frame pose files: ``{"<ts>": 4x4 list}`` (row-vector, sensor/rig -> world, metres)."""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import numpy as np

from egograph.core.errors import InputError
from egograph.io.atomic import atomic_write_text
from egograph.io.textio import read_json_checked


def pose_validity(poses: np.ndarray, tol: float = 1e-3) -> np.ndarray:
    """Which 4x4 poses (N, 4, 4) are usable: finite, ``M[3,3] == 1``, orthonormal rotation.

    hl2ss writes ``M[3,3] == 0`` for frames without tracking; such poses are singular.
    """
    p = np.asarray(poses, dtype=np.float64)
    finite = np.isfinite(p).all(axis=(-1, -2))
    safe = np.where(finite[..., None, None], p, 0.0)
    r = safe[..., :3, :3]
    rrt = np.einsum("...ij,...kj->...ik", r, r)
    ortho = np.abs(rrt - np.eye(3)).max(axis=(-1, -2)) < tol
    det_ok = np.abs(np.linalg.det(r) - 1.0) < tol
    last_col = np.abs(safe[..., :3, 3]).max(axis=-1) < tol
    homog = np.abs(safe[..., 3, 3] - 1.0) < tol
    return finite & ortho & det_ok & last_col & homog


INVALID_POSE_POLICIES = ("error", "skip")
_INT_KEY = re.compile(r"[+-]?[0-9]+")


def _read_json(path: Path):
    """The JSON document of a pose file; InputError naming the file for anything unreadable: missing,
    a folder or otherwise not readable, not UTF-8 (a UTF-8 byte order mark is allowed), not JSON,
    nested too deeply to parse."""
    return read_json_checked(path, "pose file")


def read_pose_json(path: str | Path, invalid: str = "error") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read a pose JSON -> (timestamps int64 sorted numerically, poses (N,4,4), valid (N,) bool).

    ``invalid='error'`` raises on a NaN/singular/non-rigid pose, naming the file and timestamp;
    ``invalid='skip'`` keeps the frame with ``valid=False`` (pose set to NaN) and warns once.
    A pose is never silently used when invalid.
    """
    path = Path(path)
    if invalid not in INVALID_POSE_POLICIES:
        raise ValueError(f"invalid pose policy {invalid!r}; expected one of {INVALID_POSE_POLICIES}")
    data = _read_json(path)
    if not isinstance(data, dict) or not data:
        raise InputError(path, "expected a non-empty JSON object {timestamp: 4x4 matrix}")
    keys = []
    for k in data:
        # ASCII digits only: int() would also take "1_000", " 12 " and other scripts' digits
        if not _INT_KEY.fullmatch(k):
            raise InputError(path, f"key {k[:40]!r} is not an integer timestamp")
        keys.append((int(k), k))
    keys.sort()
    ts = np.array([k for k, _ in keys], dtype=np.int64)
    if len(np.unique(ts)) != len(ts):
        raise InputError(path, "duplicate timestamps (keys equal as integers)")
    poses = np.full((len(keys), 4, 4), np.nan)
    for i, (_, k) in enumerate(keys):
        try:
            m = np.array(data[k], dtype=np.float64)
        except (TypeError, ValueError, OverflowError):  # OverflowError: an integer beyond float range
            raise InputError(path, f"pose {k}: not a numeric 4x4 matrix") from None
        if m.shape != (4, 4):
            raise InputError(path, f"pose {k}: expected 4x4, got shape {m.shape}")
        poses[i] = m
    valid = pose_validity(poses)
    if not valid.all():
        bad = [str(t) for t in ts[~valid][:5]]
        zero = int((np.nan_to_num(poses[~valid], nan=1.0) == 0).all(axis=(1, 2)).sum())
        kind = f"; {zero} all-zero, as hl2ss writes for untracked frames" if zero else ""
        msg = (f"{(~valid).sum()} of {len(ts)} invalid pose(s) (NaN, singular or not rigid{kind}), "
               f"first at {', '.join(bad)}")
        if invalid == "error":
            raise InputError(path, msg + " (io.invalid_poses=skip, the default without --strict, skips those frames)")
        warnings.warn(f"{path}: {msg}; those frames are skipped", stacklevel=2)
        poses[~valid] = np.nan
    return ts, poses, valid


def write_pose_json(path: str | Path, timestamps: np.ndarray, poses: np.ndarray) -> None:
    """Write ``{"<ts>": 4x4}`` with full float precision (shortest repr round-trips exactly)."""
    body = {str(int(t)): np.asarray(p, dtype=np.float64).tolist() for t, p in zip(timestamps, poses)}
    atomic_write_text(path, json.dumps(body))


# ---------------------------------------------------------------- interpolation between samples

def so3_log(rot: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> rotation vectors (..., 3) (axis times angle, radians), with
    ``rot = so3_exp(v)``; exact to the float precision below pi."""
    r = np.asarray(rot, dtype=np.float64)
    cos = np.clip((np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    w = np.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1)
    sin = np.sin(theta)
    # theta / (2 sin theta) -> 1/2 as theta -> 0 (series below 1e-6 rad)
    factor = np.where(theta > 1e-6, theta / (2.0 * np.where(sin > 1e-12, sin, 1.0)), 0.5 + theta ** 2 / 12.0)
    return w * factor[..., None]


def so3_exp(vec: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) (radians) -> rotation matrices (..., 3, 3) (Rodrigues)."""
    v = np.asarray(vec, dtype=np.float64)
    theta = np.linalg.norm(v, axis=-1)
    k = np.zeros(v.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta ** 2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - theta ** 2 / 24.0, (1.0 - np.cos(t)) / t ** 2)
    return np.eye(3) + a[..., None, None] * k + b[..., None, None] * (k @ k)


def interpolate_poses(timestamps: np.ndarray, poses: np.ndarray, valid: np.ndarray,
                      query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poses (row-vector 4x4) of a pose stream at times ``query`` (same ticks as ``timestamps``,
    sorted): between the two valid samples around each query, the rotation along the geodesic and
    the translation on the straight line; at the stream's ends the nearest valid sample's motion is
    extrapolated from its neighbour (at most one sample period). Returns ``(poses (M,4,4), ok (M,))``;
    NaN and False where fewer than two valid samples bracket or neighbour the query."""
    ts = np.asarray(timestamps, dtype=np.int64)[np.asarray(valid, bool)]
    ps = np.asarray(poses, dtype=np.float64)[np.asarray(valid, bool)]
    q = np.asarray(query, dtype=np.int64)
    out = np.full((len(q), 4, 4), np.nan)
    if len(ts) < 2:
        return out, np.zeros(len(q), bool)
    hi = np.clip(np.searchsorted(ts, q, side="right"), 1, len(ts) - 1)
    lo = hi - 1
    span = (ts[hi] - ts[lo]).astype(np.float64)
    s = (q - ts[lo]) / np.where(span > 0, span, 1.0)
    # within the stream, or at most one sample period beyond its ends
    ok = (s >= -1.0) & (s <= 2.0) & (span > 0)
    a, b = ps[lo], ps[hi]
    rel = so3_log(np.swapaxes(a[:, :3, :3], -1, -2) @ b[:, :3, :3])
    out[:, :3, :3] = a[:, :3, :3] @ so3_exp(rel * s[:, None])
    out[:, 3, :3] = a[:, 3, :3] + s[:, None] * (b[:, 3, :3] - a[:, 3, :3])
    out[:, :3, 3] = 0.0
    out[:, 3, 3] = 1.0
    out[~ok] = np.nan
    return out, ok
