"""Frame-to-mesh point-to-plane ICP (Open3D) as absolute pose constraints.

On every ``mesh_stride``-th frame the (mesh-unwrapped) AHAT points are registered to the
HoloLens scene mesh, coarse to fine, starting from the current pose estimate. Each step is
Open3D's point-to-plane estimation (Tukey kernel) on correspondences to the exact closest
mesh points (``RaycastingScene.compute_closest_points``, with the triangle normals).

A result becomes a constraint when the overlap is good (fitness, point-to-plane inlier RMSE)
and it did not move implausibly far. Its noise model is the point-to-plane information
(Hessian) of the final correspondences, deflated to ``mesh_effective_points`` independent
points (the HoloLens mesh errors are correlated over a view), so directions the view does
not constrain — a lone table top leaves the pose free to slide along it — get no weight,
instead of rejecting the frame. The factor keeps a Cauchy kernel (a wrong convergence).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from egograph.io.recording import mesh_raycasting_scene
from egograph.poses.config import RefineConfig
from egograph.poses.constraints import Constraints, ahat_offsets, invert_columns, sigmas
from egograph.poses.points import AhatPointSource


@dataclass
class MeshIcpStats:
    tried: int = 0
    accepted: int = 0
    no_depth: int = 0
    few_points: int = 0
    low_fitness: int = 0
    too_far: int = 0


@dataclass
class IcpResult:
    T: np.ndarray              # world <- AHAT camera, column 4x4
    fitness: float             # share of source points within the finest distance of the mesh
    rmse: float                # point-to-plane RMS of those inliers, metres
    hessian: np.ndarray        # (6, 6) Σ JᵀJ / N over inliers, AHAT body frame, [rot, trans] order


def within(delta: np.ndarray, max_trans: float, max_rot_deg: float) -> bool:
    """Is the rigid motion ``delta`` (column 4x4) at most ``max_trans`` metres and ``max_rot_deg`` degrees?"""
    ang = np.degrees(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1, 1)))
    return bool(np.linalg.norm(delta[:3, 3]) <= max_trans and ang <= max_rot_deg)


def plausible_correction(delta: np.ndarray, hessian: np.ndarray, max_trans: float, max_rot_deg: float) -> bool:
    """Is an ICP correction (body frame, column 4x4) small, counting translation only along
    the directions the view constrains (weights: eigenvalues of the translation block of the
    per-point Hessian relative to a fully constrained view, 1/3 per axis)?"""
    ang = np.degrees(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1, 1)))
    w, v = np.linalg.eigh(hessian[3:, 3:])
    comp = v.T @ delta[:3, 3]
    seen = float(np.sqrt(np.sum(np.clip(w * 3.0, 0, 1) * comp ** 2)))
    return bool(seen <= max_trans and ang <= max_rot_deg)


def point_to_plane_hessian(points_cam: np.ndarray, normals_cam: np.ndarray) -> np.ndarray:
    """``Σ JᵀJ / N`` with ``J = [(p × m)ᵀ, mᵀ]``: the point-to-plane Jacobian for a right (body-frame)
    perturbation ``T·Exp([ω, v])`` of camera-frame points p with camera-frame normals m."""
    j = np.concatenate([np.cross(points_cam, normals_cam), normals_cam], axis=1)
    return j.T @ j / max(len(j), 1)


def register_frame(points_cam: np.ndarray, scene, init_world_cam: np.ndarray, cfg: RefineConfig,
                   iterations: int = 8) -> IcpResult:
    """Point-to-plane ICP of camera-frame points onto the mesh from ``init_world_cam`` (column 4x4)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_cam)).voxel_down_sample(cfg.mesh_voxel)
    p = np.asarray(src.points)
    T = np.asarray(init_world_cam, dtype=np.float64).copy()

    def closest(T):
        pw = p @ T[:3, :3].T + T[:3, 3]
        ans = scene.compute_closest_points(o3d.core.Tensor(pw.astype(np.float32)))
        cp = ans["points"].numpy().astype(np.float64)
        nr = ans["primitive_normals"].numpy().astype(np.float64)
        return pw, cp, nr, np.linalg.norm(pw - cp, axis=1)

    fail = IcpResult(T, 0.0, np.inf, np.zeros((6, 6)))
    for d in cfg.mesh_max_distance:
        est = reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=d))
        for _ in range(iterations):
            pw, cp, nr, dist = closest(T)
            sel = np.flatnonzero(dist < d)
            if len(sel) < 6:
                return fail
            s_pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pw[sel]))
            t_pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cp[sel]))
            t_pc.normals = o3d.utility.Vector3dVector(nr[sel])
            corr = o3d.utility.Vector2iVector(np.repeat(np.arange(len(sel), dtype=np.int32)[:, None], 2, axis=1))
            dT = np.asarray(est.compute_transformation(s_pc, t_pc, corr))
            T = dT @ T
            if within(dT, 1e-4, np.degrees(1e-4)):
                break
    pw, cp, nr, dist = closest(T)
    inl = dist < cfg.mesh_max_distance[-1]
    if inl.sum() < 6:
        return fail
    res = np.einsum("ij,ij->i", pw[inl] - cp[inl], nr[inl])
    normals_cam = nr[inl] @ T[:3, :3]                       # R^T n, row-wise
    return IcpResult(T, float(inl.mean()), float(np.sqrt(np.mean(res ** 2))),
                     point_to_plane_hessian(p[inl], normals_cam))


