"""Knobs of the synthetic recording generator (design §4). Lengths in metres, angles in
degrees, times in seconds unless the name says otherwise."""

from __future__ import annotations

from dataclasses import dataclass

from egograph.core.config import Checked, knob, rule_error, section
from egograph.core.errors import ConfigError

DETECTION_SETS = ("svoe", "mvpe")
"""The simulated front-ends, one detection set each (``detections.svoe``, ``detections.mvpe``)."""

AHAT_DEVICES = ("hl2-a", "hl2-b", "pinhole")
"""AHAT geometries of the generator: the real calibrations of egograph.io.devices, and a pinhole."""

SCORE_KNOBS = ("true_score", "lookalike_score", "clutter_score", "other_score")
"""Front-end knobs holding ``[mean, std]`` of a similarity score."""


@dataclass
class SceneConfig(Checked):
    room_size: list[float] = knob([7.0, 6.0, 2.7], "room extent x, z (floor plan) and height y, metres (world is y-up, floor at y=0)",
                                  gt=0.0, length=3)
    n_instances: int = knob(8, "object instances to track (5-10 in IT3DEgo recordings)", min=1)
    n_lookalike_pairs: int = knob(2, "pairs of near-identical instances (e.g. two similar cups) that confuse appearance matching",
                                  min=0)
    moves_per_instance: int = knob(2, "pick-up/put-down cycles per instance (2 gives about three locations); fewer when the recording is too short",
                                   min=0)
    min_object_gap: float = knob(0.25, "minimum distance between resting objects on a surface, metres", min=0.0)
    mesh_noise: float = knob(0.01, "std of the HoloLens scene mesh vertex noise, metres", min=0.0)
    mesh_edge: float = knob(0.08, "edge length the scene is subdivided to before the mesh noise, metres", gt=0.0)
    mesh_triangles: int = knob(6000, "triangle budget of the decimated HoloLens mesh", min=1)
    n_props: int = knob(12, "untracked objects (5-30 cm) standing on the surfaces all recording", min=0)
    props_in_mesh: float = knob(0.5, "share of the untracked objects that are in the HoloLens mesh (the others came after "
                                "the room was mapped)", min=0.0, max=1.0)
    mesh_baked_instances: float = knob(0.4, "probability that an instance is in the HoloLens mesh at its first place "
                                       "(it stood there while the room was mapped; it stays in the mesh after it moves)",
                                       min=0.0, max=1.0)
    mesh_hole_patch: float = knob(0.3, "side of the patches the mesh's holes come in, metres", gt=0.0)
    mesh_hole_dark: float = knob(0.6, "share of the patches of dark surfaces (albedo < 0.25) missing from the mesh",
                                 min=0.0, max=1.0)
    mesh_hole_grazing: float = knob(0.6, "share of the patches seen only at grazing angles or from behind missing from the mesh",
                                    min=0.0, max=1.0)
    mesh_grazing_deg: float = knob(10.0, "a surface is seen at a grazing angle when the line to the room centre at head "
                                   "height is within this angle of it, degrees", min=0.0, max=90.0)


@dataclass
class WearerConfig(Checked):
    head_height: float = knob(1.62, "eye height while standing, metres", gt=0.0)
    walk_speed: float = knob(1.3, "walking speed, m/s", gt=0.0)
    reach_time: float = knob(0.8, "time spent looking at an object before picking it up / while putting it down, s",
                             min=0.0)
    carry_distance: list[float] = knob([0.3, 0.6], "range of hand-to-eye distance while carrying, metres",
                                       gt=0.0, length=2, ordered=True)
    watch_time: list[float] = knob([0.6, 1.2], "range of time the eyes stay on an object just put down, s",
                                   min=0.0, length=2, ordered=True)
    approach_calm: float = knob(1.8, "no fast head turn starts in this last stretch of walking up to an object to pick up, s "
                                "(the eyes are on it, as in egocentric video)", min=0.0)
    idle_time: list[float] = knob([0.6, 1.8], "range of look-around time after each put-down, s",
                                  min=0.0, length=2, ordered=True)
    head_turn_rate: float = knob(0.7, "fast head turns per second while looking around", min=0.0)
    head_turn_angle: list[float] = knob([40.0, 100.0], "range of yaw of a fast head turn, degrees",
                                        min=0.0, length=2, ordered=True)
    head_turn_time: list[float] = knob([0.2, 0.4], "range of duration of a fast head turn, s (peak rates reach 300-500 deg/s)",
                                       gt=0.0, length=2, ordered=True)
    gaze_time_constant: float = knob(0.12, "time constant of the head following its gaze target, s", gt=0.0)


