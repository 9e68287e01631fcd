"""Real HoloLens 2 AHAT calibrations shipped with egograph (package data ``egograph/data/hl2/``).

API::

    from egograph.io.devices import DEVICES, device_ahat_calibration
    DEVICES                              # ("hl2-a", "hl2-b")
    calib = device_ahat_calibration("hl2-a")   # -> egograph.io.calibration.AhatCalibration

* ``"hl2-a"``: the hl2ss calibration folder ``hl2-ahat-calibration-a/`` as
  :func:`egograph.io.calibration.read_ahat_calibration` reads it (uv2xy, extrinsics, intrinsics,
  undistort map, scale 1000, alias 1055 mm).
* ``"hl2-b"``: another headset's StreamRecorder table ``hl2-ahat-lut-b/ahat_lut.bin``. The table has
  rays only, so this calibration borrows **hl2-a's extrinsics, scale (1000) and alias (1055 mm)**;
  its intrinsics are the hl2ss bounding pinhole of its own rays and its undistort map is computed
  from its rays (see :mod:`egograph.io.streamrecorder`).

Both are 512 x 512. ``calib.uv2xy`` (H, W, 2) float32 is finite everywhere; ``calib.ray_valid``
(H, W) bool says which pixels have a ray (``calib.valid_mask`` is the same, all True for a
calibration without a flag). A real sensor reads raw 0 where ``ray_valid`` is False: beyond
60 deg off the axis (about 20 % of the image, the corners outside a circle of ~258 px radius).
For hl2-b it is the table's own flag (53439 pixels without a ray); for hl2-a, whose hl2ss files
hold extrapolated, folded values there, it is derived by
:func:`egograph.io.calibration.ahat_ray_validity`.

Facts (measured, see tests/test_real_calibration.py): 118 deg across and down through the optical
centre (rays up to 60 deg off the axis reach the middle of each image side; the "113 deg" of the
stored corner values is not a ray), focal length about 254 px at the centre falling to about
225 px per radian at 60 deg (equidistant-like fisheye); ``intrinsics.bin``'s fx 114 is the pinhole
that fits the bounding box of all uv2xy values into 512 pixels, not the lens' focal length
(:mod:`egograph.geometry.ahat_model`). The two headsets' rays differ by a median 0.028 on the
z = 1 plane (pixels valid in both).

Each call reads the files again (hl2-b about 1 s: its undistort map is computed); cache the result
if it is needed often.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from egograph.core.errors import InputError
from egograph.io.calibration import AhatCalibration, read_ahat_calibration
from egograph.io.streamrecorder import read_streamrecorder_lut

DEVICES: tuple[str, ...] = ("hl2-a", "hl2-b")
"""Names of the packaged real HoloLens 2 AHAT calibrations."""

DATA_DIR = "data/hl2"
"""Folder of the real HoloLens 2 files inside the ``egograph`` package (with README.md and LICENSE)."""

_FOLDER_A = "hl2-ahat-calibration-a"
_LUT_B = "hl2-ahat-lut-b/ahat_lut.bin"


def device_data_dir() -> Path:
    """The packaged ``data/hl2`` folder on disk (wheels and editable installs are unpacked, never zipped)."""
    return Path(str(resources.files("egograph").joinpath(DATA_DIR)))


def device_ahat_calibration(name: str) -> AhatCalibration:
    """The AHAT calibration of packaged device ``name`` (one of ``DEVICES``); see the module docstring.

    InputError naming ``name`` and the choices for an unknown name, or naming the file when the
    package data is missing or damaged.
    """
    root = device_data_dir()
    if name == "hl2-a":
        return read_ahat_calibration(root / _FOLDER_A)
    if name == "hl2-b":
        a = read_ahat_calibration(root / _FOLDER_A)
        return read_streamrecorder_lut(root / _LUT_B, a.extrinsics, scale=a.scale, alias_mm=a.alias_mm)
    raise InputError(root, f"unknown device {name!r}; choices: {', '.join(DEVICES)}")
