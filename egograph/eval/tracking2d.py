"""2D tracking metrics of a detection folder against ``2d_bbox_annot/`` (the paper's 2D table).

For every annotated (instance, PV frame) pair the detection of that instance in that frame is
compared with the true box (PV pixels); a missing detection has IoU 0 and an infinite centre
error. Pooled over every annotated pair of every instance (and per instance):

* ``auc``: success AUC, the mean over IoU thresholds 0, 0.05, ..., 1 of the share of pairs whose
  IoU exceeds the threshold (OTB/LaSOT), percent;
* ``precision_20px``: share of pairs whose centre error is at most 20 px, percent;
* ``norm_precision``: normalised precision (TrackingNet/LaSOT): the centre error with x divided by
  the true box's width and y by its height, the AUC of the share within thresholds 0 to 0.5
  (51 steps), percent.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

IOU_THRESHOLDS = np.linspace(0.0, 1.0, 21)
NORM_THRESHOLDS = np.linspace(0.0, 0.5, 51)


def iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of paired boxes ``(N, 4)`` x1 y1 x2 y2 (pixels); NaN rows of ``a`` give 0."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    iw = np.clip(np.minimum(a[:, 2], b[:, 2]) - np.maximum(a[:, 0], b[:, 0]), 0, None)
    ih = np.clip(np.minimum(a[:, 3], b[:, 3]) - np.maximum(a[:, 1], b[:, 1]), 0, None)
    inter = iw * ih
    union = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1]) + (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1]) - inter
    out = np.where(union > 0, inter / np.where(union > 0, union, 1), 0.0)
    return np.nan_to_num(out, nan=0.0)


@dataclass
class Track2dScores:
    """The three scores (percent) over ``n`` annotated pairs, ``n_detected`` of them with a box."""

    n: int
    n_detected: int
    auc: float
    precision_20px: float
    norm_precision: float
    per_instance: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"n": self.n, "n_detected": self.n_detected, "auc": self.auc, "precision_20px": self.precision_20px,
                "norm_precision": self.norm_precision,
                "per_instance": {str(k): v.as_dict() for k, v in self.per_instance.items()}}


def scores(pred: np.ndarray, gt: np.ndarray) -> Track2dScores:
    """Scores of predicted boxes ``pred`` (N, 4; NaN rows = no detection) against true ``gt`` (N, 4)."""
    pred, gt = np.asarray(pred, np.float64).reshape(-1, 4), np.asarray(gt, np.float64).reshape(-1, 4)
    n = len(gt)
    if n == 0:
        return Track2dScores(0, 0, float("nan"), float("nan"), float("nan"))
    have = np.isfinite(pred).all(axis=1)
    ov = np.where(have, iou(np.where(have[:, None], pred, 0), gt), 0.0)
    pc = 0.5 * (pred[:, :2] + pred[:, 2:])
    gc = 0.5 * (gt[:, :2] + gt[:, 2:])
    err = np.where(have, np.linalg.norm(pc - gc, axis=1), np.inf)
    size = np.maximum(gt[:, 2:] - gt[:, :2], 1e-9)
    nerr = np.where(have, np.linalg.norm((pc - gc) / size, axis=1), np.inf)
    auc = float(np.mean([(ov > t).mean() for t in IOU_THRESHOLDS]) * 100)
    p20 = float((err <= 20.0).mean() * 100)
    pn = float(np.mean([(nerr <= t).mean() for t in NORM_THRESHOLDS]) * 100)
    return Track2dScores(n, int(have.sum()), auc, p20, pn)


def pair_boxes(detections: dict, boxes: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``detections`` ``{ts: [Detection]}`` and ``boxes`` ``{instance: [(ts, Box)]}`` (2d_bbox_annot) ->
    ``(instance, pred (N, 4) with NaN where none, gt (N, 4))`` over every annotated pair. With several
    detections of one instance in a frame the highest-scoring one counts."""
    best: dict[tuple[int, int], object] = {}
    for ts, dets in detections.items():
        for d in dets:
            k = (int(ts), d.instance)
            if k not in best or d.score > best[k].score:
                best[k] = d
    inst, pred, gt = [], [], []
    for k, rows in boxes.items():
        for ts, b in rows:
            d = best.get((int(ts), int(k)))
            inst.append(int(k))
            gt.append((b.x_min, b.y_min, b.x_max, b.y_max))
            pred.append((np.nan,) * 4 if d is None else (d.box.x_min, d.box.y_min, d.box.x_max, d.box.y_max))
    return np.asarray(inst, np.int64), np.asarray(pred, np.float64).reshape(-1, 4), np.asarray(gt, np.float64).reshape(-1, 4)


def evaluate_2d(detections: dict, boxes: dict) -> Track2dScores:
    """Pooled and per-instance scores of a detection set against ``2d_bbox_annot`` boxes."""
    inst, pred, gt = pair_boxes(detections, boxes)
    out = scores(pred, gt)
    out.per_instance = {int(k): scores(pred[inst == k], gt[inst == k]) for k in np.unique(inst)}
    return out
