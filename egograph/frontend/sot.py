"""The paper's SOT re-purposing baseline: an OpenCV single-object tracker per instance, started
from its SVOE box, whose boxes become that instance's detections.

Online as the paper's pipeline: an instance has no box before its SVOE frame; from there each PV
frame updates the tracker (CSRT or KCF from OpenCV's contrib tracking module), and a frame where
it reports failure has no detection (the tracker keeps its model and may recover). Boxes in PV
pixels (x right, y down), clipped to the image; the score of a box is 1 (these trackers give no
calibrated confidence).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

METHODS = ("csrt", "kcf")


def make_tracker(method: str):
    """A fresh OpenCV tracker ``method`` (``csrt`` or ``kcf``)."""
    import cv2

    if method == "csrt":
        return cv2.TrackerCSRT.create()
    if method == "kcf":
        return cv2.TrackerKCF.create()
    raise ValueError(f"SOT method {method!r}: one of {', '.join(METHODS)}")


@dataclass
class SotState:
    """One instance's tracker: started at PV frame ``start`` from ``box`` (x1, y1, x2, y2)."""

    instance: int
    start: int
    box: tuple[float, float, float, float]
    tracker: object = None
    lost_frames: int = 0


def _xywh(box, width: int, height: int) -> tuple[int, int, int, int] | None:
    x1, y1 = max(0.0, box[0]), max(0.0, box[1])
    x2, y2 = min(float(width), box[2]), min(float(height), box[3])
    if x2 - x1 < 2 or y2 - y1 < 2:
        return None
    return int(round(x1)), int(round(y1)), max(2, int(round(x2 - x1))), max(2, int(round(y2 - y1)))


def step_frame(states: list[SotState], i: int, bgr: np.ndarray, method: str) -> list[tuple[int, tuple]]:
    """Advance every instance's tracker to PV frame ``i`` (``bgr``: the frame, OpenCV's BGR order);
    returns ``(instance, (x1, y1, x2, y2))`` of the boxes it reports in this frame."""
    h, w = bgr.shape[:2]
    out = []
    for s in states:
        if i < s.start:
            continue
        if i == s.start or s.tracker is None:
            if i != s.start:
                continue  # its SVOE frame could not be read: never started
            rect = _xywh(s.box, w, h)
            if rect is None:
                continue
            s.tracker = make_tracker(method)
            s.tracker.init(bgr, rect)
            x, y, bw, bh = rect
            out.append((s.instance, (float(x), float(y), float(x + bw), float(y + bh))))
            continue
        ok, (x, y, bw, bh) = s.tracker.update(bgr)
        if not ok or bw <= 1 or bh <= 1:
            s.lost_frames += 1
            continue
        x1, y1 = max(0.0, float(x)), max(0.0, float(y))
        x2, y2 = min(float(w), float(x + bw)), min(float(h), float(y + bh))
        if x2 - x1 >= 2 and y2 - y1 >= 2:
            out.append((s.instance, (x1, y1, x2, y2)))
    return out
