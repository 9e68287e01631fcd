"""Pose evaluation: ATE (with and without SE(3) alignment) and RPE against a reference.

Trajectories are row-vector 4x4 poses (sensor -> world, metres), compared frame by frame
on shared timestamps. The world frame of the recording is shared with its annotations,
so the unaligned ATE is the figure that matters for object positions; the aligned one
(Umeyama, rotation + translation, no scale) isolates the shape of the trajectory.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from egograph.core.errors import InputError
from egograph.geometry.hl2ss import invert_rigid


@dataclass
class PoseEval:
    n: int                     # frames compared
    ate_rmse_m: float          # camera-centre RMSE, no alignment (shared world frame)
    ate_rmse_aligned_m: float  # camera-centre RMSE after SE(3) alignment of the estimate onto the reference
    ate_max_m: float
    rot_rmse_deg: float        # absolute rotation RMSE, no alignment
    rpe_trans_m: float         # RMSE of relative translation error over ``rpe_delta`` frames
    rpe_rot_deg: float         # RMSE of relative rotation error over ``rpe_delta`` frames
    rpe_delta: int             # frames

    def as_dict(self) -> dict:
        return asdict(self)


def umeyama_se3(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R and translation t minimising ``Σ‖R src_i + t − dst_i‖²`` (column convention, no scale)."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    ms, md = src.mean(0), dst.mean(0)
    cov = (dst - md).T @ (src - ms) / len(src)
    u, _, vt = np.linalg.svd(cov)
    s = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        s[2, 2] = -1
    r = u @ s @ vt
    return r, md - r @ ms


def rotation_angle_deg(rel: np.ndarray) -> np.ndarray:
    """Angle (degrees) of rotation matrices (..., 3, 3)."""
    cos = np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.arccos(cos))


def ate_errors(est: np.ndarray, ref: np.ndarray, align: bool = False) -> np.ndarray:
    """Per-frame camera-centre error (metres) of row-vector poses (N, 4, 4), optionally after SE(3) alignment."""
    pe, pr = est[:, 3, :3], ref[:, 3, :3]
    if align:
        r, t = umeyama_se3(pe, pr)
        pe = pe @ r.T + t
    return np.linalg.norm(pe - pr, axis=1)


def rpe_errors(est: np.ndarray, ref: np.ndarray, delta: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Relative pose error over ``delta`` frames: translation (m) and rotation (deg) of
    ``inv(ref_i⁻¹ ref_j) · (est_i⁻¹ est_j)`` for j = i + delta (row-vector algebra, same thing)."""
    if len(est) <= delta:
        return np.zeros(0), np.zeros(0)
    # row-vector: relative motion i->j in frame i is  M_j @ inv(M_i)  (node_j -> node_i)
    rel_e = est[delta:] @ invert_rigid(est[:-delta])
    rel_r = ref[delta:] @ invert_rigid(ref[:-delta])
    err = rel_e @ invert_rigid(rel_r)
    return np.linalg.norm(err[:, 3, :3], axis=1), rotation_angle_deg(err[:, :3, :3])


def evaluate_trajectory(est: np.ndarray, ref: np.ndarray, rpe_delta: int = 1) -> PoseEval:
    """ATE/RPE of ``est`` against ``ref`` (both (N, 4, 4) on the same frames); NaN frames are skipped
    (RPE pairs need both ends valid)."""
    est = np.asarray(est, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    ok = np.isfinite(est).all(axis=(1, 2)) & np.isfinite(ref).all(axis=(1, 2))
    if ok.sum() < 3:
        raise ValueError("fewer than 3 frames with both poses valid")
    e, r = est[ok], ref[ok]
    ate = ate_errors(e, r)
    ate_al = ate_errors(e, r, align=True)
    rot = rotation_angle_deg(np.einsum("nij,nkj->nik", e[:, :3, :3], r[:, :3, :3]))
    # RPE over frame pairs (i, i+delta) of the full index with both ends valid
    idx = np.arange(len(est) - rpe_delta)
    pair_ok = ok[idx] & ok[idx + rpe_delta]
    est_f = np.where(ok[:, None, None], est, np.eye(4))
    ref_f = np.where(ok[:, None, None], ref, np.eye(4))
    rt, rr = rpe_errors(est_f, ref_f, rpe_delta)
    rt, rr = rt[pair_ok], rr[pair_ok]
    rms = lambda x: float(np.sqrt(np.mean(x ** 2))) if len(x) else float("nan")  # noqa: E731
    return PoseEval(n=int(ok.sum()), ate_rmse_m=rms(ate), ate_rmse_aligned_m=rms(ate_al), ate_max_m=float(ate.max()),
                    rot_rmse_deg=rms(rot), rpe_trans_m=rms(rt), rpe_rot_deg=rms(rr), rpe_delta=rpe_delta)


def match_timestamps(ts_est: np.ndarray, poses_est: np.ndarray, ts_ref: np.ndarray, poses_ref: np.ndarray,
                     tolerance_ticks: int = 50_000, where: str | Path = "poses") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pair estimate and reference poses by nearest timestamp (within ``tolerance_ticks``, 5 ms default).

    Returns (timestamps, est, ref) over the reference frames that have a match.
    """
    ts_est = np.asarray(ts_est, dtype=np.int64)
    j = np.clip(np.searchsorted(ts_est, ts_ref), 1, len(ts_est) - 1) if len(ts_est) > 1 else np.zeros(len(ts_ref), int)
    if len(ts_est) > 1:
        j = np.where(np.abs(ts_est[j - 1] - ts_ref) <= np.abs(ts_est[j] - ts_ref), j - 1, j)
    ok = np.abs(ts_est[j] - ts_ref) <= tolerance_ticks
    if ok.sum() < 3:
        raise InputError(where, f"fewer than 3 poses match the reference timestamps (within {tolerance_ticks / 1e4:.1f} ms)")
    return ts_ref[ok], poses_est[j[ok]], poses_ref[ok]


def plot_errors(path: str | Path, times_s: np.ndarray, curves: dict[str, np.ndarray], title: str = "") -> None:
    """PNG of per-frame translation error (m, unaligned) over time, one curve per trajectory."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from egograph.io.atomic import atomic_path

    fig, ax = plt.subplots(figsize=(9, 3.5))
    for name, err in curves.items():
        ax.plot(times_s, err * 100.0, lw=0.8, label=name)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("position error (cm)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
