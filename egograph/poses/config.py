"""Knobs of the pose-graph refinement (``egograph refine``). Lengths in metres, angles in
degrees, unless the name says otherwise. One boolean per constraint source."""

from __future__ import annotations

from dataclasses import dataclass

from egograph.core.config import Checked, knob, rule_error


@dataclass
class RefineConfig(Checked):
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
    hololens_sigma_rot: float = knob(0.1, "std of the white per-frame jitter of a reported pose, degrees", gt=0.0)
    hololens_sigma_trans: float = knob(0.005, "std of the white per-frame jitter of a reported pose, metres "
                                              "(includes the rotation jitter times the lever arm)", gt=0.0)
    hololens_kernel: float = knob(3.0, "Cauchy kernel width of the jitter factors, in sigmas (a pose spike is "
                                       "rejected); 0 = Gaussian", min=0.0)
    drift_rot: float = knob(0.03, "random-walk drift of the HoloLens world frame, degrees per sqrt(second)", gt=0.0)
    drift_trans: float = knob(0.003, "random-walk drift of the HoloLens world frame, metres per sqrt(second)", gt=0.0)
    drift_kernel: float = knob(3.0, "Cauchy kernel width of the drift factors, in sigmas; 0 = Gaussian", min=0.0)
    jump_turn_rate: float = knob(150.0, "relocalisation jumps are expected right after fast head turns: the end of "
                                        "every episode faster than this (reported angular speed, deg/s) ...", gt=0.0)
    jump_window: int = knob(1, "... loosens the drift factors within this many frames of it ...", min=0)
    jump_sigma_rot: float = knob(0.4, "... to this extra std, degrees ...", min=0.0)
    jump_sigma_trans: float = knob(0.04, "... and this extra std, metres (0 = no jump model)", min=0.0)
    prior_sigma_rot: float = knob(5.0, "std of the weak prior pulling the HoloLens world correction to identity "
                                       "(i.e. the refined poses to the reported ones), degrees", gt=0.0)
    prior_sigma_trans: float = knob(1.0, "std of that weak prior, metres", gt=0.0)
    jump_confirm: list[float] = knob([0.035, 0.4], "after a first solve, a loosened link stays loose only when the "
                                                     "estimated jump there exceeds [metres, degrees]; the others are "
                                                     "tightened again and the graph re-solved (so view-dependent "
                                                     "mesh errors do not move drift-free stretches); [] = one solve",
                                                     min=0.0, length=(0, 2))
    spike_trans: float = knob(0.5, "initialisation: a reported pose farther than this from the median of its "
                                    "+-5 frames is a spike and starts from its neighbours, metres", gt=0.0)
    spike_rot: float = knob(90.0, "... or rotated more than this from the median-position frame, degrees", gt=0.0)
    # ---- AHAT points
    point_stride: int = knob(6, "use every Nth AHAT pixel in each direction (6: 85x85 rays)", min=1)
    min_range: float = knob(0.2, "AHAT points nearer than this range are dropped (hands, flying pixels), metres",
                            min=0.0)
    max_range: float = knob(2.5, "AHAT points farther than this (unwrapped) range are dropped (noise grows with range²), metres",
                            gt=0.0)
    unwrap_with_mesh: bool = knob(True, "unwrap AHAT ranges beyond the alias distance with the mesh rendered from the "
                                        "reported pose; false (or no mesh): only readings below the alias distance "
                                        "are trusted as they are")
    unwrap_tolerance: float = knob(0.15, "an unwrapped point must lie this close to the rendered mesh range, metres",
                                   min=0.0)
    # ---- KISS-ICP
    icp_stride: int = knob(1, "run KISS-ICP on every Nth frame (relative factors between consecutive processed frames)",
                           min=1)
    icp_voxel: float = knob(0.05, "KISS-ICP voxel size, metres", gt=0.0)
    icp_max_iterations: int = knob(20, "KISS-ICP Gauss-Newton iterations per frame", min=1)
    icp_threshold: float = knob(0.05, "KISS-ICP fixed kernel/threshold sigma, metres (correspondences up to 3x this)",
                                gt=0.0)
    icp_max_correction: list[float] = knob([0.08, 4.0], "a KISS-ICP result that differs from the HoloLens-predicted "
                                                          "motion by more than [metres, degrees] is dropped and "
                                                          "the odometry restarts (a wrong convergence)",
                                                          gt=0.0, length=2)
    icp_max_turn_rate: float = knob(150.0, "no KISS-ICP factor across a link whose HoloLens angular speed exceeds this, "
                                           "deg/s (fast head turns are where ICP fails and where jumps sit)", gt=0.0)
    icp_sigma_rot: float = knob(0.15, "std of a KISS-ICP relative-pose factor, degrees", gt=0.0)
    icp_sigma_trans: float = knob(0.005, "std of a KISS-ICP relative-pose factor, metres", gt=0.0)
    icp_kernel: float = knob(2.0, "Cauchy kernel width of KISS-ICP factors, in sigmas", min=0.0)
    icp_min_points: int = knob(300, "frames with fewer usable AHAT points get no KISS-ICP factor", min=0)
    # ---- mesh ICP
    mesh_stride: int = knob(5, "run frame-to-mesh ICP on every Nth frame (5: one held-out keyframe per 20 frames "
                                "for the self-check, twice the evidence per segment of 10)", min=1)
    mesh_voxel: float = knob(0.03, "voxel size the AHAT source cloud is reduced to, metres", gt=0.0)
    mesh_max_distance: list[float] = knob([0.15, 0.06, 0.025], "coarse-to-fine correspondence distances, metres",
                                          gt=0.0)
    mesh_min_fitness: float = knob(0.85, "accept a mesh ICP result only when this share of source points has a "
                                        "correspondence at the finest distance", min=0.0, max=1.0)
    mesh_max_rmse: float = knob(0.015, "accept a mesh ICP result only when its inlier RMSE is below this, metres",
                                gt=0.0)
    mesh_min_points: int = knob(500, "keyframes with fewer usable AHAT points get no mesh factor", min=0)
    mesh_max_correction: list[float] = knob([0.25, 2.5], "reject a mesh ICP result that moves the starting pose by "
                                                           "more than [metres, degrees] (a wrong convergence); the "
                                                           "translation counts only along directions the view "
                                                           "constrains (sliding along a lone plane is free)",
                                                           gt=0.0, length=2)
    mesh_max_step: list[float] = knob([0.1, 1.5], "... and more than [metres, degrees] from the start, which carries "
                                                    "the world correction of the last well-constrained keyframe "
                                                    "forward (the HoloLens error drifts slowly)", gt=0.0, length=2)
    mesh_effective_points: float = knob(2.0, "a mesh factor's information is the point-to-plane Hessian per point "
                                             "times this over the residual variance: the mesh errors are correlated "
                                             "over a view, so only a few points count as independent; directions the "
                                             "view does not constrain (a lone plane) stay free", gt=0.0)
    mesh_min_sigma: float = knob(0.01, "floor of the point-to-plane residual std used for the information, metres",
                                 gt=0.0)
    mesh_kernel: float = knob(2.0, "Cauchy kernel width of mesh ICP factors, in sigmas", min=0.0)
    mesh_weak_ratio: float = knob(0.03, "a direction of a mesh factor's information (rotation counted as arc length "
                                        "at the view's RMS range) whose eigenvalue is below this share of the largest "
                                        "gets no information: a lone table top fixes height and two tilts, not the "
                                        "slide along it", min=0.0, max=1.0)
    mesh_starts: int = knob(4, "mesh ICP starts tried when the first does not converge cleanly (carried "
                               "correction, reported pose, then +-mesh_start_yaw)", min=1, max=4)
    mesh_start_yaw: float = knob(2.0, "yaw about the world vertical of the 3rd and 4th ICP starts, degrees", min=0.0)
    # ---- self-check (no ground truth) and the no-harm rule
    selfcheck: bool = knob(True, "hold mesh keyframes out of the solve, compare their mesh residual at the input "
                                 "and the refined poses per segment, and keep the input poses where the refinement "
                                 "shows no improvement (needs refine.mesh)")
    selfcheck_every: int = knob(4, "one mesh keyframe in this many is held out of the solve", min=2)
    selfcheck_segment: float = knob(10.0, "length of the segments the keep-or-refine decision is made for, seconds",
                                    gt=0.0)
    selfcheck_min_frames: int = knob(3, "a segment with fewer held-out keyframes that have depth keeps its input "
                                        "poses (no improvement can be shown)", min=1)
    selfcheck_truncate: float = knob(0.05, "mesh distances of held-out AHAT points are truncated at this before the "
                                           "residual RMS (points off the mesh: objects, people, holes), metres",
                                     gt=0.0)
    selfcheck_z: float = knob(2.0, "a segment takes the refined poses only when the mean drop of the held-out "
                                   "squared residual is this many standard errors above zero ...", min=0.0)
    selfcheck_min_gain: float = knob(0.0005, "... and the held-out residual RMS drops by at least this, metres "
                                             "(below it, mesh noise, not pose error)", min=0.0)
    selfcheck_blend: float = knob(1.0, "the refined poses are blended in over this long inside a refined segment "
                                       "next to a kept one (kept segments stay exactly the input, no step at the "
                                       "boundary), seconds", min=0.0)
    # ---- uncertainty
    covariance: bool = knob(True, "per-frame marginal covariance of the refined PV positions (gtsam.Marginals), "
                                  "written as pv_position_covariance.json")
    covariance_scale: float = knob(1.0, "the marginal covariance is multiplied by this (calibrated on the tuning "
                                        "seeds so that the NEES of the refined positions is about 3)", gt=0.0)
    # ---- COLMAP
    colmap_stride: int = knob(10, "PV keyframe stride for COLMAP", min=1)
    colmap_max_keyframes: int = knob(300, "at most this many PV keyframes (the stride grows to fit)", min=1)
    colmap_image_scale: float = knob(0.5, "PV images are resized by this factor before SIFT", gt=0.0, max=1.0)
    colmap_max_features: int = knob(2048, "SIFT features per keyframe", min=1)
    colmap_overlap: int = knob(5, "sequential matching: each keyframe is matched with the next N", min=1)
    colmap_loop_distance: float = knob(0.75, "loop-closure pairs: keyframes whose camera centres are closer than this, metres",
                                       min=0.0)
    colmap_loop_angle: float = knob(30.0, "... and whose viewing directions differ by less than this, degrees", min=0.0)
    colmap_loop_gap: int = knob(30, "... and that are at least this many frames apart", min=0)
    colmap_max_loop_pairs: int = knob(600, "at most this many loop-closure pairs (the closest in pose are kept)", min=0)
    colmap_covariance: bool = knob(True, "COLMAP relative-pose factors take their covariance from the bundle "
                                         "adjustment (pycolmap.estimate_ba_covariance, scaled by the variance of the "
                                         "reprojection residuals); false: the fixed colmap_sigma_* below", )
    colmap_min_sigma_rot: float = knob(0.01, "with colmap_covariance: floor added to the rotation std of a COLMAP "
                                             "factor, degrees (errors the model leaves out: the fixed intrinsics)",
                                       min=0.0)
    colmap_min_sigma_trans: float = knob(0.0005, "with colmap_covariance: floor added to the translation std of a "
                                                 "COLMAP factor, metres", min=0.0)
    colmap_sigma_rot: float = knob(0.3, "std of a COLMAP relative-pose factor, degrees (without colmap_covariance, "
                                        "or where the bundle adjustment gives none)", gt=0.0)
    colmap_sigma_trans: float = knob(0.01, "std of a COLMAP relative-pose factor, metres (as colmap_sigma_rot)",
                                     gt=0.0)
    colmap_kernel: float = knob(2.0, "Cauchy kernel width of COLMAP factors, in sigmas", min=0.0)
    colmap_prior_sigma: float = knob(0.05, "position prior std of every keyframe in the pose-prior bundle adjustment, metres",
                                     gt=0.0)
    colmap_min_points: int = knob(30, "keyframe pairs sharing fewer triangulated points get no factor", min=0)
    # ---- solver
    max_iterations: int = knob(50, "Levenberg-Marquardt iterations", min=1)
    seed: int = knob(0, "seed of every random choice (COLMAP's RANSAC in matching and triangulation)", min=0)

    def cross_check(self) -> None:
        if not self.mesh_max_distance:
            raise rule_error(self, "{} must list at least one distance", "mesh_max_distance")
        if not self.min_range < self.max_range:
            raise rule_error(self, "{} must be < {}", "min_range", "max_range")
