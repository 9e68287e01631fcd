"""How well a calibration registers a sequence's AHAT depth with its PV frames: the fit score.

A wrong AHAT-to-PV calibration moves every lifted point without any error; the sequence's own
frames tell. Per sampled frame:

* **PV edges**: Canny on the grey image blurred by ``blur_px``, its thresholds at a percentile of
  the frame's own gradient magnitude (so a dark or low-contrast frame finds as many edges as a
  bright one), and the distance transform of the edges truncated at ``truncate_px`` (a depth edge
  with no image edge near it -- motion blur, a hand in front, a textureless wall -- costs at most
  that much, whichever calibration is tried).
* **AHAT depth discontinuities**: neighbouring pixel pairs whose ranges jump by more than
  ``jump_m`` (modulo the alias distance: the sensor wraps, a wrap is not an edge). An occluding
  contour is an image edge on one side of such a pair.
* **registration**: each pair's occluding edge through the candidate's ray table, AHAT extrinsics,
  the frame's AHAT pose at its key plus the candidate's time offset (interpolated between the
  neighbouring frames' poses), the PV pose and the candidate's PV intrinsics (the ``posed`` chain the
  robust lift uses). The edge lies between the pair's pixels, so it is placed on their mid ray; at
  the near pixel's range where the mesh resolves both pixels' alias (the occluding side), else at
  every alias hypothesis of either pixel up to ``max_range_m``, and the pair costs the distance of
  its nearest hypothesis. (Either pixel's own centre at its own range, tried before, biased the
  refinement by 4-7 mm: the near centre lies half an AHAT pixel, 1.3 PV px, inside the occluder, and
  the far one lands by baseline parallax wherever an edge happens to be.)

The frame's cost is the mean over its pairs, in PV pixels; the score is the mean over frames
(lower fits better) with its spread (standard deviation over frames). Two calibrations are compared
frame by frame on the same sample (:func:`compare`), which removes what the frames share
(texture, blur, hands). Whether a calibration fits at all (:attr:`FitScore.offset_px`): shifting
every registered point by the same image offset should not help; the offset that helps most is
how far the calibration is off where a rotation error shows.

What it does not see: the PV extrinsics (the posed chain does not use them) and, in a frame
where the head is still, the time offset. The mesh's silhouette is not scored: it reaches the PV
frame through the PV pose and intrinsics alone, so it is the same for every AHAT extrinsic and time
offset and can neither order such candidates nor steer their refinement (it is used to resolve the
depth edges' aliasing). API::

    sample = prepare_fit(rec, cfg)                     # decode and edge the frames once
    s = fit_score(rec, sample, FitCandidate.of(ahat, pv), cfg)   # s.score, s.spread, s.offset_px
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import cv2
import numpy as np

from egograph.core.errors import InputError
from egograph.geometry.config import CalibFitConfig
from egograph.geometry.hl2ss import invert_rigid
from egograph.io.calibration import AhatCalibration, PvCalibration
from egograph.io.poses import interpolate_poses, pose_validity

EDGE_DOWNSAMPLE = 2
"""PV frames are edged at half resolution (a quarter of the time and memory: 0.23 MB per frame); the
edges of outlines blurred by ``blur_px`` lose nothing at that resolution."""

TICKS_PER_MS = 10_000


@dataclass
class FitCandidate:
    """What the fit score depends on: the AHAT rays and extrinsics, the PV intrinsics, the AHAT time
    offset (ms, ``AhatCalibration.time_offset_ms``), and the folder it came from (a label)."""

    ahat: AhatCalibration
    pv: PvCalibration
    time_offset_ms: float = 0.0
    name: str = ""

    @classmethod
    def of(cls, ahat: AhatCalibration, pv: PvCalibration, name: str = "") -> "FitCandidate":
        return cls(ahat, pv, float(ahat.time_offset_ms), name)


@dataclass
class FitFrame:
    """One sampled frame, independent of any calibration."""

    index: int                 # PV frame index in the recording
    dt: np.ndarray             # (H/2, W/2) uint8: distance to the nearest PV edge (edge_distance)
    pixels: np.ndarray         # (P, 2, 2) int: AHAT (row, col) of both pixels of each discontinuity pair
    raw: np.ndarray            # (P, 2) float: their raw depth


@dataclass
class FitSample:
    frames: list[FitFrame]
    depth_factor: float
    skipped: dict = field(default_factory=dict)   # why frames were left out: reason -> count


@dataclass
class FitScore:
    """The fit of one calibration on a sample: ``score`` (mean over frames of the mean truncated
    distance, PV px; lower fits better), ``spread`` (standard deviation over frames, px), the
    per-frame costs, the registered pairs, and the best global image shift (``offset_px``, (2,) px)
    with its gain over no shift (px)."""

    name: str
    score: float
    spread: float
    per_frame: np.ndarray
    pairs: int
    offset_px: np.ndarray
    offset_gain_px: float

    @property
    def offset_norm_px(self) -> float:
        return float(np.hypot(*self.offset_px))

    def fits(self, cfg: CalibFitConfig) -> bool:
        """Whether the calibration fits: no image shift of more than ``cfg.max_offset_px`` lowers the
        score by more than ``cfg.offset_gain_px``."""
        return not (self.offset_norm_px > cfg.max_offset_px and self.offset_gain_px > cfg.offset_gain_px)

    def to_json(self) -> dict:
        return {"name": self.name, "score_px": self.score, "spread_px": self.spread, "frames": len(self.per_frame),
                "pairs": self.pairs, "offset_px": [float(v) for v in self.offset_px],
                "offset_gain_px": self.offset_gain_px}


# ---------------------------------------------------------------- calibration-free part


def edge_distance(image: np.ndarray, cfg: CalibFitConfig) -> np.ndarray:
    """Distance from the PV pixels to the nearest edge of the frame (RGB or grey uint8), on a grid of
    ``EDGE_DOWNSAMPLE`` x ``EDGE_DOWNSAMPLE`` PV pixels, as uint8 in ``dt_step(cfg)`` PV px, truncated at
    ``cfg.truncate_px``."""
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    d = EDGE_DOWNSAMPLE
    small = cv2.resize(grey, (grey.shape[1] // d, grey.shape[0] // d), interpolation=cv2.INTER_AREA)
    blurred = cv2.GaussianBlur(small, (0, 0), cfg.blur_px / d) if cfg.blur_px > 0 else small
    gx = cv2.Sobel(blurred, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(blurred, cv2.CV_32F, 0, 1, ksize=3)
    hi = float(np.percentile(cv2.magnitude(gx, gy), cfg.edge_percentile))
    edges = cv2.Canny(blurred, max(hi * 0.4, 1.0), max(hi, 2.0), L2gradient=True)
    dist = cv2.distanceTransform(np.where(edges > 0, 0, 255).astype(np.uint8), cv2.DIST_L2, 5) * d
    return np.rint(np.minimum(dist, cfg.truncate_px) / dt_step(cfg)).astype(np.uint8)


def dt_step(cfg: CalibFitConfig) -> float:
    """PV px per unit of the stored distance transforms (255 units span the truncation)."""
    return cfg.truncate_px / 255.0


def depth_discontinuities(raw: np.ndarray, range_per_raw_m: float, alias_m: float, jump_m: float,
                          max_pairs: int) -> tuple[np.ndarray, np.ndarray]:
    """AHAT pixel pairs (P, 2, 2) (row, col) across which the range jumps by more than ``jump_m``
    modulo the alias distance, and their raw values (P, 2); at most ``max_pairs`` (an even stride)."""
    r = raw.astype(np.float32) * np.float32(range_per_raw_m)
    valid = raw > 0
    out_px, out_raw = [], []
    for axis in (1, 0):
        a = r[:, :-1] if axis == 1 else r[:-1]
        b = r[:, 1:] if axis == 1 else r[1:]
        ok = (valid[:, :-1] & valid[:, 1:]) if axis == 1 else (valid[:-1] & valid[1:])
        d = np.mod(b - a + alias_m / 2, alias_m) - alias_m / 2
        rows, cols = np.nonzero(ok & (np.abs(d) > jump_m))
        other = (rows, cols + 1) if axis == 1 else (rows + 1, cols)
        out_px.append(np.stack([np.stack([rows, cols], -1), np.stack(other, -1)], 1))
        out_raw.append(np.stack([raw[rows, cols], raw[other]], -1))
    px = np.concatenate(out_px)
    vals = np.concatenate(out_raw).astype(np.float64)
    if len(px) > max_pairs:
        keep = np.linspace(0, len(px) - 1, max_pairs).round().astype(int)
        px, vals = px[keep], vals[keep]
    return px, vals


def sample_frames(rec, n: int) -> np.ndarray:
    """Up to ``n`` PV frame indices spread evenly over the recording, among the frames with both
    poses valid and an AHAT frame."""
    usable = np.flatnonzero(rec.pv_valid & rec.depth_valid & (np.asarray(rec.depth_timestamps) >= 0))
    if len(usable) <= n:
        return usable
    return usable[np.linspace(0, len(usable) - 1, n).round().astype(int)]


def prepare_fit(rec, cfg: CalibFitConfig, frames: np.ndarray | None = None) -> FitSample:
    """Decode and edge the sampled frames of ``rec`` (``cfg.frames`` of them unless ``frames`` is
    given); frames without a PV image or AHAT frame are counted in ``skipped``."""
    idx = sample_frames(rec, cfg.frames) if frames is None else np.asarray(frames)
    out, skipped = [], {}
    per_raw = rec.depth_factor / rec.ahat.scale
    for i in idx:
        path = rec.pv_path(int(i))
        rgb = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) if path.is_file() else None
        try:
            raw = rec.depth_raw(int(i)) if rgb is not None else None
        except InputError:   # not AHAT depth (reported where the frame is used): leave it out here
            raw = None
        if rgb is None or raw is None:
            why = "no readable PV image" if rgb is None else "no readable AHAT frame"
            skipped[why] = skipped.get(why, 0) + 1
            continue
        px, vals = depth_discontinuities(raw, per_raw, rec.ahat.alias_m, cfg.jump_m, cfg.max_pairs)
        if len(px) == 0:
            skipped["no depth discontinuity"] = skipped.get("no depth discontinuity", 0) + 1
            continue
        out.append(FitFrame(int(i), edge_distance(rgb, cfg), px, vals))
    return FitSample(out, float(rec.depth_factor), skipped)


# ---------------------------------------------------------------- per calibration


def depth_poses_at(rec, frames: np.ndarray, offset_ms: float) -> tuple[np.ndarray, np.ndarray]:
    """AHAT poses of PV frames ``frames`` with the AHAT frame registered ``offset_ms`` later than
    the recording's calibration registers it (interpolated between the recording's AHAT poses)."""
    frames = np.asarray(frames, int)
    delta = offset_ms - float(rec.ahat.time_offset_ms)
    if abs(delta) < 1e-9:
        poses = rec.depth_poses[frames]
        return poses, rec.depth_valid[frames] & pose_validity(poses)
    keys = np.asarray(rec.depth_timestamps, np.int64) + int(round(rec.ahat.time_offset_ms * TICKS_PER_MS))
    ok = rec.depth_valid & (np.asarray(rec.depth_timestamps) >= 0)
    order = np.argsort(keys[ok], kind="stable")
    query = keys[frames] + int(round(delta * TICKS_PER_MS))
    return interpolate_poses(keys[ok][order], rec.depth_poses[ok][order], np.ones(int(ok.sum()), bool), query)


def _hypotheses(frame: FitFrame, cand: FitCandidate, depth_factor: float, cfg: CalibFitConfig,
                to_world: np.ndarray | None, scene) -> np.ndarray:
    """AHAT camera points (P, H, 3) of every pair's occluding edge: on the pair's mid ray (the edge lies
    between the two pixels, not at either centre) at each range hypothesis of either pixel up to
    ``cfg.max_range_m`` (NaN beyond; H = 2K for K alias hypotheses). With a mesh ray-casting ``scene``
    (and the frame's AHAT camera -> world ``to_world``) each pixel keeps one range: the largest
    ``r + k·alias`` not beyond the mesh range along its own ray plus ``cfg.mesh_slack_m`` (the robust
    lift's rule), and the pair keeps the nearer of its two (the occluding side): H = 1, NaN where both
    rays miss the mesh."""
    max_range_m = cfg.max_range_m
    a = cand.ahat
    rows, cols = frame.pixels[..., 0], frame.pixels[..., 1]
    xy = np.asarray(a.uv2xy, np.float64)[rows, cols]                     # (P, 2, 2)
    xy1 = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], -1)
    unit = xy1 / np.linalg.norm(xy1, axis=-1, keepdims=True)
    mid = unit.sum(1)
    mid /= np.linalg.norm(mid, axis=-1, keepdims=True)                   # (P, 3)
    r = frame.raw * (depth_factor / a.scale)                             # (P, 2) wrapped range
    k = np.arange(max(1, int(np.floor(max_range_m / a.alias_m)) + 1))
    rk = r[..., None] + a.alias_m * k                                    # (P, 2, K)
    rk = np.where(rk <= max_range_m, rk, np.nan)
    if scene is not None and to_world is not None:
        limit = _mesh_range(scene, unit.reshape(-1, 3), to_world).reshape(r.shape) + cfg.mesh_slack_m
        below = rk <= limit[..., None]
        last = np.where(below.any(-1), below.shape[-1] - 1 - np.argmax(below[..., ::-1], axis=-1), -1)
        resolved = np.take_along_axis(rk, np.maximum(last, 0)[..., None], -1)[..., 0]   # (P, 2)
        resolved[last < 0] = np.nan
        with warnings.catch_warnings():      # a pair whose rays both miss the mesh: NaN, no warning
            warnings.simplefilter("ignore", RuntimeWarning)
            rk = np.nanmin(resolved, axis=1)[:, None]                    # (P, 1): the occluding side
    else:
        rk = rk.reshape(len(rk), -1)                                     # (P, 2K)
    return mid[:, None, :] * rk[..., None]


def _mesh_range(scene, unit_cam: np.ndarray, to_world: np.ndarray) -> np.ndarray:
    """Range (m) to the mesh along AHAT unit rays (M, 3) of a camera at ``to_world``; inf on a miss."""
    import open3d as o3d

    rays = np.empty((len(unit_cam), 6), np.float32)
    rays[:, :3] = to_world[3, :3]
    rays[:, 3:] = unit_cam @ to_world[:3, :3]
    return scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)


def _sample_dt(dt: np.ndarray, uv: np.ndarray, step: float) -> np.ndarray:
    """Bilinear distance (PV px) at continuous PV points (..., 2) (pixel centres at +0.5); NaN outside."""
    h, w = dt.shape
    s = uv / EDGE_DOWNSAMPLE - 0.5
    inside = (s[..., 0] >= 0) & (s[..., 0] <= w - 1) & (s[..., 1] >= 0) & (s[..., 1] <= h - 1)
    s = np.where(inside[..., None], s, 0.0)
    j0 = np.minimum(s[..., 0].astype(np.int64), w - 2)
    i0 = np.minimum(s[..., 1].astype(np.int64), h - 2)
    tu, tv = s[..., 0] - j0, s[..., 1] - i0
    tu, tv = tu.astype(np.float32), tv.astype(np.float32)
    flat = dt.reshape(-1)
    at = i0 * w + j0
    a, b, c, e = (flat[at].astype(np.float32), flat[at + 1].astype(np.float32), flat[at + w].astype(np.float32),
                  flat[at + w + 1].astype(np.float32))
    v = (1 - tv) * (a + tu * (b - a)) + tv * (c + tu * (e - c))
    return np.where(inside, v * np.float32(step), np.nan)


def _scene(rec, cfg: CalibFitConfig):
    """The recording's mesh ray-casting scene when ``cfg.use_mesh`` and it has a readable mesh, else None."""
    if not cfg.use_mesh or not rec.mesh_paths():
        return None
    try:
        return rec.mesh_scene()
    except Exception:  # an unreadable mesh is reported by info; the score falls back to every hypothesis
        return None


@dataclass
class Registered:
    """A candidate's registered hypotheses on a sample: per frame (P, 2K, 2) PV points (NaN where
    behind the camera or without a pose)."""

    uv: list[np.ndarray]
    frames: list[FitFrame]
    step: float                # PV px per unit of the frames' stored distances


def hypotheses(rec, sample: FitSample, cand: FitCandidate, cfg: CalibFitConfig) -> list[np.ndarray]:
    """Per sampled frame the AHAT camera points (P, 2K, 3) of its discontinuity pairs' hypotheses under
    ``cand`` (mesh-unwrapped with ``cand``'s chain when the recording has a mesh)."""
    idx = np.array([f.index for f in sample.frames], int)
    dposes, dok = depth_poses_at(rec, idx, cand.time_offset_ms)
    to_node = invert_rigid(np.asarray(cand.ahat.extrinsics, np.float64))
    scene = _scene(rec, cfg)
    return [_hypotheses(f, cand, sample.depth_factor, cfg, to_node @ dpose if ok else None, scene)
            for f, dpose, ok in zip(sample.frames, dposes, dok)]


def register(rec, sample: FitSample, cand: FitCandidate, cfg: CalibFitConfig,
             points: list[np.ndarray] | None = None) -> Registered:
    """Every sampled discontinuity hypothesis registered into its PV frame through ``cand``;
    ``points``: the hypotheses (:func:`hypotheses`) to register, kept fixed while a calibration is
    refined (else those of ``cand``)."""
    points = hypotheses(rec, sample, cand, cfg) if points is None else points
    idx = np.array([f.index for f in sample.frames], int)
    dposes, dok = depth_poses_at(rec, idx, cand.time_offset_ms)
    k = np.asarray(cand.pv.intrinsics, np.float64)
    to_node = invert_rigid(np.asarray(cand.ahat.extrinsics, np.float64))
    out = []
    for f, pts, dpose, ok in zip(sample.frames, points, dposes, dok):
        pv_pose = rec.pv_poses[f.index]
        if not ok or not pose_validity(pv_pose):
            out.append(np.full(pts.shape[:-1] + (2,), np.nan))
            continue
        m = to_node @ dpose @ invert_rigid(pv_pose)                     # AHAT camera -> PV camera
        cam = pts @ m[:3, :3] + m[3, :3]
        uvw = cam @ k[:3, :3]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = uvw[..., :2] / uvw[..., 2:3]
        uv[~(-cam[..., 2] > 0.1)] = np.nan                               # PV looks down -z
        out.append(uv)
    return Registered(out, sample.frames, dt_step(cfg))


def _frame_costs(reg: Registered, shifts: np.ndarray | None = None, stride: int = 1) -> tuple[np.ndarray, int]:
    """Per frame the mean over its pairs of the nearest hypothesis' distance (PV px): (F,), or (S, F)
    with every registered point moved by each of ``shifts`` (S, 2); and the pairs scored (unshifted)."""
    n_shift = 1 if shifts is None else len(shifts)
    costs, pairs = np.full((n_shift, len(reg.uv)), np.nan), 0
    for n, (uv, f) in enumerate(zip(reg.uv, reg.frames)):
        q = uv[::stride][None] if shifts is None else uv[::stride][None] + shifts[:, None, None, :]
        d = _sample_dt(f.dt, q, reg.step)                                 # (S, P', H)
        best = np.min(np.where(np.isnan(d), np.inf, d), axis=2)
        ok = np.isfinite(best)
        pairs += int(ok[0].sum())
        with np.errstate(invalid="ignore", divide="ignore"):
            costs[:, n] = np.where(ok, best, 0.0).sum(1) / ok.sum(1)
    return (costs[0] if shifts is None else costs), pairs


SHIFTS_PX = np.array([(r * np.cos(a), r * np.sin(a)) for r in (4.0, 8.0, 16.0)
                      for a in np.radians(np.arange(0, 360, 45))])
"""Image shifts (PV px: 8 directions at 4, 8 and 16 px) tried to find how far a calibration is off
(:attr:`FitScore.offset_px`)."""


def fit_cost(rec, sample: FitSample, cand: FitCandidate, cfg: CalibFitConfig,
             points: list[np.ndarray] | None = None) -> float:
    """The score of ``cand`` alone (no spread, no shift test): what a refinement minimises."""
    costs, _ = _frame_costs(register(rec, sample, cand, cfg, points))
    return float(np.nanmean(costs)) if np.isfinite(costs).any() else float("nan")


def fit_score(rec, sample: FitSample, cand: FitCandidate, cfg: CalibFitConfig) -> FitScore:
    """The fit of ``cand`` on ``sample`` (see the module docstring)."""
    reg = register(rec, sample, cand, cfg)
    per_frame, pairs = _frame_costs(reg)
    good = np.isfinite(per_frame)
    score = float(per_frame[good].mean()) if good.any() else float("nan")
    spread = float(per_frame[good].std()) if good.sum() > 1 else 0.0
    # the global shift test on every 4th pair
    shifted, _ = _frame_costs(reg, np.vstack([np.zeros((1, 2)), SHIFTS_PX]), 4)
    with np.errstate(all="ignore"):
        means = np.nanmean(shifted, axis=1)
    best = int(np.nanargmin(means)) if np.isfinite(means).any() else 0
    best_shift = np.vstack([np.zeros((1, 2)), SHIFTS_PX])[best]
    gain = float(means[0] - means[best]) if np.isfinite(means[best]) else 0.0
    return FitScore(cand.name, score, spread, per_frame, pairs, best_shift, gain)


@dataclass
class Comparison:
    """Frame-by-frame difference of two scores on one sample: ``diff`` (mean of b - a, px; positive:
    ``a`` fits better), its standard error and the frames both scored."""

    diff: float
    stderr: float
    frames: int

    def clearly_worse(self, cfg: CalibFitConfig) -> bool:
        """``b`` fits clearly worse than ``a``: by more than ``cfg.margin_px`` and ``cfg.margin_sigmas``
        standard errors."""
        return self.diff > cfg.margin_px and self.diff > cfg.margin_sigmas * self.stderr


def compare(a: FitScore, b: FitScore) -> Comparison:
    both = np.isfinite(a.per_frame) & np.isfinite(b.per_frame)
    d = (b.per_frame - a.per_frame)[both]
    if len(d) == 0:
        return Comparison(float("nan"), float("nan"), 0)
    se = float(d.std(ddof=1) / np.sqrt(len(d))) if len(d) > 1 else float("inf")
    return Comparison(float(d.mean()), se, int(len(d)))
