"""The calibration that fits: the fit score orders perturbed calibrations, reading a sequence picks
the fitting folder over the one its number names (with one warning), --calibration wins, --strict
refuses a calibration that does not fit, degraded PV frames do not flip the choice, and the time
offset file and the pose interpolation behind it."""

from __future__ import annotations

import dataclasses
import json
import shutil
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from egograph.core.config import load_config
from egograph.core.errors import InputError
from egograph.core.resources import default_config
from egograph.geometry.calib_fit import FitCandidate, compare, fit_score, prepare_fit
from egograph.geometry.calib_refine import change_between, perturbed
from egograph.io.calibration import read_ahat_calibration, write_ahat_calibration
from egograph.io.devices import device_ahat_calibration
from egograph.io.poses import interpolate_poses, so3_exp, so3_log
from egograph.io.recording import Recording
from egograph.steps.recording import open_recording
from egograph.steps.settings import EgographConfig
from tests.conftest import make_recording, sequence_dir

AXIS = np.array([1.0, 2.0, -1.0]) / np.sqrt(6.0)
DIRECTION = np.array([1.0, -1.0, 2.0]) / np.sqrt(6.0)


def config(*overrides: str) -> EgographConfig:
    return load_config(EgographConfig, default_config(), list(overrides))


def true_candidate(rec: Recording) -> FitCandidate:
    return FitCandidate.of(rec.ahat, rec.pv, "true")


def other_rays(cand: FitCandidate) -> FitCandidate:
    """The other real headset's AHAT rays (hl2-b) with everything else of ``cand``."""
    b = device_ahat_calibration("hl2-b")
    return dataclasses.replace(cand, ahat=dataclasses.replace(cand.ahat, uv2xy=b.uv2xy, ray_valid=b.ray_valid),
                               name="hl2-b rays")


AXES = {"x": np.array([1.0, 0, 0]), "y": np.array([0, 1.0, 0]), "z": np.array([0, 0, 1.0])}
PERTURBATIONS = {  # name -> (rotation deg about AXIS, translation m along the AHAT camera's axis, time offset ms)
    "rot0.5": (0.5, 0.0, "x", 0.0), "rot1": (1.0, 0.0, "x", 0.0), "rot3": (3.0, 0.0, "x", 0.0),
    **{f"trans{cm}cm_{a}": (0.0, cm / 100, a, 0.0) for cm in (1, 3, 5) for a in "xyz"},
    "dt20": (0.0, 0.0, "x", 20.0), "dt40": (0.0, 0.0, "x", 40.0), "dt60": (0.0, 0.0, "x", 60.0),
}
# Not here: a 1 cm move along (1, -1, 2)/sqrt(6), whose image effects along x, y and z partly cancel,
# scores 0.05 px better than the truth on the 30-frame fixture of seed 3 (a bias of the score of about half a
# centimetre in that direction); 3 and 5 cm along it score +1.1 and +2.2 px.


def perturb(cand: FitCandidate, name: str) -> FitCandidate:
    rot, trans, axis, dt = PERTURBATIONS[name]
    return perturbed(cand, AXIS * np.radians(rot), AXES[axis] * trans, cand.time_offset_ms + dt, name)


@pytest.fixture(scope="module")
def fit_root(tmp_path_factory) -> Path:
    """A 45-frame synthetic recording with PV frames (seed 4: never used to choose a knob; the first
    second of the shared 30-frame fixture has the head too still to show a 20 ms time offset)."""
    return make_recording(tmp_path_factory.mktemp("calib_fit") / "rec", 4, "frames=45")


@pytest.fixture(scope="module")
def rgb_rec(fit_root) -> Recording:
    return Recording.open(fit_root)


@pytest.fixture(scope="module")
def sample(rgb_rec):
    return prepare_fit(rgb_rec, config().calib_fit)


