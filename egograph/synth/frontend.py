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
# Bumped whenever the same seed, views and knobs would give different detections, so cached
# recordings (egograph.synth.benchset) know to re-simulate their detections (recording.json "frontend_revision").
FRONTEND_REVISION = 2


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


def jitter_box(z: np.ndarray, box: np.ndarray, frac: float, width: int, height: int) -> np.ndarray:
    """``box`` with its corners moved by ``frac`` x box size x standard normals ``z`` (4,), kept in the image."""
    w, h = box[2] - box[0], box[3] - box[1]
    b = box + z * frac * np.array([w, h, w, h])
    b = np.clip(b, 0, [width - 1, height - 1, width - 1, height - 1])
    b[2] = max(b[2], b[0] + 2)
    b[3] = max(b[3], b[1] + 2)
    return np.round(b, 1)


class FrontEnd:
    """One front-end over a recording, with common random numbers.

    Every frame draws its random numbers from its own generator (the stream's seed plus the
    frame index) in fixed shapes, and the knobs only threshold or scale them. So the same
    seed gives the same draws whatever the knobs are: changing one knob changes the
    detections only where that knob matters, which is what calibrating the knobs needs
    (before, any knob change reshuffled every later draw of the recording).
    """

    def __init__(self, seed: np.random.SeedSequence, cfg: FrontEndConfig, twins: np.ndarray, image_size: tuple[int, int]):
        self.seed = seed
        self.cfg = cfg
        self.twins = np.asarray(twins)
        self.height, self.width = image_size
        k = len(twins)
        # Some clutter spots resemble the instance more than others, persistently.
        self.clutter_bias = np.random.default_rng(seed).normal(0, 0.05, (k, cfg.clutter_per_instance))
        # Mean and std of the score of candidate j (column) when matching instance i (row).
        mean = np.full((k, k), cfg.other_score[0])
        std = np.full((k, k), cfg.other_score[1])
        rows = np.flatnonzero(self.twins >= 0)
        mean[rows, self.twins[rows]], std[rows, self.twins[rows]] = cfg.lookalike_score
        np.fill_diagonal(mean, cfg.true_score[0])
        np.fill_diagonal(std, cfg.true_score[1])
        self.match_mean, self.match_std = mean, std

    def frame_rng(self, index: int) -> np.random.Generator:
        """The generator of frame ``index``: a child of the stream's seed, independent of other frames."""
        child = np.random.SeedSequence(self.seed.entropy, spawn_key=tuple(self.seed.spawn_key) + (index,),
                                       pool_size=self.seed.pool_size)
        return np.random.default_rng(child)

    def frame(self, view: FrameView, index: int) -> list[Candidate]:
        """Top-1 candidate per instance (only those scoring at least ``min_written_score``) in frame ``index``."""
        cfg = self.cfg
        k = len(view.visible)
        clutter = view.clutter_boxes[:, :cfg.clutter_per_instance]
        c = clutter.shape[1]
        rng = self.frame_rng(index)
        u_fire = rng.random(k)
        z_match = rng.standard_normal((k, k))
        u_clutter = rng.random((k, c))
        z_clutter = rng.standard_normal((k, c))
        z_box = rng.standard_normal((k, 4))

        fired = u_fire < detection_probability(cfg, view.visible, view.boxes, view.motion_dps)
        side = np.nan_to_num(np.sqrt(np.maximum((view.boxes[:, 2] - view.boxes[:, 0]) * (view.boxes[:, 3] - view.boxes[:, 1]), 0)))
        quality = size_factor(cfg, side) / (1.0 + (view.motion_dps / cfg.blur_half_dps) ** 2)
        match = self.match_mean + self.match_std * z_match - 0.08 * (1 - quality)[None, :]
        match[:, ~fired] = -np.inf
        seen = np.isfinite(clutter[..., 0]) & (u_clutter < cfg.clutter_rate)
        clutter_scores = np.where(seen, cfg.clutter_score[0] + self.clutter_bias[:, :c] + cfg.clutter_score[1] * z_clutter,
                                  -np.inf)
        scores = np.concatenate([match, clutter_scores], axis=1)
        best = scores.argmax(axis=1)  # first of equals, as offering candidates in order would keep
        out = []
        for i in np.flatnonzero(scores[np.arange(k), best] >= cfg.min_written_score):
            j = int(best[i])
            if j < k:
                source = SOURCE_TRUE if j == i else SOURCE_TWIN if j == self.twins[i] else SOURCE_OTHER
                box, sid = view.boxes[j], j
            else:
                source, box, sid = SOURCE_CLUTTER, clutter[i, j - k], j - k
            box = jitter_box(z_box[i], box, cfg.box_jitter, self.width, self.height)
            out.append(Candidate(int(i), box, float(np.clip(round(float(scores[i, j]), 4), 0.0, 1.0)), source, sid))
        return out
