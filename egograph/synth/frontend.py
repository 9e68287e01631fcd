"""Simulated appearance front-end (detector + instance matcher), per frame and instance.

It stands in for SAM + DINOv2 matching against the enrollment: for every instance it takes
the top-1 candidate region of the frame by similarity, as the IT3DEgo reference pipeline
does. Candidates are the instance itself, its look-alike twin, other instances and a few
persistent background spots that resemble it; detection probability falls with occlusion,
size and motion blur, and scores of true and false matches overlap around 0.6.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from egograph.synth.config import FrontEndConfig

SOURCE_TRUE, SOURCE_TWIN, SOURCE_OTHER, SOURCE_CLUTTER = "true", "twin", "other", "clutter"


@dataclass
class FrameView:
    """What the front-end can see in one PV frame (pixels, PV image)."""

    visible: np.ndarray        # (K,) visible share of each instance (occlusion and truncation), 0-1
    boxes: np.ndarray          # (K, 4) amodal boxes clipped to the image, NaN when not in view
    motion_dps: np.ndarray     # (K,) image-motion rate of each instance, deg/s
    clutter_boxes: np.ndarray  # (K, C, 4) boxes of each instance's clutter spots, NaN when not seen


@dataclass
class Candidate:
    instance: int
    box: np.ndarray
    score: float
    source: str
    source_id: int


def size_factor(cfg: FrontEndConfig, side: np.ndarray) -> np.ndarray:
    """Share of instances of a given box side (pixels) that region proposals + matching recover."""
    r = (side / cfg.size_half_px) ** cfg.size_exponent
    return r / (1.0 + r)


def detection_probability(cfg: FrontEndConfig, visible: np.ndarray, boxes: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """Probability (K,) that a region proposal covers each instance well enough to be matched."""
    side = np.sqrt(np.maximum((boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1]), 0))
    side = np.nan_to_num(side)
    vis = np.clip((visible - cfg.min_visible) / (1 - cfg.min_visible), 0, 1) ** 0.5
    size = size_factor(cfg, side)
    blur = 1.0 / (1.0 + (motion / cfg.blur_half_dps) ** 2)
    p = cfg.detect_rate * vis * size * blur
    short = np.nan_to_num(np.minimum(boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]))
    return np.where(np.isfinite(boxes[:, 0]) & (visible >= cfg.min_visible) & (short >= cfg.min_box_px), p, 0.0)


def jitter_box(rng: np.random.Generator, box: np.ndarray, frac: float, width: int, height: int) -> np.ndarray:
    w, h = box[2] - box[0], box[3] - box[1]
    b = box + rng.normal(0, frac, 4) * np.array([w, h, w, h])
    b = np.clip(b, 0, [width - 1, height - 1, width - 1, height - 1])
    b[2] = max(b[2], b[0] + 2)
    b[3] = max(b[3], b[1] + 2)
    return np.round(b, 1)


class FrontEnd:
    def __init__(self, rng: np.random.Generator, cfg: FrontEndConfig, twins: np.ndarray, image_size: tuple[int, int]):
        self.rng = rng
        self.cfg = cfg
        self.twins = np.asarray(twins)
        self.height, self.width = image_size
        k = len(twins)
        # Some clutter spots resemble the instance more than others, persistently.
        self.clutter_bias = rng.normal(0, 0.05, (k, cfg.clutter_per_instance))

    def frame(self, view: FrameView) -> list[Candidate]:
        """Top-1 candidate per instance (only those scoring at least ``min_written_score``)."""
        cfg, rng = self.cfg, self.rng
        k = len(view.visible)
        p_det = detection_probability(cfg, view.visible, view.boxes, view.motion_dps)
        fired = rng.random(k) < p_det
        side = np.nan_to_num(np.sqrt(np.maximum((view.boxes[:, 2] - view.boxes[:, 0]) * (view.boxes[:, 3] - view.boxes[:, 1]), 0)))
        quality = size_factor(cfg, side) / (1.0 + (view.motion_dps / cfg.blur_half_dps) ** 2)
        out = []
        for i in range(k):
            best: Candidate | None = None

            def offer(score: float, box: np.ndarray, source: str, sid: int):
                nonlocal best
                if best is None or score > best.score:
                    best = Candidate(i, box, float(score), source, sid)

            for j in range(k):
                if not fired[j]:
                    continue
                if j == i:
                    mean, std = cfg.true_score
                    source = SOURCE_TRUE
                elif j == self.twins[i]:
                    mean, std = cfg.lookalike_score
                    source = SOURCE_TWIN
                else:
                    mean, std = cfg.other_score
                    source = SOURCE_OTHER
                offer(rng.normal(mean, std) - 0.08 * (1 - quality[j]), view.boxes[j], source, j)
            cb = view.clutter_boxes[i]
            seen = np.isfinite(cb[:, 0]) & (rng.random(len(cb)) < cfg.clutter_rate)
            for c in np.flatnonzero(seen):
                mean, std = cfg.clutter_score
                offer(rng.normal(mean + self.clutter_bias[i, c], std), cb[c], SOURCE_CLUTTER, int(c))
            if best is not None and best.score >= cfg.min_written_score:
                best.box = jitter_box(rng, best.box, cfg.box_jitter, self.width, self.height)
                best.score = float(np.clip(round(best.score, 4), 0.0, 1.0))
                out.append(best)
        return out
