"""hl2ss calibration binaries (raw little-endian float32), as IT3DEgo ships them.

``calibrations/rm_depth_ahat/``: uv2xy.bin (H x W x 2), extrinsics.bin (4x4, rig node ->
AHAT camera, row vectors), scale.bin, alias.bin (wrap distance, mm), intrinsics.bin (4x4),
undistort_map.bin (H x W x 2); optionally time_offset.bin (1 value, ms; egograph's addition, see
``AhatCalibration.time_offset_ms``).
``calibrations/personal_video/``: intrinsics.bin (4x4, hl2ss PV form), extrinsics.bin (4x4,
rig node -> PV camera), focal_length.bin (2), principal_point.bin (2), radial_distortion.bin (3),
tangential_distortion.bin (2), projection.bin (4x4 = extrinsics @ intrinsics).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from egograph.core.errors import InputError
from egograph.io.atomic import atomic_write_bytes

AHAT_SHAPE = (512, 512)
PV_SHAPE = (720, 1280)  # rows, columns


@dataclass
class AhatCalibration:
    """AHAT depth camera calibration. Distances in metres unless the name says mm."""

    uv2xy: np.ndarray          # (H, W, 2) float32: ray [x, y, 1] per pixel (camera frame, z forward)
    extrinsics: np.ndarray     # (4, 4) rig node -> AHAT camera (row vectors)
    scale: float               # raw-to-mm scale (1000 in hl2ss)
    alias_mm: float            # range at which readings wrap (1055 mm current firmware, 999 older)
    intrinsics: np.ndarray     # (4, 4) pinhole approximation, hl2ss RM form
    undistort_map: np.ndarray  # (H, W, 2) float32
    # (H, W) bool: pixels that have a ray. None = every pixel (the hl2ss folder format has no flag).
    # uv2xy stays finite everywhere either way, so a consumer that ignores this still runs.
    ray_valid: np.ndarray | None = None
    # Values the geometry layer derives from the rays once per calibration (e.g. its pixel lookup),
    # keyed by what they are; not part of the calibration's value (compare=False).
    derived: dict = field(default_factory=dict, repr=False, compare=False)
    # AHAT capture time minus the time its pose is keyed at, ms: the AHAT frame is registered with the
    # AHAT pose stream interpolated at its key plus this (``time_offset.bin``, written by ``egograph info
    # --refine-calibration``; the release has none: 0).
    time_offset_ms: float = 0.0

    @property
    def alias_m(self) -> float:
        return self.alias_mm / 1000.0

    @property
    def valid_mask(self) -> np.ndarray:
        """(H, W) bool: ``ray_valid``, or all True when the calibration carries no flag."""
        if self.ray_valid is None:
            return np.ones(self.shape, dtype=bool)
        return np.asarray(self.ray_valid, dtype=bool)

    @property
    def shape(self) -> tuple[int, int]:
        return self.uv2xy.shape[:2]


@dataclass
class PvCalibration:
    """PV (RGB) camera calibration in the hl2ss PV convention (camera looks down -z, y up)."""

    intrinsics: np.ndarray            # (4, 4) [[-fx,0,0,0],[0,fy,0,0],[cx,cy,1,0],[0,0,0,1]]
    extrinsics: np.ndarray            # (4, 4) rig node -> PV camera (row vectors)
    focal_length: np.ndarray          # (2,) fx, fy pixels
    principal_point: np.ndarray       # (2,) cx, cy pixels
    radial_distortion: np.ndarray     # (3,)
    tangential_distortion: np.ndarray  # (2,)
    projection: np.ndarray            # (4, 4) extrinsics @ intrinsics
    shape: tuple[int, int] = PV_SHAPE  # image rows, columns


def _read_f32(path: Path, count: int | None) -> np.ndarray:
    if not path.is_file():
        raise InputError(path, "calibration file missing")
    data = np.fromfile(path, dtype="<f4")
    if count is not None and data.size != count:
        raise InputError(path, f"expected {count} float32 values, found {data.size} ({path.stat().st_size} bytes)")
    if not np.isfinite(data).all():
        raise InputError(path, "contains NaN or infinite values")
    return data.astype(np.float64)


def _read_matrix(path: Path) -> np.ndarray:
    return _read_f32(path, 16).reshape(4, 4)


TIME_OFFSET_FILE = "time_offset.bin"
"""Optional file of an ``rm_depth_ahat/`` folder: ``AhatCalibration.time_offset_ms`` (one float32, ms)."""

LUT_NAMES = ("Depth AHaT_lut.bin", "ahat_lut.bin")
"""Names a Microsoft StreamRecorder AHAT ray table may have in an ``rm_depth_ahat/`` folder."""


def read_ahat_calibration(folder: str | Path, shape: tuple[int, int] = AHAT_SHAPE) -> AhatCalibration:
    """An ``rm_depth_ahat/`` folder: hl2ss binaries, or a StreamRecorder ray table in place of uv2xy.bin.

    With ``uv2xy.bin`` the rays come from it and ``ray_valid`` is derived with
    :func:`ahat_ray_validity` (the hl2ss format has no flag). Without it, a StreamRecorder table
    (``Depth AHaT_lut.bin`` or ``ahat_lut.bin``, see :mod:`egograph.io.streamrecorder`) supplies the
    rays and their flag; ``extrinsics.bin``, ``scale.bin`` and ``alias.bin`` are still required
    (StreamRecorder does not write them in this form), ``intrinsics.bin`` and ``undistort_map.bin``
    are derived from the rays when absent (:func:`bounding_pinhole`, :func:`undistort_map_from_rays`).
    """
    folder = Path(folder)
    h, w = shape
    calib = _read_ahat_calibration(folder, h, w)
    for name, value in (("alias.bin", calib.alias_mm), ("scale.bin", calib.scale)):
        if not (np.isfinite(value) and value > 0):
            raise InputError(folder / name, f"must hold a positive number (read {value!r})")
    return calib


def _read_ahat_calibration(folder: Path, h: int, w: int) -> AhatCalibration:
    rays = folder / "uv2xy.bin"
    if rays.is_file():
        uv2xy = _read_f32(rays, h * w * 2).reshape(h, w, 2).astype(np.float32)
        ray_valid = ahat_ray_validity(uv2xy)
    else:
        luts = [folder / name for name in LUT_NAMES if (folder / name).is_file()]
        if not luts:
            tried = ", ".join(str(folder / n) for n in ("uv2xy.bin", *LUT_NAMES))
            raise InputError(folder, f"no AHAT ray table (tried {tried})")
        from egograph.io.streamrecorder import read_lut_rays  # same layer; the module imports this one
        uv2xy, ray_valid = read_lut_rays(luts[0], (h, w))
    intrinsics = _read_matrix(folder / "intrinsics.bin") if (folder / "intrinsics.bin").is_file() or rays.is_file() \
        else bounding_pinhole(uv2xy)
    if (folder / "undistort_map.bin").is_file():
        undistort = _read_f32(folder / "undistort_map.bin", h * w * 2).reshape(h, w, 2).astype(np.float32)
    elif rays.is_file():
        undistort = np.zeros((h, w, 2), np.float32)  # hl2ss folders always have one; nothing reads it
    else:
        undistort = undistort_map_from_rays(uv2xy, ray_valid, intrinsics)
    offset = folder / TIME_OFFSET_FILE
    return AhatCalibration(
        time_offset_ms=float(_read_f32(offset, 1)[0]) if offset.is_file() else 0.0,
        uv2xy=uv2xy,
        extrinsics=_read_matrix(folder / "extrinsics.bin"),
        scale=float(_read_f32(folder / "scale.bin", 1)[0]),
        alias_mm=float(_read_f32(folder / "alias.bin", 1)[0]),
        intrinsics=intrinsics,
        undistort_map=undistort,
        ray_valid=ray_valid,
    )


# ---------------------------------------------------------------- derived from the ray table
# Image coordinates below are continuous: pixel (row i, column j) covers [j, j+1) x [i, i+1), its centre is
# (j + 0.5, i + 0.5) -- the point uv2xy[i, j] was sampled at, and the convention of undistort_map.bin.

AHAT_MAX_RAY_ANGLE_DEG = 60.0
"""Largest angle (deg) between a HoloLens 2 AHAT ray and the optical axis. A StreamRecorder table flags
every ray beyond it as missing (z = 0; 53439 of 512x512 pixels of the packaged hl2-b table, all
outside a circle of about 258 px radius); an hl2ss uv2xy.bin holds extrapolated, folded values there."""

RAY_STEP_MAX = 0.04
"""Largest step (z = 1 plane) between the rays of neighbouring valid pixels. Regular steps are 0.004 at
the centre and about 0.016 at 60 deg; the folded corner values of uv2xy.bin jump by 0.07 to 1.0."""


def ahat_ray_validity(uv2xy: np.ndarray, max_angle_deg: float = AHAT_MAX_RAY_ANGLE_DEG) -> np.ndarray:
    """(H, W) bool: pixels whose ray lies within ``max_angle_deg`` of the axis and is part of the
    smooth ray field around the optical centre (4-connected through steps below ``RAY_STEP_MAX``).

    Reproduces a StreamRecorder table's own flag to 0.1 % (the mismatches lie within 0.1 deg of
    60 deg) and removes the folded corner blocks of an hl2ss uv2xy.bin whose values happen to fall
    within 60 deg.
    """
    import cv2  # io already depends on it (PNG depth)

    xy = np.asarray(uv2xy, dtype=np.float64)
    inside = (xy ** 2).sum(-1) <= np.tan(np.radians(max_angle_deg)) ** 2
    step_u = np.linalg.norm(np.diff(xy, axis=1), axis=-1) < RAY_STEP_MAX   # (H, W-1) edge j <-> j+1
    step_v = np.linalg.norm(np.diff(xy, axis=0), axis=-1) < RAY_STEP_MAX   # (H-1, W) edge i <-> i+1
    smooth = inside.copy()
    smooth[:, :-1] &= step_u
    smooth[:, 1:] &= step_u
    smooth[:-1] &= step_v
    smooth[1:] &= step_v
    n, labels = cv2.connectedComponents(smooth.astype(np.uint8), connectivity=4)
    if n <= 1:
        return np.zeros(xy.shape[:2], bool)
    # The lens' field is the largest smooth component. (Not the one holding the most central ray:
    # a table written with zeros where a pixel has no ray has its "most central" rays in a corner.)
    sizes = np.bincount(labels[smooth], minlength=n)
    region = (labels == int(np.argmax(sizes[1:]) + 1)) & smooth
    for _ in range(2):  # pixels at the rim: valid ray, but a neighbour across the rim jumps
        grow = np.zeros_like(region)
        grow[:, 1:] |= region[:, :-1] & step_u
        grow[:, :-1] |= region[:, 1:] & step_u
        grow[1:] |= region[:-1] & step_v
        grow[:-1] |= region[1:] & step_v
        region |= grow & inside
    return region


def bounding_pinhole(uv2xy: np.ndarray) -> np.ndarray:
    """The hl2ss ``intrinsics.bin`` rule (4x4 RM form): the pinhole that maps the bounding box of all
    ``uv2xy`` values (folded corners included) onto pixel indices 0 .. W-1 and 0 .. H-1:
    ``fx = (W - 1) / (x_max - x_min)``, ``cx = -fx · x_min`` (and y alike).

    Reproduces the packaged hl2-a ``intrinsics.bin`` to 0.01 px. It is a viewing pinhole for the
    undistorted image, not the lens' focal length (about 254 px at the centre of the real AHAT).
    """
    xy = np.asarray(uv2xy, dtype=np.float64)
    h, w = xy.shape[:2]
    lo, hi = xy.reshape(-1, 2).min(0), xy.reshape(-1, 2).max(0)
    f = (np.array([w, h]) - 1.0) / (hi - lo)
    k = np.eye(4)
    k[0, 0], k[1, 1] = f
    k[2, :2] = -f * lo
    return k


def _bilinear(table: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample (H, W, C) ``table`` at continuous points (N, 2), clamped to the image [0, W] x [0, H]:
    value (N, C) and its derivatives along u and v (N, C), exact for the bilinear interpolant.
    The outer half pixel extrapolates the border cells linearly, so the map stays invertible there."""
    h, w = table.shape[:2]
    s = np.clip(uv - 0.5, -0.5, [w - 0.5, h - 0.5])
    j0 = np.clip(np.floor(s[:, 0]).astype(np.int64), 0, w - 2)
    i0 = np.clip(np.floor(s[:, 1]).astype(np.int64), 0, h - 2)
    tu, tv = (s[:, 0] - j0)[:, None], (s[:, 1] - i0)[:, None]
    a, b = table[i0, j0], table[i0, j0 + 1]
    c, d = table[i0 + 1, j0], table[i0 + 1, j0 + 1]
    value = (1 - tv) * ((1 - tu) * a + tu * b) + tv * ((1 - tu) * c + tu * d)
    du = (1 - tv) * (b - a) + tv * (d - c)
    dv = (1 - tu) * (c - a) + tu * (d - b)
    return value, du, dv


