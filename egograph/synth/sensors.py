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
from egograph.synth.trajectory import HAND_THICKNESS, rot_x, rot_y, rot_z

MISS = 4294967295  # Open3D's invalid geometry/primitive id
PALM_SIZE = np.array([0.085, 0.10, HAND_THICKNESS])  # body frame: across, up, towards the wearer; metres
FOREARM = (0.3, 0.065, np.array([0.15, -0.45, 1.0]))  # length, width (m), direction in the body frame (right, up, back)
HAND_COLOR = np.array([0.85, 0.62, 0.5])
HAND_ALBEDO = 0.55


# ---------------------------------------------------------------- calibration

# The generator's head frame is x right, y up, z backward. A HoloLens rig node (the left-front
# VLC camera, mounted rotated by 90 degrees) has x pointing down, y left and z forward: the real
# extrinsics.bin (rig node -> AHAT camera) put the AHAT's forward axis at +0.29 x, +0.96 z in it, so the
# AHAT looks forward and about 17 degrees down, image x to the right, as on the device.
NODE_TO_HEAD_ROTATION = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # rows: node axes in head
AHAT_IN_HEAD = np.array([0.0, 0.03, -0.09])  # AHAT camera centre in the head frame, metres
PV_IN_HEAD = np.array([0.01, 0.0, -0.1])     # PV camera centre in the head frame, metres


@dataclass
class HeadsetCalibration:
    """The synthetic headset: calibrations as written, and where the rig node sits on the head."""

    ahat: AhatCalibration
    pv: PvCalibration
    node_to_head: np.ndarray   # (4, 4) row-vector rig node -> head frame (identity for the pinhole AHAT)
    ray_valid: np.ndarray      # (H, W) bool: AHAT pixels with a ray (the others always read raw 0)
    device: str


def _device_ahat(name: str) -> tuple[AhatCalibration, np.ndarray]:
    """A real AHAT calibration by device name and its (H, W) pixels-with-a-ray mask."""
    from egograph.io.devices import device_ahat_calibration

    calib = device_ahat_calibration(name)
    valid = getattr(calib, "ray_valid", None)  # None: every pixel has a ray
    if valid is None:
        valid = np.ones(np.asarray(calib.uv2xy).shape[:2], bool)
    return calib, np.asarray(valid, bool)


def make_calibration(ahat: AhatConfig, pv: PvConfig) -> HeadsetCalibration:
    """hl2ss-style calibration of the synthetic headset: the AHAT of a real device (its rays,
    pinhole approximation, undistort map and rig-node extrinsics; ``ahat.device``) or a pinhole
    AHAT (``ahat.device: pinhole``, ``ahat.focal``, ``ahat.tilt``); an undistorted PV camera.

    Both extrinsics are relative to the same rig node, as on the device, so the static chain
    ``inv(ahat_extrinsics) @ pv_extrinsics`` maps AHAT points into the PV camera.
    """
    h, w = AHAT_SHAPE
    pv_cam_to_head = rigid_from_rt(rot_x(np.radians(-pv.tilt)), PV_IN_HEAD)
    if ahat.device == "pinhole":
        cx, cy = w / 2, h / 2
        u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
        uv2xy = np.stack([(u - cx) / ahat.focal, (v - cy) / ahat.focal], -1).astype(np.float32)
        # Camera -> rig: AHAT looks down +z with y down; the rig (= head) looks down -z with y up.
        flip = np.diag([1.0, -1.0, -1.0])
        ahat_cam_to_rig = rigid_from_rt(rot_x(np.radians(-ahat.tilt)) @ flip, AHAT_IN_HEAD)
        a = AhatCalibration(uv2xy=uv2xy, extrinsics=invert_rigid(ahat_cam_to_rig), scale=1000.0, alias_mm=ahat.alias_mm,
                            intrinsics=rm_intrinsics_matrix(ahat.focal, ahat.focal, cx, cy),
                            undistort_map=np.stack([u - 0.5, v - 0.5], -1).astype(np.float32))
        node_to_head = np.eye(4)
        ray_valid = np.ones((h, w), bool)
    else:
        real, ray_valid = _device_ahat(ahat.device)
        # The device's rays as they are (finite everywhere; pixels without a ray render raw 0). The
        # real scale (1000) is kept; the alias distance stays a knob (alias.bin differs by firmware).
        a = AhatCalibration(uv2xy=np.asarray(real.uv2xy, np.float32), extrinsics=np.asarray(real.extrinsics, float),
                            scale=float(real.scale), alias_mm=ahat.alias_mm,
                            intrinsics=np.asarray(real.intrinsics, float),
                            undistort_map=np.asarray(real.undistort_map, np.float32), ray_valid=ray_valid)
        # Place the rig node so that the AHAT camera centre lands at AHAT_IN_HEAD.
        node_to_head = np.eye(4)
        node_to_head[:3, :3] = NODE_TO_HEAD_ROTATION
        ahat_in_node = invert_rigid(a.extrinsics)[3, :3]
        node_to_head[3, :3] = AHAT_IN_HEAD - ahat_in_node @ NODE_TO_HEAD_ROTATION
    ph, pw = PV_SHAPE
    k = pv_intrinsics_matrix(pv.focal, pv.focal, pw / 2, ph / 2)
    ext = node_to_head @ invert_rigid(pv_cam_to_head)  # rig node -> PV camera
    p = PvCalibration(intrinsics=k, extrinsics=ext, focal_length=np.array([pv.focal, pv.focal]),
                      principal_point=np.array([pw / 2, ph / 2]), radial_distortion=np.zeros(3),
                      tangential_distortion=np.zeros(2), projection=ext @ k)
    return HeadsetCalibration(a, p, node_to_head, ray_valid, ahat.device)


