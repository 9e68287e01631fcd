"""The device world's rasteriser: photographic textures (a mipmapped texture array, trilinear
filtering), smooth vertex normals, the recording's room light; it returns scene radiance and depth
in floats, which :mod:`egograph.synth.camera` turns into the PV camera's pixels.

Conventions as :mod:`egograph.synth.render_gl` (row-vector ``cam_to_world``, camera looking down -z,
y up, image row 0 at the top). Radiance is linear: albedo (sRGB textures decoded to linear) times
the light (ambient + sky * |n.L| + lamps, falling off with distance) times the room's level.
"""

from __future__ import annotations

import numpy as np

from egograph.io.calibration import PvCalibration
from egograph.synth.device import RoomLight, object_records
from egograph.synth.render_gl import NEAR_M, _mat, gl_context, projection
from egograph.synth.scene import Scene
from egograph.synth.sensors import LIGHT, Pinhole
from egograph.synth.trajectory import rot_y

MAX_LAMPS = 4
FAR_M = 30.0
LAMP_REACH = 2.0

_VERTEX = """
#version 330
uniform mat4 view_proj;
uniform mat4 model;
uniform mat4 view;
in vec3 p;
in vec3 n;
in vec2 uv;
in float layer;
in float tri;
out vec3 v_world;
out vec3 v_normal;
out vec2 v_uv;
out float v_depth;
flat out float v_layer;
flat out float v_tri;
void main() {
    vec4 w = model * vec4(p, 1.0);
    v_world = w.xyz;
    v_normal = mat3(model) * n;
    v_uv = uv;
    v_layer = layer;
    v_tri = tri;
    v_depth = -(view * w).z;
    gl_Position = view_proj * w;
}
"""

_FRAGMENT = """
#version 330
uniform sampler2DArray tex;
uniform vec3 light;
uniform vec3 ambient;
uniform vec3 sky;
uniform vec3 lamp_rgb;
uniform float level;
uniform vec3 lamps[LAMP_SLOTS];
uniform float inv_reach2;
uniform vec3 flash_pos;     // a light at the camera (phone photos); flash_gain 0 switches it off
uniform float flash_gain;
in vec3 v_world;
in vec3 v_normal;
in vec2 v_uv;
in float v_depth;
flat in float v_layer;
flat in float v_tri;
out vec4 frag;
void main() {
    vec2 st = v_uv;
    vec3 nn = normalize(v_normal);
    if (v_tri > 0.0) {   // box faces of the room: texture by world position on the face's plane
        vec3 an = abs(nn);
        st = (an.x > an.y && an.x > an.z) ? v_world.zy : ((an.y > an.z) ? v_world.xz : v_world.xy);
        st = st / v_tri;
    }
    vec3 enc = texture(tex, vec3(st, v_layer)).rgb;
    vec3 albedo = pow(enc, vec3(2.2));
    vec3 lit = ambient + sky * abs(dot(nn, light));
    for (int i = 0; i < N_LAMPS; i++) {
        vec3 to = lamps[i] - v_world;
        float d2 = dot(to, to) + 1e-6;
        lit += lamp_rgb * abs(dot(nn, to)) * inversesqrt(d2) / (1.0 + d2 * inv_reach2);
    }
    if (flash_gain > 0.0) {
        vec3 to = flash_pos - v_world;
        float d2 = dot(to, to) + 1e-6;
        lit += vec3(flash_gain) * abs(dot(nn, to)) * inversesqrt(d2) / (0.3 + d2);
    }
    frag = vec4(albedo * lit * level, v_depth);
}
"""


