"""The cached benchmark set and its one observation cache (egograph.synth.benchset)."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
from conftest import TINY

from egograph.core.config import load_config, to_dict
from egograph.io.poses import read_pose_json, write_pose_json
from egograph.io.recording import Recording
from egograph.poses.refine import apply_poses
from egograph.steps.settings import EgographConfig
from egograph.synth import benchset
from egograph.synth.benchset import (
    ANNOTATED_BOXES,
    BENCH_WORLDS,
    CODE_FILE,
    ORACLE,
    add_world_argument,
    benchmark_set,
    cached_observations,
    exact_poses_view,
    observations_key,
    observations_path,
    world_config,
)
from egograph.synth.config import SynthConfig
from egograph.synth.generate import DEVICE_REVISION

FRAMES = 20


@pytest.fixture(scope="module")
def tiny_set(tmp_path_factory):
    """Two 20-frame recordings of the tiny config, cached in a temporary folder."""
    cache = tmp_path_factory.mktemp("bench")
    return cache, benchmark_set([1, 2], FRAMES, config=TINY, cache=cache, progress=False)


def expected_key(root, cfg) -> str:
    """The key of a detection set lifted with the reported poses: front-end config and revision, lift
    knobs, io config and the lifting code's digest (nothing of the poses)."""
    meta = json.loads((root / "recording.json").read_text())
    parts = [meta["config"]["detections"], meta.get("frontend_revision", 1), cfg.lift.result_knobs(), to_dict(cfg.io),
             benchset.lift_code()]
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()[:12]


def refined_copy(root, folder, shift_m: float = 0.01):
    """A poses folder as ``egograph refine`` writes it: the reported poses shifted in x (metres)."""
    seq = next(p for p in root.iterdir() if (p / "pv_pose.json").is_file())
    folder.mkdir(exist_ok=True)
    for name in ("pv_pose.json", "depth_ahat_pose.json"):
        ts, poses, _ = read_pose_json(seq / name)
        poses = poses.copy()
        poses[:, 3, 0] += shift_m  # row vectors: translation in the last row
        write_pose_json(folder / name, ts, poses)
    return folder


def test_the_set_is_cached(tiny_set, capsys):
    cache, roots = tiny_set
    assert [r.name for r in roots] == ["seed1", "seed2"] and all((r / "recording.json").is_file() for r in roots)
    before = [(r / "recording.json").stat().st_mtime_ns for r in roots]
    assert benchmark_set([1, 2], FRAMES, config=TINY, cache=cache, progress=False) == roots
    assert "generating" not in capsys.readouterr().out
    assert [(r / "recording.json").stat().st_mtime_ns for r in roots] == before


def test_key_with_reported_poses_holds_no_poses_but_the_code(tiny_set):
    _, roots = tiny_set
    cfg = EgographConfig()
    for root in roots:
        rec = Recording.open(root)
        assert observations_key(rec, "svoe", cfg) == expected_key(root, cfg)
        assert observations_path(rec, "svoe", cfg).name == f"svoe_robust_{expected_key(root, cfg)}.npz"


@pytest.mark.parametrize("source", ["svoe", ORACLE, ANNOTATED_BOXES])
def test_key_changes_with_the_lifting_code_or_a_package_version(tiny_set, monkeypatch, source):
    # observations lifted by other code, or with another numpy, are not served as current
    rec, cfg = Recording.open(tiny_set[1][0]), EgographConfig()
    now = benchset.lift_code()
    before = observations_key(rec, source, cfg)
    monkeypatch.setattr(benchset, "lift_code", lambda: {**now, "modules": "0" * 16})
    assert observations_key(rec, source, cfg) != before
    monkeypatch.setattr(benchset, "lift_code", lambda: {**now, "packages": {**now["packages"], "numpy": "0.0"}})
    assert observations_key(rec, source, cfg) != before


