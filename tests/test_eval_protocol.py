"""IT3DEgo counting: hand-made cases, and agreement with a plain re-statement of the reference loop."""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np
import pytest

from egograph.eval.intervals import (
    PredictedInterval,
    interval_scores,
    intervals_from_predictions,
    score_intervals,
)
from egograph.eval.loader import load_gt_intervals, load_predictions
from egograph.eval.protocol import THRESHOLDS, Counts, GtInterval, evaluate_sequence

K = len(THRESHOLDS)  # 0.25, 0.5, 0.75, 1.0, 1.5 m


def counts_tuple(c: Counts):
    return (c.tp.tolist(), c.fp.tolist(), c.fn.tolist(), c.n_gt, c.n_pred)


# --------------------------------------------------------------------------- hand cases


def test_prediction_outside_any_interval_is_fp_and_missing_prediction_is_fn():
    # Frames 10, 20, 30. Instance 0 stands at the origin over [10, 20].
    # Frame 10, 20: GT covers, no prediction -> n_gt += 1, FN at every τ (twice).
    # Frame 30: prediction of instance 0, no GT covers -> n_pred += 1, matched = [] -> FP += 1 at every τ.
    gt = [GtInterval(0, 10, 20, (0, 0, 0))]
    preds = {30: {0: (0.0, 0.0, 0.0)}}
    r = evaluate_sequence([10, 20, 30], gt, preds)
    assert counts_tuple(r.total) == ([0] * K, [1] * K, [2] * K, 2, 1)
    assert r.total.precision.tolist() == [0.0] * K
    assert r.total.recall.tolist() == [0.0] * K
    assert r.total.l2_n == 0 and r.total.l2_m == 0.0


def test_missing_prediction_only():
    # One frame, one GT, no predictions at all: FN at every τ; precision guarded (n_pred = 0).
    r = evaluate_sequence([5], [GtInterval(3, 0, 10, (1, 2, 3))], {})
    assert counts_tuple(r.total) == ([0] * K, [0] * K, [1] * K, 1, 0)
    assert r.total.precision.tolist() == [0.0] * K


def test_prediction_at_wrong_place():
    # d = 0.6 m: τ = 0.25, 0.5 -> FP and FN; τ = 0.75, 1.0, 1.5 -> TP.
    r = evaluate_sequence([1], [GtInterval(0, 0, 2, (0, 0, 0))], {1: {0: (0.6, 0.0, 0.0)}})
    assert counts_tuple(r.total) == ([0, 0, 1, 1, 1], [1, 1, 0, 0, 0], [1, 1, 0, 0, 0], 1, 1)
    assert r.total.precision.tolist() == [0, 0, 1, 1, 1]
    assert r.total.l2_m == pytest.approx(0.6)
    assert r.total.pcl_hits == 0  # 0.6 > 0.3


def test_two_intervals_of_one_instance_are_chosen_by_time():
    # Instance 0 at A = origin over [0, 100], at B = (5, 0, 0) over [200, 300].
    # Prediction (5, 0, 0) in frames 50 and 250.
    # Frame 50: A covers, d = 5 -> FP + FN at every τ. Frame 250: B covers, d = 0 -> TP at every τ.
    gt = [GtInterval(0, 0, 100, (0, 0, 0)), GtInterval(0, 200, 300, (5, 0, 0))]
    preds = {50: {0: (5, 0, 0)}, 250: {0: (5, 0, 0)}}
    r = evaluate_sequence([50, 250], gt, preds)
    assert counts_tuple(r.total) == ([1] * K, [1] * K, [1] * K, 2, 2)


def test_interval_ends_are_inclusive():
    # GT [100, 200]; exact predictions in frames 99, 100, 200, 201.
    # 100 and 200 are covered -> TP (x2); 99 and 201 are not -> FP (x2).
    gt = [GtInterval(0, 100, 200, (1, 1, 1))]
    preds = {t: {0: (1, 1, 1)} for t in (99, 100, 200, 201)}
    r = evaluate_sequence([99, 100, 200, 201], gt, preds)
    assert counts_tuple(r.total) == ([2] * K, [2] * K, [0] * K, 2, 4)


