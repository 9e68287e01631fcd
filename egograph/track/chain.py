"""The landmark chain of one instance: a Point3 landmark per time chunk, joined by motion-break factors.

The instance's timeline is cut on a fixed grid of ``chunk_s`` seconds; each non-empty chunk
k gets a landmark ``L_k`` held by the chunk's detection factors
(:mod:`egograph.track.detection_factor`); consecutive landmarks are joined by a switchable
zero-motion factor (:mod:`egograph.track.switchable`), its DCS closed form (``switches: dcs``)
or, after the DCS pre-pass, a plain zero-motion factor. The offline solve is batch
Levenberg-Marquardt, in local windows around the candidate breaks, with the AHAT alias
re-chosen per observation between rounds. World frame, metres.
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import gtsam
import numpy as np

from egograph.track.config import GraphConfig
from egograph.track.detection_factor import detection_factors
from egograph.track.switchable import (
    dcs_between,
    dcs_phi,
    dcs_switch_values,
    switch_clipped,
    switch_prior,
    switchable_between,
    switchable_closed,
    switchable_closed_values,
)


def L(k: int) -> int:
    """GTSAM key of chunk k's landmark (Point3, world, metres)."""
    return gtsam.symbol("l", k)


def S(k: int) -> int:
    """GTSAM key of the switch (a 1-vector) on the break between chunks k-1 and k."""
    return gtsam.symbol("s", k)


def chunk_index(t_s: np.ndarray, chunk_s: float) -> np.ndarray:
    """Chunk id 0..C-1 per observation (times sorted, seconds) on a fixed grid from the first."""
    grid = np.floor((t_s - t_s[0]) / chunk_s).astype(np.int64)
    _, idx = np.unique(grid, return_inverse=True)
    return idx.astype(np.int64)


def _chunk_medians(world: np.ndarray, chunk: np.ndarray, n: int) -> np.ndarray:
    """(n, 3) per-coordinate median of each chunk's rows (chunks 0..n-1, none empty): one sort per
    coordinate for every chunk at once, the same bits as ``np.median`` per chunk (an even count
    takes the mean of the two middle values)."""
    world = np.asarray(world, float)
    counts = np.bincount(chunk, minlength=n)
    if not np.isfinite(world).all() or (counts == 0).any():  # np.median's NaN rule, and no empty chunk
        order = np.argsort(chunk, kind="stable")
        bounds = np.searchsorted(chunk[order], np.arange(n + 1))
        return np.array([np.median(world[order[bounds[k]:bounds[k + 1]]], axis=0) for k in range(n)]).reshape(n, 3)
    start = np.cumsum(counts) - counts
    lo, hi = start + (counts - 1) // 2, start + counts // 2
    out = np.empty((n, 3))
    for j in range(3):
        s = world[np.lexsort((world[:, j], chunk)), j]   # by chunk, then by value
        out[:, j] = np.where(counts % 2 == 1, s[hi], (s[lo] + s[hi]) / 2)
    return out


def add_break_factors(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, k: int, cfg: GraphConfig,
                      kind: str | None = None) -> None:
    """Motion-break factor between landmarks k-1 and k (and the switch variable, if any).
    ``kind``: 'switchable' | 'dcs' | 'still' (a plain Gaussian zero-motion factor); default cfg.switches."""
    kind = kind or cfg.switches
    if kind == "switchable" and cfg.switch_solve == "closed":
        graph.add(switchable_closed(L(k - 1), L(k), cfg.still_sigma_m, cfg.switch_sigma))
    elif kind == "switchable":
        graph.add(switchable_between(L(k - 1), L(k), S(k), cfg.still_sigma_m))
        graph.add(switch_prior(S(k), cfg.switch_sigma))
        values.insert(S(k), np.array([1.0]))
    elif kind == "dcs":
        graph.add(dcs_between(L(k - 1), L(k), cfg.still_sigma_m, dcs_phi(cfg.switch_sigma)))
    elif kind == "still":
        graph.add(gtsam.BetweenFactorPoint3(L(k - 1), L(k), gtsam.Point3(0, 0, 0),
                                            gtsam.noiseModel.Isotropic.Sigma(3, cfg.still_sigma_m)))
    else:
        raise ValueError(f"unknown switches {kind!r}: 'switchable' or 'dcs'")


def _landmark_keys(n: int) -> np.ndarray:
    return np.array([L(k) for k in range(n)], np.uint64)


