"""Class-agnostic object proposals in a PV frame (boxes in PV pixels, x right, y down).

Sources (``frontend.proposals``):

* ``geometry``: AHAT pixels whose wrapped range lies clearly in front of the scene mesh along the
  same ray (compared modulo the alias distance, so a wrapped reading of the wall is explained),
  grouped into segments (8-connected on the AHAT grid, split where sorted ranges jump by more than
  ``cluster_gap_m``), lifted to world points and projected into the PV image with the per-frame
  poses. A wrapped range leaves the true range ambiguous: the segment is projected at the range
  just in front of the mesh and, when that differs, at the wrapped reading itself (an object held
  near the eye); the parallax between the two sensors makes the boxes differ, the matcher decides.
* ``mesh``: the small objects standing in the scene mesh (:mod:`egograph.frontend.mesh_objects`:
  large planes removed, the rest clustered), found once per recording; in each frame the
  cluster points the PV camera sees (a ray cast against the mesh reaches them) are projected and
  boxed. Geometry cannot see these objects (the mesh explains them), however far or small.
* ``image``: OpenCV graph segmentation of the downscaled frame, one box per segment; with
  ``image_selective``, also the boxes of selective search's hierarchical grouping of segments.
* an ONNX mask model by path: one box per predicted mask.

:func:`nms` merges them per frame.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from egograph.core.errors import InputError
from egograph.frontend.config import FrontendConfig
from egograph.geometry.hl2ss import ahat_to_world_matrix, ahat_unit_rays, invert_rigid, pose_validity, pv_project

BUILTIN_SOURCES = ("geometry", "mesh", "image")
SOURCE_RANK = {"geometry": 0, "mesh": 1, "mask": 2, "image": 3}


@dataclass
class Proposal:
    """A box ``(x1, y1, x2, y2)`` in PV pixels from ``source``, with a confidence 0-1."""

    box: tuple[float, float, float, float]
    source: str
    conf: float = 1.0

    @property
    def area(self) -> float:
        x1, y1, x2, y2 = self.box
        return max(0.0, x2 - x1) * max(0.0, y2 - y1)


def iou(a, b) -> float:
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def keep_plausible(props: list[Proposal], shape: tuple[int, int], cfg: FrontendConfig) -> list[Proposal]:
    """Clip to the image (rows, cols) and drop boxes too small or too large (see the knobs)."""
    rows, cols = shape
    out = []
    for p in props:
        x1, y1, x2, y2 = p.box
        x1, x2 = float(np.clip(x1, 0, cols)), float(np.clip(x2, 0, cols))
        y1, y2 = float(np.clip(y1, 0, rows)), float(np.clip(y2, 0, rows))
        if min(x2 - x1, y2 - y1) < cfg.min_box_px or (x2 - x1) * (y2 - y1) > cfg.max_box_share * rows * cols:
            continue
        out.append(Proposal((x1, y1, x2, y2), p.source, p.conf))
    return out


def frame_proposals(sources: list, i: int, rgb: np.ndarray, cfg: FrontendConfig
                    ) -> tuple[list[list[Proposal]], list[Proposal]]:
    """PV frame ``i``'s proposals as ``detect`` makes them, before the ranking and the cap: each
    source's boxes (``sources`` from :func:`proposal_sources`, in their order) and the plausible ones
    of them all (:func:`keep_plausible`, source after source)."""
    raw = [src(i, rgb) for src in sources]
    return raw, [q for got in raw for q in keep_plausible(got, rgb.shape[:2], cfg)]


def nms(props: list[Proposal], iou_max: float, limit: int, rank: np.ndarray | None = None) -> list[Proposal]:
    """Greedy non-maximum suppression, at most ``limit`` kept: higher ``rank`` first (one per
    proposal, :func:`rank_scores`; ties keep the list's order), or without it geometry first, then
    mesh, mask and image proposals, larger confidence then larger area first; a box overlapping a
    kept one by more than ``iou_max`` goes."""
    if rank is None:
        order = sorted(props, key=lambda p: (SOURCE_RANK.get(p.source, 9), -p.conf, -p.area))
    else:
        order = [props[k] for k in np.argsort(-np.asarray(rank, np.float64), kind="stable")]
    kept: list[Proposal] = []
    for p in order:
        if all(iou(p.box, k.box) <= iou_max for k in kept):
            kept.append(p)
            if len(kept) >= limit:
                break
    return kept


def iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of every box of ``a`` (N, 4) with every box of ``b`` (M, 4) -> (N, M)."""
    ix = np.clip(np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0]), 0, None)
    iy = np.clip(np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1]), 0, None)
    inter = ix * iy
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a[:, None] + area_b[None, :] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def rank_scores(props: list[Proposal], rgb: np.ndarray, cfg: FrontendConfig) -> np.ndarray | None:
    """Each proposal's place in the per-frame cap under ``cfg.proposal_order`` (None: the source
    order of :func:`nms`). ``objectness``: the box's :func:`objectness` on the frame downscaled by
    ``image_scale`` (0-1) plus its agreement with the other sources, the largest IoU with a box
    another source proposed (0-1). Why both: a depth segment of range noise or a segment of a
    wall's shading stands out little from its surround and no other source outlines it, while an
    object on a table does both; neither term grows with the box (means, ratios), so a small object
    competes with a large one for the cap."""
    import cv2

    if cfg.proposal_order == "source" or not props:
        return None
    box = np.array([p.box for p in props], np.float64)
    s = cfg.image_scale
    small = cv2.resize(rgb, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
    rows, cols = small.shape[:2]
    scaled = np.clip(box * s, 0, [cols, rows, cols, rows])
    src = np.array([p.source for p in props])
    agree = np.where(src[:, None] != src[None, :], iou_matrix(box, box), 0.0).max(axis=1)
    return objectness(integral_lab(small), scaled) + agree


# --------------------------------------------------------------------------- geometry


class GeometryProposals:
    """Proposals from AHAT depth the recording's mesh does not explain (see module doc)."""

    def __init__(self, rec, cfg: FrontendConfig):
        self.rec, self.cfg = rec, cfg
        ahat = rec.ahat
        self.alias = float(ahat.alias_m)
        self.m_per_raw = float(rec.depth_factor) / float(ahat.scale)
        k = cfg.depth_stride
        self.dirs = ahat_unit_rays(ahat.uv2xy)[::k, ::k]
        valid = getattr(ahat, "valid_mask", None)
        self.ray_ok = np.ones(self.dirs.shape[:2], bool) if valid is None else np.asarray(valid, bool)[::k, ::k]
        self.min_px = max(1, int(np.ceil(cfg.min_segment_px / k ** 2)))
        self.scene = rec.mesh_scene()
        if self.scene is None:
            raise InputError(rec.seq_dir, "geometry proposals need the recording's mesh (mesh/*.ply); none found: "
                                          "use --proposals image")

    def unexplained(self, raw: np.ndarray, to_world: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(mask (H, W), wrapped range (H, W), mesh range (H, W))``, metres: valid pixels whose
        reading lies at least ``unexplained_m`` in front of the mesh modulo the alias."""
        import open3d as o3d

        m = raw.astype(np.float64) * self.m_per_raw
        ok = (raw > 0) & self.ray_ok
        vs, us = np.nonzero(ok)
        dirs_w = self.dirs[vs, us] @ to_world[:3, :3]
        rays = np.concatenate([np.broadcast_to(to_world[3, :3], dirs_w.shape), dirs_w], axis=1).astype(np.float32)
        mesh_r = np.full(raw.shape, np.inf)
        mesh_r[vs, us] = self.scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        a = self.alias
        with np.errstate(invalid="ignore"):  # inf mesh range (a miss) gives NaN, masked out below
            d = np.mod(m - mesh_r + a / 2, a) - a / 2
        mask = ok & np.isfinite(mesh_r) & (d <= -self.cfg.unexplained_m) & (mesh_r + d <= self.cfg.max_range_m)
        return mask, m, mesh_r

    def segments(self, mask: np.ndarray, m: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """``[(rows, cols)]`` of AHAT pixel segments (see module doc)."""
        import cv2

        n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
        flat = labels.ravel()
        order = np.argsort(flat, kind="stable")
        starts = np.searchsorted(flat[order], np.arange(n + 1))
        out = []
        for lab in range(1, n):
            if stats[lab, cv2.CC_STAT_AREA] < self.min_px:
                continue
            idx = order[starts[lab]:starts[lab + 1]]
            vs, us = np.divmod(idx, labels.shape[1])
            r = m[vs, us]
            srt = np.argsort(r)
            cuts = np.nonzero(np.diff(r[srt]) > self.cfg.cluster_gap_m)[0] + 1
            for part in np.split(srt, cuts):
                if len(part) >= self.min_px:
                    out.append((vs[part], us[part]))
        return out

    def __call__(self, i: int, raw: np.ndarray | None = None) -> list[Proposal]:
        rec = self.rec
        raw = rec.depth_raw(i) if raw is None else raw
        if raw is not None:
            raw = raw[::self.cfg.depth_stride, ::self.cfg.depth_stride]
        pose, pv_pose = rec.depth_poses[i], rec.pv_poses[i]
        if raw is None or not (rec.depth_valid[i] and rec.pv_valid[i] and pose_validity(pose)
                               and pose_validity(pv_pose)):
            return []
        to_world = ahat_to_world_matrix(rec.ahat.extrinsics, pose)
        to_pv = to_world @ invert_rigid(pv_pose)
        mask, m, mesh_r = self.unexplained(raw, to_world)
        a, props = self.alias, []
        for vs, us in self.segments(mask, m):
            fill = len(vs) / ((np.ptp(vs) + 1.0) * (np.ptp(us) + 1.0))
            if fill < self.cfg.min_fill:
                continue   # sparse speckle (dark or grazing surfaces), not a solid object
            wrapped = m[vs, us]
            with np.errstate(invalid="ignore"):
                d = np.mod(wrapped - mesh_r[vs, us] + a / 2, a) - a / 2
            near_mesh = np.median(mesh_r[vs, us] + d)
            ranges = [near_mesh]
            if self.cfg.near_eye_candidates and near_mesh - np.median(wrapped) > self.cfg.cluster_gap_m:
                ranges.append(np.median(wrapped))    # held near the eye: the reading did not wrap
            for r_med in ranges:
                r = wrapped + (r_med - np.median(wrapped))   # keep the segment's range spread
                cam = self.dirs[vs, us] * r[:, None]
                lo3, hi3 = np.percentile(cam, [5, 95], axis=0)      # one call: most of the time per segment
                if not self.cfg.min_object_m <= float(np.max(hi3 - lo3)) <= self.cfg.max_object_m:
                    continue   # furniture the mesh lacks, or range speckle: not a small object
                pv_cam = cam @ to_pv[:3, :3] + to_pv[3, :3]
                uv, depth = pv_project(pv_cam, rec.pv.intrinsics)
                uv = uv[depth > 0.05]
                if len(uv) < self.min_px:
                    continue
                lo, hi = np.percentile(uv, [2, 98], axis=0)
                pad = self.cfg.box_pad_px
                props.append(Proposal((lo[0] - pad, lo[1] - pad, hi[0] + pad, hi[1] + pad), "geometry",
                                      conf=float(min(1.0, len(vs) * self.cfg.depth_stride ** 2 / 50.0))))
        return props


# --------------------------------------------------------------------------- mesh


_MESH_OBJECTS: dict = {}   # (mesh digest, parameters) -> its objects, the last few meshes


class MeshObjectProposals:
    """Boxes of the scene mesh's small objects as the PV camera sees them (see module doc). The
    confidence is the share of the object's surface points in view and unoccluded."""

    def __init__(self, rec, cfg: FrontendConfig):
        from egograph.frontend.mesh_objects import segment_mesh_objects

        self.rec, self.cfg = rec, cfg
        self.scene = rec.mesh_scene()
        if self.scene is None:
            raise InputError(rec.seq_dir, "mesh proposals need the recording's mesh (mesh/*.ply); none found: "
                                          "use --proposals image")
        mesh = rec.mesh()
        v, t = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
        params = dict(spacing_m=cfg.mesh_spacing_m, plane_min_m2=cfg.mesh_plane_min_m2, min_extent_m=cfg.min_object_m,
                      max_extent_m=cfg.max_object_m, min_normal_spread=cfg.mesh_min_normal_spread,
                      max_support_share=cfg.mesh_max_support_share)
        # SVOE and MVPE runs of one process (the demo, egograph run) segment a mesh once
        key = (hashlib.sha1(v.tobytes() + t.tobytes()).hexdigest(), tuple(sorted(params.items())))
        if key not in _MESH_OBJECTS:
            if len(_MESH_OBJECTS) >= 4:
                _MESH_OBJECTS.pop(next(iter(_MESH_OBJECTS)))
            _MESH_OBJECTS[key] = segment_mesh_objects(v, t, **params)
        self.objects = _MESH_OBJECTS[key]
        self.n_points = np.array([len(o.points) for o in self.objects], np.int64)   # surface points per object
        self.points = np.vstack([o.points for o in self.objects]) if self.objects else np.zeros((0, 3))
        self.owner = np.repeat(np.arange(len(self.objects)), self.n_points)

    def __call__(self, i: int) -> list[Proposal]:
        import open3d as o3d

        rec = self.rec
        pose = rec.pv_poses[i]
        if not (rec.pv_valid[i] and pose_validity(pose)) or len(self.points) == 0:
            return []
        cam_c = pose[3, :3]
        to_cam = invert_rigid(pose)
        uv, depth = pv_project(self.points @ to_cam[:3, :3] + to_cam[3, :3], rec.pv.intrinsics)
        rows, cols = rec.pv.shape
        ahead = (depth > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < cols) & (uv[:, 1] >= 0) & (uv[:, 1] < rows)
        if not ahead.any():
            return []
        sel = np.nonzero(ahead)[0]
        ray = self.points[sel] - cam_c
        dist = np.linalg.norm(ray, axis=1)
        rays = np.concatenate([np.broadcast_to(cam_c, ray.shape), ray / dist[:, None]], axis=1).astype(np.float32)
        hit = self.scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        seen = sel[hit >= dist - (0.02 + 0.01 * dist)]
        props = []
        for k in np.unique(self.owner[seen]):
            mine = seen[self.owner[seen] == k]
            share = len(mine) / self.n_points[k]
            if len(mine) < 5 or share < self.cfg.mesh_min_visible:
                continue
            lo, hi = uv[mine].min(axis=0), uv[mine].max(axis=0)
            pad = self.cfg.box_pad_px
            props.append(Proposal((lo[0] - pad, lo[1] - pad, hi[0] + pad, hi[1] + pad), "mesh", float(share)))
        return props


# --------------------------------------------------------------------------- image


class ImageProposals:
    """Boxes of OpenCV graph-segmentation segments (``cv2.ximgproc``, the contrib package), at one
    scale (``seg_k``) or several (``image_k_scales``); with ``image_per_scale`` each scale keeps its
    most object-like segments (:func:`objectness`), which is then their confidence. With
    ``image_selective``, also every box of OpenCV's selective search on the same downscaled frame
    (:func:`selective_search_boxes`), its objectness as confidence."""

    def __init__(self, cfg: FrontendConfig):
        import cv2

        if not hasattr(cv2, "ximgproc"):
            raise InputError(Path(cv2.__file__), "image proposals need OpenCV's contrib modules: "
                                                 "pip install opencv-contrib-python-headless")
        self.cfg = cfg
        ks = cfg.image_k_scales or [cfg.seg_k]
        self.segs = [cv2.ximgproc.segmentation.createGraphSegmentation(cfg.seg_sigma, float(k), cfg.seg_min_size)
                     for k in ks]

    def __call__(self, rgb: np.ndarray) -> list[Proposal]:
        import cv2

        s = self.cfg.image_scale
        small = cv2.resize(rgb, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
        bgr = cv2.cvtColor(small, cv2.COLOR_RGB2BGR)
        rows, cols = small.shape[:2]
        vs, us = np.divmod(np.arange(rows * cols), cols)
        ranked = self.cfg.image_per_scale > 0
        lab_sum = integral_lab(small) if ranked else None
        out = []
        for seg in self.segs:
            labels = seg.processImage(bgr).ravel()
            n = int(labels.max()) + 1
            # every segment's bounding box in one pass over the pixels (not one mask per segment)
            lo_u, lo_v = np.full(n, cols), np.full(n, rows)
            hi_u, hi_v = np.full(n, -1), np.full(n, -1)
            np.minimum.at(lo_u, labels, us)
            np.minimum.at(lo_v, labels, vs)
            np.maximum.at(hi_u, labels, us)
            np.maximum.at(hi_v, labels, vs)
            ok = np.nonzero(hi_u >= 0)[0]
            box = np.column_stack([lo_u[ok], lo_v[ok], hi_u[ok] + 1, hi_v[ok] + 1]).astype(np.float64)
            if ranked:
                fill = np.bincount(labels, minlength=n)[ok] / np.maximum((box[:, 2] - box[:, 0]) * (box[:, 3] - box[:, 1]), 1)
                conf = objectness(lab_sum, box) * np.sqrt(fill)
                order = np.argsort(-conf, kind="stable")[:self.cfg.image_per_scale]
            else:
                conf, order = np.full(len(ok), 0.5), np.arange(len(ok))
            out += [Proposal(tuple(float(v) for v in box[j] / s), "image", float(conf[j])) for j in order]
        if self.cfg.image_selective != "none":
            box = selective_search_boxes(bgr, self.cfg.image_selective)
            conf = objectness(lab_sum if lab_sum is not None else integral_lab(small), box)
            out += [Proposal(tuple(float(v) for v in b / s), "image", float(c)) for b, c in zip(box, conf)]
        return out


def selective_search_boxes(bgr: np.ndarray, mode: str) -> np.ndarray:
    """The boxes (N, 4: x1, y1, x2, y2, pixels of ``bgr``) of OpenCV's selective search on ``bgr``
    (``cv2.ximgproc.segmentation``), ``mode`` 'single' or 'fast', sorted by their corners: OpenCV
    returns the same set in a random order that changes from call to call, and the order must not
    decide which box a tie in the cap keeps."""
    import cv2

    search = cv2.ximgproc.segmentation.createSelectiveSearchSegmentation()
    search.setBaseImage(bgr)
    if mode == "single":
        search.switchToSingleStrategy()
    else:
        search.switchToSelectiveSearchFast()
    r = np.asarray(search.process(), np.float64).reshape(-1, 4)   # x, y, w, h
    return np.unique(np.column_stack([r[:, 0], r[:, 1], r[:, 0] + r[:, 2], r[:, 1] + r[:, 3]]), axis=0)


def integral_lab(rgb: np.ndarray) -> np.ndarray:
    """Integral image (H + 1, W + 1, 3) of the CIE Lab colours of ``rgb`` (L 0-100, a and b about -128-127)."""
    import cv2

    lab = cv2.cvtColor(rgb.astype(np.float32) / 255.0, cv2.COLOR_RGB2LAB)
    out = np.zeros((lab.shape[0] + 1, lab.shape[1] + 1, 3), np.float64)
    out[1:, 1:] = lab.cumsum(0).cumsum(1)
    return out


def _box_sum(ii: np.ndarray, b: np.ndarray) -> np.ndarray:
    x1, y1, x2, y2 = (b[:, k].astype(int) for k in range(4))
    return ii[y2, x2] - ii[y1, x2] - ii[y2, x1] + ii[y1, x1]


def objectness(ii: np.ndarray, box: np.ndarray) -> np.ndarray:
    """How much each box (N, 4; pixels of the image of the integral ``ii``) stands out from its
    surround: the Lab distance between the box's mean colour and the mean colour of the ring
    around it (the box grown by half its side each way, clipped), mapped to 0-1 by ``1 - exp(-d /
    20)``. Means, not sums: a large box gains nothing by its size."""
    rows, cols = ii.shape[0] - 1, ii.shape[1] - 1
    w, h = box[:, 2] - box[:, 0], box[:, 3] - box[:, 1]
    outer = np.column_stack([np.clip(box[:, 0] - w / 2, 0, cols), np.clip(box[:, 1] - h / 2, 0, rows),
                             np.clip(box[:, 2] + w / 2, 0, cols), np.clip(box[:, 3] + h / 2, 0, rows)]).round()
    inner = box.round()
    a_in = np.maximum((inner[:, 2] - inner[:, 0]) * (inner[:, 3] - inner[:, 1]), 1)[:, None]
    a_out = ((outer[:, 2] - outer[:, 0]) * (outer[:, 3] - outer[:, 1]))[:, None] - a_in
    s_in, s_out = _box_sum(ii, inner), _box_sum(ii, outer)
    ring = (s_out - s_in) / np.maximum(a_out, 1)
    d = np.linalg.norm(s_in / a_in - ring, axis=1)
    return np.where(a_out[:, 0] > 0, 1.0 - np.exp(-d / 20.0), 0.0)


# --------------------------------------------------------------------------- ONNX mask model


class MaskModelProposals:
    """An ONNX mask model by path: input float32 (1, 3, H, W) RGB scaled 0-1 (H, W fixed by the
    model, or the frame's size when symbolic); output (1, K, h, w) (or (K, h, w)) mask
    probabilities; one box per mask with any pixel >= ``mask_threshold``, confidence = its mean
    probability inside."""

    def __init__(self, path: str | Path, cfg: FrontendConfig):
        from egograph.frontend.encoder import _session

        self.path, self.cfg = Path(path), cfg
        if not self.path.is_file():
            raise InputError(self.path, "mask model not found (frontend.proposals: 'geometry', 'image', "
                                        "'geometry+image' or an ONNX file)")
        self.session = _session(self.path, cfg.threads)
        ins = self.session.get_inputs()
        if len(ins) != 1 or len(ins[0].shape) != 4 or ins[0].shape[1] not in (3, "C"):
            raise InputError(self.path, "a mask model takes one (1, 3, H, W) float input; this one takes "
                                        + ", ".join(f"{i.name} {list(i.shape)}" for i in ins))
        self.input = ins[0]

    def __call__(self, rgb: np.ndarray) -> list[Proposal]:
        import cv2

        rows, cols = rgb.shape[:2]
        h, w = self.input.shape[2:]
        h = h if isinstance(h, int) else rows
        w = w if isinstance(w, int) else cols
        x = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
        masks = np.asarray(self.session.run(None, {self.input.name: x.transpose(2, 0, 1)[None]})[0])
        if masks.ndim == 4:
            masks = masks[0]
        if masks.ndim != 3:
            raise InputError(self.path, f"mask output has shape {list(masks.shape)}; expected (1, K, h, w)")
        sy, sx = rows / masks.shape[1], cols / masks.shape[2]
        out = []
        for m in masks:
            on = m >= self.cfg.mask_threshold
            if not on.any():
                continue
            vs, us = np.nonzero(on)
            out.append(Proposal((us.min() * sx, vs.min() * sy, (us.max() + 1) * sx, (vs.max() + 1) * sy), "mask",
                                float(m[on].mean())))
        return out


def proposal_sources(rec, cfg: FrontendConfig, name: str | None = None) -> list:
    """The callables ``(i, rgb) -> [Proposal]`` for ``name`` (default ``cfg.proposals``)."""
    name = name or cfg.proposals
    parts = name.split("+")
    if all(p in BUILTIN_SOURCES for p in parts) and len(set(parts)) == len(parts):
        out = []
        if "geometry" in parts:
            geo = GeometryProposals(rec, cfg)
            out.append(lambda i, rgb: geo(i))
        if "mesh" in parts:
            mesh = MeshObjectProposals(rec, cfg)
            out.append(lambda i, rgb: mesh(i))
        if "image" in parts:
            img = ImageProposals(cfg)
            out.append(lambda i, rgb: img(rgb))
        return out
    if name.endswith(".onnx") or Path(name).is_file():
        mm = MaskModelProposals(name, cfg)
        return [lambda i, rgb: mm(rgb)]
    raise InputError(Path(name), "unknown proposal source: 'geometry', 'mesh' or 'image', or several of them "
                                 "joined by '+' (e.g. 'geometry+mesh+image'), or an ONNX mask model file")
