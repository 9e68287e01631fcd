"""Category meshes of the device world, with texture coordinates and vertex normals.

Object frame: origin at the centre of the object's bounding box, y up, metres. Texture coordinates
follow :mod:`egograph.synth.materials`: u across the print, v down it (v = 0 its top row), the
plain materials (caps, insides, page edges, leaves) at :data:`egograph.synth.materials.PLAIN_UV`.
Sizes are those of real household objects (the IT3DEgo categories).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from egograph.synth.materials import PLAIN_UV, PLAIN_V

CATEGORIES = ("mug", "bottle", "can", "box", "book", "remote", "toy", "plant", "bowl")
"""The release's object categories the device world builds."""

# Typical full extents (x, y, z), metres.
REAL_SIZES = {
    "mug": (0.082, 0.095, 0.082), "bottle": (0.068, 0.22, 0.068), "can": (0.066, 0.122, 0.066),
    "box": (0.12, 0.18, 0.06), "book": (0.15, 0.03, 0.22), "remote": (0.05, 0.022, 0.17),
    "toy": (0.09, 0.13, 0.09), "plant": (0.12, 0.26, 0.12), "bowl": (0.16, 0.065, 0.16),
}
# Infrared reflectance proxy (AHAT): dark plastic returns little.
ALBEDO = {"mug": 0.7, "bottle": 0.5, "can": 0.85, "box": 0.75, "book": 0.6, "remote": 0.12, "toy": 0.65,
          "plant": 0.4, "bowl": 0.8}


@dataclass
class MeshUV:
    vertices: np.ndarray   # (V, 3) float64, object frame
    triangles: np.ndarray  # (T, 3) int32
    uv: np.ndarray         # (V, 2) float32
    normals: np.ndarray    # (V, 3) float32 unit


def _join(parts: list[MeshUV]) -> MeshUV:
    off = np.cumsum([0] + [len(p.vertices) for p in parts])
    return MeshUV(np.vstack([p.vertices for p in parts]), np.vstack([p.triangles + o for p, o in zip(parts, off)]).astype(np.int32),
                  np.vstack([p.uv for p in parts]).astype(np.float32), np.vstack([p.normals for p in parts]).astype(np.float32))


def lathe(profile: list[tuple[float, float, float]], segments: int = 28, plain: str | None = None) -> MeshUV:
    """Surface of revolution about y of ``profile`` [(radius, y, v), ...] (bottom to top): one ring pair
    per profile segment, normals smooth round the axis and hard between segments. ``v`` is the print
    row of each profile point; ``plain``: map the whole surface to that plain material instead."""
    a = np.linspace(0, 2 * np.pi, segments + 1)
    ca, sa = np.cos(a), np.sin(a)
    parts = []
    for (r0, y0, v0), (r1, y1, v1) in zip(profile[:-1], profile[1:]):
        dr, dy = r1 - r0, y1 - y0
        ln = np.hypot(dr, dy)
        if ln < 1e-9:
            continue
        nr, ny = dy / ln, -dr / ln   # outward for a profile going up
        ring0 = np.stack([r0 * ca, np.full_like(ca, y0), r0 * sa], 1)
        ring1 = np.stack([r1 * ca, np.full_like(ca, y1), r1 * sa], 1)
        v = np.vstack([ring0, ring1])
        nrm = np.tile(np.stack([nr * ca, np.full_like(ca, ny), nr * sa], 1), (2, 1))
        u = np.concatenate([a, a]) / (2 * np.pi)
        if plain is not None:
            uv = np.tile(PLAIN_UV[plain], (len(v), 1)) + np.stack([0.1 * (u - 0.5), np.zeros_like(u)], 1)
        else:
            uv = np.stack([u, np.concatenate([np.full_like(a, v0), np.full_like(a, v1)])], 1)
        i = np.arange(segments)
        m = segments + 1
        t = np.concatenate([np.stack([i, i + m, i + 1 + m], 1), np.stack([i, i + 1 + m, i + 1], 1)])
        parts.append(MeshUV(v, t, uv, nrm))
    return _join(parts)


def _disc(r: float, y: float, up: bool, plain: str, segments: int = 28) -> MeshUV:
    a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    v = np.vstack([[0, y, 0], np.stack([r * np.cos(a), np.full_like(a, y), r * np.sin(a)], 1)])
    i = np.arange(segments)
    j = (i + 1) % segments
    t = np.stack([np.zeros(segments, int), j + 1, i + 1] if up else [np.zeros(segments, int), i + 1, j + 1], 1)
    uv = np.tile(PLAIN_UV[plain], (len(v), 1))
    uv[1:, 0] += 0.1 * np.cos(a)
    uv[1:, 1] += 0.05 * np.sin(a)
    return MeshUV(v, t, uv, np.tile([0.0, 1.0 if up else -1.0, 0.0], (len(v), 1)))


