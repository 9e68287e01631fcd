"""More SVOE enrollment views when the enrollment frame is smeared by head motion.

An SVOE box is drawn in the first frame where the instance is fully in view, and that frame often
comes while the head is still turning towards it: the first frame a whole object enters the view
is mid-sweep. At 200 deg/s a 33 ms PV exposure smears the image by tens of pixels, and the box then
holds a blur of the object's colours that neither the embedding nor local features can match (in
the device-like world, 27 of the 39 enrollments of tuning recordings 27-32 came at more than 30
deg/s, half of them above 190 deg/s). The head slows down once it faces the object, and objects
seldom move before the person reaches them. So the object point behind the box (world metres:
the robust lift of the box, as detections are lifted, or, where the box has no depth, the scene
mesh along the ray through its centre) is projected with the reported poses into the nearest
frames in which the head turns slowly, the box scaled by the ratio of ranges; those crops become
further enrollment views.

Frames: PV camera poses are camera -> world, row vectors (:mod:`egograph.geometry.hl2ss`); pixels
x right, y down; angular speeds in degrees per second.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from egograph.core.units import TICKS_PER_SECOND
from egograph.geometry.hl2ss import invert_rigid, pose_validity, pv_project, pv_unproject, transform_points


def turn_rate_dps(poses: np.ndarray, timestamps: np.ndarray) -> np.ndarray:
    """The head's turn rate at each PV frame (deg/s): the rotation angle between consecutive camera
    poses ((N, 4, 4), camera -> world) over their time gap (``timestamps``, ticks), averaged over
    the gaps before and after the frame (one frame: 0). Next to an invalid pose (not a rotation) the
    rate means nothing; :func:`projected_boxes` and :func:`object_point` check pose validity."""
    r = np.asarray(poses, np.float64)[:, :3, :3]
    n = len(r)
    if n < 2:
        return np.zeros(n)
    t = np.asarray(timestamps, np.int64) / TICKS_PER_SECOND
    rel = np.einsum("nij,nkj->nik", r[:-1], r[1:])
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    step = np.degrees(np.arccos(cos)) / np.maximum(np.diff(t), 1e-6)
    out = np.empty(n)
    out[0], out[-1] = step[0], step[-1]
    out[1:-1] = (step[:-1] + step[1:]) / 2
    return out


@dataclass
class SharpViews:
    """The extra views of one instance: PV frame indices and boxes (x1, y1, x2, y2; PV pixels), and
    where the object point came from ('depth', 'mesh') or why there is none."""

    frames: list[int]
    boxes: list[tuple[float, float, float, float]]
    point_from: str


def object_point(rec, i: int, box, lift_cfg, ctx) -> tuple[np.ndarray | None, str]:
    """The object point behind ``box`` in PV frame ``i`` (world, metres) and where it came from:
    the robust lift (``'depth'``; :func:`egograph.geometry.robust_lift.robust_box_point`, ``ctx`` its
    context), else the first scene-mesh surface along the ray through the box centre (``'mesh'``;
    the object itself when it stood still while the room was mapped, else what stands behind it),
    else (None, the lift's reason)."""
    from egograph.geometry.chains import frame_chains
    from egograph.geometry.robust_lift import robust_box_point

    chains = frame_chains(rec, i, posed=lift_cfg.registration == "posed")
    raw = rec.depth_raw(i) if chains is not None else None
    got = robust_box_point(ctx, raw, chains, np.asarray(box, np.float64)) if raw is not None else "no depth frame"
    if not isinstance(got, str):
        return transform_points(got[0], chains.ahat_to_world), "depth"
    pose = rec.pv_poses[i]
    if ctx.raycaster is None or not (rec.pv_valid[i] and pose_validity(pose)):
        return None, got
    import open3d as o3d

    pose = np.asarray(pose, np.float64)
    centre = np.array([(box[0] + box[2]) / 2, (box[1] + box[3]) / 2], np.float64)
    d = transform_points(pv_unproject(centre, 1.0, rec.pv.intrinsics), pose) - pose[3, :3]
    d /= np.linalg.norm(d)
    ray = np.concatenate([pose[3, :3], d])[None].astype(np.float32)
    t = float(ctx.raycaster.cast_rays(o3d.core.Tensor(ray))["t_hit"].numpy()[0])
    if not np.isfinite(t):
        return None, f"{got}; the mesh has no surface along the box's ray"
    return pose[3, :3] + t * d, "mesh"


def projected_boxes(rec, i: int, box, point: np.ndarray, rate: np.ndarray, shape: tuple[int, int],
                    n: int, max_dps: float, window_s: float, gap_s: float) -> tuple[list[int], list[tuple]]:
    """Up to ``n`` (frames, boxes): ``box`` of PV frame ``i`` carried to the frames within
    ``window_s`` seconds of it where the head turns at most ``max_dps`` (``rate``), nearest in time
    first and at least ``gap_s`` apart, by projecting ``point`` (world) with the reported poses: the
    box keeps its offset from the point's projection and scales with the range; boxes not wholly
    inside the image (``shape``: rows, cols) are skipped."""
    k = np.asarray(rec.pv.intrinsics, np.float64)
    t = np.asarray(rec.timestamps, np.int64) / TICKS_PER_SECOND

    def project(f: int) -> tuple[np.ndarray, float]:
        uv, z = pv_project(transform_points(point, invert_rigid(rec.pv_poses[f])), k)
        return uv, float(z)

    uv_i, z_i = project(i)
    if not z_i > 0:
        return [], []
    x1, y1, x2, y2 = (float(v) for v in box)
    offset = np.array([(x1 + x2) / 2, (y1 + y2) / 2]) - uv_i
    w, h = x2 - x1, y2 - y1
    rows, cols = shape
    frames, boxes = [], []
    for f in np.argsort(np.abs(t - t[i]), kind="stable"):
        f = int(f)
        if len(frames) >= n or abs(t[f] - t[i]) > window_s:
            break
        if f == i or not rate[f] <= max_dps or not (rec.pv_valid[f] and pose_validity(rec.pv_poses[f])) \
                or any(abs(t[f] - t[g]) < gap_s for g in frames):
            continue
        uv, z = project(f)
        if not z > 0.05:
            continue
        s = z_i / z
        c = uv + offset * s
        b = (c[0] - s * w / 2, c[1] - s * h / 2, c[0] + s * w / 2, c[1] + s * h / 2)
        if b[0] >= 0 and b[1] >= 0 and b[2] <= cols and b[3] <= rows:
            frames.append(f)
            boxes.append(tuple(float(v) for v in b))
    return frames, boxes


def sharp_views(rec, i: int, box, shape: tuple[int, int], cfg, lift_cfg, rate: np.ndarray, ctx) -> SharpViews:
    """The extra enrollment views of the SVOE ``box`` in PV frame ``i`` (``cfg``: the
    :class:`~egograph.frontend.config.FrontendConfig`, its ``svoe_sharp_*`` knobs; ``rate``:
    :func:`turn_rate_dps` of the recording; ``ctx``: the robust lift's context)."""
    point, how = object_point(rec, i, box, lift_cfg, ctx)
    if point is None:
        return SharpViews([], [], how)
    frames, boxes = projected_boxes(rec, i, box, point, rate, shape, cfg.svoe_sharp_views, cfg.svoe_sharp_dps,
                                    cfg.svoe_sharp_window_s, cfg.svoe_sharp_gap_s)
    return SharpViews(frames, boxes, how)
