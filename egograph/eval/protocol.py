"""The IT3DEgo per-frame counting protocol, exactly as the public reference code counts.

Reference loop (``demo_sam+dinov2_svoe.ipynb``, step 4), restated:

* every PV frame of the sequence counts (the sorted keys of ``pv_pose.json``);
* per frame the predictions are a dict ``instance -> xyz`` (a later line for the
  same instance overwrites an earlier one); ``n_pred += len(predictions)``;
* for every GT interval ``[t_start, t_end]`` (100 ns ticks, inclusive at both
  ends) covering the frame: ``n_gt += 1``; no prediction for its instance ->
  FN at every threshold; else, per threshold τ (metres), TP if ``d <= τ``, else
  FP and FN; the instance is appended to a ``matched`` list (twice if two of its
  intervals cover the frame);
* then ``FP += len(predictions) - len(matched)`` at every τ.

Precision = TP / n_pred, recall = TP / n_gt, summed over all frames of all
sequences. On top of the reference counts this module accumulates the L2 error
(metres) and the angular error (radians, seen from the PV camera centre) over
the (frame, covering GT interval) pairs that have a prediction, and PCL@0.3 m.

Everything is additive over frames, so the loop is evaluated per GT interval
with numpy masks over the frame axis instead of frame by frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np

THRESHOLDS: tuple[float, ...] = (0.25, 0.5, 0.75, 1.0, 1.5)  # metres
PCL_RADIUS = 0.3  # metres: "position correctly localised" radius

# Distances closer than this (relative) to a threshold are recomputed exactly as the
# reference does (``np.linalg.norm`` of one 3-vector), so ``d <= τ`` decides the same way
# even where the vectorised sum of squares differs from it in the last bit.
_TIE_RTOL = 1e-9


@dataclass(frozen=True)
class GtInterval:
    """Ground truth: ``instance`` stood at ``xyz`` (world frame, metres) over
    ``[t_start, t_end]`` (100 ns ticks, inclusive at both ends)."""

    instance: int
    t_start: int
    t_end: int
    xyz: tuple[float, float, float]

    def __post_init__(self) -> None:
        object.__setattr__(self, "instance", int(self.instance))
        object.__setattr__(self, "t_start", int(self.t_start))
        object.__setattr__(self, "t_end", int(self.t_end))
        xyz = tuple(float(v) for v in self.xyz)
        if len(xyz) != 3:
            raise ValueError(f"xyz must have 3 values, got {len(xyz)}")
        object.__setattr__(self, "xyz", xyz)
        if self.t_end < self.t_start:
            raise ValueError(f"t_end {self.t_end} is before t_start {self.t_start}")

    def covers(self, ts: int) -> bool:
        """True when frame ``ts`` (ticks) lies in ``[t_start, t_end]``."""
        return self.t_start <= ts <= self.t_end


def _zeros(n: int) -> np.ndarray:
    return np.zeros(n, dtype=np.int64)


@dataclass
class Counts:
    """Additive evaluation counts; ``tp``, ``fp``, ``fn`` are aligned with ``thresholds``.

    ``l2_sum`` (metres) and ``angle_sum`` (radians) are sums over ``l2_n`` and
    ``angle_n`` (frame, covering GT interval) pairs with a prediction;
    ``pcl_hits`` counts the (frame, GT interval) pairs with a prediction within
    :data:`PCL_RADIUS`. Ratios with a zero denominator are reported as 0.0; the
    denominators (``n_pred``, ``n_gt``, ``l2_n``, ``angle_n``) are kept to say so.
    """

    thresholds: tuple[float, ...] = THRESHOLDS
    tp: np.ndarray = None  # type: ignore[assignment]
    fp: np.ndarray = None  # type: ignore[assignment]
    fn: np.ndarray = None  # type: ignore[assignment]
    n_gt: int = 0
    n_pred: int = 0
    l2_sum: float = 0.0
    l2_n: int = 0
    angle_sum: float = 0.0
    angle_n: int = 0
    pcl_hits: int = 0

    def __post_init__(self) -> None:
        self.thresholds = tuple(float(t) for t in self.thresholds)
        k = len(self.thresholds)
        for name in ("tp", "fp", "fn"):
            value = getattr(self, name)
            arr = _zeros(k) if value is None else np.asarray(value, dtype=np.int64).copy()
            if arr.shape != (k,):
                raise ValueError(f"{name} must have {k} entries (one per threshold), got shape {arr.shape}")
            setattr(self, name, arr)

    def __add__(self, other: Counts) -> Counts:
        if not isinstance(other, Counts):
            return NotImplemented
        if other.thresholds != self.thresholds:
            raise ValueError(f"cannot add counts for thresholds {self.thresholds} and {other.thresholds}")
        return Counts(
            thresholds=self.thresholds,
            tp=self.tp + other.tp,
            fp=self.fp + other.fp,
            fn=self.fn + other.fn,
            n_gt=self.n_gt + other.n_gt,
            n_pred=self.n_pred + other.n_pred,
            l2_sum=self.l2_sum + other.l2_sum,
            l2_n=self.l2_n + other.l2_n,
            angle_sum=self.angle_sum + other.angle_sum,
            angle_n=self.angle_n + other.angle_n,
            pcl_hits=self.pcl_hits + other.pcl_hits,
        )

    def __radd__(self, other) -> Counts:
        if isinstance(other, int) and other == 0:  # so that sum([...]) works
            return self
        return self.__add__(other)

    def __eq__(self, other) -> bool:
        if not isinstance(other, Counts):
            return NotImplemented
        return (
            self.thresholds == other.thresholds
            and np.array_equal(self.tp, other.tp)
            and np.array_equal(self.fp, other.fp)
            and np.array_equal(self.fn, other.fn)
            and (self.n_gt, self.n_pred, self.l2_n, self.angle_n, self.pcl_hits)
            == (other.n_gt, other.n_pred, other.l2_n, other.angle_n, other.pcl_hits)
            and self.l2_sum == other.l2_sum
            and self.angle_sum == other.angle_sum
        )

    @property
    def precision(self) -> np.ndarray:
        """TP / n_pred per threshold (fractions 0-1); zeros when ``n_pred == 0``."""
        return _ratio(self.tp, self.n_pred)

    @property
    def recall(self) -> np.ndarray:
        """TP / n_gt per threshold (fractions 0-1); zeros when ``n_gt == 0``."""
        return _ratio(self.tp, self.n_gt)

    @property
    def l2_m(self) -> float:
        """Mean L2 error (metres) over pairs with a prediction; 0.0 when ``l2_n == 0``."""
        return self.l2_sum / self.l2_n if self.l2_n else 0.0

    @property
    def angle_rad(self) -> float:
        """Mean angular error (radians) seen from the PV camera; 0.0 when ``angle_n == 0``."""
        return self.angle_sum / self.angle_n if self.angle_n else 0.0

    @property
    def pcl(self) -> float:
        """Share of (frame, GT) pairs with a prediction within 0.3 m; 0.0 when ``n_gt == 0``."""
        return self.pcl_hits / self.n_gt if self.n_gt else 0.0


def _ratio(num: np.ndarray, den: int) -> np.ndarray:
    num = np.asarray(num, dtype=np.float64)
    return num / den if den else np.zeros_like(num)


@dataclass
class SequenceResult:
    """Counts of one sequence: ``total`` and per instance id.

    ``per_instance`` holds every instance that has a GT interval or a prediction;
    its counts add up exactly to ``total`` (an instance's FP includes its
    predictions that no GT interval of it covered). ``n_frames`` is the number
    of PV frames evaluated.
    """

    total: Counts
    per_instance: dict[int, Counts] = field(default_factory=dict)
    n_frames: int = 0


# --------------------------------------------------------------------------- helpers


def _prediction_arrays(
    ts: np.ndarray, predictions: Mapping[int, Mapping[int, Sequence[float]]]
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """instance -> (has_pred (N,) bool, xyz (N, 3) float64, NaN where absent), on the frame axis."""
    index = {int(t): i for i, t in enumerate(ts)}
    n = len(ts)
    out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for t, per_frame in predictions.items():
        i = index.get(int(t))
        if i is None:  # not a PV frame: the reference never opens it
            continue
        for inst, xyz in per_frame.items():
            inst = int(inst)
            if inst not in out:
                out[inst] = (np.zeros(n, dtype=bool), np.full((n, 3), np.nan))
            has, pos = out[inst]
            has[i] = True
            value = np.asarray(xyz, dtype=np.float64).reshape(3)
            if not np.isfinite(value).all():
                raise ValueError(f"prediction of instance {inst} at {int(t)} is not finite: {value}")
            pos[i] = value
    return out


def _distances(gt_xyz: np.ndarray, pred: np.ndarray, thresholds: Sequence[float]) -> np.ndarray:
    """Euclidean distances (metres) from one GT point to predictions (M, 3), as the reference computes them."""
    diff = gt_xyz[None, :] - pred
    d = np.sqrt(np.einsum("ij,ij->i", diff, diff))
    thr = np.asarray(thresholds, dtype=np.float64)
    if len(d) and len(thr):
        near = (np.abs(d[:, None] - thr[None, :]) <= _TIE_RTOL * np.maximum(thr, 1.0)).any(axis=1)
        for j in np.flatnonzero(near):
            d[j] = np.linalg.norm(gt_xyz - pred[j])
    return d


def angular_errors(gt_xyz: np.ndarray, pred_xyz: np.ndarray, centers: np.ndarray) -> np.ndarray:
    """Angles (radians, 0..π) between ``gt - c`` and ``pred - c`` for rows of (M, 3) arrays.

    Computed as ``atan2(|u × v|, u · v)`` (stable near 0 and π); a degenerate
    direction (point at the camera centre) gives 0.
    """
    u = np.asarray(gt_xyz, dtype=np.float64) - centers
    v = np.asarray(pred_xyz, dtype=np.float64) - centers
    cross = np.linalg.norm(np.cross(u, v), axis=-1)
    dot = np.einsum("ij,ij->i", u, v)
    return np.arctan2(cross, dot)


# --------------------------------------------------------------------------- evaluation


def evaluate_sequence(
    timestamps: Sequence[int] | np.ndarray,
    gt: Iterable[GtInterval],
    predictions: Mapping[int, Mapping[int, Sequence[float]]],
    camera_centers: np.ndarray | None = None,
    thresholds: Sequence[float] = THRESHOLDS,
) -> SequenceResult:
    """Count one sequence exactly as the IT3DEgo reference evaluator does.

    ``timestamps``: every PV frame (100 ns ticks); ``gt``: the GT intervals;
    ``predictions``: ``ts -> instance -> xyz`` (world frame, metres; a frame
    missing from the mapping has no predictions; keys that are not PV frames are
    ignored); ``camera_centers``: (N, 3) PV camera centres aligned with
    ``timestamps`` (NaN rows = invalid pose, skipped for the angle only), or
    None to skip the angular error; ``thresholds`` in metres.
    """
    thresholds = tuple(float(t) for t in thresholds)
    ts = np.asarray([int(t) for t in timestamps], dtype=np.int64)
    if len(np.unique(ts)) != len(ts):
        raise ValueError("timestamps contain duplicates")
    n = len(ts)
    centers = None
    if camera_centers is not None:
        centers = np.asarray(camera_centers, dtype=np.float64)
        if centers.shape != (n, 3):
            raise ValueError(f"camera_centers must have shape ({n}, 3), got {centers.shape}")
    center_ok = None if centers is None else np.isfinite(centers).all(axis=1)

    pred = _prediction_arrays(ts, predictions)
    gt = list(gt)
    instances = sorted({g.instance for g in gt} | set(pred))
    per: dict[int, Counts] = {i: Counts(thresholds) for i in instances}
    matched = {i: 0 for i in instances}  # (frame, interval) pairs with a prediction
    thr = np.asarray(thresholds)

    for g in gt:
        c = per[g.instance]
        covered = (ts >= g.t_start) & (ts <= g.t_end)
        n_cov = int(covered.sum())
        c.n_gt += n_cov
        if g.instance in pred:
            has, pos = pred[g.instance]
            hit = covered & has
        else:
            hit = np.zeros(n, dtype=bool)
        n_hit = int(hit.sum())
        c.fn += n_cov - n_hit  # no prediction: FN at every threshold
        matched[g.instance] += n_hit
        if not n_hit:
            continue
        gxyz = np.asarray(g.xyz, dtype=np.float64)
        pxyz = pred[g.instance][1][hit]
        d = _distances(gxyz, pxyz, thresholds)
        ok = (d[:, None] <= thr[None, :]).sum(axis=0)
        c.tp += ok
        c.fp += n_hit - ok
        c.fn += n_hit - ok
        c.l2_sum += float(d.sum())
        c.l2_n += n_hit
        c.pcl_hits += int((d <= PCL_RADIUS).sum())
        if centers is not None:
            good = center_ok[hit]
            if good.any():
                ang = angular_errors(np.broadcast_to(gxyz, pxyz[good].shape), pxyz[good], centers[hit][good])
                c.angle_sum += float(ang.sum())
                c.angle_n += int(good.sum())

    for inst, (has, _) in pred.items():
        c = per[inst]
        n_p = int(has.sum())
        c.n_pred += n_p
        c.fp += n_p - matched[inst]  # reference: FP += len(preds) - len(matched), every threshold

    total = sum(per.values(), Counts(thresholds))
    return SequenceResult(total=total, per_instance=per, n_frames=n)

