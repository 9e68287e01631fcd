"""Sensor models of the synthetic HoloLens 2: calibration, ray-cast rendering (Open3D),
AHAT depth with range wrapping and dropouts, PV colour with matchable textures, and the
head-tracking error of the reported poses."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from egograph.geometry.hl2ss import (
    ahat_range_to_raw,
    ahat_ray_norms,
    ahat_xy1,
    invert_rigid,
    pv_intrinsics_matrix,
    rigid_from_rt,
    rm_intrinsics_matrix,
)
from egograph.io.calibration import AHAT_SHAPE, PV_SHAPE, AhatCalibration, PvCalibration
from egograph.synth.config import AhatConfig, PoseErrorConfig, PvConfig
from egograph.synth.scene import Scene, box_mesh
from egograph.synth.trajectory import rot_x, rot_y, rot_z

MISS = 4294967295  # Open3D's invalid geometry/primitive id
HAND_SIZE = np.array([0.09, 0.035, 0.11])
HAND_COLOR = np.array([0.85, 0.62, 0.5])
HAND_ALBEDO = 0.55


# ---------------------------------------------------------------- calibration

def make_calibration(ahat: AhatConfig, pv: PvConfig) -> tuple[AhatCalibration, PvCalibration]:
    """hl2ss-style calibration of the synthetic headset (pinhole AHAT, undistorted PV)."""
    h, w = AHAT_SHAPE
    cx, cy = w / 2, h / 2
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    uv2xy = np.stack([(u - cx) / ahat.focal, (v - cy) / ahat.focal], -1).astype(np.float32)
    # Camera -> rig: AHAT looks down +z with y down; the rig looks down -z with y up.
    flip = np.diag([1.0, -1.0, -1.0])
    ahat_cam_to_rig = rigid_from_rt(rot_x(np.radians(-ahat.tilt)) @ flip, [0.0, 0.03, -0.09])
    pv_cam_to_rig = rigid_from_rt(rot_x(np.radians(-pv.tilt)), [0.01, 0.0, -0.1])
    a = AhatCalibration(uv2xy=uv2xy, extrinsics=invert_rigid(ahat_cam_to_rig), scale=1000.0, alias_mm=ahat.alias_mm,
                        intrinsics=rm_intrinsics_matrix(ahat.focal, ahat.focal, cx, cy),
                        undistort_map=np.stack([u - 0.5, v - 0.5], -1).astype(np.float32))
    ph, pw = PV_SHAPE
    k = pv_intrinsics_matrix(pv.focal, pv.focal, pw / 2, ph / 2)
    ext = invert_rigid(pv_cam_to_rig)
    p = PvCalibration(intrinsics=k, extrinsics=ext, focal_length=np.array([pv.focal, pv.focal]),
                      principal_point=np.array([pw / 2, ph / 2]), radial_distortion=np.zeros(3),
                      tangential_distortion=np.zeros(2), projection=ext @ k)
    return a, p


# ---------------------------------------------------------------- ray casting

@dataclass
class FrameGeometry:
    """World-space triangles of one instant: static scene (geometry 0), objects 1..K, hand K+1."""

    scene: o3d.t.geometry.RaycastingScene
    n_objects: int
    has_hand: bool


def object_world_vertices(scene: Scene, k: int, pos: np.ndarray, yaw: float) -> np.ndarray:
    return scene.objects[k].vertices @ rot_y(yaw).T + pos


def build_raycasting_scene(scene: Scene, obj_pos: np.ndarray, obj_yaw: np.ndarray, hand: np.ndarray | None,
                           include_static: bool = True) -> FrameGeometry:
    rc = o3d.t.geometry.RaycastingScene()
    f32, i32 = o3d.core.Dtype.Float32, o3d.core.Dtype.UInt32
    if include_static:
        rc.add_triangles(o3d.core.Tensor(scene.static_vertices.astype(np.float32)),
                         o3d.core.Tensor(scene.static_triangles.astype(np.uint32)))
    else:  # keep geometry ids aligned: a degenerate far-away placeholder for the static scene
        v, t = box_mesh([1e4, 1e4, 1e4], [1e-3] * 3)
        rc.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(t.astype(np.uint32)))
    for k in range(len(scene.objects)):
        v = object_world_vertices(scene, k, obj_pos[k], obj_yaw[k])
        rc.add_triangles(o3d.core.Tensor(v.astype(np.float32), f32), o3d.core.Tensor(scene.objects[k].triangles.astype(np.uint32), i32))
    if hand is not None:
        v, t = box_mesh(hand, HAND_SIZE)
        rc.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(t.astype(np.uint32)))
    return FrameGeometry(rc, len(scene.objects), hand is not None)


def cast(geom: FrameGeometry, origin: np.ndarray, dirs: np.ndarray) -> dict[str, np.ndarray]:
    """Cast rays (origin (3,), directions (M,3), not normalised): ``t_hit`` in units of the direction."""
    rays = np.empty((len(dirs), 6), np.float32)
    rays[:, :3] = origin
    rays[:, 3:] = dirs
    ans = geom.scene.cast_rays(o3d.core.Tensor(rays))
    return {"t": ans["t_hit"].numpy(), "geom": ans["geometry_ids"].numpy(), "prim": ans["primitive_ids"].numpy(),
            "normal": ans["primitive_normals"].numpy()}


def hit_albedo(scene: Scene, hit: dict) -> np.ndarray:
    g, p = hit["geom"], hit["prim"]
    out = np.zeros(len(g), np.float32)
    st = g == 0
    out[st] = scene.static_tri_albedo[np.minimum(p[st], len(scene.static_tri_albedo) - 1)]
    for k, obj in enumerate(scene.objects):
        out[g == k + 1] = obj.albedo
    out[g == len(scene.objects) + 1] = HAND_ALBEDO
    return out


# ---------------------------------------------------------------- AHAT depth

def ahat_camera_rays(calib: AhatCalibration) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel camera-frame directions [x, y, 1] (H*W, 3) and their norms (H*W,), float32."""
    xy = calib.uv2xy.reshape(-1, 2).astype(np.float32)
    return ahat_xy1(xy), ahat_ray_norms(xy)  # float32 arithmetic, as the renderer


