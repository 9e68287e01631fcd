"""AHAT point clouds for the ICP constraints: subsampled rays, alias unwrapping, range limits.

AHAT readings wrap at the alias distance (about 1.06 m), so a reading ``r`` may be a surface
at ``r + k·alias``. Two modes:

* with the HoloLens mesh (``unwrap_with_mesh``): the mesh is ray cast from the *reported*
  AHAT pose along the subsampled rays; each reading takes the alias count ``k`` that brings
  it nearest to the rendered range and is kept only within ``unwrap_tolerance`` of it. The
  pose error (centimetres) is far below the alias distance, so the choice of ``k`` is safe;
  the point itself stays a measurement (only ``k`` comes from the mesh).
* without: only the unaliased near range is trusted, readings are taken as they are and
  limited to ``min(max_range, 0.95 · alias)``.

Points are returned in the AHAT camera frame (x right, y down, z forward; metres).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from egograph.geometry.hl2ss import ahat_raw_to_range, ahat_unit_rays, invert_rigid
from egograph.io.recording import mesh_raycasting_scene
from egograph.poses.config import RefineConfig


@dataclass
class AhatPointSource:
    rec: object                 # egograph.io.recording.Recording
    cfg: RefineConfig
    rows: np.ndarray            # (M,) pixel rows used
    cols: np.ndarray            # (M,) pixel columns used
    dirs: np.ndarray            # (M, 3) unit ray directions, AHAT camera frame
    raycaster: object | None    # open3d.t.geometry.RaycastingScene of the mesh, or None
    alias_m: float

    @classmethod
    def create(cls, rec, cfg: RefineConfig, mesh=None) -> "AhatPointSource":
        """Rays of every ``point_stride``-th pixel; a raycaster of ``mesh`` (default: the recording's cached
        mesh scene) when unwrapping."""
        s = cfg.point_stride
        h, w = rec.ahat.shape
        rr, cc = np.meshgrid(np.arange(s // 2, h, s), np.arange(s // 2, w, s), indexing="ij")
        rows, cols = rr.ravel(), cc.ravel()
        dirs = ahat_unit_rays(rec.ahat.uv2xy[rows, cols])
        rc = None
        if cfg.unwrap_with_mesh:
            rc = rec.mesh_scene() if mesh is None else mesh_raycasting_scene(mesh)
        return cls(rec=rec, cfg=cfg, rows=rows, cols=cols, dirs=dirs, raycaster=rc, alias_m=rec.ahat.alias_m)

    def ahat_to_world(self, i: int) -> np.ndarray | None:
        """Reported AHAT camera -> world (row-vector 4x4) of frame i, or None without a depth pose."""
        if not self.rec.depth_valid[i]:
            return None
        return invert_rigid(self.rec.ahat.extrinsics) @ self.rec.depth_poses[i]

    def points(self, i: int, ahat_to_world: np.ndarray | None = None) -> np.ndarray | None:
        """Usable AHAT points of frame i (M, 3) in the AHAT camera frame, or None (no depth image).

        ``ahat_to_world`` (row-vector) is the pose the mesh is rendered from for unwrapping;
        default the reported one.
        """
        raw = self.rec.depth_raw(i)
        if raw is None:
            return None
        r = ahat_raw_to_range(raw[self.rows, self.cols], self.rec.ahat.scale, self.rec.depth_factor)
        ok = r > 0
        cfg = self.cfg
        if ahat_to_world is None:
            ahat_to_world = self.ahat_to_world(i)
        if self.raycaster is not None and ahat_to_world is not None:
            expected = self._render(ahat_to_world)
            k = np.clip(np.rint((expected - r) / self.alias_m), 0, None)
            k = np.where(np.isfinite(k), k, 0)
            r = r + k * self.alias_m
            ok &= np.isfinite(expected) & (np.abs(r - expected) < cfg.unwrap_tolerance)
            ok &= (r >= cfg.min_range) & (r <= cfg.max_range)
        else:
            ok &= (r >= cfg.min_range) & (r <= min(cfg.max_range, 0.95 * self.alias_m))
        return self.dirs[ok] * r[ok, None]

    def _render(self, ahat_to_world: np.ndarray) -> np.ndarray:
        """Range (m) to the mesh along every ray from the given AHAT pose; inf where the ray misses."""
        import open3d as o3d

        m = np.asarray(ahat_to_world, dtype=np.float64)
        d_world = self.dirs @ m[:3, :3]
        rays = np.concatenate([np.broadcast_to(m[3, :3], d_world.shape), d_world], axis=1).astype(np.float32)
        hit = self.raycaster.cast_rays(o3d.core.Tensor(rays))
        return hit["t_hit"].numpy().astype(np.float64)
