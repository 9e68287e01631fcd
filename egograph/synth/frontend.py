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
class Draws:
    """A front-end's random numbers for one frame (or many, stacked on a leading axis). Their shapes
    are fixed whatever the knobs, which only threshold or scale them (common random numbers)."""

    u_fire: np.ndarray     # (K,) uniform: whether a proposal covers the instance
    z_match: np.ndarray    # (K, K) normal: score noise of candidate instance j (column) for instance i (row)
    u_clutter: np.ndarray  # (K, C) uniform: whether each clutter spot is offered
    z_clutter: np.ndarray  # (K, C) normal: score noise of each clutter spot
    z_box: np.ndarray      # (K, 4) normal: box corner jitter of each instance's written box


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


def box_side(boxes: np.ndarray) -> np.ndarray:
    """Square-root area (pixels) of boxes (..., 4), 0 where there is no box (NaN)."""
    return np.nan_to_num(np.sqrt(np.maximum((boxes[..., 2] - boxes[..., 0]) * (boxes[..., 3] - boxes[..., 1]), 0)))


def detection_probability(cfg: FrontEndConfig, visible: np.ndarray, boxes: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """Probability (..., K) that a region proposal covers each instance well enough to be matched
    (``visible`` (..., K), ``boxes`` (..., K, 4) PV pixels, ``motion`` (..., K) deg/s)."""
    side = box_side(boxes)
    vis = np.clip((visible - cfg.min_visible) / (1 - cfg.min_visible), 0, 1) ** 0.5
    size = size_factor(cfg, side)
    blur = 1.0 / (1.0 + (motion / cfg.blur_half_dps) ** 2)
    p = cfg.detect_rate * vis * size * blur
    short = np.nan_to_num(np.minimum(boxes[..., 2] - boxes[..., 0], boxes[..., 3] - boxes[..., 1]))
    return np.where(np.isfinite(boxes[..., 0]) & (visible >= cfg.min_visible) & (short >= cfg.min_box_px), p, 0.0)


def jitter_boxes(z: np.ndarray, boxes: np.ndarray, frac: float, width: int, height: int) -> np.ndarray:
    """``boxes`` (..., 4) with their corners moved by ``frac`` x box size x standard normals ``z``
    (..., 4), kept in the image, at least 2 px wide and high, rounded to 0.1 px. PV pixels."""
    w, h = boxes[..., 2] - boxes[..., 0], boxes[..., 3] - boxes[..., 1]
    b = boxes + z * frac * np.stack([w, h, w, h], axis=-1)
    b = np.clip(b, 0, [width - 1, height - 1, width - 1, height - 1])
    b[..., 2] = np.maximum(b[..., 2], b[..., 0] + 2)
    b[..., 3] = np.maximum(b[..., 3], b[..., 1] + 2)
    return np.round(b, 1)


def jitter_box(z: np.ndarray, box: np.ndarray, frac: float, width: int, height: int) -> np.ndarray:
    """One box (4,) through :func:`jitter_boxes`."""
    return jitter_boxes(z[None], np.asarray(box)[None], frac, width, height)[0]


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

    def draws(self, index: int, n_clutter: int) -> Draws:
        """The random numbers of frame ``index`` (``n_clutter`` clutter spots per instance)."""
        k = len(self.twins)
        rng = self.frame_rng(index)
        # The order of the draws is part of the recordings: changing it changes every detection.
        return Draws(u_fire=rng.random(k), z_match=rng.standard_normal((k, k)), u_clutter=rng.random((k, n_clutter)),
                     z_clutter=rng.standard_normal((k, n_clutter)), z_box=rng.standard_normal((k, 4)))

    def top1(self, visible: np.ndarray, boxes: np.ndarray, motion: np.ndarray, clutter: np.ndarray,
             d: Draws) -> tuple[np.ndarray, np.ndarray]:
        """The best candidate of each instance and its similarity score, ``(best (..., K) int,
        score (..., K))``, from one frame's view and draws or from many stacked on a leading axis.

        ``best`` indexes the K instances, then the instance's C clutter spots (``K + c``); the score
        is -inf where no candidate was offered at all. ``visible`` (..., K) 0-1, ``boxes`` (..., K, 4)
        and ``clutter`` (..., K, C, 4) PV pixels (NaN: not in view), ``motion`` (..., K) deg/s.
        """
        cfg = self.cfg
        c = clutter.shape[-2]
        fired = d.u_fire < detection_probability(cfg, visible, boxes, motion)
        quality = size_factor(cfg, box_side(boxes)) / (1.0 + (motion / cfg.blur_half_dps) ** 2)
        match = self.match_mean + self.match_std * d.z_match - 0.08 * (1 - quality)[..., None, :]
        match = np.where(fired[..., None, :], match, -np.inf)
        seen = np.isfinite(clutter[..., 0]) & (d.u_clutter < cfg.clutter_rate)
        clutter_scores = np.where(seen, cfg.clutter_score[0] + self.clutter_bias[:, :c] + cfg.clutter_score[1] * d.z_clutter,
                                  -np.inf)
        scores = np.concatenate([match, clutter_scores], axis=-1)
        best = scores.argmax(axis=-1)  # first of equals, as offering candidates in order would keep
        return best, np.take_along_axis(scores, best[..., None], axis=-1)[..., 0]

    def sources(self, instance: np.ndarray, best: np.ndarray) -> np.ndarray:
        """What candidates ``best`` of :meth:`top1` are for ``instance`` (arrays of one shape):
        ``true``, ``twin``, ``other`` or ``clutter``."""
        instance, best = np.asarray(instance), np.asarray(best)
        k = len(self.twins)
        twin = self.twins[np.clip(instance, 0, k - 1)]
        return np.where(best >= k, SOURCE_CLUTTER, np.where(best == instance, SOURCE_TRUE,
                                                            np.where(best == twin, SOURCE_TWIN, SOURCE_OTHER)))

    def frame(self, view: FrameView, index: int) -> list[Candidate]:
        """Top-1 candidate per instance (only those scoring at least ``min_written_score``) in frame ``index``."""
        cfg = self.cfg
        k = len(view.visible)
        clutter = view.clutter_boxes[:, :cfg.clutter_per_instance]
        d = self.draws(index, clutter.shape[1])
        best, top = self.top1(view.visible, view.boxes, view.motion_dps, clutter, d)
        written = np.flatnonzero(top >= cfg.min_written_score)
        out = []
        for i, source in zip(written, self.sources(written, best[written])):
            j = int(best[i])
            box, sid = (view.boxes[j], j) if j < k else (clutter[i, j - k], j - k)
            box = jitter_box(d.z_box[i], box, cfg.box_jitter, self.width, self.height)
            out.append(Candidate(int(i), box, written_score(top[i]), str(source), sid))
        return out


def written_score(score: float) -> float:
    """The similarity as the detection files carry it: 4 decimals, clipped to 0-1."""
    return float(np.clip(round(float(score), 4), 0.0, 1.0))
