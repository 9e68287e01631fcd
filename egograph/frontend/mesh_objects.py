"""Small objects standing in the scene mesh: the HoloLens mesh holds what stood still while the
room was mapped, objects included, as blobs on the tables and shelves. Found as classic tabletop
segmentation does on a point cloud:

1. sample the mesh surface evenly (``voxel_m`` apart, seeded: the same mesh gives the same points);
2. find the large planar regions (floor, walls, ceiling, table tops, shelves), each at least
   ``plane_min_m2`` of surface, from the directions the surface normals share and the offsets
   along them (:func:`remove_planes`), and drop their points;
3. cluster what is left (Open3D ``cluster_dbscan``) and keep the clusters an object could be:
   ``min_extent_m``-``max_extent_m`` across, with at least the surface of a cube of the smallest
   extent standing on a table (five faces: fewer points are a fragment, such as a table top's
   corner), not flat (their normals spread: a leftover patch of wall or the edge of a table top
   has one normal), and not lying along the support that was removed (a seam where floor meets
   wall, or wall meets ceiling, is left over with mixed normals where the mesh rounds the corner;
   its points all lie within a few centimetres of floor and wall, while an object rises above
   its table: at most ``max_support_share`` of a cluster's points within 3 spacings of removed
   support).

World frame, metres; no up axis is assumed (the planes are found in any orientation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class MeshObject:
    """One object-like cluster of mesh surface: ``points`` (N, 3) world metres, evenly spread over
    its surface (at most ``max_points``), and its extent, the 5-95 percentile size along x, y, z
    (metres)."""

    points: np.ndarray
    extent: np.ndarray

    @property
    def center(self) -> np.ndarray:
        return self.points.mean(axis=0)


def sample_surface(vertices: np.ndarray, triangles: np.ndarray, spacing_m: float,
                   seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points about ``spacing_m`` apart on the triangles' surface and their triangle normals:
    each triangle gets ``area / spacing_m**2`` points (the fraction drawn), at seeded random
    barycentric coordinates. Degenerate triangles get none."""
    v = np.asarray(vertices, np.float64)
    t = np.asarray(triangles, np.int64)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    cross = np.cross(b - a, c - a)
    area2 = np.linalg.norm(cross, axis=1)
    rng = np.random.default_rng(seed)
    expect = 0.5 * area2 / spacing_m ** 2
    count = np.floor(expect + rng.random(len(t))).astype(np.int64)
    idx = np.repeat(np.arange(len(t)), count)
    r1, r2 = rng.random(len(idx)), rng.random(len(idx))
    s = np.sqrt(r1)
    w = np.column_stack([1 - s, s * (1 - r2), s * r2])
    pts = w[:, :1] * a[idx] + w[:, 1:2] * b[idx] + w[:, 2:] * c[idx]
    with np.errstate(invalid="ignore", divide="ignore"):
        nrm = cross[idx] / area2[idx, None]
    ok = np.isfinite(nrm).all(axis=1)
    return pts[ok], nrm[ok]


def _canonical(normals: np.ndarray) -> np.ndarray:
    """Normals with their sign fixed (a plane's two sides, and windings that disagree, become one
    direction): each flipped to the side of a fixed skew axis."""
    axis = np.array([0.267, 0.534, 0.802])
    return np.where((normals @ axis)[:, None] < 0, -normals, normals)


def plane_directions(normals: np.ndarray, *, min_points: int, angle_deg: float = 10.0,
                     max_directions: int = 24) -> list[np.ndarray]:
    """The normal directions shared by at least ``min_points`` points: the fullest cell of a
    latitude-longitude histogram of the (sign-fixed) normals, refined to the mean of the normals
    within ``angle_deg`` of it; those normals leave and the next is sought. Deterministic."""
    n = _canonical(normals)
    left = np.ones(len(n), bool)
    cos_a = np.cos(np.radians(angle_deg))
    cell = np.radians(angle_deg)
    out = []
    for _ in range(max_directions):
        idx = np.nonzero(left)[0]
        if len(idx) < min_points:
            break
        lat = np.arcsin(np.clip(n[idx, 2], -1, 1))
        lon = np.arctan2(n[idx, 1], n[idx, 0])
        key = np.floor(lat / cell).astype(np.int64) * 1000 + np.floor(lon / cell).astype(np.int64)
        _, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
        best = int(np.argmax(counts))
        if counts[best] < min_points / 4:
            break
        d = n[idx[inv == best]].mean(axis=0)
        for _ in range(3):                     # refine: mean of the normals near the direction
            d /= np.linalg.norm(d)
            near = np.abs(n[idx] @ d) >= cos_a
            d = (n[idx[near]] * np.sign(n[idx[near]] @ d)[:, None]).mean(axis=0)
        d /= np.linalg.norm(d)
        near = np.abs(n[idx] @ d) >= cos_a
        if near.sum() < min_points:
            left[idx[inv == best]] = False     # a scattered cell: not a plane direction
            continue
        out.append(d)
        left[idx[near]] = False
    return out


