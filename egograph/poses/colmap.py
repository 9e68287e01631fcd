"""COLMAP (pycolmap) constraints from PV keyframes: relative-pose factors between keyframes.

1. Keyframes: every ``colmap_stride``-th frame with a valid pose and a PV image (the stride
   grows so that at most ``colmap_max_keyframes`` are used), resized by ``colmap_image_scale``.
2. SIFT features (``extract_features``, PINHOLE camera from the PV calibration, one camera).
3. Matching of image pairs given explicitly (``match_image_pairs``): sequential pairs (each
   keyframe with the next ``colmap_overlap``) and loop-closure pairs — keyframes far apart in
   time whose current camera centres and viewing directions are close — so revisits of a
   place are matched without a vocabulary tree.
4. Triangulation with the current poses (``triangulate_points`` on a reconstruction holding
   every keyframe at its current pose).
5. Bundle adjustment with position priors on every keyframe (``create_pose_prior_bundle_adjuster``:
   keeps the metric frame and scale).
6. For every matched pair that shares at least ``colmap_min_points`` triangulated points, the
   bundle-adjusted relative pose becomes a ``BetweenFactorPose3`` on the PV poses (Cauchy kernel),
   with the covariance of that relative pose from the bundle adjustment
   (``pycolmap.estimate_ba_covariance``: the Schur complement of the BA problem, scaled by the
   variance of its reprojection residuals) plus a small floor (``colmap_covariance``).

Conventions: COLMAP's ``cam_from_world`` is the OpenCV camera (x right, y down, z forward);
the hl2ss PV pose (column form) is ``P = C_cv · diag(1, -1, -1, 1)`` with ``C_cv`` = OpenCV
camera -> world.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from egograph.core.resources import require
from egograph.poses.config import RefineConfig
from egograph.poses.constraints import Constraints, invert_columns, sigmas

FLIP = np.diag([1.0, -1.0, -1.0, 1.0])


def keyframes(rec, cfg: RefineConfig, pv_estimate: np.ndarray) -> np.ndarray:
    ok = np.flatnonzero(np.isfinite(pv_estimate).all(axis=(1, 2)))
    ok = np.array([i for i in ok if rec.pv_path(int(i)).is_file()], dtype=int)
    stride = max(cfg.colmap_stride, int(np.ceil(len(ok) / max(cfg.colmap_max_keyframes, 1))))
    return ok[::stride]


def pair_list(frames: np.ndarray, pv_estimate: np.ndarray, cfg: RefineConfig) -> list[tuple[int, int]]:
    """Sequential pairs plus loop-closure pairs by pose proximity (indices into ``frames``)."""
    n = len(frames)
    pairs = {(a, b) for a in range(n) for b in range(a + 1, min(n, a + 1 + cfg.colmap_overlap))}
    c = pv_estimate[frames, :3, 3]
    view = -pv_estimate[frames, :3, 2]                    # hl2ss PV camera looks down -z
    d = np.linalg.norm(c[:, None] - c[None], axis=2)
    cosang = np.clip(view @ view.T, -1, 1)
    gap = np.abs(frames[:, None] - frames[None])
    cand = (d < cfg.colmap_loop_distance) & (cosang > np.cos(np.radians(cfg.colmap_loop_angle))) & \
        (gap >= cfg.colmap_loop_gap) & np.triu(np.ones((n, n), bool), 1)
    a, b = np.nonzero(cand)
    order = np.argsort(d[a, b] + (1 - cosang[a, b]))[:cfg.colmap_max_loop_pairs]
    pairs |= {(int(a[k]), int(b[k])) for k in order}
    return sorted(pairs)


def colmap_constraints(rec, cfg: RefineConfig, pv_estimate: np.ndarray, progress: bool = False
                       ) -> tuple[Constraints, dict]:
    """Relative PV-pose constraints from COLMAP on the PV keyframes (see the module docstring).

    ``pv_estimate``: (N, 4, 4) column PV camera -> world, the current poses (triangulation and priors).
    """
    pycolmap = require("pycolmap", "colmap", "refine.colmap=true")

    stats: dict = {}
    level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 2 if not progress else 1     # COLMAP's own log: errors (and warnings)
    try:
        return _colmap_constraints(rec, cfg, pv_estimate, progress, stats)
    finally:
        pycolmap.logging.minloglevel = level


def _colmap_constraints(rec, cfg, pv_estimate, progress, stats):
    import cv2
    pycolmap = require("pycolmap", "colmap", "refine.colmap=true")
    from tqdm import tqdm

    frames = keyframes(rec, cfg, pv_estimate)
    stats["keyframes"] = int(len(frames))
    empty = Constraints.empty("colmap", "relative", cfg.colmap_kernel, stats=stats)
    if len(frames) < 3:
        return empty, stats
    s = cfg.colmap_image_scale
    k = rec.pv.intrinsics
    fx, fy, cx, cy = -k[0, 0] * s, k[1, 1] * s, k[2, 0] * s, k[2, 1] * s
    with tempfile.TemporaryDirectory(prefix="egograph_colmap_") as tmp:
        tmp = Path(tmp)
        img_dir, db_path = tmp / "images", tmp / "database.db"
        img_dir.mkdir()
        names = []
        t = time.perf_counter()
        for i in tqdm(frames, desc="COLMAP images", unit="image", disable=not progress, leave=False):
            img = cv2.imread(str(rec.pv_path(int(i))), cv2.IMREAD_COLOR)
            if s != 1:
                img = cv2.resize(img, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
            name = f"{int(i):07d}.jpg"
            cv2.imwrite(str(img_dir / name), img, [cv2.IMWRITE_JPEG_QUALITY, 95])
            names.append(name)
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "PINHOLE"
        reader.camera_params = f"{fx},{fy},{cx},{cy}"
        ext = pycolmap.FeatureExtractionOptions()
        ext.sift.max_num_features = cfg.colmap_max_features
        ext.num_threads = 1  # SIFT on 2 threads gives other features run to run (matching on 2 does not)
        pycolmap.extract_features(db_path, img_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                                  reader_options=reader, extraction_options=ext, device=pycolmap.Device.cpu)
        stats["seconds_features"] = time.perf_counter() - t

        t = time.perf_counter()
        pairs = pair_list(frames, pv_estimate, cfg)
        (tmp / "pairs.txt").write_text("".join(f"{names[a]} {names[b]}\n" for a, b in pairs))
        match = pycolmap.FeatureMatchingOptions()
        match.num_threads = 1  # two threads gave other matches run to run under load (a CI run): same bytes first
        verify = pycolmap.TwoViewGeometryOptions()
        verify.ransac.random_seed = cfg.seed
        pycolmap.match_image_pairs(db_path, matching_options=match,
                                   pairing_options=pycolmap.ImportedPairingOptions(match_list_path=str(tmp / "pairs.txt")),
                                   verification_options=verify, device=pycolmap.Device.cpu)
        stats["pairs"] = len(pairs)
        stats["loop_pairs"] = sum(1 for a, b in pairs if b - a > cfg.colmap_overlap)
        stats["seconds_matching"] = time.perf_counter() - t

        t = time.perf_counter()
        recon = _known_pose_reconstruction(db_path, frames, names, pv_estimate)
        opts = pycolmap.IncrementalPipelineOptions()
        opts.triangulation.ignore_two_view_tracks = False
        opts.triangulation.random_seed = cfg.seed
        recon = pycolmap.triangulate_points(recon, db_path, img_dir, tmp / "sparse", options=opts)
        stats["points"] = int(recon.num_points3D())
        stats["seconds_triangulation"] = time.perf_counter() - t
        if recon.num_points3D() < 20:
            return empty, stats

        t = time.perf_counter()
        recon.update_point_3d_errors()
        stats["reproj_before_px"] = float(recon.compute_mean_reprojection_error())
        adjuster = _prior_bundle_adjustment(recon, frames, names, pv_estimate, cfg)
        recon.update_point_3d_errors()
        stats["reproj_after_px"] = float(recon.compute_mean_reprojection_error())
        stats["seconds_ba"] = time.perf_counter() - t
        bac = None
        if cfg.colmap_covariance:
            t = time.perf_counter()
            bac = pycolmap.estimate_ba_covariance(pycolmap.BACovarianceOptions(), recon, adjuster)
            stats["seconds_covariance"] = time.perf_counter() - t
        stats[MODEL_KEY] = model_files(recon, tmp / "model", frames, names, rec.timestamps)

        by_name = {img.name: img for img in recon.images.values()}
        poses, point_sets, images = {}, {}, {}
        for a, name in enumerate(names):
            img = by_name.get(name)
            if img is None or not img.has_pose:
                continue
            m = np.eye(4)
            m[:3, :4] = img.cam_from_world().matrix()
            poses[a] = np.linalg.inv(m) @ FLIP                   # hl2ss PV camera -> world (column)
            point_sets[a] = {p.point3D_id for p in img.points2D if p.has_point3D()}
            images[a] = (img.image_id, img.cam_from_world())
        out_i, out_j, out_T, out_cov = [], [], [], []
        # Ceres weighs every residual with 1 px; the covariance scales with the residuals' variance
        # (per axis, from the mean reprojection error of a 2D Gaussian: mean = sigma * sqrt(pi / 2)).
        var_px = (stats["reproj_after_px"] / np.sqrt(np.pi / 2)) ** 2
        for a, b in pairs:
            if a in poses and b in poses and len(point_sets[a] & point_sets[b]) >= cfg.colmap_min_points:
                out_i.append(int(frames[a]))
                out_j.append(int(frames[b]))
                out_T.append(invert_columns(poses[a]) @ poses[b])
                cov = None if bac is None else bac.get_cam2_cov_from_cam1(*images[a], *images[b])
                out_cov.append(None if cov is None or not np.isfinite(cov).all() else relative_covariance(cov * var_px, cfg))
    n = len(out_i)
    stats["factors"] = n
    stats["factors_with_ba_covariance"] = sum(c is not None for c in out_cov)
    fixed = sigmas(cfg.colmap_sigma_rot, cfg.colmap_sigma_trans, 1)[0]
    information = None
    if stats["factors_with_ba_covariance"]:
        information = np.array([np.linalg.inv(c) if c is not None else np.diag(fixed ** -2.0) for c in out_cov])
        stats["ba_sigma_median"] = np.median(np.sqrt([np.diag(c) for c in out_cov if c is not None]), axis=0).tolist()
    return Constraints("colmap", "relative", np.array(out_i, int), np.array(out_j, int), np.array(out_T).reshape(n, 4, 4),
                       sigmas(cfg.colmap_sigma_rot, cfg.colmap_sigma_trans, n), cfg.colmap_kernel, {"stats": stats},
                       information=information), stats


# COLMAP's OpenCV camera -> the hl2ss PV camera: a fixed rotation, so a tangent vector rotates by it.
_FLIP_ADJOINT = np.kron(np.eye(2), FLIP[:3, :3])


def relative_covariance(cov_cam2_from_cam1: np.ndarray, cfg: RefineConfig) -> np.ndarray:
    """Covariance (6x6, GTSAM Pose3 tangent ``[rot, trans]``, right perturbation) of the relative PV
    pose ``T_ab = x_a⁻¹ x_b`` from COLMAP's covariance of ``cam2_from_cam1`` (``[rot, trans]``, left
    perturbation ``Exp(δ)·S``, OpenCV cameras), plus the ``colmap_min_sigma_*`` floor.

    ``T_ab = F · S⁻¹ · F`` (``F`` the OpenCV -> hl2ss flip) and ``(Exp(δ) S)⁻¹ = S⁻¹ Exp(-δ)``, so the
    right perturbation of ``T_ab`` is ``-Ad(F)·δ``: the covariance rotates by the flip in both blocks.
    """
    c = _FLIP_ADJOINT @ cov_cam2_from_cam1 @ _FLIP_ADJOINT.T
    floor = np.r_[[np.radians(cfg.colmap_min_sigma_rot) ** 2] * 3, [cfg.colmap_min_sigma_trans ** 2] * 3]
    return 0.5 * (c + c.T) + np.diag(floor)


MODEL_KEY = "_model_files"
"""Key of the stats dict holding the bundle-adjusted model's files (name -> bytes); the refine
output writes them to ``OUT/colmap/`` and keeps them out of ``report.json``."""


def model_files(recon, folder: Path, frames, names, timestamps) -> dict[str, bytes]:
    """The reconstruction in COLMAP's text format (``cameras.txt``, ``images.txt``,
    ``points3D.txt``; COLMAP's own camera convention, world frame of the recording, metres) plus
    ``keyframes.txt`` (``image_name pv_frame_index timestamp_ticks``: the image names are
    egograph's temporary keyframe files, so this maps them back to PV frames)."""
    folder.mkdir(parents=True, exist_ok=True)
    recon.write_text(str(folder))
    files = {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}
    rows = "".join(f"{n} {int(i)} {int(timestamps[int(i)])}\n" for n, i in zip(names, frames))
    files["keyframes.txt"] = ("# image_name pv_frame_index timestamp (100 ns ticks)\n" + rows).encode()
    return files


def _known_pose_reconstruction(db_path: Path, frames, names, pv_estimate):
    """A reconstruction with the database's camera and images at the current poses (no points)."""
    pycolmap = require("pycolmap", "colmap", "refine.colmap=true")

    db = pycolmap.Database.open(str(db_path)) if hasattr(pycolmap.Database, "open") else pycolmap.Database(str(db_path))
    try:
        recon = pycolmap.Reconstruction()
        for cam in db.read_all_cameras():
            recon.add_camera_with_trivial_rig(cam)
        index = {n: a for a, n in enumerate(names)}
        for img in db.read_all_images():
            a = index[img.name]
            kp = db.read_keypoints(img.image_id)[:, :2].astype(np.float64)
            c_cv = pv_estimate[frames[a]] @ FLIP                    # OpenCV camera -> world
            cam_from_world = np.linalg.inv(c_cv)[:3, :4]
            im = pycolmap.Image(name=img.name, keypoints=kp, camera_id=img.camera_id, image_id=img.image_id)
            recon.add_image_with_trivial_frame(im, pycolmap.Rigid3d(cam_from_world))
    finally:
        db.close()
    return recon


def _prior_bundle_adjustment(recon, frames, names, pv_estimate, cfg: RefineConfig):
    """Bundle adjustment (poses and points) with a position prior on every keyframe (metric frame kept);
    returns the Ceres adjuster (its problem gives the covariance)."""
    pycolmap = require("pycolmap", "colmap", "refine.colmap=true")

    config = pycolmap.BundleAdjustmentConfig()
    priors = []
    index = {n: a for a, n in enumerate(names)}
    var = cfg.colmap_prior_sigma ** 2
    for image_id, img in recon.images.items():
        if not img.has_pose:
            continue
        config.add_image(image_id)
        a = index[img.name]
        pr = pycolmap.PosePrior()
        pr.position = pv_estimate[frames[a], :3, 3].astype(np.float64)
        pr.position_covariance = np.eye(3) * var
        pr.coordinate_system = pycolmap.PosePriorCoordinateSystem.CARTESIAN
        pr.corr_data_id = img.data_id
        priors.append(pr)
    for pid in recon.point3D_ids():
        config.add_variable_point(pid)
    config.set_constant_cam_intrinsics(next(iter(recon.cameras)))
    ba = pycolmap.BundleAdjustmentOptions()
    ba.ceres.solver_options.num_threads = 1  # Ceres' threaded evaluation sums in another order run to run
    adjuster = pycolmap.create_pose_prior_ceres_bundle_adjuster(ba, pycolmap.PosePriorBundleAdjustmentOptions(),
                                                                config, priors, recon)
    adjuster.solve()
    return adjuster
