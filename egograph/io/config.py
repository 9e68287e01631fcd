"""Configuration of reading recordings (``io.*``)."""

from __future__ import annotations

from dataclasses import dataclass

from egograph.core.config import Checked, knob
from egograph.io.annotations import BOX_FORMATS
from egograph.io.poses import INVALID_POSE_POLICIES


@dataclass
class IoConfig(Checked):
    invalid_poses: str = knob("error", "a NaN/singular pose: 'error' stops with the file and timestamp, 'skip' drops "
                                       "that frame", choices=INVALID_POSE_POLICIES)
    box_format: str = knob("xyxy", "box columns of detection/annotation files: 'xyxy' (x_min y_min x_max y_max) or "
                                   "'xywh'", choices=BOX_FORMATS)
    depth_factor: float = knob(0.0, "raw AHAT unit in mm (4 for the hl2ss version IT3DEgo used, 1 for current hl2ss); "
                                    "0 = detect from the data", min=0.0)
