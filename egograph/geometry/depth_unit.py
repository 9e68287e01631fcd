"""The raw AHAT depth unit (1 mm or 4 mm) from evidence that holds whether or not the ranges wrap:
the scene mesh.

:meth:`~egograph.io.recording.Recording.detect_depth_factor` reads the unit from the raw values
alone: wrapped 4 mm ranges stay under ~264, 1 mm ones reach ~1055. A 4 mm stream whose ranges
never wrap (an export that unwrapped them, a long-throw mode) also reaches past 300 and reads as
1 mm, every lift 4x short. When the values say 1 mm, the mesh decides: the AHAT rays of a few
frames are cast on it, and each unit is scored by how many readings agree with the mesh range
(directly, or modulo the alias range when they wrap).
"""

from __future__ import annotations

import warnings

import numpy as np

from egograph.geometry.hl2ss import ahat_to_world_matrix, ahat_unit_rays

UNITS = (1.0, 4.0)
"""The raw AHAT units in mm hl2ss versions have written."""

AGREE_M = 0.05
"""A reading agrees with the mesh when within this range of it (metres): the HoloLens mesh is coarse."""

MIN_AGREE = 0.3
"""The winning unit's share of agreeing readings must be at least this, and twice the other's."""


def mesh_depth_unit(rec, frames: int = 5, pixels: int = 2000) -> tuple[float | None, dict[float, float]]:
    """The unit the mesh supports (None: no mesh, no depth, or no clear winner) and each unit's
    share of readings that agree with the mesh range. ``frames`` depth frames, evenly spread;
    about ``pixels`` readings of each, on a fixed grid (deterministic)."""
    try:
        scene = rec.mesh_scene()
    except (ImportError, ValueError, OSError, RuntimeError):
        from egograph.core import signals

        signals.reraise_if_interrupted()
        return None, {}
    if scene is None:
        return None, {}
    import open3d as o3d

    rays = ahat_unit_rays(rec.ahat.uv2xy).astype(np.float32)
    scale = float(rec.ahat.scale)
    alias = float(rec.ahat.alias_m)
    raw_all, hit_all = [], []
    usable = np.flatnonzero(rec.depth_valid)
    for i in usable[np.linspace(0, len(usable) - 1, min(frames, len(usable))).astype(int)] if len(usable) else []:
        raw = rec.depth_raw(int(i))
        if raw is None:
            continue
        ys, xs = np.nonzero(raw > 0)
        if not len(ys):
            continue
        step = max(1, len(ys) // pixels)
        ys, xs = ys[::step], xs[::step]
        m = ahat_to_world_matrix(rec.ahat.extrinsics, rec.depth_poses[int(i)])
        r = np.empty((len(ys), 6), np.float32)
        r[:, :3] = m[3, :3]
        r[:, 3:] = rays[ys, xs] @ m[:3, :3].astype(np.float32)
        hit = scene.cast_rays(o3d.core.Tensor(r))["t_hit"].numpy()
        raw_all.append(raw[ys, xs].astype(np.float64))
        hit_all.append(hit.astype(np.float64))
    if not raw_all:
        return None, {}
    raw = np.concatenate(raw_all)
    hit = np.concatenate(hit_all)
    seen = np.isfinite(hit)
    if seen.sum() < 50:
        return None, {}
    raw, hit = raw[seen], hit[seen]
    share = {}
    for unit in UNITS:
        r = raw * unit / scale
        agree = (np.abs(r - hit) < AGREE_M) | ((r < alias) & (np.abs(r - np.mod(hit, alias)) < AGREE_M))
        share[unit] = float(agree.mean())
    best, other = sorted(UNITS, key=lambda u: -share[u])
    if share[best] >= MIN_AGREE and share[best] >= 2 * share[other]:
        return best, share
    return None, share


def settle_depth_unit(rec, stated: bool, strict: bool = False) -> None:
    """Make the raw unit of ``rec`` evidence-based: a stated unit (``io.depth_factor``) is checked on
    the mesh and kept, with a warning when the mesh clearly supports the other unit (an
    :class:`InputError` with ``strict``); a 4 mm reading from the values (wrapped ranges prove it) is
    kept; a 1 mm reading from the values is checked on the mesh, corrected to 4 mm with a warning when
    the mesh says so, and warned about as a guess when nothing can check it."""
    if stated:
        unit, share = mesh_depth_unit(rec)
        if unit is not None and unit != rec.depth_factor:
            where = rec.seq_dir / "depth_ahat"
            msg = (f"io.depth_factor states raw depth in {rec.depth_factor:g} mm units, "
                   f"but the mesh supports {unit:g} mm ({share[unit]:.0%} of sampled readings agree at {unit:g} mm, "
                   f"{share.get(rec.depth_factor, 0.0):.0%} at {rec.depth_factor:g} mm): every lifted range would be "
                   f"{unit / rec.depth_factor:g}x off")
            if strict:
                from egograph.core.errors import InputError

                raise InputError(where, msg)
            warnings.warn(f"{where}: {msg}", stacklevel=3)
        return
    if rec.depth_factor != 1.0:
        return
    unit, share = mesh_depth_unit(rec)
    if unit == 1.0:
        return
    if unit == 4.0:
        rec.depth_factor = 4.0
        warnings.warn(f"{rec.seq_dir / 'depth_ahat'}: raw depth in 4 mm units, from the mesh ({share[4.0]:.0%} of "
                      f"sampled readings agree at 4 mm, {share[1.0]:.0%} at 1 mm): ranges that never wrap read "
                      "like 1 mm values; set io.depth_factor to state the unit", stacklevel=3)
        return
    why = "no mesh to check it on" if not share else f"the mesh agrees with neither ({share[1.0]:.0%} at 1 mm, " \
                                                     f"{share[4.0]:.0%} at 4 mm)"
    warnings.warn(f"{rec.seq_dir / 'depth_ahat'}: raw depth unit taken as 1 mm from its values alone ({why}); 4 mm "
                  "ranges that never wrap look the same: set io.depth_factor=1 or 4 to state it", stacklevel=3)
