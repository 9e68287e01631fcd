"""Lifting 2D detections to 3D: the reference rule on a hand-built case, robust-mode accuracy
on the synthetic recording, bad inputs, determinism, the lifted output format."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from egograph.core.types import Box, Detection
from egograph.geometry import hl2ss as g
from egograph.geometry.config import LiftConfig
from egograph.geometry.lift import lift_recording, write_lifted_dir
from egograph.geometry.prefetch import prefetched
from egograph.geometry.reference_lift import reference_frame_map, reference_setup
from egograph.geometry.robust_lift import alias_shifts, box_reach, nearest_dominant_cluster, shrink_box
from egograph.io.detections import read_detection_dir, read_results_dir
from egograph.io.poses import read_pose_json
from egograph.io.recording import Recording
from egograph.synth.truth import synth_lift_errors


def fresh(path) -> Recording:
    """A Recording of its own (tests below edit poses and patch depth reads)."""
    return Recording.open(path)


def with_true_poses(rec: Recording) -> Recording:
    _, pv, _ = read_pose_json(rec.synth_gt_dir / "pv_pose.json")
    _, depth, _ = read_pose_json(rec.synth_gt_dir / "depth_ahat_pose.json")
    rec.pv_poses[:] = pv
    rec.depth_poses[:] = depth
    return rec


@pytest.fixture(scope="module")
def svoe(tiny_rec):
    rec = Recording.open(tiny_rec)
    return read_detection_dir(rec.detections_dir("svoe"), rec.timestamps)


def true_errors(rec, obs) -> np.ndarray:
    err, true = synth_lift_errors(rec, obs, "svoe")
    return err[true & obs.valid]


# --------------------------------------------------------------------------- reference rule, by hand

F, CX, CY = 100.0, 640.0, 360.0       # fake PV camera: uv = (cx + f x/z, cy + f y/z) in the rig frame
RIG_FROM_AHAT_T = np.array([0.0, 0.0, 1.0])  # AHAT camera sits 1 m behind the rig origin along z


def fake_recording(raw: np.ndarray, uv2xy: np.ndarray, depth_pose: np.ndarray):
    """A Recording-like object: 1 frame, identity PV extrinsics, a pinhole PV 'intrinsics', no mesh."""
    ahat_cam_to_rig = np.eye(4)
    ahat_cam_to_rig[3, :3] = RIG_FROM_AHAT_T
    k = g.rm_intrinsics_matrix(F, F, CX, CY)
    return SimpleNamespace(
        timestamps=np.array([1000], np.int64), index_of=lambda ts: {1000: 0}[int(ts)],
        depth_raw=lambda i: raw, mesh=lambda: None, mesh_scene=lambda: None, annotation_dir=None, depth_factor=4.0,
        depth_poses=depth_pose[None], depth_valid=np.array([True]),
        pv_poses=np.eye(4)[None], pv_valid=np.array([True]),
        ahat=SimpleNamespace(uv2xy=uv2xy, extrinsics=g.invert_rigid(ahat_cam_to_rig), scale=1000.0,
                             alias_mm=1055.0, alias_m=1.055, intrinsics=g.rm_intrinsics_matrix(1, 1, 0, 0)),
        pv=SimpleNamespace(intrinsics=k, extrinsics=np.eye(4), shape=(720, 1280)))


def test_reference_rule_hand_built():
    """Known AHAT pixels land on known PV pixels; the box picks exactly the reference code's pixel."""
    h, w = 3, 4
    # Ray per pixel chosen so that a point at z = 1 m lands (in the rig frame, 1 m further) on target uv.
    targets = {(0, 1): (700.9, 400.2),   # A
               (1, 2): (703.5, 402.7),   # B
               (2, 3): (700.2, 400.8)}   # C: same truncated PV pixel as A, written later -> wins
    uv2xy = np.zeros((h, w, 2), np.float32)   # rays (0, 0, 1) where not set
    raw = np.zeros((h, w), np.uint16)
    for (r, c), (u, v) in targets.items():
        uv2xy[r, c] = ((u - CX) / F * 2.0, (v - CY) / F * 2.0)  # z_rig = z + 1 = 2 for z = 1
    for (r, c) in targets:
        xy1 = np.array([*uv2xy[r, c], 1.0])
        raw[r, c] = np.rint(1.0 * np.linalg.norm(xy1) * 1000.0 / 4.0)  # z ≈ 1 m
    # E lands on PV pixel (640, 360) ... where every raw-0 point (xyz = 0, i.e. the rig's (0, 0, 1)) lands too.
    uv2xy[0, 0] = (0.5 / F * 2.0, 0.5 / F * 2.0)
    raw[0, 0] = np.rint(np.linalg.norm([*uv2xy[0, 0], 1.0]) * 1000.0 / 4.0)
    rot = g.rigid_from_rt(np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]), [0.5, 1.0, 2.0])
    rec = fake_recording(raw, uv2xy, rot)

    def cam(r, c):
        xy1 = np.array([*uv2xy[r, c], 1.0], np.float64)
        return (xy1 * raw[r, c] / (np.linalg.norm(xy1) * 1000.0 / 4.0)).astype(np.float32).astype(np.float64)

    def world(p):
        return g.transform_points(p, g.invert_rigid(rec.ahat.extrinsics) @ rot)

    boxes = {
        0: Box(698, 398, 708, 406),            # crop centre (4, 5) -> PV (402, 703): B exactly
        1: Box(699.7, 399.5, 702.0, 401.9),    # crop rows 399:401, cols 699:702, centre (1, 1) -> (400, 700): C
        2: Box(638.0, 358.0, 642.0, 362.0),    # only E landed here, then raw-0 points overwrote it -> nothing
    }
    dets = {1000: [Detection(k, b, 0.9) for k, b in boxes.items()]}
    obs, rep = lift_recording(rec, dets, LiftConfig(mode="reference", n_candidates=3), progress=False)
    assert len(obs) == 3 and obs.valid.tolist() == [True, True, False]
    np.testing.assert_allclose(obs.world[0], world(cam(1, 2)), atol=1e-9)
    np.testing.assert_allclose(obs.world[1], world(cam(2, 3)), atol=1e-9)
    assert rep.skipped == {"no_depth_pixels": 1} and rep.n_lifted == 2
    # Candidates: r + k·alias along the pixel's ray, k = 0..K-1, chosen 0.
    p = cam(2, 3)
    r = np.linalg.norm(p)
    expect = np.stack([world(p * (r + k * 1.055) / r) for k in range(3)])
    np.testing.assert_allclose(obs.candidates[1], expect, atol=1e-9)
    assert obs.chosen.tolist() == [0, 0, -1]
    np.testing.assert_allclose(obs.camera[0], world(np.zeros(3)), atol=1e-12)


