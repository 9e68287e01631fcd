"""Negative evidence: the place is in view, the depth shows it empty, and no detection fires.

For a landmark ``xyz`` (world, metres) and a PV frame, the test is:

1. *in view*: ``xyz`` projects inside the PV image (with a margin) in front of the camera,
   within ``negative_max_range_m`` of the AHAT camera; the instance has no accepted
   detection near the landmark in that frame;
2. *depth*: in a small AHAT pixel window around the landmark's projection, each valid pixel
   reads a wrapped range ``m``. The HoloLens mesh (static scene), ray cast along the same
   pixel ray, gives the range ``M`` of the surface behind. With ``R`` the landmark's range
   and ranges compared modulo the alias distance (AHAT wraps):

   * *empty* pixel: the surface seen lies clearly behind the landmark centre
     (``m - R >= margin``, modulo the alias), and so does the mesh (``M > R + margin``,
     which rules out an occluder half an alias distance in front): the ray passed through
     the place where the object would be;
   * *occupied* pixel: the surface seen lies between ``object_radius_m`` in front of the
     centre and ``agree_m`` behind it: something stands there;
   * anything else (an occluder in front) is no evidence either way;

3. a frame says *empty* when most valid window pixels are empty, *occupied* when at least
   half are occupied. The object is gone from the first of ``negative_min_frames``
   consecutive empty frames (checked every ``negative_stride`` frames); an occupied frame
   resets the count.

Depth frames are decoded lazily and cached, so only frames where some landmark is in
view during a gap are read.
"""

from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np

from egograph.geometry.ahat_model import pixel_lookup
from egograph.geometry.hl2ss import (
    ahat_to_world_matrix,
    ahat_unit_rays,
    invert_rigid,
    pose_validity,
    pv_project,
    transform_points,
)
from egograph.geometry.observations import Observations
from egograph.track.config import NegativeConfig


