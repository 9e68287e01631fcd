"""Per-frame position uncertainty of the refined PV poses: GTSAM marginals, and the file they are written to.

``pv_position_covariance.json``: ``{"<timestamp>": [[3x3]] | null}``, the covariance (m²) of the
PV camera centre in the **world** frame, one entry per PV timestamp (null where the frame has no
refined pose). From ``gtsam.Marginals`` of the pose graph at the solution: GTSAM's Pose3 marginal
is 6x6 in the body-frame tangent ``[rot, trans]``; the camera centre moves by ``R·δt`` under the
retraction, so its world covariance is ``R Σ_tt Rᵀ``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from egograph.core.errors import InputError


def position_covariances(graph, values, n: int) -> np.ndarray:
    """(n, 3, 3) world-frame covariances (m²) of the PV camera centres (key ``x_i``); NaN without a variable."""
    import gtsam

    from egograph.poses.graph import pose_key

    out = np.full((n, 3, 3), np.nan)
    marg = gtsam.Marginals(graph, values)
    for i in range(n):
        k = pose_key(i)
        if not values.exists(k):
            continue
        R = values.atPose3(k).rotation().matrix()
        out[i] = R @ marg.marginalCovariance(k)[3:, 3:] @ R.T
    return 0.5 * (out + np.swapaxes(out, 1, 2))


def write_position_covariance(path: str | Path, timestamps: np.ndarray, cov: np.ndarray) -> None:
    """Write ``{"<ts>": 3x3 list | null}`` (plain write: the caller writes inside an atomic folder)."""
    doc = {str(int(t)): (c.tolist() if np.isfinite(c).all() else None) for t, c in zip(timestamps, cov)}
    Path(path).write_text(json.dumps(doc))


def read_position_covariance(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``(timestamps int64 (N,), covariances (N, 3, 3))`` sorted by time, NaN for null entries;
    an InputError naming the file for anything that is not that."""
    from egograph.io.textio import read_json_checked

    doc = read_json_checked(path, "position covariance file")
    if not isinstance(doc, dict):
        raise InputError(path, f"expected a JSON object {{timestamp: 3x3}}, found {type(doc).__name__}")
    ts, cov = [], []
    for key, val in doc.items():
        try:
            t = int(key)
        except ValueError:
            raise InputError(path, f"key {key!r} is not an integer timestamp") from None
        if val is None:
            c = np.full((3, 3), np.nan)
        else:
            try:
                c = np.asarray(val, dtype=np.float64) if isinstance(val, list) else np.zeros(0)
            except (TypeError, ValueError):
                c = np.zeros(0)
            if c.shape != (3, 3):
                raise InputError(path, f"entry {key} is not a 3x3 list")
        ts.append(t)
        cov.append(c)
    order = np.argsort(ts)
    return np.asarray(ts, dtype=np.int64)[order], np.asarray(cov).reshape(-1, 3, 3)[order]


def nees(errors: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Per-frame normalised estimation error squared ``eᵀ Σ⁻¹ e`` (expected value 3 for 3D positions
    when the covariance is honest); NaN where either is missing."""
    out = np.full(len(errors), np.nan)
    ok = np.isfinite(errors).all(axis=1) & np.isfinite(cov).all(axis=(1, 2))
    if ok.any():
        out[ok] = np.einsum("ni,ni->n", errors[ok], np.linalg.solve(cov[ok], errors[ok][..., None])[..., 0])
    return out
