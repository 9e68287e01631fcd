"""Lift 2D detections (PV boxes) to 3D observations with AHAT depth (design §3, "Observations").

Two modes, chosen by :class:`LiftConfig` ``mode``:

``reference``
    The public IT3DEgo reference code's rule, reproduced exactly: every AHAT pixel is
    turned into a camera point (raw 0 gives the point 0, and it is *not* removed), all
    262k points are pushed through the static rig chain into the PV image, the integer
    pixel each lands on (truncation, last write wins) gets the point, and a box takes the
    valid pixel closest (L1, in crop-local integers) to its centre. No unwrapping, so
    anything farther than the alias distance (1.055 m) comes out about 1 m (or 2 m...) too
    close to the camera.

``robust`` (default)
    Per box, only the AHAT pixels that can project into it are touched. They are unwrapped
    per pixel with the HoloLens scene mesh (ray cast from the depth camera along the same
    rays: the largest ``r + k·alias`` not beyond the mesh range plus a slack), but never
    beyond the range at which the box would hold an implausibly large object (the size
    prior, ``max_object_size_m``). They are registered into the PV image through the
    per-frame poses (``posed``; accounts for head motion between the two sensors' capture
    times) or the static rig (``static``), and the pixels inside the central part of the
    box vote: the nearest dominant range cluster is the object's visible surface; its
    centroid, pushed back along the ray by a typical half-depth of a small object, is the
    observation.

Both modes keep the alias ambiguity as ``Observations.candidates``: the same ray at ranges
shifted by whole alias distances.

Frames and units: AHAT camera (x right, y down, z forward), world (the recording's),
metres; PV image pixels (1280x720, continuous coordinates, pixel ``i`` covers
``[i, i+1)``). Points are row vectors multiplied on the right (``p_out = p_in @ M``); every
chain comes from :mod:`egograph.geometry.hl2ss`.

Bad inputs never stop the lift: each detection that cannot be lifted is counted under a
reason in :class:`LiftReport`. Detections at a frame of the recording, for a known
instance, stay in the output as unlifted rows (``world`` NaN, ``chosen`` -1); detections at
an unknown timestamp, for an unknown instance, or that are not detections at all, are
dropped (they have no frame / no instance to file them under).

Limitations (robust mode):

* The mesh holds the static scene only. An object resting on or in front of a surface
  reads closer than the mesh along its rays, so "the largest candidate not beyond the mesh
  range (+ slack)" is right for it as long as it is less than about ``alias - slack``
  (0.9 m) in front of that surface.
* An object carried close to the eye (0.3-0.6 m) in front of a far wall would be unwrapped
  towards the wall (wrong by whole alias distances). The size prior catches this when the
  wrong range would make the object larger than ``max_object_size_m`` (a large box); a
  small object carried in front of a wall 1.4-2.5 m away still comes out one alias (about
  1 m) too far. The ``candidates`` keep the right range for the tracker to pick.
* Objects larger than ``max_object_size_m`` are unwrapped too short when far: raise it.
* No depth return (beyond the AHAT's reach, dark surfaces): no observation, counted.
"""

from __future__ import annotations

import math
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from itertools import islice
from pathlib import Path
from typing import Callable, Iterator, Mapping, Sequence, TypeVar

import numpy as np
from tqdm import tqdm

from egograph.core.types import Box, Detection, Prediction
from egograph.geometry.config import MIN_RANGE_M, LiftConfig
from egograph.geometry.hl2ss import (
    INVALID_RAW,
    ahat_project,
    ahat_ray_norms,
    ahat_to_pv_image_static,
    ahat_to_world_matrix,
    invert_rigid,
    pose_validity,
    pv_unproject,
    transform_points,
)
from egograph.geometry.observations import Observations
from egograph.io.detections import write_results_dir

T = TypeVar("T")

REGION_NEAR_M = 0.2        # nearest depth (in front of the PV camera) an object box is searched at
WORLD_UP = np.array([0.0, 1.0, 0.0], np.float32)  # HoloLens world frames are gravity aligned, y up
REGION_PAD_PX = 2          # AHAT pixels added around the searched rectangle (pixel footprint, rounding)
MAX_PINHOLE_RESIDUAL_PX = 32.0  # beyond this the pinhole intrinsics are useless: search the whole frame




# --------------------------------------------------------------------------- report

SKIP_REASONS = {
    "unknown_timestamp": "timestamp is not a frame of the recording",
    "unknown_instance": "instance id beyond labels.csv",
    "malformed": "not a detection with a box",
    "empty_box": "box has zero area",
    "box_outside_image": "box lies entirely outside the PV image",
    "invalid_pose": "NaN/invalid depth pose (or PV pose, for posed registration)",
    "no_depth_frame": "depth frame missing or unreadable",
    "no_depth_pixels": "too few valid depth pixels register into the box",
    "no_dominant_cluster": "no depth cluster holds enough of the box's pixels",
}


