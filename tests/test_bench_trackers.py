"""tools/bench_trackers.py: the calibration bands of the simulated front-ends, and what a run without
reference lifting says about them."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))

from bench_trackers import calibration_bands  # noqa: E402

from egograph.eval.protocol import THRESHOLDS, Counts  # noqa: E402


def _counts(p025: float, p15: float, l2: float, n: int = 1000) -> Counts:
    """Counts of ``n`` predictions with precision ``p025`` at 0.25 m, ``p15`` at 1.5 m (%, linear
    between) and mean L2 ``l2`` metres."""
    p = np.interp(THRESHOLDS, [THRESHOLDS[0], THRESHOLDS[-1]], [p025, p15]) / 100
    tp = np.round(p * n).astype(int)
    return Counts(tp=tp, fp=n - tp, fn=n - tp, n_gt=n, n_pred=n, l2_sum=l2 * n, l2_n=n)


def test_bands_hold_and_fail_as_the_pooled_values_say():
    inside = {"svoe": [_counts(23, 59, 1.35)] * 3, "mvpe": [_counts(56, 74, 0.67)] * 3}
    lines, verdict = calibration_bands(inside)
    assert verdict is True and lines[-1] == "\nall bands hold: True"
    assert sum(" OK " in line for line in lines) == 6
    # the MVPE L2 just above its band's top (0.9 m), as the device world's memory + reference lifting sits
    edge = {**inside, "mvpe": [_counts(56, 74, 0.91)] * 3}
    lines, verdict = calibration_bands(edge)
    assert verdict is False and lines[-1] == "\nall bands hold: False"
    assert [line.split(":")[0] for line in lines if " OUT " in line] == ["mvpe L2 (m)"]


def test_a_run_without_reference_lifting_does_not_say_the_bands_hold():
    lines, verdict = calibration_bands({})
    assert verdict is None
    assert lines == ["\nall bands hold: not checked (no memory on reference lifting in this run: `--modes robust`)"]
    # one set checked is a verdict on that set alone
    lines, verdict = calibration_bands({"svoe": [_counts(23, 59, 1.35)]})
    assert verdict is True and len(lines) == 4
