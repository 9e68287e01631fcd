"""The online graph tracker: one frame's observations in, that frame's best answer out.

Per instance, an iSAM2 chain of chunk landmarks (:mod:`egograph.track.chain`) grows one
observed frame at a time; after each update the *trailing segment* (the rows since the last
motion break) is tested like an offline stand (:mod:`egograph.track.segments`). The answer
per instance and frame is the current best hypothesis:

* a *stand* once the trailing segment passes the stand test (score: its confidence);
* before that, the *last seen place*: the robust centre of the trailing segment once it has
  ``graph.provisional_min_observations`` inliers (an instance's first answer:
  ``graph.first_min_observations``, 1 by default, as the memory baseline answers) and one of
  them has a matcher score of at least ``graph.provisional_min_score`` (score: the same
  confidence formula, low with few inliers); less than that at a new place keeps the previous
  answer (one stray false match neither moves nor silences the object);
* not a new place within ``graph.exclusion_radius_m`` of another instance's current answer
  with more inliers (``graph.causal_exclusion``: a look-alike confusion, the causal form of
  the offline rule);
* *nothing* while the object is carried (the segment moves with the head, or a still stand
  seen from close by has no support under it), and from the frame where depth shows the
  held place empty (negative evidence, ``graph.negative``) until it is seen again.
* once a carry has been out of sight for ``graph.put_down_after_s``, the place where the hand
  last held it (put down near there; low confidence), until it is seen again or depth shows
  that place empty.

Strictly causal: the answer for frame t uses the observations (and depth frames) of frames
<= t only. With a lag S (``lag_s`` seconds) the answer for frame t is emitted once a frame at
t + S has been processed: a hypothesis formed by then replaces the answers of the buffered
frames from the start of its evidence (the first row of its segment, the first carried
detection, the first empty depth frame; an instance's first hypothesis from frame 0), and a
stand's final position by then is used for all its buffered frames.

Memory and time per frame are bounded: a segment keeps its last ``graph.online_max_rows``
rows, and each instance's iSAM2 is restarted every ``graph.online_window_chunks`` chunks with
the newest landmark's marginal as a prior. World frame, metres; PV frame indices and 100 ns ticks.

A live loop::

    trk = OnlineTracker(cfg.graph, t0=first_pv_timestamp)
    for frame, (ts, obs) in enumerate(stream):   # obs: this frame's lifted Observations
        preds = trk.step(frame, ts, obs)          # [Prediction(instance, xyz, score)], this frame
"""

from __future__ import annotations

import dataclasses
from collections import deque
from dataclasses import dataclass, field

import gtsam
import numpy as np

from egograph.core.types import PositionInterval, Prediction
from egograph.core.units import TICKS_PER_SECOND
from egograph.geometry.observations import Observations
from egograph.track.chain import L, S, add_break_factors
from egograph.track.config import GraphConfig
from egograph.track.detection_factor import add_detection_factors, detection_covariances
from egograph.track.noise_scale import centred, refit
from egograph.track.segments import (
    NegativeFn,
    Segment,
    SupportFn,
    held_in_mid_air,
    is_stand,
    moves_with_camera,
    stand_confidence,
    with_floor,
)
from egograph.track.switchable import dcs_phi, dcs_switch_value

STAND, LAST_SEEN = "stand", "last_seen"


@dataclass
class Hypothesis:
    """Where one instance is believed to be. Mutable: a stand's estimate is refined in place
    while it is held, so lagged answers read its position as of their emission."""

    instance: int
    kind: str                   # STAND or LAST_SEEN
    xyz: np.ndarray             # world, metres
    covariance: np.ndarray      # 3x3 m^2, without the floor
    confidence: float           # 0-1
    n_inliers: int
    first_frame: int            # first inlier detection, PV frame index
    last_frame: int             # last inlier detection, PV frame index
    first_seen: int             # their timestamps, ticks
    last_seen: int
    segment_id: int             # the trailing segment that supports it now
    estimate_segment: int = -1  # the segment its estimate comes from (the best-supported one)
    ended_by: str = ""

    def prediction(self) -> Prediction:
        """The answer as a prediction, made again only when the estimate changed."""
        key = (self.xyz.tobytes(), self.confidence)
        if getattr(self, "_key", None) != key:
            self._key = key
            self._pred = Prediction(self.instance, tuple(float(v) for v in self.xyz), float(self.confidence))
        return self._pred


