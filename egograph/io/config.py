"""Configuration of reading recordings (``io.*``)."""

from __future__ import annotations

from dataclasses import dataclass

from egograph.core.config import Checked, knob
from egograph.io.annotations import BOX_FORMATS
from egograph.io.poses import INVALID_POSE_POLICIES


@dataclass
class IoConfig(Checked):
    invalid_poses: str = knob("skip", "a NaN/singular pose (hl2ss writes all-zero matrices for untracked frames): "
                                      "'skip' drops that frame with a warning and a count (as the IT3DEgo reference "
                                      "code does), 'error' stops with the file and timestamp; io.strict (--strict) "
                                      "makes 'skip' an error too", choices=INVALID_POSE_POLICIES)
    box_format: str = knob("xyxy", "box columns of detection/annotation files: 'xyxy' (x_min y_min x_max y_max) or "
                                   "'xywh'", choices=BOX_FORMATS)
    depth_factor: float = knob(0.0, "raw AHAT unit in mm (4 for the hl2ss version IT3DEgo used, 1 for current hl2ss); "
                                    "0 = detect from the data", min=0.0)
    depth_sync_ms: float = knob(15.0, "AHAT frames and poses are joined to PV frames by nearest timestamp within this "
                                      "many ms (not by equal keys: AHAT runs at 45 Hz, PV at 30 Hz, and the release "
                                      "keys AHAT by its own capture times; the synthetic AHAT lags PV by ~5 ms). Keep "
                                      "it under half the PV period (16.7 ms) so an AHAT frame serves at most one PV "
                                      "frame; 0 = equal keys only", min=0.0)
    strict: bool = knob(False, "refuse input that is missing, unreadable or partly unusable (labels, SVOE/MVPE "
                               "enrollments, frames, poses, depth sync) instead of warning and counting; --strict "
                               "on any command that opens a recording sets it")
    svoe_dir: str = knob("", "folder of the SVOE enrollment tree (<dir>/<seq>/svoe.txt or <dir>/svoe.txt) when "
                             "svoe.txt is neither in the annotation folder nor in a tree found beside the recording; "
                             "'' = search")
    mvpe_dir: str = knob("", "folder of the MVPE photos (<dir>/<instance_name>/*.jpg, as released, or "
                             "<dir>/<seq>/<instance_name>/*.jpg) when not found beside the recording; '' = search")
