"""The online graph tracker: one frame's observations in, that frame's best answer out.

The causal form of the offline place chain (:mod:`egograph.track.places`), per instance:

* *Places* are found as the stream goes: a detection whose best alias candidate lies inside a
  place's inlier gate (chi2 ``graph.inlier_chi2`` under the detection's covariance plus the
  place's) joins it, and the place's centre is the information-weighted mean of its inliers
  (covariance: the inverse of their summed information); any other detection founds a new place.
* *The place chain* is the same hidden Markov chain as offline (states: standing at each place,
  carried from each place, carried from nowhere known, standing at a place not yet seen), with the
  same detection likelihoods and transition rates, advanced frame by frame by max-product (Viterbi)
  recursion. A new place takes over the 'not yet seen' state's score (the object stood there
  unseen) and the routes of a carry or an unseen move into it; the detection that founds it is
  scored by the prior predictive density (``false_density``): one detection alone is not evidence
  that the object stands where it is (its place was fitted to it), but the next one is.
* *The answer* for a frame is the last state of the most probable state sequence so far: a place
  (its current centre), nothing while carried, and, at a place not yet seen after a carry, where
  the hand last held the object. With a lag S (``lag_s`` seconds) the answer for frame t is read
  off the most probable sequence up to t + S (backtracking), so later evidence revises it; a place
  found within the lag answers the frames before it that the sequence spends unseen just before it.

Carry evidence: a detection within ``carry_range_m`` of the camera is *in hand* when, together
with the near detections of the last two seconds (of those since its place was founded, when it
joins a young place seen only from close by), it moves with the head by a clear margin
(:func:`egograph.track.segments.moves_with_camera`, ``online_carry_margin``). Negative evidence
(``graph.negative``): when depth shows the answered place empty, standing there becomes
``places.empty_likelihood`` times less likely. The detection noise scale is fitted as the stream
goes (``graph.noise.online_auto``): the offline fit (:mod:`egograph.track.noise_scale`) on the
newest inliers of places with two or more, every ``online_refit_every`` detections.

Memory and time per frame are bounded: each place keeps its newest ``online_max_rows`` inliers (for
the scale fit) and an instance at most ``online_max_places`` places (the weakest one that no recent
path uses is forgotten); back-pointers are kept for the lag only. World frame, metres; PV frame
indices and 100 ns ticks.

A live loop::

    trk = OnlineTracker(cfg.graph, t0=first_pv_timestamp)
    for frame, (ts, obs) in enumerate(stream):   # obs: this frame's lifted Observations
        preds = trk.step(frame, ts, obs)          # [Prediction(instance, xyz, score)], this frame
"""

from __future__ import annotations

import dataclasses
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from egograph.core.types import PositionInterval, Prediction
from egograph.core.units import TICKS_PER_SECOND
from egograph.geometry.observations import Observations
from egograph.track.answers import HAND, HAND_RAW, HELD, LAST, LAST_RAW, PUT_DOWN, STAND, UNSEEN, held_rows
from egograph.track.config import GraphConfig
from egograph.track.detection_factor import lengths
from egograph.track.noise_scale import refit
from egograph.track.places import (
    ANY_CARRY,
    UNSEEN_STATE,
    candidate_covariances,
    carry_state,
    carry_states,
    log_true_share,
    mahalanobis2_3d,
    n_states,
    row_log_likelihoods,
    stand_state,
    state_kind,
    transitions,
    viterbi_step,
)
from egograph.track.segments import NegativeFn, SupportFn, moves_with_camera, with_floor

HAND_WINDOW_S = 2.0
"""Near detections of the last this many seconds decide whether a new one moves with the head."""


@dataclass(eq=False)
class OnlinePlace:
    """A place found online: the information-weighted mean of its inliers (world, metres)."""

    info: np.ndarray            # summed information of its inliers, 1/m^2
    info_x: np.ndarray          # summed information times position
    n: int
    first_frame: int
    last_frame: int
    first_seen: int             # ticks
    last_seen: int
    max_rows: int               # newest inliers kept for the noise-scale fit (graph.online_max_rows)
    xyz: np.ndarray = field(default_factory=lambda: np.zeros(3))
    xyz_tuple: tuple = (0.0, 0.0, 0.0)
    covariance: np.ndarray = field(default_factory=lambda: np.eye(3))
    supported: tuple | None = None      # (inliers when tested, whether the scene holds it up)
    near_only: bool = False             # every inlier seen from within carry_range_m
    # The kept inliers, a ring in arrays (the fit reads them all at once, every
    # noise.online_refit_every detections): position (world, metres) and information (1/m^2).
    row_world: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    row_info: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    n_kept: int = 0
    next_row: int = 0           # where the next inlier goes once the ring is full

    def update(self) -> None:
        self.covariance = np.linalg.inv(self.info)
        self.xyz = self.covariance @ self.info_x
        self.xyz_tuple = tuple(self.xyz.tolist())   # as predictions carry it (answered every frame)

    def keep(self, world: np.ndarray, info: np.ndarray) -> None:
        """Keep one inlier for the noise-scale fit (the oldest goes beyond ``max_rows``)."""
        if self.n_kept == len(self.row_world) < self.max_rows:  # full below the cap: twice the room
            grow = min(max(4, 2 * self.n_kept), self.max_rows)
            self.row_world = np.concatenate([self.row_world, np.zeros((grow - self.n_kept, 3))])
            self.row_info = np.concatenate([self.row_info, np.zeros((grow - self.n_kept, 3, 3))])
        if self.n_kept < len(self.row_world):
            at = self.n_kept
            self.n_kept += 1
        else:
            at = self.next_row
            self.next_row = (self.next_row + 1) % self.max_rows
        self.row_world[at], self.row_info[at] = world, info

    def kept(self) -> tuple[np.ndarray, np.ndarray]:
        """The kept inliers: positions (K, 3) and information (K, 3, 3), in no particular order."""
        return self.row_world[:self.n_kept], self.row_info[:self.n_kept]

    def add(self, world: np.ndarray, info: np.ndarray, frame: int, ticks: int, near: bool) -> None:
        self.near_only = self.near_only and near
        self.info = self.info + info
        self.info_x = self.info_x + info @ world
        self.n += 1
        self.last_frame, self.last_seen = frame, ticks
        self.keep(world, info)
        self.update()

    def rescale(self, f2: float) -> None:
        """Every inlier's covariance times ``f2`` (a new detection noise scale squared)."""
        self.info, self.info_x = self.info / f2, self.info_x / f2
        self.row_info[:self.n_kept] /= f2
        self.update()