def test_reference_first_minimum_wins():
    """Two pixels at the same L1 distance from the crop centre: the first in row-major order."""
    targets = {(0, 0): (700.5, 400.5), (0, 1): (702.5, 400.5)}  # crop centre (0, 1) -> cols 700, 702 tie
    uv2xy = np.zeros((1, 2, 2), np.float32)
    raw = np.zeros((1, 2), np.uint16)
    for (r, c), (u, v) in targets.items():
        uv2xy[r, c] = ((u - CX) / F * 2.0, (v - CY) / F * 2.0)
        raw[r, c] = np.rint(np.linalg.norm([*uv2xy[r, c], 1.0]) * 1000.0 / 4.0)  # z ≈ 1 m
    rec = fake_recording(raw, uv2xy, np.eye(4))
    dets = {1000: [Detection(0, Box(700, 400, 703, 401), 1.0)]}
    obs, _ = lift_recording(rec, dets, LiftConfig(mode="reference"), progress=False)
    xy1 = np.array([*uv2xy[0, 0], 1.0])
    z = raw[0, 0] / (np.linalg.norm(xy1) * 1000.0 / 4.0)
    np.testing.assert_allclose(obs.world[0] - RIG_FROM_AHAT_T, (xy1 * z).astype(np.float32), atol=1e-7)


