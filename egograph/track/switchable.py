"""Switchable motion-break factors between consecutive landmarks of one instance.

A still object's landmarks ``L_k`` and ``L_{k+1}`` (``gtsam.Point3``, world frame,
metres) should coincide. The *switchable* zero-motion between-factor of Sünderhauf &
Protzel (IROS 2012) scales that constraint by a switch variable ``s`` (a 1-vector):

    e(L_k, L_{k+1}, s) = psi(s) * (L_{k+1} - L_k),      psi(s) = clip(s, 0, 1)

whitened by an isotropic ``still_sigma_m``, with a prior pulling ``s`` to 1. Where the
object was moved, the optimiser pays the prior to turn the switch off instead of
dragging both landmarks together. The switch prior's sigma sets the price: with the
landmarks held fixed at a whitened gap ``d = |L_{k+1} - L_k| / still_sigma``, the switch
settles at ``s = 1 / (1 + d^2 sigma_s^2)``, so ``s < 0.5`` exactly when
``d > 1 / sigma_s``.

Dynamic covariance scaling (DCS, Agarwal et al. ICRA 2013) is the closed form of the same
idea: the switch is eliminated analytically, ``s = min(1, 2 phi / (phi + d^2))``, and
GTSAM applies it as an m-estimator inside a plain ``BetweenFactorPoint3`` (all C++, no
Python callback). :func:`dcs_between` builds it; :func:`dcs_switch_value` recovers the
implied switch for reporting. DCS's switch falls below 0.5 where ``d^2 > 3 phi``, so
``phi = 1 / (3 sigma_s^2)`` (:func:`dcs_phi`) puts its breaks exactly where the switchable
factor puts them (see the tests).

The switchable factor's own closed form (:func:`switchable_closed`, the default way it is solved):
with the landmarks fixed, the switch's optimum ``s* = 1 / (1 + d^2 sigma_s^2)`` lies in (0, 1], so
the clip is inactive, and putting it back into the factor's cost leaves

    0.5 * (s*^2 d^2 + (1 - s*)^2 / sigma_s^2) = 0.5 * d^2 / (1 + sigma_s^2 d^2)
                                              = 0.5 * c^2 d^2 / (c^2 + d^2),   c = 1 / sigma_s,

which is exactly GTSAM's Geman-McClure loss of width ``c`` on the whitened gap ``d``; its
iteratively reweighted weight ``c^4 / (c^2 + d^2)^2`` is ``s*^2``, the switched factor's own. So
a ``BetweenFactorPoint3`` under that kernel has the same minima over the landmarks as the factor
with its switch variable, solved all in C++, and the switch is read back as ``s*`` from the
solved landmarks (:func:`switchable_closed_values`). Unlike DCS (a different weight curve that
only breaks at the same gap) this is the same objective. Solved with the explicit switch
variables, Levenberg-Marquardt can also stall a switch at exactly 1, where the clip's slope
ends; the closed form has no such edge.

The explicit switch factor is a ``gtsam.CustomFactor`` with analytic Jacobians (``switch_solve:
explicit``, the reference): there are few of them (one per chunk boundary), while the many
detection factors stay C++ factors.
"""

from __future__ import annotations

import functools
from functools import partial

import gtsam
import numpy as np


def switch_weight(s: float) -> tuple[float, float]:
    """``psi(s) = clip(s, 0, 1)`` and its derivative: 1 on the closed interval [0, 1] (the
    one-sided slope at the ends, so a switch starting at exactly 1 can move), 0 outside."""
    if s < 0.0:
        return 0.0, 0.0
    if s > 1.0:
        return 1.0, 0.0
    return float(s), 1.0


def _switchable_error(this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
    ka, kb, ks = this.keys()
    a = values.atPoint3(ka)
    b = values.atPoint3(kb)
    s = float(values.atVector(ks)[0])
    w, dw = switch_weight(s)
    delta = np.asarray(b, dtype=float) - np.asarray(a, dtype=float)
    if H is not None:
        H[0] = -w * np.eye(3)
        H[1] = w * np.eye(3)
        H[2] = (dw * delta).reshape(3, 1)
    return w * delta


def switchable_between(key_a: int, key_b: int, key_switch: int, still_sigma_m: float) -> gtsam.CustomFactor:
    """``SwitchableBetween``: zero motion from landmark ``key_a`` to ``key_b`` (Point3,
    metres), weighted by the switch ``key_switch`` (1-vector); isotropic sigma in metres."""
    noise = gtsam.noiseModel.Isotropic.Sigma(3, still_sigma_m)
    return gtsam.CustomFactor(noise, [key_a, key_b, key_switch], partial(_switchable_error))


def switch_prior(key_switch: int, switch_sigma: float) -> gtsam.PriorFactorVector:
    """Prior pulling a switch to 1 (the constraint is on) with sigma ``switch_sigma``."""
    return gtsam.PriorFactorVector(key_switch, np.array([1.0]), gtsam.noiseModel.Isotropic.Sigma(1, switch_sigma))


@functools.lru_cache(maxsize=64)
def _dcs_noise(still_sigma_m: float, phi: float) -> gtsam.noiseModel.Base:
    """One DCS noise model per (sigma, phi), shared read-only by every factor that uses it (a chain
    has one per chunk boundary, and is built again for each solve)."""
    base = gtsam.noiseModel.Isotropic.Sigma(3, still_sigma_m)
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.DCS.Create(phi), base)


