"""PV colour by rasterisation: OpenGL 3.3 on a headless EGL context (``moderngl``; Mesa's llvmpipe
where there is no GPU), the same shading model as :func:`egograph.synth.sensors.shade_hits`.

Why a second renderer: ray casting 1280x720 rays and shading them in numpy costs about 0.4 s per
frame on one core, which made RGB benchmark recordings too slow to generate. The rasteriser
runs the same texture lookups and lights per fragment (one pass, flat triangle normals, pixel
centres sampled as the ray caster samples them), so the two agree pixel for pixel except along
silhouette edges and where float rounding puts a texel boundary on the other side of a pixel
(tests/test_synth_render.py measures it).

Conventions: poses are the generator's row-vector 4x4 ``cam_to_world`` (``x_world = x_cam @ R + t``,
``t`` in the last row), PV camera x right, y up, looking down -z (the OpenGL camera), so the view
matrix is the inverse of its transpose. Images come back RGB uint8, row 0 at the top, as the ray
caster's and as :func:`egograph.io.png.write_png` stores them.
"""

from __future__ import annotations

import numpy as np

from egograph.io.calibration import PvCalibration
from egograph.synth.scene import Scene
from egograph.synth.sensors import (
    AMBIENT,
    BAND_DIM,
    DETAIL_HALF_WIDTH,
    HAND_COLOR,
    LAMP_GAIN,
    LAMP_REACH,
    LIGHT,
    SKY_GAIN,
    STATIC_TEXTURE_SHIFT,
    Pinhole,
    Textures,
    hand_mesh,
)
from egograph.synth.trajectory import rot_y

NEAR_M, FAR_M = 0.03, 60.0   # clip planes, metres: nearer than any surface the wearer can touch, beyond any room
MAX_LAMPS = 4
NO_BAND = -1.0e9             # band height that no fragment matches (surfaces without the twin's detail)

_VERTEX = """
#version 330
uniform mat4 view_proj;   // world -> clip
uniform mat4 model;       // model -> world (identity for the static scene and the hand)
uniform float tex_offset; // added to model coordinates before the texture lookup
in vec3 p;     // model coordinates, metres
in vec3 n;     // model-frame unit triangle normal
in vec3 base;  // base colour, RGB in [0, 1]
out vec3 v_world;
out vec3 v_tex;
out float v_local_y;
flat out vec3 v_base;
flat out vec3 v_normal;
void main() {
    vec4 w = model * vec4(p, 1.0);
    v_world = w.xyz;
    v_tex = p + vec3(tex_offset);
    v_local_y = p.y;
    v_base = base;
    v_normal = mat3(model) * n;
    gl_Position = view_proj * w;
}
"""

# Mirrors Textures.shade and shade_hits step for step (same constants, same order of clipping).
_FRAGMENT = """
#version 330
uniform sampler3D lattice;   // (64, 64, 64) R32F, texel (z, y, x) = Textures.lattice[(x * 64 + y) * 64 + z]
uniform sampler3D tint;      // same layout, RGB
uniform vec3 inv_scale;      // 1 / Textures.SCALES
uniform vec3 weight;         // Textures.WEIGHTS
uniform float tint_inv_scale;
uniform float tint_shift;
uniform float contrast;
uniform float band_dim;
uniform vec3 light;
uniform vec3 gains;          // ambient, sky, lamp
uniform vec3 lamps[LAMP_SLOTS];
uniform float inv_reach2;
uniform float band_y;
uniform float band_half;
in vec3 v_world;
in vec3 v_tex;
in float v_local_y;
flat in vec3 v_base;
flat in vec3 v_normal;
out vec4 frag;
float lat(float s) {
    ivec3 q = ivec3(floor(v_tex * s)) & 63;
    return texelFetch(lattice, q.zyx, 0).r;
}
void main() {
    float v = weight.x * lat(inv_scale.x) + weight.y * lat(inv_scale.y) + weight.z * lat(inv_scale.z);
    ivec3 qt = ivec3(floor((v_tex + vec3(tint_shift)) * tint_inv_scale)) & 63;
    vec3 col = clamp(texelFetch(tint, qt.zyx, 0).rgb * (v * contrast) * v_base, 0.0, 1.0);
    if (abs(v_local_y - band_y) < band_half) col = col.bgr * band_dim;
    float lam = abs(dot(v_normal, light)) * gains.y + gains.x;
    for (int i = 0; i < N_LAMPS; i++) {  // N_LAMPS: a constant, so the compiler unrolls the loop
        vec3 to = lamps[i] - v_world;
        float d2 = dot(to, to) + 1e-6;
        lam += gains.z * abs(dot(v_normal, to)) * inversesqrt(d2) / (1.0 + d2 * inv_reach2);
    }
    col = clamp(col * lam, 0.0, 1.0);
    // The ray caster truncates (x * 255 -> uint8); the framebuffer rounds: hand it the truncated value.
    col = (floor(col * 255.0) + 0.25) / 255.0;
    frag = vec4(col, 1.0);
}
"""


