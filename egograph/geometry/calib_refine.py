"""Fit the AHAT-to-PV calibration to a sequence: the AHAT camera's rotation and translation relative
to the rig (hence to the PV camera) and the AHAT time offset that minimise the fit score
(:mod:`egograph.geometry.calib_fit`).

Three searches (scipy's Powell) over 7 numbers -- a rotation vector (deg) and a translation (cm)
applied to the AHAT camera in its own frame, and the time offset (ms): on the coarse edges of
``calib_fit`` (40 px reach: finds errors of degrees and centimetres), then twice on fine edges
(``FINE``), each from the last result with a quarter of its steps. The alias hypotheses of the depth edges are unwrapped once per search
with its starting calibration and then held fixed, so the cost is continuous in the 7 numbers. The
rays (uv2xy) and the PV intrinsics are kept.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from egograph.geometry.calib_fit import FitCandidate, FitSample, FitScore, fit_cost, fit_score, hypotheses, prepare_fit
from egograph.geometry.config import CalibFitConfig
from egograph.geometry.hl2ss import invert_rigid
from egograph.io.poses import so3_exp, so3_log

FINE = {"blur_px": 2.0, "edge_percentile": 85.0, "truncate_px": 10.0}
"""The later searches' edges: sharp (2 px blur), dense, 10 px reach."""

STEPS = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0, 20.0])
"""First steps of the first search: deg, deg, deg, cm, cm, cm, ms (each restart: a quarter of the last's)."""


@dataclass
class CalibrationRefinement:
    """A refined calibration: the AHAT calibration with the new extrinsics and time offset, the change
    (``rotation_deg`` (3,) rotation vector and ``translation_m`` (3,) of the AHAT camera in its own
    frame, ``time_offset_ms`` the new offset), the scores before and after on the same sample, and the
    cost evaluations spent."""

    candidate: FitCandidate
    rotation_deg: np.ndarray
    translation_m: np.ndarray
    time_offset_ms: float
    before: FitScore
    after: FitScore
    evaluations: int

    def to_json(self) -> dict:
        return {"rotation_deg": [float(v) for v in self.rotation_deg],
                "rotation_angle_deg": float(np.linalg.norm(self.rotation_deg)),
                "translation_m": [float(v) for v in self.translation_m],
                "translation_norm_m": float(np.linalg.norm(self.translation_m)),
                "time_offset_ms": self.time_offset_ms, "before": self.before.to_json(),
                "after": self.after.to_json(), "evaluations": self.evaluations}


def perturbed(cand: FitCandidate, rotvec_rad: np.ndarray, translation_m: np.ndarray, time_offset_ms: float,
              name: str = "") -> FitCandidate:
    """``cand`` with its AHAT camera moved by a rigid change ``D`` in its own frame (AHAT camera ->
    rig node becomes ``D`` then the old one: ``extrinsics @ inv(D)``, row vectors) and the given time
    offset."""
    d = np.eye(4)
    d[:3, :3] = so3_exp(np.asarray(rotvec_rad, float)).T   # row-vector block of the column rotation
    d[3, :3] = translation_m
    ahat = dataclasses.replace(cand.ahat, extrinsics=np.asarray(cand.ahat.extrinsics, float) @ invert_rigid(d),
                               time_offset_ms=float(time_offset_ms))
    return FitCandidate(ahat, cand.pv, float(time_offset_ms), name or cand.name)


def change_between(a: FitCandidate, b: FitCandidate) -> tuple[np.ndarray, np.ndarray, float]:
    """The change ``D`` (:func:`perturbed`) that takes ``a``'s AHAT extrinsics to ``b``'s: rotation vector
    (rad, (3,)), translation (m, (3,)), and ``b``'s time offset minus ``a``'s (ms)."""
    d = invert_rigid(np.asarray(b.ahat.extrinsics, float)) @ np.asarray(a.ahat.extrinsics, float)
    return so3_log(d[:3, :3].T), d[3, :3].copy(), b.time_offset_ms - a.time_offset_ms