# ---------------------------------------------------------------- ray casting

@dataclass
class FrameGeometry:
    """World-space triangles of one instant: static scene (geometry 0), objects 1..K, hand K+1."""

    scene: o3d.t.geometry.RaycastingScene
    n_objects: int
    has_hand: bool


def _unit_box(center: np.ndarray, size: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """Vertices (8, 3) of a box: unit-cube corners scaled by ``size`` along the rows of ``axes``, at ``center``."""
    v, _ = box_mesh((0, 0, 0), size)
    return v @ axes + center


def hand_mesh(palm: np.ndarray, yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """The carrying hand (world, metres): a palm box centred at ``palm`` facing the wearer and a
    forearm box reaching back and down to the body, turned by the body yaw (radians about y)."""
    body = rot_y(yaw).T  # rows: the body's x, y, z axes in world
    _, tris = box_mesh((0, 0, 0), (1, 1, 1))
    length, width, direction = FOREARM
    d = direction / np.linalg.norm(direction)
    side = np.cross([0.0, 1.0, 0.0], d)
    side /= np.linalg.norm(side)
    arm_axes = np.stack([side, np.cross(d, side), d]) @ body  # forearm frame: across, normal, along
    start = palm + (np.array([0.0, -0.02, HAND_THICKNESS / 2]) @ body)
    verts = np.vstack([_unit_box(palm, PALM_SIZE, body),
                       _unit_box(start + (d @ body) * length / 2, np.array([width, width, length]), arm_axes)])
    return verts, np.vstack([tris, tris + 8])


def object_world_vertices(scene: Scene, k: int, pos: np.ndarray, yaw: float) -> np.ndarray:
    return scene.objects[k].vertices @ rot_y(yaw).T + pos


def build_raycasting_scene(scene: Scene, obj_pos: np.ndarray, obj_yaw: np.ndarray, hand: tuple | None,
                           include_static: bool = True) -> FrameGeometry:
    """Ray-casting scene of one instant; ``hand``: ``(palm centre, body yaw)`` of the carrying hand, or None."""
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
        v, t = (scene.hand_mesh or hand_mesh)(*hand)[:2]
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
                  dirs_cam: np.ndarray, norms: np.ndarray, cfg: AhatConfig,
                  ray_valid: np.ndarray | None = None) -> np.ndarray:
    """Raw AHAT frame (512, 512) uint16 from a ray cast: wrapped range, noise, dropouts, flying pixels.
    Pixels without a ray (``ray_valid`` False, (H*W,) bool) read 0.

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
    if ray_valid is not None:
        raw.reshape(-1)[~ray_valid] = 0
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
    CONTRAST = 1.3               # gain on the summed lattice value
    TINT_SCALE = 0.3             # lattice spacing of the colour tint, metres
    TINT_SHIFT = 0.37            # the tint's lattice is shifted by this much against the others, metres

    def __init__(self, rng: np.random.Generator, size: int = 64):
        self.size = size
        self.lattice = rng.uniform(0.25, 1.0, size ** 3).astype(np.float32)
        self.tint = rng.uniform(0.8, 1.15, (size ** 3, 3)).astype(np.float32)

    def _index(self, p: np.ndarray, scale: float) -> np.ndarray:
        # int32 lattice index: half the memory traffic of int64 on a million pixels
        q = np.floor(p * np.float32(1.0 / scale)).astype(np.int32)
        q &= self.size - 1
        return (q[:, 0] * self.size + q[:, 1]) * self.size + q[:, 2]

    def shade(self, points: np.ndarray, base: np.ndarray, seed_offset: np.ndarray | None = None) -> np.ndarray:
        """Colour (M, 3) in [0, 1] of surface points (M, 3, metres) given base colours (M, 3)."""
        p = (points if seed_offset is None else points + seed_offset).astype(np.float32)
        v = np.zeros(len(p), np.float32)
        for scale, w in zip(self.SCALES, self.WEIGHTS):
            v += np.float32(w) * self.lattice[self._index(p, scale)]
        tint = self.tint[self._index(p + np.float32(self.TINT_SHIFT), self.TINT_SCALE)]
        tint *= (v * np.float32(self.CONTRAST))[:, None]
        tint *= base
        return np.clip(tint, 0, 1, out=tint)


LIGHT = np.array([0.3, 0.85, 0.4]) / np.linalg.norm([0.3, 0.85, 0.4])
AMBIENT, SKY_GAIN, LAMP_GAIN = 0.3, 0.35, 0.6  # light = ambient + sky * |n.LIGHT| + lamp terms
BAND_DIM = 0.8             # the twin's band: channels reversed and dimmed by this factor
LAMP_HEIGHT = 0.35  # lamps hang this far below the ceiling, metres
LAMP_REACH = 2.0    # distance at which a lamp's light falls to half, metres
DETAIL_HALF_WIDTH = 0.008  # half width of the band that tells a look-alike twin apart, metres
# Room surfaces are textured at world coordinates shifted by this much (metres): the floor (y = 0) and
# walls at round coordinates otherwise lie exactly on a lattice plane, where float rounding of the
# hit point picks one side or the other pixel by pixel (a speckle that is not on the surface).
STATIC_TEXTURE_SHIFT = 0.0041


def room_lamps(rng: np.random.Generator, room_size: np.ndarray, n: int = 2) -> np.ndarray:
    """World positions (n, 3) of the room's lamps: the light varies across the room."""
    w, d, h = room_size
    return np.column_stack([rng.uniform(0.15, 0.85, n) * w, np.full(n, h - LAMP_HEIGHT), rng.uniform(0.15, 0.85, n) * d])


def shade_hits(scene: Scene, textures: Textures, hit: dict, origin: np.ndarray, dirs: np.ndarray,
               obj_pos: np.ndarray, obj_yaw: np.ndarray, lamps: np.ndarray | None = None) -> np.ndarray:
    """RGB (M, 3) float in [0, 1] for a cast: textured and lit, black where nothing is hit.

    One texture pass over every pixel: static surfaces in world coordinates, each object in its
    own frame shifted by its pattern (look-alike twins share a pattern; the second twin has a thin
    band of another colour around it, the small detail that tells them apart). Light: ambient plus
    a sky direction plus ``lamps`` (world, (L, 3); falling off with distance), so the same surface
    is brighter near a lamp.
    """
    g, prim = hit["geom"], hit["prim"]
    t = hit["t"]
    ok = np.isfinite(t)
    pts = dirs.astype(np.float32) * np.where(ok, t, 0)[:, None]
    pts += origin.astype(np.float32)
    world = pts
    k = len(scene.objects)
    n_static = len(scene.static_tri_color)
    # Base colour per pixel from one table: static triangles, then objects, then the hand.
    lut = np.vstack([scene.static_tri_color, [o.color for o in scene.objects], [HAND_COLOR], [[0, 0, 0]]]).astype(np.float32)
    cid = np.where(g == 0, np.minimum(prim, n_static - 1), n_static + np.minimum(g, k + 2).astype(np.int64) - 1)
    cid[~ok] = n_static + k + 1
    tex_pts = world + np.float32(STATIC_TEXTURE_SHIFT)  # objects overwrite theirs below
    detail = []
    for j, obj in enumerate(scene.objects):
        m = np.flatnonzero(ok & (g == j + 1))
        if len(m):
            local = (world[m] - obj_pos[j].astype(np.float32)) @ rot_y(obj_yaw[j]).astype(np.float32)  # world -> object
            tex_pts[m] = local + np.float32(11.0 * obj.pattern + 5.0)
            if 0 <= obj.twin < j:  # the second of a look-alike pair
                detail.append(m[np.abs(local[:, 1] - np.float32(0.2 * obj.size[1])) < DETAIL_HALF_WIDTH])
    col = textures.shade(tex_pts, lut[cid])
    for m in detail:
        col[m] = col[m][:, ::-1] * np.float32(BAND_DIM)  # the band: channels swapped, a little darker
    normal = hit["normal"]
    lam = np.abs(normal @ LIGHT.astype(np.float32))
    lam *= np.float32(SKY_GAIN)
    lam += np.float32(AMBIENT)
    if lamps is not None:
        for lamp in np.asarray(lamps, np.float32):
            to = lamp - world
            d2 = np.einsum("ij,ij->i", to, to) + np.float32(1e-6)
            lam += np.float32(LAMP_GAIN) * np.abs(np.einsum("ij,ij->i", normal, to)) / np.sqrt(d2) \
                / (np.float32(1.0) + d2 / np.float32(LAMP_REACH ** 2))
    col *= lam[:, None]
    return np.clip(col, 0, 1, out=col)


@dataclass(frozen=True)
class Pinhole:
    """A pinhole camera looking down -z, y up (the PV convention): image rows and columns, focal
    lengths and principal point in pixels (pixel centres at integer + 0.5). A PvCalibration has the
    same three fields."""

    shape: tuple[int, int]
    focal_length: tuple[float, float]
    principal_point: tuple[float, float]


def pv_camera_rays(calib: PvCalibration | Pinhole, downsample: int = 1) -> tuple[np.ndarray, tuple[int, int]]:
    """PV-camera-frame ray directions (M, 3) with z = -1 (so ``t_hit`` is depth), row-major, and the grid shape."""
    h, w = calib.shape
    hs, ws = h // downsample, w // downsample
    u, v = np.meshgrid((np.arange(ws) + 0.5) * downsample, (np.arange(hs) + 0.5) * downsample)
    fx, fy = calib.focal_length
    cx, cy = calib.principal_point
    dirs = np.stack([(u - cx) / fx, -(v - cy) / fy, -np.ones_like(u)], -1).reshape(-1, 3)
    return dirs, (hs, ws)


class RaycastRenderer:
    """Colour frames by ray casting (Open3D) and :func:`shade_hits`: the reference the OpenGL
    rasteriser (:class:`egograph.synth.render_gl.PvRenderer`) is tested against, with its interface."""

    def __init__(self, scene: Scene, textures: Textures, lamps: np.ndarray | None, camera: PvCalibration | Pinhole,
                 background: float = 0.0):
        self.scene, self.textures, self.lamps, self.background = scene, textures, lamps, float(background)
        self.dirs_cam, self.shape = pv_camera_rays(camera, 1)

    def render(self, cam_to_world: np.ndarray, obj_pos: np.ndarray, obj_yaw: np.ndarray,
               hand: tuple[np.ndarray, float] | None, only: int | None = None) -> np.ndarray:
        """RGB uint8 image (H, W, 3); arguments as :meth:`egograph.synth.render_gl.PvRenderer.render`
        (``only``: no room and no hand; the caller keeps the other instances out of view)."""
        geom = build_raycasting_scene(self.scene, obj_pos, obj_yaw, hand if only is None else None,
                                      include_static=only is None)
        origin = cam_to_world[3, :3]
        dirs = self.dirs_cam @ cam_to_world[:3, :3]
        hit = cast(geom, origin, dirs)
        col = shade_hits(self.scene, self.textures, hit, origin, dirs, obj_pos, obj_yaw, self.lamps)
        if self.background:
            col[~np.isfinite(hit["t"])] = self.background
        return (col.reshape(self.shape + (3,)) * 255).astype(np.uint8)

    def release(self) -> None:
        pass


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