def _instance_graph(world: np.ndarray, cov: np.ndarray, chunk: np.ndarray, init: np.ndarray, cfg: GraphConfig,
                    kinds: Sequence[str] | None = None, factors: list | None = None
                    ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """One instance's graph: a landmark per chunk (initial ``init``), break factors between
    consecutive ones (``kinds[k-1]`` per boundary, default cfg.switches), detection factors (the
    rows' ``factors`` when made already, on the landmarks of ``chunk``)."""
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for k, p in enumerate(init):
        values.insert(L(k), gtsam.Point3(*p))
        if k:
            add_break_factors(graph, values, k, cfg, None if kinds is None else kinds[k - 1])
    if factors is None:
        factors = detection_factors(_landmark_keys(len(init))[chunk], world, cov, cfg.noise)
    for factor in factors:
        graph.add(factor)
    return graph, values


def solve_lm(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, max_iterations: int) -> gtsam.Values:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-6)
    params.setAbsoluteErrorTol(1e-9)
    return gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()


def _switch_values(result: gtsam.Values | None, landmarks: np.ndarray, cfg: GraphConfig) -> np.ndarray:
    """Effective switch (0-1) per chunk boundary k-1 -> k, index k-1."""
    n = len(landmarks)
    if cfg.switches == "switchable" and cfg.switch_solve == "closed":
        return switchable_closed_values(landmarks, cfg.still_sigma_m, cfg.switch_sigma).reshape(max(n - 1, 0))
    if cfg.switches == "switchable":
        return np.array([switch_clipped(result, S(k)) for k in range(1, n)])
    return dcs_switch_values(landmarks, cfg.still_sigma_m, dcs_phi(cfg.switch_sigma)).reshape(max(n - 1, 0))


def _landmarks_of(result: gtsam.Values, n: int) -> np.ndarray:
    return np.array([np.asarray(result.atPoint3(L(k))) for k in range(n)]).reshape(n, 3)