def test_reference_matches_literal_rule_on_real_frame(tiny_rec, svoe):
    """On a real synthetic frame, the lift equals a literal transcription of the reference code."""
    rec = fresh(tiny_rec)
    ts = next(t for t, d in svoe.items() if len(d) >= 2)
    i = rec.index_of(ts)
    obs, _ = lift_recording(rec, {ts: svoe[ts]}, LiftConfig(mode="reference"), progress=False)
    raw = rec.depth_raw(i)
    xy1 = np.concatenate([rec.ahat.uv2xy, np.ones((512, 512, 1), np.float32)], -1).astype(np.float64)
    xyz = xy1 * (raw / (np.linalg.norm(xy1, axis=-1) * rec.ahat.scale / rec.depth_factor))[..., None]
    xyz = xyz.reshape(-1, 3)
    xyz1 = np.concatenate([xyz, np.ones((len(xyz), 1))], 1)
    m = np.linalg.inv(rec.ahat.extrinsics) @ rec.pv.extrinsics @ rec.pv.intrinsics
    with np.errstate(all="ignore"):
        uv = (xyz1 @ m)[:, :2] / (xyz1 @ m)[:, 2:3]
        u, v = uv[:, 0].astype(int), uv[:, 1].astype(int)
    keep = (u >= 0) & (u < 1280) & (v >= 0) & (v < 720)
    dmap = np.zeros((720, 1280, 3), np.float32)
    dmap[v[keep], u[keep]] = xyz[keep]
    for row, d in enumerate(svoe[ts]):
        x1, y1, x2, y2 = d.box.x_min, d.box.y_min, d.box.x_max, d.box.y_max
        crop = dmap[int(y1):int(y2), int(x1):int(x2)]
        best, pick = None, None
        for a in range(crop.shape[0]):          # the reference code's double loop, literally
            for b in range(crop.shape[1]):
                if crop[a, b, 2] != 0:
                    dist = abs(a - int((y2 - y1) / 2)) + abs(b - int((x2 - x1) / 2))
                    if best is None or dist < best:
                        best, pick = dist, crop[a, b]
        p = np.append(pick.astype(np.float64), 1.0) @ np.linalg.inv(rec.ahat.extrinsics) @ rec.depth_poses[i]
        np.testing.assert_allclose(obs.world[row], p[:3], atol=1e-9)


def notebook_pick(dmap: np.ndarray, line: str):
    """The IT3DEgo notebook's rule, restated from its text for one association line
    ``instance x1 y1 x2 y2 score``: every field through ``int(float(s))``, the box dropped when
    ``int(x1) <= 1 and int(y1) <= 1``, then the crop of the integer corners and the valid pixel
    nearest (L1, first in row-major order) to ``(int((y2-y1)/2), int((x2-x1)/2))``. None: dropped
    or no depth."""
    _, x1, y1, x2, y2 = [int(float(s)) for s in line.split()[:5]]
    if int(x1) <= 1 and int(y1) <= 1:
        return None
    start_x, start_y, stop_x, stop_y = float(x1), float(y1), float(x2), float(y2)
    crop = dmap[int(start_y):int(stop_y), int(start_x):int(stop_x), :]
    ys, xs = crop[..., 2].nonzero()
    if len(xs) == 0:
        return None
    c_y, c_x = int((stop_y - start_y) / 2.0), int((stop_x - start_x) / 2.0)
    k = (np.abs(ys - c_y) + np.abs(xs - c_x)).argmin()
    return crop[ys[k], xs[k]]


