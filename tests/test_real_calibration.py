"""The packaged real HoloLens 2 AHAT calibrations (egograph/data/hl2/): readers, lens facts, undistort
map, pixel <-> camera round trip. Figures measured on the files themselves (see each test)."""

from __future__ import annotations

import configparser
import shutil
from pathlib import Path

import numpy as np
import pytest

from egograph.core.errors import InputError
from egograph.geometry.ahat_model import (
    ahat_model_summary,
    camera_to_pixel,
    field_of_view_deg,
    fit_pinhole,
    max_ray_angle_deg,
    optical_centre,
    pixel_to_camera,
    undistort_map_error_px,
)
from egograph.io.calibration import (
    AhatCalibration,
    bounding_pinhole,
    pixels_to_rays,
    read_ahat_calibration,
)
from egograph.io.devices import DEVICES, device_ahat_calibration, device_data_dir
from egograph.io.streamrecorder import read_lut_rays, read_streamrecorder_lut

ROOT = Path(__file__).resolve().parents[1]
FOLDER_A = device_data_dir() / "hl2-ahat-calibration-a"
LUT_B = device_data_dir() / "hl2-ahat-lut-b" / "ahat_lut.bin"


@pytest.fixture(scope="module")
def calibs() -> dict[str, AhatCalibration]:
    return {name: device_ahat_calibration(name) for name in DEVICES}


def _angle_deg(xy: np.ndarray) -> np.ndarray:
    return np.degrees(np.arctan(np.linalg.norm(np.asarray(xy, dtype=np.float64), axis=-1)))


# ------------------------------------------------------------------ readers

def test_both_formats_give_the_same_calibration_type(calibs):
    for name, c in calibs.items():
        assert type(c) is AhatCalibration, name
        assert c.shape == (512, 512) and c.uv2xy.dtype == np.float32 and np.isfinite(c.uv2xy).all()
        assert c.ray_valid.dtype == bool and c.ray_valid.shape == (512, 512)
        assert c.undistort_map.shape == (512, 512, 2) and c.intrinsics.shape == (4, 4)
    a, b = calibs["hl2-a"], calibs["hl2-b"]
    # hl2-b borrows hl2-a's extrinsics, scale and alias (the table has none)
    assert np.array_equal(a.extrinsics, b.extrinsics) and (a.scale, a.alias_mm) == (b.scale, b.alias_mm) == (1000, 1055)


def test_unknown_device_names_the_choices():
    with pytest.raises(InputError, match=r"'hl2-z'.*hl2-a, hl2-b"):
        device_ahat_calibration("hl2-z")


def test_package_data_ships_with_its_notice():
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / "setup.cfg")
    patterns = [p.strip() for p in cfg["options.package_data"]["egograph"].split(",")]
    pkg = ROOT / "egograph"
    for rel in ("data/hl2/README.md", "data/hl2/hl2-ahat-lut-b/LICENSE",
                "data/hl2/hl2-ahat-calibration-a/uv2xy.bin", "data/hl2/hl2-ahat-lut-b/ahat_lut.bin"):
        assert (pkg / rel).is_file(), rel
        assert any(Path(rel).match(p) for p in patterns), rel
    assert "Apache" in (device_data_dir() / "README.md").read_text()


# ------------------------------------------------------------------ rays

def test_ray_directions(calibs):
    for name, c in calibs.items():
        xy = c.uv2xy.astype(np.float64)
        # the optical axis meets the image within 6 px of its centre (measured 252.9/253.3 and 257.9/252.5)
        assert np.linalg.norm(optical_centre(c) - 256.0) < 6.0, name
        assert _angle_deg(xy[256, 256]) < 1.5, name
        # the stored corner values sit at about +-1.5 on the z = 1 plane ...
        corners = xy[[0, 0, -1, -1], [0, -1, 0, -1]]
        assert np.all((np.abs(corners) > 1.45) & (np.abs(corners) < 1.6)), (name, corners)
        assert np.array_equal(np.sign(corners), [[-1, -1], [1, -1], [-1, 1], [1, 1]])
        # ... but no corner has a ray: they lie beyond 60 deg, where the field folds (hl2-a: the
        # radius along the diagonal jumps from 1.74 back to 2.75 at pixel 32)
        assert not c.ray_valid[[0, 0, -1, -1], [0, -1, 0, -1]].any(), name
        # the middle of each side does, within 2 px of the edge: 58-60 deg off the axis
        for line, ray in ((c.ray_valid[256], xy[256]), (c.ray_valid[:, 256], xy[:, 256])):
            ends = np.flatnonzero(line)[[0, -1]]
            assert ends[0] <= 2 and ends[1] >= 509, (name, ends)
            assert np.all((_angle_deg(ray[ends]) > 57.0) & (_angle_deg(ray[ends]) <= 60.1)), name


