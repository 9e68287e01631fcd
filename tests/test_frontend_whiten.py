"""Whitened matching (egograph.frontend.whiten): background statistics decorrelate the embeddings,
so an enrollment that differs from the clutter only along a direction the clutter barely varies in
stands apart once whitened, though the plain cosine calls everything alike."""

from __future__ import annotations

import numpy as np
import pytest

from egograph.frontend.whiten import fit_whitening


def unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def test_whitened_background_has_unit_covariance():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(16, 16))
    x = rng.normal(size=(20000, 16)) @ a + 3.0
    w = fit_whitening(x, shrink=1e-9)
    z = (x - w.mean) @ w.transform
    assert np.allclose(z.mean(axis=0), 0, atol=1e-9)
    assert np.allclose(np.cov(z, rowvar=False, bias=True), np.eye(16), atol=1e-6)
    assert w.samples == 20000


def test_whitening_separates_what_the_plain_cosine_cannot():
    rng = np.random.default_rng(1)
    d = 64
    common = unit(rng.normal(size=d))                 # what every crop shares (an ImageNet "object-ness")
    rare = unit(rng.normal(size=d) - (rng.normal(size=d) @ common) * common)
    clutter = unit(5 * common + rng.normal(size=(400, d)) * 0.3 - 0.3 * rare * (rng.random((400, 1)) < 2))
    target = unit(5 * common + rng.normal(size=(5, d)) * 0.3 + 2.0 * rare)   # views of the object
    query_true = unit(5 * common + rng.normal(size=(50, d)) * 0.3 + 2.0 * rare)
    query_false = clutter[:50]
    plain = lambda q: q @ unit(target.mean(axis=0))
    assert plain(query_false).min() > 0.6                          # the paper's 0.6 passes all the clutter
    w = fit_whitening(clutter, shrink=0.1)
    proto = unit(w(target).mean(axis=0))
    white_true, white_false = w(query_true) @ proto, w(query_false) @ proto
    assert np.allclose(np.linalg.norm(w(query_true), axis=1), 1, atol=1e-6)
    assert white_true.min() > white_false.max()                    # whitened, one threshold separates them
    assert np.median(plain(query_true)) - np.median(plain(query_false)) < np.median(white_true) - np.median(white_false)


def test_whitening_needs_two_samples():
    with pytest.raises(ValueError, match="at least 2"):
        fit_whitening(np.zeros((1, 8)), shrink=0.3)
