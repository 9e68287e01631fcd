"""SVOE enrollment views from sharp frames (egograph.frontend.sharp_views, frontend.svoe_sharp_*)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from egograph.core.config import load_config
from egograph.core.resources import default_config
from egograph.core.units import TICKS_PER_SECOND
from egograph.frontend.proposals import iou_matrix
from egograph.frontend.sharp_views import projected_boxes, sharp_views, turn_rate_dps
from egograph.geometry.hl2ss import invert_rigid, pv_intrinsics_matrix, pv_project, transform_points
from egograph.steps.recording import open_recording
from egograph.steps.settings import EgographConfig

FPS = 30


def _yaw(deg: float) -> np.ndarray:
    """A row-vector rotation about the world y axis by ``deg`` degrees (4x4)."""
    a = np.radians(deg)
    m = np.eye(4)
    m[:3, :3] = np.array([[np.cos(a), 0, -np.sin(a)], [0, 1, 0], [np.sin(a), 0, np.cos(a)]])
    return m


def _times(n: int) -> np.ndarray:
    return (np.arange(n) * TICKS_PER_SECOND / FPS).astype(np.int64)


def test_turn_rate_of_a_steady_turn_and_of_a_still_head():
    """A head turning 90 deg/s reads 90 deg/s at every frame (translation does not count); a still one 0."""
    n = 10
    poses = np.stack([_yaw(90.0 * k / FPS) for k in range(n)])
    poses[:, 3, :3] = np.arange(n)[:, None] * np.array([0.05, 0.0, 0.02])   # walking
    assert np.allclose(turn_rate_dps(poses, _times(n)), 90.0, atol=1e-6)
    assert np.allclose(turn_rate_dps(np.tile(np.eye(4), (n, 1, 1)), _times(n)), 0.0, atol=1e-6)
    assert turn_rate_dps(np.eye(4)[None], _times(1)).tolist() == [0.0]


def _fake_rec(poses: np.ndarray, k: np.ndarray) -> SimpleNamespace:
    return SimpleNamespace(pv=SimpleNamespace(intrinsics=k), timestamps=_times(len(poses)), pv_poses=poses,
                           pv_valid=np.ones(len(poses), bool))


def test_projected_boxes_follow_a_still_point_nearest_sharp_frames_first():
    """The box is carried to the nearest frames where the head is slow (not to fast ones, not beyond
    the window, the gap kept between the frames chosen), centred where the point projects plus the
    box's offset from it, its size scaled by the ratio of ranges; a box leaving the image is skipped."""
    k = pv_intrinsics_matrix(1000.0, 1000.0, 640.0, 360.0)
    n = 40
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 3, 2] = -0.02 * np.arange(n)          # the camera walks 2 cm a frame towards the point (-z)
    point = np.array([0.1, 0.05, -3.0])            # world, 3 m in front at frame 0
    rate = np.zeros(n)
    rate[:13] = 200.0                               # a fast turn until frame 12
    rate[16] = 200.0
    uv0, z0 = pv_project(transform_points(point, invert_rigid(poses[10])), k)
    box = (uv0[0] - 20, uv0[1] - 30, uv0[0] + 40, uv0[1] + 50)   # the point off the box's centre
    frames, boxes = projected_boxes(_fake_rec(poses, k), 10, box, point, rate, (720, 1280), n=3, max_dps=30.0,
                                    window_s=0.5, gap_s=0.06)
    # the nearest slow frames: 13 (7-12 are fast), 14 is within 0.06 s of 13, 15, 16 is fast, 17
    assert frames == [13, 15, 17]
    for f, b in zip(frames, boxes):
        uv, z = pv_project(transform_points(point, invert_rigid(poses[f])), k)
        s = z0 / z
        assert (b[2] - b[0], b[3] - b[1]) == pytest.approx((60 * s, 80 * s))
        centre = np.array([(b[0] + b[2]) / 2, (b[1] + b[3]) / 2])
        assert centre == pytest.approx(uv + s * np.array([10.0, 10.0]))
    # the window: no slow frame within 0.09 s of frame 10
    assert projected_boxes(_fake_rec(poses, k), 10, box, point, rate, (720, 1280), 3, 30.0, 0.09, 0.0) == ([], [])
    # a box at the image's edge leaves it as the camera comes closer: skipped
    edge = (1280 - 61, uv0[1] - 30, 1279.0, uv0[1] + 50)
    assert projected_boxes(_fake_rec(poses, k), 10, edge, point, rate, (720, 1280), 3, 30.0, 0.5, 0.06) == ([], [])