@dataclass
class SkipExample:
    reason: str
    timestamp: int | None
    instance: int | None
    detail: str = ""


@dataclass
class LiftReport:
    """What the lift did: detections seen and lifted, skips per reason with a few examples."""

    mode: str
    n_detections: int = 0
    n_lifted: int = 0
    n_frames: int = 0                      # frames whose depth was read
    skipped: dict[str, int] = field(default_factory=dict)
    examples: list[SkipExample] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0                   # whole lift, wall clock
    setup_seconds: float = 0.0             # of which per-recording set-up (rays, mesh ray-casting scene)
    examples_per_reason: int = 3

    def skip(self, reason: str, ts: int | None, instance: int | None, detail: str = "", count: int = 1) -> None:
        assert reason in SKIP_REASONS, reason
        seen = self.skipped.get(reason, 0)
        self.skipped[reason] = seen + count
        if seen < self.examples_per_reason:
            self.examples.append(SkipExample(reason, ts, instance, detail))

    @property
    def n_skipped(self) -> int:
        return sum(self.skipped.values())

    def summary(self) -> str:
        lines = [f"lift ({self.mode}): {self.n_lifted} of {self.n_detections} detections lifted "
                 f"over {self.n_frames} depth frames in {self.seconds:.1f} s (set-up {self.setup_seconds:.1f} s); "
                 f"{self.n_skipped} skipped"]
        for reason, n in sorted(self.skipped.items(), key=lambda kv: -kv[1]):
            lines.append(f"  {n:6d}  {reason}: {SKIP_REASONS[reason]}")
            for ex in self.examples:
                if ex.reason == reason:
                    what = f"ts {ex.timestamp}" + (f", instance {ex.instance}" if ex.instance is not None else "")
                    lines.append(f"            e.g. {what}" + (f" ({ex.detail})" if ex.detail else ""))
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


# --------------------------------------------------------------------------- small geometry helpers

def shrink_box(box: np.ndarray, share: float) -> np.ndarray:
    """(x1, y1, x2, y2) -> the box with ``share`` of its width and height, same centre (pixels)."""
    c = 0.5 * (box[:2] + box[2:])
    half = 0.5 * share * (box[2:] - box[:2])
    return np.concatenate([c - half, c + half])


def nearest_dominant_cluster(ranges: np.ndarray, gap_m: float, min_share: float, min_pixels: int) -> np.ndarray | None:
    """Indices of the nearest range cluster holding enough pixels, or None.

    Sorted ranges (metres) are split where consecutive values differ by more than
    ``gap_m``; the first cluster (nearest the camera) with at least ``min_share`` of all
    pixels and at least ``min_pixels`` wins. Nearest, because an object occludes what is
    behind it; dominant, because flying pixels and speckle form small clusters anywhere.
    """
    n = len(ranges)
    if n == 0:
        return None
    order = np.argsort(ranges, kind="stable")
    labels = np.zeros(n, np.int64)
    labels[1:] = np.cumsum(np.diff(ranges[order]) > gap_m)
    counts = np.bincount(labels)
    good = np.flatnonzero(counts >= max(min_pixels, math.ceil(min_share * n)))
    if len(good) == 0:
        return None
    return order[labels == good[0]]


def alias_shifts(range_m: float, alias_m: float, k: int, max_range_m: float) -> np.ndarray:
    """Whole-alias shifts m (ints, ascending) of a range kept as candidates ``range + m·alias``.

    All m with the shifted range in ``(0.1, max_range_m]`` (always including m = 0), at
    most ``k`` of them, the ones with the smallest ``|m|`` (ties: the nearer range).
    """
    lo = math.floor((MIN_RANGE_M - range_m) / alias_m) + 1
    hi = math.floor((max_range_m - range_m) / alias_m)
    ms = np.arange(min(lo, 0), max(hi, 0) + 1)
    keep = ms[np.lexsort((ms, np.abs(ms)))][:k]
    return np.sort(keep)


def _pinhole_residual(uv2xy: np.ndarray, intrinsics: np.ndarray) -> float:
    """Largest distance (AHAT pixels) between a pixel centre and its ray projected with the pinhole intrinsics."""
    h, w = uv2xy.shape[:2]
    rays = np.concatenate([uv2xy, np.ones((h, w, 1), uv2xy.dtype)], axis=-1)
    uv, _ = ahat_project(rays, intrinsics)
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    err = np.hypot(uv[..., 0] - u, uv[..., 1] - v)
    err = err[np.isfinite(err)]
    return float(err.max()) if err.size else math.inf


# --------------------------------------------------------------------------- per-recording context

@dataclass
class _Frame:
    """Per-frame matrices (row vectors): AHAT camera -> world, -> PV camera, -> PV image; PV camera -> AHAT camera."""

    ahat_to_world: np.ndarray
    ahat_to_pvcam: np.ndarray
    ahat_to_pvimg: np.ndarray
    pvcam_to_ahat: np.ndarray