def test_reference_matches_notebook_on_fractional_boxes(tiny_rec, svoe):
    """Fractional boxes (SAM's are): the lift picks the notebook's pixel (1e-9 m), drops the boxes
    its border rule drops, and the old rule (the float box's half size) would have picked another
    pixel for some of them, so the test tells the two apart."""
    rec = fresh(tiny_rec)
    ts = next(t for t, d in svoe.items() if len(d) >= 2)
    i = rec.index_of(ts)
    rng = np.random.default_rng(3)
    base = svoe[ts][0].box
    boxes = [Box(base.x_min + a, base.y_min + b, base.x_max + c, base.y_max + d)
             for a, b, c, d in rng.uniform(-6.0, 6.0, size=(200, 4))]
    boxes += [Box(0.4, 1.9, 300.3, 200.7),          # border rule: int(x1) <= 1 and int(y1) <= 1 -> dropped
              Box(1.99, 0.2, 40.0, 30.0),           # dropped too
              Box(1.2, 2.0, 300.6, 200.2),          # int(y1) = 2: kept
              Box(1200.7, 300.2, 1290.9, 380.6)]    # past the right edge: the reference slices, never clips
    dets = [Detection(0, b, 0.7) for b in boxes]
    obs, rep = lift_recording(rec, {ts: dets}, LiftConfig(mode="reference"), progress=False)
    setup = reference_setup(rec)
    dmap = reference_frame_map(setup, rec.depth_raw(i))
    to_world = np.linalg.inv(rec.ahat.extrinsics) @ rec.depth_poses[i]
    differ = 0
    for row, b in enumerate(boxes):
        pick = notebook_pick(dmap, f"0 {b.x_min!r} {b.y_min!r} {b.x_max!r} {b.y_max!r} 0.7")
        if pick is None:
            assert not obs.valid[row]
            continue
        expect = (np.append(pick.astype(np.float64), 1.0) @ to_world)[:3]
        np.testing.assert_allclose(obs.world[row], expect, atol=1e-9)
        # the rule before: centre from the float box's half size, crop from truncated float corners
        crop = dmap[int(b.y_min):int(b.y_max), int(b.x_min):int(b.x_max)]
        ys, xs = crop[..., 2].nonzero()
        k = (np.abs(ys - int((b.y_max - b.y_min) / 2)) + np.abs(xs - int((b.x_max - b.x_min) / 2))).argmin()
        differ += not np.array_equal(crop[ys[k], xs[k]], pick)
    assert rep.skipped.get("reference_border") == 2
    assert not obs.valid[200] and not obs.valid[201] and obs.valid[202]
    assert differ >= 5


# --------------------------------------------------------------------------- robust mode accuracy

@pytest.fixture(scope="module")
def robust_obs(tiny_rec, svoe):
    rec = fresh(tiny_rec)
    return rec, *lift_recording(rec, svoe, LiftConfig(), progress=False)


def test_robust_accuracy_reported_poses(robust_obs):
    """Median 3D error of lifted true detections < 8 cm with the reported (drifting) poses.

    Measured 5.6 cm on the tiny recording (seed 7): the lift itself contributes ~2 cm (next
    test); the rest is the reported poses' drift (4 mm/sqrt(s)) and relocalisation jumps
    (3-8 cm), which the lift cannot see. Nearly every true detection is lifted.
    """
    rec, obs, rep = robust_obs
    _, true = synth_lift_errors(rec, obs, "svoe")
    e = true_errors(rec, obs)
    assert len(e) >= 0.95 * true.sum() > 20
    assert np.median(e) < 0.08
    assert np.percentile(e, 90) < 0.15


