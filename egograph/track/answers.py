"""Every frame answered, with a calibrated confidence (``graph.answers``).

The graph trackers answer, for every PV frame from an instance's enrollment on, their best guess of
where it is: a stand at a place, the hand while it is carried, the most probable place while it is
unseen; and as the score (the fifth column of the per-frame files) the probability that this answer
lies within ``graph.answers.distance_m`` of the truth, as the IT3DEgo evaluator counts it (a frame
of a true carry has no true interval, so an answer there is never within: an answer at the hand is
right only where the tracker's "carried" is wrong, and its confidence is low).

Each answer has a *kind* (``ANSWER_KINDS``): a stand at a place, the place where it was last seen
while unseen, the hand while carried, the newest detection of an instance with no place, where the
hand let go (online). A stand's *raw* confidence comes from the place chain (offline: the posterior
probability of the answered stand times the place's reality, :func:`offline_answers`; online: the
leading state's max-marginal, :mod:`egograph.track.online`) and :func:`calibrated` maps it through
monotone knots fitted on tuning recordings (isotonic regression, ``tools/bench_confidence.py --fit``);
every other kind's raw value says nothing about how often it is right (a constant, or a share of a
state the answer is not at), so each kind has its own fitted confidence (the share of such answers
within the distance on the tuning recordings): :func:`confidences`. Without the split, one
monotone map over all kinds pooled kinds right at very different rates (an instance with no place
answering its nearest detection with the hand's answers; docs/experiments.md, issue 41).
:func:`operating_point` keeps the answers of at least ``min_confidence`` (graph-causal:
``causal_min_confidence``): what the per-frame files hold. World frame, metres; PV frame indices.
"""

from __future__ import annotations

import contextlib
import gc
from typing import Iterator, Sequence

import numpy as np

from egograph.core.types import Prediction, predictions_of
from egograph.track.config import AnswersConfig, GraphConfig
from egograph.track.places import UNSEEN_STATE, stand_state, state_kind

STAND, UNSEEN, HAND, LAST, PUT_DOWN, HELD = range(6)
ANSWER_KINDS = ("stand", "unseen", "hand", "last", "put_down", "held")
"""Answer kinds (codes index this tuple; ``graph.answers.*_kinds`` list the confidences of the
kinds after the first, in this order): a stand at a
place (an interval's, or off the intervals the most probable place); unseen (a place the object is
not on the chain's path to: the best place, or the hand's last position); the hand while carried;
the newest (offline: nearest in time) detection of an instance with no place; where the hand let go
(graph-causal, ``put_down_after_s`` after the last detection in hand); a `last` answer whose support
was seen only from close by (:func:`held_rows`: the object was in the hand, and a detection in the
hand says nothing of where it stands: in the calibration fit on the 34 tuning recordings none of the
4,012 offline and 4,816 causal such answers was within 0.25 m, against 28 % and 13 % of the other
`last` answers; docs/experiments.md, stops 66-67)."""

HAND_RAW = 0.0
"""Raw confidence of an answer at the hand while carried (its calibrated confidence: the kind's)."""

LAST_RAW = 0.001
"""Raw confidence of an answer at the newest detection of an instance with no place yet."""

EMPTY_FACTOR = 0.1
"""Raw confidence factor of a stand at a place depth has shown empty (offline, after the cut)."""


def calibrated(raw: np.ndarray | float, knots: Sequence[Sequence[float]]) -> np.ndarray:
    """Raw confidences mapped through ``[raw, calibrated]`` knots, joined linearly (flat beyond)."""
    k = np.asarray(knots, dtype=float)
    return np.clip(np.interp(np.asarray(raw, float), k[:, 0], k[:, 1]), 0.0, 1.0)


def confidences(raw: np.ndarray, kind: np.ndarray, answers: AnswersConfig, family: str, scale: float) -> np.ndarray:
    """Calibrated confidences of answers of raw confidence ``raw`` and kind ``kind`` (codes of
    ``ANSWER_KINDS``) of tracker ``family`` (offline, causal, smooth) at detection noise scale
    ``scale``: stands through the family's knots, every other kind its fitted constant."""
    raw = np.asarray(raw, float)
    kind = np.asarray(kind, np.int64)
    out = calibrated(raw, answers.knots(family, scale))
    for code, value in enumerate(answers.kinds(family, scale), start=1):
        out[kind == code] = value
    return out


