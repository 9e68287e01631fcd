"""The generator's PV colour: the OpenGL rasteriser against the ray-cast reference, and the PNG writer."""

import cv2
import numpy as np
import pytest
from conftest import TINY

from egograph.core.config import load_config
from egograph.core.errors import ConfigError
from egograph.geometry.hl2ss import invert_rigid
from egograph.io.png import encode_png, write_png
from egograph.synth.config import SynthConfig
from egograph.synth.generate import STREAMS, generate, render_mvpe_photos
from egograph.synth.scene import make_scene
from egograph.synth.sensors import (
    Textures,
    build_raycasting_scene,
    cast,
    make_calibration,
    pv_camera_rays,
    room_lamps,
    shade_hits,
)
from egograph.synth.trajectory import make_trajectory


def _decode(data: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)


def test_png_round_trips_rgb_grey_and_16_bit(tmp_path):
    rng = np.random.default_rng(4)
    rgb = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    assert np.array_equal(_decode(encode_png(rgb))[:, :, ::-1], rgb)   # OpenCV decodes to BGR
    grey = rng.integers(0, 256, (9, 7), dtype=np.uint8)
    assert np.array_equal(_decode(encode_png(grey, level=0)), grey)
    depth = rng.integers(0, 65536, (64, 48), dtype=np.uint16)
    write_png(tmp_path / "d.png", depth, level=3)
    back = cv2.imread(str(tmp_path / "d.png"), cv2.IMREAD_UNCHANGED)
    assert back.dtype == np.uint16 and np.array_equal(back, depth)
    with pytest.raises(ValueError, match=r"\(4, 4, 2\)"):
        encode_png(np.zeros((4, 4, 2), np.uint8))
    with pytest.raises(ValueError, match="float32"):
        encode_png(np.zeros((4, 4), np.float32))


@pytest.fixture(scope="module")
def scene_and_poses():
    cfg = load_config(SynthConfig, TINY, [])
    rngs = dict(zip(STREAMS, (np.random.default_rng(s) for s in np.random.SeedSequence(5).spawn(len(STREAMS)))))
    scene = make_scene(rngs["scene"], cfg.scene)
    traj = make_trajectory(rngs["activity"], scene, cfg)
    headset = make_calibration(cfg.ahat, cfg.pv)
    rig = traj.rig_poses(np.arange(cfg.frames, dtype=float))
    pv_true = invert_rigid(headset.pv.extrinsics) @ headset.node_to_head @ rig
    textures = Textures(rngs["textures"])
    lamps = room_lamps(rngs["textures"], scene.room_size)
    return scene, traj, headset.pv, pv_true, textures, lamps


@pytest.mark.slow
def test_rasteriser_matches_the_ray_cast_reference(scene_and_poses):
    """Same shading model, same pixel centres: the images agree except for a few pixels on
    silhouettes and texel boundaries (float rounding of the surface point)."""
    from egograph.synth.render_gl import PvRenderer

    scene, traj, pv_cal, pv_true, textures, lamps = scene_and_poses
    renderer = PvRenderer(scene, textures, lamps, pv_cal)
    dirs_cam, shape = pv_camera_rays(pv_cal, 1)
    held = [f for f in range(len(pv_true)) if traj.hand_at(f)[2]]
    frames = [held[len(held) // 3], held[2 * len(held) // 3], 0]  # two with the carrying hand
    assert len(frames) == 3
    for f in frames:
        pos, yaw = traj.objects_at(f)
        palm, body_yaw, on = traj.hand_at(f)
        hand = (palm, body_yaw) if on else None
        gl = renderer.render(pv_true[f], pos, yaw, hand)
        pose = pv_true[f]
        dirs = dirs_cam @ pose[:3, :3]
        hit = cast(build_raycasting_scene(scene, pos, yaw, hand), pose[3, :3], dirs)
        ref = (shade_hits(scene, textures, hit, pose[3, :3], dirs, pos, yaw, lamps).reshape(shape + (3,)) * 255
               ).astype(np.uint8)
        assert gl.shape == ref.shape == (720, 1280, 3) and gl.dtype == np.uint8
        diff = np.abs(gl.astype(int) - ref.astype(int)).max(axis=2)
        assert (diff == 0).mean() > 0.995, f"frame {f}: {(diff == 0).mean():.4f} of pixels equal"
        assert (diff > 2).mean() < 0.002
        assert gl.std() > 20  # not a blank frame: textured surfaces
        assert np.array_equal(renderer.render(pv_true[f], pos, yaw, hand), gl)  # deterministic
    renderer.release()


@pytest.mark.slow
def test_enrollment_photos_match_the_ray_cast_reference(scene_and_poses):
    scene, _, _, _, textures, _ = scene_and_poses
    gl = render_mvpe_photos(scene, textures, 48, load_config(SynthConfig, TINY, ["pv.renderer=gl"]))
    ref = render_mvpe_photos(scene, textures, 48, load_config(SynthConfig, TINY, ["pv.renderer=raycast"]))
    assert list(gl) == list(ref) == [o.name for o in scene.objects]
    for name in gl:
        a, b = np.stack(gl[name]).astype(int), np.stack(ref[name]).astype(int)
        assert a.shape == b.shape == (25, 48, 48, 3)
        assert (np.abs(a - b).max(axis=3) == 0).mean() > 0.99, name
        assert (a == 140).all(axis=3).mean() > 0.3  # the grey backdrop (0.55) around the object


def test_gl_renderer_unavailable_is_a_config_error_naming_the_fix(tmp_path, monkeypatch):
    import egograph.synth.render_gl as render_gl

    def no_gl():
        raise render_gl.GlUnavailable("no EGL OpenGL 3.3 context (libEGL.so.1 not found)")

    monkeypatch.setattr(render_gl, "gl_context", no_gl)
    cfg = load_config(SynthConfig, TINY, ["frames=4", "mvpe_photo_size=16"])
    with pytest.raises(ConfigError, match=r"libEGL.*pv\.renderer=raycast"):
        generate(tmp_path / "rec", cfg, seed=1, progress=False)
    assert not (tmp_path / "rec").exists()