_DEPTH_VERTEX = """
#version 330
uniform mat4 view_proj;
uniform mat4 model;
in vec3 p;
void main() { gl_Position = view_proj * (model * vec4(p, 1.0)); }
"""

_DEPTH_FRAGMENT = """
#version 330
out vec4 frag;
void main() { frag = vec4(0.0); }
"""


class GlUnavailable(RuntimeError):
    """No OpenGL 3.3 context could be made (moderngl missing, or no EGL / Mesa on the system)."""


def gl_context():
    """A headless OpenGL context (EGL). Raises :class:`GlUnavailable` saying what to install."""
    try:
        import moderngl
    except ImportError as e:  # pragma: no cover - moderngl is a dependency
        raise GlUnavailable(f"moderngl is not installed ({e}): pip install moderngl") from None
    try:
        return moderngl.create_standalone_context(backend="egl", require=330)
    except Exception as e:  # glcontext raises plain Exceptions naming the library it could not load
        raise GlUnavailable(f"no EGL OpenGL 3.3 context ({e}); on Debian: apt-get install libegl1 libgl1-mesa-dri") from None


def projection(cam: PvCalibration | Pinhole, near: float = NEAR_M, far: float = FAR_M) -> np.ndarray:
    """OpenGL clip matrix (4, 4), column-vector, of the pinhole; image row 0 at the framebuffer's
    first row (y flipped), so ``glReadPixels`` returns the image top row first."""
    h, w = cam.shape
    fx, fy = cam.focal_length
    cx, cy = cam.principal_point
    return np.array([[2 * fx / w, 0.0, 1 - 2 * cx / w, 0.0],
                     [0.0, -2 * fy / h, -(2 * cy / h - 1), 0.0],
                     [0.0, 0.0, -(far + near) / (far - near), -2 * far * near / (far - near)],
                     [0.0, 0.0, -1.0, 0.0]])


def _flat_triangles(vertices: np.ndarray, triangles: np.ndarray, colors: np.ndarray) -> np.ndarray:
    """Non-indexed vertex records (3T, 9) float32: position, unit triangle normal, base colour."""
    tri = np.asarray(vertices, np.float64)[np.asarray(triangles)]            # (T, 3, 3)
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    col = np.broadcast_to(np.asarray(colors, np.float64).reshape(-1, 3), (len(tri), 3))
    rec = np.concatenate([tri, np.repeat(nrm[:, None], 3, 1), np.repeat(col[:, None], 3, 1)], axis=2)
    return np.ascontiguousarray(rec.reshape(-1, 9), np.float32)


def _mat(m: np.ndarray) -> bytes:
    return np.ascontiguousarray(np.asarray(m, np.float32).T).tobytes()  # GL reads column-major


