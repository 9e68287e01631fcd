"""TUM trajectory files (``timestamp tx ty tz qx qy qz qw``, one pose per line), as evo reads them.

A TUM pose is the sensor -> world transform (column convention: ``p_world = R p + t``);
timestamps are written in seconds. egograph poses are hl2ss row-vector 4x4 matrices
(``p_world = [p, 1] @ M``), so ``R = M[:3, :3].T`` and ``t = M[3, :3]``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from egograph.core.errors import InputError
from egograph.core.units import TICKS_PER_SECOND
from egograph.geometry.hl2ss import rigid_from_rt
from egograph.io.atomic import atomic_write_text
from egograph.io.textio import read_text_checked


def quat_from_matrix(r: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) -> unit quaternions (N, 4) ``x y z w`` with ``w >= 0``."""
    r = np.asarray(r, dtype=np.float64)
    tr = np.trace(r, axis1=1, axis2=2)
    q = np.empty((len(r), 4))
    # Shepperd: pick the largest of w, x, y, z for stability
    cand = np.stack([tr, r[:, 0, 0], r[:, 1, 1], r[:, 2, 2]], axis=1)
    k = cand.argmax(axis=1)
    for c in range(4):
        m = k == c
        if not m.any():
            continue
        rr = r[m]
        if c == 0:
            s = np.sqrt(1.0 + tr[m]) * 2
            q[m] = np.stack([(rr[:, 2, 1] - rr[:, 1, 2]) / s, (rr[:, 0, 2] - rr[:, 2, 0]) / s,
                             (rr[:, 1, 0] - rr[:, 0, 1]) / s, 0.25 * s], axis=1)
        else:
            i = c - 1
            j, l = (i + 1) % 3, (i + 2) % 3
            s = np.sqrt(1.0 + rr[:, i, i] - rr[:, j, j] - rr[:, l, l]) * 2
            v = np.empty((m.sum(), 4))
            v[:, i] = 0.25 * s
            v[:, j] = (rr[:, j, i] + rr[:, i, j]) / s
            v[:, l] = (rr[:, l, i] + rr[:, i, l]) / s
            v[:, 3] = (rr[:, l, j] - rr[:, j, l]) / s
            q[m] = v
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return np.where(q[:, 3:4] < 0, -q, q)


def matrix_from_quat(q: np.ndarray) -> np.ndarray:
    """Quaternions (N, 4) ``x y z w`` (normalised here) -> rotation matrices (N, 3, 3)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    x, y, z, w = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1)], axis=1)


def poses_to_tum_rows(poses: np.ndarray) -> np.ndarray:
    """Row-vector 4x4 poses (N, 4, 4) -> (N, 7) ``tx ty tz qx qy qz qw``."""
    p = np.asarray(poses, dtype=np.float64)
    rot = np.swapaxes(p[:, :3, :3], 1, 2)
    q = quat_from_matrix(rot)  # x y z w
    return np.concatenate([p[:, 3, :3], q], axis=1)


def tum_rows_to_poses(rows: np.ndarray) -> np.ndarray:
    """(N, 7) ``tx ty tz qx qy qz qw`` -> row-vector 4x4 poses (N, 4, 4)."""
    rows = np.asarray(rows, dtype=np.float64)
    rot = matrix_from_quat(rows[:, 3:7])
    return rigid_from_rt(rot, rows[:, :3])


def write_tum(path: str | Path, timestamps_ticks: np.ndarray, poses: np.ndarray) -> None:
    """Write a TUM file; timestamps (100 ns HoloLens ticks) are written as seconds. Invalid (NaN) poses are skipped."""
    ts = np.asarray(timestamps_ticks, dtype=np.int64)
    p = np.asarray(poses, dtype=np.float64)
    ok = np.isfinite(p).all(axis=(1, 2))
    rows = poses_to_tum_rows(p[ok]) if ok.any() else np.zeros((0, 7))
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for t, r in zip(ts[ok], rows):
        sec = f"{t // TICKS_PER_SECOND}.{t % TICKS_PER_SECOND:07d}"
        lines.append(sec + " " + " ".join(repr(float(v)) for v in r))
    atomic_write_text(path, "\n".join(lines) + "\n")


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM file -> (timestamps in 100 ns ticks int64, poses (N, 4, 4) row-vector), sorted by time.

    Accepts spaces or commas; ``#`` lines are comments. Errors name the file and line.
    """
    path = Path(path)
    text = read_text_checked(path, "TUM trajectory file")
    ts, rows = [], []
    for n, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").split()
        if len(parts) != 8:
            raise InputError(path, f"expected 8 columns (timestamp tx ty tz qx qy qz qw), got {len(parts)}", n)
        try:
            vals = [float(v) for v in parts[1:]]
            ts.append(_seconds_to_ticks(parts[0]))
        except ValueError:
            raise InputError(path, "not a number", n) from None
        q = np.array(vals[3:])
        if not np.isfinite(vals).all() or not 0.5 < np.linalg.norm(q) < 1.5:
            raise InputError(path, "non-finite value or quaternion far from unit norm", n)
        rows.append(vals)
    if not rows:
        raise InputError(path, "no poses")
    ts = np.array(ts, dtype=np.int64)
    order = np.argsort(ts, kind="stable")
    return ts[order], tum_rows_to_poses(np.array(rows)[order])


def _seconds_to_ticks(s: str) -> int:
    """'123.4567890' seconds -> 100 ns ticks, exactly (no float rounding for 7 decimals)."""
    if "e" in s.lower():
        return int(round(float(s) * TICKS_PER_SECOND))
    whole, _, frac = s.partition(".")
    sign = -1 if whole.startswith("-") else 1
    frac = (frac + "0000000")[:7]
    return sign * (abs(int(whole or "0")) * TICKS_PER_SECOND + int(frac))
