"""Configuration of reading recordings (``io.*``)."""

from __future__ import annotations

from dataclasses import dataclass

from egograph.core.config import knob


@dataclass
class IoConfig:
    invalid_poses: str = knob("error", "a NaN/singular pose: 'error' stops with the file and timestamp, 'skip' drops that frame")
    box_format: str = knob("xyxy", "box columns of detection/annotation files: 'xyxy' (x_min y_min x_max y_max) or 'xywh'")
    depth_factor: float = knob(0.0, "raw AHAT unit in mm (4 for the hl2ss version IT3DEgo used, 1 for current hl2ss); 0 = detect from the data")