@pytest.mark.slow
def test_robust_beats_reference_true_poses(tiny_rec, svoe):
    """With the true poses (lifting error only): robust median < 3 cm and below reference mode's.

    Measured on every third frame with detections: robust 1.8 cm (surface centroid vs object
    centre, AHAT noise), reference 5.3 cm median and 0.6 m mean (one pixel, no push-back,
    and no unwrapping: objects beyond 1.055 m come out about 1 m short).
    """
    rec = with_true_poses(fresh(tiny_rec))
    frames = [t for t, d in svoe.items() if d][::3]
    sub = {t: svoe[t] for t in frames}
    robust, _ = lift_recording(rec, sub, LiftConfig(), progress=False)
    ref, _ = lift_recording(rec, sub, LiftConfig(mode="reference"), progress=False)
    e_rob, e_ref = true_errors(rec, robust), true_errors(rec, ref)
    assert len(e_rob) >= 15
    assert np.median(e_rob) < 0.03
    assert np.median(e_rob) < np.median(e_ref)
    assert e_rob.mean() < 0.2 * e_ref.mean()


def test_robust_observation_fields(robust_obs):
    rec, obs, _ = robust_obs
    ok = obs.valid
    assert (obs.chosen[ok] >= 0).all() and (obs.chosen[~ok] == -1).all()
    # world is the chosen candidate; candidates lie on one ray from the depth camera, an alias apart.
    picked = obs.candidates[np.flatnonzero(ok), obs.chosen[ok]]
    np.testing.assert_allclose(picked, obs.world[ok])
    rng = np.linalg.norm(obs.candidates[ok] - obs.camera[ok][:, None], axis=2)
    np.testing.assert_allclose(rng[np.arange(ok.sum()), obs.chosen[ok]], obs.range_m[ok], rtol=1e-5)
    steps = np.diff(rng, axis=1)
    assert np.allclose(steps[np.isfinite(steps)], rec.ahat.alias_m)
    assert np.nanmax(rng) <= 5.5 + 1e-6 and np.nanmin(rng) > 0.1
    assert (obs.n_pixels[ok] >= 3).all()


# --------------------------------------------------------------------------- bad inputs

def test_bad_inputs_are_counted_and_skipped(tiny_rec, svoe, monkeypatch):
    rec = fresh(tiny_rec)
    frames = [t for t, d in svoe.items() if d][:12]
    clean = {t: svoe[t] for t in frames}
    base, base_rep = lift_recording(rec, clean, LiftConfig(), progress=False)
    assert base_rep.n_skipped == 0

    t_missing, t_nan_depth, t_nan_pv = frames[0], frames[1], frames[2]
    dets = {t: list(d) for t, d in clean.items()}
    t_extra = frames[5]
    dets[t_extra] += [Detection(1, Box(1400, 100, 1500, 200), 0.9),     # entirely right of the image
                      Detection(2, Box(300, 300, 300, 380), 0.9),       # zero width
                      Detection(99, Box(300, 300, 400, 380), 0.9)]      # beyond labels.csv
    dets[int(rec.timestamps[-1]) + 12345] = [Detection(0, Box(10, 10, 50, 50), 0.9)]  # not a frame
    real_depth = rec.depth_raw
    i_missing = rec.index_of(t_missing)
    monkeypatch.setattr(rec, "depth_raw", lambda i: None if i == i_missing else real_depth(i))
    rec.depth_poses[rec.index_of(t_nan_depth)] = np.nan      # depth_valid left True: the lift checks itself
    rec.pv_poses[rec.index_of(t_nan_pv)] = np.nan

    obs, rep = lift_recording(rec, dets, LiftConfig(), progress=False)
    n = {t: len(clean[t]) for t in frames}
    assert rep.skipped == {"no_depth_frame": n[t_missing], "invalid_pose": n[t_nan_depth] + n[t_nan_pv],
                           "box_outside_image": 1, "empty_box": 1, "unknown_instance": 1, "unknown_timestamp": 1}
    assert rep.n_detections == sum(n.values()) + 4
    assert rep.n_lifted == sum(n.values()) - n[t_missing] - n[t_nan_depth] - n[t_nan_pv]
    # Every other detection is lifted exactly as without the bad ones.
    bad = np.isin(base.timestamps, [t_missing, t_nan_depth, t_nan_pv])
    good = obs.valid
    np.testing.assert_array_equal(obs.world[good], base.world[~bad])
    # Bad rows at known frames stay, unlifted; unknown instance / timestamp rows are dropped.
    assert len(obs) == len(base) + 2 and (~obs.valid).sum() == bad.sum() + 2
    assert 99 not in obs.instance.tolist()
    # Rows keep the file order within a frame, unlifted ones included.
    in_extra = obs.timestamps == t_extra
    assert obs.instance[in_extra].tolist() == [d.instance for d in dets[t_extra] if d.instance != 99]
    assert obs.valid[in_extra].tolist() == [True] * len(clean[t_extra]) + [False, False]
    text = rep.summary()
    for reason in rep.skipped:
        assert reason in text
    assert str(t_missing) in text
    # Static registration needs no PV pose: that frame lifts.
    _, rep_static = lift_recording(rec, dets, LiftConfig(registration="static"), progress=False)
    assert rep_static.skipped["invalid_pose"] == n[t_nan_depth]


