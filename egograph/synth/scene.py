"""The synthetic room: furniture, support surfaces, object instances and their meshes.

World frame: y up, floor at y = 0, the room spans x in [0, W], z in [0, D] (metres).
Object meshes are in the object's own frame: origin at its centre, y up.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from egograph.synth.config import SceneConfig

# One box: 8 corners (unit cube, centred) and 12 outward triangles.
_CUBE_V = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
_CUBE_T = np.array([
    [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5],  # x- , x+
    [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],  # y- , y+
    [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],  # z- , z+
])


def box_mesh(center, size) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box -> (vertices (8,3), triangles (12,3))."""
    return _CUBE_V * np.asarray(size, float) + np.asarray(center, float), _CUBE_T.copy()


def cylinder_mesh(radius: float, height: float, segments: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Closed y-axis cylinder centred at the origin."""
    a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([radius * np.cos(a), np.zeros(segments), radius * np.sin(a)], 1)
    bottom, top = ring - [0, height / 2, 0], ring + [0, height / 2, 0]
    v = np.vstack([bottom, top, [[0, -height / 2, 0], [0, height / 2, 0]]])
    i = np.arange(segments)
    j = (i + 1) % segments
    cb, ct = 2 * segments, 2 * segments + 1
    tris = np.concatenate([
        np.stack([i, j + segments, j], 1), np.stack([i, i + segments, j + segments], 1),  # side
        np.stack([np.full(segments, cb), i, j], 1), np.stack([np.full(segments, ct), j + segments, i + segments], 1),
    ])
    return v, tris


@dataclass
class Part:
    """One static box of the room (wall, table top, leg, shelf board...)."""

    name: str
    center: np.ndarray
    size: np.ndarray
    color: np.ndarray   # RGB in [0, 1]
    albedo: float       # infrared reflectance proxy for AHAT returns


@dataclass
class Surface:
    """A horizontal surface objects can rest on (a work area)."""

    name: str
    center: np.ndarray   # (3,) centre of the usable area, y = surface height
    half_extent: np.ndarray  # (2,) usable half size in x, z
    front: np.ndarray    # (2,) unit xz direction towards the open floor


@dataclass
class ObjectModel:
    name: str
    shape: str                # "box" or "cylinder"
    size: np.ndarray          # (3,) full extent x, y (height), z in metres
    color: np.ndarray         # RGB in [0, 1]
    albedo: float
    pattern: int              # texture pattern id; look-alike twins share it
    twin: int = -1            # index of the look-alike instance, or -1
    vertices: np.ndarray = field(default=None, repr=False)   # local frame
    triangles: np.ndarray = field(default=None, repr=False)
    # device world only (egograph.synth.device): texture coordinates and normals of the mesh, the
    # texture layer, the print design and how a twin differs from its first (label/colour/sticker)
    uv: np.ndarray = field(default=None, repr=False)
    normals: np.ndarray = field(default=None, repr=False)
    layer: int = -1
    design: object = field(default=None, repr=False)
    lookalike: str = ""


@dataclass
class Prop:
    """An untracked object (5-30 cm) standing on a surface all recording: static scene, maybe in the mesh."""

    name: str
    shape: str
    size: np.ndarray     # (3,) full extent x, y, z, metres
    center: np.ndarray   # (3,) world, metres
    yaw: float           # radians about world y
    color: np.ndarray
    albedo: float
    in_mesh: bool        # the HoloLens mapped it (False: it came after the mapping)
    model: ObjectModel | None = None  # device world: its category mesh (object frame) and texture layer


@dataclass
class Scene:
    room_size: np.ndarray
    parts: list[Part]
    surfaces: list[Surface]
    objects: list[ObjectModel]
    props: list[Prop]
    static_vertices: np.ndarray
    static_triangles: np.ndarray
    static_tri_albedo: np.ndarray   # (T,) per static triangle
    static_tri_color: np.ndarray    # (T, 3)
    # device world only (egograph.synth.device): "device", the texture layers (sRGB uint8 images),
    # the static scene's render records, the room light and the hand's mesh function
    world: str = "legacy"
    layers: list = field(default=None, repr=False)
    static_render: np.ndarray = field(default=None, repr=False)
    light: object = None
    hand_mesh: object = field(default=None, repr=False)


DARK_ALBEDO = 0.15  # infrared reflectance of dark surfaces (AHAT config: dark_invalid below 0.25)

# name, shape, size (x, y, z) metres, base colour, albedo
CATALOGUE = [
    ("cup", "cylinder", (0.08, 0.10, 0.08), (0.85, 0.25, 0.2), 0.7),
    ("bottle", "cylinder", (0.07, 0.24, 0.07), (0.2, 0.55, 0.3), 0.5),
    ("book", "box", (0.16, 0.035, 0.23), (0.25, 0.3, 0.75), 0.6),
    ("box", "box", (0.12, 0.10, 0.09), (0.9, 0.75, 0.3), 0.8),
    ("can", "cylinder", (0.066, 0.12, 0.066), (0.75, 0.75, 0.8), 0.9),
    ("bowl", "cylinder", (0.16, 0.07, 0.16), (0.95, 0.95, 0.9), 0.85),
    ("remote", "box", (0.05, 0.025, 0.18), (0.1, 0.1, 0.12), 0.12),
    ("toy", "box", (0.10, 0.10, 0.10), (0.95, 0.45, 0.7), 0.7),
    ("jar", "cylinder", (0.10, 0.14, 0.10), (0.6, 0.4, 0.2), 0.45),
    ("mug", "cylinder", (0.09, 0.10, 0.09), (0.15, 0.15, 0.15), 0.2),
    ("plant", "cylinder", (0.12, 0.28, 0.12), (0.3, 0.6, 0.2), 0.4),
    ("speaker", "box", (0.10, 0.16, 0.10), (0.2, 0.2, 0.25), 0.18),
]


def _furniture(rng: np.random.Generator, w: float, d: float, h: float) -> tuple[list[Part], list[Surface]]:
    parts: list[Part] = []
    surfaces: list[Surface] = []
    wood = lambda: np.clip(np.array([0.55, 0.4, 0.25]) + rng.normal(0, 0.06, 3), 0, 1)  # noqa: E731

    def jitter(v, s=0.15):
        return v + rng.uniform(-s, s)

    def table(name, cx, cz, sx, sz, top, front, solid=False):
        color = wood()
        if solid:  # counter / sideboard: one block
            parts.append(Part(name, np.array([cx, top / 2, cz]), np.array([sx, top, sz]), color, 0.6))
        else:
            parts.append(Part(name + "_top", np.array([cx, top - 0.02, cz]), np.array([sx, 0.04, sz]), color, 0.6))
            for ix in (-1, 1):
                for iz in (-1, 1):
                    parts.append(Part(name + "_leg", np.array([cx + ix * (sx / 2 - 0.05), (top - 0.04) / 2, cz + iz * (sz / 2 - 0.05)]),
                                      np.array([0.05, top - 0.04, 0.05]), color * 0.8, 0.5))
        surfaces.append(Surface(name, np.array([cx, top, cz]), np.array([sx / 2 - 0.1, sz / 2 - 0.1]), np.asarray(front, float)))

    def shelf(name, cx, cz, sx, sz, boards, front):
        color = np.array([0.85, 0.85, 0.82])
        height = boards[-1] + 0.4
        # The back panel stands on the wall side, opposite the open front (revision 3 put it on the
        # open side, closing the shelf: objects on it were never visible).
        if front[0] == 0:
            parts.append(Part(name + "_back", np.array([cx, height / 2, cz - front[1] * sz / 2]), np.array([sx, height, 0.02]), color, 0.8))
        else:
            parts.append(Part(name + "_back", np.array([cx - front[0] * sx / 2, height / 2, cz]), np.array([0.02, height, sz]), color, 0.8))
        for s in (-1, 1):
            if front[0] == 0:
                parts.append(Part(name + "_side", np.array([cx + s * sx / 2, height / 2, cz]), np.array([0.02, height, sz]), color, 0.8))
            else:
                parts.append(Part(name + "_side", np.array([cx, height / 2, cz + s * sz / 2]), np.array([sx, height, 0.02]), color, 0.8))
        for b in [0.02] + list(boards) + [height]:
            parts.append(Part(name + "_board", np.array([cx, b - 0.01, cz]), np.array([sx, 0.02, sz]), color, 0.8))
        for b in boards:
            surfaces.append(Surface(f"{name}_{b:.2f}", np.array([cx, b, cz]), np.array([sx / 2 - 0.08, sz / 2 - 0.06]), np.asarray(front, float)))

    table("table_a", jitter(0.26 * w), 0.42, 1.4, 0.8, 0.75, (0, 1))
    table("desk_b", jitter(0.74 * w), 0.37, 1.3, 0.7, 0.73, (0, 1))
    table("counter_c", w - 0.32, jitter(0.5 * d), 0.6, 1.9, 0.92, (-1, 0), solid=True)
    shelf("shelf_d", jitter(0.6 * w), d - 0.2, 1.2, 0.36, (0.95, 1.4), (0, -1))
    table("table_e", 0.42, jitter(0.62 * d), 0.8, 1.4, 0.75, (1, 0))
    table("sideboard_f", jitter(0.2 * w), d - 0.27, 1.2, 0.5, 0.82, (0, -1), solid=True)
    # Dark surfaces return little infrared (AHAT dropouts, holes in the HoloLens mesh): a black
    # sideboard and a dark rug.
    parts[-1].color, parts[-1].albedo = np.array([0.12, 0.11, 0.1]), DARK_ALBEDO
    parts.append(Part("rug", np.array([0.5 * w, 0.003, 0.55 * d]), np.array([1.6, 0.006, 1.1]),
                      np.array([0.15, 0.13, 0.16]), DARK_ALBEDO))
    return parts, surfaces


def _room(w: float, d: float, h: float) -> list[Part]:
    t = 0.1
    wall = np.array([0.82, 0.8, 0.76])
    return [
        Part("floor", np.array([w / 2, -t / 2, d / 2]), np.array([w, t, d]), np.array([0.5, 0.45, 0.4]), 0.5),
        Part("ceiling", np.array([w / 2, h + t / 2, d / 2]), np.array([w, t, d]), np.array([0.9, 0.9, 0.9]), 0.8),
        Part("wall_z0", np.array([w / 2, h / 2, -t / 2]), np.array([w, h, t]), wall, 0.8),
        Part("wall_zd", np.array([w / 2, h / 2, d + t / 2]), np.array([w, h, t]), wall * 0.95, 0.8),
        Part("wall_x0", np.array([-t / 2, h / 2, d / 2]), np.array([t, h, d]), wall * 0.9, 0.8),
        Part("wall_xw", np.array([w + t / 2, h / 2, d / 2]), np.array([t, h, d]), wall * 0.97, 0.8),
    ]


def make_objects(rng: np.random.Generator, cfg: SceneConfig) -> list[ObjectModel]:
    n = cfg.n_instances
    pairs = min(cfg.n_lookalike_pairs, n // 2)
    order = rng.permutation(len(CATALOGUE))
    kinds = [CATALOGUE[k] for k in order]
    models: list[ObjectModel] = []
    counts: dict[str, int] = {}
    # The first `pairs` kinds each give two near-identical instances.
    plan = []
    for k in range(pairs):
        plan += [(kinds[k], True), (kinds[k], True)]
    for k in range(pairs, len(kinds)):
        if len(plan) >= n:
            break
        plan.append((kinds[k], False))
    for idx, ((name, shape, size, color, albedo), is_twin) in enumerate(plan[:n]):
        counts[name] = counts.get(name, 0) + 1
        scale = rng.uniform(0.9, 1.1)
        sz = np.array(size) * scale
        col = np.clip(np.array(color) + rng.normal(0, 0.04, 3), 0, 1)
        pattern = idx
        twin = -1
        if is_twin and counts[name] == 2:
            first = models[-1]
            twin = len(models) - 1
            first.twin = idx
            sz = first.size * rng.uniform(0.97, 1.03)
            col = np.clip(first.color + rng.normal(0, 0.05, 3), 0, 1)  # near-identical look
            pattern = first.pattern
        m = ObjectModel(f"{name}_{counts[name]}", shape, sz, col, float(albedo), pattern, twin)
        if shape == "box":
            m.vertices, m.triangles = box_mesh((0, 0, 0), sz)
        else:
            m.vertices, m.triangles = cylinder_mesh(sz[0] / 2, sz[1])
        models.append(m)
    return models


def prop_mesh(prop: Prop) -> tuple[np.ndarray, np.ndarray]:
    """World vertices and triangles of an untracked object."""
    from egograph.synth.trajectory import rot_y

    if prop.model is not None:
        v, t = prop.model.vertices, prop.model.triangles
    else:
        v, t = box_mesh((0, 0, 0), prop.size) if prop.shape == "box" else cylinder_mesh(prop.size[0] / 2, prop.size[1], 12)
    return v @ rot_y(prop.yaw).T + prop.center, t


def make_props(rng: np.random.Generator, cfg: SceneConfig, surfaces: list[Surface]) -> list[Prop]:
    """Untracked objects on the surfaces, 5-30 cm on their largest side, a share of them in the mesh."""
    props: list[Prop] = []
    occupied: list[np.ndarray] = []
    for j in range(cfg.n_props):
        shape = "box" if rng.random() < 0.5 else "cylinder"
        side = rng.uniform(0.05, 0.3)
        size = side * np.array([rng.uniform(0.4, 1.0), rng.uniform(0.3, 1.0), rng.uniform(0.4, 1.0)])
        size[int(rng.integers(3))] = side
        if shape == "cylinder":
            size[2] = size[0]
        color = rng.uniform(0.1, 0.95, 3)
        albedo = float(DARK_ALBEDO if rng.random() < 0.2 else rng.uniform(0.3, 0.9))
        s = int(rng.integers(len(surfaces)))
        spot = sample_spot_xz(rng, surfaces[s], size, occupied, cfg.min_object_gap)
        in_mesh = bool(rng.random() < cfg.props_in_mesh)
        yaw = float(rng.uniform(0, 2 * np.pi))
        if spot is None:
            continue
        occupied.append(spot)
        props.append(Prop(f"prop_{j}", shape, size, spot, yaw, color, albedo, in_mesh))
    return props


def make_scene(rng: np.random.Generator, cfg: SceneConfig) -> Scene:
    w, d, h = cfg.room_size
    parts = _room(w, d, h)
    furn, surfaces = _furniture(rng, w, d, h)
    parts += furn
    objects = make_objects(rng, cfg)
    props = make_props(rng, cfg, surfaces)
    verts, tris, alb, col = [], [], [], []
    off = 0
    meshes = [(box_mesh(p.center, p.size), p.albedo, p.color) for p in parts]
    meshes += [(prop_mesh(p), p.albedo, p.color) for p in props]
    for (v, t), albedo, color in meshes:
        verts.append(v)
        tris.append(t + off)
        alb.append(np.full(len(t), albedo))
        col.append(np.tile(color, (len(t), 1)))
        off += len(v)
    return Scene(np.array([w, d, h], float), parts, surfaces, objects, props,
                 np.vstack(verts), np.vstack(tris).astype(np.int32), np.concatenate(alb), np.vstack(col))


def sample_spot(rng: np.random.Generator, scene: Scene, surface: int, size: np.ndarray,
                occupied: list[np.ndarray], min_gap: float, tries: int = 60) -> np.ndarray | None:
    """A resting position (object centre) on a surface, away from occupied spots and the untracked
    objects; None if full."""
    return sample_spot_xz(rng, scene.surfaces[surface], size, list(occupied) + [p.center for p in scene.props],
                          min_gap, tries)


def sample_spot_xz(rng: np.random.Generator, s: Surface, size: np.ndarray, occupied: list[np.ndarray],
                   min_gap: float, tries: int = 60) -> np.ndarray | None:
    half = np.maximum(s.half_extent - np.array([size[0], size[2]]) / 2, 0.0)
    for _ in range(tries):
        x = s.center[0] + rng.uniform(-half[0], half[0])
        z = s.center[2] + rng.uniform(-half[1], half[1])
        p = np.array([x, s.center[1] + size[1] / 2, z])
        if all(np.linalg.norm(p[[0, 2]] - o[[0, 2]]) >= min_gap or abs(p[1] - o[1]) > 0.3 for o in occupied):
            return p
    return None


def grid_box_mesh(center, size, edge: float) -> tuple[np.ndarray, np.ndarray]:
    """Box surface as a regular grid of triangles with sides about ``edge`` (for the noisy mesh)."""
    center, size = np.asarray(center, float), np.asarray(size, float)
    verts, tris = [], []
    off = 0
    for axis in range(3):
        a, b = [k for k in range(3) if k != axis]
        na, nb = max(1, int(np.ceil(size[a] / edge))), max(1, int(np.ceil(size[b] / edge)))
        ua, ub = np.meshgrid(np.linspace(-0.5, 0.5, na + 1), np.linspace(-0.5, 0.5, nb + 1), indexing="ij")
        for sign in (-0.5, 0.5):
            v = np.zeros((ua.size, 3))
            v[:, axis] = sign
            v[:, a] = ua.ravel()
            v[:, b] = ub.ravel()
            v = v * size + center
            ii, jj = np.meshgrid(np.arange(na), np.arange(nb), indexing="ij")
            q = (ii * (nb + 1) + jj).ravel()
            t = np.concatenate([np.stack([q, q + nb + 1, q + nb + 2], 1), np.stack([q, q + nb + 2, q + 1], 1)])
            verts.append(v)
            tris.append(t + off)
            off += len(v)
    return np.vstack(verts), np.vstack(tris)


def _triangle_normals(v: np.ndarray, t: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Unit normals (T, 3) of the triangles of a convex solid, turned outward from ``center``."""
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    n = np.cross(b - a, c - a)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return n * np.where(np.einsum("ij,ij->i", n, (a + b + c) / 3 - center) < 0, -1.0, 1.0)[:, None]


def hololens_mesh(rng: np.random.Generator, scene: Scene, cfg: SceneConfig, first_places: list[np.ndarray],
                  head_height: float = 1.6):
    """The coarse scene mesh the HoloLens would store -> ``(mesh, baked instance indices)``.

    It holds what stood still while the headset mapped the room: the furniture, the untracked
    objects that were there (``Prop.in_mesh``) and a share (``mesh_baked_instances``) of the
    instances at their first place (``first_places``: world vertices per instance), which stay in the
    mesh after they move. Holes, in patches of ``mesh_hole_patch``: dark surfaces (albedo < 0.25)
    and surfaces seen only at grazing angles or from behind (normal within ``mesh_grazing_deg`` of
    perpendicular to the line to the room centre at head height, or facing away from it). Then
    centimetre vertex noise and decimation.
    """
    import open3d as o3d

    eye = np.array([scene.room_size[0] / 2, head_height, scene.room_size[1] / 2])
    baked = [k for k in range(len(first_places)) if rng.random() < cfg.mesh_baked_instances]
    solids = [(grid_box_mesh(p.center, p.size, cfg.mesh_edge), p.center, p.albedo) for p in scene.parts]
    solids += [(prop_mesh(p), p.center, p.albedo) for p in scene.props if p.in_mesh]
    solids += [((first_places[k], scene.objects[k].triangles), first_places[k].mean(0), scene.objects[k].albedo)
               for k in baked]
    # One random number per hole patch (a lattice, like the textures), so holes are contiguous.
    lattice = rng.random(32 ** 3)
    cos_grazing = np.sin(np.radians(cfg.mesh_grazing_deg))
    meshes = {"room": [], "small": []}
    for n_part, ((v, t), center, albedo) in enumerate(solids):
        cen = v[t].mean(1)
        n = _triangle_normals(v, t, center)
        view = eye - cen
        cos = np.einsum("ij,ij->i", n, view) / np.maximum(np.linalg.norm(view, axis=1), 1e-9)
        q = np.floor(cen / cfg.mesh_hole_patch).astype(np.int64) & 31
        u = lattice[(q[:, 0] * 32 + q[:, 1]) * 32 + q[:, 2]]
        hole = (cos < cos_grazing) & (u < cfg.mesh_hole_grazing)
        if albedo < 0.25:
            hole |= u < cfg.mesh_hole_dark
        # Small solids (untracked objects, baked instances) are kept at their own resolution: the
        # decimation would collapse them first, while the HoloLens keeps them as blobs.
        meshes["room" if n_part < len(scene.parts) else "small"].append((v, t[~hole]))
    out = None
    n_small = sum(len(t) for _, t in meshes["small"])
    for key, budget in (("room", max(cfg.mesh_triangles - n_small, 1)), ("small", None)):
        if not meshes[key]:
            continue
        offs = np.cumsum([0] + [len(v) for v, _ in meshes[key]])
        mesh = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(np.vstack([v for v, _ in meshes[key]])),
            o3d.utility.Vector3iVector(np.vstack([t + o for (_, t), o in zip(meshes[key], offs)]).astype(np.int32)))
        mesh = mesh.merge_close_vertices(1e-6)
        mesh.remove_unreferenced_vertices()
        v = np.asarray(mesh.vertices)
        mesh.vertices = o3d.utility.Vector3dVector(v + rng.normal(0, cfg.mesh_noise, v.shape))
        if budget is not None:
            mesh = mesh.simplify_quadric_decimation(budget)
        out = mesh if out is None else out + mesh
    mesh = out
    mesh.remove_degenerate_triangles()
    mesh.remove_unreferenced_vertices()
    mesh.compute_vertex_normals()
    return mesh, baked
