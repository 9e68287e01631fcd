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


# ---------------------------------------------------------------- generator revision 4 (issue 14 §3)

def to_plain(cfg):
    from egograph.core.config import to_dict

    return to_dict(cfg)


def _static_scene_distance(root):
    """Distance (metres) from world points to the true static scene of a synthetic recording."""
    import open3d as o3d

    from egograph.core.config import load_config
    from egograph.core.resources import synth_config
    from egograph.synth.config import SynthConfig
    from egograph.synth.generate import STREAMS
    from egograph.synth.scene import make_scene

    meta = json.loads((root / "recording.json").read_text())
    cfg = load_config(SynthConfig, synth_config("tiny"))  # the fixtures' scene config
    assert to_plain(cfg.scene) == meta["config"]["scene"]
    rng = np.random.default_rng(np.random.SeedSequence(meta["seed"]).spawn(len(STREAMS))[STREAMS.index("scene")])
    scene = make_scene(rng, cfg.scene)
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(scene.static_vertices.astype(np.float32)),
                     o3d.core.Tensor(scene.static_triangles.astype(np.uint32)))
    return lambda pts: rc.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy()


def test_ahat_round_trip_through_the_real_calibration(tiny_rec):
    """Depth rendered through hl2-a, lifted back with egograph.geometry and the written calibration
    and true depth poses, lands on the true static scene; the AHAT looks forward and down."""
    from egograph.geometry.hl2ss import ahat_raw_to_camera, ahat_to_world_matrix, transform_points

    rec = Recording.open(tiny_rec)
    meta = json.loads((tiny_rec / "recording.json").read_text())
    assert meta["config"]["ahat"]["device"] == "hl2-a"
    # the real rays: about 114 px focal, 113 deg across
    assert 1.4 < np.abs(rec.ahat.uv2xy[0, 0]).min() < 1.7 and abs(rec.ahat.intrinsics[0, 0] - 114.1) < 1
    _, depth_true, _ = read_pose_json(rec.synth_gt_dir / "depth_ahat_pose.json")
    _, pv_true, _ = read_pose_json(rec.synth_gt_dir / "pv_pose.json")
    distance = _static_scene_distance(tiny_rec)
    alias = rec.ahat.alias_m
    for i in (30, 120, 200):
        raw = rec.depth_raw(i)
        ok = raw > 0
        cam = ahat_raw_to_camera(raw, rec.ahat.uv2xy, rec.ahat.scale, 4.0)[ok]
        unit = cam / np.linalg.norm(cam, axis=1, keepdims=True)
        to_world = ahat_to_world_matrix(rec.ahat.extrinsics, depth_true[i])
        # the reading wraps at the alias distance: the nearest of r + k * alias to the scene
        d = np.stack([distance(transform_points(cam + k * alias * unit, to_world)) for k in range(4)]).min(0)
        assert np.median(d) < 0.01, (i, np.median(d))
        assert (d < 0.03).mean() > 0.8
        # forward-down: the AHAT's optical axis is 10-25 deg below the PV camera's (PV tilt 5 deg)
        ahat_fwd = to_world[2, :3]
        pv_fwd = -pv_true[i][2, :3]
        pv_down = -pv_true[i][1, :3]
        below = np.degrees(np.arcsin(np.clip(ahat_fwd @ pv_down, -1, 1)))
        assert 7 < below < 20 and ahat_fwd @ pv_fwd > 0.9
        assert to_world[0, :3] @ pv_true[i][0, :3] > 0.97  # image x to the right in both


def test_pinhole_ahat_still_reachable(tmp_path):
    from egograph.core.config import load_config
    from egograph.core.resources import synth_config
    from egograph.synth.config import SynthConfig
    from egograph.synth.sensors import make_calibration

    cfg = load_config(SynthConfig, synth_config("tiny"), ["ahat.device=pinhole"])
    hs = make_calibration(cfg.ahat, cfg.pv)
    assert np.allclose(hs.node_to_head, np.eye(4)) and hs.ray_valid.all()
    np.testing.assert_allclose(hs.ahat.uv2xy[256, 256 + 100], [100.5 / 250, 0.5 / 250], atol=1e-6)


def test_put_downs_and_pick_ups_are_watched(tiny_rec):
    """The wearer looks at what the hands do: every true interval that ends with a pick-up or starts
    with a put-down is at least a quarter visible in some frame (revision 3 missed 29 % of all true
    intervals over the benchmark set). Intervals of objects never moved may go unseen in a recording
    this short (8 s); the share over the benchmark set is measured by tools/bench_synth.py."""
    from egograph.synth.truth import never_visible_intervals

    rec = Recording.open(tiny_rec)
    gt = np.load(rec.synth_gt_dir / "instances.npz")
    ivs = json.loads((rec.synth_gt_dir / "intervals.json").read_text())
    n = len(gt["timestamps"])
    seen = [gt["visible"][iv["frame_start"]:iv["frame_end"] + 1, iv["instance"]].max() >= 0.25 for iv in ivs]
    touched = [iv["frame_start"] > 0 or iv["frame_end"] < n - 1 for iv in ivs]
    assert sum(touched) >= 2
    assert all(s for s, t in zip(seen, touched) if t)
    never, total = never_visible_intervals(rec)
    assert (never, total) == (len(ivs) - sum(seen), len(ivs))
    assert never_visible_intervals(tiny_rec) == (never, total)  # a root folder works too


def test_hand_occludes_the_carried_object(parts):
    """While carried, an object in view is partly hidden by the hand (less visible than at rest)."""
    rec, ann, gt = parts
    vis, boxes, moving = gt["visible"], gt["boxes"], gt["moving"]
    inview = np.isfinite(boxes[..., 0]) & (vis > 0)
    carried = vis[moving & inview]
    resting = vis[~moving & inview]
    assert len(carried) > 20
    assert np.median(carried) < 0.9 and np.median(carried) < np.median(resting)


def test_mesh_bakes_first_places_and_has_holes(tiny_rec):
    """The HoloLens mesh holds some instances at their first place (and still after they moved),
    some of the untracked objects, and has holes."""
    import open3d as o3d

    rec = Recording.open(tiny_rec)
    meta = json.loads((rec.synth_gt_dir / "scene.json").read_text())
    mesh = o3d.t.geometry.TriangleMesh.from_legacy(o3d.io.read_triangle_mesh(str(rec.seq_dir / "mesh" / "scene.ply")))
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(mesh)
    dist = lambda p: float(rc.compute_distance(o3d.core.Tensor(np.asarray([p], np.float32))).numpy()[0])  # noqa: E731
    gt = np.load(rec.synth_gt_dir / "instances.npz")
    props = meta["untracked_objects"]
    assert len(props) >= 5 and all(0.05 - 1e-9 <= max(p["size"]) <= 0.3 + 1e-9 for p in props)
    assert any(p["in_mesh"] for p in props) and not all(p["in_mesh"] for p in props)
    # a baked instance's first place is covered by the mesh (its top within a few cm), a moved-to place is not
    top = lambda c, h: np.asarray(c) + [0, h / 2, 0]  # noqa: E731
    sizes = [o["size"] for o in meta["objects"]]
    baked = meta["instances_in_mesh"]
    for j in baked:
        assert dist(top(gt["positions"][0, j], sizes[j][1])) < 0.04
    for m in meta["moves"]:
        if m["instance"] not in baked:
            assert dist(top(m["dst"], sizes[m["instance"]][1])) > 0.02
    # holes: the mesh has boundary edges
    legacy = o3d.io.read_triangle_mesh(str(rec.seq_dir / "mesh" / "scene.ply"))
    assert not legacy.is_watertight()