def adjoint(T: np.ndarray) -> np.ndarray:
    """GTSAM's Pose3 adjoint ([rot, trans] order) of a column 4x4: ``Ad_T ξ = log(T Exp(ξ) T⁻¹)``."""
    import gtsam

    return gtsam.Pose3(np.asarray(T, dtype=np.float64)).AdjointMap()


def mesh_constraints(rec, cfg: RefineConfig, pv_estimate: np.ndarray, points: AhatPointSource, mesh,
                     progress: bool = False) -> tuple[Constraints, MeshIcpStats]:
    """Absolute PV-pose constraints from frame-to-mesh ICP on every ``mesh_stride``-th frame.

    ``pv_estimate``: (N, 4, 4) column-vector PV camera -> world poses to start from (the
    reported ones, spike-cleaned). Frames without a valid estimate are skipped.
    """
    from tqdm import tqdm

    stats = MeshIcpStats()
    if mesh is None:
        return Constraints.empty("mesh", "absolute", cfg.mesh_kernel, note="no mesh"), stats
    scene = mesh_raycasting_scene(mesh)  # exact closest points and triangle normals for ICP
    if scene is None:
        return Constraints.empty("mesh", "absolute", cfg.mesh_kernel, note="mesh has no triangles"), stats
    offsets = ahat_offsets(rec)
    frames = [i for i in range(0, len(rec), cfg.mesh_stride) if np.isfinite(pv_estimate[i]).all()]
    out_i, out_T, out_info = [], [], []
    corr = np.eye(4)                  # world correction carried forward: true ≈ corr · estimate
    for i in tqdm(frames, desc="mesh ICP", unit="frame", disable=not progress, leave=False):
        stats.tried += 1
        est = pv_estimate[i] @ offsets[i]                          # AHAT camera -> world (estimate)
        init = corr @ est
        pts = points.points(i, ahat_to_world=init.T)
        if pts is None:
            stats.no_depth += 1
            continue
        if len(pts) < cfg.mesh_min_points:
            stats.few_points += 1
            continue
        r = register_frame(pts, scene, init, cfg)
        if r.fitness < cfg.mesh_min_fitness or r.rmse > cfg.mesh_max_rmse:
            stats.low_fitness += 1
            continue
        if not (plausible_correction(invert_columns(est) @ r.T, r.hessian, *cfg.mesh_max_correction)
                and plausible_correction(invert_columns(init) @ r.T, r.hessian, *cfg.mesh_max_step)):
            stats.too_far += 1
            continue
        if np.linalg.eigvalsh(r.hessian[3:, 3:])[0] * 3 > 0.2 and np.linalg.eigvalsh(r.hessian[:3, :3])[0] > 0.01:
            corr = r.T @ invert_columns(est)
        stats.accepted += 1
        # information in the AHAT body frame, moved to the PV body frame: ξ_ahat = Ad(O⁻¹) ξ_pv
        info_ahat = r.hessian * cfg.mesh_effective_points / max(r.rmse, cfg.mesh_min_sigma) ** 2
        ad = adjoint(invert_columns(offsets[i]))
        info = ad.T @ info_ahat @ ad + np.eye(6) * 1e-6
        out_i.append(i)
        out_T.append(r.T @ invert_columns(offsets[i]))             # PV camera -> world
        out_info.append(0.5 * (info + info.T))
    n = len(out_i)
    return Constraints("mesh", "absolute", np.array(out_i, int), np.full(n, -1), np.array(out_T).reshape(n, 4, 4),
                       sigmas(1.0, 1.0, n), cfg.mesh_kernel, {"stats": stats.__dict__},
                       information=np.array(out_info).reshape(n, 6, 6)), stats