@dataclass
class _Context:
    rec: object
    cfg: LiftConfig
    alias_m: float
    m_per_raw: float                 # metres of range per raw unit (depth_factor / scale)
    dirs: np.ndarray | None = None   # (H, W, 3) float32 unit ray directions, AHAT camera (robust)
    xy1: np.ndarray | None = None    # (H, W, 3) float64 [uv2xy, 1] (reference)
    norms: np.ndarray | None = None  # (H, W) float64 ‖[uv2xy, 1]‖ (reference)
    pad_px: int | None = None        # region padding (AHAT px); None = search the whole frame
    raycaster: object | None = None  # open3d.t.geometry.RaycastingScene of the HoloLens mesh


def mesh_scene(mesh):
    """An Open3D ``RaycastingScene`` of a legacy triangle mesh (the HoloLens scene mesh, world
    frame), or None without a mesh or triangles."""
    if mesh is None or len(mesh.triangles) == 0:
        return None
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return scene


def _mesh_raycaster(rec, report: LiftReport):
    """A RaycastingScene of the recording's mesh (built once per recording), or None with a note."""
    # An unreadable mesh (or no open3d) must not stop the lift; it only loses the unwrapping.
    try:
        scene = mesh_scene(rec.mesh())
        if scene is None:
            report.notes.append("no mesh; alias taken as read (k = 0)")
        return scene
    except (ImportError, ValueError, OSError, RuntimeError) as exc:
        report.notes.append(f"mesh unusable ({exc}); alias taken as read (k = 0)")
        return None


def _context(rec, cfg: LiftConfig, report: LiftReport) -> _Context:
    ahat = rec.ahat
    ctx = _Context(rec, cfg, alias_m=float(ahat.alias_m), m_per_raw=float(rec.depth_factor) / float(ahat.scale))
    if cfg.mode == "reference":
        uv2xy = np.asarray(ahat.uv2xy)
        ctx.xy1 = np.concatenate([uv2xy, np.ones(uv2xy.shape[:-1] + (1,), uv2xy.dtype)], axis=-1).astype(np.float64)
        ctx.norms = ahat_ray_norms(uv2xy.astype(np.float64))
        return ctx
    uv2xy = np.asarray(ahat.uv2xy, dtype=np.float64)
    norms = ahat_ray_norms(uv2xy)
    rays = np.concatenate([uv2xy, np.ones(uv2xy.shape[:-1] + (1,))], axis=-1)
    ctx.dirs = (rays / norms[..., None]).astype(np.float32)
    residual = _pinhole_residual(uv2xy, ahat.intrinsics)
    if residual <= MAX_PINHOLE_RESIDUAL_PX:
        ctx.pad_px = int(math.ceil(residual)) + REGION_PAD_PX
    else:
        report.notes.append(f"AHAT pinhole intrinsics off by {residual:.0f} px; "
                            "every box searches the whole depth frame")
    if cfg.use_mesh:
        ctx.raycaster = _mesh_raycaster(rec, report)
    else:
        report.notes.append("use_mesh false; alias taken as read (k = 0)")
    return ctx


def _frame_matrices(ctx: _Context, i: int) -> _Frame | None:
    """The frame's chains, or None when a pose it needs is invalid."""
    rec, cfg = ctx.rec, ctx.cfg
    depth_pose = rec.depth_poses[i]
    if not (rec.depth_valid[i] and pose_validity(depth_pose)):
        return None
    to_world = ahat_to_world_matrix(rec.ahat.extrinsics, depth_pose)
    if cfg.mode == "robust" and cfg.registration == "posed":
        pv_pose = rec.pv_poses[i]
        if not (rec.pv_valid[i] and pose_validity(pv_pose)):
            return None
        to_pvcam = to_world @ invert_rigid(pv_pose)
    else:
        to_pvcam = invert_rigid(rec.ahat.extrinsics) @ np.asarray(rec.pv.extrinsics, dtype=np.float64)
    return _Frame(to_world, to_pvcam, to_pvcam @ np.asarray(rec.pv.intrinsics, dtype=np.float64),
                  invert_rigid(to_pvcam))


# --------------------------------------------------------------------------- reference mode

