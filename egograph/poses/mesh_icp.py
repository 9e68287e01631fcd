"""Frame-to-mesh point-to-plane ICP (Open3D) as absolute pose constraints.

On every ``mesh_stride``-th frame the (mesh-unwrapped) AHAT points are registered to the
HoloLens scene mesh, coarse to fine, starting from the current pose estimate. Each step is a
point-to-plane Gauss-Newton step (Tukey kernel, Open3D's formulation) on correspondences to the
exact closest mesh points (``RaycastingScene.compute_closest_points``, with the triangle normals).
The step's normal equations are summed here in a fixed order (:func:`point_to_plane_step`):
Open3D's ``TransformationEstimationPointToPlane`` sums them in a TBB parallel reduction whose
split depends on thread timing, which made repeated runs differ in the last bits.

A result becomes a constraint when the overlap is good (fitness, point-to-plane inlier RMSE)
and it did not move implausibly far. Its noise model is the point-to-plane information
(Hessian) of the final correspondences, deflated to ``mesh_effective_points`` independent
points (the HoloLens mesh errors are correlated over a view), so directions the view does
not constrain — a lone table top leaves the pose free to slide along it — get no weight,
instead of rejecting the frame. The factor keeps a Cauchy kernel (a wrong convergence).
"""

from __future__ import annotations

from dataclasses import dataclass, field

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
    restarts: int = 0          # keyframes where the first start did not converge cleanly and others were tried
    held_out: int = 0          # keyframes kept out of the solve for the self-check (no ICP run)
    weak_directions: int = 0   # directions given no information, summed over accepted keyframes


@dataclass
class IcpResult:
    T: np.ndarray              # world <- AHAT camera, column 4x4
    fitness: float             # share of source points within the finest distance of the mesh
    rmse: float                # point-to-plane RMS of those inliers, metres
    hessian: np.ndarray        # (6, 6) Σ JᵀJ / N over inliers, AHAT body frame, [rot, trans] order
    converged: bool = False    # the finest stage's last step was below 0.1 mm / 0.1 mrad
    length: float = 1.0        # RMS distance of the inlier points from the AHAT camera, metres


@dataclass
class KeyframeIcp:
    """What one mesh-ICP keyframe constrains (one entry of the report)."""

    frame: int
    outcome: str                     # 'accepted' | 'held_out' | 'no_depth' | 'few_points' | 'low_fitness' | 'too_far'
    fitness: float = float("nan")
    rmse_m: float = float("nan")
    converged: bool = False
    start: int = -1                  # which start gave the result (0 = carried correction, 1 = reported, 2.. perturbed)
    eigenvalues: list = field(default_factory=list)   # normalised information eigenvalues / the largest, ascending
    strong: int = 0                  # directions kept (eigenvalue >= mesh_weak_ratio of the largest)
    weak_axes: list = field(default_factory=list)     # unit 6-vectors given no information: AHAT camera frame,
    #                                                   [rotation as arc length at the view's RMS range, translation]


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


def tukey_weights(r: np.ndarray, k: float) -> np.ndarray:
    """Open3D's ``TukeyLoss(k).Weight``: ``(1 - (r/k)²)²`` for ``|r| <= k``, else 0."""
    e = np.abs(r)
    return np.where(e > k, 0.0, (1.0 - (e / k) ** 2) ** 2)


def euler_zyx(x: np.ndarray) -> np.ndarray:
    """Column 4x4 of a 6-vector ``[rx, ry, rz, tx, ty, tz]`` as Open3D reads an ICP step
    (``TransformVector6dToMatrix4d``): ``R = Rz(rz) Ry(ry) Rx(rx)``."""
    cx, cy, cz = np.cos(x[:3])
    sx, sy, sz = np.sin(x[:3])
    T = np.eye(4)
    T[:3, :3] = [[cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx],
                 [sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx],
                 [-sy, cy * sx, cy * cx]]
    T[:3, 3] = x[3:]
    return T