def simulate_ahat(rng: np.random.Generator, scene: Scene, geom: FrameGeometry, cam_to_world: np.ndarray,
                  dirs_cam: np.ndarray, norms: np.ndarray, cfg: AhatConfig) -> np.ndarray:
    """Raw AHAT frame (512, 512) uint16 from a ray cast: wrapped range, noise, dropouts, flying pixels.

    float32 throughout: this runs on 262k pixels per frame and dominates generation time.
    """
    h, w = AHAT_SHAPE
    rot = cam_to_world[:3, :3].astype(np.float32)
    dirs = dirs_cam @ rot
    hit = cast(geom, cam_to_world[3, :3], dirs)
    rng_true = hit["t"] * norms  # rays are [x, y, 1]: t is z-depth
    valid = np.isfinite(rng_true)
    rng_true[~valid] = 0.0
    albedo = hit_albedo(scene, hit)
    # Dropouts: far returns fade, dark surfaces and grazing angles return little light, speckle.
    cos_inc = np.abs(np.einsum("ij,ij->i", dirs, hit["normal"])) / norms
    p_drop = np.clip((rng_true - np.float32(cfg.max_range)), 0, 1)
    np.maximum(p_drop, np.where(albedo < 0.25, np.float32(cfg.dark_invalid), np.float32(0)), out=p_drop)
    np.maximum(p_drop, np.clip((0.15 - cos_inc) / np.float32(0.15), 0, 1) * np.float32(0.8), out=p_drop)
    np.maximum(p_drop, np.float32(cfg.invalid_rate), out=p_drop)
    valid &= rng.random(len(p_drop), dtype=np.float32) >= p_drop
    noise = rng.standard_normal(len(rng_true), dtype=np.float32)
    img = (rng_true + noise * np.float32(cfg.noise_std) * np.maximum(rng_true, np.float32(0.3)) ** 2).reshape(h, w)
    valid = valid.reshape(h, w)
    # Flying pixels at depth edges: a mix of foreground and background.
    edge = np.zeros((h, w), bool)
    edge[:, :-1] = np.abs(img[:, 1:] - img[:, :-1]) > 0.1
    edge[:-1, :] |= np.abs(img[1:, :] - img[:-1, :]) > 0.1
    fly = edge & (rng.random((h, w), dtype=np.float32) < cfg.flying_pixel_rate)
    if fly.any():
        nb = np.roll(img, -1, axis=1)
        mix = rng.uniform(0.2, 0.8, int(fly.sum())).astype(np.float32)
        img[fly] = img[fly] * (1 - mix) + nb[fly] * mix
    wrapped = np.mod(np.maximum(img, 0), np.float32(cfg.alias_mm / 1000.0))
    raw = ahat_range_to_raw(wrapped, 1000.0, cfg.depth_factor)
    raw[~valid] = 0
    return raw


# ---------------------------------------------------------------- PV colour

class Textures:
    """Procedural, view-consistent surface textures that SIFT can match.

    Random values on 3D voxel lattices at three scales (20, 5 and 1.5 cm), looked up at the
    surface point without interpolation: every surface shows a fixed pattern of patches with
    sharp corners, the same from every viewpoint, at a few gathers per pixel.
    """

    SCALES = (0.2, 0.05, 0.015)
    WEIGHTS = (0.35, 0.4, 0.25)

    def __init__(self, rng: np.random.Generator, size: int = 64):
        self.size = size
        self.lattice = rng.uniform(0.25, 1.0, size ** 3).astype(np.float32)
        self.tint = rng.uniform(0.8, 1.15, (size ** 3, 3)).astype(np.float32)

    def _index(self, p: np.ndarray, scale: float) -> np.ndarray:
        q = np.floor(p * np.float32(1.0 / scale)).astype(np.int64) & (self.size - 1)
        return (q[:, 0] * self.size + q[:, 1]) * self.size + q[:, 2]

    def shade(self, points: np.ndarray, base: np.ndarray, seed_offset: np.ndarray | None = None) -> np.ndarray:
        """Colour (M, 3) in [0, 1] of surface points (M, 3, metres) given base colours (M, 3)."""
        p = (points if seed_offset is None else points + seed_offset).astype(np.float32)
        v = np.zeros(len(p), np.float32)
        for scale, w in zip(self.SCALES, self.WEIGHTS):
            v += np.float32(w) * self.lattice[self._index(p, scale)]
        tint = self.tint[self._index(p + 0.37, 0.3)]
        return np.clip(base * tint * (v * np.float32(1.3))[:, None], 0, 1)


