"""Joint mode: the camera poses and the still objects' landmarks in one GTSAM graph.

``egograph track --tracker graph --joint-poses`` (and ``egograph regt --joint-poses``): the PV
camera poses become variables next to the object landmarks, with every factor of the pose
refinement (:func:`egograph.poses.refine.refinement_factors`: the HoloLens error model, mesh
ICP, ...), so detections of objects that stand still also correct the poses, the way
landmarks close loops in SLAM.

One round:

1. the tracker runs with the current poses and finds the stands (segments of an instance
   whose switches stayed on and that passed the stand tests), with their inlier detections;
2. each stand with at least ``joint.min_inliers`` inliers becomes a landmark ``o(j)``; each
   inlier detection a ``BearingRangeFactor3D`` from the PV camera pose ``x(f)`` of its frame
   (bearing and range of the lifted point in the PV camera frame at the reported pose),
   with the tracker's range-dependent detection noise (scaled by ``joint.noise_scale``) and
   its robust kernel — all built-in C++ factors;
3. Levenberg-Marquardt over poses and landmarks;
4. the observations are moved by each frame's world correction
   ``W_f = reported_f⁻¹ · refined_f`` (row-vector algebra; AHAT poses follow the PV ones as in
   ``egograph refine``), and the tracker runs again on them and on the refined poses.

The landmark of a stand is seen from a few metres by many frames whose drift differs, so
the same object ties those frames together; the mesh and HoloLens factors keep the whole
trajectory in the annotation world frame.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from egograph.geometry.hl2ss import invert_rigid
from egograph.geometry.observations import Observations
from egograph.poses.refine import RefineResult, confirm_jumps, corrected_depth_poses, pose_change, refinement_factors
from egograph.track.config import DetectionNoiseConfig, JointConfig
from egograph.track.detection_factor import robust


@dataclass
class Stand:
    """A still object seen by detections: the PV frames and the world points lifted with the
    reported poses (metres), and a starting centre."""

    instance: int
    frames: np.ndarray            # (K,) PV frame indices
    world: np.ndarray             # (K, 3) lifted points, world frame, metres (the alias candidate used)
    xyz: np.ndarray               # (3,) starting centre, world, metres


@dataclass
class JointPoses:
    poses: RefineResult           # the solved PV and AHAT poses, in the form ``egograph refine`` writes
    landmarks: np.ndarray         # (J, 3) stand centres from the joint solve, world, metres
    report: dict = field(default_factory=dict)   # stands, factors, jump test, solver, pose change
    factors: object = None        # the RefinementGraph used (reusable by the next round)

    @property
    def pv_poses(self) -> np.ndarray:
        """(N, 4, 4) row-vector PV camera -> world, solved (NaN where invalid)."""
        return self.poses.pv_poses

    @property
    def depth_poses(self) -> np.ndarray:
        """(N, 4, 4) row-vector AHAT rig node -> world, moved with the PV poses."""
        return self.poses.depth_poses

    @property
    def depth_valid(self) -> np.ndarray:
        return self.poses.depth_valid


def object_key(j: int) -> int:
    """GTSAM key of the j-th stand's landmark in the joint graph."""
    return gtsam.symbol("o", int(j))


def stands_from_result(result, min_inliers: int) -> list[Stand]:
    """The stands of a :class:`~egograph.core.types.TrackResult` (offline) with their inliers."""
    out = []
    for sol in result.solutions:
        if sol.world is None:
            continue
        for seg in sol.segments:
            if not seg.stationary or seg.n_inliers < min_inliers:
                continue
            rows = seg.rows[seg.inliers]
            out.append(Stand(sol.instance, sol.frames[rows].astype(np.int64), sol.world[rows], np.asarray(seg.xyz)))
    return out


def add_stand_factors(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, stands: list[Stand],
                      pv_reported_col: np.ndarray, noise: DetectionNoiseConfig, noise_scale: float) -> int:
    """Landmark ``object_key(j)`` per stand and a bearing-range factor per detection whose frame has
    a pose variable ``x(f)``; returns the number of factors added.

    The measurement is the lifted point in the PV camera frame at the reported pose,
    ``p = R_fᵀ (w - t_f)``: bearing ``Unit3(p)``, range ``|p|`` (metres). Sigmas: across the ray
    ``(lateral_sigma_m + lateral_sigma_per_m·r)/r`` radians, along it ``range_sigma_m +
    range_sigma_per_m·r`` metres, times ``noise.scale`` and ``noise_scale``."""
    from egograph.poses.graph import pose_key

    n = 0
    for j, st in enumerate(stands):
        keys = np.array([pose_key(f) for f in st.frames])
        have = np.array([values.exists(int(k)) for k in keys], bool)
        if have.sum() == 0:
            continue
        T = pv_reported_col[st.frames[have]]
        p = np.einsum("kji,kj->ki", T[:, :3, :3], st.world[have] - T[:, :3, 3])   # R^T (w - t)
        r = np.linalg.norm(p, axis=1)
        lat = noise_scale * noise.scale * (noise.lateral_sigma_m + noise.lateral_sigma_per_m * r) / np.maximum(r, 1e-3)
        ray = noise_scale * noise.scale * (noise.range_sigma_m + noise.range_sigma_per_m * r)
        values.insert(object_key(j), gtsam.Point3(*np.asarray(st.xyz, float)))
        for key, pk, rk, lk, sk in zip(keys[have], p, r, lat, ray):
            model = robust(gtsam.noiseModel.Diagonal.Sigmas(np.array([lk, lk, sk])), noise.kernel, noise.kernel_width)
            graph.add(gtsam.BearingRangeFactor3D(int(key), object_key(j), gtsam.Unit3(pk), float(rk), model))
            n += 1
    return n


