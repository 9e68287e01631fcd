"""How noisy a front-end's lifted detections are: the detection noise scale, fitted from the stands.

The detection factors' sigmas (:mod:`egograph.track.detection_factor`) describe good boxes on
the object. A front-end whose boxes often cover part of the object, or the table beside it,
lifts points that scatter several times wider; with sigmas that small the chi2 gate calls most
true detections outliers, stands never gather support, and the intervals' covariances are
overconfident. So the offline tracker estimates one scale for all sigmas from its own stands.

Under the model, an inlier's squared Mahalanobis distance to its stand's centre, whitened by
sigmas that are ``r`` times too small, is ``r² · χ²₃`` cut at the inlier gate ``G`` (only
residuals below it are inliers). The fit matches the median: ``r² · F⁻¹(F(G / r²) / 2)`` equals
the observed median, a function that grows with ``r``, solved by false position. Each distance is
first multiplied by ``n / (n - 1)`` (``n`` inliers in its stand): the centre was fitted to the
same points. False matches inside the gate push the estimate up a little; the robust kernel
and the inlier-share rule bound what they can do.
"""

from __future__ import annotations

import math

import numpy as np

from egograph.track.detection_factor import mahalanobis2


def chi2_cdf(x: float) -> float:
    """CDF of chi-squared with 3 degrees of freedom (closed form)."""
    if x <= 0:
        return 0.0
    return math.erf(math.sqrt(x / 2)) - math.sqrt(2 * x / math.pi) * math.exp(-x / 2)


def chi2_pdf(x: float) -> float:
    """Density of chi-squared with 3 degrees of freedom: the derivative of :func:`chi2_cdf`."""
    return math.sqrt(x / (2 * math.pi)) * math.exp(-x / 2) if x > 0 else 0.0


def chi2_ppf(p: float) -> float:
    """Inverse of :func:`chi2_cdf`, to 1e-12 relative: Newton steps kept inside a bisection bracket
    (a handful of steps where bisection takes forty; the online tracker refits its noise scale,
    two nested solves, every few dozen detections)."""
    if p <= 0:
        return 0.0
    lo, hi = 0.0, 1.0
    while chi2_cdf(hi) < p:
        lo, hi = hi, 2 * hi
    x = 0.5 * (lo + hi)
    for _ in range(200):
        f = chi2_cdf(x) - p
        if f < 0:
            lo = x
        else:
            hi = x
        slope = chi2_pdf(x)
        step = x - f / slope if slope > 0 else lo - 1.0
        prev, x = x, (step if lo < step < hi else 0.5 * (lo + hi))
        if abs(x - prev) <= 1e-12 * x or hi - lo <= 1e-12 * hi:
            break
    return x


def truncated_median(r: float, gate: float) -> float:
    """Median of ``r² · χ²₃`` cut at ``gate``."""
    return r * r * chi2_ppf(0.5 * chi2_cdf(gate / (r * r)))


def fit_scale_ratio(d2: np.ndarray, gate: float, lo: float = 0.05, hi: float = 20.0) -> float:
    """The factor ``r`` by which the sigmas that whitened ``d2`` (squared distances, all within
    ``gate``) are too small; clipped to ``[lo, hi]``."""
    target = float(np.median(np.minimum(d2, gate)))
    fa, fb = truncated_median(lo, gate) - target, truncated_median(hi, gate) - target
    if fb <= 0:
        return hi
    if fa >= 0:
        return lo
    # Illinois false position on log r (the median grows smoothly with r): a dozen steps where
    # bisection takes sixty, to 1e-12 relative
    a, b = math.log(lo), math.log(hi)
    side = 0
    for _ in range(100):
        m = (a * fb - b * fa) / (fb - fa)
        fm = truncated_median(math.exp(m), gate) - target
        if fm < 0:
            a, fa = m, fm
            if side == -1:
                fb /= 2
            side = -1
        else:
            b, fb = m, fm
            if side == 1:
                fa /= 2
            side = 1
        if b - a <= 1e-12 or fm == 0:
            break
    return math.exp(m)


SETTLED = 0.05
"""A refitted scale within this relative change of the current one leaves it as it is."""


def centred(d2: np.ndarray) -> np.ndarray:
    """One stand's inlier distances ``d2`` times ``n / (n - 1)``: its centre was fitted to them."""
    n = len(d2)
    return d2 * (n / (n - 1))


def stand_residuals(solutions) -> np.ndarray:
    """Squared Mahalanobis distances of every stationary segment's inliers to its centre
    (:func:`centred`); ``solutions``: offline :class:`~egograph.track.segments.InstanceSolution`\\ s."""
    out = []
    for sol in solutions:
        for seg in sol.segments:
            if not seg.stationary or seg.n_inliers < 2:
                continue
            rows = seg.rows[seg.inliers]
            out.append(centred(mahalanobis2(sol.world[rows], seg.xyz, sol.cov[rows])))
    return np.concatenate(out) if out else np.zeros(0)


def refit(d2: np.ndarray, scale: float, noise, gate: float) -> float | None:
    """The scale that the residuals ``d2`` (whitened at ``scale``, cut at ``gate``) call for, clipped
    to ``noise.auto_range`` and rounded to 4 digits; None when there are fewer than
    ``noise.auto_min_residuals`` of them or it moves by less than :data:`SETTLED`. ``noise``: the
    :class:`~egograph.track.config.DetectionNoiseConfig`; used offline and online alike."""
    if len(d2) < noise.auto_min_residuals:
        return None
    lo, hi = noise.auto_range
    new = float(np.clip(scale * fit_scale_ratio(d2, gate), lo, hi))
    return None if abs(new / scale - 1) < SETTLED else round(new, 4)