LIGHT = np.array([0.3, 0.85, 0.4]) / np.linalg.norm([0.3, 0.85, 0.4])


def shade_hits(scene: Scene, textures: Textures, hit: dict, origin: np.ndarray, dirs: np.ndarray,
               obj_pos: np.ndarray, obj_yaw: np.ndarray) -> np.ndarray:
    """RGB (M, 3) float in [0, 1] for a cast: textured, Lambert-lit, black where nothing is hit."""
    g, prim = hit["geom"], hit["prim"]
    t = hit["t"]
    ok = np.isfinite(t)
    pts = origin.astype(np.float32) + dirs.astype(np.float32) * np.where(ok, t, 0)[:, None]
    col = np.zeros((len(g), 3), np.float32)
    st = ok & (g == 0)
    if st.any():
        col[st] = textures.shade(pts[st], scene.static_tri_color[prim[st]])
    for k, obj in enumerate(scene.objects):
        m = ok & (g == k + 1)
        if m.any():
            local = (pts[m] - obj_pos[k]) @ rot_y(obj_yaw[k])  # world -> object frame
            col[m] = textures.shade(local, np.tile(obj.color, (m.sum(), 1)), np.full(3, 11.0 * obj.pattern + 5.0))
    hm = ok & (g == len(scene.objects) + 1)
    col[hm] = HAND_COLOR
    lam = 0.45 + 0.55 * np.abs(hit["normal"] @ LIGHT.astype(np.float32))
    return np.clip(col * lam[:, None], 0, 1)


def pv_camera_rays(calib: PvCalibration, downsample: int = 1) -> tuple[np.ndarray, tuple[int, int]]:
    """PV-camera-frame ray directions (M, 3) with z = -1 (so ``t_hit`` is depth), row-major, and the grid shape."""
    h, w = calib.shape
    hs, ws = h // downsample, w // downsample
    u, v = np.meshgrid((np.arange(ws) + 0.5) * downsample, (np.arange(hs) + 0.5) * downsample)
    fx, fy = calib.focal_length
    cx, cy = calib.principal_point
    dirs = np.stack([(u - cx) / fx, -(v - cy) / fy, -np.ones_like(u)], -1).reshape(-1, 3)
    return dirs, (hs, ws)


# ---------------------------------------------------------------- reported poses

def pose_errors(rng: np.random.Generator, n: int, fps: float, ang_speed_dps: np.ndarray,
                cfg: PoseErrorConfig, pivot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-frame error transforms per frame (row-vector 4x4): reported = true @ error.

    Jitter (white), drift (random walk in translation and yaw) and relocalisation jumps
    (steps that persist) after fast head turns. Rotation errors turn about ``pivot`` (the room
    centre), not the world origin, so a drift of a degree moves nearby points by centimetres.
    Also returns the jump frame indices.
    """
    errs = np.tile(np.eye(4), (n, 1, 1))
    if not cfg.enabled:
        return errs, np.zeros(0, int)
    dt = 1.0 / fps
    drift_t = np.cumsum(rng.normal(0, cfg.drift_trans * np.sqrt(dt), (n, 3)), axis=0)
    drift_t[:, 1] *= 0.3  # gravity keeps height better observed
    drift_yaw = np.cumsum(rng.normal(0, np.radians(cfg.drift_rot) * np.sqrt(dt), n))
    jump_t = np.zeros((n, 3))
    jump_r = np.zeros((n, 3))
    fast = ang_speed_dps > cfg.fast_turn_rate
    # The first frame after each fast-turn episode may relocalise.
    ends = np.flatnonzero(fast[:-1] & ~fast[1:]) + 1
    jumps = ends[rng.random(len(ends)) < cfg.jump_rate]
    for j in jumps:
        d = rng.normal(0, 1, 3)
        jump_t[j:] += d / np.linalg.norm(d) * rng.uniform(*cfg.jump_trans)
        a = rng.normal(0, 1, 3)
        jump_r[j:] += a / np.linalg.norm(a) * np.radians(rng.uniform(*cfg.jump_rot))
    jit_t = rng.normal(0, cfg.jitter_trans, (n, 3))
    jit_r = rng.normal(0, np.radians(cfg.jitter_rot), (n, 3))
    rot = jit_r + jump_r
    rot[:, 1] += drift_yaw
    pivot = np.asarray(pivot, float)
    for i in range(n):
        r = rot_y(rot[i, 1]) @ rot_x(rot[i, 0]) @ rot_z(rot[i, 2])
        errs[i] = rigid_from_rt(r, pivot - r @ pivot + drift_t[i] + jump_t[i] + jit_t[i])
    return errs, jumps