class DeviceRenderer:
    """Renders radiance (H, W, 3) float32 and depth (H, W) float32 (metres along the view axis;
    ``FAR_M`` where nothing is hit) of a device-world scene."""

    def __init__(self, scene: Scene, light: RoomLight, camera: PvCalibration | Pinhole, extra_layers: list | None = None):
        import moderngl

        self.scene = scene
        self.shape = tuple(camera.shape)
        self.ctx = ctx = gl_context()
        lamps = np.asarray(light.lamps, np.float64).reshape(-1, 3)
        if len(lamps) > MAX_LAMPS:
            raise ValueError(f"at most {MAX_LAMPS} lamps, got {len(lamps)}")
        frag = _FRAGMENT.replace("#version 330", f"#version 330\n#define N_LAMPS {len(lamps)}\n#define LAMP_SLOTS {max(len(lamps), 1)}", 1)
        self.prog = ctx.program(vertex_shader=_VERTEX, fragment_shader=frag)
        layers = list(scene.layers) + list(extra_layers or [])
        size = layers[0].shape[0]
        # sRGB bytes as the photographs have them; the shader decodes to linear after filtering.
        data = np.stack([np.dstack([img, np.full(img.shape[:2], 255, np.uint8)]) for img in layers])
        self.tex = ctx.texture_array((size, size, len(layers)), 4, data.tobytes())
        self.tex.build_mipmaps()
        self.tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        self.tex.repeat_x = self.tex.repeat_y = True
        self.tex.use(0)
        self._set("tex", 0)
        self._set("light", tuple(float(x) for x in LIGHT))
        self.set_light(light)
        self._set("inv_reach2", 1.0 / LAMP_REACH ** 2)
        self._set("flash_gain", 0.0)
        if len(lamps) and "lamps" in self.prog:
            self.prog["lamps"].write(lamps.astype(np.float32).tobytes())
        self.proj = projection(camera, NEAR_M, FAR_M)
        self.static = self._vao(ctx.buffer(scene.static_render.tobytes()))
        self.objects = [self._vao(ctx.buffer(object_records(o).tobytes())) for o in scene.objects]
        hv, ht, _, _ = scene.hand_mesh(np.zeros(3), 0.0)
        self.hand_buffer = ctx.buffer(reserve=len(ht) * 3 * 10 * 4, dynamic=True)
        self.hand = self._vao(self.hand_buffer)
        h, w = self.shape
        self.fbo = ctx.framebuffer(color_attachments=[ctx.renderbuffer((w, h), 4, dtype="f4")],
                                   depth_attachment=ctx.depth_renderbuffer((w, h)))
        self._mgl = moderngl

    def _set(self, name: str, value) -> None:
        if name in self.prog:
            self.prog[name].value = value

    def set_light(self, light: RoomLight) -> None:
        self._set("ambient", tuple(float(x) for x in light.ambient))
        self._set("sky", tuple(float(x) for x in light.sky))
        self._set("lamp_rgb", tuple(float(x) for x in light.lamp))
        self._set("level", float(light.level))

    def set_flash(self, position: np.ndarray | None, gain: float = 0.0) -> None:
        """A light at ``position`` (world, metres), the phone's own light of an enrollment photo."""
        self._set("flash_gain", float(gain) if position is not None else 0.0)
        if position is not None:
            self._set("flash_pos", tuple(float(x) for x in position))

    def _vao(self, buffer):
        return self.ctx.vertex_array(self.prog, [(buffer, "3f 3f 2f 1f 1f", "p", "n", "uv", "layer", "tri")])

    def render(self, cam_to_world: np.ndarray, obj_pos: np.ndarray, obj_yaw: np.ndarray, hand=None,
               only: list[int] | None = None, room: bool = True, extra=None) -> tuple[np.ndarray, np.ndarray]:
        """Radiance and depth seen from ``cam_to_world`` with instance k at ``obj_pos[k]`` turned by
        ``obj_yaw[k]``, the hand ``(palm, yaw, grip)`` or None; ``only``: the instances to draw (all
        when None); ``room``: draw the static scene; ``extra``: (vertex array, model matrix) pairs
        drawn too (the tabletop of enrollment photos)."""
        mgl, ctx = self._mgl, self.ctx
        view = np.linalg.inv(np.asarray(cam_to_world, np.float64).T)
        self.fbo.use()
        ctx.enable(mgl.DEPTH_TEST)
        self.fbo.clear(0.0, 0.0, 0.0, FAR_M, depth=1.0)
        self.prog["view_proj"].write(_mat(self.proj @ view))
        self.prog["view"].write(_mat(view))
        draws = [(self.static, np.eye(4))] if room else []
        for k, vao in enumerate(self.objects):
            if only is not None and k not in only:
                continue
            model = np.eye(4)
            model[:3, :3] = rot_y(float(obj_yaw[k]))
            model[:3, 3] = obj_pos[k]
            draws.append((vao, model))
        if hand is not None:
            hv, ht, huv, hn = self.scene.hand_mesh(*hand)
            rec = np.concatenate([hv[ht], hn[ht], huv[ht], np.full(ht.shape + (1,), float(self.scene.hand_mesh.layer)),
                                  np.zeros(ht.shape + (1,))], 2).reshape(-1, 10).astype(np.float32)
            self.hand_buffer.write(rec.tobytes())
            draws.append((self.hand, np.eye(4)))
        draws += list(extra or [])
        for vao, model in draws:
            self.prog["model"].write(_mat(model))
            vao.render(mgl.TRIANGLES)
        h, w = self.shape
        out = np.frombuffer(self.fbo.read(components=4, dtype="f4", alignment=1), np.float32).reshape(h, w, 4)
        return out[:, :, :3], out[:, :, 3]

    def records_vao(self, records: np.ndarray):
        """A vertex array of extra render records (3T, 10) (see :func:`egograph.synth.device._static_records`)."""
        return self._vao(self.ctx.buffer(np.ascontiguousarray(records, np.float32).tobytes()))

    def release(self) -> None:
        self.ctx.release()