def _nearest_candidates(candidates: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Per row, the alias candidate (NaN-padded (M, K, 3)) nearest ``target`` (M, 3)."""
    d = np.linalg.norm(candidates - target[:, None, :], axis=2)
    d = np.where(np.isfinite(d), d, np.inf)
    best = np.argmin(d, axis=1)
    return candidates[np.arange(len(candidates)), best]


def solve_instance_offline(world, cov, candidates, chunk, cfg: GraphConfig):
    """An instance's chain solved offline, ``alias_rounds`` times re-choosing each observation's
    alias candidate nearest its landmark: (world per observation, landmarks per chunk, switches)."""
    n = int(chunk.max()) + 1
    init = _chunk_medians(world, chunk, n)
    for round_ in range(max(0, cfg.alias_rounds) + 1):
        landmarks, switches = _solve_chain(world, cov, chunk, init, cfg)
        if round_ == cfg.alias_rounds or candidates is None:
            break
        better = _nearest_candidates(candidates, landmarks[chunk])
        if np.allclose(better, world, equal_nan=True):
            break
        world = better
        init = landmarks
    return world, landmarks, switches


def _solve_chain(world, cov, chunk, init, cfg: GraphConfig) -> tuple[np.ndarray, np.ndarray]:
    """Landmarks and effective switches of one chain. With switchable factors and
    ``dcs_prepass``, a DCS solve (all C++) first finds the boundaries that are clearly still
    (implied switch >= ``prepass_keep``); those get a plain zero-motion factor, every other
    boundary an explicit switch, and the switchable solve starts from the DCS landmarks."""
    n = len(init)
    if cfg.switches == "switchable" and cfg.dcs_prepass and n > 1:
        factors = detection_factors(_landmark_keys(n)[chunk], world, cov, cfg.noise)  # for both solves below
        graph, values = _instance_graph(world, cov, chunk, init, cfg, ["dcs"] * (n - 1), factors)
        dcs = dataclasses.replace(cfg, switches="dcs")
        landmarks = _landmarks_of(solve_lm(graph, values, cfg.max_iterations), n)
        implied = _switch_values(None, landmarks, dcs)
        sw = np.ones(n - 1)
        # Each candidate break is decided in a local window of the chain (a switch only couples
        # its neighbours). Closed-form switches: all windows in one C++ solve. Explicit ones: a
        # solve per window (piece), which keeps the Python CustomFactors in small graphs, as
        # GTSAM's cost per CustomFactor call grows with the size of the graph it sits in.
        windows = _candidate_windows(np.flatnonzero(implied < cfg.prepass_keep) + 1, n, cfg.prepass_window)
        if cfg.switch_solve == "closed":
            return _solve_windows_closed(landmarks, implied, windows, cfg, chunk, factors)
        for lo, hi, own_lo, own_hi in _window_pieces(windows, cfg.prepass_max_window, cfg.prepass_window):
            rows = (chunk >= lo) & (chunk < hi)
            kinds = ["still" if implied[k - 1] >= cfg.prepass_keep else "switchable" for k in range(lo + 1, hi)]
            graph, values = _instance_graph(world[rows], cov[rows], chunk[rows] - lo, landmarks[lo:hi], cfg, kinds)
            result = solve_lm(graph, values, cfg.max_iterations)
            landmarks[own_lo:own_hi] = _landmarks_of(result, hi - lo)[own_lo - lo:own_hi - lo]
            for k in range(max(own_lo, lo + 1), own_hi):
                if kinds[k - lo - 1] == "switchable":
                    sw[k - 1] = switch_clipped(result, S(k - lo))
        return landmarks, sw
    graph, values = _instance_graph(world, cov, chunk, init, cfg)
    result = solve_lm(graph, values, cfg.max_iterations)
    landmarks = _landmarks_of(result, n)
    return landmarks, _switch_values(result, landmarks, cfg)


def _solve_windows_closed(landmarks, implied, windows, cfg: GraphConfig, chunk, factors):
    """Every candidate window [lo, hi) of a chain solved in one Levenberg-Marquardt problem, the
    windows as disjoint components: landmarks keyed by their chunk in the whole chain, started from
    the DCS ``landmarks``; a boundary DCS found clearly still (``implied`` >= ``prepass_keep``) gets a
    plain zero-motion factor, every other one the closed-form switchable factor. ``factors``: the
    detection factor of each row (``chunk`` its landmark), those of rows in a window go in.
    Landmarks outside the windows keep their DCS values, their boundaries switch 1.
    -> (landmarks, switches)."""
    n = len(landmarks)
    sw = np.ones(n - 1)
    if not windows:
        return landmarks, sw
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    inside = np.zeros(n, bool)
    closed = np.zeros(n, bool)   # boundary k (chunks k-1, k) has a switchable factor
    for lo, hi in windows:
        inside[lo:hi] = True
        for k in range(lo, hi):
            values.insert(L(k), gtsam.Point3(*landmarks[k]))
            if k > lo:
                kind = "still" if implied[k - 1] >= cfg.prepass_keep else "switchable"
                closed[k] = kind == "switchable"
                add_break_factors(graph, values, k, cfg, kind)
    for j in np.flatnonzero(inside[chunk]).tolist():
        graph.add(factors[j])
    result = solve_lm(graph, values, cfg.max_iterations)
    idx = np.flatnonzero(inside)
    landmarks = landmarks.copy()
    landmarks[idx] = np.array([np.asarray(result.atPoint3(L(int(k)))) for k in idx]).reshape(len(idx), 3)
    s_all = switchable_closed_values(landmarks, cfg.still_sigma_m, cfg.switch_sigma)
    ks = np.flatnonzero(closed)
    sw[ks - 1] = s_all[ks - 1]
    return landmarks, sw


def _candidate_windows(boundaries: np.ndarray, n: int, pad: int) -> list[tuple[int, int]]:
    """Chunk ranges [lo, hi) reaching ``pad`` chunks either side of each candidate boundary
    (boundary k joins chunks k-1 and k), overlapping ranges merged."""
    out: list[list[int]] = []
    for k in boundaries:
        lo, hi = max(0, int(k) - pad), min(n, int(k) + pad)
        if out and lo <= out[-1][1]:
            out[-1][1] = max(out[-1][1], hi)
        else:
            out.append([lo, hi])
    return [(lo, hi) for lo, hi in out]


def _window_pieces(windows: list[tuple[int, int]], max_len: int, pad: int) -> list[tuple[int, int, int, int]]:
    """Each window [lo, hi) cut into overlapping pieces of at most ``max_len`` chunks: (piece_lo,
    piece_hi, own_lo, own_hi). A piece decides only the chunks [own_lo, own_hi) and the
    boundaries in (own_lo, own_hi) (also own_lo, except at the window's start), at least ``pad``
    chunks from a cut, so each decision sees ``pad`` chunks of context either side as in an
    uncut window; the owned ranges partition the window."""
    out = []
    step = max(1, max_len - 2 * pad)
    for lo, hi in windows:
        if max_len <= 2 * pad or hi - lo <= max_len:
            out.append((lo, hi, lo, hi))
            continue
        s = lo
        while True:
            e = min(s + max_len, hi)
            own_lo = lo if s == lo else s + pad
            own_hi = hi if e == hi else e - pad
            out.append((s, e, own_lo, own_hi))
            if e == hi:
                break
            s += step
    return out