@pytest.mark.parametrize("d, tp", [(0.25, [1] * 5), (0.5, [0, 1, 1, 1, 1]), (1.5, [0, 0, 0, 0, 1])])
def test_distance_equal_to_threshold_is_tp(d, tp):
    # d == τ exactly (the offsets are exact in binary floating point) -> TP at that τ.
    r = evaluate_sequence([0], [GtInterval(0, 0, 0, (0, 0, 0))], {0: {0: (0.0, d, 0.0)}})
    miss = [1 - x for x in tp]
    assert counts_tuple(r.total) == (tp, miss, miss, 1, 1)


def test_near_tie_decided_like_the_reference_norm():
    # Distances within rounding of a threshold: decided by np.linalg.norm of the 3-vector,
    # exactly as the reference computes them.
    rng = np.random.default_rng(7)
    for _ in range(200):
        g = rng.uniform(-3, 3, 3)
        u = rng.normal(size=3)
        tau = THRESHOLDS[rng.integers(K)]
        p = g + u / np.linalg.norm(u) * tau
        d = np.linalg.norm(g - p)
        r = evaluate_sequence([0], [GtInterval(0, 0, 0, tuple(g))], {0: {0: tuple(p)}})
        assert r.total.tp.tolist() == [int(d <= t) for t in THRESHOLDS]


def test_duplicate_covering_intervals_follow_the_reference_quirk():
    # Instance 0 has two GT intervals that both cover frame 7: [0, 10] at the origin, [5, 15] at (3, 0, 0).
    # Prediction at the origin. n_gt += 2; first: TP; second: d = 3 -> FP + FN at every τ;
    # matched = [0, 0] -> FP += 1 - 2 = -1. Totals: tp 1, fp 0, fn 1, n_pred 1 (tp + fp == n_pred holds).
    gt = [GtInterval(0, 0, 10, (0, 0, 0)), GtInterval(0, 5, 15, (3, 0, 0))]
    r = evaluate_sequence([7], gt, {7: {0: (0, 0, 0)}})
    assert counts_tuple(r.total) == ([1] * K, [0] * K, [1] * K, 2, 1)


def test_per_instance_counts_add_up_and_false_predictions_count_to_their_instance():
    # Frame 1: instance 0 GT at origin, predicted exactly -> TP for 0.
    # Instance 1 has no GT but is predicted -> FP at every τ, attributed to instance 1.
    gt = [GtInterval(0, 0, 5, (0, 0, 0))]
    r = evaluate_sequence([1], gt, {1: {0: (0, 0, 0), 1: (4, 4, 4)}})
    assert counts_tuple(r.per_instance[0]) == ([1] * K, [0] * K, [0] * K, 1, 1)
    assert counts_tuple(r.per_instance[1]) == ([0] * K, [1] * K, [0] * K, 0, 1)
    assert sum(r.per_instance.values()) == r.total
    assert counts_tuple(r.total) == ([1] * K, [1] * K, [0] * K, 1, 2)


def test_multi_sequence_totals_sum_counts():
    # Sequence A: one exact prediction -> tp 1, n_pred 1 (P = 1).
    # Sequence B: three predictions 10 m off -> tp 0, n_pred 3 (P = 0).
    # Summed: P = 1 / 4 at every τ (a mean of per-sequence ratios would give 0.5).
    a = evaluate_sequence([0], [GtInterval(0, 0, 0, (0, 0, 0))], {0: {0: (0, 0, 0)}})
    b = evaluate_sequence([0, 1, 2], [GtInterval(0, 0, 2, (0, 0, 0))], {t: {0: (10, 0, 0)} for t in range(3)})
    total = a.total + b.total
    assert counts_tuple(total) == ([1] * K, [3] * K, [3] * K, 4, 4)
    assert total.precision.tolist() == [0.25] * K
    assert total.recall.tolist() == [0.25] * K
    assert sum([a.total, b.total]) == total


