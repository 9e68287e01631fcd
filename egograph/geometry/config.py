"""Configuration of the geometry stage: how 2D detections become 3D observations (``lift.*``).

Kept apart from the lifting code so that reading the configuration imports no heavy module.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from egograph.core.config import Checked, knob

MODES = ("robust", "reference")

REGISTRATIONS = ("posed", "static")

MIN_RANGE_M = 0.1          # AHAT returns closer than this are not physical (the visor)

SUPPORT_GAP_M = 0.35
"""How far a resting object's centre sits at most above the surface holding it (half its height
plus mesh noise), metres: the default of ``lift.max_support_gap_m`` and ``graph.max_support_gap_m``."""


@dataclass
class LiftConfig(Checked):
    """How 2D detections become 3D observations (``egograph lift``)."""

    mode: str = knob("robust", "'robust' (mesh-unwrapped, clustered box depth) or 'reference' "
                               "(the IT3DEgo reference code's single-pixel rule, static rig, no unwrapping)",
                     choices=MODES)
    registration: str = knob("posed", "robust mode's AHAT -> PV registration: 'posed' (per-frame poses, "
                                      "follows head motion between the sensors' capture times) or 'static' (rig "
                                      "extrinsics, as the reference code); reference mode always uses static",
                             choices=REGISTRATIONS)
    shrink: float = knob(0.5, "share of the box width and of its height kept around the box centre, 0-1 "
                              "(the centre of a box is mostly object, its rim mostly background)", gt=0.0, max=1.0)
    cluster_gap_m: float = knob(0.05, "a jump of more than this between sorted pixel ranges starts a new "
                                      "depth cluster, metres", gt=0.0)
    min_cluster_share: float = knob(0.2, "a depth cluster counts as dominant with at least this share of "
                                         "the box's registered pixels, 0-1", min=0.0, max=1.0)
    min_pixels: int = knob(3, "fewest AHAT pixels a dominant cluster needs (a 20 px PV box is ~5x5 AHAT "
                              "pixels at the synthetic 4:1 focal ratio)", min=1)
    surface_to_center_m: float = knob(0.03, "the visible-surface centroid is pushed back along its ray by "
                                            "this typical half-depth of a small object, metres", min=0.0)
    max_range_m: float = knob(5.5, "alias candidates beyond this range from the depth camera are dropped, metres",
                              gt=MIN_RANGE_M)
    max_object_size_m: float = knob(0.45, "largest plausible object extent, metres: robust mode unwraps no pixel "
                                          "to a range at which the box would hold a larger object (extent about "
                                          "box side / focal x range); keeps objects carried near the eye from "
                                          "being unwrapped onto the wall behind them; raise it for large instances",
                                    gt=0.0)
    hand_reach_m: float = knob(0.8, "robust mode: a mesh-unwrapped point beyond this range with no mesh surface "
                                     "within max_support_gap_m below it is taken for a carried object, and the "
                                     "box is lifted again with unwrapping capped here, metres (0 = off)", min=0.0)
    max_support_gap_m: float = knob(SUPPORT_GAP_M, "a resting object's centre is at most this far above the surface "
                                                   "holding it (half its height plus mesh noise), metres; the same "
                                                   "quantity as graph.max_support_gap_m, kept apart because this one "
                                                   "changes the observations (a lift cache key) and that one only "
                                                   "the tracking", min=0.0)
    use_mesh: bool = knob(True, "resolve the AHAT alias per pixel with the recording's HoloLens mesh; "
                                "false (or no mesh) takes the wrapped range as read (k = 0)")
    mesh_slack_m: float = knob(0.15, "per pixel, take the largest candidate r + k*alias not beyond the "
                                     "mesh range plus this slack, metres (objects rest on or in front of "
                                     "mesh surfaces; the slack covers mesh noise and pose drift; alias/2 "
                                     "gives the candidate nearest to the mesh)", min=0.0)
    n_candidates: int = knob(6, "alias candidates kept per observation, K (6 covers (0.1, 5.5] m at a "
                                "0.999 m alias)", min=1)
    decode_threads: int = knob(2, "threads decoding depth PNGs ahead of the lifting loop; OpenCV releases "
                                  "the GIL while decoding, and robust lifting is bound by the decode, so 2 "
                                  "uses both cores of a small machine (does not change the observations)", min=1)

    def result_knobs(self) -> dict:
        """The knobs the observations depend on (cache keys): all but ``decode_threads``."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "decode_threads"}