def reference_depth_map(raw: np.ndarray, xy1: np.ndarray, norms: np.ndarray, scale: float, depth_factor: float,
                        ahat_to_pv_image: np.ndarray, pv_shape: tuple[int, int]) -> np.ndarray:
    """The reference code's AHAT -> PV registration: (rows, cols, 3) float32 map of AHAT camera points.

    Every pixel, raw 0 included (its point is 0 and it still overwrites whatever landed on
    its PV pixel before), is projected with ``ahat_to_pv_image``; the PV pixel is the
    truncated ``uv``; with several points per pixel the last one written wins.
    """
    h, w = pv_shape
    z = raw / (norms * scale / depth_factor)
    xyz = (xy1 * z[..., None]).reshape(-1, 3)
    xyz1 = np.concatenate([xyz, np.ones((len(xyz), 1))], axis=1)
    p = xyz1 @ ahat_to_pv_image
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = p[:, :2] / p[:, 2:3]
        u = uv[:, 0].astype(int)  # truncation towards zero, as the reference code
        v = uv[:, 1].astype(int)
    keep = (u >= 0) & (u < w) & (v >= 0) & (v < h) & np.isfinite(uv).all(axis=1)
    out = np.zeros((h, w, 3), np.float32)
    out[v[keep], u[keep]] = xyz[keep]
    return out


def reference_pick(depth_map: np.ndarray, box: Sequence[float]) -> tuple[np.ndarray, int] | None:
    """The reference code's choice of one AHAT point for a box (x1, y1, x2, y2), PV pixels.

    In the crop ``map[int(y1):int(y2), int(x1):int(x2)]``, among pixels with non-zero z, the
    first (row-major) minimising ``|row - int((y2-y1)/2)| + |col - int((x2-x1)/2)|``
    (crop-local). Returns (AHAT camera point (3,), pixels with depth in the crop), or None.
    """
    x1, y1, x2, y2 = box
    crop = depth_map[int(y1):int(y2), int(x1):int(x2)]
    rows, cols = np.nonzero(crop[..., 2] != 0)
    if len(rows) == 0:
        return None
    dist = np.abs(rows - int((y2 - y1) / 2)) + np.abs(cols - int((x2 - x1) / 2))
    j = int(np.argmin(dist))
    return crop[rows[j], cols[j]].astype(np.float64), len(rows)


# --------------------------------------------------------------------------- robust mode

def _ahat_region(ctx: _Context, frame: _Frame, box: np.ndarray, reach_m: float) -> tuple[int, int, int, int]:
    """AHAT pixel rectangle (r0, r1, c0, c1) whose points can project into ``box`` (PV pixels).

    The box corners are back-projected at the nearest and farthest depths an object can
    have (``reach_m``, or the alias distance: an unwrapped reading is never farther than
    that); the segments between them project (pinhole) into a convex region of the AHAT
    image bounded by the projections of their end points. The pinhole residual of the
    real (distorted) rays plus a pixel is added around it.
    """
    h, w = ctx.rec.ahat.uv2xy.shape[:2]
    if ctx.pad_px is None:
        return 0, h, 0, w
    x1, y1, x2, y2 = box
    corners = np.array([[x1, y1], [x2, y1], [x1, y2], [x2, y2]], dtype=np.float64)
    pv_pts = np.concatenate([pv_unproject(corners, np.full(4, d), ctx.rec.pv.intrinsics)
                             for d in (REGION_NEAR_M, max(reach_m, ctx.alias_m) + 0.1)])
    cam = transform_points(pv_pts, frame.pvcam_to_ahat)
    if (cam[:, 2] <= 0.05).any():  # a corner ray passes behind the AHAT camera: no bound from it
        return 0, h, 0, w
    uv, _ = ahat_project(cam, ctx.rec.ahat.intrinsics)
    pad = ctx.pad_px
    c0 = max(int(math.floor(uv[:, 0].min())) - pad, 0)
    c1 = min(int(math.ceil(uv[:, 0].max())) + pad, w)
    r0 = max(int(math.floor(uv[:, 1].min())) - pad, 0)
    r1 = min(int(math.ceil(uv[:, 1].max())) + pad, h)
    return r0, max(r1, r0), c0, max(c1, c0)


def _alias_count(ctx: _Context) -> int:
    """Whole aliases k = 0..n-1 a reading may be off by: all within max_range_m with a mesh, only 0 without."""
    if ctx.raycaster is None:
        return 1
    return int(math.floor(ctx.cfg.max_range_m / ctx.alias_m)) + 1


def _in_box_per_alias(ctx: _Context, frame: _Frame, dirs: np.ndarray, ranges: np.ndarray,
                      sbox: np.ndarray, reach_m: float) -> np.ndarray:
    """(n_k, N) bool: pixel n at range ``ranges[n] + k·alias`` registers inside ``sbox``.

    Unwrapped ranges beyond ``reach_m`` are out (k = 0, the reading itself, always stays in).
    ``dirs`` are unit AHAT camera rays, ``ranges`` wrapped readings (metres). The PV image
    coordinates are affine in the range along a ray, so one product per pixel serves every k.
    """
    m = frame.ahat_to_pvimg.astype(np.float32)
    per_metre = dirs @ m[:3, :3]                                              # (N, 3)
    ks = np.arange(_alias_count(ctx), dtype=np.float32)
    r = ranges[None, :] + ks[:, None] * np.float32(ctx.alias_m)               # (n_k, N)
    w = r * per_metre[:, 2] + m[3, 2]
    nu = r * per_metre[:, 0] + m[3, 0]
    nv = r * per_metre[:, 1] + m[3, 1]
    x1, y1, x2, y2 = (np.float32(c) for c in sbox)
    # PV cameras look down -z: in front means w = z_pv < 0, and then x1 <= nu / w < x2
    # reads nu <= x1·w and nu > x2·w (no division needed).
    allowed = (r <= np.float32(reach_m)) | (ks[:, None] == 0)
    return (allowed & (w < 0) & (nu <= x1 * w) & (nu > x2 * w)
            & (nv <= y1 * w) & (nv > y2 * w))