@pytest.fixture(scope="module")
def smeared(device_rec):
    """Every (frame, instance, true box) of the device recording where the head turns faster than 30 deg/s
    while the instance stands, at least 95 % visible, its true box at least 500 px (an SVOE box could be
    drawn there), with the recording, its config, the turn rates and the robust lift's context."""
    from egograph.geometry.robust_lift import robust_context

    cfg = load_config(EgographConfig, default_config())
    rec = open_recording(device_rec, cfg)
    rate = turn_rate_dps(rec.pv_poses, rec.timestamps)
    with np.load(rec.synth_gt_dir / "instances.npz") as gt:
        boxes, vis, moving = gt["boxes"], gt["visible"], gt["moving"]
    cases = [(i, j, boxes[i, j]) for i in np.flatnonzero(rate > cfg.frontend.svoe_sharp_dps)
             for j in range(boxes.shape[1])
             if np.isfinite(boxes[i, j, 0]) and vis[i, j] >= 0.95 and not moving[i, j]
             and (boxes[i, j, 2] - boxes[i, j, 0]) * (boxes[i, j, 3] - boxes[i, j, 1]) >= 500]
    return rec, cfg, rate, robust_context(rec, cfg.lift, []), cases, boxes


@pytest.mark.parametrize("source", ["depth", "mesh"])
def test_sharp_views_show_the_instance(smeared, source, monkeypatch):
    """Boxes drawn while the head turns fast, carried to sharp frames by the object point behind them
    (the robust lift; or the scene mesh along the box's ray, the depth images taken away): every view's
    box lies on the instance's true box in its frame (IoU >= 0.4; measured: all >= 0.5, median 0.88),
    from frames where the head turns at most svoe_sharp_dps, within the window."""
    rec, cfg, rate, ctx, cases, boxes = smeared
    if source == "mesh":
        monkeypatch.setattr(rec, "depth_raw", lambda i: None)
    ious, froms = [], set()
    t = np.asarray(rec.timestamps) / TICKS_PER_SECOND
    for i, j, box in cases:
        got = sharp_views(rec, i, box, (720, 1280), cfg.frontend, cfg.lift, rate, ctx)
        froms.add(got.point_from)
        assert len(got.frames) <= cfg.frontend.svoe_sharp_views
        for f, b in zip(got.frames, got.boxes):
            assert rate[f] <= cfg.frontend.svoe_sharp_dps and abs(t[f] - t[i]) <= cfg.frontend.svoe_sharp_window_s
            ious.append(iou_matrix(np.array([b]), boxes[f, j][None])[0, 0] if np.isfinite(boxes[f, j, 0]) else 0.0)
    assert froms == {source}
    assert len(ious) >= 20, len(ious)
    assert min(ious) >= 0.4 and np.median(ious) >= 0.7, (min(ious), np.median(ious))


def test_detect_enrolls_smeared_svoe_boxes_with_views_from_sharp_frames(device_rec):
    """egograph detect's SVOE enrollment on the device recording (every SVOE box drawn during a fast
    turn: 62-544 deg/s): smeared boxes get views from sharp frames and the summary names them; with
    frontend.svoe_sharp_views=0 the box and its augmentations alone."""
    from egograph.steps.detect import DetectReport, enroll_svoe

    class Shapes:   # what enroll_svoe needs of an encoder: one row per crop
        def embed(self, crops):
            return np.array([[c.shape[0], c.shape[1]] for c in crops], float)

    cfg = load_config(EgographConfig, default_config())
    rec = open_recording(device_rec, cfg)
    report = DetectReport()
    views = enroll_svoe(rec, Shapes(), cfg.frontend, report, 5, lift_cfg=cfg.lift)
    off = load_config(EgographConfig, default_config(), ["frontend.svoe_sharp_views=0"])
    plain = enroll_svoe(rec, Shapes(), off.frontend, DetectReport(), 5, lift_cfg=off.lift)
    assert sorted(views) == sorted(plain) == [0, 1, 2, 3, 4]
    assert sorted(report.sharp_views) == [0, 1, 2, 3, 4]     # every box drawn faster than 30 deg/s
    added = {k: len(v[1]) for k, v in report.sharp_views.items()}
    assert sum(1 for n in added.values() if n) >= 3, report.sharp_views
    for k in views:
        assert len(views[k]) == len(plain[k]) + added[k] and len(plain[k]) == 4
    assert "views added from sharp frames (frontend.svoe_sharp_views)" in report.summary()