def isotonic_knots(raw: np.ndarray, correct: np.ndarray, n_knots: int = 16, min_share: float = 0.0
                   ) -> list[list[float]]:
    """Calibration knots ``[raw, calibrated]`` fitted to answers of raw confidence ``raw`` and
    ``correct`` (1 within the distance, 0 not): the isotonic regression of ``correct`` on ``raw``
    (pool-adjacent-violators; ties in raw pooled first), its blocks then merged with a neighbour
    while one holds fewer than ``min_share`` of the answers (a block of a few answers from one
    recording is noise that does not transfer) and while more than ``n_knots - 2`` remain (the
    adjacent pair whose values differ least, weighted by the smaller's answers). Each block is a
    knot at its mean raw value; 0 and 1 pinned to the end values; rounded, raw strictly
    increasing, calibrated non-decreasing (what ``graph.answers.*_calibration`` accepts)."""
    order = np.argsort(raw, kind="stable")
    x, y = np.asarray(raw, float)[order], np.asarray(correct, float)[order]
    if not len(x):
        raise ValueError("no answers to fit a calibration to")
    blocks: list[list[float]] = []   # [sum of correct, count, sum of raw]
    for xi, yi in zip(x, y):
        if blocks and blocks[-1][2] / blocks[-1][1] == xi:
            blocks[-1][0] += yi
            blocks[-1][1] += 1
            blocks[-1][2] += xi
        else:
            blocks.append([yi, 1.0, xi])
        while len(blocks) > 1 and blocks[-2][0] / blocks[-2][1] >= blocks[-1][0] / blocks[-1][1]:
            _merge(blocks, len(blocks) - 2)

    def gap(k: int) -> float:  # merging blocks k and k + 1 costs the value step times the smaller's answers
        b, c = blocks[k], blocks[k + 1]
        return min(b[1], c[1]) * (c[0] / c[1] - b[0] / b[1])

    while len(blocks) > 1:
        small = [k for k, b in enumerate(blocks) if b[1] < min_share * len(x)]
        if small:
            k = min(small, key=lambda k: blocks[k][1])
            k = k - 1 if k == len(blocks) - 1 or (k > 0 and gap(k - 1) <= gap(k)) else k
        elif len(blocks) > n_knots - 2:
            k = min(range(len(blocks) - 1), key=gap)
        else:
            break
        _merge(blocks, k)
    xs = [b[2] / b[1] for b in blocks]
    ys = [b[0] / b[1] for b in blocks]
    knots = [[0.0, ys[0]]] + [[x_, y_] for x_, y_ in zip(xs, ys)] + [[1.0, ys[-1]]]
    out: list[list[float]] = []
    for x_, y_ in knots:
        x_, y_ = round(float(x_), 6), round(float(y_), 4)
        if out and x_ <= out[-1][0]:
            out[-1][1] = max(out[-1][1], y_)
            continue
        out.append([x_, max(y_, out[-1][1]) if out else y_])
    if len(out) == 1:  # every answer at raw 1
        out.insert(0, [0.0, out[0][1]])
    return out


def _merge(blocks: list[list[float]], k: int) -> None:
    """Blocks k and k + 1 of an isotonic fit pooled into k."""
    c = blocks.pop(k + 1)
    for i in range(3):
        blocks[k][i] += c[i]