def _mesh_alias(ctx: _Context, frame: _Frame, dirs: np.ndarray, ranges: np.ndarray, reach_m: float) -> np.ndarray:
    """Whole aliases k (int, per pixel) to add: the largest r + k·alias not beyond mesh range + slack
    (nor beyond ``reach_m``).

    The mesh is ray cast from the depth camera along the same (unit) rays, so ``t_hit``
    is the mesh range (metres). No mesh, or a ray missing it: k = 0.
    """
    if ctx.raycaster is None or len(ranges) == 0:
        return np.zeros(len(ranges), np.intp)
    import open3d as o3d

    rays = np.empty((len(dirs), 6), np.float32)
    rays[:, :3] = frame.ahat_to_world[3, :3]
    rays[:, 3:] = dirs @ frame.ahat_to_world[:3, :3].astype(np.float32)
    mesh_range = ctx.raycaster.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    alias = np.float32(ctx.alias_m)
    k_max = np.floor((np.float32(reach_m) - ranges) / alias)
    with np.errstate(invalid="ignore"):
        k = np.floor((mesh_range + np.float32(ctx.cfg.mesh_slack_m) - ranges) / alias)
    k = np.where(np.isfinite(mesh_range), np.clip(k, 0, np.maximum(k_max, 0)), 0)
    return k.astype(np.intp)


def box_reach(box: np.ndarray, pv_intrinsics: np.ndarray, max_object_size_m: float, max_range_m: float) -> float:
    """Farthest range (metres) an object seen as ``box`` (PV pixels) can be at and still be small.

    The box spans ``a = max(width / fx, height / fy)`` (tangent units), so at range r the
    object is about ``a·r`` across; beyond ``max_object_size_m / a`` it would be too big.
    """
    k = np.asarray(pv_intrinsics, dtype=np.float64)
    span = max((box[2] - box[0]) / abs(k[0, 0]), (box[3] - box[1]) / abs(k[1, 1]))
    return float(min(max_range_m, max_object_size_m / span)) if span > 0 else float(max_range_m)


def _box_point(ctx: _Context, frame: _Frame, dirs: np.ndarray, ranges: np.ndarray, sbox: np.ndarray,
               reach_m: float) -> tuple[np.ndarray, int] | str:
    """Unwrap, register and cluster candidate pixels (unit rays, wrapped ranges) for one range limit.

    Only pixels that land in the shrunk box for some alias k are ray cast against the
    mesh; each is then kept if it lands there at the k the mesh chooses.
    """
    cfg = ctx.cfg
    inbox = _in_box_per_alias(ctx, frame, dirs, ranges, sbox, reach_m)
    cand = np.flatnonzero(inbox.any(axis=0))
    k = _mesh_alias(ctx, frame, dirs[cand], ranges[cand], reach_m)
    keep = inbox[k, cand]
    sel = cand[keep]
    if len(sel) < cfg.min_pixels:
        return "no_depth_pixels"
    unwrapped = ranges[sel] + k[keep].astype(np.float32) * np.float32(ctx.alias_m)
    idx = nearest_dominant_cluster(unwrapped, cfg.cluster_gap_m, cfg.min_cluster_share, cfg.min_pixels)
    if idx is None:
        return "no_dominant_cluster"
    surface = (dirs[sel[idx]] * unwrapped[idx, None]).astype(np.float64).mean(axis=0)
    # The mean of surface points sits on the visible face; the centre is behind it.
    point = surface * (1.0 + cfg.surface_to_center_m / np.linalg.norm(surface))
    return point, len(idx)


def _supported(ctx: _Context, frame: _Frame, point: np.ndarray) -> bool:
    """Does a mesh surface lie within ``max_support_gap_m`` below ``point`` (AHAT camera)?"""
    import open3d as o3d

    ray = np.zeros((1, 6), np.float32)
    ray[0, :3] = transform_points(point, frame.ahat_to_world)
    ray[0, 3:] = -WORLD_UP
    t = float(ctx.raycaster.cast_rays(o3d.core.Tensor(ray))["t_hit"].numpy()[0])
    return t <= ctx.cfg.max_support_gap_m