def test_pixels_without_ray(calibs):
    a, b = calibs["hl2-a"], calibs["hl2-b"]
    assert int((~b.ray_valid).sum()) == 53439  # z == 0 in the table
    raw = np.fromfile(LUT_B, "<f4").reshape(512, 512, 3)
    gone = raw[..., 2] == 0
    # where the table has no ray its x, y still hold z = 1 plane values (not unit vectors)
    assert np.linalg.norm(raw[gone][:, :2], axis=-1).max() > 2.5
    assert np.array_equal(b.uv2xy[gone], raw[gone][:, :2])
    # the table's flag is "within 60 deg of the axis" up to 0.1 deg
    ang = _angle_deg(b.uv2xy)
    assert ang[b.ray_valid].max() < 60.1 and ang[~b.ray_valid].min() > 59.9
    # hl2-a's derived flag: about as many, 98 % the same pixels as the other headset's
    assert 50000 < int((~a.ray_valid).sum()) < 55000
    assert (a.ray_valid == b.ray_valid).mean() > 0.98
    assert _angle_deg(a.uv2xy)[a.ray_valid].max() <= 60.0 + 1e-6


def test_headsets_differ_by_a_median_0_028(calibs):
    a, b = calibs["hl2-a"], calibs["hl2-b"]
    both = a.ray_valid & b.ray_valid
    d = np.linalg.norm(a.uv2xy.astype(np.float64) - b.uv2xy, axis=-1)
    assert np.median(d[both]) == pytest.approx(0.0284, abs=0.001)  # measured 0.02836
    assert np.median(d) == pytest.approx(0.0315, abs=0.001)         # all pixels, folded corners too


# ------------------------------------------------------------------ lens model

def test_field_of_view(calibs):
    # Measured 118.05/118.11 (hl2-a) and 118.76/118.69 (hl2-b): rays reach 60 deg at the middle of
    # each side; +-1.5 deg covers both headsets. (The 113 deg of the corner values is not a ray.)
    for name, c in calibs.items():
        across, down = field_of_view_deg(c)
        assert across == pytest.approx(118.4, abs=1.5) and down == pytest.approx(118.4, abs=1.5), name
        assert max_ray_angle_deg(c) == pytest.approx(60.0, abs=0.1), name


def test_intrinsics_bin_is_the_bounding_pinhole_not_the_focal(calibs):
    a = calibs["hl2-a"]
    k_file = np.fromfile(FOLDER_A / "intrinsics.bin", "<f4").reshape(4, 4)
    assert np.allclose(k_file[[0, 1, 2, 2], [0, 1, 0, 1]], [114.14, 114.84, 252.61, 256.84], atol=0.01)
    assert np.allclose(bounding_pinhole(a.uv2xy), k_file, atol=0.01)
    # the lens' focal length at the centre: the local pixel step of the rays there
    c = optical_centre(a)
    h = 0.5
    dxdu = (pixels_to_rays(c + [h, 0], a.uv2xy)[0] - pixels_to_rays(c - [h, 0], a.uv2xy)[0]) / (2 * h)
    dydv = (pixels_to_rays(c + [0, h], a.uv2xy)[1] - pixels_to_rays(c - [0, h], a.uv2xy)[1]) / (2 * h)
    fx, fy, _, _ = fit_pinhole(a)
    assert fx == pytest.approx(1 / dxdu, abs=1.0) and fy == pytest.approx(1 / dydv, abs=1.0)
    assert fx == pytest.approx(253.8, abs=1.0) and fy == pytest.approx(254.2, abs=1.0)
    assert fx - k_file[0, 0] > 100  # intrinsics.bin is a wide viewing pinhole
    # a fisheye: the fitted focal falls with the fitted radius
    assert fit_pinhole(a, 128.0)[0] < fx - 10 and fit_pinhole(a, None)[0] < 190


def test_summary_for_info(calibs):
    s = ahat_model_summary(calibs["hl2-a"]).to_dict()
    assert s["fov_across_deg"] == pytest.approx(118.05, abs=0.05)
    assert s["intrinsics_focal_px"] == (114.14, 114.84)
    assert s["pixels_without_ray"] == int((~calibs["hl2-a"].ray_valid).sum())
    assert np.allclose(s["principal_point_px"], optical_centre(calibs["hl2-a"]), atol=0.01)


def test_undistort_map_consistency(calibs):
    a, b = calibs["hl2-a"], calibs["hl2-b"]
    # hl2-a's file: entry [i, j] is the raw point (centre + 0.5) of the pinhole ray of index (j, i);
    # within 58 deg it agrees with the rays to 0.003 px (measured 0.0026) and always has a point
    err, missing = undistort_map_error_px(a)
    assert err < 0.005 and missing == 0
    k = a.intrinsics
    vv, uu = np.mgrid[0:512, 0:512]
    rays = np.stack([(uu - k[2, 0]) / k[0, 0], (vv - k[2, 1]) / k[1, 1]], -1)
    sentinel = np.all(a.undistort_map == 511.5, axis=-1)
    assert sentinel.sum() == 30448 and _angle_deg(rays[sentinel]).min() > 59.9
    # hl2-b's map is computed from its rays with the same rule
    err_b, missing_b = undistort_map_error_px(b)
    assert err_b < 1e-3 and missing_b == 0


