"""Write a complete synthetic recording in the IT3DEgo layout, with the truth in ``synth_gt/``.

Randomness: one ``SeedSequence(seed)`` spawns an independent stream per part (scene,
activity, depth noise, pose error, each front-end), so the same seed and config give
byte-identical output, and changing e.g. the MVPE front-end leaves the scene unchanged.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from egograph import __version__
from egograph.core.config import to_dict
from egograph.core.errors import ConfigError
from egograph.core.types import Box, Detection
from egograph.geometry.hl2ss import invert_rigid, pv_project, transform_points
from egograph.io.annotations import Annotations, CenterAnnotation, MotionInterval, SvoeEnrollment, save_annotations
from egograph.io.atomic import atomic_dir, atomic_write_text
from egograph.io.calibration import PV_SHAPE, PvCalibration, write_ahat_calibration, write_pv_calibration
from egograph.io.detections import write_detection_dir
from egograph.io.png import write_png
from egograph.io.poses import write_pose_json
from egograph.synth.config import FrontEndConfig, SynthConfig
from egograph.synth.frontend import FRONTEND_REVISION, SOURCE_TRUE, FrameView, FrontEnd
from egograph.synth.scene import Scene, box_mesh, hololens_mesh, make_scene
from egograph.synth.sensors import (
    Pinhole,
    RaycastRenderer,
    Textures,
    ahat_camera_rays,
    build_raycasting_scene,
    cast,
    make_calibration,
    object_world_vertices,
    pose_errors,
    pv_camera_rays,
    room_lamps,
    simulate_ahat,
)
from egograph.synth.trajectory import Trajectory, make_trajectory, rot_y

TS0 = 133_400_000_000_000_000  # a HoloLens-like 100 ns tick count (2023)
# Bumped whenever the same seed and config would render a different recording, so caches of
# generated recordings (egograph.synth.benchset) know to regenerate.
GENERATOR_REVISION = 4  # 4: real AHAT calibration, gaze on the hands, hand occlusion, baked mesh, fast RGB
# Revision of the PV colour frames alone (recordings without RGB do not depend on it): 1 ray cast and
# shaded in numpy (generator revision 4), 2 rasterised by OpenGL (pv.renderer=gl) and written by io.png.
PV_REVISION = 2
# Revision of the device world (world: device; recording.json "device_revision"): bumped whenever the
# same seed and config would give a different device-world recording.
DEVICE_REVISION = 1
# The device world draws its looks and its camera noise from the last two streams (spawned children of
# a SeedSequence do not depend on how many are spawned: the legacy streams are unchanged).
STREAMS = ("scene", "activity", "depth", "pose_error", "svoe", "mvpe", "textures", "mesh", "look", "camera")


@dataclass
class SynthResult:
    root: Path
    sequence: str
    frames: int
    instances: list[str]
    n_intervals: int
    n_moves: int
    seconds: float
    fps_generation: float


def stationary_runs(held: np.ndarray) -> list[tuple[int, int]]:
    """Inclusive frame ranges where ``held`` is False."""
    runs, start = [], None
    for j, h in enumerate(held):
        if not h and start is None:
            start = j
        if h and start is not None:
            runs.append((start, j - 1))
            start = None
    if start is not None:
        runs.append((start, len(held) - 1))
    return runs


def _project_box(vertices_world: np.ndarray, world_to_pv: np.ndarray, k_pv: np.ndarray,
                 shape: tuple[int, int]) -> tuple[np.ndarray | None, float]:
    """Amodal box clipped to the image (x1, y1, x2, y2) and the share of it inside the image."""
    uv, depth = pv_project(transform_points(vertices_world, world_to_pv), k_pv)
    if (depth < 0.1).any():
        return None, 0.0
    h, w = shape
    x1, y1 = uv.min(0)
    x2, y2 = uv.max(0)
    full = (x2 - x1) * (y2 - y1)
    cx1, cy1, cx2, cy2 = max(x1, 0), max(y1, 0), min(x2, w - 1), min(y2, h - 1)
    if cx2 <= cx1 or cy2 <= cy1 or full <= 0:
        return None, 0.0
    return np.array([cx1, cy1, cx2, cy2]), float((cx2 - cx1) * (cy2 - cy1) / full)


def silhouette_pixels(scene: Scene, j: int, pos: np.ndarray, yaw: float, origin: np.ndarray, pose: np.ndarray,
                      dirs_cam: np.ndarray, grid: tuple[int, int], box_grid: np.ndarray, hand=None) -> int:
    """Pixels of the (downsampled) PV grid the object covers when nothing else is in the scene
    (``hand``: ``(vertices, triangles)`` of a hand in front of it, world metres: the pixels the
    object still shows with the hand alone in the scene).

    Only the rays inside its box are cast, so occlusion by other objects, furniture or the
    hand is measured against the true unoccluded silhouette.
    """
    import open3d as o3d

    h, w = grid
    x1, y1 = max(int(np.floor(box_grid[0])), 0), max(int(np.floor(box_grid[1])), 0)
    x2, y2 = min(int(np.ceil(box_grid[2])) + 1, w), min(int(np.ceil(box_grid[3])) + 1, h)
    if x2 <= x1 or y2 <= y1:
        return 0
    rows, cols = np.mgrid[y1:y2, x1:x2]
    idx = (rows * w + cols).ravel()
    rc = o3d.t.geometry.RaycastingScene()
    v = object_world_vertices(scene, j, pos, yaw)
    rc.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(scene.objects[j].triangles.astype(np.uint32)))
    if hand is not None:
        rc.add_triangles(o3d.core.Tensor(np.asarray(hand[0], np.float32)), o3d.core.Tensor(np.asarray(hand[1], np.uint32)))
    rays = np.empty((len(idx), 6), np.float32)
    rays[:, :3] = origin
    rays[:, 3:] = dirs_cam[idx] @ pose[:3, :3]
    ans = rc.cast_rays(o3d.core.Tensor(rays))
    if hand is None:
        return int(np.isfinite(ans["t_hit"].numpy()).sum())
    return int((ans["geometry_ids"].numpy() == 0).sum())


def _clutter_spots(rng: np.random.Generator, scene: Scene, per_instance: int) -> np.ndarray:
    """Persistent background spots (K, C, 3) on surfaces that resemble each instance."""
    k = len(scene.objects)
    out = np.zeros((k, per_instance, 3))
    for i in range(k):
        for c in range(per_instance):
            s = scene.surfaces[int(rng.integers(len(scene.surfaces)))]
            off = rng.uniform(-1, 1, 2) * s.half_extent
            out[i, c] = s.center + np.array([off[0], scene.objects[i].size[1] / 2, off[1]])
    return out


def open_pv_renderer(cfg: SynthConfig, scene: Scene, textures: Textures, lamps: np.ndarray | None,
                     camera: PvCalibration | Pinhole, background: float = 0.0):
    """The colour renderer of ``pv.renderer`` for ``camera``: the OpenGL rasteriser (``gl``) or the
    ray caster (``raycast``), both with ``render(cam_to_world, obj_pos, obj_yaw, hand, only=None)``
    and ``release()``. No OpenGL -> ConfigError saying what to install (never a silent switch: the
    two renderers do not give the same bytes)."""
    if cfg.pv.renderer != "gl":
        return RaycastRenderer(scene, textures, lamps, camera, background)
    from egograph.synth.render_gl import GlUnavailable, PvRenderer

    try:
        return PvRenderer(scene, textures, lamps, camera, background)
    except GlUnavailable as e:
        raise ConfigError(f"pv.renderer=gl: {e}; or render by ray casting (slower): --set pv.renderer=raycast") from None


def render_mvpe_photos(scene: Scene, textures: Textures, size: int, cfg: SynthConfig) -> dict[str, list[np.ndarray]]:
    """25 RGB photos per instance (12 at 30 deg, 12 at 60 deg elevation, 1 top-down) on a grey
    backdrop, by ``cfg.pv.renderer``."""
    photos: dict[str, list[np.ndarray]] = {}
    f = size * 1.2
    renderer = open_pv_renderer(cfg, scene, textures, None, Pinhole((size, size), (f, f), (size / 2, size / 2)), 0.55)
    views = [(30.0, a) for a in range(0, 360, 30)] + [(60.0, a + 15) for a in range(0, 360, 30)] + [(89.0, 0.0)]
    for k, obj in enumerate(scene.objects):
        pos = np.zeros((len(scene.objects), 3)) + 1e3  # the others far out of view
        pos[k] = 0.0
        yaw = np.zeros(len(scene.objects))
        dist = 2.2 * float(np.linalg.norm(obj.size)) / 2 / np.tan(np.arctan(size / 2 / f))
        imgs = []
        for elev, azim in views:
            e, a = np.radians(elev), np.radians(azim)
            eye = dist * np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])
            fwd = -eye / np.linalg.norm(eye)
            up0 = np.array([0.0, 1.0, 0.0]) if elev < 85 else np.array([0.0, 0.0, -1.0])
            right = np.cross(fwd, up0)
            right /= np.linalg.norm(right)
            up = np.cross(right, fwd)
            cam_to_world = np.eye(4)
            cam_to_world[:3, :3] = np.stack([right, up, -fwd])  # rows: camera axes in world (row-vector rotation)
            cam_to_world[3, :3] = eye
            imgs.append(renderer.render(cam_to_world, pos, yaw, None, only=k))
        photos[obj.name] = imgs
    renderer.release()
    return photos


def _open_device_renderer(scene: Scene, light, camera, extra_layers=None):
    from egograph.synth.render_device import DeviceRenderer
    from egograph.synth.render_gl import GlUnavailable

    try:
        return DeviceRenderer(scene, light, camera, extra_layers)
    except GlUnavailable as e:
        raise ConfigError(f"world=device renders by OpenGL: {e}") from None


def _look_at(eye: np.ndarray, target: np.ndarray, roll: float = 0.0) -> np.ndarray:
    """Row-vector cam_to_world of a camera at ``eye`` looking at ``target`` (y up, looking down -z)."""
    fwd = np.asarray(target, float) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    c, s = np.cos(roll), np.sin(roll)
    right, up = c * right + s * up, -s * right + c * up
    pose = np.eye(4)
    pose[:3, :3] = np.stack([right, up, -fwd])
    pose[3, :3] = eye
    return pose


def render_mvpe_photos_device(scene: Scene, cfg: SynthConfig, rng: np.random.Generator) -> dict[str, list[np.ndarray]]:
    """25 enrollment photos per instance as people take them with a phone: the object on a tabletop
    (wood or a tablecloth, a wall behind, ``device.mvpe_clutter`` other objects around it) from
    around and above, and ``device.mvpe_in_hand`` views with the object held up in a hand; the
    room's light plus the phone's own light, auto-exposed, with the phone's (small) noise."""
    from dataclasses import replace as dc_replace

    from egograph.synth.camera import AutoExposure, develop, metered
    from egograph.synth.device import RoomLight, _static_records
    from egograph.synth.materials import PhotoLibrary, fabric_texture, wood_texture
    from egograph.synth.scene import box_mesh as _box

    size = cfg.mvpe_photo_size
    f = size * 0.9
    lib = PhotoLibrary()
    base = len(scene.layers)
    tops = [wood_texture(rng, lib, rng.uniform(0, 0.8)), fabric_texture(rng, lib, rng.uniform(120, 230, 3))]
    phone_light = RoomLight(1.0, False, np.array([0.35, 0.33, 0.3]), np.array([0.3, 0.3, 0.32]),
                            np.array([0.5, 0.47, 0.42]), np.array([[0.4, 1.4, 0.6]]))
    renderer = _open_device_renderer(scene, phone_light, Pinhole((size, size), (f, f), (size / 2, size / 2)), tops)
    phone = dc_replace(cfg.device.camera, jpeg_quality=0, read_noise=2.0, full_well=6000.0)
    n_hand = min(cfg.device.mvpe_in_hand, 25)
    photos: dict[str, list[np.ndarray]] = {}
    k_all = len(scene.objects)
    yaw0 = np.zeros(k_all)
    for k, obj in enumerate(scene.objects):
        top = base + int(rng.integers(2))
        table_v, table_t = _box([0.0, -0.02, 0.0], [1.6, 0.04, 1.1])
        # The table in a corner of a room: walls on all sides, so no view looks into the void.
        recs = [_static_records(table_v, table_t, top, 0.7)]
        for c, s in (([0.0, 0.7, -1.2], [3.0, 3.0, 0.02]), ([0.0, 0.7, 1.6], [3.0, 3.0, 0.02]),
                     ([-1.4, 0.7, 0.2], [0.02, 3.0, 3.0]), ([1.4, 0.7, 0.2], [0.02, 3.0, 3.0]),
                     ([0.0, -0.75, 0.2], [3.0, 0.02, 3.0])):
            wall_v, wall_t = _box(c, s)
            recs.append(_static_records(wall_v, wall_t, 1 if s[1] > 0.1 else 0, 1.5))
        dist = 1.9 * float(np.linalg.norm(obj.size)) / 2 / np.tan(np.arctan(size / 2 / f))
        pool = list(scene.props)
        for c in range(min(cfg.device.mvpe_clutter, len(pool))):
            p = pool[int(rng.integers(len(pool)))]
            # Beyond the camera's distance: clutter stands behind and beside the object, not in front of the lens.
            ang, rad = rng.uniform(0, 2 * np.pi), rng.uniform(max(0.25, 1.2 * dist), 1.2 * dist + 0.3)
            r = rot_y(rng.uniform(0, 2 * np.pi))
            v = p.model.vertices @ r.T + [rad * np.cos(ang), p.model.size[1] / 2, rad * np.sin(ang)]
            recs.append(_static_records(v, p.model.triangles, p.model.layer, 0.0, p.model.uv, p.model.normals @ r.T))
        vao = renderer.records_vao(np.vstack(recs))
        extra = [(vao, np.eye(4))]
        pos = np.zeros((k_all, 3))
        yaw = yaw0.copy()
        yaw[k] = rng.uniform(0, 2 * np.pi)
        imgs = []
        for m in range(25):
            in_hand = m >= 25 - n_hand
            if in_hand:
                pos[k] = [0.0, 0.35, 0.1]
                azim = rng.uniform(-0.5, 0.5)
                elev = np.radians(rng.uniform(15, 40))
                eye = pos[k] + dist * 1.1 * np.array([np.cos(elev) * np.sin(azim), np.sin(elev), np.cos(elev) * np.cos(azim)])
                body_yaw = float(np.arctan2(-(pos[k] - eye)[0], -(pos[k] - eye)[2]))
                body = np.array([[np.cos(body_yaw), 0, -np.sin(body_yaw)], [0, 1, 0], [np.sin(body_yaw), 0, np.cos(body_yaw)]])
                g = np.array([max(obj.size[0], obj.size[2]), obj.size[1], max(obj.size[0], obj.size[2])])
                palm = pos[k] + np.array([g[0] / 2 + 0.014, -0.1 * g[1], 0.0]) @ body
                hand = (palm, body_yaw, g)
            else:
                pos[k] = [0.0, obj.size[1] / 2, 0.0]
                azim = np.radians(m * 360.0 / (25 - n_hand)) + rng.uniform(-0.1, 0.1)
                elev = np.radians(rng.uniform(20, 60))
                eye = pos[k] + dist * np.array([np.cos(elev) * np.sin(azim), np.sin(elev), np.cos(elev) * np.cos(azim)])
                hand = None
            renderer.set_flash(eye, 0.25)
            pose = _look_at(eye, pos[k] + rng.normal(0, 0.01, 3), rng.normal(0, 0.05))
            radiance, _ = renderer.render(pose, pos, yaw, hand, only=[k], room=False, extra=extra)
            ex = AutoExposure(phone, 30.0).exposure(metered(radiance))
            imgs.append(develop(radiance, ex, phone, rng))
        photos[obj.name] = imgs
        vao.release()
    renderer.release()
    return photos


