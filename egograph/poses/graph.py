"""The GTSAM pose graph of the refinement.

Key scheme (stable; the joint tracker mode adds its landmark factors to the same graph):

* ``pose_key(i) == gtsam.symbol('x', i)``: the **PV camera -> world** pose of frame ``i``
  (index into ``rec.timestamps``) as a ``gtsam.Pose3`` in the column convention,
  ``Pose3(M.T)`` for the hl2ss row-vector ``pv_pose.json`` matrix ``M``. Only frames with a
  valid reported PV pose have a variable.
* ``world_key(i) == gtsam.symbol('w', i)``: the HoloLens world correction of frame i
  (``Pose3``, world -> world) in the head-tracking error model
  ``x_i ≈ w_i · reported_i`` (white jitter), ``w_i ≈ w_{i+1}`` (random-walk drift; a
  relocalisation jump breaks one of these robustly). Present when ``refine.hololens``.
* The AHAT camera -> world pose of frame i is ``x_i.compose(Pose3(ahat_offsets(rec)[i]))``
  (``egograph.poses.constraints.ahat_offsets``: AHAT camera -> PV camera at frame i, from the
  reported poses, so the few-ms PV/AHAT capture offset is included).

All factors are built-in C++ ones (``BetweenFactorPose3``, ``PriorFactorPose3``), robust
(Cauchy) where the source's kernel width is > 0.
"""

from __future__ import annotations

import time

import gtsam
import numpy as np

from egograph.poses.constraints import Constraints


def pose_key(i: int) -> int:
    """GTSAM key of frame i's PV camera -> world pose."""
    return gtsam.symbol("x", int(i))


def world_key(i: int) -> int:
    """GTSAM key of frame i's HoloLens world correction (x_i ≈ w_i · reported_i)."""
    return gtsam.symbol("w", int(i))


KEYS = {"x": pose_key, "w": world_key}


def noise_model(sig: np.ndarray, kernel: float, estimator: str = "cauchy", information: np.ndarray | None = None):
    """Diagonal sigmas ([rot rad x3, trans m x3]) or a full 6x6 information matrix, with a robust
    kernel of width ``kernel`` (whitened units)."""
    if information is not None:
        base = gtsam.noiseModel.Gaussian.Information(np.asarray(information, dtype=np.float64))
    else:
        base = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sig, dtype=np.float64))
    if kernel and kernel > 0:
        est = gtsam.noiseModel.mEstimator
        m = est.GemanMcClure.Create(float(kernel)) if estimator == "gm" else est.Cauchy.Create(float(kernel))
        return gtsam.noiseModel.Robust.Create(m, base)
    return base


def add_constraints(graph: gtsam.NonlinearFactorGraph, c: Constraints, values: gtsam.Values) -> int:
    """Add a batch of constraints as factors on variables present in ``values``; returns how many were added."""
    n = 0
    ki, kj = KEYS[c.key_i], KEYS[c.key_j]
    for k in range(len(c)):
        a = ki(int(c.i[k]))
        if not values.exists(a):
            continue
        model = noise_model(c.sigmas[k], c.kernel, c.estimator,
                            None if c.information is None else c.information[k])
        T = gtsam.Pose3(np.asarray(c.T[k], dtype=np.float64))
        if c.kind == "relative":
            b = kj(int(c.j[k]))
            if not values.exists(b):
                continue
            graph.add(gtsam.BetweenFactorPose3(a, b, T, model))
        else:
            graph.add(gtsam.PriorFactorPose3(a, T, model))
        n += 1
    return n


def build_graph(initial: np.ndarray, valid: np.ndarray, constraints: list[Constraints],
                world_initial: np.ndarray | None = None
                ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, dict[str, int]]:
    """Pose graph over the frames with ``valid`` initial PV poses (column-vector (N, 4, 4)).

    ``world_initial`` (N, 4, 4 column, or None): initial HoloLens world corrections ``w_i``
    of the valid frames; None = no ``w`` variables. Returns the graph, the initial values and
    the number of factors per source.
    """
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for i in np.flatnonzero(valid):
        values.insert(pose_key(i), gtsam.Pose3(np.asarray(initial[i], dtype=np.float64)))
        if world_initial is not None:
            values.insert(world_key(i), gtsam.Pose3(np.asarray(world_initial[i], dtype=np.float64)))
    counts: dict[str, int] = {}
    for c in constraints:
        counts[c.source] = counts.get(c.source, 0) + add_constraints(graph, c, values)
    return graph, values, counts


def solve(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, max_iterations: int = 50) -> tuple[gtsam.Values, dict]:
    """Levenberg-Marquardt; returns the optimised values and a small report."""
    t = time.perf_counter()
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(max_iterations))
    params.setRelativeErrorTol(1e-6)
    params.setAbsoluteErrorTol(1e-6)
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    e0 = graph.error(values)
    result = opt.optimize()
    return result, {"error_initial": float(e0), "error_final": float(graph.error(result)),
                    "iterations": int(opt.iterations()), "seconds": time.perf_counter() - t}


def values_to_columns(values: gtsam.Values, n: int) -> np.ndarray:
    """(n, 4, 4) column-vector poses from the values (NaN for frames without a variable)."""
    out = np.full((n, 4, 4), np.nan)
    for i in range(n):
        k = pose_key(i)
        if values.exists(k):
            out[i] = values.atPose3(k).matrix()
    return out
