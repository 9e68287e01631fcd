"""The wearer's activity: walking between work areas, looking around with fast head turns,
picking objects up, carrying them in view and putting them down elsewhere.

Produces the true head (rig node) trajectory and every object's world position per PV
frame; values between frames (the AHAT capture time) are interpolated.
Rig frame: x right, y up, z backward (the head looks down -z). World: y up.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from egograph.geometry.hl2ss import rigid_from_rt
from egograph.synth.config import SynthConfig
from egograph.synth.scene import Scene, sample_spot

HAND_THICKNESS = 0.03  # palm thickness, metres (egograph.synth.sensors.hand_mesh)


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def head_rotation(yaw, pitch, roll) -> np.ndarray:
    """World-from-rig rotation(s), column convention; yaw 0 looks down world -z. Vectorised."""
    yaw, pitch, roll = (np.atleast_1d(np.asarray(a, float)) for a in (yaw, pitch, roll))
    out = np.einsum("nij,njk,nkl->nil", np.stack([rot_y(a) for a in yaw]),
                    np.stack([rot_x(a) for a in pitch]), np.stack([rot_z(a) for a in roll]))
    return out


def look_angles(eye: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Yaw and pitch (radians) that point the head's -z axis from ``eye`` at ``target``."""
    d = np.asarray(target, float) - np.asarray(eye, float)
    yaw = np.arctan2(-d[..., 0], -d[..., 2])
    pitch = np.arctan2(d[..., 1], np.hypot(d[..., 0], d[..., 2]))
    return yaw, pitch


def smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


@dataclass
class Move:
    instance: int
    pick_frame: int      # first frame the object is in hand (dynamic)
    place_frame: int     # last frame it is in hand; stationary again from place_frame + 1
    src: np.ndarray
    dst: np.ndarray


@dataclass
class Trajectory:
    fps: float
    head_pos: np.ndarray      # (N, 3) rig origin in world, metres
    yaw: np.ndarray           # (N,) radians
    pitch: np.ndarray
    roll: np.ndarray
    obj_pos: np.ndarray       # (N, K, 3) object centres in world
    obj_yaw: np.ndarray       # (N, K) radians about world y
    held: np.ndarray          # (N, K) bool: in hand (motion state dynamic)
    hand_pos: np.ndarray      # (N, 3) palm centre in world, metres (on the carried object's side facing the wearer)
    hand_active: np.ndarray   # (N,) bool
    hand_yaw: np.ndarray = None  # (N,) body yaw (radians about world y): the forearm points back towards the body
    moves: list[Move] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.yaw)

    def _interp(self, arr: np.ndarray, f: np.ndarray) -> np.ndarray:
        f = np.clip(np.asarray(f, float), 0, len(self) - 1)
        i0 = np.floor(f).astype(int)
        i1 = np.minimum(i0 + 1, len(self) - 1)
        w = (f - i0).reshape((-1,) + (1,) * (arr.ndim - 1))
        return arr[i0] * (1 - w) + arr[i1] * w

    def rig_poses(self, f: np.ndarray) -> np.ndarray:
        """Row-vector rig -> world poses (M, 4, 4) at fractional frame indices ``f``."""
        f = np.atleast_1d(f)
        r = head_rotation(self._interp(self.yaw, f), self._interp(self.pitch, f), self._interp(self.roll, f))
        return rigid_from_rt(r, self._interp(self.head_pos, f))

    def objects_at(self, f: float) -> tuple[np.ndarray, np.ndarray]:
        """Object centres (K, 3) and yaws (K,) at a fractional frame index."""
        f = np.atleast_1d(float(f))
        return self._interp(self.obj_pos, f)[0], self._interp(self.obj_yaw, f)[0]

    def hand_at(self, f: float) -> tuple[np.ndarray, float, bool]:
        """Palm centre (3,), body yaw (radians) and whether the hand is in the scene, at a fractional frame."""
        i = int(round(min(max(f, 0), len(self) - 1)))
        ff = np.atleast_1d(float(f))
        return self._interp(self.hand_pos, ff)[0], float(self._interp(self.hand_yaw, ff)[0]), bool(self.hand_active[i])

    def angular_speed_dps(self) -> np.ndarray:
        """Head angular speed per frame, degrees per second."""
        r = head_rotation(self.yaw, self.pitch, self.roll)
        rel = np.einsum("nji,njk->nik", r[:-1], r[1:])
        ang = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1))) * self.fps
        return np.concatenate([[0.0], ang])