def front_end(seed: int, name: str, cfg: FrontEndConfig, twins: np.ndarray) -> FrontEnd:
    """The front-end of detection set ``name`` (svoe, mvpe) of the recording of ``seed``, on its own
    random stream."""
    return FrontEnd(np.random.SeedSequence(seed).spawn(len(STREAMS))[STREAMS.index(name)], cfg, twins, PV_SHAPE)


def simulate_detections(cfg: SynthConfig, seed: int, ts: np.ndarray, views: dict) -> tuple[dict, dict]:
    """Run both front-ends (SVOE, MVPE) over the per-frame views -> detections and their truth lines.

    Each front-end has its own random stream of ``seed``, so this gives the same output inside
    ``generate`` and when re-run later on the views saved in ``synth_gt/`` (``egograph synth --redetect``).
    """
    detections: dict[str, dict[int, list[Detection]]] = {}
    truth: dict[str, list[str]] = {}
    for name in ("svoe", "mvpe"):
        fe = front_end(seed, name, getattr(cfg.detections, name), views["twins"])
        detections[name], truth[name] = {}, []
        for i, t in enumerate(ts):
            view = FrameView(views["visible"][i], views["boxes"][i], views["motion_dps"][i], views["clutter_boxes"][i])
            cands = fe.frame(view, i)
            detections[name][int(t)] = [Detection(c.instance, Box(*map(float, c.box)), c.score) for c in cands]
            truth[name] += [f"{t} {c.instance} {int(c.source != SOURCE_TRUE)} {c.source} {c.source_id}" for c in cands]
    return detections, truth


