"""Issue 18: what a mesh-ICP factor constrains, the no-harm self-check, and the position covariance."""

from __future__ import annotations

import json

import numpy as np
import pytest

from egograph.core.config import load_config
from egograph.core.errors import InputError
from egograph.poses.config import RefineConfig
from egograph.poses.covariance import nees, read_position_covariance, write_position_covariance
from egograph.poses.mesh_icp import holdout_mask, point_to_plane_hessian, project_information
from egograph.poses.selfcheck import blend_poses, blend_weights, decide_segments, segment_bounds


def _planes(normals: list, n: int = 3000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points on planes 1.5 m from the camera along each unit normal, with those normals."""
    rng = np.random.default_rng(seed)
    pts, nrm = [], []
    for m in normals:
        m = np.asarray(m, float)
        u = np.cross(m, [0.3, 0.5, 0.8])
        u /= np.linalg.norm(u)
        w = np.cross(m, u)
        a, b = rng.uniform(-1, 1, (2, n))
        pts.append(1.5 * m + a[:, None] * u + b[:, None] * w)
        nrm.append(np.tile(m, (n, 1)))
    return np.concatenate(pts), np.concatenate(nrm)


@pytest.mark.parametrize("normals, strong", [([[0, 0, 1]], 3), ([[0, 0, 1], [1, 0, 0]], 5),
                                              ([[0, 0, 1], [1, 0, 0], [0, 1, 0]], 6)])
def test_information_eigen_structure_of_plane_views(normals, strong):
    """One plane fixes the distance along its normal and the two tilts (3 DOF); two planes leave only the
    slide along their intersection; three fix all six. The weak directions get ~no information."""
    p, m = _planes(normals)
    h = point_to_plane_hessian(p, m)
    length = float(np.sqrt(np.mean(np.sum(p ** 2, axis=1))))
    hp, ev, ok = project_information(h, length, weak_ratio=0.03)
    assert ok.sum() == strong
    assert np.all(ev[~ok] < 1e-8) and np.all(ev[ok] > 0.03)
    w = np.linalg.eigvalsh(hp)
    assert np.all(w > 0)                                              # positive definite for GTSAM
    assert strong == 6 or w[:6 - strong].max() < 1e-7 * w.max()      # weak ~ 0
    if strong == 3:   # floor n = z: free are rotation about z and translation along x and y
        free = np.linalg.eigh(hp)[1][:, :3]
        proj = free @ free.T
        for axis in (2, 3, 4):
            e = np.eye(6)[axis]
            assert np.linalg.norm(proj @ e - e) < 1e-6
        assert np.linalg.norm(proj @ np.eye(6)[5]) < 1e-6            # the normal is not free


def test_weak_direction_gets_no_information_in_the_graph():
    """A mesh factor 5 cm off along a lone plane and 1 cm off along its normal moves the pose only along
    the normal (with the projected information), where the raw 1e-6-regularised Hessian of a nearly
    planar view would drag it along the plane too."""
    import gtsam

    p, m = _planes([[0, 0, 1]])
    p2, m2 = _planes([[1, 0, 0]], n=60, seed=1)              # 2 % of the points on a second surface
    pts, nrm = np.concatenate([p, p2]), np.concatenate([m, m2])
    h = point_to_plane_hessian(pts, nrm)
    hp, _, ok = project_information(h, 1.5, weak_ratio=0.03)
    assert ok.sum() == 3
    meas = gtsam.Pose3(gtsam.Rot3(), np.array([0.05, 0.0, 0.01]))

    def solve(info):
        g = gtsam.NonlinearFactorGraph()
        g.add(gtsam.PriorFactorPose3(1, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 0.1)))
        g.add(gtsam.PriorFactorPose3(1, meas, gtsam.noiseModel.Gaussian.Information(info * 2 / 0.01 ** 2)))
        v = gtsam.Values()
        v.insert(1, gtsam.Pose3())
        return gtsam.LevenbergMarquardtOptimizer(g, v).optimize().atPose3(1).translation()

    t = solve(hp)
    assert abs(t[2] - 0.01) < 0.001 and abs(t[0]) < 0.001
    assert abs(solve(h + np.eye(6) * 1e-6)[0]) > 0.01        # the unprojected factor slides it


def test_holdout_and_segments():
    assert np.flatnonzero(holdout_mask(10, 4)).tolist() == [2, 6]
    assert not holdout_mask(10, 0).any()
    t = np.arange(0, 25.0, 0.5)                               # 25 s: segments 0-10, 10-25 (the short tail joins)
    assert segment_bounds(t, 10.0) == [(0, 19), (20, 49)]
    cfg = load_config(RefineConfig, None, [])
    frames = np.arange(0, 50, 4)
    before = np.full(len(frames), 0.03 ** 2)
    after = np.where(frames < 20, 0.03 ** 2 + np.linspace(-1e-6, 1e-6, len(frames)),   # no change in segment 1
                     (0.012 + np.linspace(0, 0.002, len(frames))) ** 2)                 # clearly lower in segment 2
    seg = decide_segments(t, frames, before, after, cfg)
    assert [s.poses for s in seg] == ["input", "refined"]
    assert seg[1].residual_input_m == pytest.approx(0.03) and seg[1].residual_refined_m < 0.015
    a = blend_weights(t, seg, 1.0)
    assert np.all(a[:20] == 0) and a[20] == pytest.approx(0.5) and a[21] == 1.0 and np.all(a[21:] == 1)
    few = decide_segments(t, frames[:2], before[:2], after[:2], cfg)
    assert all(s.poses == "input" for s in few) and "fewer than" in few[0].reason


def test_blend_poses_endpoints_and_midway():
    import gtsam

    inp = np.tile(np.eye(4), (3, 1, 1))
    ref = inp.copy()
    c = gtsam.Pose3(gtsam.Rot3.Yaw(0.2), np.array([0.1, 0.0, 0.0])).matrix()
    ref[:] = c
    out = blend_poses(inp, ref, np.array([0.0, 0.5, 1.0]))
    assert np.array_equal(out[0], inp[0]) and np.array_equal(out[2], ref[2])
    half = gtsam.Pose3.Logmap(gtsam.Pose3(out[1]))
    assert np.allclose(half, 0.5 * gtsam.Pose3.Logmap(gtsam.Pose3(c)), atol=1e-12)


def test_covariance_file_round_trip_and_errors(tmp_path):
    ts = np.array([300, 100, 200], dtype=np.int64)
    cov = np.stack([np.eye(3) * 1e-4, np.full((3, 3), np.nan), np.diag([1e-6, 2e-6, 3e-6])])
    p = tmp_path / "pv_position_covariance.json"
    write_position_covariance(p, ts, cov)
    rt, rc = read_position_covariance(p)
    assert rt.tolist() == [100, 200, 300]
    assert np.isnan(rc[0]).all() and np.array_equal(rc[1], cov[2]) and np.array_equal(rc[2], cov[0])
    for bad in ("[1, 2]", '{"x": null}', '{"1": [[1, 2]]}', "{"):
        p.write_text(bad)
        with pytest.raises(InputError):
            read_position_covariance(p)
    e = np.array([[0.01, 0.0, 0.0], [np.nan, 0, 0]])
    assert nees(e, np.stack([np.eye(3) * 1e-4] * 2))[0] == pytest.approx(1.0) and np.isnan(nees(e, cov[:2])[1])


@pytest.mark.slow
def test_no_harm_on_true_poses_and_covariance_written(exact_rec, tmp_path):
    """The true poses given as reported: the self-check finds nothing to improve, so the output is the input
    (ATE and aligned ATE not worse); the covariance is written per frame and reads back."""
    from conftest import true_poses

    from egograph.io.recording import Recording
    from egograph.poses.evaluate import evaluate_trajectory
    from egograph.poses.refine import refine_recording, write_refined

    rec = Recording.open(exact_rec)
    _, gt, _ = true_poses(exact_rec)
    res = refine_recording(rec, load_config(RefineConfig, None, ["icp=false", "mesh=true", "colmap=false"]))
    before, after = evaluate_trajectory(rec.pv_poses, gt), evaluate_trajectory(res.pv_poses, gt)
    assert after.ate_rmse_m <= before.ate_rmse_m + 1e-9
    assert after.ate_rmse_aligned_m <= before.ate_rmse_aligned_m + 1e-9
    assert not res.selfcheck["helped"] and res.selfcheck["segments"]
    assert all(s["poses"] == "input" and s["reason"] for s in res.selfcheck["segments"])
    assert len(res.selfcheck["held_out"]) >= 3
    cov = res.position_cov
    assert cov.shape == (len(rec), 3, 3) and np.isfinite(cov).all()
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    out = write_refined(res, tmp_path / "out", rec, load_config(RefineConfig, None, []))
    ts, back = read_position_covariance(out / "pv_position_covariance.json")
    assert np.array_equal(ts, rec.timestamps) and np.allclose(back, cov, rtol=1e-12, atol=0)
    report = json.loads((out / "report.json").read_text())
    assert report["selfcheck"]["segments"][0]["poses"] == "input"
    assert "Self-check" in (out / "report.md").read_text()