def robust_box_point(ctx: _Context, raw: np.ndarray, frame: _Frame, box: np.ndarray) -> tuple[np.ndarray, int] | str:
    """The object point (AHAT camera, metres) behind a PV box and its pixel support, or a skip reason.

    Objects either rest on a surface or are carried. When the mesh-unwrapped point floats
    (no surface below it) beyond hand reach, it is taken for a carried object unwrapped
    onto the background, and the box is lifted again with unwrapping capped at hand reach.
    """
    cfg = ctx.cfg
    sbox = shrink_box(box, cfg.shrink)
    reach = box_reach(box, ctx.rec.pv.intrinsics, cfg.max_object_size_m, cfg.max_range_m)
    r0, r1, c0, c1 = _ahat_region(ctx, frame, box, reach)
    sub = raw[r0:r1, c0:c1]
    valid = sub != INVALID_RAW
    if np.count_nonzero(valid) < cfg.min_pixels:
        return "no_depth_pixels"
    ranges = sub[valid].astype(np.float32) * np.float32(ctx.m_per_raw)
    dirs = ctx.dirs[r0:r1, c0:c1][valid]
    res = _box_point(ctx, frame, dirs, ranges, sbox, reach)
    if (isinstance(res, tuple) and ctx.raycaster is not None and 0 < cfg.hand_reach_m < reach
            and np.linalg.norm(res[0]) > cfg.hand_reach_m and not _supported(ctx, frame, res[0])):
        near = _box_point(ctx, frame, dirs, ranges, sbox, cfg.hand_reach_m)
        if isinstance(near, tuple):
            return near
    return res


# --------------------------------------------------------------------------- rows

class _Rows:
    """Column lists of the Observations being built."""

    def __init__(self, k: int):
        self.k = k
        self.cols: dict[str, list] = {n: [] for n in ("timestamps", "frame", "instance", "score", "box", "world",
                                                     "camera", "range_m", "candidates", "chosen", "n_pixels")}

    def add(self, ts: int, frame: int, det: Detection, world=None, camera=None, range_m=np.nan,
            candidates=None, chosen=-1, n_pixels=0) -> None:
        c = self.cols
        c["timestamps"].append(ts)
        c["frame"].append(frame)
        c["instance"].append(det.instance)
        c["score"].append(det.score)
        c["box"].append((det.box.x_min, det.box.y_min, det.box.x_max, det.box.y_max))
        c["world"].append(np.full(3, np.nan) if world is None else world)
        c["camera"].append(np.full(3, np.nan) if camera is None else camera)
        c["range_m"].append(range_m)
        c["candidates"].append(np.full((self.k, 3), np.nan) if candidates is None else candidates)
        c["chosen"].append(chosen)
        c["n_pixels"].append(n_pixels)

    def build(self) -> Observations:
        c = self.cols
        if not c["timestamps"]:
            return Observations.empty(self.k)
        return Observations(
            timestamps=np.asarray(c["timestamps"], np.int64), frame=np.asarray(c["frame"], np.int32),
            instance=np.asarray(c["instance"], np.int32), score=np.asarray(c["score"], np.float32),
            box=np.asarray(c["box"], np.float32), world=np.asarray(c["world"], np.float64),
            camera=np.asarray(c["camera"], np.float64), range_m=np.asarray(c["range_m"], np.float32),
            candidates=np.asarray(c["candidates"], np.float64), chosen=np.asarray(c["chosen"], np.int8),
            n_pixels=np.asarray(c["n_pixels"], np.int32))


def _add_lifted(rows: _Rows, ctx: _Context, frame: _Frame, ts: int, i: int, det: Detection,
                point: np.ndarray, n_pixels: int, shifts: np.ndarray) -> None:
    """One lifted row: ``point`` (AHAT camera) to world, with candidates along its ray at ``shifts`` aliases."""
    r = float(np.linalg.norm(point))
    ranges = r + shifts * ctx.alias_m
    cands = np.full((rows.k, 3), np.nan)
    cands[:len(shifts)] = transform_points(point[None, :] * (ranges / r)[:, None], frame.ahat_to_world)
    chosen = int(np.flatnonzero(shifts == 0)[0])
    rows.add(ts, i, det, world=cands[chosen].copy(), camera=frame.ahat_to_world[3, :3].copy(), range_m=r,
             candidates=cands, chosen=chosen, n_pixels=n_pixels)


# --------------------------------------------------------------------------- validation

def _labels_count(rec, report: LiftReport) -> int | None:
    """Instances in the recording's labels.csv, or None (no annotations, or unreadable: noted)."""
    ann = getattr(rec, "annotation_dir", None)
    if ann is None or not (Path(ann) / "labels.csv").is_file():
        return None
    from egograph.core.errors import InputError
    from egograph.io.annotations import read_labels

    try:
        return len(read_labels(Path(ann) / "labels.csv"))
    except InputError as exc:
        report.notes.append(f"instance ids not checked: {exc}")
        return None