@dataclass
class AhatConfig(Checked):
    device: str = knob("hl2-a", "AHAT geometry: a real HoloLens 2 calibration (its per-pixel rays, about 114 px focal "
                       "and 113 deg across with strong distortion, and its rig-node extrinsics: the camera looks about "
                       "17 deg below the head's forward direction) or `pinhole` (focal and tilt below; the generator "
                       "before revision 4)", choices=AHAT_DEVICES)
    focal: float = knob(250.0, "pinhole AHAT only: focal length, pixels (512x512, about 90 deg field of view)", gt=0.0)
    tilt: float = knob(15.0, "pinhole AHAT only: camera pitch below the head's forward direction, degrees",
                       min=-90.0, max=90.0)
    alias_mm: float = knob(1055.0, "range at which AHAT readings wrap, mm (alias.bin; 1055 current firmware, 999 older)",
                           gt=0.0)
    depth_factor: float = knob(4.0, "raw unit: raw = range_mm / depth_factor (4 in the hl2ss version IT3DEgo used, 1 current)",
                               gt=0.0)
    noise_std: float = knob(0.003, "range noise std at 1 m, metres; grows with range squared", min=0.0)
    max_range: float = knob(3.5, "returns beyond this true range (metres) fade out (invalid pixels)", gt=0.0)
    dark_invalid: float = knob(0.35, "probability that a pixel on a dark surface (albedo < 0.25) has no return",
                               min=0.0, max=1.0)
    invalid_rate: float = knob(0.02, "share of pixels with no return anywhere (speckle)", min=0.0, max=1.0)
    flying_pixel_rate: float = knob(0.5, "probability that a depth-edge pixel reads a value between foreground and background",
                                    min=0.0, max=1.0)
    time_offset_ms: float = knob(5.0, "AHAT capture time minus PV capture time, ms (jitter 1 ms)")


@dataclass
class PvConfig(Checked):
    focal: float = knob(1000.0, "PV focal length, pixels (1280x720, about 65 deg horizontal field of view)", gt=0.0)
    tilt: float = knob(5.0, "PV camera pitch below the head's forward direction, degrees", min=-90.0, max=90.0)
    rgb: bool = knob(True, "render PV RGB frames (switch off for speed: depth, poses, annotations are always written)")
    renderer: str = knob("gl", "PV colour renderer: gl (OpenGL rasteriser on a headless EGL context, Mesa's llvmpipe "
                         "without a GPU; about 8x faster) or raycast (Open3D ray casting shaded in numpy: the same "
                         "shading model, the reference the rasteriser is tested against)", choices=["gl", "raycast"])
    png_compression: int = knob(1, "deflate level of PV frames (0-9; 0 stores, ISA-L compresses at 1-3 and treats "
                                   "higher levels as 3)", min=0, max=9)
    visibility_downsample: int = knob(4, "PV visibility buffer is rendered at 1/N resolution (occlusion and box annotations)",
                                      min=1)


@dataclass
class PoseErrorConfig(Checked):
    enabled: bool = knob(True, "perturb reported poses; false writes the true poses")
    jitter_trans: float = knob(0.001, "per-frame translation jitter std, metres", min=0.0)
    jitter_rot: float = knob(0.1, "per-frame rotation jitter std, degrees", min=0.0)
    drift_trans: float = knob(0.002, "random-walk translation drift, metres per sqrt(second)", min=0.0)
    drift_rot: float = knob(0.03, "random-walk yaw drift, degrees per sqrt(second)", min=0.0)
    jump_rate: float = knob(0.08, "probability of a relocalisation jump after a fast head turn", min=0.0, max=1.0)
    jump_trans: list[float] = knob([0.02, 0.06], "range of relocalisation jump size, metres",
                                   min=0.0, length=2, ordered=True)
    jump_rot: list[float] = knob([0.2, 0.6], "range of relocalisation jump rotation, degrees",
                                 min=0.0, length=2, ordered=True)
    fast_turn_rate: float = knob(150.0, "head angular speed counted as a fast turn, deg/s", gt=0.0)