@dataclass
class _Instance:
    """One instance's incremental state."""

    delta: np.ndarray                   # log max-product score per state (places.n_states layout)
    places: list = field(default_factory=list)
    back: deque = field(default_factory=deque)   # (frame, back-pointers into the previous frame's states)
    near: deque = field(default_factory=deque)   # (ticks, world, camera, range) near detections
    hands: deque = field(default_factory=lambda: deque(maxlen=64))  # (ticks, where the hand held it)
    hand_rows: deque = field(default_factory=lambda: deque(maxlen=3))
    n_rows: int = 0
    last_negative_check: int = -1
    created: int = 0                    # the PV frame of its first detection
    version: int = 0                    # bumped whenever a place is added, moved, merged or dropped
    arrays: tuple | None = None         # (version, centres (k, 3), covariances (k, 3, 3), inliers (k,))
    best: int = 1                       # its leading state now (UNSEEN_STATE before the first frame)
    lead: float = 1.0                   # the leading state's max-marginal now (_lead_probability)
    claim: tuple | None = None          # (centre, inliers) of the place it stands at, answered (_claim)
    claimed: tuple | None = None        # (version, claims version, places claimed) (_claimed)
    kept_spots: tuple | None = None     # (version, centres, covariances, inliers) of places of n >= 2 (spots)
    last_xyz: np.ndarray | None = None  # its newest detection (world, metres): the answer while nothing better is known
    last_frame: int = -1                # the PV frame of that detection
    last_ts: int = -1                   # and its timestamp, ticks
    seen: list = field(default_factory=list)  # (world (n, 3), range (n,)) of every frame's detections so far
    last_held: tuple = (-1, False)      # (n_rows, whether the newest detection's support was seen close by)

    def place_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Its places' centres (world, metres), covariances (m^2) and inlier counts, as arrays
        (rebuilt only after a change: they are read per frame and per detection)."""
        if self.arrays is None or self.arrays[0] != self.version:
            self.arrays = (self.version,
                           np.array([p.xyz for p in self.places], float).reshape(-1, 3),
                           np.array([p.covariance for p in self.places], float).reshape(-1, 3, 3),
                           np.array([p.n for p in self.places], float))
        return self.arrays[1:]

    def moved(self, j: int) -> None:
        """Place ``j`` gained an inlier: a new version, its row of the arrays refreshed in place."""
        fresh = self.arrays is not None and self.arrays[0] == self.version
        self.version += 1
        if fresh:
            _, xyz, cov, n = self.arrays
            p = self.places[j]
            xyz[j], cov[j], n[j] = p.xyz, p.covariance, p.n
            self.arrays = (self.version, xyz, cov, n)

    def spots(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Its places with two or more inliers, where look-alike matches of other instances gather:
        centres (P, 3), covariances (P, 3, 3), inliers (P,)."""
        if self.kept_spots is None or self.kept_spots[0] != self.version:
            xyz, cov, n = self.place_arrays()
            keep = n >= 2
            self.kept_spots = (self.version, xyz[keep], cov[keep], n[keep])
        return self.kept_spots[1:]


def alias_candidates(obs: Observations, sel: np.ndarray) -> np.ndarray:
    """(M, C, 3) the AHAT alias candidates of rows ``sel``, the chosen one being ``world`` (the
    lifted point is the authority; the candidates are its alternatives), world frame, metres."""
    world = np.asarray(obs.world[sel], float)
    cands = np.array(obs.candidates[sel], float)
    if cands.ndim != 3 or cands.shape[1] == 0:
        return world[:, None, :]
    chosen = np.asarray(obs.chosen[sel], int)
    at = np.where((chosen >= 0) & (chosen < cands.shape[1]), chosen, 0)
    cands[np.arange(len(sel)), at] = world
    return cands


def _predecessors(delta: np.ndarray, log_a_new: np.ndarray) -> tuple[float, int]:
    best = int(np.argmax(delta + log_a_new))
    return float(delta[best] + log_a_new[best]), best