def planar_regions(points: np.ndarray, normal: np.ndarray, cell_m: float, min_m2: float) -> np.ndarray:
    """Mask of the (nearly coplanar) ``points`` in connected regions of at least ``min_m2``: the
    points are binned on a grid of ``cell_m`` cells in their plane, and the occupied cells joined
    8-connected (OpenCV) and measured by their count."""
    import cv2

    u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    ij = np.floor(np.column_stack([points @ u, points @ v]) / cell_m).astype(np.int64)
    ij -= ij.min(axis=0)
    grid = np.zeros(ij.max(axis=0) + 1, np.uint8)
    grid[ij[:, 0], ij[:, 1]] = 1
    n, labels = cv2.connectedComponents(grid, connectivity=8)
    cells = np.bincount(labels.ravel(), minlength=n)
    cells[0] = 0                                   # the empty cells
    big = cells * cell_m ** 2 >= min_m2
    return big[labels[ij[:, 0], ij[:, 1]]]


def remove_planes(points: np.ndarray, normals: np.ndarray, *, spacing_m: float, plane_min_m2: float,
                  plane_tol: float = 1.5) -> np.ndarray:
    """Mask of the points not on a large planar region (see module doc). For each shared normal
    direction (:func:`plane_directions`), the points facing it are binned by their offset along it
    (``spacing_m`` bins); each offset peak (within ``plane_tol`` spacings) is split into connected
    regions (:func:`planar_regions`, cells of 2 spacings), and a region of at least ``plane_min_m2``
    is support: its points go. Regions, not infinite planes: an object's face level with a distant
    table top stays. Deterministic; no up axis assumed."""
    min_pts = max(20, int(plane_min_m2 / spacing_m ** 2))
    keep = np.ones(len(points), bool)
    cos_a = np.cos(np.radians(25.0))
    for d in plane_directions(normals, min_points=min_pts):
        facing = np.nonzero(np.abs(normals @ d) >= cos_a)[0]
        off = points[facing] @ d
        bins = np.floor(off / spacing_m).astype(np.int64)
        lo = bins.min()
        counts = np.bincount(bins - lo)
        # peaks: offset bins holding a plane's worth of points with their neighbours
        win = int(np.ceil(plane_tol))
        smooth = np.convolve(counts, np.ones(2 * win + 1, np.int64), mode="same")
        is_peak = smooth >= min_pts
        # local maxima of the smoothed counts, each taken with the bins within the tolerance
        peaks = [b for b in np.nonzero(is_peak)[0]
                 if smooth[b] >= smooth[max(b - 1, 0)] and smooth[b] >= smooth[min(b + 1, len(smooth) - 1)]]
        taken = np.zeros(len(counts), bool)
        for b in sorted(peaks, key=lambda b: -smooth[b]):
            if taken[b]:
                continue
            band = slice(max(b - win, 0), b + win + 1)
            taken[band] = True
            sel = facing[(bins - lo >= band.start) & (bins - lo < band.stop)]
            sel = sel[keep[sel]]
            if len(sel) < min_pts:
                continue
            keep[sel[planar_regions(points[sel], d, 2.0 * spacing_m, plane_min_m2)]] = False
    return keep


def segment_mesh_objects(vertices: np.ndarray, triangles: np.ndarray, *, spacing_m: float = 0.015,
                         plane_min_m2: float = 0.05, min_extent_m: float = 0.03, max_extent_m: float = 0.5,
                         min_normal_spread: float = 0.15, max_support_share: float = 0.85, max_points: int = 200,
                         seed: int = 0) -> list[MeshObject]:
    """The object-like clusters of a scene mesh (see module doc), sorted by their centre (x, then y,
    then z) so the order does not depend on the clustering's. ``min_normal_spread``: share of a
    cluster's points whose normal lies more than 30 degrees from the cluster's dominant normal direction;
    ``max_support_share``: most share of a cluster's points within ``3 * spacing_m`` of the removed
    support surface (1 keeps every cluster)."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    pts, nrm = sample_surface(vertices, triangles, spacing_m, seed)
    if len(pts) == 0:
        return []
    keep = remove_planes(pts, nrm, spacing_m=spacing_m, plane_min_m2=plane_min_m2)
    support = cKDTree(pts[~keep]) if (~keep).any() and max_support_share < 1 else None
    pts, nrm = pts[keep], nrm[keep]
    if len(pts) == 0:
        return []
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    labels = np.asarray(pcd.cluster_dbscan(2.5 * spacing_m, 6))
    out = []
    rng = np.random.default_rng(seed)
    min_points = int(np.ceil(5 * min_extent_m ** 2 / spacing_m ** 2))
    for lab in range(int(labels.max()) + 1 if len(labels) else 0):
        idx = np.nonzero(labels == lab)[0]
        if len(idx) < min_points:
            continue
        q, qn = pts[idx], nrm[idx]
        ext = np.percentile(q, 95, axis=0) - np.percentile(q, 5, axis=0)
        if not min_extent_m <= float(ext.max()) <= max_extent_m:
            continue
        # the dominant normal direction (either sign: mesh windings need not agree)
        main = np.linalg.eigh(qn.T @ qn)[1][:, -1]
        spread = float(np.mean(np.abs(qn @ main) < np.cos(np.radians(30))))
        if spread < min_normal_spread:
            continue
        if support is not None:
            near, _ = support.query(q, distance_upper_bound=3 * spacing_m)
            if np.mean(np.isfinite(near)) > max_support_share:
                continue
        if len(idx) > max_points:
            q = q[np.sort(rng.choice(len(idx), max_points, replace=False))]
        out.append(MeshObject(q, ext))
    out.sort(key=lambda o: tuple(np.round(o.center, 4)))
    return out