def write_detection_sets(root: Path, seq: str, detections: dict, truth: dict) -> None:
    for name, per_frame in detections.items():
        write_detection_dir(root / "detections" / seq / name, per_frame)
        lines = truth[name]
        atomic_write_text(root / "synth_gt" / seq / f"detections_{name}.txt",
                          "# ts instance is_false source source_id  (source: true|twin|other|clutter)\n"
                          + "\n".join(lines) + ("\n" if lines else ""))


def redetect(root: str | Path, cfg: SynthConfig) -> dict[str, int]:
    """Re-simulate the detection sets of an existing synthetic recording with ``cfg.detections``.

    Only the front-end changes: scene, activity, depth and poses stay as generated. Used to
    calibrate the front-ends without re-rendering. Returns detections written per set.
    """
    root = Path(root)
    meta = json.loads((root / "recording.json").read_text())
    seq, seed = meta["sequence"], int(meta["seed"])
    with np.load(root / "synth_gt" / seq / "instances.npz") as data:
        views = {k: data[k] for k in ("visible", "boxes", "clutter_boxes", "motion_dps", "twins")}
        ts = data["timestamps"]
    detections, truth = simulate_detections(cfg, seed, ts, views)
    write_detection_sets(root, seq, detections, truth)
    meta["config"]["detections"] = to_dict(cfg.detections)
    meta["frontend_revision"] = FRONTEND_REVISION
    atomic_write_text(root / "recording.json", json.dumps(meta, indent=1))
    return {k: sum(len(v) for v in d.values()) for k, d in detections.items()}