def test_score_orders_candidates_by_perturbation_size(rgb_rec, sample):
    cfg = config().calib_fit
    assert len(sample.frames) == 40   # the sample: every frame has an image and depth
    true = fit_score(rgb_rec, sample, true_candidate(rgb_rec), cfg)
    scores = {n: fit_score(rgb_rec, sample, perturb(true_candidate(rgb_rec), n), cfg) for n in PERTURBATIONS}
    families = [("rot0.5", "rot1", "rot3"), ("dt20", "dt40", "dt60")]
    families += [tuple(f"trans{cm}cm_{a}" for cm in (1, 3, 5)) for a in "xyz"]
    for family in families:
        values = [true.score] + [scores[n].score for n in family]
        assert values == sorted(values), (family, values)
        # the smallest perturbation of each family is already clearly worse, frame by frame
        assert compare(true, scores[family[0]]).clearly_worse(cfg), family
    other = fit_score(rgb_rec, sample, other_rays(true_candidate(rgb_rec)), cfg)
    assert compare(true, other).clearly_worse(cfg)
    assert true.fits(cfg) and not scores["rot3"].fits(cfg)


def _release_layout(src: Path, dst: Path, folders: dict[str, FitCandidate], seq_name: str = "raw_video_19") -> Path:
    """A release-like dataset: the recording's sequence as ``seq_name`` and one calibration folder per
    group (``calibrations/calibrations_vid1_17/`` ...) holding the given candidates."""
    seq = sequence_dir(src)
    shutil.copytree(seq, dst / seq_name, symlinks=True)
    shutil.copytree(src / "annotations" / seq.name, dst / "annotations" / seq_name)
    pv_dir = src / "calibrations" / "personal_video"
    for name, cand in folders.items():
        folder = dst / "calibrations" / name
        write_ahat_calibration(folder / "rm_depth_ahat", cand.ahat)
        shutil.copytree(pv_dir, folder / "personal_video")
    return dst / seq_name


@pytest.mark.parametrize("wrong", ["rot0.5", "dt20", pytest.param("trans1cm_x", marks=pytest.mark.slow),
                                   pytest.param("trans1cm_z", marks=pytest.mark.slow),
                                   pytest.param("hl2-b rays", marks=pytest.mark.slow)])
def test_reading_picks_the_fitting_folder_over_the_numbered_one(fit_root, rgb_rec, tmp_path, wrong):
    true = true_candidate(rgb_rec)
    bad = other_rays(true) if wrong == "hl2-b rays" else perturb(true, wrong)
    seq = _release_layout(fit_root, tmp_path, {"calibrations_vid1_17": true, "calibrations_vid18_30": bad})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rec = open_recording(seq, config())
    assert rec.calibration_dir.name == "calibrations_vid1_17"
    said = [str(w.message) for w in caught if "fits clearly worse" in str(w.message)]
    assert len(said) == 1 and "calibrations_vid18_30" in said[0] and "calibrations_vid1_17" in said[0], said
    fit = rec.calibration_fit
    assert fit.switched and fit.by_number.name == "calibrations_vid18_30"
    # the data chose the folder whose numbers are the truth's: lifting through it is lifting through the truth
    assert np.array_equal(rec.ahat.extrinsics, read_ahat_calibration(fit_root / "calibrations" / "rm_depth_ahat").extrinsics)


def test_numbered_folder_that_fits_is_kept_without_warning(fit_root, rgb_rec, tmp_path):
    true = true_candidate(rgb_rec)
    seq = _release_layout(fit_root, tmp_path, {"calibrations_vid1_17": perturb(true, "rot1"),
                                                   "calibrations_vid18_30": true,
                                                   "calibrations_vid31_40": perturb(true, "dt40")})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rec = open_recording(seq, config())
    assert rec.calibration_dir.name == "calibrations_vid18_30"
    assert not [w for w in caught if "calibration" in str(w.message)]
    # selection off: by number, no scoring
    rec = open_recording(seq, config("calib_fit.select=false"))
    assert rec.calibration_dir.name == "calibrations_vid18_30" and rec.calibration_fit.scores == {}


def test_no_numbered_folder_takes_the_best_fitting(fit_root, rgb_rec, tmp_path):
    true = true_candidate(rgb_rec)
    seq = _release_layout(fit_root, tmp_path, {"calibrations_a": perturb(true, "trans3cm_y"),
                                                   "calibrations_b": true}, seq_name="tiny_seq")
    with pytest.warns(UserWarning, match="no calibration folder is named for this sequence"):
        rec = open_recording(seq, config())
    assert rec.calibration_dir.name == "calibrations_b"


