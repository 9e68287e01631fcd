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


@dataclass
class CalibFitConfig(Checked):
    """How well a calibration registers the AHAT depth with the PV frames (``egograph.geometry.calib_fit``),
    and how the calibration folder of a sequence is chosen with it."""

    select: bool = knob(True, "of several calibration folders found for a sequence, use the best-fitting one when "
                              "the one named by the sequence's number fits clearly worse (margin_px, margin_sigmas), "
                              "with a warning; false: by number only, as the release's notebooks do")
    frames: int = knob(40, "PV frames sampled (evenly over the recording) to score a calibration: each is decoded "
                           "and edged once, then every candidate is scored on the same frames", min=2)
    blur_px: float = knob(6.0, "Gaussian blur (sigma, PV px) before the edges are found: fine texture makes no edge, "
                               "an object's outline does (2 px left so many texture edges that a 0.5 deg error "
                               "already cost as much as a 3 deg one)", min=0.0)
    edge_percentile: float = knob(93.0, "Canny's upper threshold at this percentile of the frame's own gradient "
                                        "magnitude (the lower at 0.4 of it): as many edges in a dark frame as in a "
                                        "bright one", min=1.0, max=99.9)
    truncate_px: float = knob(40.0, "a depth edge costs its distance to the nearest PV edge, at most this much (PV px): "
                                    "blur, hands and bare walls cost every calibration alike; 40 px keeps a 3 deg "
                                    "error (52 px at the synthetic PV focal) costing more than a 2 deg one", gt=0.0)
    jump_m: float = knob(0.1, "AHAT neighbours whose ranges differ by more than this (modulo the alias distance) "
                              "make a depth discontinuity, metres", gt=0.0)
    max_pairs: int = knob(3000, "depth discontinuities used per frame at most (an even stride over them)", min=10)
    max_range_m: float = knob(3.5, "alias hypotheses of a wrapped range are tried up to this range, metres", gt=0.0)
    use_mesh: bool = knob(True, "resolve each depth edge pixel's alias with the recording's HoloLens mesh (the robust "
                                "lift's rule; imports Open3D); without a mesh, or false, every alias hypothesis is "
                                "tried and the nearest to a PV edge counts, which blunts the score")
    mesh_slack_m: float = knob(0.15, "with use_mesh: take the largest r + k*alias not beyond the mesh range plus this, "
                                     "metres", min=0.0)
    margin_px: float = knob(0.15, "the number-chosen calibration fits clearly worse than the best when its score is "
                                  "higher by more than this (PV px, mean over the sampled frames) ... Chosen on "
                                  "synthetic recordings (seed 3, 60 frames; checked on seed 5, 300 frames): the "
                                  "smallest errors to catch cost 0.7 / 1.5 px (1 cm), 0.8 / 3.9 px (20 ms), 2.8 / "
                                  "2.1 px (0.5 deg); identical folders differ by 0", min=0.0)
    margin_sigmas: float = knob(3.0, "... and by more than this many standard errors of the frame-by-frame "
                                     "difference", min=0.0)
    max_offset_px: float = knob(6.0, "a calibration does not fit when shifting every registered depth edge by one "
                                     "image offset longer than this (PV px; 8 directions at 4, 8 and 16 px are "
                                     "tried; 8 px is 0.46 deg of rotation at the synthetic PV focal) lowers its "
                                     "score by more than offset_gain_px; --strict refuses it. A 1 cm or 20 ms error is "
                                     "caught this way on some recordings (seed 4: 8 px) and not on others (seed 3: "
                                     "4 px); 0.5 deg on both", min=0.0)
    offset_gain_px: float = knob(0.1, "see max_offset_px (PV px)", min=0.0)