def test_a_recording_made_by_other_code_is_made_again(tmp_path, capsys):
    roots = benchmark_set([3], FRAMES, config=TINY, cache=tmp_path, progress=False)
    code_file = roots[0] / CODE_FILE
    made = json.loads(code_file.read_text())
    assert made == benchset.generator_code()
    capsys.readouterr()
    # the generator's code changed: generated again, and the message says why
    code_file.write_text(json.dumps({**made, "recording": {**made["recording"], "modules": "0" * 16}}))
    benchmark_set([3], FRAMES, config=TINY, cache=tmp_path, progress=False)
    assert "generating benchmark recording seed 3" in (out := capsys.readouterr().out)
    assert "egograph code changed" in out
    assert json.loads(code_file.read_text()) == made
    # only the front-ends' code changed: detections re-simulated, the rest kept
    depth = sorted(roots[0].rglob("*.png"))[0]
    mtime = depth.stat().st_mtime_ns
    code_file.write_text(json.dumps({**made, "detections": {**made["detections"], "modules": "0" * 16}}))
    benchmark_set([3], FRAMES, config=TINY, cache=tmp_path, progress=False)
    out = capsys.readouterr().out
    assert "re-simulating detections of seed 3" in out and "generating" not in out
    assert depth.stat().st_mtime_ns == mtime and json.loads(code_file.read_text()) == made
    # a recording cached before code digests were kept is made again
    code_file.unlink()
    benchmark_set([3], FRAMES, config=TINY, cache=tmp_path, progress=False)
    assert "made before code digests were recorded" in capsys.readouterr().out


@pytest.mark.parametrize("source", ["svoe", ORACLE, ANNOTATED_BOXES])
def test_key_changes_with_the_poses(tiny_set, tmp_path, source):
    _, roots = tiny_set
    cfg = EgographConfig()
    rec = Recording.open(roots[0])
    key = observations_key(rec, source, cfg)
    assert observations_key(Recording.open(roots[0]), source, cfg) == key  # same poses, same key
    refined = apply_poses(rec, refined_copy(roots[0], tmp_path / "refined"))
    other = apply_poses(rec, refined_copy(roots[0], tmp_path / "other", 0.02))
    keys = {key, observations_key(refined, source, cfg), observations_key(other, source, cfg)}
    assert len(keys) == 3
    again = apply_poses(rec, tmp_path / "refined")  # the same refined poses again: the same key
    assert observations_key(again, source, cfg) == observations_key(refined, source, cfg)


def test_key_changes_with_the_depth_poses_alone(tiny_set):
    _, roots = tiny_set
    cfg = EgographConfig()
    rec = Recording.open(roots[0])
    key = observations_key(rec, "mvpe", cfg)
    rec.depth_poses[0, 3, 0] += 0.01  # edited in place
    assert observations_key(rec, "mvpe", cfg) != key


def test_key_changes_with_the_lift_config_but_not_decode_threads(tiny_set):
    _, roots = tiny_set
    rec = Recording.open(roots[0])
    cfg = EgographConfig()
    key = observations_key(rec, "svoe", cfg)
    cfg.lift.decode_threads = 1
    assert observations_key(rec, "svoe", cfg) == key
    cfg.lift.shrink = 0.4
    assert observations_key(rec, "svoe", cfg) != key
    cfg = EgographConfig()
    cfg.lift.mode = "reference"
    assert observations_key(rec, "svoe", cfg) != key
    assert observations_path(rec, "svoe", cfg).name.startswith("svoe_reference_")
    cfg = EgographConfig()
    cfg.io.box_format = "xywh"
    assert observations_key(rec, "svoe", cfg) != key


def test_sources_have_their_own_keys(tiny_set):
    _, roots = tiny_set
    rec = Recording.open(roots[0])
    cfg = EgographConfig()
    assert observations_key(rec, "svoe", cfg) == observations_key(rec, "mvpe", cfg)  # the name tells them apart
    assert observations_key(rec, ORACLE, cfg) == observations_key(rec, ANNOTATED_BOXES, cfg)
    assert observations_key(rec, ORACLE, cfg) != observations_key(rec, "svoe", cfg)  # no front-end config
    names = {observations_path(rec, s, cfg).name.split("_")[0] for s in ("svoe", "mvpe", ORACLE, ANNOTATED_BOXES)}
    assert names == {"svoe", "mvpe", "oracle", "boxes"}


