"""Verification of shortlisted proposals by local features with geometric verification, and the
calibrated probability that a box is the instance.

The global embedding of a crop tells categories apart, not instances: a look-alike or a piece of
clutter scores as high as the instance. Local features with geometric verification tell two
objects of one category apart by their print, and say "not verified" rather than "similar" for
clutter. Per enrolled instance the embedding shortlists its ``verify_top_k`` most similar
proposals; each is verified against every enrollment view (the MVPE photos; the SVOE crop and its
augmentations): RootSIFT keypoints (OpenCV SIFT, descriptors L1-normalised and square-rooted), the
ratio test, and a RANSAC homography; the evidence is the most inliers over the views and how far
they spread over the crop.

The score written is a calibrated probability (logistic regression, coefficients in the
configuration, fitted on tuning recordings by ``tools/fit_verify.py``) from: the embedding cosine,
its margin over the best other instance, (under whitening) the whitened cosine, the verified
inliers, their spread, the inlier margin over the best other instance verified on the same crop,
and the colour histogram's agreement. The calibration map that turns the pair model's probability
into the emitted one adds the box's 3D plausibility (:func:`size_features`): its size at the
depth behind it against the instance's size at enrollment, or, without an enrolled size, against
the sizes an object a hand moves can have. A crop with too few keypoints (small or textureless: below
``verify_min_keypoints`` or a short side under ``verify_min_side_px``) has nothing to verify: a
second model without the local-feature terms scores it, and the detection says so (``det_conf``
0 instead of 1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from egograph.frontend.config import FrontendConfig
from egograph.frontend.encoder import as_rgb

# the features of one (proposal, instance) pair, in the order of the stored coefficients
FEATURES = ("cosine", "cosine_margin", "whitened", "log_inliers", "spread", "inlier_margin", "colour")
FALLBACK_FEATURES = ("cosine", "cosine_margin", "whitened", "colour")
# the calibration map's 3D-plausibility terms (size_features), after [bias, logit(p), textured]
SIZE_FEATURES = ("no_depth", "size_ratio", "has_ratio", "size_outside")


@dataclass
class LocalFeatures:
    """RootSIFT keypoints of one image: positions (N, 2) in its pixels (after ``scale``),
    descriptors (N, 128) float32, the image's side lengths and its colour histogram."""

    xy: np.ndarray
    desc: np.ndarray
    size: tuple[int, int]          # (rows, cols) of the image the keypoints are in
    hist: np.ndarray               # hue-saturation histogram, sums to 1

    @property
    def n(self) -> int:
        return len(self.xy)