# ------------------------------------------------------------------ pixel <-> camera point

def test_pixel_camera_pixel_round_trip(calibs):
    rng = np.random.default_rng(7)
    for name, c in calibs.items():
        v = c.ray_valid
        idx = np.argwhere(v)[rng.choice(int(v.sum()), 20000)]
        uv = idx[:, ::-1] + rng.uniform(0, 1, (20000, 2))
        z = rng.uniform(0.2, 3.0, 20000)
        pts = pixel_to_camera(uv, z, c)
        back = camera_to_pixel(pts, c)
        err = np.linalg.norm(back - uv, axis=1)
        ok = np.isfinite(err)
        # measured: 1e-13 px where it converges; NaN (never a wrong pixel) for 0.1 % at the rim,
        # cells whose bilinear interpolant touches a folded neighbour
        assert err[ok].max() < 1e-6, name
        assert (~ok).mean() < 0.003, name
        interior = v & np.roll(v, 1, 0) & np.roll(v, -1, 0) & np.roll(v, 1, 1) & np.roll(v, -1, 1)
        assert interior[idx[~ok, 0], idx[~ok, 1]].mean() < 0.2 if (~ok).any() else True
    # a point behind the camera or outside the 60 deg cone has no pixel
    out = camera_to_pixel(np.array([[0.0, 0.0, -1.0], [3.0, 0.0, 1.0]]), calibs["hl2-a"])
    assert np.isnan(out).all()


# ------------------------------------------------------------------ the StreamRecorder reader

def test_lut_in_a_calibration_folder(calibs, tmp_path):
    folder = tmp_path / "rm_depth_ahat"
    folder.mkdir()
    shutil.copy(LUT_B, folder / "Depth AHaT_lut.bin")
    for name in ("extrinsics.bin", "scale.bin", "alias.bin"):
        shutil.copy(FOLDER_A / name, folder / name)
    c = read_ahat_calibration(folder)
    b = calibs["hl2-b"]
    assert np.array_equal(c.uv2xy, b.uv2xy) and np.array_equal(c.ray_valid, b.ray_valid)
    assert np.allclose(c.intrinsics, b.intrinsics) and np.array_equal(c.undistort_map, b.undistort_map)
    (folder / "Depth AHaT_lut.bin").unlink()
    with pytest.raises(InputError, match=r"no AHAT ray table.*uv2xy\.bin.*Depth AHaT_lut\.bin"):
        read_ahat_calibration(folder)


def _write(path: Path, values: np.ndarray) -> Path:
    path.write_bytes(np.asarray(values, "<f4").tobytes())
    return path


@pytest.mark.parametrize("damage, message", [
    ("truncated", r"expected 512x512x3 float32 rays \(3145728 bytes\), found 3145724 bytes"),
    ("nan", r"1 pixel\(s\) hold NaN"),
    ("not_unit", r"1 ray\(s\) are not unit length"),
    ("backwards", r"1 ray\(s\) point backwards"),
    ("missing", r"ray table missing"),
])
def test_damaged_lut_names_the_file(tmp_path, damage, message):
    lut = np.fromfile(LUT_B, "<f4").reshape(512, 512, 3).copy()
    path = tmp_path / "Depth AHaT_lut.bin"
    if damage == "truncated":
        _write(path, lut.ravel()[:-1])
    elif damage == "nan":
        lut[256, 256, 0] = np.nan
        _write(path, lut)
    elif damage == "not_unit":
        lut[256, 256] *= 1.1
        _write(path, lut)
    elif damage == "backwards":
        lut[256, 256, 2] = -lut[256, 256, 2]
        _write(path, lut)
    with pytest.raises(InputError, match=message) as info:
        read_lut_rays(path)
    assert str(info.value).startswith(str(path))


def test_lut_reader_checks_what_the_caller_supplies(tmp_path):
    with pytest.raises(InputError, match="extrinsics"):
        read_streamrecorder_lut(LUT_B, np.eye(3))
    with pytest.raises(InputError, match="alias_mm"):
        read_streamrecorder_lut(LUT_B, np.eye(4), alias_mm=0.0)


def test_info_reports_the_lens_and_never_visible_intervals(tiny_rec):
    """`egograph info --json`: the AHAT lens of the recording (the generator renders through hl2-a by
    default: 118 deg across, ~254 px at the centre) and, synthetic, the true intervals never a
    quarter visible, counted against the truth."""
    from egograph.io.recording import Recording
    from egograph.steps.info import summarize
    from egograph.synth.truth import never_visible_intervals

    rec = Recording.open(tiny_rec)
    s = summarize(rec)
    lens = s["ahat"]
    assert abs(lens["fov_across_deg"] - 118.05) < 0.5 and abs(lens["fov_down_deg"] - 118.11) < 0.5
    assert abs(lens["focal_px"][0] - 253.8) < 1.5
    assert lens["pixels_without_ray"] > 40000
    nv = s["intervals_never_visible"]
    assert (nv["count"], nv["total"]) == never_visible_intervals(rec) and 0 <= nv["count"] <= nv["total"] > 0
