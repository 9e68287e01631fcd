"""Session fixtures: small synthetic recordings built once and shared by every test module."""

from __future__ import annotations

import fcntl
import os
import shutil
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

from egograph.core.config import load_config
from egograph.core.resources import synth_config
from egograph.io.poses import read_pose_json, write_pose_json
from egograph.synth.config import SynthConfig
from egograph.synth.generate import generate

REPO = Path(__file__).resolve().parents[1]
TINY = synth_config("tiny")


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


def built_once(tmp_path_factory, name: str, build: Callable[[Path], None]) -> Path:
    """``name``'s folder, made by ``build(folder)`` once for the whole run: under pytest-xdist every
    worker process has its own session, so the first worker to ask builds it in the run's shared
    temporary folder (under a lock) and the others wait and read it. For recordings that tests only
    read: a 150-frame render costs 36 s, and three test files on different workers asked for it."""
    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base   # xdist: base is per worker
    root = shared / f"shared-{name}"
    with open(shared / f"shared-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)   # released when the file closes
        if not (root / ".built").is_file():
            shutil.rmtree(root, ignore_errors=True)   # a build a killed worker left half done
            build(root)
            (root / ".built").touch()
    return root


@pytest.fixture(scope="session")
def device_rec(tmp_path_factory) -> Path:
    """A 150-frame recording of the device world (synth/device-tiny, seed 2: one carry, frames 61-102,
    with the hand reaching for it, and fast head turns), with PV RGB frames. Read only: shared by the
    test workers (:func:`built_once`)."""
    cfg = load_config(SynthConfig, synth_config("device-tiny"), ["frames=150"])
    return built_once(tmp_path_factory, "device", lambda root: generate(root / "rec", cfg, seed=2, progress=False)) / "rec"


def sequence_dir(root: Path) -> Path:
    """The sequence folder of a recording root (the one holding ``pv_pose.json``)."""
    return next(p for p in root.iterdir() if (p / "pv_pose.json").is_file())


def true_poses(root: Path):
    """``(timestamps, pv, depth)``: the true row-vector poses of a synthetic recording (synth_gt)."""
    gt = root / "synth_gt" / sequence_dir(root).name
    ts, pv, _ = read_pose_json(gt / "pv_pose.json")
    _, depth, _ = read_pose_json(gt / "depth_ahat_pose.json")
    return ts, pv, depth


def copy_with_pose_error(src: Path, dst: Path, make_error, frames: int | None = None) -> Path:
    """Copy a recording, replacing its reported poses by ``truth @ make_error(ts, pv)[f]`` (row
    vectors: a world-frame error, the generator's model); only the first ``frames`` when given."""
    shutil.copytree(src, dst)
    ts, pv, depth = true_poses(dst)
    err = make_error(ts, pv)
    n = frames or len(ts)
    seq = sequence_dir(dst)
    write_pose_json(seq / "pv_pose.json", ts[:n], (pv @ err)[:n])
    write_pose_json(seq / "depth_ahat_pose.json", ts[:n], (depth @ err)[:n])
    return dst


def no_pose_error(ts, pv):
    return np.tile(np.eye(4), (len(ts), 1, 1))


@pytest.fixture(scope="session")
def exact_rec(tiny_rec, tmp_path_factory) -> Path:
    """The tiny recording with the true poses as the reported ones (pose error switched off)."""
    return copy_with_pose_error(tiny_rec, tmp_path_factory.mktemp("exact") / "rec", no_pose_error)