def test_no_mesh_takes_reading_as_is(tiny_rec, svoe):
    rec = fresh(tiny_rec)
    sub = {t: svoe[t] for t in [t for t, d in svoe.items() if d][:5]}
    obs, rep = lift_recording(rec, sub, LiftConfig(use_mesh=False), progress=False)
    assert any("k = 0" in n for n in rep.notes)
    assert (obs.range_m[obs.valid] < rec.ahat.alias_m + 0.05).all()


# --------------------------------------------------------------------------- determinism, output

@pytest.mark.parametrize("threads", [1, 3])
def test_deterministic(tiny_rec, svoe, robust_obs, threads):
    """Same observations on a second run, whatever the number of depth-decoding threads
    (the default is 2): frames are decoded out of order but lifted in order."""
    rec = fresh(tiny_rec)
    _, obs1, _ = robust_obs
    obs2, _ = lift_recording(rec, svoe, LiftConfig(decode_threads=threads), progress=False)
    for name in obs1.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(obs1, name), getattr(obs2, name), err_msg=name)


def test_prefetched_keeps_order_and_ahead():
    """Loads come back in key order, and never more than ``ahead`` run ahead of the consumer."""
    import threading
    import time

    started, lock = [], threading.Lock()

    def load(k):
        with lock:
            started.append(k)
        time.sleep(0.002 * (k % 3))  # uneven decode times: later keys may finish first
        return k * k

    got = []
    for key, val in prefetched(load, list(range(20)), ahead=4, threads=3):
        with lock:
            assert len(started) <= key + 1 + 4
        got.append((key, val))
    assert got == [(k, k * k) for k in range(20)]


def test_write_lifted_dir(tmp_path, robust_obs):
    rec, obs, _ = robust_obs
    write_lifted_dir(tmp_path / "lifted", obs, rec.timestamps)
    back = read_results_dir(tmp_path / "lifted")
    assert len(back) == len(rec)
    assert sum(len(v) for v in back.values()) == int(obs.valid.sum())
    j = int(np.flatnonzero(obs.valid)[0])
    p = next(p for p in back[int(obs.timestamps[j])] if p.instance == obs.instance[j])
    np.testing.assert_allclose(p.xyz, obs.world[j], atol=1e-6)


# --------------------------------------------------------------------------- helpers