def test_cached_observations_lift_once(tiny_set):
    _, roots = tiny_set
    rec = Recording.open(roots[1])
    cfg = EgographConfig()
    path = observations_path(rec, "mvpe", cfg)
    assert not path.exists()
    obs, report = cached_observations(rec, "mvpe", cfg)
    assert report is not None and path.is_file() and len(obs) > 0
    again, report = cached_observations(rec, "mvpe", cfg)
    assert report is None
    np.testing.assert_array_equal(again.world, obs.world)
    _, report = cached_observations(rec, "mvpe", cfg, relift=True)
    assert report is not None


def test_exact_poses_view_lifts_with_the_true_poses(tiny_set):
    """The view's observations are its own: lifted with the true poses, not read from the
    original's cache (both carry the poses of their own files, so their keys are equal)."""
    _, roots = tiny_set
    cfg = EgographConfig()
    rec = Recording.open(roots[0])
    obs, _ = cached_observations(rec, ORACLE, cfg)  # the original's cache is filled first
    view = exact_poses_view(roots[0])
    assert not (view / "observations").is_symlink()
    exact = Recording.open(view)
    assert observations_key(exact, ORACLE, cfg) == observations_key(rec, ORACLE, cfg)
    true_obs, report = cached_observations(exact, ORACLE, cfg)
    assert report is not None  # lifted, not read back
    ts, gt, _ = read_pose_json(roots[0] / "synth_gt" / rec.seq_dir.name / "pv_pose.json")
    np.testing.assert_array_equal(exact.pv_poses, gt)
    assert not np.allclose(true_obs.world, obs.world, atol=1e-4)  # the reported poses carry error
    np.testing.assert_array_equal(true_obs.timestamps, obs.timestamps)  # the same boxes


@pytest.mark.parametrize("world", BENCH_WORLDS)
@pytest.mark.parametrize("primary", ["svoe", "mvpe"])
def test_world_config_is_of_that_world(world, primary):
    cfg = load_config(SynthConfig, world_config(world, primary))
    assert cfg.world == world and cfg.detections.primary == primary


def test_bench_tools_build_in_the_device_world_unless_told():
    import argparse

    ap = argparse.ArgumentParser()
    add_world_argument(ap)
    assert ap.parse_args([]).world == "device" and ap.parse_args(["--world", "legacy"]).world == "legacy"
    with pytest.raises(ValueError, match="benchmark world"):
        world_config("lab")


def test_device_set_is_generated_in_the_device_world_beside_the_legacy_one(tiny_set):
    """The device world's recording of a seed lives under CACHE/device/ and records the device world; the
    legacy recording of the same seed and length stays where it was, untouched."""
    cache, roots = tiny_set
    before = (roots[0] / "recording.json").stat().st_mtime_ns
    (root,) = benchmark_set([1], FRAMES, config=world_config("device"), cache=cache, progress=False)
    assert root == cache / "device" / f"f{FRAMES}" / "seed1" and roots[0] == cache / f"f{FRAMES}" / "seed1"
    meta = json.loads((root / "recording.json").read_text())
    assert meta["config"]["world"] == "device" and meta["device_revision"] == DEVICE_REVISION
    assert json.loads((roots[0] / "recording.json").read_text())["config"].get("world", "legacy") == "legacy"
    assert (roots[0] / "recording.json").stat().st_mtime_ns == before


@pytest.mark.slow
@pytest.mark.parametrize("rgb", [False, True])
def test_a_set_built_in_parallel_is_the_same_bytes_as_one_built_in_turn(tmp_path, rgb):
    """tools/benchset.py --jobs 2 builds the recordings in processes of their own, on one thread each:
    the same files, byte for byte, in the seeds' order, as building them one after another."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
    from benchset import build

    def digests(root):
        return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted(root.rglob("*")) if p.is_file()}

    import os

    before = {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "LP_NUM_THREADS")}
    one = build([3, 4], 8, config=TINY, cache=tmp_path / "one", rgb=rgb, jobs=1)
    two = build([3, 4], 8, config=TINY, cache=tmp_path / "two", rgb=rgb, jobs=2)
    assert {k: os.environ.get(k) for k in before} == before        # the children's settings stay theirs
    assert [r.name for r in two] == ["seed3", "seed4"]
    for a, b in zip(one, two):
        assert digests(a) == digests(b) and len(digests(a)) > 5