def pixels_to_rays(uv: np.ndarray, uv2xy: np.ndarray) -> np.ndarray:
    """Continuous AHAT image points (..., 2) -> rays (..., 2) on the z = 1 plane (bilinear in uv2xy)."""
    uv = np.asarray(uv, dtype=np.float64)
    value, _, _ = _bilinear(np.asarray(uv2xy, dtype=np.float64), uv.reshape(-1, 2))
    return value.reshape(uv.shape)


def rays_to_pixels(xy: np.ndarray, uv2xy: np.ndarray, valid: np.ndarray | None = None,
                   iterations: int = 12, tol_px: float = 1e-4) -> np.ndarray:
    """Rays on the z = 1 plane (..., 2) -> continuous AHAT image points (..., 2): the inverse of
    :func:`pixels_to_rays`. NaN where the ray has no pixel (outside ``valid``, or not converged).

    Newton's method on the bilinear interpolant of ``uv2xy`` (exact Jacobian per cell), started from
    an equidistant fisheye model (pixel radius ∝ angle) fitted to the valid rays; 4-6 iterations
    bring every valid ray of the real tables below 1e-4 px.
    """
    table = np.asarray(uv2xy, dtype=np.float64)
    h, w = table.shape[:2]
    valid = np.ones((h, w), bool) if valid is None else np.asarray(valid, bool)
    q = np.asarray(xy, dtype=np.float64)
    finite = np.isfinite(q.reshape(-1, 2)).all(1)
    flat = np.where(finite[:, None], q.reshape(-1, 2), 0.0)  # NaN in (a point behind the camera): NaN out
    p = _equidistant_guess(flat, table, valid)
    for _ in range(iterations):
        value, du, dv = _bilinear(table, p)
        r = value - flat
        det = du[:, 0] * dv[:, 1] - dv[:, 0] * du[:, 1]
        det = np.where(np.abs(det) > 1e-12, det, 1e-12)
        step = np.stack([(dv[:, 1] * r[:, 0] - dv[:, 0] * r[:, 1]) / det,
                         (-du[:, 1] * r[:, 0] + du[:, 0] * r[:, 1]) / det], -1)
        step = np.clip(step, -32.0, 32.0)  # a fold or a flat cell must not throw a point far off
        p = np.clip(p - step, 0.0, [float(w), float(h)])
        if np.nanmax(np.abs(step), initial=0.0) < tol_px:
            break
    value, _, _ = _bilinear(table, p)
    err = np.linalg.norm(value - flat, axis=1)
    jj = np.clip(np.floor(p[:, 0]).astype(np.int64), 0, w - 1)
    ii = np.clip(np.floor(p[:, 1]).astype(np.int64), 0, h - 1)
    # a residual of 1e-5 on the z = 1 plane is under 0.003 px anywhere in the table
    ok = (err < 1e-5) & valid[ii, jj] & finite
    p[~ok] = np.nan
    return p.reshape(q.shape)


