"""The synthetic recording generator: layout, truth consistency, realism properties, determinism."""

import hashlib
import json

import cv2
import numpy as np
import pytest
from conftest import make_recording

from egograph.io.annotations import load_annotations, read_mvpe_photos
from egograph.io.detections import read_detection_dir
from egograph.io.poses import read_pose_json
from egograph.io.recording import Recording
from egograph.poses.metrics import pose_differences


def tree_digest(root):
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        if p.is_file():
            h.update(str(p.relative_to(root)).encode())
            h.update(p.read_bytes())
    return h.hexdigest()


@pytest.mark.slow
def test_same_seed_same_bytes(tmp_path):
    a = make_recording(tmp_path / "a", 11, "frames=12", "pv.rgb=true", "mvpe_photo_size=32")
    b = make_recording(tmp_path / "b", 11, "frames=12", "pv.rgb=true", "mvpe_photo_size=32")
    c = make_recording(tmp_path / "c", 12, "frames=12", "pv.rgb=false", "mvpe_photo_size=32")
    assert tree_digest(a) == tree_digest(b)
    assert tree_digest(a) != tree_digest(c)


@pytest.mark.slow
def test_rgb_frames_written(tiny_rgb_rec):
    rec = Recording.open(tiny_rgb_rec)
    img = rec.rgb(5)
    assert img.shape == (720, 1280, 3)
    # Textured enough for SIFT to find features.
    sift = cv2.SIFT_create()
    kp = sift.detect(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), None)
    assert len(kp) > 300


@pytest.fixture(scope="module")
def parts(tiny_rec):
    rec = Recording.open(tiny_rec)
    ann = load_annotations(rec.annotation_dir)
    gt = np.load(rec.synth_gt_dir / "instances.npz")
    return rec, ann, gt


def test_intervals_match_truth(parts):
    rec, ann, gt = parts
    ts, moving, pos = gt["timestamps"], gt["moving"], gt["positions"]
    assert np.array_equal(ts, rec.timestamps)
    assert len(ann.labels) == moving.shape[1] == 5
    assert moving.any(), "someone moved an object"
    for c in ann.centers:
        a, b = rec.index_of(c.t_start), rec.index_of(c.t_end)
        assert not moving[a:b + 1, c.instance].any()
        np.testing.assert_allclose(pos[a:b + 1, c.instance], np.tile(c.xyz, (b + 1 - a, 1)), atol=1e-9)
    # Every stationary frame is covered by exactly one interval of its instance.
    covered = np.zeros_like(moving, dtype=int)
    for c in ann.centers:
        covered[rec.index_of(c.t_start):rec.index_of(c.t_end) + 1, c.instance] += 1
    assert np.array_equal(covered, (~moving).astype(int))
    assert {(m.instance, m.t_start, m.t_end) for m in ann.motion} == {(c.instance, c.t_start, c.t_end) for c in ann.centers}
    # Location ids count the moves of each instance.
    for i in range(5):
        locs = [c.location_id for c in ann.centers if c.instance == i]
        assert locs == list(range(len(locs)))


def test_box_annotations_and_enrollment(parts):
    rec, ann, gt = parts
    vis, boxes = gt["visible"], gt["boxes"]
    for inst, rows in ann.boxes.items():
        for ts, box in rows:
            i = rec.index_of(ts)
            assert i % 5 == 0 and vis[i, inst] >= 0.25
            assert 0 <= box.x_min < box.x_max <= 1280 and 0 <= box.y_min < box.y_max <= 720
    for e in ann.svoe:
        i = rec.index_of(e.ts)
        assert e.box.area >= 500 and vis[i, e.instance] >= 0.95
        assert not (vis[:i, e.instance] >= 0.95).any() or all(
            np.prod(boxes[j, e.instance, 2:] - boxes[j, e.instance, :2]) < 500 for j in np.flatnonzero(vis[:i, e.instance] >= 0.95))


def test_detections_realism(parts):
    rec, ann, gt = parts
    truth = {}
    for name in ("svoe", "mvpe"):
        dets = read_detection_dir(rec.detections_dir(name), rec.timestamps)
        n = sum(len(v) for v in dets.values())
        rows = [l.split() for l in (rec.synth_gt_dir / f"detections_{name}.txt").read_text().splitlines()
                if l and not l.startswith("#")]
        assert len(rows) == n > 0
        false = np.array([int(r[2]) for r in rows])
        scores = np.array([d.score for v in dets.values() for d in v])
        truth[name] = (false.mean(), n)
        assert scores.min() >= 0.45 and scores.max() <= 1.0
        # One match per instance per frame (top-1), as the reference association writes.
        for v in dets.values():
            ids = [d.instance for d in v]
            assert len(ids) == len(set(ids))
    assert truth["mvpe"][1] > truth["svoe"][1]  # MVPE detects more


