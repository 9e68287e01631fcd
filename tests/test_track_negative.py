"""Negative evidence: a place seen empty in depth (the object moved away, or had not arrived)."""

from __future__ import annotations

import numpy as np
import pytest

from egograph.core.config import load_config
from egograph.steps.lift import lift
from egograph.steps.recording import open_recording
from egograph.steps.settings import EgographConfig
from egograph.track.config import NegativeConfig
from egograph.track.negative import NegativeEvidence


@pytest.fixture(scope="module")
def moved(tiny_rec):
    """The tiny recording, its MVPE observations, and one instance that moves: (old, new) places."""
    cfg = load_config(EgographConfig, None)
    rec = open_recording(tiny_rec, cfg)
    obs, _ = lift(rec, "mvpe", cfg, progress=False)
    with np.load(rec.synth_gt_dir / "instances.npz") as d:
        pos, moving = d["positions"], d["moving"]
    inst = int(np.flatnonzero(moving.any(axis=0))[0])
    f_move = np.flatnonzero(moving[:, inst])
    return rec, obs, inst, pos[0, inst], pos[-1, inst], int(f_move.min()), int(f_move.max())


def test_new_place_is_seen_empty_before_the_object_arrives(moved):
    rec, obs, inst, old, new, f_pick, f_put = moved
    # On the tiny recording the wearer glances at the new place for only 3 frames before the
    # pick-up (they watch their hands), so every frame is tested and two empty ones suffice.
    ne = NegativeEvidence(rec, obs, NegativeConfig(min_frames=2, stride=1), 0.6)
    gone = ne(inst, new, 0, f_pick)
    assert gone is not None and gone < f_pick
    # ... and it is not empty once the object stands there
    assert ne(inst, new, f_put + 1, len(rec)) is None


def test_occupied_place_gives_no_negative_evidence(moved):
    rec, obs, inst, old, new, f_pick, f_put = moved
    ne = NegativeEvidence(rec, obs, NegativeConfig(), 0.6)
    assert ne(inst, old, 0, f_pick) is None
    verdicts = [ne.frame_verdict(old, f) for f in range(0, f_pick, 3) if ne._in_view(old, np.array([f]))[0]]
    assert verdicts and verdicts.count(-1) > len(verdicts) / 2


def test_a_point_in_mid_air_is_empty_once_in_view(moved):
    rec, obs, inst, old, new, f_pick, f_put = moved
    ne = NegativeEvidence(rec, obs, NegativeConfig(min_frames=2), 0.6)
    # 30 cm above where the object will stand: the depth sees the table behind it.
    air = new + np.array([0.0, 0.3, 0.0])
    f = ne(inst, air, 0, len(rec))
    assert f is not None
    assert ne.n_frames_read >= 2


def test_frames_without_depth_give_no_evidence(moved, monkeypatch):
    rec, obs, inst, old, new, f_pick, f_put = moved
    ne = NegativeEvidence(rec, obs, NegativeConfig(), 0.6)
    monkeypatch.setattr(rec, "depth_raw", lambda i: None)
    assert ne(inst, new, 0, f_pick) is None