@dataclass
class _Run:
    """From ``start`` (PV frame index) on, the instance's answer is ``hyp`` (None: nothing)."""

    start: int
    hyp: Hypothesis | None


@dataclass
class _Instance:
    """One instance's incremental state."""

    isam: gtsam.ISAM2
    t_origin_s: float                   # time of its first observation, s since t0 (chunk grid origin)
    cell: int = -1                      # grid cell of the newest chunk
    k: int = -1                         # newest chunk id
    chunks_in_isam: int = 0
    chunk_first_row: int = 0            # global row index of chunk k's first row
    n_rows: int = 0                     # rows seen so far (global row index of the next one)
    seg_first_row: int = 0              # global row index where the trailing segment starts
    segment_id: int = 0
    rows: "_Rows | None" = None          # the trailing segment's newest rows
    held: Hypothesis | None = None
    runs: list = field(default_factory=list)    # answer runs not yet fully emitted
    switches: list = field(default_factory=list)
    last_negative_check: int = -1
    carry: deque = field(default_factory=lambda: deque(maxlen=6))  # (world, camera) of the last carried rows
    in_carry: bool = False              # the answer is nothing because the object is carried
    carry_ticks: int = 0                # timestamp of the newest carried detection
    answered: bool = False              # some hypothesis has been held (the first one needs first_min_observations)


class _Rows:
    """The newest rows of an instance's trailing segment, at most ``capacity``, in numpy buffers of
    twice that (appends shift the kept rows to the front when the end is reached)."""

    def __init__(self, capacity: int):
        self.cap, n = capacity, 2 * capacity
        self.row = np.zeros(n, np.int64)
        self.frame = np.zeros(n, np.int64)
        self.ticks = np.zeros(n, np.int64)
        self.world, self.camera = np.zeros((n, 3)), np.zeros((n, 3))
        self.cov, self.info = np.zeros((n, 3, 3)), np.zeros((n, 3, 3))
        self.range, self.score = np.zeros(n), np.zeros(n)
        self.lo = self.hi = 0

    _FIELDS = ("row", "frame", "ticks", "world", "camera", "cov", "info", "range", "score")

    def append(self, row0: int, frame: int, ticks: int, world, cov, info, camera, rng, score) -> None:
        m = min(len(world), self.cap)
        world, cov, info, camera, rng, score = world[-m:], cov[-m:], info[-m:], camera[-m:], rng[-m:], score[-m:]
        if self.hi + m > len(self.row):
            keep = max(0, min(self.hi - self.lo, self.cap - m))
            for name in self._FIELDS:
                a = getattr(self, name)
                a[:keep] = a[self.hi - keep:self.hi]
            self.lo, self.hi = 0, keep
        sl = slice(self.hi, self.hi + m)
        self.row[sl] = row0 + np.arange(m)
        self.frame[sl], self.ticks[sl] = frame, ticks
        self.world[sl], self.cov[sl], self.info[sl], self.camera[sl], self.range[sl] = world, cov, info, camera, rng
        self.score[sl] = score
        self.hi += m
        self.lo = max(self.lo, self.hi - self.cap)

    def drop_before(self, row: int) -> None:
        """Forget rows whose global index is below ``row`` (the segment starts there)."""
        self.lo += int(np.searchsorted(self.row[self.lo:self.hi], row))

    def view(self):
        sl = slice(self.lo, self.hi)
        return (self.frame[sl], self.ticks[sl], self.world[sl], self.cov[sl], self.info[sl], self.camera[sl],
                self.range[sl])