class NegativeEvidence:
    """Callable ``(instance, xyz, frame_from, frame_to) -> first frame the place is seen empty, or None``."""

    def __init__(self, rec, obs: Observations, cfg: NegativeConfig, score_threshold: float):
        self.rec, self.cfg = rec, cfg
        ahat = rec.ahat
        self.alias = float(ahat.alias_m)
        self.m_per_raw = float(rec.depth_factor) / float(ahat.scale)
        self.dirs = ahat_unit_rays(ahat.uv2xy)  # (H, W, 3) float64 unit rays, AHAT camera
        self.ahat_shape = self.dirs.shape[:2]
        self.lookup = pixel_lookup(ahat)
        self.pv_shape = tuple(rec.pv.shape)
        self.scene = rec.mesh_scene()  # the recording's cached scene: the lift already built it
        keep = obs.valid & (np.asarray(obs.score, np.float32) >= np.float32(score_threshold))
        self.det = {}
        for inst in np.unique(obs.instance[keep]):
            m = keep & (obs.instance == inst)
            self.det[int(inst)] = (obs.frame[m].astype(np.int64), obs.world[m])
        self._cache: OrderedDict[int, np.ndarray | None] = OrderedDict()
        self.n_frames_read = 0

    def supported(self, xyz, max_gap_m: float, reach_m: float = 0.1) -> bool:
        """A resting object stands on something: the scene mesh lies at most ``max_gap_m`` below
        ``xyz`` or below a point ``reach_m`` beside it (a centre estimated a little past a table's
        edge), looking down from ``reach_m`` above it (a visible-surface point estimated a little
        below the table top); world y up, as HoloLens world frames are gravity-aligned. True
        without a mesh."""
        if self.scene is None:
            return True
        offsets = reach_m * np.array([[0, 1, 0], [1, 1, 0], [-1, 1, 0], [0, 1, 1], [0, 1, -1]], dtype=np.float64)
        down = np.array([0.0, -1.0, 0.0])
        below = [_cast(self.scene, np.asarray(xyz, dtype=np.float64) + o, down[None])[0] for o in offsets]
        return bool(min(below) - reach_m <= max_gap_m)

    def _depth(self, i: int) -> np.ndarray | None:
        if i in self._cache:
            self._cache.move_to_end(i)
            return self._cache[i]
        raw = self.rec.depth_raw(i)
        self.n_frames_read += 1
        self._cache[i] = raw
        if len(self._cache) > self.cfg.cache_frames:
            self._cache.popitem(last=False)
        return raw

    def _in_view(self, xyz: np.ndarray, frames: np.ndarray) -> np.ndarray:
        """Vectorised over frames: the point projects inside the PV image, in front."""
        rec, cfg = self.rec, self.cfg
        poses = rec.pv_poses[frames]
        ok = rec.pv_valid[frames] & pose_validity(poses)
        inv = np.stack([invert_rigid(p) if v else np.eye(4) for p, v in zip(poses, ok)]) if len(frames) else \
            np.zeros((0, 4, 4))
        cam = np.einsum("i,fij->fj", np.append(xyz, 1.0), inv)[:, :3]
        uv, depth = pv_project(cam, rec.pv.intrinsics)
        rows, cols = self.pv_shape
        m = cfg.image_margin_px
        inside = (depth > 0.1) & (uv[:, 0] >= m) & (uv[:, 0] < cols - m) & (uv[:, 1] >= m) & (uv[:, 1] < rows - m)
        return ok & inside

    def _detected_near(self, instance: int, xyz: np.ndarray, frame: int) -> bool:
        frames, world = self.det.get(instance, (np.zeros(0, np.int64), np.zeros((0, 3))))
        m = frames == frame
        return bool(m.any() and (np.linalg.norm(world[m] - xyz, axis=1) <= self.cfg.detection_gate_m).any())

    def frame_verdict(self, xyz: np.ndarray, i: int) -> int:
        """+1 empty, -1 occupied, 0 no evidence, for landmark ``xyz`` in frame ``i``."""
        rec, cfg = self.rec, self.cfg
        pose = rec.depth_poses[i]
        if self.scene is None or not (rec.depth_valid[i] and pose_validity(pose)):
            return 0
        to_world = ahat_to_world_matrix(rec.ahat.extrinsics, pose)
        p_cam = transform_points(xyz[None], invert_rigid(to_world))[0]
        r_land = float(np.linalg.norm(p_cam))
        if r_land > cfg.max_range_m or p_cam[2] <= 0:
            return 0
        # Through the real rays: intrinsics.bin is a wide viewing pinhole, up to 86 px off on the device.
        uv = self.lookup.project_one(p_cam)
        if uv is None:
            return 0
        h, w = self.ahat_shape
        u, v = int(math.floor(uv[0])), int(math.floor(uv[1]))
        k = cfg.window_px
        if not (k <= u < w - k and k <= v < h - k):
            return 0
        raw = self._depth(i)
        if raw is None:
            return 0
        win = raw[v - k:v + k + 1, u - k:u + k + 1].astype(np.float64).ravel()
        valid = win > 0
        if valid.sum() < 3:
            return 0
        m = win[valid] * self.m_per_raw
        dirs_cam = self.dirs[v - k:v + k + 1, u - k:u + k + 1].reshape(-1, 3)[valid]
        dirs_w = dirs_cam @ to_world[:3, :3]
        origin = to_world[3, :3]
        mesh_r = _cast(self.scene, origin, dirs_w)
        d = _signed(m, r_land, self.alias)
        occupied = (d >= -cfg.object_radius_m) & (d <= cfg.agree_m)
        empty = (d >= cfg.margin_m) & (mesh_r > r_land + cfg.margin_m)
        if occupied.mean() >= 0.5:
            return -1
        return 1 if empty.mean() >= cfg.empty_share else 0

    def __call__(self, instance: int, xyz, frame_from: int, frame_to: int) -> int | None:
        xyz = np.asarray(xyz, dtype=np.float64)
        frames = np.arange(frame_from, frame_to, max(1, self.cfg.stride))
        if not len(frames):
            return None
        frames = frames[self._in_view(xyz, frames)]
        run_start, run = None, 0
        for i in frames:
            i = int(i)
            if self._detected_near(instance, xyz, i):
                run_start, run = None, 0
                continue
            verdict = self.frame_verdict(xyz, i)
            if verdict > 0:
                run_start = i if run == 0 else run_start
                run += 1
                if run >= self.cfg.min_frames:
                    return run_start
            elif verdict < 0:
                run_start, run = None, 0
        return None


def _signed(a: np.ndarray, b: float, alias: float) -> np.ndarray:
    """``a - b`` modulo the alias distance, in ``[-alias/2, alias/2)`` (metres)."""
    return np.mod(np.asarray(a) - b + alias / 2, alias) - alias / 2


def _cast(scene, origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Range (metres) to the mesh along unit rays from ``origin``; inf on a miss."""
    import open3d as o3d

    rays = np.concatenate([np.broadcast_to(origin, dirs.shape), dirs], axis=1).astype(np.float32)
    hit = scene.cast_rays(o3d.core.Tensor(rays))
    return hit["t_hit"].numpy().astype(np.float64)
