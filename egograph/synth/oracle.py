"""The oracle tracker of the benchmarks: the ceiling of lifting and poses on a synthetic recording.

Every true box (``synth_gt/<seq>/instances.npz``, frames where the object is at least a quarter
visible) is lifted with the pipeline's lifting, and each true interval's position is solved from
its own lifted boxes (the graph tracker's robust landmark); the position is predicted over the
whole true interval. It uses no detection set, so it is the same for SVOE and MVPE.
"""

from __future__ import annotations

import numpy as np

from egograph.core.types import Box, Detection, PositionInterval, TrackResult
from egograph.eval.metrics import gt_intervals
from egograph.track.intervals import per_frame_predictions
from egograph.track.segments import fixed_interval_estimate

MIN_VISIBLE = 0.25
"""Share of an object's silhouette that must be visible for its true box to count (0-1)."""


def true_box_detections(rec, min_visible: float = MIN_VISIBLE) -> dict[int, list[Detection]]:
    """The true PV boxes (pixels, x1 y1 x2 y2) of frames where the object is at least
    ``min_visible`` visible, as score-1 detections keyed by PV timestamp (ticks)."""
    with np.load(rec.synth_gt_dir / "instances.npz") as d:
        boxes, visible = d["boxes"], d["visible"]
    dets: dict[int, list[Detection]] = {}
    ts = np.asarray(rec.timestamps)
    for f, i in zip(*np.nonzero((visible >= min_visible) & np.isfinite(boxes[..., 0]))):
        dets.setdefault(int(ts[f]), []).append(Detection(int(i), Box(*map(float, boxes[f, i])), 1.0))
    return dets


def oracle_tracker(rec, obs, graph_cfg) -> TrackResult:
    """Oracle result from the lifted true boxes ``obs`` (lifted from :func:`true_box_detections`):
    per true interval with at least one lifted box, the landmark of those boxes (world, metres,
    with its covariance), predicted on every PV frame of the interval."""
    intervals = []
    for g in gt_intervals(rec):
        rows = np.flatnonzero(obs.valid & (obs.instance == g.instance) & (obs.timestamps >= g.t_start)
                              & (obs.timestamps <= g.t_end))
        if not len(rows):
            continue
        xyz, c = fixed_interval_estimate(obs.world[rows], obs.camera[rows], graph_cfg)
        intervals.append(PositionInterval(g.instance, g.t_start, g.t_end, tuple(map(float, xyz)), c.tolist(),
                                          len(rows), 1.0))
    per_frame = per_frame_predictions(intervals, np.asarray(rec.timestamps))
    return TrackResult(per_frame=per_frame, intervals=intervals,
                       metadata={"tracker": "oracle", "observations": len(obs)})
