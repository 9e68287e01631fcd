"""tools/bench_detect.py --recall: why a visible instance is not covered by a proposal."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))

from bench_detect import MISS_CAUSES, cause_detail, cause_row, miss_cause  # noqa: E402

TRUTH = np.array([100.0, 100.0, 140.0, 160.0])   # 40 x 60 px


def boxes(*b) -> np.ndarray:
    return np.array(b, np.float64).reshape(-1, 4)


@pytest.mark.parametrize("plausible, kept, cause, best", [
    # kept at the cap, IoU 0.64 (a box 5 px larger each way)
    (boxes([95, 95, 145, 165]), boxes([95, 95, 145, 165]), "covered", 0),
    # a good box exists but NMS or the cap dropped it: the best is row 1
    (boxes([0, 0, 20, 20], [98, 98, 142, 162]), boxes([0, 0, 20, 20]), "lost to the cap or NMS", 1),
    # merged with its surround: holds the whole true box, IoU 2400 / 12000 = 0.2
    (boxes([60, 60, 180, 160]), boxes(), "too large", 0),
    # a fragment inside the true box: IoU 600 / 2400 = 0.25
    (boxes([110, 110, 130, 140]), boxes(), "too small", 0),
    # shifted by half its width: IoU 1200 / 3600 = 0.33, neither holds the other
    (boxes([120, 100, 160, 160]), boxes(), "displaced", 0),
    # swallowed whole by a segment 25x its size (IoU 0.04): the smallest that holds it
    (boxes([0, 0, 400, 120], [0, 0, 300, 200]), boxes(), "too large", 1),
    # slivers only (IoU 0.02 and 0.04): the largest
    (boxes([101, 101, 105, 113], [101, 101, 105, 125]), boxes(), "too small", 1),
    # a corner touch only (IoU < 0.1) and no proposal at all
    (boxes([135, 155, 200, 220]), boxes(), "nothing near", -1),
    (boxes(), boxes(), "nothing near", -1),
])
def test_miss_cause(plausible, kept, cause, best):
    got, row = miss_cause(TRUTH, plausible, kept)
    assert MISS_CAUSES[got] == cause and row == best


def test_cause_tables_count_shares_range_and_carried():
    # (cause index, source of the best, range m, carried)
    causes = [(0, "mesh", 1.0, False), (0, "geometry", 0.8, True), (2, "image", 4.0, False),
              (2, "image", 5.0, True), (5, "", 1.5, False)]
    row = cause_row("v", "geometry+image", causes, reach_m=3.5)
    assert row[:3] == ["v", "geometry+image", 5]
    assert row[3:3 + len(MISS_CAUSES)] == pytest.approx([40.0, 0.0, 40.0, 0.0, 0.0, 20.0])
    assert row[-2:] == pytest.approx([200 / 3, 100 / 3])   # of the 3 not covered: 2 beyond 3.5 m, 1 carried
    assert cause_detail(causes) == [["too large", "image", 2, 40.0, 4.5, 1], ["nothing near", "-", 1, 20.0, 1.5, 0]]