def ldlt_solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``x`` with ``a x = b`` for a small symmetric positive semi-definite ``a``, by Eigen's LDLT with
    diagonal pivoting (what Open3D's ``SolveLinearSystemPSD`` calls), zero pivots included: their
    components come out 0 (a direction the system does not constrain stays put), as in Eigen.
    Plain Python floats: for a 6x6 system far cheaper than numpy calls on tiny arrays."""
    m = np.asarray(a, dtype=np.float64).tolist()   # its lower triangle is factored in place
    n = len(m)
    swaps = list(range(n))
    for k in range(n):
        j = max(range(k, n), key=lambda i: (abs(m[i][i]), -i))     # the first largest diagonal entry
        swaps[k] = j
        if j != k:                            # symmetric swap of k and j within the lower triangle
            m[k][:k], m[j][:k] = m[j][:k], m[k][:k]
            for i in range(j + 1, n):
                m[i][k], m[i][j] = m[i][j], m[i][k]
            m[k][k], m[j][j] = m[j][j], m[k][k]
            for i in range(k + 1, j):
                m[i][k], m[j][i] = m[j][i], m[i][k]
        if k > 0:
            tmp = [m[i][i] * m[k][i] for i in range(k)]
            m[k][k] -= sum(m[k][i] * tmp[i] for i in range(k))
            for r in range(k + 1, n):
                m[r][k] -= sum(m[r][i] * tmp[i] for i in range(k))
        if m[k][k] != 0:
            for r in range(k + 1, n):
                m[r][k] /= m[k][k]
        elif k == 0:                          # an all-zero diagonal: nothing constrained
            return np.zeros(n)
    x = np.asarray(b, dtype=np.float64).tolist()
    for k in range(n):
        x[k], x[swaps[k]] = x[swaps[k]], x[k]
    for i in range(n):
        x[i] -= sum(m[i][c] * x[c] for c in range(i))
    tiny = np.finfo(np.float64).tiny
    x = [x[i] / m[i][i] if abs(m[i][i]) > tiny else 0.0 for i in range(n)]
    for i in reversed(range(n)):
        x[i] -= sum(m[r][i] * x[r] for r in range(i + 1, n))
    for k in reversed(range(n)):
        x[k], x[swaps[k]] = x[swaps[k]], x[k]
    return np.array(x)


def point_to_plane_step(src: np.ndarray, dst: np.ndarray, normals: np.ndarray, k: float) -> np.ndarray:
    """One robust point-to-plane Gauss-Newton step (column 4x4, world frame) moving the points
    ``src`` onto the planes (``dst``, ``normals``) of their correspondences, Tukey kernel of width k.

    The same step as Open3D's ``TransformationEstimationPointToPlane(TukeyLoss(k))``
    (``J = [src × n, n]``, ``r = (src - dst)·n``, ``x = -(Σ w JJᵀ)⁻¹ Σ w J r`` by LDLT, Euler ZYX),
    but deterministic: the sums run in a fixed order (numpy's einsum loop, no BLAS or TBB
    threads), where Open3D's parallel reduction changes the rounding from run to run. Identity
    when the solution is not finite.
    """
    r = np.einsum("ij,ij->i", src - dst, normals)
    (sx, sy, sz), (nx, ny, nz) = src.T, normals.T
    jt = np.empty((6, len(r)))                                       # Jᵀ, rows contiguous: [src × n; n]
    jt[0], jt[1], jt[2] = sy * nz - sz * ny, sz * nx - sx * nz, sx * ny - sy * nx
    jt[3:] = normals.T
    jwt = jt * tukey_weights(r, k)
    x = ldlt_solve(np.einsum("in,jn->ij", jwt, jt), -np.einsum("in,n->i", jwt, r))
    return euler_zyx(x) if np.isfinite(x).all() else np.eye(4)


def register_frame(points_cam: np.ndarray, scene, init_world_cam: np.ndarray, cfg: RefineConfig,
                   iterations: int = 8) -> IcpResult:
    """Point-to-plane ICP of camera-frame points onto the mesh from ``init_world_cam`` (column 4x4)."""
    import open3d as o3d

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
    converged = False
    for d in cfg.mesh_max_distance:
        converged = False
        for _ in range(iterations):
            pw, cp, nr, dist = closest(T)
            sel = np.flatnonzero(dist < d)
            if len(sel) < 6:
                return fail
            dT = point_to_plane_step(pw[sel], cp[sel], nr[sel], d)
            T = dT @ T
            if within(dT, 1e-4, np.degrees(1e-4)):
                converged = True
                break
    pw, cp, nr, dist = closest(T)
    inl = dist < cfg.mesh_max_distance[-1]
    if inl.sum() < 6:
        return fail
    res = np.einsum("ij,ij->i", pw[inl] - cp[inl], nr[inl])
    normals_cam = nr[inl] @ T[:3, :3]                       # R^T n, row-wise
    return IcpResult(T, float(inl.mean()), float(np.sqrt(np.mean(res ** 2))),
                     point_to_plane_hessian(p[inl], normals_cam), converged,
                     float(np.sqrt(np.mean(np.sum(p[inl] ** 2, axis=1)))))


def information_directions(hessian: np.ndarray, length: float) -> tuple[np.ndarray, np.ndarray]:
    """Eigen-decomposition of a point-to-plane information ([rot, trans], body frame) with the
    rotation expressed as arc length at ``length`` metres (``ξn = [length·ω, v]``), so that rotation
    and translation eigenvalues compare in one unit: ascending eigenvalues and their unit
    eigenvectors (columns) in the normalised coordinates."""
    s = np.r_[[1.0 / max(length, 1e-3)] * 3, [1.0] * 3]
    w, v = np.linalg.eigh(0.5 * (hessian + hessian.T) * s[:, None] * s[None, :])
    return np.clip(w, 0.0, None), v


def project_information(hessian: np.ndarray, length: float, weak_ratio: float,
                        floor: float = 1e-9) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The information restricted to the directions the view constrains.

    Directions whose normalised eigenvalue (:func:`information_directions`) is below
    ``weak_ratio`` times the largest get ``floor`` times the largest instead (no information,
    but a positive-definite matrix for GTSAM's Gaussian model); the others keep theirs.
    Returns the projected (6, 6) information in the input's units, the normalised eigenvalues
    divided by the largest (ascending) and a boolean mask of the strong ones.
    """
    w, v = information_directions(hessian, length)
    top = max(float(w[-1]), 1e-300)
    strong = w >= weak_ratio * top
    wp = np.where(strong, w, floor * top)
    hn = (v * wp) @ v.T
    s = np.r_[[max(length, 1e-3)] * 3, [1.0] * 3]          # back to [rad, m]: H = S Hn S
    hp = hn * s[:, None] * s[None, :]
    return 0.5 * (hp + hp.T), w / top, strong


def adjoint(T: np.ndarray) -> np.ndarray:
    """GTSAM's Pose3 adjoint ([rot, trans] order) of a column 4x4: ``Ad_T ξ = log(T Exp(ξ) T⁻¹)``."""
    import gtsam

    return gtsam.Pose3(np.asarray(T, dtype=np.float64)).AdjointMap()


def perturbed(T: np.ndarray, yaw_deg: float) -> np.ndarray:
    """``T`` (column 4x4, camera -> world) turned by ``yaw_deg`` about the world vertical (y) through its centre."""
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    out = T.copy()
    out[:3, :3] = R @ T[:3, :3]
    return out


def clean(r: IcpResult, cfg: RefineConfig) -> bool:
    """Did an ICP run end cleanly (overlap and inlier residual within the acceptance limits)? Whether the
    finest stage also met its step tolerance is recorded (``converged``) but does not trigger restarts:
    on the tuning seeds those restarts cost a third of the ICP time and changed no accepted factor."""
    return r.fitness >= cfg.mesh_min_fitness and r.rmse <= cfg.mesh_max_rmse


def register_multistart(pts: np.ndarray, scene, starts: list[np.ndarray], cfg: RefineConfig) -> tuple[IcpResult, int]:
    """ICP from the first start; only when it does not converge cleanly, from the others too.
    The best clean result (lowest inlier RMSE) wins, else the one with the highest fitness."""
    best, best_k = None, 0
    for k, T0 in enumerate(starts):
        r = register_frame(pts, scene, T0, cfg)
        if clean(r, cfg):
            if best is None or not clean(best, cfg) or r.rmse < best.rmse:
                best, best_k = r, k
            break                          # a clean result is good enough: no more starts
        if best is None or (not clean(best, cfg) and r.fitness > best.fitness):
            best, best_k = r, k
    return best, best_k


def holdout_mask(n: int, every: int) -> np.ndarray:
    """Which of ``n`` keyframes (in order) are held out of the solve: one in ``every`` (the middle
    one of each group, so the first and last keyframes stay in the solve); none for every < 2."""
    m = np.zeros(n, bool)
    if every >= 2:
        m[every // 2::every] = True
    return m


def mesh_constraints(rec, cfg: RefineConfig, pv_estimate: np.ndarray, points: AhatPointSource, mesh,
                     progress: bool = False) -> tuple[Constraints, MeshIcpStats]:
    """Absolute PV-pose constraints from frame-to-mesh ICP on every ``mesh_stride``-th frame.

    ``pv_estimate``: (N, 4, 4) column-vector PV camera -> world poses to start from (the
    reported ones, spike-cleaned). Frames without a valid estimate are skipped. One keyframe in
    ``selfcheck_every`` is held out (no factor; ``info['held_out']``) for the self-check.
    ``info['keyframes']`` lists a :class:`KeyframeIcp` per keyframe: fitness, RMSE, start used
    and the eigen-structure of its information (which directions it constrains).

    Each factor's information is the point-to-plane Hessian of the final correspondences
    projected onto the directions the view constrains (:func:`project_information` with
    ``mesh_weak_ratio``), deflated to ``mesh_effective_points`` over the residual variance.
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
    held = holdout_mask(len(frames), cfg.selfcheck_every if cfg.selfcheck else 0)
    out_i, out_T, out_info = [], [], []
    records: list[KeyframeIcp] = []
    corr = np.eye(4)                  # world correction carried forward: true ≈ corr · estimate
    for k, i in enumerate(tqdm(frames, desc="mesh ICP", unit="frame", disable=not progress, leave=False)):
        if held[k]:
            stats.held_out += 1
            records.append(KeyframeIcp(i, "held_out"))
            continue
        stats.tried += 1
        est = pv_estimate[i] @ offsets[i]                          # AHAT camera -> world (estimate)
        init = corr @ est
        pts = points.points(i, ahat_to_world=init.T)
        if pts is None:
            stats.no_depth += 1
            records.append(KeyframeIcp(i, "no_depth"))
            continue
        if len(pts) < cfg.mesh_min_points:
            stats.few_points += 1
            records.append(KeyframeIcp(i, "few_points"))
            continue
        starts = [init] + ([est] if not np.allclose(init, est) else [])
        starts += [perturbed(init, sgn * cfg.mesh_start_yaw) for sgn in (1, -1)]
        r, start = register_multistart(pts, scene, starts[:cfg.mesh_starts], cfg)
        stats.restarts += int(start > 0 or not clean(r, cfg))
        rec_k = KeyframeIcp(i, "low_fitness", r.fitness, r.rmse, r.converged, start)
        records.append(rec_k)
        if r.fitness < cfg.mesh_min_fitness or r.rmse > cfg.mesh_max_rmse:
            stats.low_fitness += 1
            continue
        if not (plausible_correction(invert_columns(est) @ r.T, r.hessian, *cfg.mesh_max_correction)
                and plausible_correction(invert_columns(init) @ r.T, r.hessian, *cfg.mesh_max_step)):
            stats.too_far += 1
            rec_k.outcome = "too_far"
            continue
        if np.linalg.eigvalsh(r.hessian[3:, 3:])[0] * 3 > 0.2 and np.linalg.eigvalsh(r.hessian[:3, :3])[0] > 0.01:
            corr = r.T @ invert_columns(est)
        stats.accepted += 1
        # weak directions get no information (not a confident wrong one), then AHAT body -> PV body frame:
        # ξ_ahat = Ad(O⁻¹) ξ_pv
        hp, ev, strong = project_information(r.hessian, r.length, cfg.mesh_weak_ratio)
        info_ahat = hp * cfg.mesh_effective_points / max(r.rmse, cfg.mesh_min_sigma) ** 2
        ad = adjoint(invert_columns(offsets[i]))
        info = ad.T @ info_ahat @ ad
        rec_k.outcome, rec_k.eigenvalues, rec_k.strong = "accepted", [float(x) for x in ev], int(strong.sum())
        if not strong.all():
            _, v = information_directions(r.hessian, r.length)
            rec_k.weak_axes = [[round(float(x), 4) for x in col] for col in v[:, ~strong].T]
        stats.weak_directions += int((~strong).sum())
        out_i.append(i)
        out_T.append(r.T @ invert_columns(offsets[i]))             # PV camera -> world
        out_info.append(0.5 * (info + info.T))
    n = len(out_i)
    return Constraints("mesh", "absolute", np.array(out_i, int), np.full(n, -1), np.array(out_T).reshape(n, 4, 4),
                       sigmas(1.0, 1.0, n), cfg.mesh_kernel,
                       {"stats": stats.__dict__, "keyframes": records,
                        "held_out": np.array([f for f, h in zip(frames, held) if h], int)},
                       information=np.array(out_info).reshape(n, 6, 6)), stats
