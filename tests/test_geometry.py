"""hl2ss conventions: round trips through PV and AHAT on a synthetic recording (no noise)."""

import numpy as np
import pytest

from egograph.geometry import hl2ss as g
from egograph.geometry.ahat_model import camera_to_pixel, pixel_lookup
from egograph.io.poses import read_pose_json
from egograph.io.recording import Recording


@pytest.fixture(scope="module")
def rec(tiny_rec):
    return Recording.open(tiny_rec)


@pytest.fixture(scope="module")
def truth(rec):
    _, pv, _ = read_pose_json(rec.synth_gt_dir / "pv_pose.json")
    _, depth, _ = read_pose_json(rec.synth_gt_dir / "depth_ahat_pose.json")
    return pv, depth


def test_invert_rigid_and_transform():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(3, 3))
    q, _ = np.linalg.qr(a)
    q *= np.sign(np.linalg.det(q))
    m = g.rigid_from_rt(q, [1.0, -2.0, 0.5])
    p = rng.normal(size=(10, 3))
    np.testing.assert_allclose(g.transform_points(p, m), p @ q.T + [1.0, -2.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(g.transform_points(g.transform_points(p, m), g.invert_rigid(m)), p, atol=1e-12)
    assert g.pose_validity(np.stack([m, np.full((4, 4), np.nan), np.zeros((4, 4))])).tolist() == [True, False, False]


def test_ahat_pixel_round_trip(rec, truth):
    """AHAT pixel + range -> camera -> world -> AHAT pixel again, at < 1 mm / 0.01 px."""
    _, depth = truth
    ahat = rec.ahat
    rng = np.random.default_rng(1)
    v, u = rng.integers(0, 512, 400), rng.integers(0, 512, 400)
    # pixels with a ray, away from the rim (the real lens has none in its corners, none past 60 deg)
    angle = np.degrees(np.arctan(np.linalg.norm(np.asarray(ahat.uv2xy, float)[v, u], axis=1)))
    keep = ahat.valid_mask[v, u] & (angle < 55.0)
    v, u = v[keep][:50], u[keep][:50]
    ranges = rng.uniform(0.3, 4.0, len(v))
    # Unwrapped float raw values (no quantisation) -> camera points.
    raw = np.zeros((512, 512))
    raw[v, u] = ranges * ahat.scale / rec.depth_factor
    cam = g.ahat_raw_to_camera(raw, ahat.uv2xy, ahat.scale, rec.depth_factor)[v, u]
    np.testing.assert_allclose(np.linalg.norm(cam, axis=1), ranges, atol=1e-6)
    i = 100
    world = g.transform_points(cam, g.ahat_to_world_matrix(ahat.extrinsics, depth[i]))
    back = g.transform_points(world, g.invert_rigid(g.ahat_to_world_matrix(ahat.extrinsics, depth[i])))
    np.testing.assert_allclose(back, cam, atol=1e-9)
    # through the real rays: intrinsics.bin is a wide viewing pinhole, not the lens
    uv = pixel_lookup(ahat).project(back)
    np.testing.assert_allclose(uv, np.stack([u + 0.5, v + 0.5], 1), atol=2e-2)
    np.testing.assert_allclose(camera_to_pixel(back, ahat), np.stack([u + 0.5, v + 0.5], 1), atol=1e-4)


def test_world_point_through_pv_and_ahat(rec, truth):
    """A true object centre: project into PV and AHAT, lift back from each, within 1 mm."""
    pv, depth = truth
    data = np.load(rec.synth_gt_dir / "instances.npz")
    vis = data["visible"]
    i, k = np.unravel_index(np.argmax(vis), vis.shape)
    x = data["positions"][i, k]
    # PV: world -> camera -> pixels + depth -> back.
    cam = g.transform_points(x, g.world_to_pv_matrix(pv[i]))
    uv, d = g.pv_project(cam, rec.pv.intrinsics)
    assert 0 <= uv[0] < 1280 and 0 <= uv[1] < 720 and d > 0
    back = g.transform_points(g.pv_unproject(uv, d, rec.pv.intrinsics), pv[i])
    assert np.linalg.norm(back - x) < 1e-3
    # The annotated-style projection lands inside the true box of that frame.
    box = data["boxes"][i, k]
    assert box[0] - 1 <= uv[0] <= box[2] + 1 and box[1] - 1 <= uv[1] <= box[3] + 1
    # AHAT: world -> camera -> range along the ray -> raw -> camera -> world.
    to_cam = g.invert_rigid(g.ahat_to_world_matrix(rec.ahat.extrinsics, depth[i]))
    pa = g.transform_points(x, to_cam)
    r = np.linalg.norm(pa)
    xy = pa[:2] / pa[2]
    z = (r * rec.ahat.scale / rec.depth_factor) / (np.sqrt(xy @ xy + 1) * rec.ahat.scale / rec.depth_factor)
    lifted = np.append(xy, 1.0) * z
    assert np.linalg.norm(g.transform_points(lifted, g.invert_rigid(to_cam)) - x) < 1e-3
    # OpenCV form agrees with the hl2ss PV convention.
    k_cv, c2w = g.pv_to_opencv(rec.pv.intrinsics, pv[i])
    pc = np.linalg.inv(c2w) @ np.append(x, 1.0)
    uv_cv = (k_cv @ pc[:3])[:2] / pc[2]
    np.testing.assert_allclose(uv_cv, uv, atol=1e-6)


def test_static_and_posed_registration_agree_without_head_motion(rec, truth):
    """AHAT -> PV image: the rig chain and the per-frame pose chain coincide at one instant."""
    _, depth = truth
    rig = depth[50]
    pv_pose = g.invert_rigid(rec.pv.extrinsics) @ rig  # PV camera -> world at the same instant
    static = g.ahat_to_pv_image_static(rec.ahat.extrinsics, rec.pv.extrinsics, rec.pv.intrinsics)
    posed = g.ahat_to_pv_image_posed(rec.ahat.extrinsics, rig, pv_pose, rec.pv.intrinsics)
    pts = np.random.default_rng(2).uniform([-0.5, -0.5, 0.5], [0.5, 0.5, 3.0], (20, 3))
    uv_s, _ = g.project_homogeneous(pts, static)
    uv_p, _ = g.project_homogeneous(pts, posed)
    np.testing.assert_allclose(uv_s, uv_p, atol=1e-6)


def test_alias_wrap_and_candidates():
    r = np.array([0.3, 1.8, 2.2])
    w = g.wrap_range(r, 1.055)
    np.testing.assert_allclose(w, [0.3, 0.745, 2.2 - 2 * 1.055])
    c = g.alias_candidates(w, 1.055, 2.3)
    for true, row in zip(r, c):
        assert np.nanmin(np.abs(row - true)) < 1e-9
    assert np.isnan(c[:, -1]).any()
    raw = g.ahat_range_to_raw(np.array([0.745]), 1000.0, 4.0)
    assert raw.dtype == np.uint16 and raw[0] == 186  # 745 mm in 4 mm units


def test_ahat_unit_rays_match_the_camera_points(rec):
    """Unit rays (float64) point at the camera points of any reading; [x, y, 1] keeps the input dtype."""
    uv2xy = rec.ahat.uv2xy
    dirs = g.ahat_unit_rays(uv2xy)
    assert dirs.shape == uv2xy.shape[:2] + (3,) and dirs.dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=-1), 1.0, atol=1e-12)
    xy1 = g.ahat_xy1(uv2xy)
    assert xy1.dtype == uv2xy.dtype and (xy1[..., 2] == 1).all()
    raw = np.full(uv2xy.shape[:2], 250.0)
    cam = g.ahat_raw_to_camera(raw, uv2xy, rec.ahat.scale, rec.depth_factor)
    # (ahat_raw_to_camera works in the calibration's float32)
    np.testing.assert_allclose(cam, dirs * 250.0 * rec.depth_factor / rec.ahat.scale, atol=1e-6)
    # subsets of pixels get the same bits as the full grid
    assert g.ahat_unit_rays(uv2xy[::7, 3::5]).tobytes() == dirs[::7, 3::5].tobytes()


def test_recording_builds_its_mesh_scene_once_and_lazily(tiny_rec):
    """Opening a recording does not import Open3D; its mesh scene is built once and shared by copies."""
    import dataclasses
    import subprocess
    import sys

    code = ("import sys; from egograph.io.recording import Recording; "
            f"Recording.open({str(tiny_rec)!r}); print('open3d' in sys.modules)")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() \
        == "False"
    rec = Recording.open(tiny_rec)
    scene = rec.mesh_scene()
    assert scene is not None and rec.mesh_scene() is scene
    assert dataclasses.replace(rec, pv_poses=rec.pv_poses.copy()).mesh_scene() is scene
