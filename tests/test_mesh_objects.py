"""Objects standing in the scene mesh (``egograph.frontend.mesh_objects``) and the ``mesh``
proposals made from them: on a hand-built room the segmentation finds exactly the objects on the
table and the floor (not the table, the walls or a poster on a wall), the same points every run,
and a camera sees each object's box where the projection of its corners puts it, and no box for
an object hidden behind a panel."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

o3d = pytest.importorskip("open3d")

from egograph.core.config import load_config  # noqa: E402
from egograph.core.resources import default_config  # noqa: E402
from egograph.frontend.proposals import MeshObjectProposals, iou, proposal_sources  # noqa: E402
from egograph.geometry.hl2ss import pv_intrinsics_matrix, pv_project  # noqa: E402
from egograph.frontend.mesh_objects import sample_surface, segment_mesh_objects  # noqa: E402
from egograph.io.recording import mesh_raycasting_scene  # noqa: E402
from egograph.steps.settings import EgographConfig  # noqa: E402

_CUBE_V = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
_CUBE_T = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                    [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])


def box(center, size):
    return _CUBE_V * np.asarray(size, float) + np.asarray(center, float), _CUBE_T


def cylinder(center, radius, height, n=24):
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.stack([radius * np.cos(a), np.zeros(n), radius * np.sin(a)], 1)
    v = np.vstack([ring - [0, height / 2, 0], ring + [0, height / 2, 0], [[0, -height / 2, 0], [0, height / 2, 0]]])
    t = []
    for i in range(n):
        j = (i + 1) % n
        t += [[i, j, n + j], [i, n + j, n + i], [2 * n, j, i], [2 * n + 1, n + i, n + j]]
    return v + np.asarray(center, float), np.array(t)


def merge(parts):
    vs, ts, off = [], [], 0
    for v, t in parts:
        vs.append(v)
        ts.append(t + off)
        off += len(v)
    return np.vstack(vs), np.vstack(ts)


# a 4 x 4 x 2.5 m room (y up): floor, ceiling and walls as thin slabs, a table (top at 0.75 m),
# and three objects: a 10 cm cube and a 20 cm cylinder on the table, a 15 cm cube on the floor
CUBE, CYL, FLOOR_CUBE = (1.8, 0.80, 2.0), (2.3, 0.85, 2.1), (3.0, 0.075, 3.0)
ROOM = [box((2, -0.01, 2), (4, 0.02, 4)), box((2, 2.51, 2), (4, 0.02, 4)),
        box((-0.01, 1.25, 2), (0.02, 2.5, 4)), box((4.01, 1.25, 2), (0.02, 2.5, 4)),
        box((2, 1.25, -0.01), (4, 2.5, 0.02)), box((2, 1.25, 4.01), (4, 2.5, 0.02)),
        box((2, 0.735, 2), (1.2, 0.03, 0.8)),                       # table top
        box((2, 1.5, 0.0025), (0.3, 0.3, 0.005))]                    # a poster on the wall z = 0
OBJECTS = [box(CUBE, (0.1, 0.1, 0.1)), cylinder(CYL, 0.04, 0.2), box(FLOOR_CUBE, (0.15, 0.15, 0.15))]


def room_mesh(extra=()):
    v, t = merge(ROOM + OBJECTS + list(extra))
    return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(t.astype(np.int32)))


def test_surface_samples_are_on_the_triangles_and_even():
    v, t = box((0, 0, 0), (1, 1, 1))
    pts, nrm = sample_surface(v, t, 0.02, seed=3)
    assert abs(len(pts) - 6 / 0.02 ** 2) < 0.02 * 6 / 0.02 ** 2
    assert np.allclose(np.abs(pts).max(axis=1), 0.5, atol=1e-9)        # every point on a face
    assert np.allclose(np.linalg.norm(nrm, axis=1), 1)
    again, _ = sample_surface(v, t, 0.02, seed=3)
    assert np.array_equal(pts, again)


def test_segmentation_finds_the_objects_not_the_room():
    mesh = room_mesh()
    objs = segment_mesh_objects(np.asarray(mesh.vertices), np.asarray(mesh.triangles))
    centers = np.array([o.center for o in objs])
    assert len(objs) == 3, centers
    for want in (CUBE, CYL, FLOOR_CUBE):
        # the points are on the visible surface and the part within a plane's tolerance of the
        # support is gone: the centre sits a little high, never off sideways
        d = centers - np.asarray(want)
        k = int(np.argmin(np.linalg.norm(d[:, [0, 2]], axis=1)))
        assert np.linalg.norm(d[k, [0, 2]]) < 0.01 and 0 <= d[k, 1] < 0.03, (want, centers[k])
    again = segment_mesh_objects(np.asarray(mesh.vertices), np.asarray(mesh.triangles))
    assert all(np.array_equal(a.points, b.points) for a, b in zip(objs, again))


def corner_seam(z0, z1, pitch=0.015, depth=0.01):
    """Where the floor (y = 0) meets the wall x = 0 the mesh rounds the corner: a 45-degree strip
    from 5 cm up the wall to 5 cm out on the floor, from ``z0`` to ``z1``, rippled along its length
    (ridges ``depth`` out every ``pitch``): no plane, its normals 70 degrees apart, as the leftover
    seams of a mapped room are."""
    out = np.array([0.5, 0.5, 0.0]) * np.sqrt(2) * depth
    v = []
    for k, z in enumerate(np.arange(z0, z1 + 1e-9, pitch)):
        lift = out * (k % 2)
        v += [np.array([0.0, 0.05, z]) + lift, np.array([0.05, 0.0, z]) + lift]
    t = [[2 * k, 2 * k + 2, 2 * k + 3] for k in range(len(v) // 2 - 1)] + \
        [[2 * k, 2 * k + 3, 2 * k + 1] for k in range(len(v) // 2 - 1)]
    return np.array(v), np.array(t)


def test_a_seam_along_the_floor_and_wall_is_not_an_object():
    mesh = room_mesh([corner_seam(1.0, 1.35)])
    v, t = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    kept = segment_mesh_objects(v, t, max_support_share=1.0)          # the test that tells them apart off
    assert any(o.center[0] < 0.1 and o.center[1] < 0.1 for o in kept), [o.center for o in kept]
    objs = segment_mesh_objects(v, t)
    assert len(objs) == 3 and all(o.center[0] > 1 for o in objs), [o.center for o in objs]


def look_at(eye, target):
    """A PV camera pose (row vectors, camera -> world; the camera looks down -z, y up)."""
    f = np.asarray(target, float) - eye
    f /= np.linalg.norm(f)
    right = np.cross(f, [0, 1, 0])
    right /= np.linalg.norm(right)
    up = np.cross(right, f)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([right, up, -f])
    pose[3, :3] = eye
    return pose


def fake_recording(mesh, pose):
    k = pv_intrinsics_matrix(700.0, 700.0, 640.0, 360.0)
    return SimpleNamespace(seq_dir=Path("."), mesh=lambda: mesh, mesh_scene=lambda: mesh_raycasting_scene(mesh),
                           pv_poses=pose[None], pv_valid=np.array([True]),
                           pv=SimpleNamespace(intrinsics=k, shape=(720, 1280)))


def projected_box(pose, k, v):
    to_cam = np.linalg.inv(pose)
    uv, _ = pv_project(v @ to_cam[:3, :3] + to_cam[3, :3], k)
    return (*uv.min(axis=0), *uv.max(axis=0))


def test_mesh_proposals_box_each_seen_object_and_skip_a_hidden_one():
    cfg = load_config(EgographConfig, default_config(), ["frontend.box_pad_px=0"]).frontend
    pose = look_at(np.array([2.0, 1.5, 3.4]), (2.05, 0.8, 2.05))
    rec = fake_recording(room_mesh(), pose)
    props = MeshObjectProposals(rec, cfg)(0)
    k = rec.pv.intrinsics
    for center, v in ((CUBE, OBJECTS[0][0]), (CYL, OBJECTS[1][0])):
        want = projected_box(pose, k, v)
        assert max(iou(want, p.box) for p in props) > 0.8, (center, want, [p.box for p in props])
    assert all(p.source == "mesh" and 0 < p.conf <= 1 for p in props)

    # a panel on the table (0.5 x 0.4 m: a plane by its size, not an object) hides the cylinder
    hidden = room_mesh([box((2.3, 0.95, 2.45), (0.5, 0.4, 0.02))])
    rec = fake_recording(hidden, pose)
    props = MeshObjectProposals(rec, cfg)(0)
    want_cyl = projected_box(pose, k, OBJECTS[1][0])
    want_cube = projected_box(pose, k, OBJECTS[0][0])
    assert max((iou(want_cyl, p.box) for p in props), default=0) < 0.3
    assert max(iou(want_cube, p.box) for p in props) > 0.8


def test_proposal_sources_join_by_plus_and_name_the_choices():
    from egograph.core.errors import InputError

    cfg = load_config(EgographConfig, default_config()).frontend
    rec = fake_recording(room_mesh(), look_at(np.array([2.0, 1.5, 3.4]), (2.0, 0.8, 2.0)))
    assert len(proposal_sources(rec, cfg, "mesh+image")) == 2
    with pytest.raises(InputError, match="'geometry', 'mesh' or 'image'"):
        proposal_sources(rec, cfg, "mesh+sky")
