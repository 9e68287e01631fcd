"""``egograph export`` (issue 15 §3, §4): interval centres as PLY, poses as TUM, a rerun recording."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from egograph.cli.main import main
from egograph.core.types import PositionInterval
from egograph.steps.export import intervals_ply_text, two_sigma_ellipsoid

TPS = 10_000_000


def test_ply_of_interval_centres_reads_back_in_open3d(tmp_path):
    import open3d as o3d

    ivs = [PositionInterval(0, 1000, 1000 + 3 * TPS, (1.0, 0.5, -2.0), np.diag([1e-4, 4e-4, 9e-4]).tolist(), 9, 0.8),
           PositionInterval(3, 1000 + 4 * TPS, 1000 + 9 * TPS, (-0.25, 0.0, 3.5), np.eye(3).tolist(), 2, 0.4)]
    path = tmp_path / "iv.ply"
    path.write_text(intervals_ply_text(ivs, t0=1000))
    pc = o3d.io.read_point_cloud(str(path))
    assert np.allclose(np.asarray(pc.points), [iv.xyz for iv in ivs])
    assert pc.has_colors() and not np.allclose(np.asarray(pc.colors)[0], np.asarray(pc.colors)[1])
    body = path.read_text().split("end_header\n")[1].split("\n")
    tok = body[1].split()
    assert int(tok[6]) == 3 and float(tok[7]) == pytest.approx(4.0) and float(tok[8]) == pytest.approx(9.0)
    assert float(tok[9]) == pytest.approx(1.0)   # sigma_m: root of the largest eigenvalue


def test_two_sigma_ellipsoid_is_the_covariance():
    from egograph.poses.tum import matrix_from_quat

    rng = np.random.default_rng(4)
    a = rng.normal(size=(3, 3))
    cov = a @ a.T * 1e-3
    half, q = two_sigma_ellipsoid(cov)
    r = matrix_from_quat(q[None])[0]
    assert np.allclose(r @ np.diag((half / 2) ** 2) @ r.T, cov, atol=1e-12)


@pytest.fixture(scope="module")
def graph_results(tiny_rec, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("export") / "graph"
    assert main(["track", str(tiny_rec), "--tracker", "graph", "--out", str(out), "--quiet"]) == 0
    return out


@pytest.mark.slow
def test_export_writes_ply_and_tum_that_match_the_inputs(tiny_rec, graph_results, tmp_path):
    from egograph.poses.tum import read_tum
    from egograph.track.intervals import read_intervals_json
    from tests.conftest import true_poses

    out = tmp_path / "exp"
    assert main(["export", str(tiny_rec), str(graph_results), "--out", str(out)]) == 0
    ivs, _ = read_intervals_json(graph_results / "intervals.json")
    text = (out / "intervals.ply").read_text()
    rows = [r.split() for r in text.split("end_header\n")[1].splitlines()]
    assert len(rows) == len(ivs) > 0
    assert np.allclose([[float(v) for v in r[:3]] for r in rows], [iv.xyz for iv in ivs])
    ts, pv, _ = true_poses(tiny_rec)
    t_true, p_true = read_tum(out / "pv_true.tum")
    assert np.array_equal(t_true, ts) and np.allclose(p_true, pv, atol=1e-9)
    t_rep, _ = read_tum(out / "pv_reported.tum")
    assert len(t_rep) == len(ts)
    # the same command again leaves the folder as it is
    before = (out / "egograph.json").stat().st_mtime_ns
    assert main(["export", str(tiny_rec), str(graph_results), "--out", str(out)]) == 0
    assert (out / "egograph.json").stat().st_mtime_ns == before


def test_export_names_a_missing_results_folder(tiny_rec, tmp_path, capsys):
    assert main(["export", str(tiny_rec), str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "nope" in err and "not found" in err and not (tmp_path / "o").exists()


@pytest.mark.slow
def test_rrd_loads_back_with_every_part(tiny_rec, graph_results, tmp_path):
    pytest.importorskip("rerun", reason="the viewer extra (rerun-sdk) is installed by tools/env.sh")
    from rerun.chunk import RrdReader

    from egograph.track.intervals import read_intervals_json

    out = tmp_path / "exp"
    assert main(["export", str(tiny_rec), str(graph_results), "--out", str(out), "--rrd", "--key-every", "60"]) == 0
    rows: dict[str, int] = {}
    for ch in RrdReader(str(out / "recording.rrd")).stream():
        rows[str(ch.entity_path)] = rows.get(str(ch.entity_path), 0) + ch.num_rows
    ivs, _ = read_intervals_json(graph_results / "intervals.json")
    assert rows.get("/world/mesh", 0) >= 1
    assert rows.get("/world/camera_path", 0) >= 1
    assert rows.get("/world/camera", 0) == 240          # one pose per PV frame of the tiny recording
    assert rows.get("/world/depth", 0) == 4             # frames 0, 60, 120, 180
    for k in {iv.instance for iv in ivs}:
        n = sum(iv.instance == k for iv in ivs)
        assert rows.get(f"/world/intervals/{k}", 0) == 2 * n  # shown at its start, cleared at its end