def generate(out: str | Path, cfg: SynthConfig, seed: int, progress: bool = True,
             extra_files: dict[str, str] | None = None) -> SynthResult:
    """Generate one recording into ``out`` (replaced atomically when complete); ``extra_files``
    (name -> text) are written at its top level in the same rename (run record, configuration)."""
    t_start = time.perf_counter()
    out = Path(out)
    rngs = dict(zip(STREAMS, (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(len(STREAMS)))))
    device = cfg.world == "device"
    if device:
        from egograph.synth.device import hand_path, make_device_scene, room_light
        from egograph.synth.materials import PhotoLibrary

        scene = make_device_scene(rngs["scene"], rngs["look"], cfg, PhotoLibrary())
        light = room_light(rngs["look"], cfg, np.array(cfg.scene.room_size))
    else:
        scene = make_scene(rngs["scene"], cfg.scene)
    traj = make_trajectory(rngs["activity"], scene, cfg)
    hand_obj = np.full(cfg.frames, -1)
    if device:
        traj.hand_pos, traj.hand_active, hand_obj, hand_grip = hand_path(traj, scene, cfg)
    headset = make_calibration(cfg.ahat, cfg.pv)
    ahat_cal, pv_cal = headset.ahat, headset.pv
    n, k = cfg.frames, len(scene.objects)
    fps = cfg.fps
    ts = TS0 + seed * 10**11 + np.round(np.arange(n) * 1e7 / fps).astype(np.int64)

    # True poses: PV at frame times, AHAT rig pose a few ms later (different sensor clock).
    rng_d = rngs["depth"]
    depth_offset = (cfg.ahat.time_offset_ms + rng_d.normal(0, 1.0, n)) / 1000.0 * fps  # in frames
    rig_pv = traj.rig_poses(np.arange(n, dtype=float))
    rig_depth = traj.rig_poses(np.arange(n) + depth_offset)
    # The trajectory gives head poses; the depth pose is the rig node's, PV's its camera's.
    pv_cam_to_node = invert_rigid(pv_cal.extrinsics)
    pv_true = pv_cam_to_node @ headset.node_to_head @ rig_pv
    depth_true = headset.node_to_head @ rig_depth
    ang_speed = traj.angular_speed_dps()
    errs, jumps = pose_errors(rngs["pose_error"], n, fps, ang_speed, cfg.pose_error,
                              pivot=np.array([scene.room_size[0] / 2, 1.0, scene.room_size[1] / 2]))
    pv_rep = pv_true @ errs
    depth_rep = depth_true @ errs

    clutter = _clutter_spots(rngs["scene"], scene, max(cfg.detections.svoe.clutter_per_instance,
                                                        cfg.detections.mvpe.clutter_per_instance))
    twins = np.array([o.twin for o in scene.objects])
    textures = None if device else Textures(rngs["textures"])
    lamps = None if device else room_lamps(rngs["textures"], scene.room_size)

    ahat_dirs, ahat_norms = ahat_camera_rays(ahat_cal)
    ahat_cam_to_node = invert_rigid(ahat_cal.extrinsics)
    ray_valid = headset.ray_valid.reshape(-1)
    ds = cfg.pv.visibility_downsample
    vis_dirs, vis_shape = pv_camera_rays(pv_cal, ds)
    # Enrollment photos first: they need nothing from the frames, and a missing OpenGL fails here,
    # before any frame is rendered.
    if device:
        from egograph.synth.camera import AutoExposure, NoiseBank, develop, image_motion, metered, vignette

        photos = render_mvpe_photos_device(scene, cfg, rngs["look"])
        pv_renderer = _open_device_renderer(scene, light, pv_cal) if cfg.pv.rgb else None
        ae = AutoExposure(cfg.device.camera, fps)

        def rig_open_close(i: int, seconds: float) -> np.ndarray:
            """Rig poses (2, 4, 4) at shutter open and close of frame i (exposure centred on the frame time)."""
            return traj.rig_poses(np.array([i - seconds * fps / 2, i + seconds * fps / 2]))

        def _turn_dps(rig: np.ndarray, seconds: float) -> float:
            rel = rig[0, :3, :3] @ rig[1, :3, :3].T
            return float(np.degrees(np.arccos(np.clip((np.trace(rel) - 1) / 2, -1, 1))) / max(seconds, 1e-9))
        vig = vignette(PV_SHAPE, cfg.device.camera.vignetting)
        noise = NoiseBank(rngs["camera"], PV_SHAPE + (3,)) if cfg.pv.rgb else None
        exposure = np.zeros((n, 4))
        prev_metered = None
    else:
        photos = render_mvpe_photos(scene, textures, cfg.mvpe_photo_size, cfg)
        pv_renderer = open_pv_renderer(cfg, scene, textures, lamps, pv_cal) if cfg.pv.rgb else None
    k_pv = pv_cal.intrinsics
    hand_cover = np.zeros((n, k), np.float32)

    visible = np.zeros((n, k))
    boxes = np.full((n, k, 4), np.nan)
    clutter_boxes = np.full((n,) + clutter.shape[:2] + (4,), np.nan)
    motion = np.zeros((n, k))
    bbox_annot: dict[int, list[tuple[int, Box]]] = {i: [] for i in range(k)}
    svoe: dict[int, SvoeEnrollment] = {}
    clutter_half = np.array([o.size for o in scene.objects]) / 2

    with atomic_dir(out) as tmp:
        seq_dir = tmp / cfg.sequence
        (seq_dir / "pv").mkdir(parents=True)
        (seq_dir / "depth_ahat").mkdir()
        for i in tqdm(range(n), desc=f"synth {cfg.sequence}", unit="frame", disable=not progress, mininterval=1.0):
            obj_pos, obj_yaw = traj.objects_at(i)
            hand, hand_yaw, hand_on = traj.hand_at(i)
            hand_args = None if not hand_on else (hand, hand_yaw, hand_grip[i]) if device else (hand, hand_yaw)
            geom = build_raycasting_scene(scene, obj_pos, obj_yaw, hand_args)
            pose = pv_true[i]
            origin = pose[3, :3]
            dirs = vis_dirs @ pose[:3, :3]
            hit = cast(geom, origin, dirs)
            seen = np.bincount(hit["geom"][hit["geom"] != 0xFFFFFFFF].astype(np.int64), minlength=k + 2)[1:k + 1]
            world_to_pv = invert_rigid(pose)
            for j in range(k):
                box, inside = _project_box(object_world_vertices(scene, j, obj_pos[j], obj_yaw[j]), world_to_pv, k_pv, PV_SHAPE)
                if box is None:
                    continue
                # Unoccluded footprint: the object alone, cast through the pixels of its box only.
                full = silhouette_pixels(scene, j, obj_pos[j], obj_yaw[j], origin, pose, vis_dirs, vis_shape, box / ds)
                if full == 0:
                    continue
                boxes[i, j] = box
                visible[i, j] = min(1.0, seen[j] / full) * inside
                if device and hand_on and hand_obj[i] == j:
                    alone = silhouette_pixels(scene, j, obj_pos[j], obj_yaw[j], origin, pose, vis_dirs, vis_shape, box / ds,
                                              scene.hand_mesh(*hand_args)[:2])
                    hand_cover[i, j] = 1.0 - min(1.0, alone / full)
            # Clutter spots: seen where the static surface at their pixel is at their depth.
            cb = np.full(clutter.shape[:2] + (4,), np.nan)
            uv, dep = pv_project(transform_points(clutter.reshape(-1, 3), world_to_pv), k_pv)
            px = np.floor(uv / ds).astype(int)
            inimg = (dep > 0.2) & (px[:, 0] >= 0) & (px[:, 0] < vis_shape[1]) & (px[:, 1] >= 0) & (px[:, 1] < vis_shape[0])
            for m in np.flatnonzero(inimg):
                idx = px[m, 1] * vis_shape[1] + px[m, 0]
                if hit["geom"][idx] == 0 and abs(hit["t"][idx] - dep[m]) < 0.2:
                    a, c = divmod(m, clutter.shape[1])
                    v, _ = box_mesh(clutter[a, c], clutter_half[a] * 2)
                    b, _ = _project_box(v, world_to_pv, k_pv, PV_SHAPE)
                    if b is not None:
                        cb[a, c] = b
            clutter_boxes[i] = cb
            motion[i] = np.where(traj.held[i], 0.3 * ang_speed[i] + 20.0, ang_speed[i])
            # Annotations: amodal boxes every stride-th frame when at least a quarter visible.
            for j in range(k):
                if not np.isfinite(boxes[i, j, 0]):
                    continue
                b = np.round(boxes[i, j])
                if i % cfg.annotation_stride == 0 and visible[i, j] >= 0.25:
                    bbox_annot[j].append((int(ts[i]), Box(*map(float, b))))
                if j not in svoe and visible[i, j] >= 0.95 and (b[2] - b[0]) * (b[3] - b[1]) >= 500:
                    svoe[j] = SvoeEnrollment(j, int(ts[i]), Box(*map(float, b)))
            # AHAT depth at its own capture time.
            fd = i + depth_offset[i]
            obj_d, yaw_d = traj.objects_at(fd)
            hand_d, hand_yaw_d, hand_d_on = traj.hand_at(fd)
            hand_d_args = None if not hand_d_on else (hand_d, hand_yaw_d, hand_grip[min(int(round(fd)), n - 1)]) if device \
                else (hand_d, hand_yaw_d)
            geom_d = build_raycasting_scene(scene, obj_d, yaw_d, hand_d_args)
            raw = simulate_ahat(rng_d, scene, geom_d, ahat_cam_to_node @ depth_true[i], ahat_dirs, ahat_norms, cfg.ahat,
                                ray_valid)
            write_png(seq_dir / "depth_ahat" / f"{ts[i]}.png", raw, 1)
            if pv_renderer is not None and device:
                radiance, depth = pv_renderer.render(pose, obj_pos, obj_yaw, hand_args)
                m = metered(radiance)
                ex = ae.exposure(m if prev_metered is None else prev_metered)
                prev_metered = m
                flow = None
                if cfg.device.camera.blur:
                    shutter = pv_cam_to_node @ headset.node_to_head @ rig_open_close(i, ex.seconds)
                    flow = image_motion(depth, k_pv, pose, shutter[0], shutter[1])
                img = develop(radiance, ex, cfg.device.camera, rngs["camera"], vig, flow, noise)
                exposure[i] = (ex.seconds, ex.gain, ex.metered, _turn_dps(rig_open_close(i, ex.seconds), ex.seconds))
                write_png(seq_dir / "pv" / f"{ts[i]}.png", img, cfg.pv.png_compression)
            elif pv_renderer is not None:
                img = pv_renderer.render(pose, obj_pos, obj_yaw, (hand, hand_yaw) if hand_on else None)
                write_png(seq_dir / "pv" / f"{ts[i]}.png", img, cfg.pv.png_compression)

        if pv_renderer is not None:
            pv_renderer.release()
        views = {"visible": visible, "boxes": boxes, "clutter_boxes": clutter_boxes, "motion_dps": motion, "twins": twins}
        detections, det_truth = simulate_detections(cfg, seed, ts, views)
        device_truth = None
        if device:
            device_truth = {"hand_cover": hand_cover, "hand_instance": hand_obj, "hand_on": traj.hand_active,
                            "head_angular_speed_dps": ang_speed.astype(np.float32), "light": light}
            if cfg.pv.rgb:
                device_truth.update(pv_exposure_s=exposure[:, 0], pv_gain=exposure[:, 1], pv_metered=exposure[:, 2],
                                    pv_exposure_turn_dps=exposure[:, 3])
        _write_outputs(tmp, cfg, seed, scene, traj, ts, pv_rep, depth_rep, pv_true, depth_true, ahat_cal, pv_cal,
                       views, detections, det_truth, bbox_annot, svoe, jumps, depth_offset, rngs, photos, device_truth)
        for name, text in (extra_files or {}).items():
            (tmp / name).write_text(text)
    seconds = time.perf_counter() - t_start
    n_int = sum(len(stationary_runs(traj.held[:, j])) for j in range(k))
    return SynthResult(out, cfg.sequence, n, [o.name for o in scene.objects], n_int, len(traj.moves), seconds, n / seconds)