def support_ranges(world: np.ndarray, range_m: np.ndarray, at: np.ndarray, radius: float,
                   block: int = 64) -> np.ndarray:
    """Per row of ``at`` (indices into ``world``), the median range from the depth camera (metres) of
    the detections ``world`` (M, 3) within ``radius`` metres of that row's point (the row among them;
    ranges that are not finite left out, NaN when none is): how close by the answer's support was
    seen. Blocks of ``block`` rows keep the distance matrix small on an instance with thousands of
    detections."""
    world = np.asarray(world, float)
    range_m = np.asarray(range_m, float)
    out = np.full(len(at), np.nan)
    for s in range(0, len(at), block):
        rows = np.asarray(at[s:s + block], np.int64)
        d2 = ((world[None, :, :] - world[rows][:, None, :]) ** 2).sum(axis=2)
        near = np.sort(np.where(d2 <= radius * radius, range_m[None, :], np.nan), axis=1)  # NaN sorts last
        n = np.isfinite(near).sum(axis=1)
        lo, hi = np.maximum((n - 1) // 2, 0)[:, None], (n // 2)[:, None]
        med = (np.take_along_axis(near, lo, 1) + np.take_along_axis(near, hi, 1))[:, 0] / 2
        out[s:s + block] = np.where(n > 0, med, np.nan)
    return out


def held_rows(world: np.ndarray, range_m: np.ndarray, at: np.ndarray, cfg: AnswersConfig) -> np.ndarray:
    """Whether each row of ``at`` (indices into the instance's detections ``world``, ``range_m``) would
    be answered as HELD rather than LAST: the detections within ``distance_m`` of it were seen from
    a median range under ``held_range_m`` (metres)."""
    if cfg.held_range_m <= 0 or not len(at):
        return np.zeros(len(at), bool)
    return support_ranges(world, range_m, at, cfg.distance_m) < cfg.held_range_m


def _nearest(frames: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Index into sorted ``frames`` of the one nearest each of ``at`` (ties: the earlier)."""
    i = np.clip(np.searchsorted(frames, at), 1, max(len(frames) - 1, 1))
    lo = np.maximum(i - 1, 0)
    hi = np.minimum(i, len(frames) - 1)
    return np.where(np.abs(frames[lo] - at) <= np.abs(frames[hi] - at), lo, hi)


def offline_answers(sol, path: np.ndarray | None, post: np.ndarray | None, reality: Sequence[float],
                    n_frames: int, cfg: GraphConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One instance's answer at every frame, offline -> (xyz (T, 3) world metres, raw confidence (T,),
    kind (T,) codes of ``ANSWER_KINDS``).

    Frames its intervals cover answer the interval (raw: the posterior of its stand there times the
    place's reality; of UNSEEN, halved, at the hand's last position); a carried frame answers the
    nearest detection in hand (raw ``HAND_RAW``); any other frame the place of largest posterior
    times reality (raw: that product, times ``EMPTY_FACTOR`` at a place depth showed empty). Without
    places, the nearest detection in time (raw ``LAST_RAW``). Kinds: an interval at a place and the
    most probable place STAND, an UNSEEN interval UNSEEN, a carried frame HAND, no places LAST, or
    HELD where that detection's support was seen from close by (:func:`held_rows`). Rows NaN when
    the instance has no detection."""
    xyz = np.full((n_frames, 3), np.nan)
    raw = np.zeros(n_frames)
    kind = np.full(n_frames, STAND, np.int64)
    if sol.world is None or not len(sol.world):
        return xyz, raw, kind
    frames = np.asarray(sol.frames, np.int64)
    order = np.argsort(frames, kind="stable")
    t = np.arange(n_frames)
    places = sol.places or []
    k = len(places)
    if post is None or k == 0:
        row = order[_nearest(frames[order], t)]
        xyz[:] = sol.world[row]
        raw[:] = LAST_RAW
        kind[:] = LAST
        if sol.range_m is not None:
            answered, inverse = np.unique(row, return_inverse=True)
            kind[held_rows(sol.world, sol.range_m, answered, cfg.answers)[inverse]] = HELD
        return xyz, raw, kind
    real = np.asarray(reality, float)
    stand = post[:, [stand_state(j) for j in range(k)]] * real[None, :]
    covered = np.zeros(n_frames, bool)
    for iv in sol.intervals:
        a, b = int(iv.extra["start_frame"]), int(iv.extra["end_frame"])
        xyz[a:b + 1] = iv.xyz
        j = iv.extra.get("place")
        raw[a:b + 1] = stand[a:b + 1, j] if j is not None else post[a:b + 1, UNSEEN_STATE] * 0.5
        kind[a:b + 1] = STAND if j is not None else UNSEEN
        covered[a:b + 1] = True
    kinds = np.array([state_kind(int(s)) for s in range(post.shape[1])])[path]
    best = np.argmax(stand, axis=1)
    rest = ~covered
    carried = rest & (kinds == -1)
    near = np.flatnonzero(np.asarray(sol.range_m) <= cfg.carry_range_m)
    if len(near):
        near = near[np.argsort(frames[near], kind="stable")]
        at = carried.nonzero()[0]
        xyz[at] = sol.world[near][_nearest(frames[near], at)]
        raw[at] = HAND_RAW
        kind[at] = HAND
        rest &= ~carried
    at = np.flatnonzero(rest)
    xyz[at] = np.array([p.xyz for p in places])[best[at]]
    raw[at] = stand[at, best[at]] * np.where(kinds[at] == best[at], EMPTY_FACTOR, 1.0)
    return xyz, raw, kind


@contextlib.contextmanager
def gc_paused() -> Iterator[None]:
    """The cyclic garbage collector paused while every frame's answers are made: tens of thousands
    of small records hold no reference cycles, yet each collection the allocations trigger scans
    them all again (about half the cost of making them)."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def predictions(instance: int, xyz: np.ndarray, conf: np.ndarray, t_frames: np.ndarray,
                into: dict[int, list[Prediction]]) -> None:
    """Append one instance's answers (rows of ``xyz`` that are finite) to ``into`` (ticks -> list)."""
    rows = np.flatnonzero(np.isfinite(xyz[:, 0]))
    for t, pred in zip(np.asarray(t_frames)[rows].tolist(), predictions_of(int(instance), xyz[rows], conf[rows])):
        into.setdefault(t, []).append(pred)


def operating_point(answers: dict[int, list[Prediction]], cfg: AnswersConfig, causal: bool = False
                    ) -> dict[int, list[Prediction]]:
    """The answers of at least ``cfg.min_confidence`` (``causal_min_confidence`` for graph-causal;
    every key kept, ``[]`` where none)."""
    floor = cfg.causal_min_confidence if causal else cfg.min_confidence
    return {t: [p for p in preds if p.score >= floor] for t, preds in answers.items()}