def test_helpers():
    np.testing.assert_allclose(shrink_box(np.array([0.0, 10, 100, 30]), 0.5), [25, 15, 75, 25])
    ranges = np.array([2.0, 0.50, 0.52, 0.51, 0.9, 0.91, 0.92, 0.93, 0.94, 0.95])
    # 0.5x is nearer but holds 3 of 10 < 40 %: the 0.9x cluster wins; at 30 % the near one does.
    assert sorted(nearest_dominant_cluster(ranges, 0.05, 0.4, 2).tolist()) == [4, 5, 6, 7, 8, 9]
    assert sorted(nearest_dominant_cluster(ranges, 0.05, 0.3, 2).tolist()) == [1, 2, 3]
    assert nearest_dominant_cluster(ranges, 0.05, 0.9, 2) is None
    assert alias_shifts(0.5, 1.0, 6, 5.5).tolist() == [0, 1, 2, 3, 4, 5]
    assert alias_shifts(2.5, 1.0, 6, 5.5).tolist() == [-2, -1, 0, 1, 2, 3]
    assert alias_shifts(2.5, 1.0, 2, 5.5).tolist() == [-1, 0]
    # A 200 px wide box at f = 1000 spans 0.2 (tangent units): a 0.45 m object is at most 2.25 m away.
    k = g.pv_intrinsics_matrix(1000.0, 1000.0, 640.0, 360.0)
    assert box_reach(np.array([100.0, 100, 300, 150]), k, 0.45, 5.5) == pytest.approx(2.25)
    assert box_reach(np.array([100.0, 100, 105, 105]), k, 0.45, 5.5) == 5.5
    with pytest.raises(ValueError):
        LiftConfig(mode="nope").check()


@pytest.mark.slow
def test_fisheye_region_bound_loses_no_pixel(tiny_rec, svoe, monkeypatch):
    """With a real (fisheye) AHAT calibration the robust lift bounds each box's AHAT region through
    the ray table instead of searching the whole frame. Brute force over every pixel and alias:
    each reading that registers into the box at a range the lift searches (from REGION_NEAR_M,
    within reach or the reading itself) lies inside the bound."""
    import dataclasses

    from egograph.geometry import lift as lift_module
    from egograph.geometry import robust_lift
    from egograph.io.devices import device_ahat_calibration

    rec = fresh(tiny_rec)
    real = device_ahat_calibration("hl2-a")
    real = dataclasses.replace(real, alias_mm=rec.ahat.alias_mm, scale=rec.ahat.scale, extrinsics=rec.ahat.extrinsics)
    rec = dataclasses.replace(rec, ahat=real)
    sub = dict(list(svoe.items())[::6])
    calls = []
    lift_one = lift_module.robust_box_point

    def spy(ctx, raw, frame, box):
        calls.append((ctx, raw, frame, np.array(box)))
        return lift_one(ctx, raw, frame, box)

    monkeypatch.setattr(lift_module, "robust_box_point", spy)
    obs, rep = lift_recording(rec, sub, LiftConfig(), progress=False)
    assert any("ray table" in n for n in rep.notes) and obs.valid.sum() > 10 and len(calls) > 10
    checked = 0
    for ctx, raw, frame, box in calls:
        reach = robust_lift.box_reach(box, rec.pv.intrinsics, ctx.cfg.max_object_size_m, ctx.cfg.max_range_m)
        r0, r1, c0, c1 = robust_lift._ahat_region(ctx, frame, box, reach)
        raw = raw.astype(np.float64).ravel()
        dirs = ctx.dirs.reshape(-1, 3).astype(np.float64)
        for k in range(robust_lift._alias_count(ctx)):
            r = raw * ctx.m_per_raw + k * ctx.alias_m
            p = np.concatenate([dirs * r[:, None], np.ones((len(r), 1))], 1) @ frame.ahat_to_pvimg
            with np.errstate(all="ignore"):
                u, v = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
            hit = ((raw > 0) & (p[:, 2] < 0) & (u >= box[0]) & (u < box[2]) & (v >= box[1]) & (v < box[3])
                   & (r >= robust_lift.REGION_NEAR_M) & ((r <= reach) | (k == 0)))
            rows, cols = np.divmod(np.flatnonzero(hit), 512)
            checked += len(rows)
            assert ((rows >= r0) & (rows < r1) & (cols >= c0) & (cols < c1)).all(), (box, k)
    assert checked > 1000
