"""Ground-truth re-estimation (``egograph regt``): the graph with the intervals fixed.

The stationary intervals come from ``motion_state_annot.txt``; every annotated 2D box
of ``2d_bbox_annot/`` inside an interval is a detection (score 1) of that interval's one
landmark. Boxes are lifted with robust lifting (mesh-unwrapped cluster depth, reported
poses), and each landmark is solved with the same robust, range-dependent detection
factors as the tracker; its covariance is the GTSAM marginal plus the tracker's
``covariance_floor_m``. The re-estimates are written in ``3d_center_annot.txt`` format
(``location_id`` counts the instance's earlier intervals), with covariances in JSON.

The *audit* compares the given centres (``3d_center_annot.txt``) with the re-estimates:
an interval is flagged when they differ by more than ``audit_m`` metres **and** by more
than ``audit_sigma`` standard deviations (Mahalanobis distance under the re-estimate's
covariance), so a well-seen interval is held to its precision and a poorly seen one is
not flagged for noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from egograph.core.types import Detection
from egograph.geometry.observations import Observations
from egograph.io.annotations import Annotations, CenterAnnotation
from egograph.track.config import GraphConfig, RegtConfig
from egograph.track.detection_factor import detection_covariances, mahalanobis2
from egograph.track.joint import Stand
from egograph.track.segments import fixed_interval_estimate


@dataclass
class Reestimate:
    instance: int
    t_start: int                    # ticks
    t_end: int                      # ticks
    location_id: int
    xyz: tuple[float, float, float] | None   # world, metres; None when no box of the interval lifted
    covariance: list[list[float]] | None     # 3x3, m^2
    n_views: int                    # lifted boxes used
    given: tuple[float, float, float] | None = None  # the annotated centre, when there is one
    distance_m: float | None = None
    sigmas: float | None = None
    flagged: bool = False
    extra: dict = field(default_factory=dict)


def box_detections(ann: Annotations) -> dict[int, list[Detection]]:
    """Annotated 2D boxes as per-frame detections with score 1 (``ts -> [Detection]``)."""
    out: dict[int, list[Detection]] = {}
    for inst, rows in ann.boxes.items():
        for ts, box in rows:
            out.setdefault(int(ts), []).append(Detection(int(inst), box, 1.0))
    return out


def reestimate_centres(ann: Annotations, obs: Observations, cfg: GraphConfig, regt: RegtConfig) -> list[Reestimate]:
    """One re-estimate per stationary interval of ``ann.motion`` from the lifted boxes ``obs``."""
    given = {(c.instance, c.t_start, c.t_end): c.xyz for c in ann.centers}
    count: dict[int, int] = {}
    out = []
    for mi, rows in interval_rows(ann, obs):
        loc = count.get(mi.instance, 0)
        count[mi.instance] = loc + 1
        est = Reestimate(mi.instance, mi.t_start, mi.t_end, loc, None, None, len(rows),
                         given.get((mi.instance, mi.t_start, mi.t_end)))
        if len(rows):
            xyz, c = fixed_interval_estimate(obs.world[rows], obs.camera[rows], cfg)
            est.xyz, est.covariance = tuple(float(v) for v in xyz), c.tolist()
            if est.given is not None:
                d = np.asarray(est.given) - xyz
                est.distance_m = float(np.linalg.norm(d))
                est.sigmas = float(np.sqrt(d @ np.linalg.solve(c, d)))
                est.flagged = est.distance_m > regt.audit_m and est.sigmas > regt.audit_sigma
        out.append(est)
    return out


def interval_rows(ann: Annotations, obs: Observations):
    """(motion interval, rows of ``obs`` lifted inside it) for every stationary interval, in
    instance and time order."""
    valid = obs.valid
    for mi in sorted(ann.motion, key=lambda m: (m.instance, m.t_start)):
        rows = np.flatnonzero(valid & (obs.instance == mi.instance) & (obs.timestamps >= mi.t_start)
                              & (obs.timestamps <= mi.t_end))
        yield mi, rows


def interval_stands(ann: Annotations, obs: Observations, cfg: GraphConfig, min_inliers: int) -> list[Stand]:
    """The annotated intervals as stands for the joint pose solve: each interval's lifted boxes
    within ``cfg.inlier_chi2`` of its re-estimate (at least ``min_inliers`` of them)."""
    out = []
    for mi, rows in interval_rows(ann, obs):
        if len(rows) < min_inliers:
            continue
        xyz, _ = fixed_interval_estimate(obs.world[rows], obs.camera[rows], cfg)
        cov = detection_covariances(obs.world[rows], obs.camera[rows], cfg.noise)
        inl = rows[mahalanobis2(obs.world[rows], xyz, cov) <= cfg.inlier_chi2]
        if len(inl) >= min_inliers:
            out.append(Stand(mi.instance, obs.frame[inl].astype(np.int64), obs.world[inl], xyz))
    return out


def as_center_annotations(estimates: list[Reestimate]) -> list[CenterAnnotation]:
    """``3d_center_annot.txt`` rows: the re-estimate, or the given centre where no box lifted
    (intervals with neither are left out)."""
    rows = []
    for e in estimates:
        xyz = e.xyz if e.xyz is not None else e.given
        if xyz is not None:
            rows.append(CenterAnnotation(e.t_start, e.t_end, e.instance, xyz, e.location_id))
    return rows


def audit_text(estimates: list[Reestimate], regt: RegtConfig) -> str:
    """Markdown audit: every flagged interval, then counts."""
    flagged = [e for e in estimates if e.flagged]
    lines = [f"# Audit of 3d_center_annot.txt (flag: > {regt.audit_m} m and > {regt.audit_sigma} sigma)", "",
             "| instance | location | t_start | t_end | views | given - re-estimate (m) | sigmas |", "|---|---|---|---|---|---|---|"]
    for e in flagged:
        lines.append(f"| {e.instance} | {e.location_id} | {e.t_start} | {e.t_end} | {e.n_views} | "
                     f"{e.distance_m:.3f} | {e.sigmas:.1f} |")
    n_given = sum(e.given is not None for e in estimates)
    n_none = sum(e.xyz is None for e in estimates)
    lines += ["", f"{len(flagged)} of {n_given} annotated centres flagged; {len(estimates)} intervals, "
                  f"{n_none} without any lifted box (kept as given)."]
    return "\n".join(lines) + "\n"