def colour_histogram(rgb: np.ndarray, bins: tuple[int, int] = (12, 4)) -> np.ndarray:
    """Hue x saturation histogram (sums to 1) of the pixels with some saturation and brightness
    (grey pixels carry no hue), plus one bin for the grey ones; ``rgb`` uint8 RGB (grey and RGBA
    converted, anything else refused: a BGR image would swap red and blue hues)."""
    import cv2

    rgb = as_rgb(rgb, what="colour histogram image")
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV).reshape(-1, 3).astype(np.int32)
    grey = (hsv[:, 1] < 40) | (hsv[:, 2] < 40)
    h = np.minimum(hsv[~grey, 0] * bins[0] // 180, bins[0] - 1)
    s = np.minimum((hsv[~grey, 1] - 40) * bins[1] // 216, bins[1] - 1)
    out = np.bincount(h * bins[1] + s, minlength=bins[0] * bins[1]).astype(np.float64)
    out = np.append(out, grey.sum())
    return out / max(out.sum(), 1.0)


@dataclass
class ViewSet:
    """An instance's enrollment views stacked for matching: every view's descriptors in one array
    (view ``j``'s rows at ``offsets[j]:offsets[j + 1]``), so that a crop is matched against all of
    them in one product instead of one matcher call per view."""

    views: list[LocalFeatures]
    desc: np.ndarray               # (sum of the views' keypoints, 128) float32
    offsets: np.ndarray            # (len(views) + 1,) row offsets


def view_set(views: list[LocalFeatures]) -> ViewSet:
    """``views`` stacked (:class:`ViewSet`)."""
    desc = np.concatenate([v.desc for v in views] or [np.zeros((0, 128), np.float32)]).astype(np.float32)
    return ViewSet(list(views), np.ascontiguousarray(desc), np.cumsum([0] + [v.n for v in views]))


class Verifier:
    """Local features and geometric verification (see module doc). ``features`` of every
    enrollment view once, of each shortlisted crop once per frame; :meth:`best` compares a crop
    with an instance's views, :meth:`verify` with one view. With ``frontend.threads`` above 1,
    :meth:`map` runs such calls on that many threads (OpenCV releases the GIL; every call is
    independent and OpenCV's RANSAC seeds each call alike, so the results do not depend on it)."""

    def __init__(self, cfg: FrontendConfig):
        import threading

        self.cfg = cfg
        self._local = threading.local()       # one SIFT per thread
        self.pool = None
        if cfg.threads > 1:
            from concurrent.futures import ThreadPoolExecutor

            self.pool = ThreadPoolExecutor(cfg.threads, thread_name_prefix="egograph-verify")

    def map(self, fn, *args) -> list:
        """``[fn(*a) for a in zip(*args)]``, on the pool when there is one (order kept)."""
        return list(self.pool.map(fn, *args)) if self.pool is not None else list(map(fn, *args))

    def close(self) -> None:
        """Stop the pool's threads."""
        if self.pool is not None:
            self.pool.shutdown()
            self.pool = None

    def _sift(self):
        import cv2

        sift = getattr(self._local, "sift", None)
        if sift is None:
            sift = self._local.sift = cv2.SIFT_create(nfeatures=self.cfg.verify_max_keypoints,
                                                      contrastThreshold=self.cfg.verify_contrast)
        return sift

    def features(self, rgb: np.ndarray, order: str = "rgb") -> LocalFeatures:
        """RootSIFT of ``rgb`` (uint8 RGB, or BGR with ``order`` 'bgr'; grey and RGBA converted, anything
        else refused by :func:`~egograph.frontend.encoder.as_rgb`: the colour histogram must see
        the colours the enrollment's did) resampled so that its longer side is ``verify_side_px``
        (small crops are enlarged: SIFT's finest octave needs a few pixels per feature)."""
        import cv2

        rgb = as_rgb(rgb, order, "verification image")
        rows, cols = rgb.shape[:2]
        f = self.cfg.verify_side_px / max(rows, cols)
        img = cv2.resize(rgb, (max(1, round(cols * f)), max(1, round(rows * f))),
                         interpolation=cv2.INTER_AREA if f < 1 else cv2.INTER_LINEAR)
        grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
        if self.cfg.verify_stretch:
            grey = stretch(grey)
        kps, desc = self._sift().detectAndCompute(grey, None)
        if desc is None or not kps:
            xy, desc = np.zeros((0, 2), np.float32), np.zeros((0, 128), np.float32)
        else:
            xy = np.array([k.pt for k in kps], np.float32)
            desc = desc / np.maximum(desc.sum(axis=1, keepdims=True), 1e-7)   # RootSIFT: L1, then sqrt
            desc = np.sqrt(desc).astype(np.float32)
        return LocalFeatures(xy, desc, img.shape[:2], colour_histogram(img))

    def ratio_matches(self, crop: LocalFeatures, views: ViewSet) -> tuple[np.ndarray, np.ndarray]:
        """Lowe's ratio test of every view keypoint against the crop's: (each view row's nearest
        crop keypoint, whether it passes: nearest < ``verify_ratio`` x second-nearest L2 distance),
        OpenCV's brute-force 2-nearest search (``cv2.batchDistance``, which BFMatcher's knnMatch runs)
        in one call over all views: no per-match Python objects, and no BLAS threads that would
        spin against the verification's own."""
        import cv2

        if crop.n < 2 or not len(views.desc):
            return np.zeros(len(views.desc), np.intp), np.zeros(len(views.desc), bool)
        dist, idx = cv2.batchDistance(views.desc, np.ascontiguousarray(crop.desc, np.float32), cv2.CV_32F,
                                      normType=cv2.NORM_L2, K=2)
        return idx[:, 0].astype(np.intp), dist[:, 0] < self.cfg.verify_ratio * dist[:, 1]

    def homography(self, crop: LocalFeatures, view: LocalFeatures, src: np.ndarray, dst: np.ndarray
                   ) -> tuple[int, float]:
        """(inliers of a RANSAC homography from the ``view`` points ``src`` to the ``crop`` points
        ``dst``, the ratio test's matches in view keypoint order; their spread: the square root of
        their bounding box's share of the crop, 0-1). Fewer than 4 matches (or 4 distinct crop
        points), or a homography that folds the view or changes its scale by more than
        ``verify_max_scale``, count 0."""
        import cv2

        if len(src) < 4 or len(np.unique(dst.round(0), axis=0)) < 4:
            return 0, 0.0
        h, mask = cv2.findHomography(src, dst, cv2.RANSAC, self.cfg.verify_reproj_px, maxIters=500, confidence=0.99)
        if h is None or mask is None:
            return 0, 0.0
        det = float(np.linalg.det(h[:2, :2]))
        scale = np.sqrt(abs(det)) if det > 0 else 0.0
        ms = self.cfg.verify_max_scale
        if not (1.0 / ms <= scale * max(view.size) / max(crop.size) <= ms):
            return 0, 0.0
        ok = mask.ravel().astype(bool)
        n = int(ok.sum())
        if n < 4:
            return 0, 0.0
        pts = dst[ok]
        span = np.ptp(pts, axis=0) / np.maximum(np.array(crop.size[::-1], np.float32), 1.0)
        return n, float(np.sqrt(np.clip(span[0] * span[1], 0.0, 1.0)))

    def verify(self, crop: LocalFeatures, view: LocalFeatures) -> tuple[int, float]:
        """(inliers, spread) of ``view`` against ``crop`` (:meth:`ratio_matches`, :meth:`homography`)."""
        if crop.n < 2 or view.n < 2:
            return 0, 0.0
        nearest, good = self.ratio_matches(crop, view_set([view]))
        return self.homography(crop, view, view.xy[good], crop.xy[nearest[good]])

    def best(self, crop: LocalFeatures, vs: ViewSet) -> tuple[int, float, float]:
        """(most inliers over the views of ``vs``, their spread, best histogram intersection over the
        views), the views in their order; views after one with ``verify_enough`` inliers are not
        verified, nor one with fewer ratio-test matches than the inliers already found, or than the
        4 a homography needs (neither can change the result but the first: speed)."""
        best_n, best_s, col = 0, 0.0, 0.0
        nearest, good = self.ratio_matches(crop, vs)
        for j, v in enumerate(vs.views):
            col = max(col, float(np.minimum(crop.hist, v.hist).sum()))
            if best_n >= self.cfg.verify_enough:
                continue
            rows = np.flatnonzero(good[vs.offsets[j]:vs.offsets[j + 1]])
            if len(rows) < max(best_n, 4):
                continue
            n, s = self.homography(crop, v, v.xy[rows], crop.xy[nearest[vs.offsets[j] + rows]])
            if n > best_n or (n == best_n and s > best_s):
                best_n, best_s = n, s
        return best_n, best_s, col


def stretch(grey: np.ndarray, low: float = 1.0, high: float = 99.0) -> np.ndarray:
    """``grey`` (uint8) with its ``low``-``high`` percentile range stretched to 0-255. SIFT's
    contrast threshold is absolute: in a dark, low-contrast PV crop (the device's exposure) it finds
    almost no keypoint, in the same crop stretched as many as in a well-lit photograph."""
    lo, hi = np.percentile(grey, (low, high))
    if hi - lo < 1.0:
        return grey
    return np.clip((grey.astype(np.float32) - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)


def textured(f: LocalFeatures, crop_shape: tuple[int, int], cfg: FrontendConfig) -> bool:
    """Whether a crop has something to verify: enough keypoints and a short side (original pixels)
    of at least ``verify_min_side_px``."""
    return f.n >= cfg.verify_min_keypoints and min(crop_shape[:2]) >= cfg.verify_min_side_px


def probability(x: np.ndarray, coef) -> np.ndarray:
    """Logistic model ``1 / (1 + exp(-(b + w . x)))``: ``coef`` = [b, w1, ..., wn], ``x`` (N, n)."""
    c = np.asarray(coef, np.float64)
    z = c[0] + np.asarray(x, np.float64) @ c[1:]
    return 1.0 / (1.0 + np.exp(-np.clip(z, -40, 40)))


def size_features(size_m, enrolled_m, size_range_m) -> np.ndarray:
    """The calibration map's 3D-plausibility terms (N, len(SIZE_FEATURES)) of boxes whose size at
    the depth behind them is ``size_m`` (metres, NaN without depth) for instances enrolled at
    ``enrolled_m`` (metres, NaN when the enrollment box had no depth; MVPE photos have none):
    ``no_depth`` 1 without a size; ``size_ratio`` |log(size / enrolled)| capped at 2 (0 when
    either is missing); ``has_ratio`` 1 when both are known; ``size_outside`` how far (in log
    units) the size lies outside ``size_range_m`` = (low, high), 0 without depth. A wrong box is
    often a patch of clutter, a handle or a shelf, whose size at its depth no instance has."""
    s, e = np.broadcast_arrays(np.asarray(size_m, np.float64), np.asarray(enrolled_m, np.float64))
    has = np.isfinite(s) & (s > 0)
    both = has & np.isfinite(e) & (e > 0)
    safe_s = np.where(has, s, 1.0)
    ratio = np.where(both, np.minimum(np.abs(np.log(safe_s / np.where(both, e, 1.0))), 2.0), 0.0)
    lo, hi = (float(v) for v in size_range_m)
    outside = np.where(has, np.maximum(0.0, np.maximum(np.log(lo / safe_s), np.log(safe_s / hi))), 0.0)
    return np.stack([~has, ratio, both, outside], axis=-1).astype(np.float64)


def calibrate(p: np.ndarray, textured_: np.ndarray, coef, size_x: np.ndarray | None = None) -> np.ndarray:
    """The emitted probability: the pair model's ``p`` mapped by the calibration ``coef`` =
    [a, b, c, d...] as ``1 / (1 + exp(-(a + b logit(p) + c textured + d . size_x)))``, ``size_x``
    the 3D-plausibility terms of :func:`size_features` (``...`` x len(SIZE_FEATURES); None: no
    depth terms, ``coef``'s ``d`` ignored). The pair model is fitted on every shortlisted pair;
    the detections are each instance's most probable proposal, a selection on which a model
    fitted on few true pairs runs over- or under-confident, so the map is fitted on those
    candidates (``tools/fit_verify.py``); [0, 1, 0, 0, ...] is the identity. ``b`` > 0 keeps the
    order among crops alike in ``textured_`` and size."""
    q = np.clip(np.asarray(p, np.float64), 1e-9, 1 - 1e-9)
    c = np.asarray(coef, np.float64)
    z = c[0] + c[1] * np.log(q / (1 - q)) + c[2] * np.asarray(textured_, np.float64)
    if size_x is not None and len(c) > 3:
        z = z + np.asarray(size_x, np.float64) @ c[3:]
    return 1.0 / (1.0 + np.exp(-np.clip(z, -40, 40)))


def owned(prob: np.ndarray, listed: np.ndarray) -> np.ndarray:
    """(K, P) instance x proposal probabilities with -inf where the pair was not shortlisted or the
    proposal is more probably another instance (one proposal shows one object; ties to the first)."""
    owner = np.argmax(np.where(listed, prob, -np.inf), axis=0)
    mine = owner[None, :] == np.arange(prob.shape[0])[:, None]
    return np.where(listed & mine, prob, -np.inf)


def feature_rows(cos, cos_margin, white, inliers, spread, inlier_margin, colour) -> np.ndarray:
    """The model's inputs (N, len(FEATURES)) in :data:`FEATURES` order (inliers as log1p)."""
    return np.column_stack([cos, cos_margin, white, np.log1p(inliers), spread,
                            np.sign(inlier_margin) * np.log1p(np.abs(inlier_margin)), colour]).astype(np.float64)


def fallback_rows(full: np.ndarray) -> np.ndarray:
    """The fallback model's inputs: the :data:`FALLBACK_FEATURES` columns of ``full``."""
    return full[:, [FEATURES.index(k) for k in FALLBACK_FEATURES]]


def expected_calibration_error(p: np.ndarray, y: np.ndarray, bins: int = 10) -> float:
    """ECE: over ``bins`` equal-width probability bins, the share-weighted |mean p - share true|."""
    p, y = np.asarray(p, float), np.asarray(y, float)
    if not len(p):
        return float("nan")
    k = np.minimum((p * bins).astype(int), bins - 1)
    err = 0.0
    for b in range(bins):
        m = k == b
        if m.any():
            err += m.mean() * abs(p[m].mean() - y[m].mean())
    return float(err)
