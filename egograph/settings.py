"""The pipeline's typed configuration (``configs/default.yaml``), one section per stage.

Each stage declares its own knobs where it is implemented (``LiftConfig`` in
``egograph/geometry/lift.py``, ``BaselineConfig`` in ``egograph/track/baselines.py``, ``GraphConfig`` in
``egograph/track/graph.py``);
this module only assembles them. ``egograph <cmd> --show-config`` lists every knob.
"""

from __future__ import annotations

from dataclasses import dataclass

from egograph.config import knob, section
from egograph.geometry.lift import LiftConfig
from egograph.poses.config import RefineConfig
from egograph.track.baselines import BaselineConfig
from egograph.track.graph import GraphConfig
from egograph.track.joint import JointConfig
from egograph.track.regt import RegtConfig


@dataclass
class IoConfig:
    invalid_poses: str = knob("error", "a NaN/singular pose: 'error' stops with the file and timestamp, 'skip' drops that frame")
    box_format: str = knob("xyxy", "box columns of detection/annotation files: 'xyxy' (x_min y_min x_max y_max) or 'xywh'")
    depth_factor: float = knob(0.0, "raw AHAT unit in mm (4 for the hl2ss version IT3DEgo used, 1 for current hl2ss); 0 = detect from the data")


@dataclass
class EgographConfig:
    io: IoConfig = section(IoConfig, "reading recordings")
    lift: LiftConfig = section(LiftConfig, "2D detections -> 3D observations")
    track: BaselineConfig = section(BaselineConfig, "the paper's baseline trackers (memory, kf)")
    graph: GraphConfig = section(GraphConfig, "the factor-graph tracker (graph, graph-causal), regt and smooth")
    regt: RegtConfig = section(RegtConfig, "ground-truth re-estimation audit")
    refine: RefineConfig = section(RefineConfig, "pose-graph refinement of the HoloLens poses (egograph refine; "
                                                 "also the pose factors of --joint-poses)")
    joint: JointConfig = section(JointConfig, "joint mode: poses and still-object landmarks in one graph (--joint-poses)")
