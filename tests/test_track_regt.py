"""Ground-truth re-estimation from the 2D box annotations, and the audit of the given centres."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from egograph.core.config import load_config
from egograph.geometry.lift import lift_recording
from egograph.io.annotations import CenterAnnotation, load_annotations, read_centers, write_centers
from egograph.steps.recording import open_recording
from egograph.steps.settings import EgographConfig
from egograph.track.config import RegtConfig
from egograph.track.regt import as_center_annotations, audit_text, box_detections, reestimate_centres


@pytest.fixture(scope="module")
def lifted_boxes(tiny_rec):
    cfg = load_config(EgographConfig, None)
    rec = open_recording(tiny_rec, cfg)
    ann = load_annotations(rec.annotation_dir)
    obs, _ = lift_recording(rec, box_detections(ann), cfg.lift, progress=False)
    return cfg, ann, obs


def test_reestimated_centres_match_the_truth(lifted_boxes):
    cfg, ann, obs = lifted_boxes
    est = reestimate_centres(ann, obs, cfg.graph, RegtConfig())
    assert len(est) == len(ann.motion)
    truth = {(c.instance, c.t_start): np.array(c.xyz) for c in ann.centers}  # synthetic centres are exact
    err = [np.linalg.norm(np.array(e.xyz) - truth[(e.instance, e.t_start)]) for e in est if e.xyz is not None]
    assert len(err) >= 3
    assert np.median(err) < 0.05
    assert not any(e.flagged for e in est)


def test_audit_flags_a_shifted_centre_and_not_the_others(lifted_boxes):
    cfg, ann, obs = lifted_boxes
    seen = [e for e in reestimate_centres(ann, obs, cfg.graph, RegtConfig()) if e.n_views >= 3]
    target = (seen[0].instance, seen[0].t_start)
    shifted = [dataclasses.replace(c, xyz=tuple(np.add(c.xyz, [0.2, 0, 0]))) if (c.instance, c.t_start) == target
               else c for c in ann.centers]
    est = reestimate_centres(dataclasses.replace(ann, centers=shifted), obs, cfg.graph, RegtConfig())
    flagged = {(e.instance, e.t_start) for e in est if e.flagged}
    assert flagged == {target}
    text = audit_text(est, RegtConfig())
    assert "1 of" in text and f"| {target[0]} |" in text


def test_reestimates_round_trip_in_center_annotation_format(lifted_boxes, tmp_path):
    cfg, ann, obs = lifted_boxes
    rows = as_center_annotations(reestimate_centres(ann, obs, cfg.graph, RegtConfig()))
    write_centers(tmp_path / "3d_center_annot.txt", rows)
    back = read_centers(tmp_path / "3d_center_annot.txt")
    assert [(r.instance, r.t_start, r.t_end, r.location_id) for r in back] == \
        [(r.instance, r.t_start, r.t_end, r.location_id) for r in rows]
    assert np.allclose([r.xyz for r in back], [r.xyz for r in rows], atol=1e-9)
    # every annotated interval is in the file (the given centre where no box lifted)
    assert len(back) == len(ann.motion)


def test_interval_without_boxes_keeps_its_given_centre(lifted_boxes):
    cfg, ann, obs = lifted_boxes
    est = reestimate_centres(ann, obs.select(obs.instance < 0), cfg.graph, RegtConfig())
    assert all(e.xyz is None and e.n_views == 0 and not e.flagged for e in est)
    assert [r.xyz for r in as_center_annotations(est)] == [c.xyz for c in sorted(
        ann.centers, key=lambda c: (c.instance, c.t_start))]
    assert isinstance(as_center_annotations(est)[0], CenterAnnotation)
