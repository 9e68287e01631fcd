"""The device world's scene: the same room layout as the legacy world (furniture from the scene
stream), instances and untracked objects of the release's categories with photographic prints
(:mod:`egograph.synth.materials`, :mod:`egograph.synth.meshes`), look-alike twins that share their
mesh and differ by a label, a colour or a sticker, the room's light, and the hand and forearm that
reach for, carry and let go of every carried object.

World frame as :mod:`egograph.synth.scene` (y up, metres). The body frame of the hand: x right,
y up, z back towards the wearer, turned by the body yaw.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from egograph.synth.config import SynthConfig
from egograph.synth.materials import (
    PhotoLibrary,
    fabric_texture,
    photo_texture,
    plaster_texture,
    random_design,
    render_design,
    skin_texture,
    twin_design,
    wood_texture,
)
from egograph.synth.meshes import ALBEDO, CATEGORIES, REAL_SIZES, MeshUV, _join, _tube, box_uv, category_mesh
from egograph.synth.scene import (
    ObjectModel,
    Prop,
    Scene,
    _furniture,
    _room,
    box_mesh,
    sample_spot_xz,
)
from egograph.synth.trajectory import Trajectory, rot_y, smoothstep

HAND_REST = np.array([0.22, -0.62, -0.12])  # palm relative to the eye in the body frame when the hand is down, metres
FINGER_RADIUS = 0.009


@dataclass
class RoomLight:
    """Light of one recording: level (1 = an office at ~300 lux), colours of the ambient, sky and
    lamp terms (linear RGB), lamp positions (world, metres)."""

    level: float
    dim: bool
    ambient: np.ndarray
    sky: np.ndarray
    lamp: np.ndarray
    lamps: np.ndarray


def room_light(rng: np.random.Generator, cfg: SynthConfig, room_size: np.ndarray) -> RoomLight:
    lc = cfg.device.light
    dim = bool(rng.random() < lc.dim_share)
    lo, hi = lc.dim if dim else lc.bright
    level = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    warm = rng.uniform(*lc.warm)
    lamp = np.array([1.0, 0.92 - 0.2 * warm, 0.85 - 0.45 * warm])
    daylight = np.array([0.95, 0.98, 1.05])
    w, d, h = room_size
    n_lamps = 1 if dim else 2
    lamps = np.column_stack([rng.uniform(0.15, 0.85, n_lamps) * w, np.full(n_lamps, h - 0.35), rng.uniform(0.15, 0.85, n_lamps) * d])
    # A dim room is lit by its lamp: little ambient and no daylight from the windows.
    ambient = (0.12 if dim else 0.3) * (lamp if dim else daylight)
    sky = (0.05 if dim else 0.35) * daylight
    return RoomLight(level, dim, ambient, sky, lamp * (0.9 if dim else 0.6), lamps)


def _static_records(v: np.ndarray, t: np.ndarray, layer: int, scale: float, uv=None, normals=None) -> np.ndarray:
    """Render records (3T, 10) of triangles: position, normal, uv, layer, triplanar scale (metres per
    texture repeat; 0: use uv). Flat normals when ``normals`` is None."""
    tri = np.asarray(v, np.float64)[t]
    if normals is None:
        nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
        nrm = np.repeat(nrm[:, None], 3, 1)
    else:
        nrm = np.asarray(normals, np.float64)[t]
    uvs = np.zeros(tri.shape[:2] + (2,)) if uv is None else np.asarray(uv, np.float64)[t]
    rec = np.concatenate([tri, nrm, uvs, np.full(tri.shape[:2] + (1,), float(layer)),
                          np.full(tri.shape[:2] + (1,), float(scale))], 2)
    return rec.reshape(-1, 10).astype(np.float32)


def object_records(obj: ObjectModel) -> np.ndarray:
    """Render records of an instance in its own frame."""
    return _static_records(obj.vertices, obj.triangles, obj.layer, 0.0, obj.uv, obj.normals)


def _model(name: str, category: str, size: np.ndarray, mesh: MeshUV, layer: int, design, pattern: int) -> ObjectModel:
    ext = np.ptp(mesh.vertices, 0)
    m = ObjectModel(name, category, ext, np.asarray(design.material) / 255.0, float(ALBEDO[category]), pattern)
    m.vertices, m.triangles, m.uv, m.normals = mesh.vertices, mesh.triangles.astype(np.int64), mesh.uv, mesh.normals
    m.layer, m.design = layer, design
    return m


def make_device_scene(rng: np.random.Generator, rng_look: np.random.Generator, cfg: SynthConfig,
                      lib: PhotoLibrary) -> Scene:
    """The device world's scene: furniture from ``rng`` (as the legacy world), everything that looks
    from ``rng_look``."""
    sc = cfg.scene
    w, d, h = sc.room_size
    parts = _room(w, d, h)
    furn, surfaces = _furniture(rng, w, d, h)
    parts += furn
    layers: list[np.ndarray] = []

    def add(img: np.ndarray) -> int:
        layers.append(img)
        return len(layers) - 1

    # Room materials.
    wall_col = np.array([[235, 232, 222], [220, 215, 200], [200, 208, 212], [225, 220, 215]])[int(rng_look.integers(4))]
    mat = {"floor": add(wood_texture(rng_look, lib, rng_look.uniform(0.0, 0.6))),
           "wall": add(plaster_texture(rng_look, lib, wall_col.astype(float))),
           "ceiling": add(plaster_texture(rng_look, lib, np.array([240.0, 240, 238]))),
           "table": add(wood_texture(rng_look, lib, rng_look.uniform(0.2, 0.9))),
           "shelf": add(plaster_texture(rng_look, lib, np.array([228.0, 226, 220]))),
           "counter": add(plaster_texture(rng_look, lib, np.array([150.0, 150, 145]))),
           "dark": add(wood_texture(rng_look, lib, 1.0)),
           "rug": add(fabric_texture(rng_look, lib, np.array([110.0, 60, 55]) * rng_look.uniform(0.6, 1.3)))}
    scale = {"floor": 1.2, "wall": 1.5, "ceiling": 2.0, "table": 0.9, "shelf": 1.0, "counter": 0.6, "dark": 0.9, "rug": 0.5}

    def material(name: str) -> str:
        for prefix, m in (("floor", "floor"), ("ceiling", "ceiling"), ("wall", "wall"), ("rug", "rug"),
                          ("sideboard", "dark"), ("shelf", "shelf"), ("counter", "counter")):
            if name.startswith(prefix):
                return m
        return "table"

    # Instances: categories in a random order; the first pairs are look-alikes of one category.
    n = sc.n_instances
    pairs = min(sc.n_lookalike_pairs, n // 2)
    order = [CATEGORIES[k] for k in rng.permutation(len(CATEGORIES))]
    plan = []
    for k in range(pairs):
        plan += [(order[k % len(order)], True), (order[k % len(order)], True)]
    k = pairs
    while len(plan) < n:
        plan.append((order[k % len(order)], False))
        k += 1
    objects: list[ObjectModel] = []
    counts: dict[str, int] = {}
    lk = cfg.device.lookalikes
    n_pair = 0
    for idx, (cat, is_twin) in enumerate(plan[:n]):
        counts[cat] = counts.get(cat, 0) + 1
        name = f"{cat}_{counts[cat]}"
        if is_twin and idx % 2 == 1:
            first = objects[-1]
            kind = lk.kinds[n_pair % len(lk.kinds)]
            n_pair += 1
            design = twin_design(rng_look, first.design, kind, tuple(lk.hue_shift), lk.sticker_size)
            m = ObjectModel(name, cat, first.size.copy(), np.asarray(design.material) / 255.0, first.albedo, idx, idx - 1)
            # The same mesh (the same arrays): a twin differs only in its print.
            m.vertices, m.triangles, m.uv, m.normals = first.vertices, first.triangles, first.uv, first.normals
            m.layer, m.design, m.lookalike = add(render_design(lib, design)), design, kind
            first.twin = idx
            objects.append(m)
            continue
        size = np.array(REAL_SIZES[cat]) * rng.uniform(0.88, 1.12)
        design = random_design(rng_look, cat)
        objects.append(_model(name, cat, size, category_mesh(cat, size), add(render_design(lib, design)), design, idx))

    # Untracked objects: the same categories, other prints, standing on the surfaces.
    props: list[Prop] = []
    occupied: list[np.ndarray] = []
    for j in range(sc.n_props):
        cat = CATEGORIES[int(rng.integers(len(CATEGORIES)))]
        size = np.array(REAL_SIZES[cat]) * rng.uniform(0.8, 1.4)
        design = random_design(rng_look, cat)
        model = _model(f"prop_{j}", cat, size, category_mesh(cat, size), add(render_design(lib, design)), design, -1)
        s = int(rng.integers(len(surfaces)))
        spot = sample_spot_xz(rng, surfaces[s], model.size, occupied, sc.min_object_gap)
        in_mesh = bool(rng.random() < sc.props_in_mesh)
        yaw = float(rng.uniform(0, 2 * np.pi))
        if spot is None:
            continue
        occupied.append(spot)
        props.append(Prop(f"prop_{j}", cat, model.size, spot, yaw, model.color, model.albedo, in_mesh, model))

    # Two pictures on the walls (photographs in thin frames).
    pictures = []
    for p in range(2):
        img = photo_texture(lib, ("china", "flower", "astronaut", "rocket")[int(rng_look.integers(4))], rng_look)
        pw, ph = rng_look.uniform(0.5, 0.9), rng_look.uniform(0.4, 0.7)
        if p == 0:
            c, size = np.array([rng_look.uniform(1.0, w - 1.0), 1.6, 0.012]), (pw, ph, 0.02)
            mesh = box_uv(size, {"+z": "print"})
        else:
            c, size = np.array([0.012, 1.6, rng_look.uniform(1.0, d - 1.0)]), (0.02, ph, pw)
            mesh = box_uv(size, {"+x": "print"})
        pictures.append((mesh.vertices + c, mesh.triangles, mesh.uv, mesh.normals, add(img)))

    skin = add(skin_texture(rng_look))
    hand_fn = make_hand_mesh(skin)

    # Geometry for ray casting, and the render records.
    verts, tris, alb, col, recs = [], [], [], [], []
    off = 0
    for p in parts:
        v, t = box_mesh(p.center, p.size)
        verts.append(v), tris.append(t + off), alb.append(np.full(len(t), p.albedo)), col.append(np.tile(p.color, (len(t), 1)))
        m = material(p.name)
        recs.append(_static_records(v, t, mat[m], scale[m]))
        off += len(v)
    for p in props:
        r = rot_y(p.yaw)
        v = p.model.vertices @ r.T + p.center
        t = p.model.triangles
        verts.append(v), tris.append(t + off), alb.append(np.full(len(t), p.albedo)), col.append(np.tile(p.color, (len(t), 1)))
        recs.append(_static_records(v, t, p.model.layer, 0.0, p.model.uv, p.model.normals @ r.T))
        off += len(v)
    for v, t, uv, nrm, layer in pictures:
        verts.append(v), tris.append(t + off), alb.append(np.full(len(t), 0.6)), col.append(np.tile([0.5, 0.5, 0.5], (len(t), 1)))
        recs.append(_static_records(v, t, layer, 0.0, uv, nrm))
        off += len(v)
    scene = Scene(np.array([w, d, h], float), parts, surfaces, objects, props, np.vstack(verts),
                  np.vstack(tris).astype(np.int32), np.concatenate(alb), np.vstack(col))
    scene.world, scene.layers, scene.static_render, scene.hand_mesh = "device", layers, np.vstack(recs), hand_fn
    return scene


# ---------------------------------------------------------------- hands

def make_hand_mesh(skin_layer: int):
    """The device world's hand and forearm as a function ``(palm, yaw, grip) -> (vertices, triangles,
    uv, normals)`` (world, metres): a palm on the right side of the gripped object (``grip``: its full
    extents x, y, z in the body frame), four fingers wrapped over its near face, a thumb behind it,
    the forearm reaching back and down to the body. ``palm``: palm centre; ``yaw``: body yaw, radians."""
    forearm_dir = np.array([0.25, -0.6, 1.0]) / np.linalg.norm([0.25, -0.6, 1.0])

    def mesh(palm: np.ndarray, yaw: float, grip=(0.08, 0.1, 0.08)):
        gw, gh, gd = (float(g) for g in grip)
        body = rot_y(yaw).T  # rows: the body's axes in world
        # Object centre relative to the palm (body frame).
        oc = np.array([-(gw / 2 + 0.014), 0.1 * gh, 0.0])
        parts = [box_uv((0.026, 0.09, 0.085), {})]
        for k, dy in enumerate((-0.03, -0.01, 0.01, 0.03)):
            y = oc[1] - 0.1 * gh + dy + 0.1 * gh
            path = np.array([[0.0, y, 0.035], [oc[0] + gw / 2, y, oc[2] + gd / 2 + FINGER_RADIUS + 0.002],
                             [oc[0] + gw * (0.15 - 0.05 * k), y, oc[2] + gd / 2 + FINGER_RADIUS + 0.002]])
            parts.append(_tube(path, FINGER_RADIUS, "cap", 8))
        thumb = np.array([[0.0, 0.02, -0.03], [oc[0] + gw / 2, 0.035, oc[2] - gd / 2 - 0.012], [oc[0] + gw * 0.2, 0.035, oc[2] - gd / 2 - 0.012]])
        parts.append(_tube(thumb, 0.010, "cap", 8))
        wrist = np.array([0.004, -0.045, 0.03])
        parts.append(_tube(np.array([wrist + forearm_dir * s for s in (0.0, 0.12, 0.28)]), 0.03, "cap", 12))
        m = _join(parts)
        v = m.vertices @ body + palm
        uv = (m.vertices[:, [0, 1]] * 4.0 + 0.5).astype(np.float32)
        return v, m.triangles, uv, (m.normals @ body).astype(np.float32)

    mesh.layer = skin_layer
    return mesh


def hand_path(traj: Trajectory, scene: Scene, cfg: SynthConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Palm centre (N, 3), active (N,), gripped object (N,) (-1: none) and grip extents (N, 3) of the
    device world's hand: it reaches from below the view to the object during the look before the
    pick-up (``wearer.reach_time``), holds it while carried, and withdraws during the look after the
    put-down, back to below the view."""
    n = len(traj)
    body = np.stack([rot_y(a) for a in traj.hand_yaw])
    rest = traj.head_pos + np.einsum("nij,j->ni", body, HAND_REST)
    pos = rest.copy()
    active = np.zeros(n, bool)
    obj = np.full(n, -1)
    grip = np.tile([0.08, 0.1, 0.08], (n, 1)).astype(float)
    reach = max(2, int(round(cfg.wearer.reach_time * traj.fps)))
    withdraw = max(2, int(round(cfg.wearer.watch_time[0] * traj.fps)))
    starts = sorted(m.pick_frame for m in traj.moves)
    for mv in traj.moves:
        i = mv.instance
        size = scene.objects[i].size
        g = np.array([max(size[0], size[2]), size[1], max(size[0], size[2])])
        offset = np.array([g[0] / 2 + 0.014, -0.1 * g[1], 0.0])
        a, b = mv.pick_frame, mv.place_frame
        frames = np.arange(max(0, a - (reach if cfg.device.hand_reach else 0)), b + 1)
        if cfg.device.hand_reach:
            nxt = [s for s in starts if s > b]
            end = min(n - 1, b + withdraw, (nxt[0] - reach - 1) if nxt else n - 1)
            frames = np.arange(frames[0], max(end, b) + 1)
        on = np.einsum("nij,j->ni", body[frames], offset) + traj.obj_pos[frames, i]
        w = np.ones(len(frames))
        pre = frames < a
        post = frames > b
        if pre.any():
            w[pre] = smoothstep((frames[pre] - frames[0] + 1) / (a - frames[0] + 1))
        if post.any():
            w[post] = 1 - smoothstep((frames[post] - b) / (frames[-1] - b + 1))
        pos[frames] = rest[frames] + w[:, None] * (on - rest[frames])
        active[frames] = True
        obj[frames] = i
        grip[frames] = g
    return pos, active, obj, grip