def test_sensors_and_poses(parts, tiny_rec):
    rec, ann, gt = parts
    raws = [rec.depth_raw(i) for i in range(0, 240, 40)]
    valid = np.mean([(r > 0).mean() for r in raws])
    assert 0.5 < valid < 0.995  # invalid pixels exist but most return
    assert max(int(r.max()) for r in raws) <= int(1055 / 4) + 1  # wrapped at the alias distance
    _, true_pv, _ = read_pose_json(rec.synth_gt_dir / "pv_pose.json")
    trans, rot = pose_differences(rec.pv_poses, true_pv)
    assert 0.0005 < np.median(trans) < 0.2 and np.median(rot) < 2.0
    _, true_depth, _ = read_pose_json(rec.synth_gt_dir / "depth_ahat_pose.json")
    # AHAT is captured a few ms after PV: its rig pose is near, not equal, to the PV rig pose.
    offs = gt["depth_offset_s"]
    assert 0.002 < np.median(offs) < 0.008
    photos = read_mvpe_photos(tiny_rec / "mvpe" / "tiny_seq")
    assert sorted(photos) == sorted(ann.labels) and all(len(v) == 25 for v in photos.values())
    meta = json.loads((tiny_rec / "recording.json").read_text())
    assert meta["seed"] == 7 and meta["detection_sets"] == ["mvpe", "svoe"]


def test_frontend_scores_overlap_and_degrade():
    """True and false matches overlap around 0.6; occlusion, small size and blur lower recall."""
    from egograph.synth.config import FrontEndConfig
    from egograph.synth.frontend import FrameView, FrontEnd

    cfg = FrontEndConfig(detect_rate=0.6, true_score=[0.66, 0.09], lookalike_score=[0.64, 0.08],
                         clutter_score=[0.56, 0.08])
    fe = FrontEnd(np.random.SeedSequence(0), cfg, np.array([1, 0, -1]), (720, 1280))
    big = np.array([[100, 100, 220, 220], [400, 100, 520, 220], [700, 300, 820, 420]], float)
    clutter = np.full((3, 3, 4), np.nan)
    clutter[:, 0] = [900, 500, 960, 560]
    sources, scores, hits = [], [], {"sharp": 0, "blurred": 0}
    for kind, motion in (("sharp", 0.0), ("blurred", 300.0)):
        for index in range(400):
            view = FrameView(np.array([1.0, 1.0, 1.0]), big, np.full(3, motion), clutter)
            for c in fe.frame(view, index):
                sources.append(c.source)
                scores.append(c.score)
                hits[kind] += c.source == "true"
    src, sc = np.array(sources), np.array(scores)
    assert ((sc > 0.6) & (src != "true")).sum() > 20 and ((sc < 0.6) & (src == "true")).sum() > 20
    assert (src == "twin").sum() > 20  # the look-alike pair confuses the matcher
    assert hits["blurred"] < 0.6 * hits["sharp"]


def test_frontend_common_random_numbers():
    """A knob change alters detections only where that knob matters: without clutter, every
    detection that clutter did not win is unchanged (same box, same score), frame by frame."""
    from egograph.synth.config import FrontEndConfig
    from egograph.synth.frontend import FrameView, FrontEnd

    k, c = 4, 3
    twins = np.array([1, 0, -1, -1])
    base = FrontEndConfig(detect_rate=0.7, clutter_rate=0.5, clutter_score=[0.6, 0.08])
    runs = {}
    for name, cfg in (("base", base), ("no_clutter", FrontEndConfig(**{**vars(base), "clutter_rate": 0.0}))):
        fe = FrontEnd(np.random.SeedSequence([5, 1]), cfg, twins, (720, 1280))
        rng = np.random.default_rng(3)
        out = []
        for index in range(300):
            xy = rng.uniform(100, 600, (k, 2))
            boxes = np.hstack([xy, xy + rng.uniform(60, 160, (k, 2))])
            cxy = rng.uniform(100, 600, (k, c, 2))
            view = FrameView(rng.uniform(0.2, 1.0, k), boxes, rng.uniform(0, 200, k),
                             np.concatenate([cxy, cxy + 80], axis=2))
            out.append({d.instance: d for d in fe.frame(view, index)})
        runs[name] = out
    kept = 0
    for a, b in zip(runs["base"], runs["no_clutter"]):
        assert not any(d.source == "clutter" for d in b.values())
        for i, d in a.items():
            if d.source != "clutter":
                assert i in b and b[i].score == d.score and np.array_equal(b[i].box, d.box)
                kept += 1
    n_clutter = sum(d.source == "clutter" for f in runs["base"] for d in f.values())
    assert kept > 100 and n_clutter > 30


@pytest.mark.slow
def test_redetect_reproduces_and_changes_only_detections(tmp_path):
    from conftest import TINY

    from egograph.core.config import load_config
    from egograph.synth.config import SynthConfig
    from egograph.synth.generate import redetect

    root = make_recording(tmp_path / "r", 5, "frames=40", "pv.rgb=false", "mvpe_photo_size=32")
    before = tree_digest(root)
    det = root / "detections" / "tiny_seq" / "svoe"
    redetect(root, load_config(SynthConfig, TINY))  # same front-end: same detections
    assert tree_digest(det) == tree_digest(make_recording(tmp_path / "s", 5, "frames=40", "pv.rgb=false",
                                                          "mvpe_photo_size=32") / "detections" / "tiny_seq" / "svoe")
    depth_before = tree_digest(root / "tiny_seq")
    n = redetect(root, load_config(SynthConfig, TINY, ["detections.svoe.detect_rate=0.0",
                                                       "detections.svoe.clutter_rate=0.0"]))
    assert n["svoe"] <= sum(1 for _ in det.glob("*.txt"))  # only "other" matches can remain
    assert tree_digest(root / "tiny_seq") == depth_before
    assert tree_digest(root) != before
