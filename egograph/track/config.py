"""Configuration of the trackers (``track.*``, ``graph.*``, ``joint.*``, ``regt.*``), every knob
documented at its definition. Imports neither GTSAM nor Open3D, so reading, showing and checking
a configuration stays light.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from egograph.core.config import Checked, knob, rule_error, section
from egograph.geometry.config import SUPPORT_GAP_M

KERNELS = ("cauchy", "huber", "geman_mcclure", "tukey", "none")
"""Robust kernels a detection factor can take (``graph.noise.kernel``)."""

SWITCHES = ("switchable", "dcs")
"""Motion-break factors (``graph.switches``)."""

SWITCH_SOLVES = ("closed", "explicit")
"""How switchable factors are solved (``graph.switch_solve``)."""

SCORE_THRESHOLD = 0.6
"""The paper's acceptance threshold on the matcher score (cosine similarity): the default of
``track.score_threshold`` (baselines) and ``graph.score_threshold``. They mean the same thing but
are two knobs so that one tracker can be tuned alone (``smooth`` runs the graph at 0 on another
tracker's already-thresholded predictions)."""


def _score_threshold(doc: str):
    return knob(SCORE_THRESHOLD, doc, min=-1.0, max=1.0)


@dataclass
class BaselineConfig(Checked):
    score_threshold: float = _score_threshold(
        "minimum matcher score (cosine similarity) of a detection the baselines use; >= is accepted (paper: 0.6)"
    )
    kf_reset_distance_m: float = knob(
        0.15,
        "KF: a measurement farther than this from the predicted position resets the filter there, metres (paper: 0.15)", gt=0.0
    )
    kf_process_noise: float = knob(
        0.1,
        "KF: spectral density q of the white-noise acceleration driving the constant-velocity model, m^2/s^3 "
        "(acceleration noise; velocity variance grows by q per second, position by q*dt^3/3)", min=0.0
    )
    kf_measurement_noise_m: float = knob(
        0.05, "KF: standard deviation of each coordinate of a lifted 3D position, metres", gt=0.0
    )
    kf_initial_velocity_std: float = knob(
        0.25,
        "KF: standard deviation of each velocity component when a filter starts or resets (velocity 0), m/s "
        "(small: a newly seen or just-moved object is usually at rest)", min=0.0
    )


@dataclass
class DetectionNoiseConfig(Checked):
    range_sigma_m: float = knob(0.04, "detection noise along the viewing ray at zero range, metres (surface vs centre, depth cluster)",
                                gt=0.0)
    range_sigma_per_m: float = knob(0.02, "growth of the along-ray sigma per metre of range (AHAT noise, alias errors)",
                                    min=0.0)
    lateral_sigma_m: float = knob(0.015, "detection noise across the ray at zero range, metres (box jitter on the object)",
                                  gt=0.0)
    lateral_sigma_per_m: float = knob(0.012, "growth of the across-ray sigma per metre of range (pose rotation, registration), m/m",
                                      min=0.0)
    kernel: str = knob("cauchy", "robust kernel on detection factors: cauchy | huber | geman_mcclure | tukey | none",
                       choices=KERNELS)
    kernel_width: float = knob(2.0, "kernel width in whitened units (sigmas)", gt=0.0)
    scale: float = knob(1.0, "multiplies every sigma above: how noisy this front-end's lifted detections are; "
                             "used as given only without auto_scale (offline) or online_auto (causal), "
                             "which fit it and report it as noise_scale in the metadata", gt=0.0)
    auto_scale: bool = knob(True, "offline: estimate scale from the tracker's own stands (the whitened "
                                  "residuals of their inlier detections, fitted as a chi2 cut at inlier_chi2), "
                                  "starting from auto_start, and solve again until it settles (the causal "
                                  "mode: online_auto)")
    auto_start: float = knob(3.0, "auto_scale and online_auto: the first scale. Generous, so that a noisy "
                                  "front-end's stands are found at all: from a small start the fit can settle "
                                  "on the few tight stands that start lets through", gt=0.0)
    auto_rounds: int = knob(4, "offline auto_scale: most re-solves", min=1)
    auto_min_residuals: int = knob(30, "auto_scale and online_auto: fewest inlier residuals an estimate needs "
                                       "(fewer: the solve at the current scale, auto_start at first, stands)",
                                   min=3)
    auto_range: list = knob([0.5, 6.0], "auto_scale and online_auto: the estimate is clipped to this range",
                            length=2, ordered=True, gt=0.0)
    online_auto: bool = knob(True, "causal mode: fit scale as it goes, from the stands confirmed so far (the "
                                    "offline fit on the past only), starting from auto_start; every "
                                    "online_refit_every detections, each change of at least 5 % rescales the "
                                    "kept rows and applies to newer factors")
    online_refit_every: int = knob(50, "causal mode with online_auto: detections between two fits", min=1)


@dataclass
class NegativeConfig(Checked):
    margin_m: float = knob(0.08, "a pixel is empty when its reading, and the mesh, lie at least this far behind "
                                 "the landmark centre, metres", gt=0.0)
    agree_m: float = knob(0.03, "a reading up to this far behind the landmark centre may still be the object, metres",
                          min=0.0)
    object_radius_m: float = knob(0.15, "a reading up to this far in front of the landmark centre is the object "
                                        "(occupied), metres", min=0.0)
    max_range_m: float = knob(2.5, "only landmarks within this range of the depth camera are tested, metres", gt=0.0)
    window_px: int = knob(2, "half side of the AHAT pixel window around the landmark's projection", min=0)
    image_margin_px: float = knob(40.0, "the landmark must project this far inside the PV image, pixels", min=0.0)
    min_frames: int = knob(3, "consecutive empty frames needed to say the object is gone", min=1)
    stride: int = knob(2, "test every Nth frame of a gap", min=1)
    empty_share: float = knob(0.6, "share of valid window pixels that must be empty for an empty frame",
                              min=0.0, max=1.0)
    detection_gate_m: float = knob(0.3, "a detection of the instance this close to the landmark means it is there",
                                   min=0.0)
    cache_frames: int = knob(64, "decoded depth frames kept in memory", min=0)

    def cross_check(self) -> None:
        # a reading that is both "still the object" and "behind it, empty" would count both ways
        if not self.agree_m < self.margin_m:
            raise rule_error(self, "{} must be < {}", "agree_m", "margin_m")


@dataclass
class PlacesConfig(Checked):
    segment_min_inliers: int = knob(2, "offline: a segment of the chain with at least this many inliers (and not "
                                       "moving with the head) may found or join a place", min=1)
    overlap: float = knob(0.5, "offline: a segment joins a place that already explains (inlier gate) at least this "
                               "share of the segment's inliers or of the place's: both are one location", min=0.0,
                          max=1.0)
    support_min_inliers: int = knob(10, "offline: a place with fewer inliers than this must have a surface of the "
                                        "scene mesh under it (graph.max_support_gap_m); a few alias-wrapped or "
                                        "hand-held detections in mid-air are not a place", min=0)
    true_share: float = knob(0.6, "place chain: prior probability that an accepted detection scoring at least "
                                  "confident_score is the instance (the rest are false matches)", gt=0.0, lt=1.0)
    confident_score: float = knob(0.67, "place chain: a detection scoring at least this has prior probability "
                                        "true_share of being the instance, below it weak_true_share", min=-1.0,
                                  max=1.0)
    weak_true_share: float = knob(0.3, "place chain: prior probability that an accepted detection scoring below "
                                       "confident_score is the instance", gt=0.0, lt=1.0)
    carry_detect_rate: float = knob(0.2, "place chain: probability that a carried object (in front of the eyes) is "
                                         "detected in a frame; each frame without it makes a carry less likely",
                                    min=0.0, lt=1.0)
    false_density: float = knob(0.0167, "place chain: density of false matches over the scene, per m^3 (about one "
                                        "over the volume where detections land)", gt=0.0)
    lookalike_share: float = knob(0.5, "place chain: share of false matches that land at another instance's place "
                                       "(a look-alike) rather than anywhere", min=0.0, lt=1.0)
    false_spot_concentration: float = knob(10.0, "place chain: the look-alike share of false matches lands at a known "
                                                 "spot in proportion to its inliers, or at a new spot with this "
                                                 "weight (a Chinese restaurant process): a young place is not yet "
                                                 "where false matches gather", gt=0.0)
    carry_density: float = knob(0.5, "place chain: density of the detections of a carried object within "
                                     "graph.carry_range_m of the camera, per m^3", gt=0.0)
    pick_up_rate: float = knob(0.02, "place chain: pick-ups per second of a standing object", gt=0.0, lt=1.0)
    carry_s: float = knob(5.0, "place chain: mean time an object is carried, s", gt=0.0)
    unseen_put_down: float = knob(0.3, "place chain: share of carries that end at a place the object is never seen at "
                                       "(reported where the hand last held it)", min=0.0, max=1.0)
    put_back: float = knob(0.1, "place chain: share of carries that end where they began (put back)", min=0.0,
                           max=1.0)
    unseen_move_rate: float = knob(0.002, "place chain: moves per second from one place to another with no carry seen",
                                   min=0.0, lt=1.0)
    min_answer_probability: float = knob(0.3, "causal mode: the newest frame is answered only when its most probable "
                                               "state has at least this share of the frame's max-product scores (a "
                                               "lone match at a new place, or at another instance's, is as likely "
                                               "false); a lagged answer takes the later evidence instead", min=0.0,
                                         max=1.0)
    empty_likelihood: float = knob(0.01, "causal mode: a frame where depth shows the place empty makes standing there "
                                         "this many times less likely (graph.negative)", gt=0.0, max=1.0)
    start_unknown: float = knob(0.05, "place chain: prior probability that at the first frame the object is carried "
                                      "or at an unseen place (the rest is spread over its places)", gt=0.0, lt=1.0)

    def cross_check(self) -> None:
        # the shares of a carry's end must leave room for the object's other places
        if self.put_back + self.unseen_put_down > 1.0:
            raise rule_error(self, "{} + {} must be <= 1", "put_back", "unseen_put_down")


# Calibration fitted on tuning seeds 4-20 at 900 and 3000 frames (34 recordings, SVOE and MVPE: the
# lengths of both held-out sets, generated on an AMD EPYC) by tools/bench_confidence.py --fit: the
# stands' [raw, calibrated] knots (isotonic, each block at least the share of the answers that MIN_SHARE in
# tools/bench_confidence.py gives its family and front-end) and the other kinds' confidences (graph.answers below). A
# kind no tuning answer has (offline: put_down; smooth: unseen, put_down, held; noisy smooth: put_down) has the
# share of all the family's answers. Refitted at stop 52: the knots before were fitted at 0feb345 on
# the 900-frame recordings only, before the closed-form switch solve (03262a4) changed the raw confidences
# (docs/experiments.md). Refitted at stop 59, when (1) egograph smooth came to pick its knots by the scale of
# the distinct sightings (egograph.track.smooth.sightings_scale), so the noisy_smooth_* knots had tuning
# answers for the first time (SVOE-like), and (2) graph-causal, for an unseen instance every one of whose
# places another instance claimed, came to answer the newest detection rather than a claimed place
# (causal_kinds' unseen and last swapped: 0.065 / 0.98 -> 0.90 / 0.03). The offline and causal knots moved
# too, with the offline code unchanged: the tuning recordings were generated anew on another machine (AMD
# EPYC; stop 52: Intel Xeon), whose answers differ a little (offline stands 198,710 against 198,810).
# Refitted at stop 64 on 34 tuning recordings instead of 14 (seeds 9, 10 and 13-20 made for it; code unchanged),
# each family's block share chosen again by leave-one-recording-out (MIN_SHARE): on the 12 held-out recordings
# of 3000 frames the offline graph's SVOE ECE went 0.058 -> 0.033, on the demo's set (1-3, 301-303 x 900)
# 0.045 -> 0.060 (docs/experiments.md, stop 64). The fit's record (docs/bench/bench_confidence-fit.json) was
# made at stop 65 on an Intel Xeon from the same seeds generated there: the same kinds lack answers and the
# operating points are the same, but the knots differ (e.g. causal's lowest level 0.4798 below, 0.5638 in the record;
# noisy_causal's last 0.0334, 0.0141): the recordings differ with the CPU that generates them (docs/experiments.md,
# stop 65).
# Refitted at stop 67 for the held kind (graph.answers.held_range_m), on the same 34 recordings generated again on
# an AMD EPYC (the fit's record docs/bench/bench_confidence-fit.json, at 797864f): the stands' knots came out the
# same to the digit, held answers were right 0 times in every family (4,012-5,223 each; smooth: none, so the
# share of all its answers), and the last kind, rid of them, rose (offline 0.2063 -> 0.2797, noisy offline
# 0.1495 -> 0.1765, causal 0.0938 -> 0.1279, noisy causal 0.0334 -> 0.0389, noisy smooth 0.39 -> 0.9972 on 352
# answers) (docs/experiments.md, stop 67).
_OFFLINE_CALIBRATION = [[0.0, 0.9689], [0.406484, 0.9689], [0.755279, 0.9935], [1.0, 0.9935]]
_NOISY_OFFLINE_CALIBRATION = [[0.0, 0.6562], [0.333428, 0.6562], [0.661877, 0.8457], [1.0, 0.8457]]
_CAUSAL_CALIBRATION = [[0.0, 0.4798], [0.638176, 0.4798], [0.82278, 0.8804], [0.99392, 0.9133], [0.999433, 0.9781],
    [0.99998, 0.991], [1.0, 0.991]]
_NOISY_CAUSAL_CALIBRATION = [[0.0, 0.3457], [0.684687, 0.3457], [0.988283, 0.5614], [0.999409, 0.8137], [0.999508,
    0.8569], [1.0, 0.8569]]
_SMOOTH_CALIBRATION = [[0.0, 0.8], [0.485373, 0.8], [0.5, 0.8673], [1.0, 0.8673]]
_NOISY_SMOOTH_CALIBRATION = [[0.0, 0.2204], [0.174088, 0.2204], [0.480887, 0.3386], [0.499999, 0.3509], [0.5, 0.4114],
    [1.0, 0.4114]]

_KINDS = {"offline": [1.0, 0.0185, 0.2797, 0.9171, 0.0],
          "noisy_offline": [0.7069, 0.0355, 0.1765, 0.6995, 0.0],
          "causal": [0.3828, 0.0761, 0.1279, 0.7915, 0.0],
          "noisy_causal": [0.3509, 0.0215, 0.0389, 0.1653, 0.0],
          "smooth": [0.8161, 0.0, 0.0, 0.8161, 0.8161],
          "noisy_smooth": [0.1277, 0.1207, 0.9972, 0.3698, 0.0]}


@dataclass
class AnswersConfig(Checked):
    every_frame: bool = knob(True, "every frame from an instance's enrollment on is answered (a stand at a place, "
                                   "the hand while carried, the most probable place while unseen) with a calibrated "
                                   "confidence; false: the old policy (answers only where a place has enough "
                                   "support, nothing while carried)")
    min_confidence: float = knob(0.3, "the operating point of the offline graph and of smooth: the per-frame files "
                                      "hold the answers of at least this confidence (answers.tsv holds every "
                                      "answer, for the precision-recall curves). Chosen on the tuning recordings "
                                      "(seeds 4-20 at 900 and 3000 frames, SVOE and MVPE pooled) where the "
                                      "smaller of the offline graph's and smooth's margins over every baseline's "
                                      "point (P and R at every threshold, the least of them) is widest: 1.3 points "
                                      "at 0.3, 0.7 at 0.25, below 0 at 0.2 and less (smooth's SVOE P@1) and "
                                      "from 0.35 (its SVOE R@1.5): a narrow band, at its widest point "
                                      "(tools/bench_confidence.py --fit: its operating-point table); egograph "
                                      "track/smooth --min-confidence sets it and causal_min_confidence",
                                 min=0.0, max=1.0)
    causal_min_confidence: float = knob(0.0, "the operating point of graph-causal (every lag), as min_confidence; "
                                             "0: every answer, as the baselines answer every frame. Chosen as "
                                             "min_confidence: graph-causal's margin over every baseline's point on "
                                             "the tuning recordings is 3.4 points at 0-0.03 (binding: MVPE R@1.5), "
                                             "1.4 from 0.04 to 0.15, below 0 from 0.2 (SVOE R@1.5: a noisy "
                                             "front-end's answers at the hand and at the newest detection, right "
                                             "within 0.25 m 3 % and 1 % of the time, are often right within 1.5 m)",
                                        min=0.0, max=1.0)
    distance_m: float = knob(0.25, "the confidence is the probability that the answer lies within this distance "
                                   "of the truth (what the calibration below was fitted for), metres", gt=0.0)
    held_range_m: float = knob(0.45, "an answer at an instance's newest (offline: nearest in time) detection whose "
                                     "support (the instance's detections within distance_m of it) was seen from a "
                                     "median range under this is of the kind held, not last: the object was in the "
                                     "hand, which says nothing of where it stands (egograph.track.answers.held_rows). "
                                     "About half an arm's length, set before it was measured (carry_range_m is 0.9): "
                                     "on the tuning recordings none of those answers was within 0.25 m. 0: no held "
                                     "kind (its answers are last), metres", min=0.0)
    offline_calibration: list = knob(_OFFLINE_CALIBRATION,
                                     "offline graph: the raw confidence of an answer at a stand -> calibrated, as "
                                     "[raw, calibrated] knots joined linearly (an isotonic fit on tuning recordings: "
                                     "tools/bench_confidence.py --fit; the other kinds of answer: offline_kinds)")
    causal_calibration: list = knob(_CAUSAL_CALIBRATION,
                                    "graph-causal (every lag): raw confidence -> calibrated knots, as "
                                    "offline_calibration")
    smooth_calibration: list = knob(_SMOOTH_CALIBRATION,
                                    "egograph smooth (the graph on another tracker's answers, whose scores it does "
                                    "not read): raw confidence -> calibrated knots, as offline_calibration")
    noisy_scale: float = knob(1.3, "a front-end whose fitted detection noise scale (graph.noise, the tracker's "
                                   "own estimate of how far its lifted detections scatter) is at least this is "
                                   "noisy: its answers are right less often at the same raw confidence, and take "
                                   "the noisy_* knots below (between the scales the tuning front-ends fit: about "
                                   "0.6 for MVPE-like boxes, 2.7 for SVOE-like)", gt=0.0)
    noisy_offline_calibration: list = knob(_NOISY_OFFLINE_CALIBRATION, "offline_calibration of a noisy front-end")
    noisy_causal_calibration: list = knob(_NOISY_CAUSAL_CALIBRATION, "causal_calibration of a noisy front-end "
                                                                   "(online: the scale fitted so far)")
    noisy_smooth_calibration: list = knob(_NOISY_SMOOTH_CALIBRATION,
                                          "smooth_calibration of a noisy front-end (for smooth the scale fitted "
                                          "on the other tracker's distinct sightings: egograph.track.smooth."
                                          "sightings_scale)")
    offline_kinds: list = knob(_KINDS["offline"],
                               "offline graph: the confidence of its answers that are not at a stand, per kind: "
                               "[unseen, hand, last, put_down, held] (egograph.track.answers.ANSWER_KINDS; the share "
                               "of such answers within distance_m on the tuning recordings, tools/bench_confidence.py "
                               "--fit: their raw value carries no evidence of being right, and one monotone map with "
                               "the stands' pooled kinds that are right at very different rates)",
                               min=0.0, max=1.0, length=5)
    causal_kinds: list = knob(_KINDS["causal"], "graph-causal: as offline_kinds", min=0.0, max=1.0, length=5)
    smooth_kinds: list = knob(_KINDS["smooth"], "egograph smooth: as offline_kinds", min=0.0, max=1.0, length=5)
    noisy_offline_kinds: list = knob(_KINDS["noisy_offline"], "offline_kinds of a noisy front-end", min=0.0, max=1.0,
                                     length=5)
    noisy_causal_kinds: list = knob(_KINDS["noisy_causal"], "causal_kinds of a noisy front-end", min=0.0, max=1.0,
                                    length=5)
    noisy_smooth_kinds: list = knob(_KINDS["noisy_smooth"], "smooth_kinds of a noisy front-end", min=0.0, max=1.0,
                                    length=5)

    def knots(self, family: str, scale: float) -> list:
        """The calibration knots of tracker ``family``'s stands (offline, causal, smooth) at detection
        noise scale ``scale``."""
        return getattr(self, f"{'noisy_' if scale >= self.noisy_scale else ''}{family}_calibration")

    def kinds(self, family: str, scale: float) -> list:
        """The confidences of tracker ``family``'s answers of kinds unseen, hand, last, put_down, held
        (in this order; egograph.track.answers.ANSWER_KINDS) at detection noise scale ``scale``."""
        return getattr(self, f"{'noisy_' if scale >= self.noisy_scale else ''}{family}_kinds")

    def cross_check(self) -> None:
        for name in ("offline_calibration", "causal_calibration", "smooth_calibration", "noisy_offline_calibration",
                     "noisy_causal_calibration", "noisy_smooth_calibration"):
            knots = getattr(self, name)
            try:
                arr = np.asarray(knots, dtype=float)
                ok = arr.ndim == 2 and arr.shape[1] == 2 and len(arr) >= 2 and bool(np.all(np.diff(arr[:, 0]) > 0)) \
                    and bool(np.all(np.diff(arr[:, 1]) >= 0))
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise rule_error(self, "{} must be [raw, calibrated] pairs, raw increasing, calibrated "
                                       "non-decreasing", name)


@dataclass
class GraphConfig(Checked):
    score_threshold: float = _score_threshold("minimum matcher score of a detection the graph uses (the paper's 0.6; "
                                              "the same rule as track.score_threshold, set apart)")
    chunk_s: float = knob(0.5, "length of the time grid that over-segments an instance's timeline into landmarks, s",
                          gt=0.0)
    still_sigma_m: float = knob(0.05, "sigma of the zero-motion factor between consecutive landmarks, metres", gt=0.0)
    switch_sigma: float = knob(0.5, "sigma of the prior pulling each switch to 1; a break costs 0.5/sigma^2 and "
                                    "fires where landmarks differ by more than still_sigma_m/switch_sigma", gt=0.0)
    switches: str = knob("switchable", "motion-break factor: 'switchable' (a switch per boundary, solved as "
                                       "switch_solve says) or 'dcs' (dynamic covariance scaling: another weight "
                                       "curve that breaks at the same gap, all C++)", choices=SWITCHES)
    switch_solve: str = knob("closed", "switchable only: 'closed' solves each switch in closed form (its optimum "
                                       "given the landmarks, which leaves a Geman-McClure kernel on the zero-motion "
                                       "factor: the same objective, all C++, every candidate window of a chain in one "
                                       "solve; egograph.track.switchable); 'explicit' keeps the switch variables as "
                                       "Python CustomFactors, solved window by window (the reference, several times "
                                       "slower)", choices=SWITCH_SOLVES)
    dcs_prepass: bool = knob(True, "switchable only: a DCS solve first; boundaries it finds clearly still get a plain "
                                   "zero-motion factor, the rest switchable ones (a smaller problem; with explicit "
                                   "switches, far fewer Python CustomFactors)")
    prepass_keep: float = knob(0.95, "a boundary whose DCS-implied switch is at least this is clearly still",
                               min=0.0, max=1.0)
    prepass_window: int = knob(10, "each candidate break is solved with this many chunks of the chain either side",
                               min=1)
    prepass_max_window: int = knob(60, "explicit switches: merged windows longer than this many chunks are solved in "
                                       "overlapping pieces "
                                       "of this length (prepass_window chunks of context at each cut), so the cost "
                                       "grows linearly with the recording, not with the longest run of candidates",
                                       min=1)
    break_below: float = knob(0.5, "a switch below this value (0-1) is a motion break", min=0.0, max=1.0)
    min_observations: int = knob(3, "fewest inlier detections a stand of the chain, and a place over the whole "
                                    "recording, need", min=1)
    min_inlier_share: float = knob(0.6, "share of a segment's detections its centre must explain to be stationary",
                                   min=0.0, max=1.0)
    inlier_chi2: float = knob(11.34, "squared Mahalanobis gate of an inlier (chi2, 3 dof, 99 %)", gt=0.0)
    merge_radius_m: float = knob(0.12, "offline: segments whose centres are closer than this are one place (as are "
                                       "segments that share most inliers), metres", min=0.0)
    carry_range_m: float = knob(0.9, "a detection this close to the camera may be an object in hand, metres", min=0.0)
    min_carry_observations: int = knob(2, "detections within carry_range_m moving with the head (a segment of the "
                                          "chain offline, the last two seconds online) needed before they count "
                                          "as an object in hand", min=1)
    carry_spread_m: float = knob(0.03, "near detections that spread more than this (median, metres) and more than "
                                       "their offsets to the head do are an object in hand", min=0.0)
    online_carry_margin: float = knob(2.0, "causal mode: near detections move with the head only when they spread "
                                           "more than this many times their offsets to the head do (a still head "
                                           "leaves the two equal up to noise: a few detections of an object just "
                                           "put down must not count as in hand)", min=1.0)
    exclusion_radius_m: float = knob(0.15, "offline: a place of one instance within this distance of another "
                                           "instance's place with more inliers over overlapping times is that "
                                           "instance's (a look-alike confusion), metres; 0 disables", min=0.0)
    covariance_floor_m: float = knob(0.03, "isotropic sigma added to every interval covariance for errors shared "
                                           "by its detections (pose drift, surface-to-centre bias), metres", min=0.0)
    alias_rounds: int = knob(1, "re-solves after re-choosing each detection's AHAT alias candidate", min=0)
    max_iterations: int = knob(50, "Levenberg-Marquardt iteration limit", min=1)
    max_support_gap_m: float = knob(SUPPORT_GAP_M, "a stand of the chain seen only from within carry_range_m, and a "
                                                   "place with fewer than places.support_min_inliers inliers, need "
                                                   "the scene mesh at most this far below its centre (an object held "
                                                   "still in hand is in mid-air), metres; 0 disables; needs the "
                                                   "recording's mesh (the quantity of lift.max_support_gap_m)",
                                    min=0.0)
    negative_evidence: bool = knob(True, "where depth shows the place empty, the object is gone: offline an "
                                         "interval ends there, online standing there becomes "
                                         "places.empty_likelihood times less likely (reads depth frames)")
    lag_s: float = knob(0.0, "causal mode (graph-causal, egograph.track.online): the answer for a frame may use the "
                             "frames up to this many seconds after it (0: strictly causal; large: towards offline), s",
                        min=0.0)
    put_down_after_s: float = knob(2.0, "causal mode: after a carry, an object at a place not seen yet is answered "
                                        "where the hand last held it (put down near there), at low confidence, once "
                                        "this long has passed since the last detection in hand; 0: never, s",
                                   min=0.0)
    put_down_sigma_m: float = knob(0.3, "position sigma of an answer where the hand last held the object, metres",
                                   gt=0.0)
    online_max_rows: int = knob(300, "causal mode: newest inliers kept per place (for the noise-scale fit; bounds "
                                     "memory)", min=1)
    online_max_places: int = knob(32, "causal mode: places kept per instance (beyond, the weakest that no state leads "
                                      "is forgotten: bounds time per frame)", min=1)
    noise: DetectionNoiseConfig = section(DetectionNoiseConfig, "detection factor noise and robust kernel")
    negative: NegativeConfig = section(NegativeConfig, "negative evidence from depth")
    places: PlacesConfig = section(PlacesConfig, "offline: places pooled across motion breaks and the place chain "
                                                 "that says which one holds the instance at every frame "
                                                 "(egograph.track.places)")
    answers: AnswersConfig = section(AnswersConfig, "what the graph trackers answer per frame, their confidence "
                                                    "and the operating point (egograph.track.answers)")


@dataclass
class JointConfig(Checked):
    rounds: int = knob(1, "joint mode: (track -> joint pose/landmark solve -> re-track) rounds", min=1)
    min_inliers: int = knob(3, "joint mode: a stand joins the pose graph with at least this many inlier detections",
                            min=1)
    noise_scale: float = knob(1.0, "joint mode: detection sigmas are multiplied by this in the pose graph; the "
                                   "detections of one stand share part of their error (the visible surface is "
                                   "not the centre), so they are not independent measurements of the poses", gt=0.0)
    max_iterations: int = knob(50, "joint mode: Levenberg-Marquardt iteration limit of the joint solve", min=1)


@dataclass
class RegtConfig(Checked):
    audit_m: float = knob(0.1, "audit: flag a given centre farther than this from the re-estimate, metres ...", min=0.0)
    audit_sigma: float = knob(4.0, "... and farther than this many sigmas (Mahalanobis, re-estimate covariance; "
                                   "4 sigma in 3D is a chi2 tail of 0.1 %: only gross disagreements)", min=0.0)
