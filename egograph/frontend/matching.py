"""Enrollment (SVOE: one box in one PV frame; MVPE: photos) and cosine-similarity matching of
proposals against it, top-1 per instance per frame as the reference pipeline does."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from egograph.frontend.config import FrontendConfig


def crop(rgb: np.ndarray, box, margin: float = 0.0) -> np.ndarray | None:
    """The pixels of ``box`` (x1, y1, x2, y2; PV pixels) enlarged by ``margin`` x its side on each
    side, clipped to the image; None when nothing of the box is inside."""
    rows, cols = rgb.shape[:2]
    x1, y1, x2, y2 = (float(v) for v in box)
    mx, my = margin * (x2 - x1), margin * (y2 - y1)
    a, b = int(max(0, np.floor(x1 - mx))), int(min(cols, np.ceil(x2 + mx)))
    c, d = int(max(0, np.floor(y1 - my))), int(min(rows, np.ceil(y2 + my)))
    if b - a < 2 or d - c < 2:
        return None
    return rgb[c:d, a:b]


def svoe_views(rgb: np.ndarray, box, cfg: FrontendConfig) -> list[np.ndarray]:
    """Crops of the enrollment box: as given (with ``crop_margin``), and with ``svoe_augment`` its
    mirror image and the box scaled by 0.8 and 1.25 about its centre."""
    first = crop(rgb, box, cfg.crop_margin)
    if first is None:
        return []
    views = [first]
    if cfg.svoe_augment:
        views.append(first[:, ::-1].copy())
        x1, y1, x2, y2 = (float(v) for v in box)
        cx, cy, w, h = (x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1
        for s in (0.8, 1.25):
            c = crop(rgb, (cx - s * w / 2, cy - s * h / 2, cx + s * w / 2, cy + s * h / 2), cfg.crop_margin)
            if c is not None:
                views.append(c)
    return views


@dataclass
class Enrollment:
    """Unit embeddings of the views of each enrolled instance: ``views[instance]`` (V, D)."""

    views: dict[int, np.ndarray] = field(default_factory=dict)
    pooling: str = "mean"

    def similarity(self, emb: np.ndarray) -> dict[int, np.ndarray]:
        """Cosine similarity of each proposal embedding (P, D, unit rows) with each instance:
        ``mean`` pooling compares with the normalised mean of the views, ``max`` takes the best view."""
        out = {}
        for inst, v in self.views.items():
            if self.pooling == "max":
                out[inst] = (emb @ v.T).max(axis=1) if len(emb) else np.zeros(0, np.float32)
            else:
                mean = v.mean(axis=0)
                out[inst] = emb @ (mean / max(float(np.linalg.norm(mean)), 1e-12))
        return out


def pick(sims: np.ndarray, boxes: list, threshold: float, guide_uv=None, radius_px: float = 0.0) -> int | None:
    """Index of the proposal kept for one instance in one frame: the most similar one at or above
    ``threshold``; with ``guide_uv`` (the projection of a 3D estimate, PV pixels) and a radius, the
    above-threshold proposal whose centre is nearest to it when within ``radius_px`` (3D guidance)."""
    ok = np.nonzero(sims >= threshold)[0]
    if not len(ok):
        return None
    if guide_uv is not None and radius_px > 0:
        centres = np.array([[(boxes[k][0] + boxes[k][2]) / 2, (boxes[k][1] + boxes[k][3]) / 2] for k in ok])
        dist = np.linalg.norm(centres - np.asarray(guide_uv, float)[None], axis=1)
        j = int(np.argmin(dist))
        if dist[j] <= radius_px:
            return int(ok[j])
    return int(ok[np.argmax(sims[ok])])


def autocrop(photo: np.ndarray, margin: float, tol: float = 30.0) -> np.ndarray:
    """An enrollment photo cut to the object when it stands on a plain background: the pixels
    differing from the median border colour by more than ``tol`` (RGB distance, 0-255 units),
    their box enlarged by ``margin`` x its side; the photo itself when that is nothing or almost all."""
    border = np.concatenate([photo[0], photo[-1], photo[:, 0], photo[:, -1]]).astype(np.float32)
    fg = np.linalg.norm(photo.astype(np.float32) - np.median(border, axis=0), axis=2) > tol
    if fg.sum() < 16 or fg.mean() > 0.8:
        return photo
    vs, us = np.nonzero(fg)
    out = crop(photo, (us.min(), vs.min(), us.max() + 1, vs.max() + 1), margin)
    return photo if out is None else out
