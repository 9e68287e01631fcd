"""The device world (world: device): photographic look-alikes, the PV camera's blur, exposure and
noise, and the hand that covers the carried object."""

import json

import cv2
import numpy as np
import pytest

from egograph.core.config import load_config
from egograph.core.errors import ConfigError
from egograph.core.resources import synth_config
from egograph.synth.camera import AutoExposure, Exposure, develop, image_motion
from egograph.synth.config import PvCameraConfig, SynthConfig
from egograph.synth.generate import STREAMS, generate, recorded_config
from egograph.synth.materials import PhotoLibrary, render_design

DEVICE_TINY = synth_config("device-tiny")
SEED = 2  # its 150 frames hold one carry (frames 61-102) and fast head turns


def _ranks(x: np.ndarray) -> np.ndarray:
    r = np.empty(len(x))
    r[np.argsort(x, kind="stable")] = np.arange(len(x))
    return r


def spearman(a, b) -> float:
    ra, rb = _ranks(np.asarray(a, float)), _ranks(np.asarray(b, float))
    return float(np.corrcoef(ra, rb)[0, 1])


def _truth(root):
    seq = json.loads((root / "recording.json").read_text())["sequence"]
    gt = root / "synth_gt" / seq
    with np.load(gt / "device.npz") as d:
        dev = {k: d[k] for k in d}
    with np.load(gt / "instances.npz") as d:
        inst = {k: d[k] for k in d}
    return seq, dev, inst, json.loads((gt / "scene.json").read_text())


@pytest.mark.slow
def test_sharpness_falls_with_the_heads_turn_rate(device_rec):
    seq, dev, _, _ = _truth(device_rec)
    frames = sorted((device_rec / seq / "pv").glob("*.png"))
    sharp = [cv2.Laplacian(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE), cv2.CV_64F).var() for f in frames]
    rate = dev["pv_exposure_turn_dps"]
    assert rate.max() > 200 and (rate < 5).sum() > 20   # still and fast frames both present
    assert spearman(sharp, rate) <= -0.3


@pytest.mark.slow
def test_lookalikes_share_their_mesh_and_differ_in_their_pixels(device_rec):
    seq, _, inst, meta = _truth(device_rec)
    objs = meta["objects"]
    first = next(j for j, o in enumerate(objs) if o["twin"] > j)
    twin = objs[first]["twin"]
    assert objs[twin]["lookalike"] == "sticker" and objs[first]["size"] == objs[twin]["size"]
    a = sorted((device_rec / "mvpe" / seq / objs[first]["name"]).glob("*.jpg"))
    b = sorted((device_rec / "mvpe" / seq / objs[twin]["name"]).glob("*.jpg"))
    assert len(a) == len(b) == 25
    # The scene itself: the same mesh arrays, prints that differ in a small region only.
    from egograph.synth.device import make_device_scene

    cfg = load_config(SynthConfig, DEVICE_TINY, ["frames=150"])
    rngs = dict(zip(STREAMS, (np.random.default_rng(s) for s in np.random.SeedSequence(SEED).spawn(len(STREAMS)))))
    scene = make_device_scene(rngs["scene"], rngs["look"], cfg, PhotoLibrary())
    o1, o2 = scene.objects[first], scene.objects[twin]
    assert o1.name == objs[first]["name"] and np.array_equal(o1.vertices, o2.vertices) and np.array_equal(o1.uv, o2.uv)
    t1, t2 = scene.layers[o1.layer], scene.layers[o2.layer]
    differ = (np.abs(t1.astype(int) - t2.astype(int)).max(-1) > 8).mean()
    assert 0.002 < differ < 0.06   # a sticker: under 6 % of the texture, not nothing
    # A colour twin: the same design with its hue turned gives another print.
    from dataclasses import replace

    turned = render_design(PhotoLibrary(), replace(o1.design, hue=120.0))
    assert not np.array_equal(turned, t1)
    # Crops of the pair in the PV frames where both are well visible: not equal images.
    vis, boxes = inst["visible"], inst["boxes"]
    both = np.flatnonzero((vis[:, first] > 0.5) & (vis[:, twin] > 0.5))
    if len(both):
        f = sorted((device_rec / seq / "pv").glob("*.png"))[both[0]]
        img = cv2.imread(str(f))
        crops = [cv2.resize(img[int(b[1]):int(b[3]) + 1, int(b[0]):int(b[2]) + 1], (64, 64))
                 for b in (boxes[both[0], first], boxes[both[0], twin])]
        assert not np.array_equal(crops[0], crops[1])