def dcs_between(key_a: int, key_b: int, still_sigma_m: float, phi: float) -> gtsam.BetweenFactorPoint3:
    """The DCS fast path: zero-motion ``BetweenFactorPoint3`` under a DCS kernel ``phi``."""
    return gtsam.BetweenFactorPoint3(key_a, key_b, gtsam.Point3(0, 0, 0), _dcs_noise(still_sigma_m, phi))


def dcs_phi(switch_sigma: float) -> float:
    """The DCS ``phi`` that breaks at the same whitened gap as a switch prior of ``switch_sigma``."""
    return 1.0 / (3.0 * switch_sigma**2)


def dcs_switch_value(a: np.ndarray, b: np.ndarray, still_sigma_m: float, phi: float) -> float:
    """The switch DCS implies for landmarks ``a``, ``b`` (metres): ``min(1, 2 phi / (phi + d^2))``."""
    d2 = float(np.sum((np.asarray(b) - np.asarray(a)) ** 2)) / still_sigma_m**2
    return min(1.0, 2.0 * phi / (phi + d2))


def dcs_switch_values(landmarks: np.ndarray, still_sigma_m: float, phi: float) -> np.ndarray:
    """:func:`dcs_switch_value` of every consecutive pair of ``landmarks`` (n, 3) at once: (n-1,), the
    same bits (each row's three squares summed in the same order)."""
    d2 = whitened_gaps2(landmarks, still_sigma_m)
    return np.minimum(1.0, 2.0 * phi / (phi + d2))


def whitened_gaps2(landmarks: np.ndarray, still_sigma_m: float) -> np.ndarray:
    """Squared gap ``d^2`` between every consecutive pair of ``landmarks`` (n, 3), metres, whitened by
    ``still_sigma_m``: (n-1,), each row's three squares summed in order."""
    diff = np.asarray(landmarks, float)
    return ((diff[1:] - diff[:-1]) ** 2).sum(axis=1) / still_sigma_m**2


def switch_clipped(values: gtsam.Values, key_switch: int) -> float:
    """The effective switch ``psi(s)`` of a solved switch variable."""
    return switch_weight(float(values.atVector(key_switch)[0]))[0]


@functools.lru_cache(maxsize=64)
def _closed_noise(still_sigma_m: float, switch_sigma: float) -> gtsam.noiseModel.Base:
    """The Geman-McClure noise model of :func:`switchable_closed`, one per (sigma, switch sigma),
    shared read-only by every factor that uses it."""
    base = gtsam.noiseModel.Isotropic.Sigma(3, still_sigma_m)
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.GemanMcClure.Create(1.0 / switch_sigma), base)


def switchable_closed(key_a: int, key_b: int, still_sigma_m: float, switch_sigma: float) -> gtsam.BetweenFactorPoint3:
    """``SwitchableBetween`` with its switch eliminated in closed form: zero motion from landmark
    ``key_a`` to ``key_b`` (Point3, metres, isotropic ``still_sigma_m``) under a Geman-McClure
    kernel of width ``1 / switch_sigma``, the same cost over the landmarks as
    :func:`switchable_between` plus :func:`switch_prior` at the switch's optimum (module docstring)."""
    return gtsam.BetweenFactorPoint3(key_a, key_b, gtsam.Point3(0, 0, 0), _closed_noise(still_sigma_m, switch_sigma))


def switchable_closed_values(landmarks: np.ndarray, still_sigma_m: float, switch_sigma: float) -> np.ndarray:
    """The optimal switch ``1 / (1 + d^2 switch_sigma^2)`` of every consecutive pair of ``landmarks``
    (n, 3), metres: (n-1,), ``d`` the gap whitened by ``still_sigma_m``."""
    return 1.0 / (1.0 + switch_sigma**2 * whitened_gaps2(landmarks, still_sigma_m))