def test_angular_error_known_geometry_and_invalid_pose():
    # Camera at the origin; GT (1, 0, 0); prediction (0, 1, 0): angle π/2, L2 = √2.
    gt = [GtInterval(0, 0, 1, (1, 0, 0))]
    preds = {0: {0: (0, 1, 0)}, 1: {0: (0, 1, 0)}}
    r = evaluate_sequence([0, 1], gt, preds, camera_centers=np.zeros((2, 3)))
    assert r.total.angle_rad == pytest.approx(math.pi / 2)
    assert r.total.angle_n == 2
    assert r.total.l2_m == pytest.approx(math.sqrt(2))
    # Frame 1 has an invalid pose (NaN centre): skipped for the angle only.
    centers = np.array([[0.0, 0.0, 0.0], [np.nan] * 3])
    r = evaluate_sequence([0, 1], gt, preds, camera_centers=centers)
    assert (r.total.angle_n, r.total.l2_n, r.total.n_gt) == (1, 2, 2)
    # Camera at (1, 1, 0) between them: GT direction (0, -1, 0), prediction (-1, 0, 0) -> π/2 as well;
    # camera at (2, 0, 0): GT direction (-1, 0, 0), prediction (-2, 1, 0) -> atan(1/2).
    r = evaluate_sequence([0, 1], gt, preds, camera_centers=np.array([[1.0, 1, 0], [2.0, 0, 0]]))
    assert r.total.angle_rad == pytest.approx((math.pi / 2 + math.atan(0.5)) / 2)


def test_pcl_is_share_within_30cm():
    # Two GT frames: predictions 0.3 m (hit, inclusive) and 0.31 m (miss) away -> PCL 0.5.
    gt = [GtInterval(0, 0, 1, (0, 0, 0))]
    r = evaluate_sequence([0, 1], gt, {0: {0: (0.3, 0, 0)}, 1: {0: (0.31, 0, 0)}})
    assert r.total.pcl == 0.5


def test_frames_outside_timestamps_are_ignored_and_camera_shape_checked():
    gt = [GtInterval(0, 0, 10, (0, 0, 0))]
    r = evaluate_sequence([1], gt, {1: {0: (0, 0, 0)}, 2: {0: (9, 9, 9)}})  # 2 is not a PV frame
    assert counts_tuple(r.total) == ([1] * K, [0] * K, [0] * K, 1, 1)
    with pytest.raises(ValueError):
        evaluate_sequence([1, 2], gt, {}, camera_centers=np.zeros((3, 3)))


# --------------------------------------------------------------------------- interval-level score


def test_interval_scores_hand_case():
    # Ten frames, 0.1 s apart (1e6 ticks). Frame k spans index k.
    ts = [k * 1_000_000 for k in range(10)]
    gt = [
        GtInterval(0, 0, 4_000_000, (0, 0, 0)),          # A: frames 0-4
        GtInterval(0, 5_000_000, 9_000_000, (2, 0, 0)),  # B: frames 5-9   (true break at 4e6 ticks)
        GtInterval(1, 0, 9_000_000, (1, 1, 0)),          # C: frames 0-9
        GtInterval(2, 0, 9_000_000, (5, 5, 0)),          # D: frames 0-9
        GtInterval(3, 0, 2_000_000, (9, 0, 0)),          # E: frames 0-2   (true break at 2e6 ticks)
        GtInterval(3, 6_000_000, 9_000_000, (9, 1, 0)),  # F: frames 6-9
    ]
    pred = [
        PredictedInterval(0, 0, 3_000_000, (0.1, 0, 0)),          # vs A: tIoU 4/5, 0.1 m -> A recovered
        PredictedInterval(0, 4_000_000, 9_000_000, (2, 0, 0.3)),  # vs B: tIoU 5/6 but 0.3 m -> not
        (1, 0, 3_000_000, (1, 1, 0)),                             # vs C: tIoU 4/10 -> not
        (1, 6_000_000, 9_000_000, (1, 1, 0)),                     # vs C: tIoU 4/10 -> not
        (2, 0, 4_000_000, (5, 5, 0)),                             # vs D: tIoU 5/10 = 0.5 -> recovered
    ]
    s = interval_scores(gt, pred, ts)
    # Recovered: A and D out of 6 -> 1/3.
    assert (s["n_true"], s["n_recovered"]) == (6, 2)
    assert s["recovered_fraction"] == pytest.approx(1 / 3)
    # True breaks: instance 0 at 4e6, instance 3 at 2e6 -> 2. Instance 0's predicted break is at 3e6
    # -> |4e6 - 3e6| = 1e6 ticks = 0.1 s. Instance 3 has no predicted break -> no error.
    assert s["n_breaks"] == 2
    assert s["n_breaks_with_prediction"] == 1
    assert s["break_errors_s"] == [pytest.approx(0.1)]
    assert s["median_break_error_s"] == pytest.approx(0.1)
    # Additive over sequences.
    twice = score_intervals(gt, pred, ts) + score_intervals(gt, pred, ts)
    assert (twice.n_true, twice.n_recovered, twice.n_breaks) == (12, 4, 4)