def box_uv(size, faces: dict[str, str | tuple]) -> MeshUV:
    """A box of full extents ``size`` centred at the origin; ``faces`` maps each face (+x, -x, +y, -y,
    +z, -z) to ``"print"`` (the whole print), ``("print", u0, u1)`` (a slice of it) or a plain material."""
    sx, sy, sz = np.asarray(size, float) / 2
    spec = {  # face: (centre axis/sign, u axis, v axis (down the print))
        "+z": (np.array([0, 0, sz]), np.array([sx, 0, 0]), np.array([0, -sy, 0])),
        "-z": (np.array([0, 0, -sz]), np.array([-sx, 0, 0]), np.array([0, -sy, 0])),
        "+x": (np.array([sx, 0, 0]), np.array([0, 0, -sz]), np.array([0, -sy, 0])),
        "-x": (np.array([-sx, 0, 0]), np.array([0, 0, sz]), np.array([0, -sy, 0])),
        "+y": (np.array([0, sy, 0]), np.array([sx, 0, 0]), np.array([0, 0, sz])),
        "-y": (np.array([0, -sy, 0]), np.array([sx, 0, 0]), np.array([0, 0, -sz])),
    }
    parts = []
    for name, (c, eu, ev) in spec.items():
        corners = np.array([c - eu - ev, c + eu - ev, c + eu + ev, c - eu + ev])
        what = faces.get(name, "cap")
        st = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
        if what == "print" or isinstance(what, tuple):
            u0, u1 = (0.0, 1.0) if what == "print" else what[1:]
            uv = np.stack([u0 + st[:, 0] * (u1 - u0), st[:, 1] * PLAIN_V * 0.999], 1)
        else:
            uv = np.asarray(PLAIN_UV[what]) + (st - 0.5) * [0.2, 0.1]
        n = c / np.linalg.norm(c)
        t = np.array([[0, 2, 1], [0, 3, 2]]) if np.dot(np.cross(eu, ev), n) < 0 else np.array([[0, 1, 2], [0, 2, 3]])
        parts.append(MeshUV(corners, t, uv, np.tile(n, (4, 1))))
    return _join(parts)


