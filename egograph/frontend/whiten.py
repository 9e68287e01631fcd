"""Whitened matching: cosine similarity after decorrelating the embeddings with the statistics of
the recording's own proposals (the background).

Generic ImageNet features put most crops close together: on the synthetic benchmark nearly every
proposal lies within cosine 0.6 of an SVOE enrollment, so the paper's threshold passes clutter as
readily as the object. Subtracting the background mean and whitening by the background covariance
(shrunk towards a multiple of the identity) turns the cosine into a discriminative score, the
"exemplar LDA" of Hariharan, Malik and Ramanan (ECCV 2012): directions every crop varies along
count little, the ones that set the enrollment apart from the background count much. The statistics
come from the proposals of a sample of the recording's PV frames, so no label and no other data is
needed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Whitening:
    """``x -> unit((x - mean) @ transform)`` for embeddings ``x`` (N, D)."""

    mean: np.ndarray         # (D,)
    transform: np.ndarray    # (D, D), symmetric
    samples: int             # background embeddings the statistics came from

    def __call__(self, emb: np.ndarray) -> np.ndarray:
        x = (np.asarray(emb, np.float64) - self.mean) @ self.transform
        return (x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-12)).astype(np.float32)


def fit_whitening(background: np.ndarray, shrink: float) -> Whitening:
    """Whitening fitted to ``background`` embeddings (N, D): covariance C shrunk as
    ``(1 - shrink) C + shrink tr(C)/D I`` (shrink in (0, 1]: with fewer samples than dimensions C
    alone is singular), transform ``C^(-1/2)``. Raises ValueError with fewer than 2 samples."""
    x = np.asarray(background, np.float64)
    if x.ndim != 2 or len(x) < 2:
        raise ValueError(f"whitening needs at least 2 background embeddings, got {len(x) if x.ndim == 2 else 0}")
    mean = x.mean(axis=0)
    c = np.cov(x - mean, rowvar=False, bias=True)
    d = c.shape[0]
    c = (1.0 - shrink) * c + shrink * float(np.trace(c)) / d * np.eye(d)
    w, v = np.linalg.eigh(c)
    w = np.maximum(w, 1e-12 * max(float(w.max()), 1e-300))
    return Whitening(mean, (v * w ** -0.5) @ v.T, len(x))