@pytest.mark.slow
def test_the_hand_covers_part_of_the_carried_object_and_comes_and_goes(device_rec):
    _, dev, inst, meta = _truth(device_rec)
    assert meta["moves"], "the test recording must hold a carry"
    for mv in meta["moves"]:
        j, a, b = mv["instance"], mv["pick_frame"], mv["place_frame"]
        carry = np.arange(a, b + 1)
        seen = carry[np.isfinite(inst["boxes"][carry, j, 0])]
        cover = dev["hand_cover"][seen, j]
        assert len(seen) >= 10
        assert (cover > 0.02).mean() >= 0.5          # the hand is over it on most carry frames it is seen
        assert np.median(cover[cover > 0]) < 0.9      # partly: the object still shows
        # The hand reaches in before the pick-up and withdraws after the put-down.
        assert dev["hand_on"][a - 5] and dev["hand_instance"][a - 5] == j
        assert dev["hand_on"][b + 5]
        assert not dev["hand_on"][a - 40:a - 30].any()


def test_auto_exposure_lags_and_caps():
    cfg = PvCameraConfig()
    ae = AutoExposure(cfg, 30.0)
    bright = ae.exposure(0.5)
    assert bright.gain == 1.0 and np.isclose(bright.seconds * 0.5 * cfg.sensitivity, cfg.ae_target)
    # Into a dark room: a frame later the exposure has moved only part of the way.
    nxt = ae.exposure(0.02)
    assert bright.seconds < nxt.seconds * nxt.gain < 0.5 * cfg.ae_target / 0.02 / cfg.sensitivity
    for _ in range(90):  # three seconds later: settled, or capped at 33 ms and the largest gain
        last = ae.exposure(0.002)
    assert last.seconds == pytest.approx(cfg.exposure_ms[1] / 1000) and last.gain == cfg.max_gain


def test_noise_grows_with_the_gain_and_blur_follows_the_motion():
    cfg = PvCameraConfig(jpeg_quality=0, denoise_sigma=0.0, vignetting=0.0)
    flat = np.full((64, 64, 3), 0.2, np.float32)
    low = develop(flat, Exposure(0.02, 1.0, 0.2), cfg, np.random.default_rng(1))
    high = develop(flat / 8, Exposure(0.02, 8.0, 0.025), cfg, np.random.default_rng(1))
    assert abs(float(low.mean()) - float(high.mean())) < 3          # the same brightness
    assert high.astype(float).std() > 2.0 * low.astype(float).std()  # more noise at gain 8
    # A camera turning about its vertical axis: image motion along x, more for a longer exposure.
    k = np.array([[1000.0, 0, 640], [0, 1000.0, 360], [0, 0, 1]])
    pose = np.eye(4)
    turn = np.eye(4)
    a = np.radians(1.0)
    turn[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    flow = image_motion(np.full((720, 1280), 2.0, np.float32), k, pose, pose, turn)
    # at the image centre a turn by a moves the image by f tan(a); rows hardly move
    assert abs(abs(flow[360, 640, 0]) - 1000 * np.tan(a)) < 0.3 and np.abs(flow[300:420, :, 1]).max() < 1.0


def test_device_recordings_are_deterministic(tmp_path):
    cfg = load_config(SynthConfig, DEVICE_TINY, ["frames=6", "mvpe_photo_size=48"])
    generate(tmp_path / "a", cfg, seed=4, progress=False)
    generate(tmp_path / "b", cfg, seed=4, progress=False)
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert len(files) > 20
    for rel in files:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel
    meta = json.loads((tmp_path / "a" / "recording.json").read_text())
    assert meta["world"] == "device" and "scikit-image" in meta["photo_packages"]


def test_legacy_recordings_carry_no_device_knobs_and_device_needs_gl():
    legacy = load_config(SynthConfig, synth_config("tiny"), [])
    assert "world" not in recorded_config(legacy) and "device" not in recorded_config(legacy)
    assert recorded_config(load_config(SynthConfig, DEVICE_TINY, []))["world"] == "device"
    with pytest.raises(ConfigError, match="pv.renderer must be gl"):
        load_config(SynthConfig, DEVICE_TINY, ["pv.renderer=raycast"])