def test_explicit_calibration_wins_and_strict_refuses_one_that_does_not_fit(fit_root, rgb_rec, tmp_path):
    true = true_candidate(rgb_rec)
    seq = _release_layout(fit_root, tmp_path, {"calibrations_vid1_17": true,
                                                   "calibrations_vid18_30": perturb(true, "rot3")})
    bad_dir = tmp_path / "calibrations" / "calibrations_vid18_30"
    rec = open_recording(seq, config(), calibration=bad_dir, score_calibration=True)
    assert rec.calibration_dir == bad_dir
    [(folder, score)] = rec.calibration_fit.scores.items()
    assert folder == bad_dir and not score.fits(config().calib_fit)
    with pytest.raises(InputError, match="does not fit this sequence"):
        open_recording(seq, config("io.strict=true"), calibration=bad_dir)
    good = open_recording(seq, config("io.strict=true"), calibration=tmp_path / "calibrations" / "calibrations_vid1_17")
    assert good.calibration_fit.scores[good.calibration_dir].fits(config().calib_fit)


def _degrade(img: np.ndarray, how: str, rng: np.random.Generator) -> np.ndarray:
    if how == "blur":   # defocus and a 15 px horizontal motion streak
        out = cv2.GaussianBlur(img, (0, 0), 2.5)
        return cv2.filter2D(out, -1, np.full((1, 15), 1 / 15))
    if how == "dark":   # a fifth of the light, photon (shot) noise at ~20 electrons per grey level
        lam = img.astype(np.float64) * 0.2 * 20
        return np.clip(rng.poisson(lam) / 20.0, 0, 255).astype(np.uint8)
    # a hand-sized dark blob in front of the camera, somewhere else in each frame
    out = img.copy()
    h, w = img.shape[:2]
    cv2.ellipse(out, (int(rng.uniform(0.2, 0.8) * w), int(rng.uniform(0.5, 0.9) * h)), (180, 120),
                float(rng.uniform(0, 180)), 0, 360, (70, 50, 40), -1)
    return out


@pytest.mark.parametrize("how", ["blob", pytest.param("blur", marks=pytest.mark.slow),
                                 pytest.param("dark", marks=pytest.mark.slow)])
def test_degraded_frames_do_not_flip_the_choice(fit_root, rgb_rec, tmp_path, how):
    true = true_candidate(rgb_rec)
    seq = _release_layout(fit_root, tmp_path, {"calibrations_vid1_17": true,
                                                   "calibrations_vid18_30": perturb(true, "rot0.5"),
                                                   "calibrations_vid31_40": perturb(true, "dt20")})
    rng = np.random.default_rng(11)
    for png in sorted((seq / "pv").glob("*.png")):
        img = cv2.imread(str(png))
        png.unlink()   # a copy may be a link to the fixture's frame
        cv2.imwrite(str(png), _degrade(img, how, rng))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rec = open_recording(seq, config())
    scores = rec.calibration_fit.scores
    best = min(scores, key=lambda p: scores[p].score)
    assert best.name == "calibrations_vid1_17", {p.name: s.score for p, s in scores.items()}
    assert rec.calibration_dir.name == "calibrations_vid1_17", [str(w.message) for w in caught]


def test_info_reports_every_candidate_and_marks_the_one_used(fit_root, rgb_rec, tmp_path):
    from egograph.cli.main import main

    true = true_candidate(rgb_rec)
    seq = _release_layout(fit_root, tmp_path, {"calibrations_vid1_17": true,
                                                   "calibrations_vid18_30": perturb(true, "trans3cm_y")})
    out = tmp_path / "info.json"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["info", str(seq), "--json", str(out)]) == 0
    fit = json.loads(out.read_text())["calibration_fit"]
    rows = {Path(c["folder"]).name: c for c in fit["candidates"]}
    assert set(rows) == {"calibrations_vid1_17", "calibrations_vid18_30"}
    assert rows["calibrations_vid1_17"]["used"] and rows["calibrations_vid18_30"]["by_number"] and fit["switched"]
    assert rows["calibrations_vid1_17"]["score_px"] < rows["calibrations_vid18_30"]["score_px"]