def _stand_point(rng, scene: Scene, surface: int, spot: np.ndarray) -> np.ndarray:
    s = scene.surfaces[surface]
    f = s.front
    along = abs(f[0]) * s.half_extent[0] + abs(f[1]) * s.half_extent[1] + 0.1
    d_edge = float(np.dot(s.center[[0, 2]] - spot[[0, 2]], f)) + along
    xz = spot[[0, 2]] + f * (d_edge + rng.uniform(0.3, 0.45))
    xz += np.array([-f[1], f[0]]) * rng.uniform(-0.15, 0.15)
    w, d = scene.room_size[0], scene.room_size[1]
    return np.clip(xz, [0.4, 0.4], [w - 0.4, d - 0.4])


def make_trajectory(rng: np.random.Generator, scene: Scene, cfg: SynthConfig) -> Trajectory:
    n = cfg.frames
    fps = cfg.fps
    wc = cfg.wearer
    k = len(scene.objects)
    dt = 1.0 / fps

    # Initial resting places: each object on a surface, spread over the surfaces.
    occupied: list[np.ndarray] = []
    rest = np.zeros((k, 3))
    rest_surface = np.zeros(k, int)
    for i, obj in enumerate(scene.objects):
        for _ in range(50):
            s = int(rng.integers(len(scene.surfaces)))
            p = sample_spot(rng, scene, s, obj.size, occupied, cfg.scene.min_object_gap)
            if p is not None:
                break
        else:
            raise RuntimeError("could not place all objects; enlarge the room or reduce n_instances")
        rest[i], rest_surface[i] = p, s
        occupied.append(p)

    head_xz = np.zeros((n, 2))
    head_y = np.full(n, wc.head_height)
    gaze = np.zeros((n, 3))           # gaze target point (world), or NaN where pitch is forced
    forced_pitch = np.full(n, np.nan)  # radians, where the head looks down at the carried object
    turn_rate = np.zeros(n)            # fast head turn rate per frame (per second)
    walking = np.zeros(n, bool)
    carrying = np.full(n, -1)
    moves: list[Move] = []

    state = {"f": 0, "xz": _stand_point(rng, scene, int(rest_surface[0]), rest[0])}

    def remaining() -> int:
        return n - state["f"]

    def hold(seconds: float, target_fn, rate: float = 0.0, pitch=None, carry=-1, dip=0.0):
        m = max(1, int(round(seconds * fps)))
        a, b = state["f"], min(n, state["f"] + m)
        if a >= b:
            return
        head_xz[a:b] = state["xz"]
        head_y[a:b] = wc.head_height - dip
        gaze[a:b] = [target_fn(j) for j in range(a, b)]
        if pitch is not None:
            forced_pitch[a:b] = pitch
        turn_rate[a:b] = rate
        carrying[a:b] = carry
        state["f"] = b

    def walk(to_xz: np.ndarray, target_fn, rate: float = 0.0, pitch=None, carry=-1):
        dist = float(np.linalg.norm(to_xz - state["xz"]))
        seconds = dist / wc.walk_speed + 0.5
        m = max(1, int(round(seconds * fps)))
        a, b = state["f"], min(n, state["f"] + m)
        if a >= b:
            return
        s = smoothstep((np.arange(a, b) - a + 1) / m)
        head_xz[a:b] = state["xz"] + s[:, None] * (to_xz - state["xz"])
        t = np.arange(a, b) * dt
        head_y[a:b] = wc.head_height + 0.015 * np.sin(2 * np.pi * 1.9 * t) * np.sin(np.pi * s)
        gaze[a:b] = [target_fn(j) for j in range(a, b)]
        if pitch is not None:
            forced_pitch[a:b] = pitch
        turn_rate[a:b] = rate
        walking[a:b] = True
        carrying[a:b] = carry
        state["f"] = b
        state["xz"] = head_xz[b - 1].copy()

    def calm(seconds: float):
        # No fast head turn starts in the last ``seconds`` before now (a turn lasts up to ~1.7 s).
        a = max(0, state["f"] - int(round(seconds * fps)))
        turn_rate[a:state["f"]] = 0.0

    def look_around(seconds: float):
        # Look at a few other work areas in turn, with fast head turns on top.
        m = max(1, int(round(seconds * fps)))
        pieces = max(1, int(seconds / 1.2))
        for _ in range(pieces):
            s = scene.surfaces[int(rng.integers(len(scene.surfaces)))]
            target = s.center + np.array([0, 0.05, 0])
            hold(m / fps / pieces, lambda j, t=target: t, rate=wc.head_turn_rate)

    obj_pos = np.repeat(rest[None], n, axis=0)
    obj_yaw = np.repeat(rng.uniform(0, 2 * np.pi, k)[None], n, axis=0)
    held = np.zeros((n, k), bool)
    carry_dist = np.zeros(n)

    look_around(rng.uniform(*wc.idle_time))
    schedule = [int(i) for _ in range(cfg.scene.moves_per_instance) for i in rng.permutation(k)]
    cur = rest.copy()
    cur_surface = rest_surface.copy()
    for i in schedule:
        obj = scene.objects[i]
        occupied = [cur[j] for j in range(k) if j != i]
        choices = [s for s in range(len(scene.surfaces)) if s != cur_surface[i]]
        dst = None
        for _ in range(30):
            s_dst = int(rng.choice(choices))
            dst = sample_spot(rng, scene, s_dst, obj.size, occupied, cfg.scene.min_object_gap)
            if dst is not None:
                break
        if dst is None:
            continue
        stand_src = _stand_point(rng, scene, int(cur_surface[i]), cur[i])
        stand_dst = _stand_point(rng, scene, s_dst, dst)
        need = (np.linalg.norm(stand_src - state["xz"]) + np.linalg.norm(stand_dst - stand_src)) / wc.walk_speed \
            + 1.0 + 2 * wc.reach_time + wc.watch_time[0] + wc.idle_time[0]
        if need * fps > remaining():
            break
        src = cur[i].copy()
        dip_src = 0.15 if src[1] < 0.85 else 0.0
        dip_dst = 0.15 if dst[1] < 0.85 else 0.0
        walk(stand_src, lambda j, t=src: t, rate=wc.head_turn_rate / 3)
        calm(wc.approach_calm)
        hold(wc.reach_time, lambda j, t=src: t, dip=dip_src)
        pick = state["f"]
        d = rng.uniform(*wc.carry_distance)
        a = state["f"]
        walk(stand_dst, lambda j, t=dst: t, pitch=np.radians(-28.0), carry=i)
        hold(wc.reach_time, lambda j, t=dst: t, carry=i, dip=dip_dst)
        place = state["f"] - 1
        carry_dist[a:state["f"]] = d
        # The hand withdraws while the eyes stay a moment on the object just put down.
        hold(rng.uniform(*wc.watch_time), lambda j, t=dst: t, dip=dip_dst)
        moves.append(Move(i, pick, place, src, dst.copy()))
        cur[i] = dst
        cur_surface[i] = s_dst
        look_around(rng.uniform(*wc.idle_time))
    # Wander for the rest of the recording.
    while remaining() > 0:
        s = int(rng.integers(len(scene.surfaces)))
        spot = scene.surfaces[s].center.copy()
        walk(_stand_point(rng, scene, s, spot), lambda j, t=spot: t, rate=wc.head_turn_rate / 3)
        look_around(rng.uniform(*wc.idle_time))

    # Head orientation: look at the gaze target, follow it with a first-order lag.
    eye = np.column_stack([head_xz[:, 0], head_y, head_xz[:, 1]])
    yaw_d, pitch_d = look_angles(eye, gaze)
    pitch_d = np.where(np.isnan(forced_pitch), pitch_d, forced_pitch)
    # While carrying and walking, the head faces the walking direction.
    step = np.gradient(head_xz, axis=0)
    moving = np.linalg.norm(step, axis=1) > 1e-4
    walk_yaw = np.arctan2(-step[:, 0], -step[:, 1])
    use_walk = (carrying >= 0) & walking & moving
    yaw_d = np.where(use_walk, walk_yaw, yaw_d)
    yaw_d = np.unwrap(yaw_d)
    alpha = 1 - np.exp(-dt / wc.gaze_time_constant)
    yaw = np.empty(n)
    pitch = np.empty(n)
    yaw[0], pitch[0] = yaw_d[0], pitch_d[0]
    for j in range(1, n):
        yaw[j] = yaw[j - 1] + alpha * (yaw_d[j] - yaw[j - 1])
        pitch[j] = pitch[j - 1] + alpha * (pitch_d[j] - pitch[j - 1])
    body_yaw = yaw.copy()

    # Fast head turns (a Poisson process where turn_rate > 0): out, hold, back.
    offset = np.zeros(n)
    j = 0
    while j < n:
        if turn_rate[j] > 0 and rng.random() < turn_rate[j] * dt:
            amp = np.radians(rng.uniform(*wc.head_turn_angle)) * rng.choice([-1, 1])
            dur = rng.uniform(*wc.head_turn_time)
            hold_s = rng.uniform(0.3, 0.9)
            m, h = max(2, int(dur * fps)), int(hold_s * fps)
            prof = np.concatenate([smoothstep(np.arange(1, m + 1) / m), np.ones(h), 1 - smoothstep(np.arange(1, m + 1) / m)])
            e = min(n, j + len(prof))
            offset[j:e] += amp * prof[: e - j]
            j = e
        else:
            j += 1
    yaw = yaw + offset
    pitch = pitch + rng.normal(0, np.radians(0.5), n).cumsum() * 0.02
    roll = np.radians(2.0) * np.sin(2 * np.pi * 0.15 * np.arange(n) * dt + rng.uniform(0, 6))

    # Carried object: in front of the body, below the eyes, 0.3-0.6 m away; the hand grips it on the
    # side facing the wearer (so it hides part of it), the forearm reaching back to the body.
    hand_active = carrying >= 0
    body = np.stack([rot_y(a) for a in body_yaw])
    local = np.column_stack([np.full(n, 0.06), -0.28 * np.maximum(carry_dist, 0.3) / 0.45, -np.maximum(carry_dist, 0.3)])
    carry_pos = eye + np.einsum("nij,nj->ni", body, local)
    hand_pos = carry_pos.copy()
    for mv in moves:
        i = mv.instance
        a, b = mv.pick_frame, mv.place_frame
        size = scene.objects[i].size
        lift = max(2, int(0.4 * fps))
        put = max(2, int(cfg.wearer.reach_time * fps))
        w = np.ones(b + 1 - a)
        w[:lift] = smoothstep(np.arange(1, lift + 1) / lift)[: len(w)]
        tail = min(put, len(w))
        w[-tail:] = np.minimum(w[-tail:], 1 - smoothstep(np.arange(1, tail + 1) / tail))
        base = np.where((np.arange(a, b + 1) - a < len(w) / 2)[:, None], mv.src, mv.dst)
        obj_pos[a:b + 1, i] = base + w[:, None] * (carry_pos[a:b + 1] - base)
        obj_pos[b + 1:, i] = mv.dst
        obj_yaw[a:b + 1, i] = obj_yaw[a, i] + np.linspace(0, rng.uniform(-1, 1), b + 1 - a)
        obj_yaw[b + 1:, i] = obj_yaw[b, i]
        held[a:b + 1, i] = True
        # Palm against the object's near side, a little right of and below its centre (body frame:
        # x right, y up, z back towards the wearer).
        grip = np.array([0.02, -0.15 * size[1], max(size[0], size[2]) / 2 + HAND_THICKNESS / 2])
        hand_pos[a:b + 1] = obj_pos[a:b + 1, i] + np.einsum("nij,j->ni", body[a:b + 1], grip)
    return Trajectory(fps, eye, yaw, pitch, roll, obj_pos, obj_yaw, held, hand_pos, hand_active, hand_yaw=body_yaw, moves=moves)
