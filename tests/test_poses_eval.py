"""Pose evaluation (ATE/RPE), TUM files, ``egograph eval-poses``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from egograph.cli import main
from egograph.core.errors import InputError
from egograph.geometry.hl2ss import rigid_from_rt
from egograph.poses.evaluate import evaluate_trajectory, match_timestamps, umeyama_se3
from egograph.poses.tum import read_tum, write_tum


def _rot(axis: np.ndarray, deg: float) -> np.ndarray:
    import gtsam

    return gtsam.Rot3.Rodrigues(np.radians(deg) * np.asarray(axis, float) / np.linalg.norm(axis)).matrix()


def _trajectory(n: int = 200, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.normal(0, 0.01, (n, 3)), axis=0)
    rots = [_rot(rng.normal(size=3), rng.uniform(0, 180)) for _ in range(n)]
    return rigid_from_rt(np.array(rots), t)


def test_tum_round_trip(tmp_path):
    poses = _trajectory(50)
    ts = 133_401_100_000_000 + np.arange(50) * 333_333
    write_tum(tmp_path / "a.tum", ts, poses)
    ts2, poses2 = read_tum(tmp_path / "a.tum")
    assert np.array_equal(ts2, ts)
    assert np.abs(poses2 - poses).max() < 1e-12
    # evo's layout: timestamp tx ty tz qx qy qz qw, seconds
    first = (tmp_path / "a.tum").read_text().splitlines()[1].split()
    assert len(first) == 8 and float(first[0]) == pytest.approx(ts[0] / 1e7)
    assert np.allclose([float(v) for v in first[1:4]], poses[0, 3, :3])


def test_tum_bad_line_names_file_and_line(tmp_path):
    p = tmp_path / "bad.tum"
    p.write_text("# header\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n")
    with pytest.raises(InputError, match=r"bad.tum:3"):
        read_tum(p)


def test_ate_identical_is_zero_and_aligned_removes_rigid_offset():
    ref = _trajectory()
    e = evaluate_trajectory(ref, ref)
    assert e.ate_rmse_m == pytest.approx(0, abs=1e-12) and e.rpe_trans_m == pytest.approx(0, abs=1e-12)
    # the whole trajectory moved rigidly: unaligned ATE large, aligned ~0, RPE ~0
    g = rigid_from_rt(_rot([0.3, 1, 0.2], 7.0), np.array([0.5, -0.2, 0.1]))
    moved = ref @ g
    e = evaluate_trajectory(moved, ref)
    assert e.ate_rmse_m > 0.1
    assert e.ate_rmse_aligned_m < 1e-9
    assert e.rpe_trans_m < 1e-9 and e.rpe_rot_deg < 1e-5


def test_umeyama_recovers_transform():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(100, 3))
    r = _rot([1, 2, 3], 40)
    r_est, t_est = umeyama_se3(src, src @ r.T + [1, 2, 3])
    assert np.allclose(r_est, r) and np.allclose(t_est, [1, 2, 3])


def test_rpe_counts_a_single_step():
    ref = _trajectory(100)
    est = ref.copy()
    est[50:, 3, :3] += [0.03, 0, 0]   # a 3 cm jump that persists
    e = evaluate_trajectory(est, ref)
    assert e.rpe_trans_m == pytest.approx(0.03 / np.sqrt(99), rel=1e-6)
    assert e.ate_rmse_m == pytest.approx(0.03 * np.sqrt(50 / 100), rel=1e-6)


def test_match_timestamps_needs_overlap():
    ts = np.arange(10) * 333_333
    p = np.tile(np.eye(4), (10, 1, 1))
    with pytest.raises(InputError):
        match_timestamps(ts + 10**9, p, ts, p)
    t2, a, b = match_timestamps(ts + 100, p, ts, p)
    assert len(t2) == 10


def test_eval_poses_cli(tiny_rec, tmp_path):
    out = tmp_path / "e.json"
    assert main(["eval-poses", str(tiny_rec), "--json", str(out), "--plot", str(tmp_path / "e.png")]) == 0
    r = json.loads(out.read_text())
    for k in ("ate_rmse_m", "ate_rmse_aligned_m", "rpe_trans_m", "rpe_rot_deg"):
        assert np.isfinite(r[k])
    assert 0 < r["ate_rmse_m"] < 0.2 and r["ate_rmse_aligned_m"] <= r["ate_rmse_m"] + 1e-9
    assert (tmp_path / "e.png").stat().st_size > 1000
    # the truth as a TUM file against synth_gt: zero
    from egograph.io.poses import read_pose_json

    seq = next(p for p in tiny_rec.iterdir() if (p / "pv_pose.json").is_file())
    ts, gt, _ = read_pose_json(tiny_rec / "synth_gt" / seq.name / "pv_pose.json")
    write_tum(tmp_path / "gt.tum", ts, gt)
    assert main(["eval-poses", str(tiny_rec), str(tmp_path / "gt.tum"), "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["ate_rmse_m"] < 1e-6 and r["rpe_rot_deg"] < 1e-4


def test_eval_poses_cli_bad_input(tiny_rec, tmp_path, capsys):
    (tmp_path / "x.tum").write_text("1 2 3\n")
    assert main(["eval-poses", str(tiny_rec), str(tmp_path / "x.tum")]) == 2
    assert "x.tum:1" in capsys.readouterr().err