def joint_poses(rec, stands: list[Stand], refine_cfg, noise: DetectionNoiseConfig, cfg: JointConfig,
                progress: bool = False, factors=None) -> JointPoses:
    """Solve the refinement factors of ``rec`` together with the stands' landmarks.

    ``stands`` hold points lifted with ``rec``'s (reported) poses. ``factors``: a
    :class:`~egograph.poses.refine.RefinementGraph` of ``rec`` to reuse (it is not modified);
    built from ``refine_cfg`` when None, with the relocalisation-jump candidates left loose
    (``JointPoses.factors`` returns it): the jump test of ``egograph refine`` runs here on the
    joint solution, so an object seen before and after a jump also decides whether it happened."""
    from egograph.poses.constraints import pv_columns
    from egograph.poses.graph import solve, values_to_columns

    t = time.perf_counter()
    rg = factors if factors is not None else refinement_factors(rec, refine_cfg, progress=progress,
                                                                confirm_jumps_now=False)
    t_factors = time.perf_counter() - t
    pv_reported = pv_columns(rec)
    graph, values = rg.rebuild()
    n_det = add_stand_factors(graph, values, stands, pv_reported, noise, cfg.noise_scale)
    result, rep = solve(graph, values, cfg.max_iterations)
    drift = [c for c in rg.constraints if c.source == "drift"]
    jumps = None
    if refine_cfg.jump_confirm and drift and drift[0].info["loose"].any():
        # the relocalisation-jump test of ``egograph refine``, now with the landmarks' evidence too
        saved = drift[0].sigmas.copy()
        jumps = confirm_jumps(drift[0], result, refine_cfg)
        graph, values = rg.rebuild()
        drift[0].sigmas = saved                     # ``factors`` stays reusable for the next round
        add_stand_factors(graph, values, stands, pv_reported, noise, cfg.noise_scale)
        result, rep = solve(graph, result, cfg.max_iterations)
    pv_row = np.swapaxes(values_to_columns(result, len(rec)), 1, 2)
    depth_row, depth_valid = corrected_depth_poses(rec, pv_row)
    lms = np.array([np.asarray(result.atPoint3(object_key(j))) if result.exists(object_key(j)) else np.full(3, np.nan)
                    for j in range(len(stands))]).reshape(-1, 3)
    report = {"stands": len(stands), "detection_factors": n_det, "jumps": jumps,
              "refinement_factors": dict(rg.factor_counts), "factors_seconds": t_factors, "solver": rep,
              "change": pose_change(rec.pv_poses, pv_row)}
    poses = RefineResult(rec.timestamps.copy(), pv_row, depth_row, np.isfinite(pv_row).all(axis=(1, 2)), depth_valid,
                         dict(rg.stage_seconds, joint_solve=rep["seconds"]), dict(rg.factor_counts, stands=n_det),
                         {"joint": {k: v for k, v in report.items() if k != "change"}}, report["change"])
    if progress:
        ch = report["change"]
        print(f"joint poses: {len(stands)} stands, {n_det} detection factors; error {rep['error_initial']:.1f} -> "
              f"{rep['error_final']:.1f} in {rep['iterations']} iterations ({rep['seconds']:.1f} s); poses moved "
              f"{1000 * ch.get('trans_rms_m', 0):.1f} mm / {ch.get('rot_rms_deg', 0):.3f} deg RMS", flush=True)
    return JointPoses(poses, lms, report, rg)


def unmove_points(world: np.ndarray, frames: np.ndarray, corrections: np.ndarray) -> np.ndarray:
    """Inverse of the move of :func:`move_observations` for points ``world`` (K, 3) seen at ``frames``."""
    W = invert_rigid(corrections[np.asarray(frames, dtype=np.int64)])
    return np.einsum("ki,kij->kj", world, W[:, :3, :3]) + W[:, 3, :3]


def move_observations(obs: Observations, corrections: np.ndarray) -> Observations:
    """Observations re-expressed with corrected poses: world point, camera centre and every
    alias candidate of a detection move by its frame's correction (row vectors: ``p' = [p 1] · W``;
    ``corrections`` from :func:`egograph.poses.refine.world_corrections`, the same ones the
    refined AHAT poses get, so this equals lifting with them)."""
    if len(obs) == 0:
        return obs
    W = corrections[obs.frame.astype(np.int64)]                        # (M, 4, 4)
    R, t = W[:, :3, :3], W[:, 3, :3]

    def move(p: np.ndarray) -> np.ndarray:
        return np.einsum("mi,mij->mj", p, R) + t

    cand = np.einsum("mki,mij->mkj", obs.candidates, R) + t[:, None, :]
    return dataclasses.replace(obs, world=move(obs.world), camera=move(obs.camera), candidates=cand)


def with_joint_poses(rec, jp: JointPoses):
    """A copy of ``rec`` with the joint solve's PV and AHAT poses."""
    return dataclasses.replace(rec, pv_poses=jp.pv_poses, pv_valid=jp.poses.pv_valid,
                               depth_poses=jp.depth_poses, depth_valid=jp.depth_valid)