def test_time_offset_file_round_trips_and_shifts_the_ahat_poses(fit_root, rgb_rec, tmp_path):
    dst = tmp_path / "rec"
    shutil.copytree(fit_root, dst, symlinks=True)
    folder = dst / "calibrations" / "rm_depth_ahat"
    ahat = read_ahat_calibration(folder)
    assert ahat.time_offset_ms == 0.0 and not (folder / "time_offset.bin").exists()
    write_ahat_calibration(folder, dataclasses.replace(ahat, time_offset_ms=16.5))
    assert read_ahat_calibration(folder).time_offset_ms == pytest.approx(16.5)
    shifted = Recording.open(dst)
    # half a frame (33.3 ms at 30 fps) later: halfway between a frame's AHAT pose and the next one's
    i = 10
    ts = rgb_rec.depth_timestamps
    s = (16.5e4) / (ts[i + 1] - ts[i])
    a, b = rgb_rec.depth_poses[i], rgb_rec.depth_poses[i + 1]
    expect_t = a[3, :3] + s * (b[3, :3] - a[3, :3])
    assert np.allclose(shifted.depth_poses[i][3, :3], expect_t, atol=1e-9)
    assert not np.allclose(shifted.depth_poses[i], a)


def test_pose_interpolation_follows_the_geodesic():
    rot = so3_exp(np.array([0.0, 0.4, 0.0]))
    a, b = np.eye(4), np.eye(4)
    b[:3, :3], b[3, :3] = rot, [1.0, 2.0, 3.0]
    out, ok = interpolate_poses(np.array([0, 100]), np.stack([a, b]), np.array([True, True]), np.array([25, 100, 150, 400]))
    assert ok.tolist() == [True, True, True, False]
    assert np.allclose(so3_log(out[0][:3, :3]), [0, 0.1, 0]) and np.allclose(out[0][3, :3], [0.25, 0.5, 0.75])
    assert np.allclose(out[1], b) and np.allclose(so3_log(out[2][:3, :3]), [0, 0.6, 0])
    v = np.array([0.3, -0.2, 0.5])
    assert np.allclose(so3_log(so3_exp(v)), v)


def test_perturbation_change_round_trips(rgb_rec):
    true = true_candidate(rgb_rec)
    moved = perturbed(true, AXIS * np.radians(2.0), DIRECTION * 0.03, 40.0)
    rot, trans, dt = change_between(true, moved)
    assert np.allclose(rot, AXIS * np.radians(2.0)) and np.allclose(trans, DIRECTION * 0.03) and dt == 40.0
    # the AHAT camera centre in the rig moved by 3 cm
    from egograph.geometry.hl2ss import invert_rigid

    c0 = invert_rigid(true.ahat.extrinsics)[3, :3]
    c1 = invert_rigid(moved.ahat.extrinsics)[3, :3]
    assert np.linalg.norm(c1 - c0) == pytest.approx(0.03)
    assert moved.pv is true.pv   # the refinement leaves the PV calibration as it is


def test_fine_score_is_lowest_at_the_true_translation(rgb_rec):
    """The score the refinement ends on (its fine edges) has its minimum at the true AHAT position: no
    4 mm move along an AHAT axis scores better than the truth by more than 0.05 px. Scoring each depth
    edge pixel at its own centre and range (before issue 43's fix) scored 4 mm along -y and -z better by
    0.11 and 0.18 px on this recording, and left 4-7 mm of an injected 3 cm in the refinement."""
    from egograph.geometry.calib_fit import fit_cost
    from egograph.geometry.calib_refine import FINE

    cfg = dataclasses.replace(config().calib_fit, **FINE)
    sample = prepare_fit(rgb_rec, cfg)
    true = true_candidate(rgb_rec)
    at_truth = fit_cost(rgb_rec, sample, true, cfg)
    for axis in AXES.values():
        for mm in (-4.0, 4.0):
            moved = perturbed(true, np.zeros(3), axis * mm / 1000, true.time_offset_ms)
            assert fit_cost(rgb_rec, sample, moved, cfg) > at_truth - 0.05, (axis, mm)


