"""Every frame answered, with a calibrated confidence (``graph.answers``).

The graph trackers answer, for every PV frame from an instance's enrollment on, their best guess of
where it is: a stand at a place, the hand while it is carried, the most probable place while it is
unseen; and as the score (the fifth column of the per-frame files) the probability that this answer
lies within ``graph.answers.distance_m`` of the truth, as the IT3DEgo evaluator counts it (a frame
of a carry has no true interval, so an answer there is never within: its confidence is low).

The place chain gives a *raw* confidence per answer (offline: the posterior probability of the
answered stand times the place's reality, :func:`offline_answers`; online: the leading state's
max-marginal, :mod:`egograph.track.online`); :func:`calibrated` maps it through monotone knots fitted
on tuning recordings (isotonic regression, ``tools/bench_confidence.py --fit``) so that a confidence
matches the frequency of answers within the distance. :func:`operating_point` keeps the answers of at
least ``min_confidence`` (graph-causal: ``causal_min_confidence``): what the per-frame files hold. World frame, metres; PV frame indices.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from egograph.core.types import Prediction
from egograph.track.config import AnswersConfig, GraphConfig
from egograph.track.places import UNSEEN_STATE, stand_state, state_kind

HAND_RAW = 0.0
"""Raw confidence of an answer at the hand while carried (never inside a true interval)."""

LAST_RAW = 0.001
"""Raw confidence of an answer at the newest detection of an instance with no place yet (a sliver
above the hand's, so that calibration tells the two apart: such a detection is often right)."""

EMPTY_FACTOR = 0.1
"""Raw confidence factor of a stand at a place depth has shown empty (offline, after the cut)."""


def calibrated(raw: np.ndarray | float, knots: Sequence[Sequence[float]]) -> np.ndarray:
    """Raw confidences mapped through ``[raw, calibrated]`` knots, joined linearly (flat beyond)."""
    k = np.asarray(knots, dtype=float)
    return np.clip(np.interp(np.asarray(raw, float), k[:, 0], k[:, 1]), 0.0, 1.0)


def _nearest(frames: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Index into sorted ``frames`` of the one nearest each of ``at`` (ties: the earlier)."""
    i = np.clip(np.searchsorted(frames, at), 1, max(len(frames) - 1, 1))
    lo = np.maximum(i - 1, 0)
    hi = np.minimum(i, len(frames) - 1)
    return np.where(np.abs(frames[lo] - at) <= np.abs(frames[hi] - at), lo, hi)


def offline_answers(sol, path: np.ndarray | None, post: np.ndarray | None, reality: Sequence[float],
                    n_frames: int, cfg: GraphConfig) -> tuple[np.ndarray, np.ndarray]:
    """One instance's answer at every frame, offline -> (xyz (T, 3) world metres, raw confidence (T,)).

    Frames its intervals cover answer the interval (raw: the posterior of its stand there times the
    place's reality; of UNSEEN, halved, at the hand's last position); a carried frame answers the
    nearest detection in hand (raw ``HAND_RAW``); any other frame the place of largest posterior
    times reality (raw: that product, times ``EMPTY_FACTOR`` at a place depth showed empty). Without
    places, the nearest detection in time (raw ``LAST_RAW``). Rows NaN when the instance has no detection."""
    xyz = np.full((n_frames, 3), np.nan)
    raw = np.zeros(n_frames)
    if sol.world is None or not len(sol.world):
        return xyz, raw
    frames = np.asarray(sol.frames, np.int64)
    order = np.argsort(frames, kind="stable")
    t = np.arange(n_frames)
    places = sol.places or []
    k = len(places)
    if post is None or k == 0:
        xyz[:] = sol.world[order][_nearest(frames[order], t)]
        raw[:] = LAST_RAW
        return xyz, raw
    real = np.asarray(reality, float)
    stand = post[:, [stand_state(j) for j in range(k)]] * real[None, :]
    covered = np.zeros(n_frames, bool)
    for iv in sol.intervals:
        a, b = int(iv.extra["start_frame"]), int(iv.extra["end_frame"])
        xyz[a:b + 1] = iv.xyz
        j = iv.extra.get("place")
        raw[a:b + 1] = stand[a:b + 1, j] if j is not None else post[a:b + 1, UNSEEN_STATE] * 0.5
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
        rest &= ~carried
    at = np.flatnonzero(rest)
    xyz[at] = np.array([p.xyz for p in places])[best[at]]
    raw[at] = stand[at, best[at]] * np.where(kinds[at] == best[at], EMPTY_FACTOR, 1.0)
    return xyz, raw


def predictions(instance: int, xyz: np.ndarray, conf: np.ndarray, t_frames: np.ndarray,
                into: dict[int, list[Prediction]]) -> None:
    """Append one instance's answers (rows of ``xyz`` that are finite) to ``into`` (ticks -> list)."""
    for f in np.flatnonzero(np.isfinite(xyz[:, 0])):
        into.setdefault(int(t_frames[f]), []).append(Prediction(int(instance), tuple(float(v) for v in xyz[f]),
                                                                float(conf[f])))


def operating_point(answers: dict[int, list[Prediction]], cfg: AnswersConfig, causal: bool = False
                    ) -> dict[int, list[Prediction]]:
    """The answers of at least ``cfg.min_confidence`` (``causal_min_confidence`` for graph-causal;
    every key kept, ``[]`` where none)."""
    floor = cfg.causal_min_confidence if causal else cfg.min_confidence
    return {t: [p for p in preds if p.score >= floor] for t, preds in answers.items()}