class PvRenderer:
    """Rasterises PV colour frames of one scene (static room, instances, carrying hand)."""

    def __init__(self, scene: Scene, textures: Textures, lamps: np.ndarray | None, camera: PvCalibration | Pinhole,
                 background: float = 0.0):
        """``lamps``: world positions (L, 3) of the room's lamps, or None (sky light only);
        ``camera``: the PV calibration or any pinhole; ``background``: grey level in [0, 1] where
        nothing is hit."""
        import moderngl

        self.scene = scene
        self.shape = tuple(camera.shape)
        self.background = float(background)
        self.ctx = gl_context()
        ctx = self.ctx
        lamps = np.zeros((0, 3)) if lamps is None else np.asarray(lamps, np.float64).reshape(-1, 3)
        if len(lamps) > MAX_LAMPS:
            raise ValueError(f"at most {MAX_LAMPS} lamps, got {len(lamps)}")
        fragment = _FRAGMENT.replace("#version 330", f"#version 330\n#define N_LAMPS {len(lamps)}\n#define LAMP_SLOTS {max(len(lamps), 1)}", 1)
        self.prog = ctx.program(vertex_shader=_VERTEX, fragment_shader=fragment)
        # Depth pre-pass: every pixel is then shaded once (the room's boxes overlap a lot on screen).
        self.depth_prog = ctx.program(vertex_shader=_DEPTH_VERTEX, fragment_shader=_DEPTH_FRAGMENT)
        size = textures.size
        self.lattice = ctx.texture3d((size, size, size), 1, textures.lattice.astype(np.float32).tobytes(), dtype="f4")
        self.tint = ctx.texture3d((size, size, size), 3, textures.tint.astype(np.float32).tobytes(), dtype="f4")
        for tex in (self.lattice, self.tint):
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.lattice.use(0)
        self.tint.use(1)
        self._set("lattice", 0)
        self._set("tint", 1)
        self._set("inv_scale", tuple(float(np.float32(1.0 / s)) for s in Textures.SCALES))
        self._set("weight", tuple(float(w) for w in Textures.WEIGHTS))
        self._set("tint_inv_scale", float(np.float32(1.0 / Textures.TINT_SCALE)))
        self._set("tint_shift", Textures.TINT_SHIFT)
        self._set("contrast", Textures.CONTRAST)
        self._set("band_dim", BAND_DIM)
        self._set("gains", (AMBIENT, SKY_GAIN, LAMP_GAIN))
        self._set("light", tuple(float(x) for x in LIGHT))
        self._set("inv_reach2", 1.0 / LAMP_REACH ** 2)
        self._set("band_half", DETAIL_HALF_WIDTH)
        if len(lamps) and "lamps" in self.prog:
            self.prog["lamps"].write(lamps.astype(np.float32).tobytes())
        self.proj = projection(camera)
        self.static = self._vaos(ctx.buffer(_flat_triangles(scene.static_vertices, scene.static_triangles,
                                                            scene.static_tri_color).tobytes()))
        self.objects = [self._vaos(ctx.buffer(_flat_triangles(o.vertices, o.triangles, o.color).tobytes()))
                        for o in scene.objects]
        _, ht = hand_mesh(np.zeros(3), 0.0)
        self.hand_buffer = ctx.buffer(reserve=len(ht) * 3 * 9 * 4, dynamic=True)
        self.hand = self._vaos(self.hand_buffer)
        h, w = self.shape
        self.fbo = ctx.framebuffer(color_attachments=[ctx.renderbuffer((w, h), 4, dtype="f1")],
                                   depth_attachment=ctx.depth_renderbuffer((w, h)))
        self._moderngl = moderngl

    def _set(self, name: str, value) -> None:
        if name in self.prog:  # the GLSL compiler drops unused uniforms
            self.prog[name].value = value

    def _vaos(self, buffer) -> tuple:
        """(shading, depth-only) vertex arrays over one buffer of vertex records."""
        return (self.ctx.vertex_array(self.prog, [(buffer, "3f 3f 3f", "p", "n", "base")]),
                self.ctx.vertex_array(self.depth_prog, [(buffer, "3f 24x", "p")]))

    def render(self, cam_to_world: np.ndarray, obj_pos: np.ndarray, obj_yaw: np.ndarray,
               hand: tuple[np.ndarray, float] | None, only: int | None = None) -> np.ndarray:
        """RGB uint8 image (H, W, 3) seen from ``cam_to_world`` (row-vector PV pose, metres) with
        instance k at ``obj_pos[k]`` (world, metres) turned by ``obj_yaw[k]`` (radians about y) and
        the carrying hand at ``(palm centre, body yaw)`` or None. ``only``: draw that instance
        alone (no room, no hand), as the enrollment photos show it."""
        view = np.linalg.inv(np.asarray(cam_to_world, np.float64).T)
        draws = [] if only is not None else [(self.static, np.eye(4), STATIC_TEXTURE_SHIFT, NO_BAND)]
        for k, (obj, vaos) in enumerate(zip(self.scene.objects, self.objects)):
            if only is not None and k != only:
                continue
            model = np.eye(4)
            model[:3, :3] = rot_y(float(obj_yaw[k]))
            model[:3, 3] = obj_pos[k]
            twin_band = 0.2 * obj.size[1] if 0 <= obj.twin < k else NO_BAND  # the second of a look-alike pair
            draws.append((vaos, model, 11.0 * obj.pattern + 5.0, twin_band))
        if hand is not None and only is None:
            hv, ht = hand_mesh(*hand)
            self.hand_buffer.write(_flat_triangles(hv, ht, HAND_COLOR).tobytes())
            draws.append((self.hand, np.eye(4), STATIC_TEXTURE_SHIFT, NO_BAND))
        mgl, ctx = self._moderngl, self.ctx
        self.fbo.use()
        ctx.enable(mgl.DEPTH_TEST)
        bg = self.background
        self.fbo.clear(bg, bg, bg, 1.0, depth=1.0)
        vp = _mat(self.proj @ view)
        self.depth_prog["view_proj"].write(vp)
        self.prog["view_proj"].write(vp)
        ctx.depth_func = "<"
        self.fbo.color_mask = (False, False, False, False)
        for (_, depth_vao), model, _, _ in draws:
            self.depth_prog["model"].write(_mat(model))
            depth_vao.render(mgl.TRIANGLES)
        ctx.depth_func = "<="
        self.fbo.color_mask = (True, True, True, True)
        for (vao, _), model, tex_offset, band_y in draws:
            self.prog["model"].write(_mat(model))
            self._set("tex_offset", float(tex_offset))
            self._set("band_y", float(band_y))
            vao.render(mgl.TRIANGLES)
        h, w = self.shape
        data = self.fbo.read(components=3, alignment=1)
        return np.frombuffer(data, np.uint8).reshape(h, w, 3)

    def release(self) -> None:
        self.ctx.release()
