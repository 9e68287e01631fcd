"""The paper's 2D table (eval-2d) and its SOT baseline (sot): issue 16 §5, §6."""

from __future__ import annotations

import numpy as np
import pytest

from egograph.cli.main import main
from egograph.eval.tracking2d import iou, scores


def test_perfect_boxes_score_full_marks_but_the_last_iou_threshold():
    gt = np.array([[10, 10, 50, 30], [100, 100, 120, 160.0]])
    s = scores(gt, gt)
    assert s.auc == pytest.approx(100 * 20 / 21)   # IoU 1 exceeds every threshold but 1 itself
    assert s.precision_20px == 100 and s.norm_precision == 100


def test_shift_and_miss():
    gt = np.array([[0, 0, 40, 40], [0, 0, 40, 40.0]])
    pred = np.array([[30, 0, 70, 40], [np.nan] * 4])   # shifted 30 px: IoU 10/70; the second missed
    assert iou(pred[:1], gt[:1])[0] == pytest.approx(400 / 2800)
    s = scores(pred, gt)
    assert s.n == 2 and s.n_detected == 1
    assert s.precision_20px == 0                                  # 30 px > 20 px; a miss never counts
    assert s.auc == pytest.approx(100 * 0.5 * 3 / 21)              # IoU 0.143 > 0, 0.05, 0.10 only
    # normalised error 30/40 = 0.75 exceeds every threshold up to 0.5
    assert s.norm_precision == 0


@pytest.mark.slow
def test_sot_boxes_follow_the_object_and_score_in_eval_2d(tiny_rgb_rec, tmp_path, capsys):
    import json

    out = tmp_path / "sot"
    assert main(["sot", str(tiny_rgb_rec), "--out", str(out), "--quiet"]) == 0
    files = sorted(out.glob("*.txt"))
    assert len(files) == 30 and any(f.read_text() for f in files)
    assert main(["eval-2d", str(tiny_rgb_rec), str(out), "svoe", "--names", "sot,simulated",
                 "--json", str(tmp_path / "s.json")]) == 0
    table = json.loads((tmp_path / "s.json").read_text())
    # measured on this fixture (one SVOE instance, 6 annotated boxes): SOT 91.3 AUC, 100 P@20px, 95.4 P_norm
    assert table["sot"]["auc"] > 70 and table["sot"]["precision_20px"] > 80 and table["sot"]["norm_precision"] > 70
    assert table["sot"]["n"] == table["simulated"]["n"] > 0


def test_eval_2d_names_a_missing_detection_folder(tiny_rgb_rec, tmp_path, capsys):
    assert main(["eval-2d", str(tiny_rgb_rec), str(tmp_path / "nope")]) == 2
    assert "nope" in capsys.readouterr().err