def _usable_box(det, pv_shape: tuple[int, int], ts: int, report: LiftReport) -> np.ndarray | None:
    """The detection's box clipped to the PV image (x1, y1, x2, y2), or None (counted)."""
    b = det.box
    if not (b.x_max > b.x_min and b.y_max > b.y_min):
        report.skip("empty_box", ts, det.instance, f"box {b.x_min:g} {b.y_min:g} {b.x_max:g} {b.y_max:g}")
        return None
    clipped = b.clip(pv_shape[1], pv_shape[0])
    if clipped is None:
        report.skip("box_outside_image", ts, det.instance, f"box {b.x_min:g} {b.y_min:g} {b.x_max:g} {b.y_max:g}")
        return None
    return np.array([clipped.x_min, clipped.y_min, clipped.x_max, clipped.y_max])


def _frames_to_lift(rec, detections: Mapping[int, Sequence[Detection]], n_instances: int | None,
                    report: LiftReport) -> list[tuple[int, int, list[Detection]]]:
    """(frame index, timestamp, detections) per frame, in frame order; unknown ts/instance counted and dropped."""
    out = []
    for ts, dets in detections.items():
        dets = list(dets or ())
        if not dets:
            continue
        report.n_detections += len(dets)
        try:
            ts = int(ts)
            i = rec.index_of(ts)
        except (KeyError, TypeError, ValueError):
            report.skip("unknown_timestamp", ts if isinstance(ts, int) else None, None,
                        f"{len(dets)} detection(s) at {ts!r}", count=len(dets))
            continue
        keep = []
        for d in dets:
            if not isinstance(d, Detection) or not isinstance(d.box, Box):
                report.skip("malformed", ts, None, f"{type(d).__name__}")
            elif n_instances is not None and d.instance >= n_instances:
                report.skip("unknown_instance", ts, d.instance, f"{n_instances} instances in labels.csv")
            else:
                keep.append(d)
        if keep:
            out.append((i, ts, keep))
    out.sort(key=lambda x: x[0])
    return out


# --------------------------------------------------------------------------- driver

def lift_recording(rec, detections: dict[int, list[Detection]], cfg: LiftConfig, progress: bool = True,
                   n_instances: int | None = None) -> tuple[Observations, LiftReport]:
    """Lift every detection of a recording to a 3D observation (world frame, metres).

    ``detections`` maps PV timestamps to that frame's detections (as
    :func:`~egograph.io.detections.read_detection_dir` returns). ``n_instances`` bounds
    the instance ids; None reads it from the recording's ``labels.csv`` when it has
    annotations (no bound otherwise). Rows come out in frame order, detections in file
    order within a frame. Never raises on bad data: see the module doc and the report.
    """
    cfg.check()
    t0 = time.perf_counter()
    report = LiftReport(mode=cfg.mode)
    if n_instances is None:
        n_instances = _labels_count(rec, report)
    frames = _frames_to_lift(rec, detections, n_instances, report)
    ctx = _context(rec, cfg, report)
    report.setup_seconds = time.perf_counter() - t0
    rows = _Rows(cfg.n_candidates)
    # Plan first (boxes, poses: cheap) so the depth frames that will be needed can be
    # decoded ahead, on the other core, while the current frame is lifted.
    plan = []
    for i, ts, dets in frames:
        boxes = [_usable_box(d, rec.pv.shape, ts, report) for d in dets]
        frame = None
        if any(b is not None for b in boxes):
            frame = _frame_matrices(ctx, i) or "invalid_pose"
        plan.append((i, ts, dets, boxes, frame))
    depth = prefetched(rec.depth_raw, [p[0] for p in plan if isinstance(p[4], _Frame)],
                       PREFETCH_PER_THREAD * cfg.decode_threads, cfg.decode_threads)
    bar = tqdm(plan, desc=f"lift ({cfg.mode})", unit="frame", disable=not progress, mininterval=1.0)
    for i, ts, dets, boxes, frame in bar:
        state = _frame_state(ctx, frame, next(depth)[1]) if isinstance(frame, _Frame) else frame
        if isinstance(state, _FrameDepth):
            report.n_frames += 1
        for d, box in zip(dets, boxes):
            if box is None:  # already counted
                rows.add(ts, i, d)
            elif isinstance(state, str):
                report.skip(state, ts, d.instance, SKIP_DETAILS.get(state, ""))
                rows.add(ts, i, d)
            else:
                _lift_one(ctx, state, ts, i, d, box, rows, report)
    report.seconds = time.perf_counter() - t0
    return rows.build(), report


SKIP_DETAILS = {"no_depth_frame": "missing or unreadable depth_ahat png"}
PREFETCH_PER_THREAD = 3  # depth frames decoded ahead per decoding thread (512 KB each)
_END = object()


