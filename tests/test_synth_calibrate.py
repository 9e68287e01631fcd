"""The front-end calibration harness (egograph.synth.calibrate) gives exactly what generating the
detections and lifting them with the reference rule gives, at any setting of the free knobs."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from egograph.core.config import load_config
from egograph.core.resources import default_config
from egograph.geometry.lift import lift_recording
from egograph.io.detections import read_detection_dir
from egograph.steps.recording import open_recording
from egograph.steps.settings import EgographConfig
from egograph.synth import calibrate as cal
from egograph.synth.config import SynthConfig
from egograph.synth.frontend import jitter_box, jitter_boxes
from egograph.synth.generate import redetect

from conftest import TINY

FIELDS = ("timestamps", "frame", "instance", "score", "box", "world", "camera", "range_m", "chosen")
SETTINGS = [
    [],
    ["detections.svoe.true_score=[0.55,0.1]", "detections.svoe.clutter_rate=0.7", "detections.svoe.detect_rate=0.9",
     "detections.mvpe.clutter_score=[0.55,0.05]", "detections.mvpe.size_half_px=120",
     "detections.mvpe.lookalike_score=[0.7,0.05]"],
]


@pytest.fixture(scope="module")
def calib_rec(tiny_rec, tmp_path_factory):
    """A copy of the tiny recording (its detections are re-simulated here), opened for reference lifting."""
    root = tmp_path_factory.mktemp("calib") / "rec"
    shutil.copytree(tiny_rec, root)
    cfg = load_config(EgographConfig, default_config(), ["lift.mode=reference"])
    return root, cfg, open_recording(root, cfg)


@pytest.fixture(scope="module")
def tables(calib_rec):
    _, cfg, rec = calib_rec
    scfg = load_config(SynthConfig, TINY, [])
    return cal.candidate_tables(rec, {s: getattr(scfg.detections, s) for s in ("svoe", "mvpe")}, cfg.lift)


def test_jitter_boxes_is_jitter_box_per_box():
    rng = np.random.default_rng(3)
    boxes = np.sort(rng.uniform(0, 1300, (50, 2, 2)), axis=1).transpose(0, 2, 1).reshape(50, 4)
    z = rng.standard_normal((50, 4))
    many = jitter_boxes(z, boxes, 0.35, 1280, 720)
    assert np.array_equal(many, np.stack([jitter_box(z[i], boxes[i], 0.35, 1280, 720) for i in range(50)]))
    assert (many[:, 2] >= many[:, 0] + 2).all() and (many[:, 3] >= many[:, 1] + 2).all()


@pytest.mark.slow
@pytest.mark.parametrize("overrides", SETTINGS, ids=["tiny", "changed-knobs"])
def test_table_equals_generating_and_lifting(calib_rec, tables, overrides):
    root, cfg, rec = calib_rec
    scfg = load_config(SynthConfig, TINY, overrides)
    redetect(root, scfg)  # the real way: detections written by the generator's front-end ...
    seq = cal.annotated_sequence(rec)
    for det_set in ("svoe", "mvpe"):
        fe = getattr(scfg.detections, det_set)
        dets = read_detection_dir(root / "detections" / rec.name / det_set, rec.timestamps)
        real, _ = lift_recording(rec, dets, cfg.lift, progress=False)  # ... and lifted by the reference rule
        obs, source = cal.simulate_observations(tables[det_set], fe)
        assert len(obs) == len(real) > 20
        for name in FIELDS:
            assert np.array_equal(getattr(obs, name), getattr(real, name), equal_nan=True), (det_set, name)
        assert cal.memory_counts(seq, obs, cfg.track) == cal.memory_counts(seq, real, cfg.track)
        # the sources are the generator's truth lines, row for row
        truth = [ln.split() for ln in (rec.synth_gt_dir / f"detections_{det_set}.txt").read_text().splitlines()
                 if ln and not ln.startswith("#")]
        assert list(source) == [t[3] for t in truth]


@pytest.mark.slow
def test_table_refuses_other_table_knobs_and_round_trips(calib_rec, tables, tmp_path):
    _, cfg, rec = calib_rec
    scfg = load_config(SynthConfig, TINY, ["detections.svoe.box_jitter=0.5"])
    with pytest.raises(ValueError, match="box_jitter"):
        cal.simulate_observations(tables["svoe"], scfg.detections.svoe)
    base = load_config(SynthConfig, TINY, [])
    cal.save_table(tables["mvpe"], tmp_path / "mvpe")
    back = cal.load_table(rec, tmp_path / "mvpe", "mvpe", base.detections.mvpe)
    a, _ = cal.simulate_observations(tables["mvpe"], base.detections.mvpe)
    b, _ = cal.simulate_observations(back, base.detections.mvpe)
    for name in FIELDS:
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True)
    other = load_config(SynthConfig, TINY, ["detections.mvpe.min_written_score=0.5"])
    assert cal.load_table(rec, tmp_path / "mvpe", "mvpe", other.detections.mvpe) is None
    assert cal.load_table(rec, tmp_path / "mvpe", "svoe", base.detections.mvpe) is None
