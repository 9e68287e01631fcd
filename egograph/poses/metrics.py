"""Pose error metrics between two trajectories of row-vector 4x4 poses (sensor -> world)."""

from __future__ import annotations

import numpy as np


def pose_differences(estimate: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame translation error (metres) and rotation error (degrees), no alignment.

    Frames where either pose is NaN give NaN.
    """
    est = np.asarray(estimate, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    trans = np.linalg.norm(est[:, 3, :3] - ref[:, 3, :3], axis=1)
    rel = np.einsum("nij,nkj->nik", est[:, :3, :3], ref[:, :3, :3])  # R_est @ R_ref^T
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return trans, np.degrees(np.arccos(cos))


def error_summary(trans: np.ndarray, rot_deg: np.ndarray) -> dict[str, float]:
    """RMSE / median / max of translation (m) and rotation (deg) errors over valid frames."""
    ok = np.isfinite(trans) & np.isfinite(rot_deg)
    if not ok.any():
        return {"n": 0}
    t, r = trans[ok], rot_deg[ok]
    return {"n": int(ok.sum()), "trans_rmse_m": float(np.sqrt(np.mean(t ** 2))), "trans_median_m": float(np.median(t)),
            "trans_max_m": float(t.max()), "rot_rmse_deg": float(np.sqrt(np.mean(r ** 2))),
            "rot_median_deg": float(np.median(r)), "rot_max_deg": float(r.max())}