def test_intervals_from_predictions_groups_within_1cm_of_the_run_start():
    ts = [k * 10 for k in range(8)]
    preds = {
        0: {0: (0.0, 0, 0)},
        10: {0: (0.005, 0, 0)},
        20: {0: (0.009, 0, 0)},    # still within 1 cm of the run's first position
        30: {0: (0.016, 0, 0)},    # 1.6 cm from the run start -> new interval (anchor, not chain)
        40: {0: (0.5, 0, 0)},      # jump -> new interval
        # 50: no prediction -> closes the run
        60: {0: (0.5, 0, 0), 1: (1, 1, 1)},
        70: {1: (1, 1, 1)},
    }
    got = intervals_from_predictions(ts, preds)
    assert [(iv.instance, iv.t_start, iv.t_end) for iv in got] == [
        (0, 0, 20), (0, 30, 30), (0, 40, 40), (0, 60, 60), (1, 60, 70)
    ]
    assert got[0].xyz[0] == pytest.approx(0.014 / 3)
    # Fed to the interval score: instance 1 stood at (1, 1, 1) over frames 6-7.
    s = interval_scores([GtInterval(1, 60, 70, (1, 1, 1))], got, ts)
    assert s["recovered_fraction"] == 1.0 and s["median_break_error_s"] is None


# --------------------------------------------------------------------------- reference re-statement


def reference_eval(timestamps, gt_path, results_dir, thresholds=THRESHOLDS):
    """Plain, frame-by-frame re-statement of the reference loop, reading the files itself."""
    gt_3d, gt_range = defaultdict(list), defaultdict(list)
    with open(gt_path) as f:
        for line in f:
            s = line.split()
            gt_3d[int(s[2])].append(np.array([float(s[3]), float(s[4]), float(s[5])]))
            gt_range[int(s[2])].append([int(s[0]), int(s[1])])
    k = len(thresholds)
    tp, fp, fn = [0] * k, [0] * k, [0] * k
    num_gts = num_preds = 0
    for ts in sorted(timestamps):
        res = {}
        path = results_dir / f"{ts}.txt"
        if path.exists():
            with open(path) as f:
                for line in f:
                    s = line.split()
                    res[int(s[0])] = np.array([float(s[1]), float(s[2]), float(s[3])])
        num_preds += len(res)
        matched = []
        for inst in gt_3d:
            for i in range(len(gt_3d[inst])):
                if gt_range[inst][i][0] <= ts <= gt_range[inst][i][1]:
                    num_gts += 1
                    if inst not in res:
                        for j in range(k):
                            fn[j] += 1
                        continue
                    dist = np.linalg.norm(gt_3d[inst][i] - res[inst])
                    for j, t in enumerate(thresholds):
                        if dist <= t:
                            tp[j] += 1
                        else:
                            fp[j] += 1
                            fn[j] += 1
                    matched.append(inst)
        for j in range(k):
            fp[j] += len(res) - len(matched)
    return tp, fp, fn, num_gts, num_preds


