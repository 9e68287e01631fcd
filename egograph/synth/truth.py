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


def detections_against_truth(rec, det_dir) -> dict[str, np.ndarray]:
    """Every detection of the per-frame folder ``det_dir`` against the generator's true boxes
    (``synth_gt/<seq>/instances.npz``), for benchmarks and tests to apply their own rule:

    ``instance`` (D,) the detection's instance id; ``iou`` (D, K) its IoU with each instance's true
    (amodal, PV pixel) box at its frame, 0 where that instance has no box; ``visible`` (D, K) each
    instance's visible share at that frame; ``centre_inside`` (D, K) whether the detection's box
    centre lies in that true box; ``own`` (D,) whether its instance id is one of the K.
    """
    from egograph.io.detections import read_detection_dir

    if rec.synth_gt_dir is None:
        raise ValueError(f"{rec.seq_dir}: not a synthetic recording (no synth_gt/)")
    with np.load(rec.synth_gt_dir / "instances.npz") as gt:
        boxes, visible = gt["boxes"], gt["visible"]
    dets = read_detection_dir(det_dir, rec.timestamps)
    rows = [(i, d.instance, d.box.x_min, d.box.y_min, d.box.x_max, d.box.y_max)
            for i, ts in enumerate(rec.timestamps) for d in dets[int(ts)]]
    a = np.array(rows, np.float64).reshape(-1, 6)
    frame, b = a[:, 0].astype(int), a[:, 2:]
    tb = np.nan_to_num(boxes[frame].astype(np.float64), nan=0.0)          # (D, K, 4); no box: empty
    w = np.clip(np.minimum(b[:, None, 2], tb[..., 2]) - np.maximum(b[:, None, 0], tb[..., 0]), 0, None)
    h = np.clip(np.minimum(b[:, None, 3], tb[..., 3]) - np.maximum(b[:, None, 1], tb[..., 1]), 0, None)
    inter = w * h
    union = ((b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1]))[:, None] + (tb[..., 2] - tb[..., 0]) * (tb[..., 3] - tb[..., 1]) - inter
    cx, cy = (b[:, 0] + b[:, 2]) / 2, (b[:, 1] + b[:, 3]) / 2
    has_box = np.isfinite(boxes[frame, :, 0])
    inside = has_box & (tb[..., 0] <= cx[:, None]) & (cx[:, None] <= tb[..., 2]) & (tb[..., 1] <= cy[:, None]) \
        & (cy[:, None] <= tb[..., 3])
    instance = a[:, 1].astype(int)
    return {"instance": instance, "iou": np.where(union > 0, inter / np.maximum(union, 1e-12), 0.0),
            "visible": visible[frame].astype(np.float64), "centre_inside": inside,
            "own": (instance >= 0) & (instance < boxes.shape[1])}


def own_column(match: dict[str, np.ndarray], key: str) -> np.ndarray:
    """``match[key]`` (D, K) at each detection's own instance (D,); False / 0 for an unknown id."""
    col = np.clip(match["instance"], 0, match[key].shape[1] - 1)
    val = match[key][np.arange(len(col)), col]
    return np.where(match["own"], val, np.zeros_like(val))
