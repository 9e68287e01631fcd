"""``egograph plot``: the pictures of a run and their HTML page (issue 15 §2)."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from egograph.cli.main import main
from egograph.core.types import PositionInterval
from egograph.eval import plots
from egograph.eval.protocol import GtInterval

TPS = 10_000_000  # ticks per second
CARRY_RGB = (0x98, 0x4E, 0xA3)  # plots._CARRY


def _scene(n: int = 60) -> plots.PlotScene:
    ts = np.arange(n, dtype=np.int64) * (TPS // 30) + 1000
    gt = [GtInterval(0, int(ts[0]), int(ts[29]), (1.0, 0.0, 2.0)), GtInterval(0, int(ts[40]), int(ts[-1]), (3.0, 0.0, 2.0))]
    carries = np.zeros((n, 1), bool)
    carries[30:40, 0] = True
    cam = np.zeros((n, 3))
    cam[:, 0] = np.linspace(0, 2, n)
    return plots.PlotScene("seq", ts, ["cup"], gt, carries=carries, camera=cam,
                           mesh_xz=np.random.default_rng(0).uniform(0, 4, (500, 2)))


def _run(scene: plots.PlotScene) -> plots.TrackerRun:
    n = len(scene.timestamps)
    xyz = np.full((n, 3), np.nan)
    xyz[:35] = (1.0, 0.0, 2.5)   # 0.5 m off the first centre; still there during the carry
    xyz[45:] = (3.0, 0.0, 2.0)   # exact at the second place
    iv = PositionInterval(0, int(scene.timestamps[0]), int(scene.timestamps[34]), (1.0, 0.0, 2.5),
                          [[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.04]], 10, 0.9)
    return plots.TrackerRun("t", {0: xyz}, [iv])


def test_prediction_errors_against_the_covering_interval():
    scene = _scene()
    err = plots.prediction_errors(scene, _run(scene))[0]
    assert np.allclose(err[:30], 0.5)
    assert np.isnan(err[30:45]).all()      # carried (no true interval) or no prediction
    assert np.allclose(err[45:], 0.0)


def test_runs_and_sheet_rows():
    assert plots.runs(np.array([0, 1, 1, 0, 1], bool)) == [(1, 2), (4, 4)]
    assert plots.runs(np.zeros(3, bool)) == []
    scene = _scene()
    rows = plots.sheet_rows(scene)
    assert len(rows) == 1 and rows[0][1] == 0   # the break at frame 29 (the last interval ends at the last frame)
    # -1 s, -0.25 s, +0.25 s, +1 s at 30 fps around frame 29, clipped to the recording
    assert rows[0][2] == [0, 22, 37, 59]


def test_timeline_shows_carries_and_is_deterministic():
    scene = _scene()
    png = plots.plot_timeline(scene, _run(scene))
    assert png == plots.plot_timeline(scene, _run(scene))
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert (img.shape[1], img.shape[0]) == plots.figure_size_px(plots.timeline_height_in(1))
    purple = (img[..., ::-1] == CARRY_RGB).all(axis=2).sum()
    assert purple > 200   # the carry (10 of 60 frames) is drawn
    assert b"Software" not in png and b"matplotlib" not in png


def test_contact_sheet_projects_truth_and_predictions_around_the_break():
    from egograph.geometry.hl2ss import pv_intrinsics_matrix

    scene = _scene()
    n = len(scene.timestamps)
    # camera at the origin looking down world +z (hl2ss PV looks down its -z): the cup is 2 m ahead
    pose = np.diag([-1.0, 1.0, -1.0, 1.0])
    scene.pv = plots.PvFrames(image=lambda i: np.zeros((720, 1280, 3), np.uint8), poses=np.tile(pose, (n, 1, 1)),
                              valid=np.ones(n, bool), intrinsics=pv_intrinsics_matrix(1000, 1000, 640, 360))
    png = plots.plot_contact_sheet(scene, [_run(scene)])
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
    assert (img.shape[1], img.shape[0]) == plots.figure_size_px(plots.sheet_height_in(1))  # one break, one row
    tracker = np.array([0x1B, 0x9E, 0x77])  # Dark2's first colour: the first tracker's marker
    assert (img == tracker).all(axis=2).sum() > 20   # predicted before the carry: frames 0 and 22
    black = (img == 0).all(axis=2)
    tiles = [(a, b) for a, b in plots.runs(black.sum(axis=0) > 50) if b - a > 50]  # not the 1-pixel frame lines
    assert len(tiles) == 4   # four frames around the break
    rows = black[:, tiles[0][0]:tiles[0][1] + 1].sum(axis=1) > (tiles[0][1] - tiles[0][0]) // 2
    top, bottom = np.flatnonzero(rows)[[0, -1]]   # the frames' rows (mostly black)
    white_in_tiles = [int((img[top:bottom + 1, a:b + 1] == 255).all(axis=2).sum()) for a, b in tiles]
    # the true cross (white) while the first interval covers the frame (0, 22), not after it (37, 59) for
    # this break's instance -- the name is drawn in white too
    assert white_in_tiles[0] > 20 and white_in_tiles[1] > 20
    assert white_in_tiles[2] == 0


def test_missing_results_folder_exits_2_naming_it(tmp_path, capsys):
    out = tmp_path / "plots"
    (tmp_path / "rec").mkdir()  # beside the output: an output inside an input is refused first
    assert main(["plot", str(tmp_path / "rec"), str(tmp_path / "no_such_results"), "--out", str(out)]) == 2
    assert "no_such_results" in capsys.readouterr().err
    assert not out.exists()


# --------------------------------------------------------------------------- end to end


def _track(rec: Path, out: Path, tracker: str = "memory") -> Path:
    assert main(["track", str(rec), "--tracker", tracker, "--out", str(out), "--quiet"]) == 0
    return out


def _files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def _check_page(out: Path) -> list[str]:
    """Every PNG decodes at the size its figure was made, the page links each of them."""
    page = (out / "index.html").read_text()
    linked = re.findall(r'<img src="([^"]+)"', page)
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert sorted(set(linked)) == pngs
    for name in pngs:
        img = cv2.imread(str(out / name), cv2.IMREAD_COLOR)
        assert img is not None, name
        assert img.shape[1] == plots.figure_size_px(1)[0], name
    return pngs


@pytest.mark.slow
def test_plot_tiny_recording(tiny_rec, tmp_path):
    res = _track(tiny_rec, tmp_path / "mem")
    out = tmp_path / "plots"
    args = ["plot", str(tiny_rec), str(res), "--detections", "svoe", "--out", str(out)]
    with pytest.warns(UserWarning, match="no PV images"):
        assert main(args) == 0
    pngs = _check_page(out)
    # no PV images: no contact sheet; memory's scores (its last detection's) make a curve over confidence
    assert pngs == ["curves.png", "map_mem.png", "metrics.png", "timeline_mem.png"]
    heights = {n: cv2.imread(str(out / n)).shape[0] for n in pngs}
    assert heights["metrics.png"] == plots.figure_size_px(plots.METRICS_HEIGHT_IN)[1]
    assert heights["curves.png"] == plots.figure_size_px(plots.CURVES_HEIGHT_IN)[1]
    assert heights["map_mem.png"] == plots.figure_size_px(plots.MAP_HEIGHT_IN)[1]
    assert heights["timeline_mem.png"] == plots.figure_size_px(plots.timeline_height_in(5))[1]  # 5 instances
    timeline = cv2.imread(str(out / "timeline_mem.png"))[..., ::-1]
    assert (timeline == CARRY_RGB).all(axis=2).sum() > 500   # can_1 is carried for 85 of 240 frames
    page = (out / "index.html").read_text()
    assert "<table>" in page and "P@0.25" in page and "<td>mem</td>" in page and "AP@0.25" in page
    first = _files(out)
    with pytest.warns(UserWarning):
        assert main(args) == 0
    assert _files(out) == first   # same inputs, same bytes
    assert not list(tmp_path.glob(".plots*"))   # no temporary left beside it


@pytest.mark.slow
def test_plot_rgb_recording_contact_sheet(tiny_rgb_rec, tmp_path):
    a = _track(tiny_rgb_rec, tmp_path / "mem")
    b = _track(tiny_rgb_rec, tmp_path / "kf", "kf")
    out = tmp_path / "plots"
    assert main(["plot", str(tiny_rgb_rec), str(a), str(b), "--names", "memory,kf", "--out", str(out)]) == 0
    pngs = _check_page(out)
    assert pngs == ["curves.png", "map_kf.png", "map_memory.png", "metrics.png", "pv_sheet.png", "timeline_kf.png",
                    "timeline_memory.png"]
    sheet = cv2.imread(str(out / "pv_sheet.png"))
    assert sheet.shape[0] == plots.figure_size_px(plots.sheet_height_in(1))[1]   # 30 frames: no break, one row
    assert main(["plot", str(tiny_rgb_rec), str(a), str(b), "--names", "x,x", "--out", str(out)]) == 2