def equidistant_model(table: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, float]:
    """The equidistant fisheye closest to a ray table: ``pixel = c + f · atan(‖xy‖) · xy / ‖xy‖``,
    with ``c`` (2,) the continuous pixel of the most central ray and ``f`` (px per radian) a
    least-squares fit over the valid pixels."""
    h, w = table.shape[:2]
    rr = np.linalg.norm(table, axis=-1)
    i, j = np.unravel_index(np.argmin(np.where(valid, rr, np.inf)), rr.shape)
    c = np.array([j + 0.5, i + 0.5])
    vv, uu = np.mgrid[0:h, 0:w]
    rpix = np.hypot(uu + 0.5 - c[0], vv + 0.5 - c[1])[valid]
    theta = np.arctan(rr[valid])
    f = float((rpix * theta).sum() / max((theta * theta).sum(), 1e-12))
    return c, f


def _equidistant_guess(xy: np.ndarray, table: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Start points for :func:`rays_to_pixels` from :func:`equidistant_model`."""
    c, f = equidistant_model(table, valid)
    n = np.linalg.norm(xy, axis=1, keepdims=True)
    direction = np.divide(xy, n, out=np.zeros_like(xy), where=n > 0)
    return c + f * np.arctan(n) * direction


def undistort_map_from_rays(uv2xy: np.ndarray, valid: np.ndarray | None, intrinsics: np.ndarray) -> np.ndarray:
    """The hl2ss ``undistort_map.bin`` (H, W, 2) float32 for a ray table: entry [i, j] is the continuous
    raw-image point whose ray is the pinhole ray of pixel index (j, i), ``((j - cx) / fx, (i - cy) / fy)``;
    ``(W - 0.5, H - 0.5)`` where that ray has no pixel. ``cv2.remap(raw, map - 0.5, ...)`` undistorts.

    Matches the packaged hl2-a file to 0.01 px (median) where both have a pixel.
    """
    table = np.asarray(uv2xy, dtype=np.float64)
    h, w = table.shape[:2]
    k = np.asarray(intrinsics, dtype=np.float64)
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([(uu - k[2, 0]) / k[0, 0], (vv - k[2, 1]) / k[1, 1]], -1)
    out = np.full((h, w, 2), [w - 0.5, h - 0.5])
    # no valid ray lies farther out than the widest one: skip those pinhole pixels (half of them)
    reach = np.linalg.norm(table[valid], axis=-1).max() if valid is not None else np.inf
    near = np.linalg.norm(rays, axis=-1) <= reach * 1.001
    found = rays_to_pixels(rays[near], table, valid)
    ok = np.isfinite(found).all(-1)
    sub = out[near]
    sub[ok] = found[ok]
    out[near] = sub
    return out.astype(np.float32)


def read_pv_calibration(folder: str | Path, shape: tuple[int, int] = PV_SHAPE) -> PvCalibration:
    folder = Path(folder)
    intrinsics = _read_matrix(folder / "intrinsics.bin")
    extrinsics = _read_matrix(folder / "extrinsics.bin")

    def optional(name: str, n: int, default: np.ndarray) -> np.ndarray:
        return _read_f32(folder / name, n) if (folder / name).exists() else default

    return PvCalibration(
        intrinsics=intrinsics,
        extrinsics=extrinsics,
        focal_length=optional("focal_length.bin", 2, np.array([-intrinsics[0, 0], intrinsics[1, 1]])),
        principal_point=optional("principal_point.bin", 2, intrinsics[2, :2].copy()),
        radial_distortion=optional("radial_distortion.bin", 3, np.zeros(3)),
        tangential_distortion=optional("tangential_distortion.bin", 2, np.zeros(2)),
        projection=optional("projection.bin", 16, (extrinsics @ intrinsics).ravel()).reshape(4, 4),
        shape=shape,
    )


def _write_f32(path: Path, values: np.ndarray) -> None:
    atomic_write_bytes(path, np.asarray(values, dtype="<f4").tobytes())


def write_ahat_calibration(folder: str | Path, calib: AhatCalibration) -> None:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    _write_f32(folder / "uv2xy.bin", calib.uv2xy)
    _write_f32(folder / "extrinsics.bin", calib.extrinsics)
    _write_f32(folder / "scale.bin", [calib.scale])
    _write_f32(folder / "alias.bin", [calib.alias_mm])
    _write_f32(folder / "intrinsics.bin", calib.intrinsics)
    _write_f32(folder / "undistort_map.bin", calib.undistort_map)
    if calib.time_offset_ms:  # absent means 0 (the release's folders have none)
        _write_f32(folder / TIME_OFFSET_FILE, [calib.time_offset_ms])


def write_pv_calibration(folder: str | Path, calib: PvCalibration) -> None:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    _write_f32(folder / "intrinsics.bin", calib.intrinsics)
    _write_f32(folder / "extrinsics.bin", calib.extrinsics)
    _write_f32(folder / "focal_length.bin", calib.focal_length)
    _write_f32(folder / "principal_point.bin", calib.principal_point)
    _write_f32(folder / "radial_distortion.bin", calib.radial_distortion)
    _write_f32(folder / "tangential_distortion.bin", calib.tangential_distortion)
    _write_f32(folder / "projection.bin", calib.projection)


def _is_calibration(path: Path) -> bool:
    return (path / "rm_depth_ahat").is_dir()


def _calibration_candidates(base: Path) -> list[Path]:
    """Calibration folders directly in ``base``: ``calibrations/`` itself, and the release's
    per-group folders ``calibrations_<group>/`` beside it or inside it (any case)."""
    out = []
    try:
        children = sorted(c for c in base.iterdir() if c.is_dir())
    except OSError:
        return out
    for c in children:
        name = c.name.lower()
        if name == "calibrations" or name.startswith("calibrations_") or name.startswith("calibration_"):
            if _is_calibration(c):
                out.append(c)
            if name == "calibrations":
                out += [g for g in sorted(c.iterdir()) if g.is_dir() and _is_calibration(g)]
    return out


_GROUP_RANGE = re.compile(r"(\d+)[_-](\d+)$")
_NUMBERS = re.compile(r"\d+")


def _group_covers(folder: Path, numbers: list[int]) -> bool | None:
    """Whether a group folder named ``..._<first>_<last>`` (``calibrations_vid1_17``) covers one of
    the sequence's ``numbers``; None when its name gives no range."""
    m = _GROUP_RANGE.search(folder.name)
    if m is None:
        return None
    lo, hi = int(m.group(1)), int(m.group(2))
    return any(lo <= n <= hi for n in numbers)


@dataclass
class CalibrationChoice:
    """The calibration folders found for a sequence and the one its number names.

    ``candidates``: every folder at the nearest level holding one (see :func:`find_calibration_dir`);
    ``by_number``: the one taken without looking at the data (the only candidate, or the group whose
    range holds the sequence's number), None when that rule names none or several (``why`` says which).
    """

    candidates: list[Path]
    by_number: Path | None
    why: str = ""


def calibration_choice(seq_dir: str | Path) -> CalibrationChoice:
    """Every calibration folder at the nearest level above ``seq_dir`` and the one chosen by the
    sequence's number (:func:`find_calibration_dir` without ``explicit``); InputError naming the
    levels tried when there is none."""
    seq_dir = Path(seq_dir).resolve()
    numbers = [int(n) for n in _NUMBERS.findall(seq_dir.name)]
    tried = []
    for base in [seq_dir, *list(seq_dir.parents)[:3]]:
        tried.append(f"{base}/calibrations*/")
        cands = _calibration_candidates(base)
        if len(cands) == 1:
            return CalibrationChoice(cands, cands[0], "the only calibration folder")
        if cands:
            covering = [c for c in cands if _group_covers(c, numbers)]
            if len(covering) == 1:
                return CalibrationChoice(cands, covering[0], "named for this sequence's number "
                                                             f"({', '.join(map(str, numbers))})")
            names = ", ".join(c.name for c in cands)
            return CalibrationChoice(cands, None, f"{len(cands)} calibration folders in {base} ({names}) and "
                                                  f"{'several' if covering else 'none'} of them named for this "
                                                  f"sequence's number ({', '.join(map(str, numbers)) or 'none in its name'})")
    raise InputError(seq_dir, "no calibration folder (with rm_depth_ahat/ inside) found; tried "
                              + ", ".join(tried) + "; pass --calibration DIR")


def explicit_calibration_dir(explicit: str | Path) -> Path:
    """A calibration folder given on the command line: that folder, or its ``calibrations/`` child;
    InputError naming both when neither holds ``rm_depth_ahat/``."""
    p = Path(explicit)
    for cand in (p, p / "calibrations"):
        if _is_calibration(cand):
            return cand
    raise InputError(p, f"not a calibration folder (tried {p / 'rm_depth_ahat'}, "
                        f"{p / 'calibrations' / 'rm_depth_ahat'})")


def find_calibration_dir(seq_dir: str | Path, explicit: str | Path | None = None) -> Path:
    """The calibration folder (holding ``rm_depth_ahat/`` and ``personal_video/``) of a sequence.

    Given explicitly: that folder, or its ``calibrations/`` child. Otherwise the sequence folder and
    then each parent in turn (up to three levels) are searched for ``calibrations/``, and for the
    release's per-group folders ``calibrations_<group>/`` (beside or inside ``calibrations/``, any
    case). The nearest level with a candidate decides: one candidate is taken; of several, the group
    whose name ends in a range ``<first>_<last>`` (``calibrations_vid1_17``) holding a number of the
    sequence name (``raw_video_03`` -> 3). InputError naming what was tried otherwise. (Which of
    several candidates fits the data best: :mod:`egograph.steps.calibration`.)
    """
    if explicit is not None:
        return explicit_calibration_dir(explicit)
    choice = calibration_choice(seq_dir)
    if choice.by_number is None:
        raise InputError(Path(seq_dir).resolve(), choice.why + "; pass --calibration DIR")
    return choice.by_number