def _mahalanobis2(world: np.ndarray, centre: np.ndarray, info: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distance of each row to ``centre`` under its information matrix."""
    d = world - centre
    return np.einsum("mi,mij,mj->m", d, info, d)


def _isam() -> gtsam.ISAM2:
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(0.01)
    return gtsam.ISAM2(params)


class OnlineTracker:
    """The graph tracker fed one PV frame at a time (module doc).

    ``cfg``: the ``graph`` configuration; ``t0``: the recording's first PV timestamp (ticks: the
    time origin of the chunk grid); ``lag_s``: answers wait this many seconds for later evidence
    (default ``cfg.lag_s``; 0 is strictly causal); ``negative``/``support``: as for
    :func:`egograph.track.graph.graph_tracker` (they may read only frames up to the current one).
    """

    def __init__(self, cfg: GraphConfig, t0: int, *, lag_s: float | None = None,
                 negative: NegativeFn | None = None, support: SupportFn | None = None):
        self.cfg, self.t0 = cfg, int(t0)
        self.lag_ticks = int(round((cfg.lag_s if lag_s is None else lag_s) * TICKS_PER_SECOND))
        self.negative, self.support = negative, support
        self.inst: dict[int, _Instance] = {}
        self.pending: deque = deque()    # (frame, timestamp) not yet emitted
        self.ready: deque = deque()      # (frame, timestamp, predictions) emitted, not yet collected
        self.spans: list[tuple[Hypothesis, int, int, int, int]] = []  # stand reported over (f0, t0, f1, t1)
        self._open: dict[int, list] = {}  # instance -> [hyp, f0, t0, f1, t1] of the span being emitted
        self.last_frame = -1
        self.n_observations = 0
        # detection noise scale (graph.noise): fitted as the stream goes with online_auto
        self.scale = float(cfg.noise.auto_start if cfg.noise.online_auto else cfg.noise.scale)
        self.scales = [self.scale]
        self._noise = dataclasses.replace(cfg.noise, scale=self.scale)
        self._residuals: dict[tuple[int, int], np.ndarray] = {}  # (instance, segment) -> stand inliers' d2
        self._next_fit = cfg.noise.online_refit_every

    # ------------------------------------------------------------------ the loop

    def step(self, frame: int, timestamp: int, obs: Observations | None = None) -> list[Prediction]:
        """Process PV frame ``frame`` (index, increasing) at ``timestamp`` (ticks) with its
        observations (rows of other frames are refused; invalid and below-threshold rows are
        ignored). Returns the causal answer for this frame, one prediction per instance; with a
        lag, the final answers of earlier frames are collected with :meth:`collect`."""
        frame = int(frame)
        if frame <= self.last_frame:
            raise ValueError(f"frame {frame} after frame {self.last_frame}: frames must increase")
        self.last_frame = frame
        self.pending.append((frame, int(timestamp)))
        if obs is not None and len(obs):
            if np.any(obs.frame != frame):
                raise ValueError(f"observations of frames {sorted(set(obs.frame.tolist()) - {frame})} given "
                                 f"with frame {frame}")
            keep = obs.valid & (np.asarray(obs.score, np.float32) >= np.float32(self.cfg.score_threshold))
            for inst in np.unique(obs.instance[keep]):
                sel = np.flatnonzero(keep & (obs.instance == inst))
                self._observe(int(inst), frame, int(timestamp), obs, sel)
        if self.cfg.put_down_after_s > 0:
            for i, st in self.inst.items():
                self._guess_put_down(i, st, frame, int(timestamp))
        if self.negative is not None:
            for i, st in self.inst.items():
                self._check_negative(i, st, frame)
        now = {i: st.runs[-1].hyp for i, st in self.inst.items() if st.runs}
        self._emit(int(timestamp) - self.lag_ticks)
        return [now[i].prediction() for i in sorted(now) if now[i] is not None]

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
        """The stands reported so far (emitted frames), one interval per stand and run of
        frames, at the stand's latest estimate; last-seen answers are per-frame only."""
        spans = list(self.spans) + [tuple(s) for s in self._open.values() if s[0].kind == STAND]
        out = []
        for hyp, f0, t0, f1, t1 in spans:
            out.append(PositionInterval(
                instance=hyp.instance, t_start=t0, t_end=t1, xyz=tuple(float(v) for v in hyp.xyz),
                covariance=with_floor(hyp.covariance, self.cfg).tolist(), n_observations=hyp.n_inliers,
                confidence=hyp.confidence, first_seen=hyp.first_seen,
                last_seen=hyp.last_seen, ended_by=hyp.ended_by or "end",
                extra={"start_frame": f0, "end_frame": f1, "segment": hyp.segment_id},
            ))
        return sorted(out, key=lambda iv: (iv.instance, iv.t_start))

    # ------------------------------------------------------------------ per instance

    def _observe(self, inst: int, frame: int, ts: int, obs: Observations, sel: np.ndarray) -> None:
        cfg = self.cfg
        self.n_observations += len(sel)
        t_s = (ts - self.t0) / TICKS_PER_SECOND
        st = self.inst.get(inst)
        if st is None:
            st = self.inst[inst] = _Instance(_isam(), t_s, rows=_Rows(cfg.online_max_rows))
        world = np.asarray(obs.world[sel], dtype=float)
        camera = np.asarray(obs.camera[sel], dtype=float)
        cov = detection_covariances(world, camera, self._noise)
        info = np.linalg.inv(cov)
        cell = int(np.floor((t_s - st.t_origin_s) / cfg.chunk_s))
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        new_chunk = cell > st.cell
        if new_chunk:
            st.cell, st.k = cell, st.k + 1
            k = st.k
            if k and st.chunks_in_isam >= cfg.online_window_chunks:
                self._restart(st, k - 1)
            values.insert(L(k), gtsam.Point3(*np.median(world, axis=0)))
            if k:
                add_break_factors(graph, values, k, cfg)
            st.chunks_in_isam += 1
            st.chunk_first_row = st.n_rows
        k = st.k
        add_detection_factors(graph, np.full(len(world), L(k)), world, cov, self._noise)
        st.isam.update(graph, values)
        here = np.asarray(st.isam.calculateEstimatePoint3(L(k)), dtype=float)
        if k and st.chunks_in_isam > 1:
            if cfg.switches == "switchable":
                sw = min(1.0, max(0.0, float(st.isam.calculateEstimateVector(S(k))[0])))
            else:
                sw = dcs_switch_value(np.asarray(st.isam.calculateEstimatePoint3(L(k - 1))), here,
                                      cfg.still_sigma_m, dcs_phi(cfg.switch_sigma))
            if sw < cfg.break_below and st.seg_first_row < st.chunk_first_row:
                st.seg_first_row = st.chunk_first_row
                st.segment_id += 1
            if new_chunk:
                st.switches.append(sw)
        rng = np.asarray(obs.range_m[sel], dtype=float)
        score = np.asarray(obs.score[sel], dtype=float)
        st.rows.append(st.n_rows, frame, ts, world, cov, info, camera, rng, score)
        st.n_rows += len(sel)
        st.rows.drop_before(st.seg_first_row)
        self._decide(inst, st, here, frame)
        if cfg.noise.online_auto and self.n_observations >= self._next_fit:
            self._next_fit = self.n_observations + cfg.noise.online_refit_every
            self._refit_scale()

    def _refit_scale(self) -> None:
        """The offline scale fit (:mod:`egograph.track.noise_scale`) on the residuals of the stands
        confirmed so far; a change of at least 5 % rescales every kept row's covariance (so the stand
        tests use it at once) and the factors of newer detections."""
        d2 = np.concatenate(list(self._residuals.values())) if self._residuals else np.zeros(0)
        new = refit(d2, self.scale, self.cfg.noise, self.cfg.inlier_chi2)
        if new is None:
            return
        f2 = (new / self.scale) ** 2
        for st in self.inst.values():
            sl = slice(st.rows.lo, st.rows.hi)
            st.rows.cov[sl] *= f2
            st.rows.info[sl] /= f2
        self.scale = new
        self.scales.append(self.scale)
        self._noise = dataclasses.replace(self.cfg.noise, scale=self.scale)
        self._residuals.clear()  # residuals were whitened at the old scale

    def _restart(self, st: _Instance, k_last: int) -> None:
        """Bound the history: a new iSAM2 holding only landmark ``k_last`` under its marginal."""
        est = st.isam.calculateEstimatePoint3(L(k_last))
        try:
            marg = st.isam.marginalCovariance(L(k_last))
        except RuntimeError:
            marg = self.cfg.still_sigma_m**2 * np.eye(3)
        st.isam = _isam()
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        graph.add(gtsam.PriorFactorPoint3(L(k_last), gtsam.Point3(*est), gtsam.noiseModel.Gaussian.Covariance(marg)))
        values.insert(L(k_last), gtsam.Point3(*est))
        st.isam.update(graph, values)
        st.chunks_in_isam = 1

    def _decide(self, inst: int, st: _Instance, here: np.ndarray, frame: int) -> None:
        """The best hypothesis after this frame's observations (module doc)."""
        cfg = self.cfg
        frames, ticks, world, cov, info, camera, rng = st.rows.view()
        seg, moving, near = _stand_around(here, world, cov, info, camera, rng, cfg)
        mid_air = seg.stationary and near and held_in_mid_air(seg, rng, cfg, self.support)
        seg_start = int(frames[0])
        held = st.held
        if moving or mid_air:
            if held is not None and np.linalg.norm(here - held.xyz) <= cfg.merge_radius_m:
                return  # still where it stood (looked at closely, or the pick-up just begun)
            if held is not None or not st.runs:
                self._switch(inst, st, None, seg_start)  # carried: nothing from its first detection
                st.in_carry = True
            st.carry.extend(zip(world[-len(world):], camera[-len(camera):]))
            st.carry_ticks = int(ticks[-1])
            return
        if near and st.seg_first_row >= st.chunk_first_row:
            return  # seen from hand range within one chunk: maybe in hand; wait for a motion-break test
        if near and st.in_carry and st.carry:
            # still in hand if, together with the carry before it, it keeps its offset to the head
            cw = np.concatenate([np.array([w for w, _ in st.carry]), world])
            cc = np.concatenate([np.array([c for _, c in st.carry]), camera])
            if moves_with_camera(cw, cc, np.zeros(len(cw)), cfg):
                return
        if seg.stationary:
            kind = STAND
            if self.cfg.noise.online_auto and seg.n_inliers >= 2:
                self._residuals.pop((inst, st.segment_id), None)  # newest last: the oldest are dropped
                self._residuals[(inst, st.segment_id)] = centred(
                    _mahalanobis2(world[seg.inliers], seg.xyz, info[seg.inliers]))
                while len(self._residuals) > 64:
                    self._residuals.pop(next(iter(self._residuals)))
        elif (seg.n_inliers >= (cfg.provisional_min_observations if st.answered else cfg.first_min_observations)
              and st.rows.score[st.rows.lo:st.rows.hi][seg.inliers].max() >= cfg.provisional_min_score):
            kind = LAST_SEEN
        else:
            return  # too little at a new place: keep the previous answer
        inl, inl_ticks = frames[seg.inliers], ticks[seg.inliers]
        conf = stand_confidence(seg, len(seg.rows), cfg)
        if held is not None and held.segment_id == st.segment_id:
            # the same segment, refined (a last-seen place may become a stand; a stand stays one),
            # unless the estimate came from an earlier, better-supported segment of the same stand
            held.kind = STAND if STAND in (held.kind, kind) else kind
            held.last_frame, held.last_seen = int(inl.max()), int(inl_ticks.max())
            if held.estimate_segment == st.segment_id or seg.n_inliers >= held.n_inliers:
                held.xyz, held.covariance, held.confidence = seg.xyz, seg.covariance, conf
                held.n_inliers, held.estimate_segment = seg.n_inliers, st.segment_id
            return
        if held is not None and held.kind == STAND and np.linalg.norm(held.xyz - seg.xyz) <= cfg.merge_radius_m:
            # the held stand again, after a break (a stray detection between): one stand, the
            # estimate of the better-supported segment
            held.segment_id, held.last_frame, held.last_seen = st.segment_id, int(inl.max()), int(inl_ticks.max())
            if kind == STAND and seg.n_inliers >= held.n_inliers:
                held.xyz, held.covariance, held.confidence, held.n_inliers = seg.xyz, seg.covariance, conf, seg.n_inliers
                held.estimate_segment = st.segment_id
            return
        if kind == LAST_SEEN and held is not None and held.kind == STAND:
            return  # a held stand gives way to another stand, a carry or an empty place, not to a glimpse
        if cfg.causal_exclusion and self._claimed(inst, seg.xyz, seg.n_inliers):
            return  # another instance's better-supported answer is there: a look-alike confusion
        hyp = Hypothesis(inst, kind, seg.xyz, seg.covariance, conf, seg.n_inliers, int(inl.min()),
                         int(inl.max()), int(inl_ticks.min()), int(inl_ticks.max()), st.segment_id, st.segment_id)
        same_place = held is not None and np.linalg.norm(held.xyz - seg.xyz) <= cfg.merge_radius_m
        if same_place:
            valid_from = None
        elif not st.runs:
            valid_from = 0  # an instance's first hypothesis: it was there before it was first seen
        elif held is None:
            valid_from = max(seg_start, st.runs[-1].start)  # not back into a carry or an empty place
        else:
            valid_from = seg_start
        self._switch(inst, st, hyp, valid_from)

    def _switch(self, inst: int, st: _Instance, hyp: Hypothesis | None, valid_from: int | None) -> None:
        """Answer ``hyp`` from now on, and from ``valid_from`` for frames not yet emitted (None: now)."""
        if st.held is not None and hyp is not st.held and not st.held.ended_by:
            st.held.ended_by = "detection" if hyp is not None else "carried"
        st.held = hyp
        if hyp is not None:
            st.answered = True
            st.in_carry = False
            st.carry.clear()
        oldest = self.pending[0][0] if self.pending else self.last_frame
        start = max(self.last_frame if valid_from is None else valid_from, oldest)
        while st.runs and st.runs[-1].start >= start:
            st.runs.pop()
        st.runs.append(_Run(start, hyp))

    def _guess_put_down(self, inst: int, st: _Instance, frame: int, ts: int) -> None:
        """A carry unseen for ``put_down_after_s`` seconds: answer where the hand last held it (the
        object is put down near where it was last seen carried), as a low-confidence last-seen
        place, until it is seen again or depth shows that place empty."""
        if not (st.in_carry and st.held is None and st.carry):
            return
        if ts - st.carry_ticks < self.cfg.put_down_after_s * TICKS_PER_SECOND:
            return
        world = np.array([w for w, _ in st.carry])[-3:]
        xyz = np.median(world, axis=0)
        sigma = self.cfg.put_down_sigma_m
        hyp = Hypothesis(inst, LAST_SEEN, xyz, sigma**2 * np.eye(3), 0.1, 1, frame, frame, st.carry_ticks,
                         st.carry_ticks, st.segment_id, st.segment_id)
        if self.cfg.causal_exclusion and self._claimed(inst, xyz, 1):
            return
        self._switch(inst, st, hyp, None)

    def _claimed(self, inst: int, xyz: np.ndarray, n_inliers: int) -> bool:
        """Whether another instance's current answer lies within ``exclusion_radius_m`` of ``xyz``
        with more inlier detections than ``n_inliers`` (its state as of now: causal)."""
        r = self.cfg.exclusion_radius_m
        for j, other in self.inst.items():
            h = other.held
            if j != inst and h is not None and h.n_inliers > n_inliers and np.linalg.norm(h.xyz - xyz) <= r:
                return True
        return False

    def _check_negative(self, inst: int, st: _Instance, frame: int) -> None:
        """End the held answer when depth shows its place empty (a run of ``min_frames`` empty
        frames, tested every ``stride`` frames, completed at this frame)."""
        held, ncfg = st.held, self.cfg.negative
        if held is None or frame - held.last_frame <= ncfg.stride or frame - st.last_negative_check < ncfg.stride:
            return
        st.last_negative_check = frame
        lo = max(held.last_frame + 1, frame - ncfg.stride * (ncfg.min_frames + 1))
        gone = self.negative(inst, held.xyz, lo, frame + 1)
        if gone is not None:
            held.ended_by = "negative"
            self._switch(inst, st, None, int(gone))

    # ------------------------------------------------------------------ emission

    def _emit(self, up_to: int | None) -> None:
        """Emit pending frames with timestamp <= ``up_to`` (None: all)."""
        while self.pending and (up_to is None or self.pending[0][1] <= up_to):
            f, ts = self.pending.popleft()
            preds = []
            for i in sorted(self.inst):
                st = self.inst[i]
                while len(st.runs) > 1 and st.runs[1].start <= f:
                    st.runs.pop(0)
                hyp = st.runs[0].hyp if st.runs and st.runs[0].start <= f else None
                self._extend_span(i, hyp, f, ts)
                if hyp is not None:
                    preds.append(hyp.prediction())
            self.ready.append((f, ts, preds))

    def _extend_span(self, inst: int, hyp: Hypothesis | None, f: int, ts: int) -> None:
        span = self._open.get(inst)
        if span is not None and span[0] is hyp:
            span[3], span[4] = f, ts
            return
        self._close_span(inst)
        if hyp is not None and hyp.kind == STAND:
            self._open[inst] = [hyp, f, ts, f, ts]

    def _close_span(self, inst: int) -> None:
        span = self._open.pop(inst, None)
        if span is not None and span[0].kind == STAND:
            self.spans.append(tuple(span))


