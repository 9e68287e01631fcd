"""hl2ss calibration binaries (raw little-endian float32), as IT3DEgo ships them.

``calibrations/rm_depth_ahat/``: uv2xy.bin (H x W x 2), extrinsics.bin (4x4, rig node ->
AHAT camera, row vectors), scale.bin, alias.bin (wrap distance, mm), intrinsics.bin (4x4),
undistort_map.bin (H x W x 2).
``calibrations/personal_video/``: intrinsics.bin (4x4, hl2ss PV form), extrinsics.bin (4x4,
rig node -> PV camera), focal_length.bin (2), principal_point.bin (2), radial_distortion.bin (3),
tangential_distortion.bin (2), projection.bin (4x4 = extrinsics @ intrinsics).
"""

from __future__ import annotations

from dataclasses import dataclass
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

    @property
    def alias_m(self) -> float:
        return self.alias_mm / 1000.0

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


def read_ahat_calibration(folder: str | Path, shape: tuple[int, int] = AHAT_SHAPE) -> AhatCalibration:
    folder = Path(folder)
    h, w = shape
    calib = _read_ahat_calibration(folder, h, w)
    for name, value in (("alias.bin", calib.alias_mm), ("scale.bin", calib.scale)):
        if not (np.isfinite(value) and value > 0):
            raise InputError(folder / name, f"must hold a positive number (read {value!r})")
    return calib


def _read_ahat_calibration(folder: Path, h: int, w: int) -> AhatCalibration:
    return AhatCalibration(
        uv2xy=_read_f32(folder / "uv2xy.bin", h * w * 2).reshape(h, w, 2).astype(np.float32),
        extrinsics=_read_matrix(folder / "extrinsics.bin"),
        scale=float(_read_f32(folder / "scale.bin", 1)[0]),
        alias_mm=float(_read_f32(folder / "alias.bin", 1)[0]),
        intrinsics=_read_matrix(folder / "intrinsics.bin"),
        undistort_map=_read_f32(folder / "undistort_map.bin", h * w * 2).reshape(h, w, 2).astype(np.float32)
        if (folder / "undistort_map.bin").exists() else np.zeros((h, w, 2), np.float32),
    )


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


def find_calibration_dir(seq_dir: str | Path, explicit: str | Path | None = None) -> Path:
    """The ``calibrations`` folder for a sequence: given, or found in/beside/above it.

    The real dataset has one calibration folder per group of recordings, so this looks in
    the sequence folder, then each parent in turn (up to three levels).
    """
    if explicit is not None:
        p = Path(explicit)
        if (p / "rm_depth_ahat").is_dir():
            return p
        if (p / "calibrations" / "rm_depth_ahat").is_dir():
            return p / "calibrations"
        raise InputError(p, "not a calibration folder (no rm_depth_ahat/ inside)")
    seq_dir = Path(seq_dir).resolve()
    for base in [seq_dir, *list(seq_dir.parents)[:3]]:
        cand = base / "calibrations"
        if (cand / "rm_depth_ahat").is_dir():
            return cand
    raise InputError(seq_dir, "no calibrations/ folder found in or above the recording; pass --calibration DIR")
