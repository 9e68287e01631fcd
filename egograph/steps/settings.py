"""The pipeline's typed configuration (``configs/default.yaml``), one section per stage.

Each stage declares its own knobs, with their documentation and allowed values, in a config module
of its layer that imports no heavy dependency: ``IoConfig`` in ``egograph/io/config.py``,
``LiftConfig`` in ``egograph/geometry/config.py``, ``RefineConfig`` in ``egograph/poses/config.py``,
the trackers' in ``egograph/track/config.py``; this module only assembles them.
``egograph <cmd> --show-config`` lists every knob.
"""

from __future__ import annotations

from dataclasses import dataclass

from egograph.core.config import Checked, section
from egograph.frontend.config import AdaptConfig, FrontendConfig
from egograph.geometry.config import CalibFitConfig, LiftConfig
from egograph.io.config import IoConfig
from egograph.poses.config import RefineConfig
from egograph.track.config import BaselineConfig, GraphConfig, JointConfig, RegtConfig


@dataclass
class EgographConfig(Checked):
    io: IoConfig = section(IoConfig, "reading recordings")
    lift: LiftConfig = section(LiftConfig, "2D detections -> 3D observations")
    calib_fit: CalibFitConfig = section(CalibFitConfig, "how well a calibration registers AHAT depth with the PV "
                                                        "frames; choosing the calibration folder with it")
    track: BaselineConfig = section(BaselineConfig, "the paper's baseline trackers (memory, kf)")
    graph: GraphConfig = section(GraphConfig, "the factor-graph tracker (graph, graph-causal), regt and smooth")
    regt: RegtConfig = section(RegtConfig, "ground-truth re-estimation audit")
    refine: RefineConfig = section(RefineConfig, "pose-graph refinement of the HoloLens poses (egograph refine; "
                                                 "also the pose factors of --joint-poses)")
    joint: JointConfig = section(JointConfig, "joint mode: poses and still-object landmarks in one graph (--joint-poses)")
    frontend: FrontendConfig = section(FrontendConfig, "the appearance front-end: proposals, ONNX encoder, "
                                                       "enrollment matching (egograph detect)")
    adapt: AdaptConfig = section(AdaptConfig, "the tracker teaches the front-end: a per-recording appearance head "
                                              "from the graph's confident stands (egograph detect --adapt)")