def prefetched(load: Callable[[int], T], keys: Sequence[int], ahead: int, threads: int = 1
               ) -> Iterator[tuple[int, T]]:
    """``(key, load(key))`` in order, with up to ``ahead`` loads running on ``threads`` background threads.

    PNG decoding (OpenCV) releases the GIL, so on other cores it overlaps with the numpy
    work of the frame being lifted (and, with two threads, with the next frame's decode).
    """
    if not keys:
        return
    with ThreadPoolExecutor(max_workers=threads) as pool:
        todo = iter(keys)
        pending = deque((k, pool.submit(load, k)) for k in islice(todo, ahead))
        while pending:
            key, fut = pending.popleft()
            nxt = next(todo, _END)
            if nxt is not _END:
                pending.append((nxt, pool.submit(load, nxt)))
            yield key, fut.result()


@dataclass
class _FrameDepth:
    """What a frame's detections are lifted from: its chains, its raw depth, and (reference) its PV depth map."""

    frame: _Frame
    raw: np.ndarray
    depth_map: np.ndarray | None = None


def _frame_state(ctx: _Context, frame: _Frame, raw: np.ndarray | None) -> _FrameDepth | str:
    """A frame's chains and depth, or the reason none of its detections can be lifted."""
    if raw is None:
        return "no_depth_frame"
    out = _FrameDepth(frame, raw)
    if ctx.cfg.mode == "reference":
        rec = ctx.rec
        # The reference code registers through the static rig whatever the config says.
        to_img = ahat_to_pv_image_static(rec.ahat.extrinsics, rec.pv.extrinsics, rec.pv.intrinsics)
        out.depth_map = reference_depth_map(raw, ctx.xy1, ctx.norms, float(rec.ahat.scale), float(rec.depth_factor),
                                            to_img, rec.pv.shape)
    return out


def _lift_one(ctx: _Context, state: _FrameDepth, ts: int, i: int, det: Detection, box: np.ndarray, rows: _Rows,
              report: LiftReport) -> None:
    """Lift one detection (box clipped to the image) and add its row, lifted or not."""
    cfg = ctx.cfg
    if cfg.mode == "reference":
        picked = reference_pick(state.depth_map, box)
        if picked is None:
            report.skip("no_depth_pixels", ts, det.instance, "no pixel with depth in the box")
            rows.add(ts, i, det)
            return
        point, n = picked[0], 1
        shifts = np.arange(cfg.n_candidates)  # r + k·alias, k = 0..K-1, chosen k = 0
    else:
        res = robust_box_point(ctx, state.raw, state.frame, box)
        if isinstance(res, str):
            report.skip(res, ts, det.instance)
            rows.add(ts, i, det)
            return
        point, n = res
        shifts = alias_shifts(float(np.linalg.norm(point)), ctx.alias_m, cfg.n_candidates, cfg.max_range_m)
    _add_lifted(rows, ctx, state.frame, ts, i, det, point, n, shifts)
    report.n_lifted += 1


# --------------------------------------------------------------------------- output

def write_lifted_dir(path: str | Path, obs: Observations, timestamps: Sequence[int]) -> None:
    """The reference "lifted" format: one ``<ts>.txt`` per PV frame, rows ``instance x y z score``.

    Only lifted rows are written (world frame, metres); frames without any get an empty file.
    """
    per_frame: dict[int, list[Prediction]] = {}
    for j in np.flatnonzero(obs.valid):
        per_frame.setdefault(int(obs.timestamps[j]), []).append(
            Prediction(int(obs.instance[j]), tuple(float(x) for x in obs.world[j]), float(obs.score[j])))
    write_results_dir(path, per_frame, [int(t) for t in timestamps])


# --------------------------------------------------------------------------- synthetic truth

def synth_lift_errors(rec, obs: Observations, detection_set: str) -> tuple[np.ndarray, np.ndarray]:
    """Per observation row: 3D error (metres, NaN when not lifted) against the synthetic truth, and is-true.

    Joins ``synth_gt/<seq>/detections_<set>.txt`` (``ts instance is_false ...``) with the
    true object centres ``instances.npz['positions']`` at the detection's PV frame. Rows
    of false detections get is-true False (their error is to the instance's true centre).
    """
    gt = rec.synth_gt_dir
    if gt is None:
        raise ValueError(f"{rec.seq_dir}: not a synthetic recording (no synth_gt/)")
    is_false: dict[tuple[int, int], bool] = {}
    for line in (gt / f"detections_{detection_set}.txt").read_text().splitlines():
        tok = line.split()
        if tok and not tok[0].startswith("#"):
            is_false[(int(tok[0]), int(tok[1]))] = tok[2] != "0"
    with np.load(gt / "instances.npz") as data:
        positions = data["positions"]
    truth = positions[obs.frame, obs.instance]
    err = np.linalg.norm(obs.world - truth, axis=1)
    true = np.array([not is_false.get((int(t), int(k)), True) for t, k in zip(obs.timestamps, obs.instance)], bool)
    return err, true