@dataclass
class FrontEndConfig(Checked):
    """A simulated appearance front-end (detector + instance matcher), top-1 per instance per frame."""

    detect_rate: float = knob(0.8, "detection probability of a fully visible, large, sharp instance", min=0.0, max=1.0)
    min_visible: float = knob(0.15, "visible share below which an instance is never detected", min=0.0, max=1.0)
    size_half_px: float = knob(40.0, "box side (pixels) at which detection probability halves", gt=0.0)
    size_exponent: float = knob(4.0, "steepness of the fall of detection probability with box side: s^e / (s^e + half^e)",
                                gt=0.0)
    min_box_px: float = knob(34.0, "boxes with a smaller side (pixels) are never proposed (region proposals drop tiny regions)",
                             min=0.0)
    blur_half_dps: float = knob(120.0, "image-motion rate (deg/s) at which detection probability halves", gt=0.0)
    true_score: list[float] = knob([0.7, 0.08], "mean and std of the similarity score of a true match", length=2)
    lookalike_score: list[float] = knob([0.62, 0.08], "mean and std of the score of the look-alike twin", length=2)
    clutter_score: list[float] = knob([0.5, 0.08], "mean and std of the score of persistent background clutter",
                                      length=2)
    other_score: list[float] = knob([0.3, 0.06], "mean and std of the score of a different (not look-alike) instance",
                                    length=2)
    clutter_per_instance: int = knob(3, "persistent clutter spots per instance that resemble it", min=0)
    clutter_rate: float = knob(0.35, "probability that a visible clutter spot produces a candidate in a frame",
                               min=0.0, max=1.0)
    box_jitter: float = knob(0.08, "box corner jitter, share of box size", min=0.0)
    min_written_score: float = knob(0.45, "candidates below this similarity are not written (trackers threshold at 0.6)")

    def cross_check(self) -> None:
        for name in SCORE_KNOBS:
            if not getattr(self, name)[1] >= 0:
                raise rule_error(self, "{} must be [mean, std] with std >= 0", name)


@dataclass
class DetectionsConfig(Checked):
    svoe: FrontEndConfig = section(FrontEndConfig, "single-view online enrollment front-end (weaker)")
    mvpe: FrontEndConfig = section(FrontEndConfig, "multi-view pre-enrollment front-end (stronger)")
    primary: str = knob("svoe", "detection set the demo tracks by default (both sets are always written)",
                        choices=DETECTION_SETS)


WORLDS = ("legacy", "device")
"""Generator worlds: ``legacy`` (procedural lattice textures on boxes and cylinders, sharp noise-free
PV frames: generator revision 4, kept so earlier records stay comparable) and ``device`` (photographic
surfaces, category meshes, look-alikes that differ as real ones do, the PV camera's exposure, noise,
motion blur and compression, hands that reach and withdraw, MVPE photos on a tabletop)."""

LOOKALIKE_KINDS = ("label", "colour", "sticker")


@dataclass
class LookalikeConfig(Checked):
    """How the twins of the device world differ (the legacy world's twins share a pattern and differ by a band)."""

    kinds: list[str] = knob(["sticker", "colour", "label"], "how the second instance of pair p differs, cycling through "
                            "the list: sticker (the same print, one small region replaced: a logo or sticker), colour "
                            "(the same design in another colour: hue turned by `hue_shift`), label (another print or "
                            "photograph on the same product); the first pair of every recording takes the first kind")
    hue_shift: list[float] = knob([60.0, 150.0], "range of the hue turn of a colour twin, degrees (smaller is closer)",
                                  min=0.0, max=180.0, length=2, ordered=True)
    sticker_size: float = knob(0.18, "side of the region a sticker twin replaces, share of the label's height "
                                "(smaller is closer)", gt=0.0, max=1.0)

    def cross_check(self) -> None:
        if not self.kinds or any(k not in LOOKALIKE_KINDS for k in self.kinds):
            raise rule_error(self, "{} must be a non-empty list of " + "/".join(LOOKALIKE_KINDS), "kinds")


@dataclass
class RoomLightConfig(Checked):
    """The device world's room light, drawn once per recording."""

    dim_share: float = knob(0.35, "probability that a recording is in a dim room (evening, one lamp)", min=0.0, max=1.0)
    bright: list[float] = knob([0.6, 1.6], "range of the light level of a lit room (1 is an office at about 300 lux)",
                               gt=0.0, length=2, ordered=True)
    dim: list[float] = knob([0.05, 0.15], "range of the light level of a dim room", gt=0.0, length=2, ordered=True)
    warm: list[float] = knob([0.0, 1.0], "range of the lamps' warmth (0 daylight white, 1 tungsten orange)",
                             min=0.0, max=1.0, length=2, ordered=True)