def _tube(path: np.ndarray, radius: float, plain: str, segments: int = 10) -> MeshUV:
    """A tube of ``radius`` along a polyline ``path`` (P, 3) (a mug handle, a finger)."""
    rings, norms = [], []
    for k in range(len(path)):
        d = path[min(k + 1, len(path) - 1)] - path[max(k - 1, 0)]
        d /= np.linalg.norm(d)
        a = np.cross(d, [0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.cross(d, [1.0, 0.0, 0.0])
        a /= np.linalg.norm(a)
        b = np.cross(d, a)
        ang = np.linspace(0, 2 * np.pi, segments, endpoint=False)
        nr = np.outer(np.cos(ang), a) + np.outer(np.sin(ang), b)
        rings.append(path[k] + radius * nr)
        norms.append(nr)
    v = np.vstack(rings)
    i = np.arange(segments)
    j = (i + 1) % segments
    tris = []
    for k in range(len(path) - 1):
        o, p = k * segments, (k + 1) * segments
        tris += [np.stack([o + i, p + i, p + j], 1), np.stack([o + i, p + j, o + j], 1)]
    return MeshUV(v, np.vstack(tris), np.tile(PLAIN_UV[plain], (len(v), 1)), np.vstack(norms))


def category_mesh(category: str, size) -> MeshUV:
    """The mesh of a category at full extents ``size`` (x, y, z) metres (x = z = diameter for round ones)."""
    sx, sy, sz = (float(s) for s in size)
    r, h = sx / 2, sy
    b = -h / 2
    P = PLAIN_V
    if category == "mug":
        body = lathe([(0, b, P), (r * 0.92, b, 0.0), (r, b + 0.05 * h, 0.0), (r, b + h, P * 0.999)])
        inside = lathe([(r * 0.9, b + h, 0), (r * 0.9, b + 0.1 * h, 0), (0.0, b + 0.1 * h, 0)], plain="inside")
        rim = lathe([(r, b + h, 0), (r * 0.9, b + h, 0)], plain="cap")
        ang = np.linspace(-np.pi / 2 * 0.9, np.pi / 2 * 0.9, 9)
        hr = 0.3 * h
        handle = np.stack([r * 0.95 + hr * 0.9 * np.cos(ang), b + 0.5 * h + hr * np.sin(ang), np.zeros_like(ang)], 1)
        return _join([body, inside, rim, _tube(handle, 0.008, "inside")])
    if category == "bottle":
        return _join([lathe([(0, b, P), (r * 0.95, b, 0.0), (r, b + 0.03 * h, 0.02), (r, b + 0.62 * h, 0.9 * P),
                             (r * 0.85, b + 0.72 * h, P * 0.999)]),
                      lathe([(r * 0.85, b + 0.72 * h, 0), (r * 0.4, b + 0.84 * h, 0), (r * 0.4, b + 0.88 * h, 0)], plain="inside"),
                      lathe([(r * 0.42, b + 0.88 * h, 0), (r * 0.42, b + h, 0), (0, b + h, 0)], plain="cap")])
    if category == "can":
        return _join([lathe([(0, b, 0), (r * 0.85, b, 0), (r, b + 0.06 * h, 0)], plain="cap"),
                      lathe([(r, b + 0.06 * h, 0.0), (r, b + 0.94 * h, P * 0.999)]),
                      lathe([(r, b + 0.94 * h, 0), (r * 0.88, b + h, 0), (0, b + h - 0.004, 0)], plain="cap")])
    if category == "bowl":
        return _join([lathe([(0, b, P), (r * 0.45, b, P * 0.9), (r * 0.8, b + 0.35 * h, 0.45 * P), (r, b + h, 0.0)]),
                      lathe([(r, b + h, 0), (r * 0.93, b + h, 0), (r * 0.74, b + 0.4 * h, 0), (0, b + 0.12 * h, 0)],
                            plain="inside")])
    if category == "toy":  # a figure: round body, head, two ears
        parts = [lathe([(0, b, P), (r * 0.8, b + 0.05 * h, 0.8 * P), (r, b + 0.3 * h, 0.5 * P), (r * 0.75, b + 0.55 * h, 0.2 * P),
                        (r * 0.45, b + 0.62 * h, 0.05 * P), (r * 0.7, b + 0.75 * h, 0.02), (r * 0.6, b + 0.92 * h, 0.01),
                        (0, b + h * 0.97, 0.0)])]
        for s in (-1, 1):
            parts.append(lathe([(0, -0.015, 0), (0.012, 0, 0), (0, 0.015, 0)], segments=10, plain="cap"))
            parts[-1].vertices += [s * r * 0.45, b + 0.93 * h, 0]
        return _join(parts)
    if category == "plant":  # a pot with leaves fanning out of it
        pot_h = 0.42 * h
        pot = lathe([(0, b, P), (r * 0.7, b, 0.6 * P), (r * 0.85, b + pot_h, 0.2 * P), (r * 0.85, b + pot_h, 0.0)])
        soil = _disc(r * 0.8, b + pot_h * 0.92, True, "inside")
        leaves = []
        rng = np.random.default_rng(int(sx * 1e4))
        for k in range(9):
            ang = 2 * np.pi * k / 9 + rng.uniform(-0.2, 0.2)
            tilt = rng.uniform(0.25, 0.7)
            length = (h - pot_h) * rng.uniform(0.75, 1.05) / np.cos(tilt)
            d = np.array([np.sin(tilt) * np.cos(ang), np.cos(tilt), np.sin(tilt) * np.sin(ang)])
            side = np.array([-np.sin(ang), 0, np.cos(ang)]) * 0.022
            base = np.array([0, b + pot_h * 0.9, 0])
            tip = base + d * length
            mid = base + d * length * 0.5
            v = np.array([base, mid - side, tip, mid + side])
            nrm = np.cross(side, d)
            nrm /= np.linalg.norm(nrm)
            leaves.append(MeshUV(v, np.array([[0, 1, 2], [0, 2, 3]]), np.tile(PLAIN_UV["leaf"], (4, 1)) +
                                 np.array([[0, 0], [-0.08, 0.02], [0, 0.05], [0.08, 0.02]]), np.tile(nrm, (4, 1))))
        m = _join([pot, soil] + leaves)
        m.vertices[:, [0, 2]] = np.clip(m.vertices[:, [0, 2]], -r, r)
        return m
    if category == "book":  # lying flat: the cover on top, the spine at -x, pages on the other sides
        return box_uv((sx, sy, sz), {"+y": "print", "-y": ("print", 0.6, 1.0), "-x": "cap", "+x": "pages",
                                     "+z": "pages", "-z": "pages"})
    if category == "remote":
        return box_uv((sx, sy, sz), {"+y": ("print", 0.1, 0.6), "-y": "inside", "+x": "inside", "-x": "inside",
                                     "+z": "inside", "-z": "inside"})
    # box: printed on every side
    return box_uv((sx, sy, sz), {"+z": ("print", 0.0, 0.5), "-z": ("print", 0.5, 1.0), "+x": ("print", 0.52, 0.75),
                                 "-x": ("print", 0.75, 1.0), "+y": "cap", "-y": "cap"})