def _stage(rec, sample: FitSample, start: FitCandidate, cfg: CalibFitConfig, steps: np.ndarray,
           max_evaluations: int, method: str = "powell") -> tuple[np.ndarray, int]:
    from scipy.optimize import minimize

    points = hypotheses(rec, sample, start, cfg)
    scale = np.array([np.pi / 180] * 3 + [0.01] * 3 + [1.0])

    def cost(x):
        c = fit_cost(rec, sample, perturbed(start, x[:3] * scale[:3], x[3:6] * scale[3:6],
                                            start.time_offset_ms + x[6]), cfg, points)
        return c if np.isfinite(c) else 1e9

    if method == "powell":
        res = minimize(cost, np.zeros(7), method="Powell", options={"direc": np.diag(steps), "xtol": 1e-2,
                                                                    "ftol": 1e-5, "maxfev": max_evaluations})
    else:
        res = minimize(cost, np.zeros(7), method="Nelder-Mead",
                       options={"initial_simplex": np.vstack([np.zeros(7), np.diag(steps)]),
                                "maxfev": max_evaluations, "xatol": 1e-2, "fatol": 1e-4})
    x = res.x
    return x, int(res.nfev)


def refine_calibration(rec, cand: FitCandidate, cfg: CalibFitConfig, frames: int = 200,
                       max_evaluations: int = 1500) -> CalibrationRefinement:
    """Refine ``cand`` on ``frames`` sampled frames of ``rec`` (three searches, at most
    ``max_evaluations`` cost evaluations each); the scores before and after are on the same sample."""
    coarse = dataclasses.replace(cfg, frames=frames)
    sample = prepare_fit(rec, coarse)
    before = fit_score(rec, sample, cand, coarse)
    current, spent = cand, 0
    # Powell on the coarse edges (capture), then on the fine edges, restarted once with smaller steps.
    # Measured on seed 5 (100 frames, 2 deg / 3 cm / 40 ms injected), residual rotation / translation /
    # time offset: this schedule 0.22 deg / 11.1 mm / 0.0 ms; coarse edges only (Powell x3) 0.29 deg /
    # 21 mm; Powell then Nelder-Mead x2 0.31 deg / 21 mm; Nelder-Mead coarse + fine 0.83 deg / 22 mm.
    # The rotation about the AHAT x axis and the translation along y (and z) form a shallow valley;
    # 200 frames (the default) narrow it: this schedule then left 0.18 deg / 4.2 mm / 0.0 ms (seed 5)
    # and 0.15 deg / 6.6 mm (seed 7) with each depth edge pixel scored at its own centre and range, a
    # score whose minimum lies 4-7 mm from the truth; with the edge on the pair's mid ray at the near
    # range (calib_fit._hypotheses) 0.07 deg / 0.9 mm / 0.0 ms and 0.09 deg / 2.1 mm / 0.0 ms.
    fine = dataclasses.replace(coarse, **FINE)
    fine_sample = prepare_fit(rec, fine, frames=np.array([f.index for f in sample.frames]))
    stages = ((coarse, sample, STEPS), (fine, fine_sample, STEPS / 4), (fine, fine_sample, STEPS / 16))
    for stage_cfg, stage_sample, steps in stages:
        x, n = _stage(rec, stage_sample, current, stage_cfg, steps, max_evaluations)
        spent += n
        current = perturbed(current, np.radians(x[:3]), x[3:6] / 100.0, current.time_offset_ms + x[6])
    rot, trans, _ = change_between(cand, current)
    current = dataclasses.replace(current, name=(cand.name or "calibration") + " refined")
    after = fit_score(rec, sample, current, coarse)
    return CalibrationRefinement(current, np.degrees(rot), trans, current.time_offset_ms, before, after, spent)
