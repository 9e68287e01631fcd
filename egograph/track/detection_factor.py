"""Detection factors: one lifted observation pulls its chunk's landmark (world frame, metres).

With the camera poses fixed, a detection lifted to the world point ``p`` seen from the
depth camera centre ``c`` is a ``PriorFactorPoint3`` on the landmark with an anisotropic
Gaussian: along the ray the error grows with range (AHAT range noise, the visible
surface against the object centre, alias mistakes), across it with range times the
angular error (pose, box jitter, PV-AHAT registration):

    sigma_ray(r) = scale * (range_sigma_m + range_sigma_per_m * r)
    sigma_lat(r) = scale * (lateral_sigma_m + lateral_sigma_per_m * r)
    Cov = sigma_lat^2 I + (sigma_ray^2 - sigma_lat^2) u u^T,  u = (p - c) / |p - c|

A robust kernel on top (Cauchy by default) bounds the pull of a persistent false match
(a look-alike twin, clutter) so that it cannot drag the landmark of a real object.
When poses are variables (joint mode) the same noise applies to a pose-landmark factor.
"""

from __future__ import annotations

import gtsam
import numpy as np

from egograph.track.config import KERNELS, DetectionNoiseConfig

ESTIMATORS = {
    "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
    "huber": gtsam.noiseModel.mEstimator.Huber,
    "geman_mcclure": gtsam.noiseModel.mEstimator.GemanMcClure,
    "tukey": gtsam.noiseModel.mEstimator.Tukey,
}




def lengths(v: np.ndarray) -> np.ndarray:
    """Euclidean length of each vector along the last axis of ``v``: ``np.linalg.norm(v, axis=-1)``,
    the same bits, without its argument checks (the online tracker asks for it several times per
    detection, on arrays of a few dozen rows)."""
    return np.sqrt((v * v).sum(axis=-1))


def detection_covariances(world: np.ndarray, camera: np.ndarray, cfg: DetectionNoiseConfig) -> np.ndarray:
    """(M, 3, 3) world-frame covariances (m^2) of lifted points ``world`` seen from ``camera`` (M, 3)."""
    ray = np.asarray(world, float) - np.asarray(camera, float)
    r = lengths(ray)
    u = ray / np.maximum(r, 1e-9)[:, None]
    s_ray = cfg.scale * (cfg.range_sigma_m + cfg.range_sigma_per_m * r)
    s_lat = cfg.scale * (cfg.lateral_sigma_m + cfg.lateral_sigma_per_m * r)
    cov = (s_lat**2)[:, None, None] * np.eye(3)
    cov += (s_ray**2 - s_lat**2)[:, None, None] * (u[:, :, None] * u[:, None, :])
    return cov


def m_estimator(kernel: str, width: float):
    """The named GTSAM m-estimator of ``width``, or None for ``none`` (Gaussian)."""
    if kernel == "none":
        return None
    if kernel not in ESTIMATORS:
        raise ValueError(f"unknown robust kernel {kernel!r}; choose one of {', '.join(KERNELS)}")
    return ESTIMATORS[kernel].Create(width)


def robust(base: gtsam.noiseModel.Base, kernel: str, width: float) -> gtsam.noiseModel.Base:
    """Wrap a noise model in the named m-estimator (``none`` keeps it Gaussian)."""
    estimator = m_estimator(kernel, width)
    return base if estimator is None else gtsam.noiseModel.Robust.Create(estimator, base)


NOISE_MODEL_CACHE_SIZE = 200_000
"""Detection noise models kept for reuse (:func:`detection_noise_model`); beyond this many the cache
starts again (about 1 kB each)."""

_noise_models: dict[tuple, gtsam.noiseModel.Base] = {}


def detection_noise_model(cov: np.ndarray, kernel: str, width: float) -> gtsam.noiseModel.Base:
    """The robust Gaussian noise model of one detection covariance ``cov`` (3, 3) m^2, made once per
    covariance and kernel: an offline solve builds the factor of every detection again for each
    window of the chain, each segment and place it falls in and each alias and noise-scale round,
    and making the model (a Cholesky factor in GTSAM) cost more than the rest of the factor. The
    same covariance bytes give the same model, so every solve is the same, bit for bit. GTSAM's
    noise models are immutable and shared by the factors that hold them."""
    key = (np.ascontiguousarray(cov, dtype=float).tobytes(), kernel, width)
    model = _noise_models.get(key)
    if model is None:
        if len(_noise_models) >= NOISE_MODEL_CACHE_SIZE:
            _noise_models.clear()
        base = gtsam.noiseModel.Gaussian.Covariance(cov)
        estimator = m_estimator(kernel, width)
        model = base if estimator is None else gtsam.noiseModel.Robust.Create(estimator, base)
        _noise_models[key] = model
    return model


def detection_factors(keys: np.ndarray, world: np.ndarray, covariances: np.ndarray,
                      cfg: DetectionNoiseConfig) -> list[gtsam.PriorFactorPoint3]:
    """One robust ``PriorFactorPoint3`` per row: landmark ``keys[j]`` observed at ``world[j]``. GTSAM
    factors are immutable: a list made once can fill several graphs over the same landmarks."""
    m_estimator(cfg.kernel, cfg.kernel_width)  # an unknown kernel is refused even without a row
    model, prior = detection_noise_model, gtsam.PriorFactorPoint3
    kernel, width = cfg.kernel, cfg.kernel_width
    return [prior(key, p, model(cov, kernel, width))
            for key, p, cov in zip(keys.tolist(), np.asarray(world, float), np.asarray(covariances, float))]


def add_detection_factors(graph: gtsam.NonlinearFactorGraph, keys: np.ndarray, world: np.ndarray,
                          covariances: np.ndarray, cfg: DetectionNoiseConfig) -> None:
    """Add :func:`detection_factors` of the rows to ``graph``."""
    for factor in detection_factors(keys, world, covariances, cfg):
        graph.add(factor)


def mahalanobis2(world: np.ndarray, centre: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distance of each row of ``world`` to ``centre`` (M,) under its covariance."""
    d = np.asarray(world, float) - np.asarray(centre, float)
    return np.einsum("mi,mi->m", d, np.linalg.solve(covariances, d[:, :, None])[:, :, 0])