@dataclass
class PvCameraConfig(Checked):
    """The device world's PV camera (HoloLens 2 photo/video stream, 1280x720 at 30 fps, video-encoded)."""

    ae_target: float = knob(0.16, "auto-exposure target: mean linear (pre-gamma) pixel value of the metered frame",
                            gt=0.0, lt=1.0)
    ae_time_constant: float = knob(0.35, "time constant of auto-exposure following its target (log exposure), s",
                                   min=0.0)
    exposure_ms: list[float] = knob([2.0, 33.0], "range of the exposure time, ms (33 at 30 fps)", gt=0.0, length=2,
                                    ordered=True)
    max_gain: float = knob(8.0, "largest analogue+digital gain; beyond it a dark room stays underexposed", min=1.0)
    full_well: float = knob(3000.0, "electrons at full scale with gain 1 (small phone-size pixels)", gt=0.0)
    read_noise: float = knob(3.0, "read noise std, electrons", min=0.0)
    sensitivity: float = knob(15.0, "linear pixel value per (radiance x second) at gain 1 (radiance: albedo x light x "
                              "the room's level; a lit white surface in a level-1 room is about 1): such a surface fills "
                              "the pixel in 1/15 s, so a level-1 room is exposed about 1/60 s", gt=0.0)
    blur: bool = knob(True, "integrate the head's motion over the exposure (per-pixel flow from depth and the PV "
                      "poses at shutter open and close)")
    blur_taps: int = knob(10, "most samples along a pixel's motion path, one per 2 pixels of the longest path (fewer "
                          "when it moves less)", min=1)
    denoise_sigma: float = knob(0.7, "the ISP's spatial noise reduction: Gaussian std at gain 1, pixels, growing with the "
                                "square root of the gain (0 switches it off)", min=0.0)
    vignetting: float = knob(0.35, "light lost in the image corners, share", min=0.0, max=1.0)
    jpeg_quality: int = knob(80, "quality of the JPEG round trip that stands for the release's video compression "
                             "(0 switches it off)", min=0, max=100)


@dataclass
class DeviceWorldConfig(Checked):
    """Knobs of the device world (``world: device``); the legacy world ignores them."""

    lookalikes: LookalikeConfig = section(LookalikeConfig, "how look-alike twins differ")
    light: RoomLightConfig = section(RoomLightConfig, "the room's light")
    camera: PvCameraConfig = section(PvCameraConfig, "the PV camera's exposure, noise, blur and compression")
    hand_reach: bool = knob(True, "the hand reaches for the object during the look before a pick-up and withdraws "
                            "during the look after the put-down (false: it is there only while carrying)")
    mvpe_in_hand: int = knob(5, "MVPE photos per instance taken with the object in hand (the others on a tabletop)",
                             min=0)
    mvpe_clutter: int = knob(4, "other objects on the tabletop around the object in its MVPE photos", min=0)


@dataclass
class SynthConfig(Checked):
    sequence: str = knob("synth_seq", "sequence folder name")
    world: str = knob("legacy", "generator world: legacy (revision 4: lattice textures, boxes and cylinders, sharp "
                      "noise-free frames) or device (photographic surfaces, category meshes, the PV camera's exposure, "
                      "noise, blur and compression, reaching hands; needs pv.renderer=gl)", choices=WORLDS)
    frames: int = knob(3000, "number of PV frames at 30 fps (at least 2: the wearer's motion is differentiated over frames)", min=2)
    fps: float = knob(30.0, "PV frame rate, frames per second", gt=0.0)
    annotation_stride: int = knob(5, "2D boxes are annotated every Nth frame when at least a quarter visible", min=1)
    mvpe_photo_size: int = knob(256, "side of the rendered MVPE enrollment photos, pixels", min=1)
    scene: SceneConfig = section(SceneConfig, "room, furniture and objects")
    wearer: WearerConfig = section(WearerConfig, "the person wearing the headset")
    ahat: AhatConfig = section(AhatConfig, "AHAT depth sensor model")
    pv: PvConfig = section(PvConfig, "PV (RGB) camera model")
    pose_error: PoseErrorConfig = section(PoseErrorConfig, "HoloLens head-tracking error model of the reported poses")
    detections: DetectionsConfig = section(DetectionsConfig, "simulated detection front-ends")
    device: DeviceWorldConfig = section(DeviceWorldConfig, "the device world (world: device)")

    def cross_check(self) -> None:
        # the sequence name becomes a folder under the output root
        if not self.sequence or "/" in self.sequence or "\\" in self.sequence or self.sequence in (".", ".."):
            raise rule_error(self, "{} must be a folder name (not empty, no path separator)", "sequence")
        if self.world == "device" and self.pv.renderer != "gl":
            raise ConfigError(f"world=device renders by OpenGL only: pv.renderer must be gl, not {self.pv.renderer!r}")
