"""The ``robust`` lifting mode (default): mesh-unwrapped, clustered box depth.

Per box, only the AHAT pixels that can project into it are touched. They are unwrapped per
pixel with the HoloLens scene mesh (ray cast from the depth camera along the same rays: the
largest ``r + k·alias`` not beyond the mesh range plus a slack), but never beyond the range at
which the box would hold an implausibly large object (the size prior, ``max_object_size_m``).
They are registered into the PV image through the per-frame poses (``posed``; accounts for
head motion between the two sensors' capture times) or the static rig (``static``), and the
pixels inside the central part of the box vote: the nearest dominant range cluster is the
object's visible surface; its centroid, pushed back along the ray by a typical half-depth of a
small object, is the observation.

Frames and units: AHAT camera (x right, y down, z forward), world (the recording's), metres;
PV image pixels (1280x720, continuous coordinates, pixel ``i`` covers ``[i, i+1)``). Driven by
:func:`egograph.geometry.lift.lift_recording`.

Limitations:

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
from dataclasses import dataclass

import numpy as np

from egograph.core import signals
from egograph.geometry.ahat_model import pixel_lookup
from egograph.geometry.chains import FrameChains
from egograph.geometry.config import MIN_RANGE_M, LiftConfig
from egograph.geometry.hl2ss import (
    INVALID_RAW,
    ahat_project,
    ahat_unit_rays,
    ahat_xy1,
    pv_unproject,
    transform_points,
)

REGION_NEAR_M = 0.2        # nearest depth (in front of the PV camera) an object box is searched at
WORLD_UP = np.array([0.0, 1.0, 0.0], np.float32)  # HoloLens world frames are gravity aligned, y up
REGION_PAD_PX = 2          # AHAT pixels added around the searched rectangle (pixel footprint, rounding)
MAX_PINHOLE_RESIDUAL_PX = 32.0  # beyond this the pinhole intrinsics are useless: search the whole frame


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
    uv, _ = ahat_project(ahat_xy1(uv2xy), intrinsics)
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    err = np.hypot(uv[..., 0] - u, uv[..., 1] - v)
    err = err[np.isfinite(err)]
    return float(err.max()) if err.size else math.inf


# --------------------------------------------------------------------------- per-recording context

@dataclass
class RobustContext:
    """What every box of a recording is lifted with."""

    rec: object
    cfg: LiftConfig
    alias_m: float
    m_per_raw: float                 # metres of range per raw unit (depth_factor / scale)
    dirs: np.ndarray                 # (H, W, 3) float32 unit ray directions, AHAT camera
    pad_px: int | None = None        # region padding (AHAT px) of the pinhole bound; None = the ray-table bound
    lookup: object | None = None     # ahat_model.PixelLookup when the pinhole intrinsics are too far off
    raycaster: object | None = None  # open3d.t.geometry.RaycastingScene of the HoloLens mesh


def _mesh_raycaster(rec, notes: list[str]):
    """The recording's (cached) mesh RaycastingScene, or None with a note."""
    # An unreadable mesh (or no open3d) must not stop the lift; it only loses the unwrapping.
    try:
        scene = rec.mesh_scene()
        if scene is None:
            notes.append("no mesh; alias taken as read (k = 0)")
        return scene
    except (ImportError, ValueError, OSError, RuntimeError) as exc:
        # Ctrl-C while Open3D's module initialises comes out as ImportError("initialization
        # failed"): stop, do not carry on without the mesh.
        signals.reraise_if_interrupted()
        notes.append(f"mesh unusable ({exc}); alias taken as read (k = 0)")
        return None


def robust_context(rec, cfg: LiftConfig, notes: list[str]) -> RobustContext:
    """Rays, region padding and mesh scene of a recording; what degrades the lift goes to ``notes``."""
    ahat = rec.ahat
    ctx = RobustContext(rec, cfg, alias_m=float(ahat.alias_m), m_per_raw=float(rec.depth_factor) / float(ahat.scale),
                        dirs=ahat_unit_rays(ahat.uv2xy).astype(np.float32))
    residual = _pinhole_residual(np.asarray(ahat.uv2xy, dtype=np.float64), ahat.intrinsics)
    if residual <= MAX_PINHOLE_RESIDUAL_PX:
        ctx.pad_px = int(math.ceil(residual)) + REGION_PAD_PX
    else:
        # A real (fisheye) AHAT: intrinsics.bin is a wide viewing pinhole, not the lens. Bound the
        # region through the ray table instead (ahat_model.pixel_lookup).
        ctx.lookup = pixel_lookup(ahat)
        notes.append(f"AHAT pinhole intrinsics off by {residual:.0f} px (a fisheye lens): box regions "
                     "bounded through the ray table")
    if cfg.use_mesh:
        ctx.raycaster = _mesh_raycaster(rec, notes)
    else:
        notes.append("use_mesh false; alias taken as read (k = 0)")
    return ctx