class OnlineTracker:
    """The graph tracker fed one PV frame at a time (module doc).

    ``cfg``: the ``graph`` configuration; ``t0``: the recording's first PV timestamp (ticks);
    ``lag_s``: answers wait this many seconds for later evidence (default ``cfg.lag_s``; 0 is
    strictly causal); ``negative``/``support``: as for :func:`egograph.track.graph.graph_tracker`
    (they may read only frames up to the current one).
    """

    def __init__(self, cfg: GraphConfig, t0: int, *, lag_s: float | None = None,
                 negative: NegativeFn | None = None, support: SupportFn | None = None):
        self.cfg, self.t0 = cfg, int(t0)
        self.lag_ticks = int(round((cfg.lag_s if lag_s is None else lag_s) * TICKS_PER_SECOND))
        self.negative, self.support = negative, support
        self.inst: dict[int, _Instance] = {}
        self.pending: deque = deque()    # (frame, timestamp) not yet emitted
        self.ready: deque = deque()      # (frame, timestamp, predictions) emitted, not yet collected
        self.spans: list[tuple] = []     # (instance, place, f0, t0, f1, t1, confidence) stands reported
        self._open: dict[int, list] = {}
        self.last_frame, self.last_ts = -1, None
        self.n_observations = 0
        self.fps = 30.0
        self.scale = float(cfg.noise.auto_start if cfg.noise.online_auto else cfg.noise.scale)
        self.scales = [self.scale]
        self._noise = dataclasses.replace(cfg.noise, scale=self.scale)
        self._cfg_scaled = dataclasses.replace(cfg, noise=self._noise)
        self._next_fit = cfg.noise.online_refit_every
        self._trans: dict[tuple[int, float], np.ndarray] = {}
        self._keep_back = max(2, int(np.ceil(self.lag_ticks / TICKS_PER_SECOND * 60.0)) + 2)
        # every instance's claim (_claim): centre (world, metres), inliers, whether it stands anywhere
        self._claim_xyz, self._claim_n, self._claim_on = np.zeros((0, 3)), np.zeros(0), np.zeros(0, bool)
        self._claim_row: dict[int, int] = {}
        self._claims_version = 0
        self._calibration: tuple | None = None  # graph.answers.causal_calibration/_kinds as arrays (_answer)

    # ------------------------------------------------------------------ the loop

    def step(self, frame: int, timestamp: int, obs: Observations | None = None) -> list[Prediction]:
        """Process PV frame ``frame`` (index, increasing) at ``timestamp`` (ticks) with its
        observations (rows of other frames are refused; invalid and below-threshold rows are
        ignored). Returns the causal answer for this frame, one prediction per instance; with a
        lag, the final answers of earlier frames are collected with :meth:`collect`."""
        frame, timestamp = int(frame), int(timestamp)
        if frame <= self.last_frame:
            raise ValueError(f"frame {frame} after frame {self.last_frame}: frames must increase")
        if obs is not None and len(obs) and np.any(obs.frame != frame):
            raise ValueError(f"observations of frames {sorted(set(obs.frame.tolist()) - {frame})} given "
                             f"with frame {frame}")
        if self.last_ts is not None and timestamp > self.last_ts:
            self.fps = 0.9 * self.fps + 0.1 * TICKS_PER_SECOND * (frame - self.last_frame) / (timestamp - self.last_ts)
        self.last_frame, self.last_ts = frame, timestamp
        self.pending.append((frame, timestamp))
        rows: dict[int, np.ndarray] = {}
        if obs is not None and len(obs):
            keep = obs.valid & (np.asarray(obs.score, np.float32) >= np.float32(self.cfg.score_threshold))
            for inst in np.unique(obs.instance[keep]):
                rows[int(inst)] = np.flatnonzero(keep & (obs.instance == inst))
                if int(inst) not in self.inst:
                    self.inst[int(inst)] = self._new_instance(frame)
        for i, st in self.inst.items():
            self._advance(i, st, frame, timestamp, obs, rows.get(i))
        if self.cfg.noise.online_auto and self.n_observations >= self._next_fit:
            self._next_fit = self.n_observations + self.cfg.noise.online_refit_every
            self._refit_scale()
        now = {i: self._answer(i, st, st.best, None, timestamp, st.lead)
               for i, st in self.inst.items()}
        self._emit(timestamp - self.lag_ticks, now)
        return [now[i] for i in sorted(now) if now[i] is not None]

    def collect(self) -> list[tuple[int, int, list[Prediction]]]:
        """Final answers emitted since the last call: (frame, timestamp, predictions), in frame order."""
        out = list(self.ready)
        self.ready.clear()
        return out

    def finish(self) -> list[tuple[int, int, list[Prediction]]]:
        """End of the stream: emit every pending frame (with what is known now) and collect."""
        self._emit(None)
        for i in list(self._open):
            self._close_span(i)
        return self.collect()

    def intervals(self) -> list[PositionInterval]:
        """The stands reported so far (emitted frames), one interval per place and run of frames,
        at the place's latest estimate."""
        spans = list(self.spans) + [tuple(s) for s in self._open.values()]
        out = []
        for inst, place, f0, t0, f1, t1, conf in spans:
            out.append(PositionInterval(
                instance=inst, t_start=t0, t_end=t1, xyz=tuple(float(v) for v in place.xyz),
                covariance=with_floor(place.covariance, self.cfg).tolist(), n_observations=place.n,
                confidence=conf, first_seen=place.first_seen, last_seen=place.last_seen, ended_by="end",
                extra={"start_frame": f0, "end_frame": f1},
            ))
        out.sort(key=lambda iv: (iv.instance, iv.t_start))
        for a, b in zip(out, out[1:]):
            if a.instance == b.instance:
                a.ended_by = "detection"
        return out

    # ------------------------------------------------------------------ per instance

    def _new_instance(self, frame: int) -> _Instance:
        _, prior = transitions(0, self.cfg, self.fps)
        return _Instance(delta=prior.copy(), back=deque(maxlen=self._keep_back), near=deque(),
                         hand_rows=deque(maxlen=3), created=frame)

    def _transitions(self, k: int) -> np.ndarray:
        """Log transitions into each state of ``k`` places (to, from), as :func:`viterbi_step` takes them."""
        key = (k, round(self.fps, 1))
        if key not in self._trans:
            if len(self._trans) > 256:
                self._trans.clear()
            self._trans[key] = np.ascontiguousarray(transitions(k, self.cfg, self.fps)[0].T)
        return self._trans[key]

    def _advance(self, inst: int, st: _Instance, frame: int, ts: int, obs: Observations | None,
                 sel: np.ndarray | None) -> None:
        """One frame of the place chain: transition, new places, detections, negative evidence."""
        delta, back = viterbi_step(st.delta, self._transitions(len(st.places)))
        held_now = False
        if sel is not None and len(sel):
            delta, back, held_now = self._observe(inst, st, frame, ts, obs, sel, delta, back)
        if not held_now:
            delta[carry_states(len(st.places))] += np.log1p(-self.cfg.places.carry_detect_rate)
        claimed = self._claimed(inst, st)
        if self.support is not None:
            claimed = claimed | np.array([not self._held_up(p) for p in st.places], bool)
        if claimed.any():  # in mid-air, or another instance's: not a place to stand
            delta[stand_state(np.flatnonzero(claimed))] = -np.inf
        if self.negative is not None:
            self._check_negative(inst, st, frame, delta)
        best = int(np.argmax(delta))
        st.delta = delta - delta[best]
        st.back.append((frame, back.astype(np.int32)))
        while len(st.places) > self.cfg.online_max_places:
            lead = state_kind(int(np.argmax(st.delta)))
            weakest = min((j for j in range(len(st.places)) if j != lead),
                          key=lambda j: (st.places[j].n, st.places[j].last_frame))
            self._forget(st, weakest)
            best = int(np.argmax(st.delta))
        st.best = best
        st.lead = self._lead_probability(st)
        kind = state_kind(st.best)
        answered = kind >= 0 and st.lead >= self.cfg.places.min_answer_probability
        self._claim(inst, st, (st.places[kind].xyz, st.places[kind].n) if answered else None)

    def _observe(self, inst: int, st: _Instance, frame: int, ts: int, obs: Observations, sel: np.ndarray,
                 delta: np.ndarray, back: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
        cfg = self.cfg
        self.n_observations += len(sel)
        st.n_rows += len(sel)
        world = np.asarray(obs.world[sel], float)
        camera = np.asarray(obs.camera[sel], float)
        rng = np.asarray(obs.range_m[sel], float)
        cands = alias_candidates(obs, sel)
        cand_cov = candidate_covariances(cands, camera, self._cfg_scaled)
        log_true = log_true_share(obs.score[sel], cfg)
        # each detection joins the place whose gate (or merge radius) its best alias candidate falls in
        joins = np.full(len(sel), -1)
        chosen = np.zeros(len(sel), int)  # the alias candidate a joining detection takes
        for r in range(len(sel)):
            j, c = self._nearest_place(st, cands[r], cand_cov[r])
            if j >= 0:
                joins[r], chosen[r], world[r] = j, c, cands[r, c]
        # near detections that no place seen from afar explains, moving with the head: in hand
        young = ts - HAND_WINDOW_S * TICKS_PER_SECOND
        free = np.array([j < 0 or (st.places[j].near_only and st.places[j].first_seen >= young) for j in joins], bool)
        # one that joins such a place is judged on the near detections since the place was founded:
        # an object just put down is still, and the carry before it must not outvote that
        since = np.array([st.places[j].first_seen if j >= 0 else young for j in joins], np.int64)
        in_hand = self._in_hand(st, ts, world, camera, rng, free, since)
        joins[in_hand] = -1
        founded = np.full(len(sel), -1)  # the place each of the others founds
        for r in np.flatnonzero((joins < 0) & ~in_hand):
            j, c = self._nearest_place(st, cands[r], cand_cov[r])  # a place founded this frame
            if j >= 0:
                joins[r], chosen[r], world[r] = j, c, cands[r, c]
                continue
            founded[r] = len(st.places)
            delta, back = self._found(st, world[r], cand_cov[r, 0], frame, ts, delta, back)
        k = len(st.places)
        new = set(int(j) for j in founded if j >= 0)
        own_xyz, own_cov, own_n = st.place_arrays()
        own_n = own_n.copy()
        if new:
            own_n[sorted(new)] = 0
        parts = [(own_xyz, own_cov, own_n)] + [o.spots() for j, o in self.inst.items() if j != inst]
        spots = tuple(np.concatenate(a) for a in zip(*parts))  # own places, then others' (_Instance.spots)
        ll = row_log_likelihoods(spots, k, cands, cand_cov, log_true, in_hand, cfg)
        for r in range(len(sel)):
            if founded[r] >= 0:  # the founding detection: prior predictive under its own place
                s = stand_state(int(founded[r]))
                ll[r, s] = np.logaddexp(log_true[r] + np.log(cfg.places.false_density), ll[r, UNSEEN_STATE])
        delta = delta + ll.sum(axis=0)
        joined = np.flatnonzero(joins >= 0)
        info = np.linalg.inv(cand_cov[joined, chosen[joined]])  # each at the candidate it took
        for r, inf in zip(joined, info):
            st.places[int(joins[r])].add(world[r], inf, frame, ts, bool(rng[r] <= cfg.carry_range_m))
            st.moved(int(joins[r]))
        for r in np.flatnonzero(founded >= 0):
            st.places[int(founded[r])].near_only = bool(rng[r] <= cfg.carry_range_m)
        for j in sorted({int(v) for v in joins if v >= 0}, reverse=True):
            delta, back = self._merge_into(st, j, delta, back)
        st.last_xyz, st.last_frame, st.last_ts = world[-1], frame, ts
        if cfg.answers.every_frame and cfg.answers.held_range_m > 0:
            st.seen.append((world, rng))
        if in_hand.any():
            for w in world[in_hand]:
                st.hand_rows.append(w)
            st.hands.append((ts, np.median(np.array(st.hand_rows), axis=0)))
            # the near detections that founded places just before were the object in hand already
            since = ts - HAND_WINDOW_S * TICKS_PER_SECOND
            for j in reversed(range(len(st.places))):
                p = st.places[j]
                if p.near_only and p.first_seen >= since and p.n <= len(st.near):
                    delta, back = self._forget(st, j, delta, back)
        return delta, back, bool(in_hand.any())

    def _found(self, st: _Instance, world: np.ndarray, cov: np.ndarray, frame: int, ts: int,
               delta: np.ndarray, back: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A new place at ``world``: its stand state takes the routes into it from the previous
        frame (standing there unseen, a carry ending, an unseen move); its carry state none."""
        pc, dt = self.cfg.places, 1.0 / max(self.fps, 1e-3)
        k = len(st.places)
        prev = st.delta  # scores of the previous frame (before this frame's transition)
        lift, drop = pc.pick_up_rate * dt, dt / pc.carry_s
        into = np.full(len(prev), -np.inf)
        into[UNSEEN_STATE] = np.log1p(-lift)
        into[ANY_CARRY] = np.log(drop * (1.0 - pc.unseen_put_down) / (k + 1))
        for j in range((len(prev) - 2) // 2):  # places of the previous frame
            into[carry_state(j)] = np.log(max(drop * (1.0 - pc.put_back - pc.unseen_put_down), 1e-300) / (k + 1))
            into[stand_state(j)] = np.log(max(pc.unseen_move_rate * dt, 1e-300) / (k + 1))
        score, src = _predecessors(prev, into)
        info = np.linalg.inv(cov)
        p = OnlinePlace(info=info, info_x=info @ world, n=1, first_frame=frame, last_frame=frame, first_seen=ts,
                        last_seen=ts, max_rows=self.cfg.online_max_rows)
        p.keep(world, info)
        p.update()
        st.places.append(p)
        st.version += 1
        delta = np.concatenate([delta, [score, -np.inf]])
        back = np.concatenate([back, [src, src]])
        return delta, back

    def _nearest_place(self, st: _Instance, cands: np.ndarray, cand_cov: np.ndarray) -> tuple[int, int]:
        """(place, alias candidate) of the place whose inlier gate one of a detection's candidates
        ``cands`` (C, 3) falls in, or that lies within ``merge_radius_m`` of it, the closest in the
        Mahalanobis sense; (-1, -1) when none."""
        if not st.places:
            return -1, -1
        finite = np.isfinite(cands[:, 0])
        ok = None if finite.all() else np.flatnonzero(finite)                  # None: every candidate
        if ok is not None:
            if len(ok) == 0:
                return -1, -1
            cands, cand_cov = cands[ok], cand_cov[ok]
        px, pc, _ = st.place_arrays()                                          # (P, 3), (P, 3, 3)
        d = cands[None] - px[:, None]                                          # (P, C, 3)
        d2 = mahalanobis2_3d(d, cand_cov[None] + pc[:, None])[0]
        if len(cands) == 1:                                                    # one candidate: no alias
            c, best_d2, dc = np.zeros(len(px), int), d2[:, 0], d[:, 0]
        else:
            c = np.argmin(d2, axis=1)                                          # each place's best candidate
            rows = np.arange(len(px))
            best_d2, dc = d2[rows, c], d[rows, c]
        fits = (best_d2 <= self.cfg.inlier_chi2) | (lengths(dc) <= self.cfg.merge_radius_m)
        if not fits.any():
            return -1, -1
        j = int(np.argmin(np.where(fits, best_d2, np.inf)))                  # first of equals, as a loop would
        return j, int(c[j] if ok is None else ok[c[j]])

    def _in_hand(self, st: _Instance, ts: int, world: np.ndarray, camera: np.ndarray, rng: np.ndarray,
                 free: np.ndarray, since: np.ndarray) -> np.ndarray:
        """Per detection: one that no place explains (``free``), seen from within ``carry_range_m``
        and, with the near detections seen from ``since`` on (ticks, per detection; at most
        :data:`HAND_WINDOW_S` seconds back), moving with the head (an alias-wrapped view of a
        standing object also keeps its offset to the head, but its other candidate fits the place)."""
        cfg = self.cfg
        near = free & (rng <= cfg.carry_range_m)
        while st.near and ts - st.near[0][0] > HAND_WINDOW_S * TICKS_PER_SECOND:
            st.near.popleft()
        for r in np.flatnonzero(near):
            st.near.append((ts, world[r], camera[r], rng[r]))
        out = np.zeros(len(world), bool)
        if len(st.near) < max(cfg.min_carry_observations, 2) or not near.any():
            return out
        t = np.array([x[0] for x in st.near])
        w = np.array([x[1] for x in st.near])
        c = np.array([x[2] for x in st.near])
        r = np.array([x[3] for x in st.near])
        verdict: dict[int, bool] = {}
        for q in np.flatnonzero(near):
            lo = int(since[q])
            if lo not in verdict:
                m = t >= lo
                verdict[lo] = bool(m.sum() >= max(cfg.min_carry_observations, 2)
                                   and moves_with_camera(w[m], c[m], r[m], cfg, cfg.online_carry_margin))
            out[q] = verdict[lo]
        return out

    def _claimed(self, inst: int, st: _Instance) -> np.ndarray:
        """Per place of ``st``: another instance stands there now, within ``exclusion_radius_m``
        and with more inliers (two objects cannot stand in one place at once). An instance stands
        at its leading state's place when that would be answered (``places.min_answer_probability``;
        a guess among equals claims nothing); the claims are kept in arrays by :meth:`_claim`, and
        the answer until its places or any claim change."""
        memo = st.claimed
        if memo is not None and memo[0] == st.version and memo[1] == self._claims_version:
            return memo[2]
        on = self._claim_on.copy()
        if inst in self._claim_row:
            on[self._claim_row[inst]] = False
        claimed = np.zeros(len(st.places), bool)
        if st.places and on.any():
            cx, cn = self._claim_xyz[on], self._claim_n[on]
            px, _, pn = st.place_arrays()
            near = lengths(px[:, None] - cx[None]) <= self.cfg.exclusion_radius_m
            claimed = (near & (cn[None] > pn[:, None])).any(axis=1)
        claimed.flags.writeable = False
        st.claimed = (st.version, self._claims_version, claimed)
        return claimed

    def _claim(self, inst: int, st: _Instance, claim: tuple | None) -> None:
        """Instance ``inst`` now stands at ``claim`` (centre, inliers) or at no answered place (None)."""
        old = st.claim
        st.claim = claim
        if (old is None) == (claim is None) and (claim is None or (old[0] is claim[0] and old[1] == claim[1])):
            return
        if inst not in self._claim_row:
            self._claim_row[inst] = len(self._claim_on)
            self._claim_xyz = np.concatenate([self._claim_xyz, np.zeros((1, 3))])
            self._claim_n = np.concatenate([self._claim_n, [0.0]])
            self._claim_on = np.concatenate([self._claim_on, [False]])
        row = self._claim_row[inst]
        self._claim_on[row] = claim is not None
        if claim is not None:
            self._claim_xyz[row], self._claim_n[row] = claim
        self._claims_version += 1

    def _merge_into(self, st: _Instance, j: int, delta: np.ndarray, back: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
        """Place ``j`` moved within ``merge_radius_m`` of another: one place, the stronger keeps the
        inliers of both and the better score of each state."""
        gap = lengths(st.place_arrays()[0] - st.places[j].xyz)
        near = [int(i) for i in np.flatnonzero(gap <= self.cfg.merge_radius_m) if i != j]
        if not near:
            return delta, back
        i = max(near, key=lambda q: st.places[q].n)
        keep, lose = (i, j) if st.places[i].n >= st.places[j].n else (j, i)
        a, b = st.places[keep], st.places[lose]
        a.info, a.info_x, a.n = a.info + b.info, a.info_x + b.info_x, a.n + b.n
        a.first_frame, a.first_seen = min(a.first_frame, b.first_frame), min(a.first_seen, b.first_seen)
        a.near_only = a.near_only and b.near_only
        for w, i in zip(*b.kept()):
            a.keep(w, i)
        a.update()
        for s_keep, s_lose in ((stand_state(keep), stand_state(lose)), (carry_state(keep), carry_state(lose))):
            if delta[s_lose] > delta[s_keep]:
                delta[s_keep], back[s_keep] = delta[s_lose], back[s_lose]
        into = {stand_state(lose): stand_state(keep), carry_state(lose): carry_state(keep)}
        return self._forget(st, lose, delta, back, into)

    @staticmethod
    def _forget(st: _Instance, j: int, delta: np.ndarray | None = None, back: np.ndarray | None = None,
                into: dict | None = None) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Drop place ``j`` and its two states. States are only ever appended, so an index names one
        state in every stored frame: each frame's entries for the two go, the other entries shift
        down, and back-pointers into them go to ``into`` (default: the unseen state for its stand,
        the carry from nowhere known for its carry). ``delta``/``back``: this frame's, when called
        within a frame."""
        gone = into or {stand_state(j): UNSEEN_STATE, carry_state(j): ANY_CARRY}
        top = n_states(len(st.places))
        kept_all = [s for s in range(top) if s not in gone]
        remap = np.empty(top, np.int64)
        remap[kept_all] = np.arange(len(kept_all))
        for s, to in gone.items():
            remap[s] = remap[to]

        def entries(n: int) -> list[int]:
            return [s for s in range(n) if s not in gone]

        st.places.pop(j)
        st.version += 1
        st.delta = st.delta[entries(len(st.delta))]
        kept = deque(maxlen=st.back.maxlen)
        for f, b in st.back:
            kept.append((f, remap[b[entries(len(b))]].astype(np.int32)))
        st.back = kept
        if delta is not None:
            delta = delta[entries(len(delta))]
        if back is not None:
            back = remap[back[entries(len(back))]]
        return delta, back

    def _check_negative(self, inst: int, st: _Instance, frame: int, delta: np.ndarray) -> None:
        """Depth showing the leading place empty (a run of ``min_frames`` empty frames, tested
        every ``stride`` frames) makes standing there ``empty_likelihood`` times less likely."""
        ncfg = self.cfg.negative
        lead = state_kind(int(np.argmax(delta)))
        if lead < 0 or frame - st.last_negative_check < ncfg.stride:
            return
        p = st.places[lead]
        if frame - p.last_frame <= ncfg.stride:
            return
        st.last_negative_check = frame
        lo = max(p.last_frame + 1, frame - ncfg.stride * (ncfg.min_frames + 1))
        if self.negative(inst, p.xyz, lo, frame + 1) is not None:
            delta[stand_state(lead)] += np.log(self.cfg.places.empty_likelihood)

    def _refit_scale(self) -> None:
        """The offline scale fit on the newest inliers of every place with two or more; a change of
        at least 5 % rescales every place (its inliers' information)."""
        # every place's kept inliers at once (a refit every few dozen detections made the p99 when it
        # went place by place): squared Mahalanobis distances to their centre, times n / (n - 1) (noise_scale.centred)
        fit = [p for st in self.inst.values() for p in st.places if p.n >= 2 and p.n_kept >= 2]
        d2 = np.zeros(0)
        if fit:
            kept = np.array([p.n_kept for p in fit])
            d = (np.concatenate([p.row_world[:p.n_kept] for p in fit])
                 - np.repeat(np.array([p.xyz for p in fit]), kept, axis=0))
            info = np.concatenate([p.row_info[:p.n_kept] for p in fit])
            d2 = np.einsum("mi,mij,mj->m", d, info, d) * np.repeat(kept / (kept - 1), kept)
        new = refit(d2, self.scale, self.cfg.noise, self.cfg.inlier_chi2)
        if new is None:
            return
        f2 = (new / self.scale) ** 2
        for st in self.inst.values():
            for p in st.places:
                p.rescale(f2)
            st.version += 1
        self.scale = new
        self.scales.append(self.scale)
        self._noise = dataclasses.replace(self.cfg.noise, scale=self.scale)
        self._cfg_scaled = dataclasses.replace(self.cfg, noise=self._noise)

    # ------------------------------------------------------------------ answers and emission

    @staticmethod
    def _lead_probability(st: _Instance) -> float:
        """The leading state's share of the frame's max-product scores (its max-marginal); kept
        per frame as ``st.lead`` by :meth:`_advance`."""
        return float(1.0 / np.exp(st.delta - st.delta[st.best]).sum())

    def _answer(self, inst: int, st: _Instance, state: int, next_kind: int | None, ts: int,
                lead: float | None = None) -> Prediction | None:
        """The prediction of a state at frame time ``ts``, its score calibrated
        (a stand: ``graph.answers.causal_calibration``; every other kind its confidence,
        ``graph.answers.causal_kinds``). With ``graph.answers.every_frame`` every frame is
        answered (:meth:`_raw_answer`, else :meth:`_fallback_answer`); without, None where nothing is
        reported (below ``places.min_answer_probability``, carried, unseen before
        ``put_down_after_s``)."""
        every = self.cfg.answers.every_frame
        low = lead is not None and lead < self.cfg.places.min_answer_probability
        pred, kind = (None, STAND) if low and not every else self._raw_answer(inst, st, state, next_kind, ts, lead)
        if pred is None and every:
            pred, kind = self._fallback_answer(inst, st, state, ts)
        if pred is None:
            return None
        if every:  # the calibration knots as arrays once (this runs per instance and frame)
            if self._calibration is None or self._calibration[0] != self.scale:  # the scale fitted so far
                knots = np.asarray(self.cfg.answers.knots("causal", self.scale), float)
                self._calibration = (self.scale, np.ascontiguousarray(knots[:, 0]), np.ascontiguousarray(knots[:, 1]),
                                     [0.0, *self.cfg.answers.kinds("causal", self.scale)])
            _, x, y, fixed = self._calibration
            score = float(np.interp(pred.score, x, y)) if kind == STAND else fixed[kind]
            pred = Prediction(pred.instance, pred.xyz, min(max(score, 0.0), 1.0))
        return pred

    def _fallback_answer(self, inst: int, st: _Instance, state: int, ts: int) -> tuple[Prediction | None, int]:
        """The answer where the chain reports nothing, and its kind (egograph.track.answers): carried,
        the hand's last position (HAND, raw 0); unseen (standing at a place not among its places),
        the newest detection when it is newer than every inlier of the place of the best stand score
        (that place is then left behind), else that place (UNSEEN; raw, both: that place's share of
        the frame's scores, halved), else the hand's last position; with no place to stand at (none,
        or every one claimed by another instance or not held up) and no hand, the newest detection
        (LAST, raw ``LAST_RAW``; HELD when its support so far was seen from close by,
        egograph.track.answers.held_rows)."""
        kind = state_kind(state)
        held = [xyz for t, xyz in st.hands if t <= ts]
        if kind == -1 and held:
            return Prediction(inst, tuple(float(v) for v in held[-1]), HAND_RAW), HAND
        if kind == -2 and st.places:
            stands = st.delta[2::2][:len(st.places)]
            j = int(np.argmax(stands))
            if np.isfinite(stands[j]):  # (else every place is claimed or not held up: none to stand at)
                share = 0.5 * float(np.exp(stands[j] - np.logaddexp.reduce(st.delta)))
                if st.last_xyz is not None and st.last_frame > st.places[j].last_frame:
                    return Prediction(inst, tuple(float(v) for v in st.last_xyz), share), UNSEEN
                return Prediction(inst, st.places[j].xyz_tuple, share), UNSEEN
        if held:
            return Prediction(inst, tuple(float(v) for v in held[-1]), HAND_RAW), HAND
        if st.last_xyz is not None:
            return Prediction(inst, tuple(float(v) for v in st.last_xyz), LAST_RAW), self._last_kind(st)
        return None, LAST

    def _last_kind(self, st: _Instance) -> int:
        """LAST, or HELD when the detections so far within ``graph.answers.distance_m`` of the newest
        one were seen from a median range under ``held_range_m``; worked out once per new detection."""
        if st.last_held[0] != st.n_rows:
            held = False
            if st.seen:
                world = np.concatenate([w for w, _ in st.seen])
                rng = np.concatenate([r for _, r in st.seen])
                held = bool(held_rows(world, rng, np.array([len(world) - 1]), self.cfg.answers)[0])
            st.last_held = (st.n_rows, held)
        return HELD if st.last_held[1] else LAST

    def _raw_answer(self, inst: int, st: _Instance, state: int, next_kind: int | None, ts: int,
                    lead: float | None) -> tuple[Prediction | None, int]:
        """The uncalibrated prediction of a state and its kind (egograph.track.answers): a place's
        current centre (STAND); at a place not yet seen, the place the sequence goes to next (lagged,
        STAND) or, ``put_down_after_s`` after the last detection in hand, where the hand held the
        object (PUT_DOWN); None otherwise."""
        kind = state_kind(state)
        if kind >= 0:
            return self._place_prediction(inst, st, kind, lead), STAND
        if kind == -2:
            if next_kind is not None and next_kind >= 0:
                return self._place_prediction(inst, st, next_kind, lead), STAND
            after = self.cfg.put_down_after_s
            if after > 0:
                due = ts - after * TICKS_PER_SECOND
                held = [xyz for t, xyz in st.hands if t <= ts]
                last_held = next((t for t, _ in reversed(st.hands) if t <= ts), None)
                if held and last_held <= due:
                    if self.cfg.answers.every_frame and st.last_xyz is not None and st.last_ts > last_held:
                        # a detection since the hand let go: where it was put down (memory's rule)
                        return Prediction(inst, tuple(float(v) for v in st.last_xyz), 0.1), PUT_DOWN
                    return Prediction(inst, tuple(float(v) for v in held[-1]), 0.1), PUT_DOWN
        return None, STAND

    @staticmethod
    def _place_prediction(inst: int, st: _Instance, k: int, lead: float | None) -> Prediction:
        """A place's current centre, scored with the state's max-marginal when answered at once, and
        by its support (inliers n: n / (n + 5)) when answered with a lag."""
        p = st.places[k]
        score = lead if lead is not None else p.n / (p.n + 5.0)
        return Prediction(inst, p.xyz_tuple, float(score))

    def _held_up(self, p: OnlinePlace) -> bool:
        """Whether the object could stand at place ``p``: a place of fewer than
        ``places.support_min_inliers`` inliers needs the scene under it (tested again each time its
        inliers double)."""
        if self.support is None or p.n >= self.cfg.places.support_min_inliers:
            return True
        if p.supported is None or p.supported[0] * 2 <= p.n:
            p.supported = (p.n, bool(self.support(p.xyz)))
        return p.supported[1]

    def _emit(self, up_to: int | None, now: dict[int, Prediction | None] | None = None) -> None:
        """Emit pending frames with timestamp <= ``up_to`` (None: all): each instance's state there
        on the most probable sequence up to now. ``now``: the newest frame's answers, when made
        already (the sequence ends in each instance's leading state, so they are its answers)."""
        due = []
        while self.pending and (up_to is None or self.pending[0][1] <= up_to):
            due.append(self.pending.popleft())
        if not due:
            return
        if now is not None and len(due) == 1 and due[0][0] == self.last_frame:  # no lag: the leading states
            paths = {i: {self.last_frame: (st.best, None)} for i, st in self.inst.items()}
        else:
            paths = {i: self._backtrack(st, due[0][0]) for i, st in self.inst.items()}
        for f, ts in due:
            preds = []
            for i in sorted(self.inst):
                st = self.inst[i]
                state, next_kind = paths[i].get(f, (None, None))
                if f == self.last_frame and now is not None:
                    pred = now[i]
                else:
                    lead = st.lead if f == self.last_frame else None
                    pred = None if state is None else self._answer(i, st, state, next_kind, ts, lead)
                self._extend_span(i, st, state, pred, f, ts)
                if pred is not None:
                    preds.append(pred)
            self.ready.append((f, ts, preds))

    def _backtrack(self, st: _Instance, oldest: int) -> dict[int, tuple[int, int | None]]:
        """frame -> (state, kind of the next place/carry state after its run) on the most probable
        sequence ending now, for the frames from ``oldest`` on that the back-pointers still cover.
        Frames before the instance's first detection count as unseen, leading to the sequence's
        first state (a lagged answer back-fills the first place)."""
        out = {}
        state = st.best
        next_kind = None
        first = None
        for f, b in reversed(st.back):
            if f < oldest:
                break
            kind = state_kind(state)
            out[f] = (state, next_kind if kind == -2 else None)
            if kind != -2:
                next_kind = kind
            first = f
            state = int(b[state]) if state < len(b) else UNSEEN_STATE
        if first is not None and first == st.back[0][0] and st.back[0][0] == st.created:
            for f in range(oldest, first):
                out[f] = (UNSEEN_STATE, next_kind)
        return out

    def _extend_span(self, inst: int, st: _Instance, state: int | None, pred: Prediction | None, f: int,
                     ts: int) -> None:
        kind = None if state is None else state_kind(state)
        place = st.places[kind] if kind is not None and kind >= 0 else None
        span = self._open.get(inst)
        if span is not None and place is not None and span[1] is place:
            span[4], span[5] = f, ts
            return
        self._close_span(inst)
        if place is not None:
            self._open[inst] = [inst, place, f, ts, f, ts, pred.score if pred is not None else 1.0]

    def _close_span(self, inst: int) -> None:
        span = self._open.pop(inst, None)
        if span is not None:
            self.spans.append(tuple(span))


def run_online(obs: Observations, t_frames: np.ndarray, cfg: GraphConfig, *, lag_s: float | None = None,
               negative: NegativeFn | None = None, support: SupportFn | None = None,
               ) -> tuple[dict[int, list[Prediction]], OnlineTracker]:
    """Replay a recording's observations through :class:`OnlineTracker`, frame by frame:
    per-frame final answers (ticks -> predictions, every frame of ``t_frames``) and the tracker."""
    t_frames = np.asarray(t_frames, dtype=np.int64)
    trk = OnlineTracker(cfg, int(t_frames[0]) if len(t_frames) else 0, lag_s=lag_s, negative=negative,
                        support=support)
    order = np.argsort(obs.frame, kind="stable")
    frames_sorted = obs.frame[order]
    bounds = np.searchsorted(frames_sorted, np.arange(len(t_frames) + 1))
    out: dict[int, list[Prediction]] = {}
    for f, ts in enumerate(t_frames):
        rows = order[bounds[f]:bounds[f + 1]]
        trk.step(f, int(ts), obs.select(rows) if len(rows) else None)
        for g, t, preds in trk.collect():
            out[t] = preds
    for g, t, preds in trk.finish():
        out[t] = preds
    return out, trk
