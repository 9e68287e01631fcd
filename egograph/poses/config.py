"""Knobs of the pose-graph refinement (``egograph refine``). Lengths in metres, angles in
degrees, unless the name says otherwise. One boolean per constraint source."""

from __future__ import annotations

from dataclasses import dataclass

from egograph.core.config import knob
from egograph.core.errors import ConfigError


@dataclass
class RefineConfig:
    # ---- sources
    hololens: bool = knob(True, "HoloLens relative motion between consecutive frames as between-factors "
                                "(false: frames are tied only by the other sources and the weak prior)")
    icp: bool = knob(False, "KISS-ICP odometry on AHAT point clouds as relative constraints (robust kernel); off by "
                            "default: on the benchmark it is slower than the 3-minute budget and no better than the "
                            "HoloLens relative tracking (see README)")
    mesh: bool = knob(True, "frame-to-mesh point-to-plane ICP (Open3D) against the HoloLens scene mesh as absolute "
                            "constraints on keyframes (robust kernel)")
    colmap: bool = knob(False, "COLMAP (pycolmap) SIFT on PV keyframes, triangulation with the current poses and "
                               "bundle adjustment, as relative-pose factors between keyframes (needs pv/*.png; slow)")
    # ---- HoloLens error model: reported_i = E_i · true_i, E_i = drift/jumps (slow) x jitter (white)
    hololens_sigma_rot: float = knob(0.1, "std of the white per-frame jitter of a reported pose, degrees")
    hololens_sigma_trans: float = knob(0.005, "std of the white per-frame jitter of a reported pose, metres "
                                              "(includes the rotation jitter times the lever arm)")
    hololens_kernel: float = knob(3.0, "Cauchy kernel width of the jitter factors, in sigmas (a pose spike is "
                                       "rejected); 0 = Gaussian")
    drift_rot: float = knob(0.03, "random-walk drift of the HoloLens world frame, degrees per sqrt(second)")
    drift_trans: float = knob(0.003, "random-walk drift of the HoloLens world frame, metres per sqrt(second)")
    drift_kernel: float = knob(3.0, "Cauchy kernel width of the drift factors, in sigmas; 0 = Gaussian")
    jump_turn_rate: float = knob(150.0, "relocalisation jumps are expected right after fast head turns: the end of "
                                        "every episode faster than this (reported angular speed, deg/s) ...")
    jump_window: int = knob(1, "... loosens the drift factors within this many frames of it ...")
    jump_sigma_rot: float = knob(0.4, "... to this extra std, degrees ...")
    jump_sigma_trans: float = knob(0.04, "... and this extra std, metres (0 = no jump model)")
    prior_sigma_rot: float = knob(5.0, "std of the weak prior pulling the HoloLens world correction to identity "
                                       "(i.e. the refined poses to the reported ones), degrees")
    prior_sigma_trans: float = knob(1.0, "std of that weak prior, metres")
    jump_confirm: list[float] = knob([0.035, 0.4], "after a first solve, a loosened link stays loose only when the "
                                                     "estimated jump there exceeds [metres, degrees]; the others are "
                                                     "tightened again and the graph re-solved (so view-dependent "
                                                     "mesh errors do not move drift-free stretches); [] = one solve")
    spike_trans: float = knob(0.5, "initialisation: a reported pose farther than this from the median of its "
                                    "+-5 frames is a spike and starts from its neighbours, metres")
    spike_rot: float = knob(90.0, "... or rotated more than this from the median-position frame, degrees")
    # ---- AHAT points
    point_stride: int = knob(6, "use every Nth AHAT pixel in each direction (6: 85x85 rays)")
    min_range: float = knob(0.2, "AHAT points nearer than this range are dropped (hands, flying pixels), metres")
    max_range: float = knob(2.5, "AHAT points farther than this (unwrapped) range are dropped (noise grows with range²), metres")
    unwrap_with_mesh: bool = knob(True, "unwrap AHAT ranges beyond the alias distance with the mesh rendered from the "
                                        "reported pose; false (or no mesh): only readings below the alias distance "
                                        "are trusted as they are")
    unwrap_tolerance: float = knob(0.15, "an unwrapped point must lie this close to the rendered mesh range, metres")
    # ---- KISS-ICP
    icp_stride: int = knob(1, "run KISS-ICP on every Nth frame (relative factors between consecutive processed frames)")
    icp_voxel: float = knob(0.05, "KISS-ICP voxel size, metres")
    icp_max_iterations: int = knob(20, "KISS-ICP Gauss-Newton iterations per frame")
    icp_threshold: float = knob(0.05, "KISS-ICP fixed kernel/threshold sigma, metres (correspondences up to 3x this)")
    icp_max_correction: list[float] = knob([0.08, 4.0], "a KISS-ICP result that differs from the HoloLens-predicted "
                                                          "motion by more than [metres, degrees] is dropped and "
                                                          "the odometry restarts (a wrong convergence)")
    icp_max_turn_rate: float = knob(150.0, "no KISS-ICP factor across a link whose HoloLens angular speed exceeds this, "
                                           "deg/s (fast head turns are where ICP fails and where jumps sit)")
    icp_sigma_rot: float = knob(0.15, "std of a KISS-ICP relative-pose factor, degrees")
    icp_sigma_trans: float = knob(0.005, "std of a KISS-ICP relative-pose factor, metres")
    icp_kernel: float = knob(2.0, "Cauchy kernel width of KISS-ICP factors, in sigmas")
    icp_min_points: int = knob(300, "frames with fewer usable AHAT points get no KISS-ICP factor")
    # ---- mesh ICP
    mesh_stride: int = knob(10, "run frame-to-mesh ICP on every Nth frame")
    mesh_voxel: float = knob(0.03, "voxel size the AHAT source cloud is reduced to, metres")
    mesh_max_distance: list[float] = knob([0.15, 0.06, 0.025], "coarse-to-fine correspondence distances, metres")
    mesh_min_fitness: float = knob(0.85, "accept a mesh ICP result only when this share of source points has a "
                                        "correspondence at the finest distance")
    mesh_max_rmse: float = knob(0.015, "accept a mesh ICP result only when its inlier RMSE is below this, metres")
    mesh_min_points: int = knob(500, "keyframes with fewer usable AHAT points get no mesh factor")
    mesh_max_correction: list[float] = knob([0.25, 2.5], "reject a mesh ICP result that moves the starting pose by "
                                                           "more than [metres, degrees] (a wrong convergence); the "
                                                           "translation counts only along directions the view "
                                                           "constrains (sliding along a lone plane is free)")
    mesh_max_step: list[float] = knob([0.1, 1.5], "... and more than [metres, degrees] from the start, which carries "
                                                    "the world correction of the last well-constrained keyframe "
                                                    "forward (the HoloLens error drifts slowly)")
    mesh_effective_points: float = knob(2.0, "a mesh factor's information is the point-to-plane Hessian per point "
                                             "times this over the residual variance: the mesh errors are correlated "
                                             "over a view, so only a few points count as independent; directions the "
                                             "view does not constrain (a lone plane) stay free")
    mesh_min_sigma: float = knob(0.01, "floor of the point-to-plane residual std used for the information, metres")
    mesh_kernel: float = knob(2.0, "Cauchy kernel width of mesh ICP factors, in sigmas")
    # ---- COLMAP
    colmap_stride: int = knob(10, "PV keyframe stride for COLMAP")
    colmap_max_keyframes: int = knob(300, "at most this many PV keyframes (the stride grows to fit)")
    colmap_image_scale: float = knob(0.5, "PV images are resized by this factor before SIFT")
    colmap_max_features: int = knob(2048, "SIFT features per keyframe")
    colmap_overlap: int = knob(5, "sequential matching: each keyframe is matched with the next N")
    colmap_loop_distance: float = knob(0.75, "loop-closure pairs: keyframes whose camera centres are closer than this, metres")
    colmap_loop_angle: float = knob(30.0, "... and whose viewing directions differ by less than this, degrees")
    colmap_loop_gap: int = knob(30, "... and that are at least this many frames apart")
    colmap_max_loop_pairs: int = knob(600, "at most this many loop-closure pairs (the closest in pose are kept)")
    colmap_sigma_rot: float = knob(0.3, "std of a COLMAP relative-pose factor, degrees")
    colmap_sigma_trans: float = knob(0.01, "std of a COLMAP relative-pose factor, metres")
    colmap_kernel: float = knob(2.0, "Cauchy kernel width of COLMAP factors, in sigmas")
    colmap_prior_sigma: float = knob(0.05, "position prior std of every keyframe in the pose-prior bundle adjustment, metres")
    colmap_min_points: int = knob(30, "keyframe pairs sharing fewer triangulated points get no factor")
    # ---- solver
    max_iterations: int = knob(50, "Levenberg-Marquardt iterations")
    seed: int = knob(0, "seed of every random choice (COLMAP's RANSAC in matching and triangulation)")

    def check(self) -> None:
        for name in ("point_stride", "icp_stride", "mesh_stride", "colmap_stride"):
            if getattr(self, name) < 1:
                raise ConfigError(f"refine.{name} must be >= 1")
        for name in ("hololens_sigma_rot", "hololens_sigma_trans", "prior_sigma_rot", "prior_sigma_trans",
                     "icp_sigma_rot", "icp_sigma_trans", "mesh_effective_points", "mesh_min_sigma",
                     "colmap_sigma_rot", "colmap_sigma_trans", "icp_voxel", "mesh_voxel"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"refine.{name} must be > 0")
        if not self.mesh_max_distance or any(d <= 0 for d in self.mesh_max_distance):
            raise ConfigError("refine.mesh_max_distance must be a non-empty list of positive distances")
        if not 0 < self.colmap_image_scale <= 1:
            raise ConfigError("refine.colmap_image_scale must be in (0, 1]")