# --------------------------------------------------------------------------- per box

def _ahat_region(ctx: RobustContext, frame: FrameChains, box: np.ndarray, reach_m: float) -> tuple[int, int, int, int]:
    """AHAT pixel rectangle (r0, r1, c0, c1) whose points can project into ``box`` (PV pixels).

    The box corners are back-projected at the nearest and farthest depths an object can
    have (``reach_m``, or the alias distance: an unwrapped reading is never farther than
    that); the segments between them project (pinhole) into a convex region of the AHAT
    image bounded by the projections of their end points. The pinhole residual of the
    real (distorted) rays plus a pixel is added around it.
    """
    h, w = ctx.rec.ahat.uv2xy.shape[:2]
    if ctx.pad_px is None:
        return _ahat_region_rays(ctx, frame, box, reach_m) if ctx.lookup is not None else (0, h, 0, w)
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


REGION_EDGE_SAMPLES = 5     # points per box edge for the ray-table bound (a fisheye bends straight edges)
REGION_DEPTH_SAMPLES = 8    # depths per point, geometric from REGION_NEAR_M to the far end


def _ahat_region_rays(ctx: RobustContext, frame: FrameChains, box: np.ndarray,
                      reach_m: float) -> tuple[int, int, int, int]:
    """:func:`_ahat_region` for a lens that is no pinhole: points along the box's edges at depths
    from near to far, projected through the real rays (:class:`~egograph.geometry.ahat_model.PixelLookup`),
    bound the region; the sampling gaps and the lookup's error are covered by the padding. An empty
    rectangle when no sampled point is in the AHAT field."""
    h, w = ctx.rec.ahat.uv2xy.shape[:2]
    x1, y1, x2, y2 = box
    t = np.linspace(0.0, 1.0, REGION_EDGE_SAMPLES)
    edges = np.concatenate([np.stack([x1 + (x2 - x1) * t, np.full_like(t, y1)], 1),
                            np.stack([x1 + (x2 - x1) * t, np.full_like(t, y2)], 1),
                            np.stack([np.full_like(t, x1), y1 + (y2 - y1) * t], 1),
                            np.stack([np.full_like(t, x2), y1 + (y2 - y1) * t], 1)])
    far = max(reach_m, ctx.alias_m) + 0.1
    depths = np.geomspace(REGION_NEAR_M, far, REGION_DEPTH_SAMPLES)
    pv_pts = np.concatenate([pv_unproject(edges, np.full(len(edges), d), ctx.rec.pv.intrinsics) for d in depths])
    uv = ctx.lookup.project(transform_points(pv_pts, frame.pvcam_to_ahat))
    uv = uv[np.isfinite(uv).all(1)]
    if not len(uv):
        return 0, 0, 0, 0
    # between samples a bent edge strays at most a few pixels; 2 more than the pinhole padding
    pad = REGION_PAD_PX + 2
    c0 = max(int(math.floor(uv[:, 0].min())) - pad, 0)
    c1 = min(int(math.ceil(uv[:, 0].max())) + pad, w)
    r0 = max(int(math.floor(uv[:, 1].min())) - pad, 0)
    r1 = min(int(math.ceil(uv[:, 1].max())) + pad, h)
    return r0, max(r1, r0), c0, max(c1, c0)


def _alias_count(ctx: RobustContext) -> int:
    """Whole aliases k = 0..n-1 a reading may be off by: all within max_range_m with a mesh, only 0 without."""
    if ctx.raycaster is None:
        return 1
    return int(math.floor(ctx.cfg.max_range_m / ctx.alias_m)) + 1


def _in_box_per_alias(ctx: RobustContext, frame: FrameChains, dirs: np.ndarray, ranges: np.ndarray,
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


def _mesh_alias(ctx: RobustContext, frame: FrameChains, dirs: np.ndarray, ranges: np.ndarray,
                reach_m: float) -> np.ndarray:
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


def _box_point(ctx: RobustContext, frame: FrameChains, dirs: np.ndarray, ranges: np.ndarray, sbox: np.ndarray,
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


def _supported(ctx: RobustContext, frame: FrameChains, point: np.ndarray) -> bool:
    """Does a mesh surface lie within ``max_support_gap_m`` below ``point`` (AHAT camera)?"""
    import open3d as o3d

    ray = np.zeros((1, 6), np.float32)
    ray[0, :3] = transform_points(point, frame.ahat_to_world)
    ray[0, 3:] = -WORLD_UP
    t = float(ctx.raycaster.cast_rays(o3d.core.Tensor(ray))["t_hit"].numpy()[0])
    return t <= ctx.cfg.max_support_gap_m


def robust_box_point(ctx: RobustContext, raw: np.ndarray, frame: FrameChains,
                     box: np.ndarray) -> tuple[np.ndarray, int] | str:
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
