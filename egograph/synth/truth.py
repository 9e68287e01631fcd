"""The synthetic truth a recording written by ``egograph synth`` carries (``synth_gt/<seq>/``),
joined with pipeline outputs for benchmarks and tests."""

from __future__ import annotations

import json

import numpy as np

from egograph.geometry.observations import Observations


def synth_lift_errors(rec, obs: Observations, detection_set: str) -> tuple[np.ndarray, np.ndarray]:
    """Per observation row: 3D error (metres, NaN when not lifted) against the synthetic truth, and is-true.

    Joins ``synth_gt/<seq>/detections_<set>.txt`` (``ts instance is_false ...``) with the
    true object centres ``instances.npz['positions']`` at the detection's PV frame. Rows
    of false detections get is-true False (their error is to the instance's true centre).
    """
    gt = rec.synth_gt_dir
    if gt is None:
        raise ValueError(f"{rec.seq_dir}: not a synthetic recording (no synth_gt/)")
    is_false: dict[tuple[int, int], bool] = {}
    for line in (gt / f"detections_{detection_set}.txt").read_text().splitlines():
        tok = line.split()
        if tok and not tok[0].startswith("#"):
            is_false[(int(tok[0]), int(tok[1]))] = tok[2] != "0"
    with np.load(gt / "instances.npz") as data:
        positions = data["positions"]
    truth = positions[obs.frame, obs.instance]
    err = np.linalg.norm(obs.world - truth, axis=1)
    true = np.array([not is_false.get((int(t), int(k)), True) for t, k in zip(obs.timestamps, obs.instance)], bool)
    return err, true


NEVER_VISIBLE_SHARE = 0.25
"""Visible share of the silhouette (0-1) an object must reach in some frame of a true interval for the
interval to count as seen: the share at which the annotators draw a box (design §4)."""


def never_visible_intervals(rec, min_visible: float = NEVER_VISIBLE_SHARE) -> tuple[int, int]:
    """``(count, total)``: true stationary intervals of a synthetic recording in which the object is
    never at least ``min_visible`` visible in PV, and all true intervals.

    Reads ``synth_gt/<seq>/intervals.json`` (inclusive PV frame ranges) and the per-frame visible
    shares ``instances.npz['visible']`` (occlusion by furniture, other objects and the hand, and
    truncation by the image border). ``rec``: a Recording or a recording root folder.
    """
    from pathlib import Path

    if isinstance(rec, (str, Path)):
        root = Path(rec)
        meta = json.loads((root / "recording.json").read_text())
        gt = root / "synth_gt" / meta["sequence"]
    else:
        gt = rec.synth_gt_dir
        if gt is None:
            raise ValueError(f"{rec.seq_dir}: not a synthetic recording (no synth_gt/)")
    intervals = json.loads((gt / "intervals.json").read_text())
    with np.load(gt / "instances.npz") as data:
        visible = data["visible"]
    never = sum(1 for iv in intervals
                if not (visible[iv["frame_start"]:iv["frame_end"] + 1, iv["instance"]] >= min_visible).any())
    return never, len(intervals)