def _stand_around(xyz: np.ndarray, world: np.ndarray, cov: np.ndarray, info: np.ndarray, camera: np.ndarray,
                  range_m: np.ndarray, cfg: GraphConfig) -> tuple[Segment, bool, bool]:
    """The offline stand test around a given centre (iSAM2's newest landmark) without a robust
    re-solve: the centre becomes the information-weighted mean of the inliers around ``xyz``,
    its covariance the inverse of their summed information. Also whether the rows move with the
    head (a carry), and whether they were seen from hand range (median range <= carry_range_m)."""
    rows = np.arange(len(world))
    inl = _mahalanobis2(world, xyz, info) <= cfg.inlier_chi2
    c = cov[0]
    for _ in range(2):
        if not inl.any():
            break
        c = np.linalg.inv(info[inl].sum(axis=0))
        xyz = c @ np.einsum("mij,mj->i", info[inl], world[inl])
        inl = _mahalanobis2(world, xyz, info) <= cfg.inlier_chi2
    seg = Segment(rows, xyz, c, inl)
    near = bool(np.median(range_m) <= cfg.carry_range_m)
    moving = near and moves_with_camera(world, camera, range_m, cfg)
    seg.stationary = is_stand(seg, moving, cfg)
    carried = moving and int((range_m <= cfg.carry_range_m).sum()) >= cfg.min_carry_observations
    return seg, carried, near


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