@pytest.mark.slow
def test_refinement_recovers_an_injected_error(rgb_rec):
    """An injected 1 deg / 1 cm / 20 ms AHAT-PV error, refined on the 45 frames of the fixture: measured
    0.22 deg / 3.1 mm / 0.03 ms left (28 s CPU). tools/bench_calib_fit.py measures the issue's target
    (2 deg / 3 cm / 40 ms on 300 frames); from that larger error 45 frames are too few: the coarse search
    runs off to a rotation of degrees."""
    from egograph.geometry.calib_refine import refine_calibration

    true = true_candidate(rgb_rec)
    bad = perturbed(true, AXIS * np.radians(1.0), DIRECTION * 0.01, true.time_offset_ms + 20.0)
    r = refine_calibration(rgb_rec, bad, config().calib_fit, frames=45)
    rot, trans, dt = change_between(true, r.candidate)
    assert np.degrees(np.linalg.norm(rot)) < 0.3
    assert np.linalg.norm(trans) < 0.005
    assert abs(dt) < 5.0
    assert r.after.score < r.before.score


def test_refined_calibration_is_written_as_a_release_folder(fit_root, rgb_rec, tmp_path):
    """The folder format and the run record (a short search on 6 frames; the accuracy of the
    refinement is measured by tools/bench_calib_fit.py on a 300-frame recording)."""
    from egograph.steps.calibration import refine_calibration_folder

    true = true_candidate(rgb_rec)
    start = _release_layout(fit_root, tmp_path / "data", {"calibrations_vid1_17": perturb(true, "rot1")})
    rec = open_recording(start, config())
    out = tmp_path / "refined"
    r = refine_calibration_folder(rec, config(), out, frames=6, max_evaluations=40)
    assert r.after.score < r.before.score
    ahat = read_ahat_calibration(out / "rm_depth_ahat")
    assert np.allclose(ahat.extrinsics, r.candidate.ahat.extrinsics, atol=1e-6)
    assert ahat.time_offset_ms == pytest.approx(r.time_offset_ms, abs=1e-3)
    fit = json.loads((out / "fit.json").read_text())
    assert fit["before"]["score_px"] == pytest.approx(r.before.score) and fit["after"]["score_px"] == pytest.approx(r.after.score)
    assert json.loads((out / "egograph.json").read_text())["step"] == "refine-calibration"
    again = open_recording(start, config(), calibration=out)
    assert np.allclose(again.ahat.extrinsics, ahat.extrinsics)
    assert refine_calibration_folder(rec, config(), out, frames=6, max_evaluations=40) is None   # up to date


@pytest.mark.slow
def test_device_like_frames_do_not_flip_the_choice(device_rec, tmp_path):
    """Blurred, noisy, compressed PV frames with a hand in view (issue 38's device world): the true
    folder still scores best, and the perturbed folder the sequence's number names is replaced by it with
    the warning."""
    truth = np.load(device_rec / "synth_gt" / sequence_dir(device_rec).name / "device.npz")
    assert truth["hand_on"].any()   # the hand is in the recording the choice is made on
    rec = Recording.open(device_rec)
    true = true_candidate(rec)
    seq = _release_layout(device_rec, tmp_path, {"calibrations_vid1_17": true,
                                                     "calibrations_vid18_30": perturb(true, "rot1"),
                                                     "calibrations_vid31_40": perturb(true, "dt40")})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        chosen = open_recording(seq, config())
    scores = chosen.calibration_fit.scores
    best = min(scores, key=lambda p: scores[p].score)
    assert best.name == "calibrations_vid1_17", {p.name: s.score for p, s in scores.items()}
    assert chosen.calibration_dir.name == "calibrations_vid1_17"
    assert any("fits clearly worse" in str(w.message) and "calibrations_vid18_30" in str(w.message) for w in caught)
