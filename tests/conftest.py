"""Session fixtures: small synthetic recordings built once and shared by every test module."""

from __future__ import annotations

from pathlib import Path

import pytest

from egograph.config import load_config
from egograph.synth.config import SynthConfig
from egograph.synth.generate import generate

REPO = Path(__file__).resolve().parents[1]
TINY = REPO / "configs" / "synth" / "tiny.yaml"


def make_recording(root: Path, seed: int, *overrides: str) -> Path:
    cfg = load_config(SynthConfig, TINY, list(overrides))
    generate(root, cfg, seed=seed, progress=False)
    return root


@pytest.fixture(scope="session")
def tiny_rec(tmp_path_factory) -> Path:
    """A 240-frame synthetic recording (depth, poses, annotations, detections; no RGB)."""
    return make_recording(tmp_path_factory.mktemp("tiny") / "rec", 7, "pv.rgb=false")


@pytest.fixture(scope="session")
def tiny_rgb_rec(tmp_path_factory) -> Path:
    """A 30-frame synthetic recording with PV RGB frames."""
    return make_recording(tmp_path_factory.mktemp("tiny_rgb") / "rec", 3, "frames=30")