def make_random_case(tmp_path, seed, n_frames=200, n_inst=5):
    """Random GT intervals and result files (with duplicate lines, missing files, boundary distances)."""
    rng = np.random.default_rng(seed)
    ts = (133_500_000_000_000_000 + np.cumsum(rng.integers(300_000, 370_000, n_frames))).tolist()
    gt_lines, gt_pos = [], defaultdict(list)
    for inst in range(n_inst):
        for _ in range(rng.integers(1, 4)):
            a, b = sorted(rng.integers(0, n_frames, 2))
            t0 = ts[a] - int(rng.integers(0, 2)) * 1000   # sometimes off-frame ends
            t1 = ts[b] + int(rng.integers(0, 2)) * 1000
            xyz = rng.uniform(-4, 4, 3)
            gt_pos[inst].append(xyz)
            gt_lines.append(f"{t0} {t1} {inst} " + " ".join(repr(float(v)) for v in xyz) + " 0\n")
    gt_path = tmp_path / "3d_center_annot.txt"
    gt_path.write_text("".join(gt_lines))
    res_dir = tmp_path / "results"
    res_dir.mkdir()
    for t in ts:
        if rng.random() < 0.05:
            continue  # no file for this frame
        lines = []
        for inst in range(n_inst + 1):  # instance n_inst never has a GT
            if rng.random() > 0.6:
                continue
            base = gt_pos[inst][rng.integers(len(gt_pos[inst]))] if gt_pos[inst] else np.zeros(3)
            u = rng.normal(size=3)
            u /= np.linalg.norm(u)
            if rng.random() < 0.2:  # exactly on a threshold (up to rounding)
                p = base + u * THRESHOLDS[rng.integers(K)]
            else:
                p = base + u * rng.uniform(0, 2.0)
            lines.append(f"{inst} " + " ".join(repr(float(v)) for v in p) + " 0.9\n")
            if rng.random() < 0.1:  # a second line for the same instance: the last one wins
                q = base + rng.normal(scale=0.5, size=3)
                lines.append(f"{inst} " + " ".join(repr(float(v)) for v in q) + " 0.7\n")
        (res_dir / f"{t}.txt").write_text("".join(lines))
    return ts, gt_path, res_dir


@pytest.mark.parametrize("seed", range(8))
def test_matches_reference_restatement_on_random_case(tmp_path, seed):
    ts, gt_path, res_dir = make_random_case(tmp_path, seed)
    gt = load_gt_intervals(gt_path)
    preds = load_predictions(res_dir, ts)
    r = evaluate_sequence(ts, gt, preds)
    assert counts_tuple(r.total) == reference_eval(ts, gt_path, res_dir)
    assert preds.frames_without_file == sum(not (res_dir / f"{t}.txt").exists() for t in ts)
    assert sum(r.per_instance.values()) == r.total

    # L2 and angle: plain loop over (frame, covering interval) pairs with a prediction.
    centers = np.random.default_rng(seed + 100).uniform(-2, 2, (len(ts), 3))
    r = evaluate_sequence(ts, gt, preds, camera_centers=centers)
    l2, ang = [], []
    for i, t in enumerate(ts):
        for g in gt:
            if g.t_start <= t <= g.t_end and g.instance in preds[t]:
                gx, px = np.array(g.xyz), preds[t][g.instance]
                l2.append(np.linalg.norm(gx - px))
                u, v = gx - centers[i], px - centers[i]
                ang.append(math.acos(np.clip(u @ v / np.linalg.norm(u) / np.linalg.norm(v), -1, 1)))
    assert r.total.l2_n == len(l2) and r.total.angle_n == len(ang)
    assert r.total.l2_m == pytest.approx(np.mean(l2))
    assert r.total.angle_rad == pytest.approx(np.mean(ang))


def test_loader_last_line_wins_and_missing_files(tmp_path):
    res = tmp_path / "res"
    res.mkdir()
    (res / "10.txt").write_text("0 1 1 1 0.5\n0 2 2 2 0.9\n1 5 5 5 0.3\n")
    (res / "20.txt").write_text("")
    preds = load_predictions(res, [10, 20, 30])
    assert sorted(preds) == [10, 20, 30]
    assert preds[10][0].tolist() == [2, 2, 2]
    assert preds[20] == {} and preds[30] == {}
    assert preds.missing == [30] and preds.frames_without_file == 1


def test_3000_frames_10_instances_count_every_gt_and_prediction():
    # (speed belongs to a benchmark, not to a timed unit test on a shared machine)
    rng = np.random.default_rng(0)
    ts = np.arange(3000, dtype=np.int64) * 333_333 + 10**17
    gt = []
    for inst in range(10):
        cuts = np.sort(rng.choice(np.arange(1, 3000), 2, replace=False))
        for a, b in zip([0, *cuts], [*cuts, 3000]):
            gt.append(GtInterval(inst, int(ts[a]), int(ts[b - 1]), tuple(rng.uniform(-3, 3, 3))))
    preds = {int(t): {i: rng.uniform(-3, 3, 3) for i in range(10) if rng.random() < 0.8} for t in ts}
    centers = rng.uniform(-1, 1, (3000, 3))
    r = evaluate_sequence(ts, gt, preds, centers)
    assert r.total.n_gt == 30000
    assert r.total.n_pred == sum(len(v) for v in preds.values())