def _write_outputs(tmp: Path, cfg: SynthConfig, seed: int, scene: Scene, traj: Trajectory, ts: np.ndarray,
                   pv_rep, depth_rep, pv_true, depth_true, ahat_cal, pv_cal, views, detections, det_truth,
                   bbox_annot, svoe, jumps, depth_offset, rngs, photos, device_truth=None) -> None:
    import open3d as o3d

    seq = cfg.sequence
    seq_dir = tmp / seq
    k = len(scene.objects)
    write_pose_json(seq_dir / "pv_pose.json", ts, pv_rep)
    write_pose_json(seq_dir / "depth_ahat_pose.json", ts, depth_rep)
    (seq_dir / "mesh").mkdir()
    first_places = [object_world_vertices(scene, j, traj.obj_pos[0, j], traj.obj_yaw[0, j]) for j in range(k)]
    mesh, baked = hololens_mesh(rngs["mesh"], scene, cfg.scene, first_places, cfg.wearer.head_height)
    o3d.io.write_triangle_mesh(str(seq_dir / "mesh" / "scene.ply"), mesh, write_ascii=False)
    write_ahat_calibration(tmp / "calibrations" / "rm_depth_ahat", ahat_cal)
    write_pv_calibration(tmp / "calibrations" / "personal_video", pv_cal)

    # Annotations exactly like the real ones.
    centers, motion, intervals = [], [], []
    for j in range(k):
        for loc, (a, b) in enumerate(stationary_runs(traj.held[:, j])):
            xyz = tuple(float(x) for x in traj.obj_pos[a, j])
            centers.append(CenterAnnotation(int(ts[a]), int(ts[b]), j, xyz, loc))
            motion.append(MotionInterval(j, int(ts[a]), int(ts[b])))
            intervals.append({"instance": j, "name": scene.objects[j].name, "location_id": loc,
                              "frame_start": a, "frame_end": b, "t_start": int(ts[a]), "t_end": int(ts[b]), "xyz": list(xyz)})
    ann = Annotations(labels=[o.name for o in scene.objects], centers=centers, motion=motion,
                      boxes={j: rows for j, rows in bbox_annot.items() if rows}, svoe=[svoe[j] for j in sorted(svoe)])
    save_annotations(tmp / "annotations" / seq, ann)
    write_detection_sets(tmp, seq, detections, det_truth)

    # MVPE enrollment photos.
    for name, imgs in photos.items():
        d = tmp / "mvpe" / seq / name
        d.mkdir(parents=True)
        for m, img in enumerate(imgs):
            cv2.imwrite(str(d / f"{m:02d}.jpg"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 92])

    # The truth.
    gt = tmp / "synth_gt" / seq
    gt.mkdir(parents=True, exist_ok=True)
    write_pose_json(gt / "pv_pose.json", ts, pv_true)
    write_pose_json(gt / "depth_ahat_pose.json", ts, depth_true)
    np.savez_compressed(gt / "instances.npz", timestamps=ts, positions=traj.obj_pos.astype(np.float64),
                        moving=traj.held, visible=views["visible"].astype(np.float32),
                        boxes=views["boxes"].astype(np.float32), clutter_boxes=views["clutter_boxes"].astype(np.float32),
                        motion_dps=views["motion_dps"].astype(np.float32), twins=views["twins"],
                        depth_offset_s=(depth_offset / cfg.fps).astype(np.float64))
    if device_truth is not None:
        # The device world's truth beside it: the share of the gripped instance's silhouette the hand
        # covers (hand_cover (N, K), PV visibility grid), which instance the hand is on (-1 none),
        # the head's angular speed (deg/s, from the frame before) and, with RGB, the PV camera's exposure
        # (s), gain, metering and the head's turn rate over the exposure (deg/s, shutter open to close).
        np.savez_compressed(gt / "device.npz", **{k: np.asarray(v) for k, v in device_truth.items() if k != "light"})
    (gt / "intervals.json").write_text(json.dumps(intervals, indent=1))
    meta = {
        "objects": [{"name": o.name, "shape": o.shape, "size": o.size.tolist(), "color": o.color.tolist(),
                     "albedo": o.albedo, "twin": o.twin,
                     **({"lookalike": o.lookalike} if scene.world == "device" and o.lookalike else {})}
                    for o in scene.objects],
        "surfaces": [{"name": s.name, "center": s.center.tolist()} for s in scene.surfaces],
        # in the HoloLens mesh at their first place (frame 0), and after they moved
        "instances_in_mesh": [int(j) for j in baked],
        "untracked_objects": [{"name": p.name, "shape": p.shape, "size": p.size.tolist(), "center": p.center.tolist(),
                               "albedo": p.albedo, "in_mesh": p.in_mesh} for p in scene.props],
        "moves": [{"instance": m.instance, "pick_frame": m.pick_frame, "place_frame": m.place_frame,
                   "src": m.src.tolist(), "dst": m.dst.tolist()} for m in traj.moves],
        "relocalisation_jump_frames": [int(j) for j in jumps],
    }
    world = {}
    if device_truth is not None:
        from egograph.synth.materials import photo_sources

        light = device_truth["light"]
        meta["room_light"] = {"level": light.level, "dim": light.dim, "lamps": light.lamps.tolist()}
        world = {"world": "device", "device_revision": DEVICE_REVISION, "photo_packages": photo_sources()}
    (gt / "scene.json").write_text(json.dumps(meta, indent=1))
    (tmp / "recording.json").write_text(json.dumps({
        "generator": "egograph.synth", "version": __version__, "revision": GENERATOR_REVISION, **world,
        "frontend_revision": FRONTEND_REVISION, **({"pv_revision": PV_REVISION} if cfg.pv.rgb else {}), "seed": seed, "sequence": seq,
        "frames": cfg.frames, "detection_sets": sorted(detections), "primary_detections": cfg.detections.primary,
        "config": recorded_config(cfg)}, indent=1))


def recorded_config(cfg: SynthConfig) -> dict:
    """The config a recording carries: a legacy-world recording without the device world's knobs
    (as recordings before the device world, so their records and caches stay comparable)."""
    out = to_dict(cfg)
    if out.get("world") == "legacy":
        out.pop("world")
        out.pop("device", None)
    return out
