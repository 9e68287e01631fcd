"""Pictures of a tracker's run on one recording, and the HTML page that shows them.

Everything here draws from plain arrays (:class:`PlotScene`, :class:`TrackerRun`); reading the
recording, its truth and the results folders is the ``plot`` step's job
(:mod:`egograph.steps.plot`). Figures are matplotlib (Agg) and written as PNG with no metadata
that changes between runs (no software version, no date), so the same inputs give the same bytes.

Frames and units: positions are in the recording's world frame, metres; the HoloLens world has
y up, so the map is the x-z plane seen from above (x to the right, z down the page, which keeps
the view unmirrored). Times are seconds from the first PV frame. Every figure is
:data:`WIDTH_IN` inches wide at :data:`DPI` dots per inch.
"""

from __future__ import annotations

import html
import io
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from egograph.core.types import PositionInterval
from egograph.core.units import TICKS_PER_SECOND
from egograph.eval.protocol import GtInterval
from egograph.eval.report import EvalReport, format_metric_cells, threshold_label
from egograph.geometry.hl2ss import pv_project, transform_points, world_to_pv_matrix

DPI = 100
"""Dots per inch of every PNG."""
WIDTH_IN = 12.0
"""Width of every figure, inches (``WIDTH_IN * DPI`` pixels)."""
LANE_IN = 1.1
"""Height of one instance's lane in the timeline, inches."""
TILE_IN = 2.0
"""Height of one row of the PV contact sheet, inches."""
SHEET_OFFSETS_S = (-1.0, -0.25, 0.25, 1.0)
"""Seconds from a break (the last frame of a true interval) of the frames shown around it."""
MAX_BREAKS = 8
"""Breaks shown on the contact sheet (the first ones in time)."""
ERROR_BANDS_M = (0.25, 1.0)
"""Prediction error bands of the timeline (metres): good, fair, bad beyond the last."""
_BAND_COLOURS = ("#1a9850", "#fdae61", "#d73027")
_NO_TRUTH = "#bdbdbd"
_TRUE_DET, _FALSE_DET, _UNKNOWN_DET = "#1f78b4", "#e31a1c", "#222222"
_CARRY = "#984ea3"
_TRUTH_SHADES = ("#4d4d4d", "#969696")      # alternate, so that two true intervals in a row show apart
_INTERVAL_SHADES = ("#3a7dc9", "#9cc3ea")   # the same for the tracker's intervals


# --------------------------------------------------------------------------- inputs


@dataclass
class DetectionTicks:
    """Detections of one set: per instance the PV frame indices, and whether each is false
    (True), true (False) or unknown (no synthetic truth: ``is_false`` None)."""

    name: str
    frames: dict[int, np.ndarray]
    is_false: dict[int, np.ndarray] | None = None


@dataclass
class PvFrames:
    """PV images (``image(i)`` -> (H, W, 3) uint8 RGB or None), their poses (N, 4, 4) row-vector
    camera -> world and validity, and the hl2ss 4x4 intrinsics."""

    image: Callable[[int], np.ndarray | None]
    poses: np.ndarray
    valid: np.ndarray
    intrinsics: np.ndarray


@dataclass
class PlotScene:
    """What the pictures show of a recording.

    ``timestamps`` (N,) PV frames, ticks; ``labels`` instance names (index = id); ``gt`` the
    annotated intervals (3d_center_annot.txt); ``stationary`` ``(instance, t_start, t_end)`` from
    motion_state_annot.txt (used where there is no 3D centre annotation); ``carries`` (N, K) bool
    (synthetic truth: instance k is carried at frame i) or None; ``camera`` (N, 3) PV camera
    centres (NaN where the pose is invalid); ``mesh_xz`` (M, 2) triangle centres' x and z, or None.
    """

    recording: str
    timestamps: np.ndarray
    labels: list[str]
    gt: list[GtInterval] = field(default_factory=list)
    stationary: list[tuple[int, int, int]] = field(default_factory=list)
    carries: np.ndarray | None = None
    camera: np.ndarray | None = None
    mesh_xz: np.ndarray | None = None
    detections: DetectionTicks | None = None
    pv: PvFrames | None = None

    @property
    def times_s(self) -> np.ndarray:
        ts = np.asarray(self.timestamps, dtype=np.int64)
        return (ts - ts[0]) / TICKS_PER_SECOND if len(ts) else np.zeros(0)

    def name(self, instance: int) -> str:
        return self.labels[instance] if 0 <= instance < len(self.labels) else str(instance)


@dataclass
class TrackerRun:
    """One tracker's results: ``predictions`` instance -> (N, 3) world xyz (metres, NaN where the
    frame has none), its position ``intervals`` (None for per-frame trackers), its evaluation."""

    name: str
    predictions: dict[int, np.ndarray]
    intervals: list[PositionInterval] | None = None
    report: EvalReport | None = None
    detections: DetectionTicks | None = None   # the detections it was tracked with (the scene's when None)


# --------------------------------------------------------------------------- numbers


def prediction_errors(scene: PlotScene, run: TrackerRun) -> dict[int, np.ndarray]:
    """instance -> (N,) distance (metres) of each frame's prediction to the centre of the true
    interval covering the frame (the first, if two do); NaN without prediction or covering interval."""
    ts = np.asarray(scene.timestamps, dtype=np.int64)
    out = {}
    for inst, xyz in run.predictions.items():
        err = np.full(len(ts), np.nan)
        for g in reversed([g for g in scene.gt if g.instance == inst]):  # the first interval wins
            cov = (ts >= g.t_start) & (ts <= g.t_end)
            err[cov] = np.linalg.norm(xyz[cov] - np.asarray(g.xyz), axis=1)
        out[inst] = err
    return out


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[(first, last), ...]`` inclusive index ranges where ``mask`` is True."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.flatnonzero(np.diff(m.astype(np.int8)))
    return [(int(a), int(b) - 1) for a, b in zip(d[::2], d[1::2])]


def _frame_step_s(t: np.ndarray) -> float:
    return float(np.median(np.diff(t))) if len(t) > 1 else 1.0 / 30


def _spans(t: np.ndarray, mask: np.ndarray) -> list[tuple[float, float]]:
    """``broken_barh`` spans (start s, width s) of the runs of ``mask``, a frame wide at least."""
    dt = _frame_step_s(t)
    return [(t[a], t[b] - t[a] + dt) for a, b in runs(mask)]


def _tick_spans(scene: PlotScene, t0: int, t1: int) -> tuple[float, float]:
    base = int(scene.timestamps[0])
    dt = _frame_step_s(scene.times_s)
    return ((t0 - base) / TICKS_PER_SECOND, (t1 - t0) / TICKS_PER_SECOND + dt)


def instances_of(scene: PlotScene, trackers: Sequence[TrackerRun]) -> list[int]:
    """Instances with truth, predictions, intervals or detections, in id order."""
    ids = {g.instance for g in scene.gt} | {s[0] for s in scene.stationary}
    for r in trackers:
        ids |= {i for i, x in r.predictions.items() if np.isfinite(x).any()}
        ids |= {iv.instance for iv in r.intervals or ()}
    if scene.detections is not None:
        ids |= {i for i, f in scene.detections.frames.items() if len(f)}
    return sorted(ids)


# --------------------------------------------------------------------------- figures


def _figure(height_in: float, constrained: bool = True):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(WIDTH_IN, height_in), dpi=DPI, layout="constrained" if constrained else None)
    FigureCanvasAgg(fig)
    return fig


def png_bytes(fig) -> bytes:
    """The figure as PNG at :data:`DPI`, without the metadata that would differ between runs."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    return buf.getvalue()


def figure_size_px(height_in: float) -> tuple[int, int]:
    """(width, height) pixels of a figure :data:`WIDTH_IN` wide and ``height_in`` high."""
    return int(round(WIDTH_IN * DPI)), int(round(height_in * DPI))


def _instance_colour(k: int):
    from matplotlib import colormaps

    return colormaps["tab10"](k % 10)


def _tracker_colour(k: int):
    from matplotlib import colormaps

    return colormaps["Dark2"](k % 8)


# nine markers against eight colours: a (marker, colour) pair repeats only after 72 trackers
_TRACKER_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*", "h")


def timeline_height_in(n_instances: int) -> float:
    return 1.2 + LANE_IN * max(n_instances, 1)


def plot_timeline(scene: PlotScene, run: TrackerRun) -> bytes:
    """One lane per instance, four rows each: the truth (true intervals, carries in orange), the
    tracker's intervals, its per-frame predictions coloured by error (green <= 0.25 m, orange
    <= 1 m, red beyond, grey where no true interval covers the frame) and the detections as ticks
    (blue true, red false, dark grey when unknown). PNG bytes."""
    from matplotlib.patches import Patch

    insts = instances_of(scene, [run])
    fig = _figure(timeline_height_in(len(insts)))
    axes = fig.subplots(max(len(insts), 1), 1, sharex=True, squeeze=False)[:, 0]
    t = scene.times_s
    errors = prediction_errors(scene, run)
    for ax, inst in zip(axes, insts):
        truth = [g for g in scene.gt if g.instance == inst]
        bars = [_tick_spans(scene, g.t_start, g.t_end) for g in truth]
        if not truth:
            bars = [_tick_spans(scene, a, b) for i, a, b in scene.stationary if i == inst]
        ax.broken_barh(bars, (2.6, 0.8), facecolors=[_TRUTH_SHADES[k % 2] for k in range(len(bars))])
        if scene.carries is not None and inst < scene.carries.shape[1]:
            ax.broken_barh(_spans(t, scene.carries[:, inst]), (2.6, 0.8), facecolors=_CARRY)
        ivs = [iv for iv in run.intervals or () if iv.instance == inst]
        bars = [_tick_spans(scene, iv.t_start, iv.t_end) for iv in ivs]
        ax.broken_barh(bars, (1.6, 0.8), facecolors=[_INTERVAL_SHADES[k % 2] for k in range(len(bars))])
        if run.intervals is None:
            ax.text(0.005, 2.0, "none: a per-frame tracker", transform=ax.get_yaxis_transform(), va="center",
                    fontsize=7, color="grey")
        if inst in run.predictions:
            has = np.isfinite(run.predictions[inst]).all(axis=1)
            err = errors[inst]
            lo, hi = ERROR_BANDS_M
            for mask, c in ((has & np.isnan(err), _NO_TRUTH), (err <= lo, _BAND_COLOURS[0]),
                            ((err > lo) & (err <= hi), _BAND_COLOURS[1]), (err > hi, _BAND_COLOURS[2])):
                ax.broken_barh(_spans(t, mask), (0.65, 0.7), facecolors=c)
        det = scene.detections or run.detections
        if det is not None and inst in det.frames:
            frames = det.frames[inst]
            false = det.is_false.get(inst) if det.is_false is not None else None
            groups = [(frames, _UNKNOWN_DET)] if false is None else [(frames[~false], _TRUE_DET),
                                                                     (frames[false], _FALSE_DET)]
            for f, c in groups:
                ax.vlines(t[f], -0.35, 0.35, colors=c, linewidth=0.8)
        ax.set_ylim(-0.6, 3.6)
        ax.set_yticks([0, 1, 2, 3], ["detections", "predictions", "intervals", "truth"], fontsize=7)
        ax.set_ylabel(f"{inst} {scene.name(inst)}", rotation=0, ha="right", va="center", fontsize=9)
        ax.grid(True, axis="x", alpha=0.3)
    axes[-1].set_xlabel("time (s from the first PV frame)")
    if len(t):
        axes[-1].set_xlim(t[0], t[-1] + _frame_step_s(t))
    handles = [Patch(color=_TRUTH_SHADES[0], label="true interval"), Patch(color=_CARRY, label="carried (truth)"),
               Patch(color=_INTERVAL_SHADES[0], label="tracker interval"),
               Patch(color=_BAND_COLOURS[0], label=f"error <= {ERROR_BANDS_M[0]:g} m"),
               Patch(color=_BAND_COLOURS[1], label=f"<= {ERROR_BANDS_M[1]:g} m"),
               Patch(color=_BAND_COLOURS[2], label=f"> {ERROR_BANDS_M[1]:g} m"),
               Patch(color=_NO_TRUTH, label="no true interval")]
    shown = scene.detections or run.detections
    if shown is not None:
        if shown.is_false is not None:
            handles += [Patch(color=_TRUE_DET, label="true detection"), Patch(color=_FALSE_DET, label="false detection")]
        else:
            handles += [Patch(color=_UNKNOWN_DET, label="detection")]
    det_name = f", detections {shown.name}" if shown is not None else ""
    fig.suptitle(f"{scene.recording}: {run.name}{det_name}: timeline per instance")
    fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 6), fontsize=8, frameon=False)
    return png_bytes(fig)


MAP_HEIGHT_IN = 9.0


def _ellipse(ax, xz: np.ndarray, cov_xz: np.ndarray, colour, n_sigma: float = 2.0) -> None:
    from matplotlib.patches import Ellipse

    vals, vecs = np.linalg.eigh(np.asarray(cov_xz, dtype=np.float64))
    vals = np.clip(vals, 0.0, None)
    angle = float(np.degrees(np.arctan2(vecs[1, 1], vecs[0, 1])))  # the major axis
    ax.add_patch(Ellipse(tuple(xz), 2 * n_sigma * np.sqrt(vals[1]), 2 * n_sigma * np.sqrt(vals[0]), angle=angle,
                         facecolor="none", edgecolor=colour, linewidth=1.2))


def plot_map(scene: PlotScene, run: TrackerRun) -> bytes:
    """Top-down map (x-z, seen from above): the mesh's triangle density in grey, the PV camera
    path, the true centres (stars), the tracker's interval centres (circles) with 2-sigma ellipses
    of their x-z covariance. PNG bytes."""
    from matplotlib.lines import Line2D

    fig = _figure(MAP_HEIGHT_IN)
    ax = fig.subplots()
    pts = [np.zeros((0, 2))]
    if scene.mesh_xz is not None and len(scene.mesh_xz):
        m = scene.mesh_xz
        bins = int(np.clip(np.sqrt(len(m)), 40, 200))  # a sparse mesh in coarse cells, a dense one in fine
        h, xe, ze = np.histogram2d(m[:, 0], m[:, 1], bins=bins)
        ax.imshow(np.log1p(h.T), extent=(xe[0], xe[-1], ze[0], ze[-1]), origin="lower", cmap="Greys",
                  interpolation="nearest", aspect="auto", alpha=0.8)
        pts.append(np.array([[xe[0], ze[0]], [xe[-1], ze[-1]]]))
    if scene.camera is not None:
        cam = scene.camera[np.isfinite(scene.camera).all(axis=1)]
        if len(cam):
            ax.plot(cam[:, 0], cam[:, 2], color="black", linewidth=0.8, alpha=0.7)
            ax.plot(cam[0, 0], cam[0, 2], marker=">", color="black", markersize=6)
            pts.append(cam[:, [0, 2]])
    for g in scene.gt:
        c = _instance_colour(g.instance)
        ax.plot(g.xyz[0], g.xyz[2], marker="*", markersize=14, color=c, markeredgecolor="black")
        ax.annotate(f"{g.instance} {scene.name(g.instance)}", (g.xyz[0], g.xyz[2]), xytext=(6, 6),
                    textcoords="offset points", fontsize=8)
        pts.append(np.array([[g.xyz[0], g.xyz[2]]]))
    for iv in run.intervals or ():
        c = _instance_colour(iv.instance)
        xz = np.array([iv.xyz[0], iv.xyz[2]])
        ax.plot(*xz, marker="o", markersize=6, color=c, markeredgecolor="black")
        cov = np.asarray(iv.covariance, dtype=np.float64)[np.ix_([0, 2], [0, 2])]
        _ellipse(ax, xz, cov, c)
        pts.append(xz[None])
    allp = np.concatenate(pts)
    if len(allp):
        lo, hi = allp.min(axis=0), allp.max(axis=0)
        pad = 0.05 * max(float((hi - lo).max()), 1.0)
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(hi[1] + pad, lo[1] - pad)  # z down the page: the view from above, not mirrored
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m, down the page: seen from above, world y up)")
    ax.grid(True, alpha=0.3)
    handles = [Line2D([], [], color="black", linewidth=0.8, label="PV camera path (> start)"),
               Line2D([], [], marker="*", linestyle="", color="grey", markeredgecolor="black", markersize=12,
                      label="true centre"),
               Line2D([], [], marker="o", linestyle="", color="grey", markeredgecolor="black",
                      label="interval centre, 2-sigma ellipse")]
    if scene.mesh_xz is not None:
        handles.insert(0, Line2D([], [], marker="s", linestyle="", color="#999999", label="mesh (triangle density)"))
    fig.legend(handles=handles, loc="outside right upper", fontsize=8)
    ax.set_title(f"{scene.recording}: {run.name}: top-down map (x-z)")
    return png_bytes(fig)


METRICS_HEIGHT_IN = 8.0


def plot_metrics(scene: PlotScene, trackers: Sequence[TrackerRun]) -> bytes:
    """Error over time (every per-frame prediction's distance to the covering true centre, metres;
    one colour per tracker) above precision and recall (percent) against threshold (metres),
    one line per tracker; the legend right of the plots. PNG bytes."""
    fig = _figure(METRICS_HEIGHT_IN)
    grid = fig.add_gridspec(2, 2, height_ratios=(1.2, 1.0))
    ax_e = fig.add_subplot(grid[0, :])
    ax_p, ax_r = fig.add_subplot(grid[1, 0]), fig.add_subplot(grid[1, 1])
    t = scene.times_s
    for k, run in enumerate(trackers):
        c, mk = _tracker_colour(k), _TRACKER_MARKERS[k % len(_TRACKER_MARKERS)]
        errs = prediction_errors(scene, run)
        tt = np.concatenate([t[np.isfinite(e)] for e in errs.values()] or [np.zeros(0)])
        ee = np.concatenate([e[np.isfinite(e)] for e in errs.values()] or [np.zeros(0)])
        ax_e.scatter(tt, ee, s=4, color=c, marker=mk, linewidths=0, label=run.name)
        if run.report is not None:
            tot = run.report.total
            th = np.asarray(tot.thresholds)
            ax_p.plot(th, 100 * tot.precision, marker=mk, color=c)
            ax_r.plot(th, 100 * tot.recall, marker=mk, color=c)
    for th in ERROR_BANDS_M:
        ax_e.axhline(th, color="grey", linewidth=0.6, linestyle="--")
    ax_e.set_xlabel("time (s from the first PV frame)")
    ax_e.set_ylabel("error (m)")
    ax_e.set_title("distance of each prediction to the true centre covering its frame")
    ax_e.set_ylim(bottom=0)
    if len(t):
        ax_e.set_xlim(t[0], t[-1])
    for ax, what in ((ax_p, "precision"), (ax_r, "recall")):
        ax.set_xlabel("threshold τ (m)")
        ax.set_ylabel(f"{what} (%)")
        ax.set_title(f"{what} against threshold")
        ax.set_ylim(0, 100)
        ax.grid(True, alpha=0.3)
    ax_e.grid(True, alpha=0.3)
    fig.suptitle(f"{scene.recording}: {', '.join(r.name for r in trackers)}")
    fig.legend(*ax_e.get_legend_handles_labels(), loc="outside right upper", markerscale=3, fontsize=9,
               title="tracker")
    return png_bytes(fig)


CURVES_HEIGHT_IN = 4.2


def plot_curves(scene: PlotScene, trackers: Sequence[TrackerRun]) -> bytes | None:
    """Precision against recall (percent) as the confidence threshold sweeps, one panel per
    threshold τ, one line per tracker (its answers by their confidence, the fifth column), and each
    tracker's operating point (what its per-frame files hold) as a marker; AP (all-point
    interpolated) in the legend. None without an evaluation. PNG bytes."""
    runs = [r for r in trackers if r.report is not None and r.report.answers is not None]
    if not runs:
        return None
    taus = runs[0].report.thresholds
    fig = _figure(CURVES_HEIGHT_IN)
    axes = fig.subplots(1, len(taus), sharey=True, squeeze=False)[0]
    for k, run in enumerate(trackers):
        if run not in runs:
            continue
        c, mk = _tracker_colour(k), _TRACKER_MARKERS[k % len(_TRACKER_MARKERS)]
        curves = run.report.curves()
        tot = run.report.total
        for j, (ax, tau) in enumerate(zip(axes, taus)):
            cv = curves[tau]
            ax.step(100 * cv.recall, 100 * cv.precision, where="post", color=c, linewidth=1.0,
                    label=f"{run.name} (AP@{tau:g} {100 * cv.ap:.1f})" if j == 0 else None)
            ax.plot([100 * tot.recall[j]], [100 * tot.precision[j]], marker=mk, color=c, markersize=7,
                    markeredgecolor="black", linestyle="none")
    for ax, tau in zip(axes, taus):
        ax.set_title(f"τ = {tau:g} m")
        ax.set_xlabel("recall (%)")
        ax.set_xlim(0, 100)
        ax.set_ylim(0, 100)
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("precision (%)")
    fig.suptitle(f"{scene.recording}: precision against recall over confidence (markers: operating points)")
    fig.legend(loc="outside lower center", ncols=min(len(runs), 3), fontsize=8, frameon=False,
               title="AP at the first threshold; the others in index.html", title_fontsize=8)
    return png_bytes(fig)


def curve_rows(trackers: Sequence[TrackerRun]) -> tuple[list[str], list[list[str]]]:
    """Header and rows of the average-precision and calibration table: AP (percent, all-point
    interpolated) per threshold and the expected calibration error at 0.25 m."""
    from egograph.eval.curves import CALIBRATION_TAU, reliability

    runs = [r for r in trackers if r.report is not None and r.report.answers is not None]
    if not runs:
        return [], []
    taus = runs[0].report.thresholds
    header = ["tracker"] + [f"AP@{threshold_label(t)}" for t in taus] + [f"ECE@{CALIBRATION_TAU:g}"]
    rows = []
    for run in runs:
        curves = run.report.curves()
        rel = reliability(run.report.answers, CALIBRATION_TAU)
        rows.append([run.name] + [f"{100 * curves[t].ap:.1f}" for t in taus] + [f"{rel.ece:.3f}"])
    return header, rows


def breaks(scene: PlotScene) -> list[tuple[int, int]]:
    """``(instance, t_end)`` of the true intervals that end before the last frame (the object is
    picked up), in time order, at most :data:`MAX_BREAKS`."""
    last = int(scene.timestamps[-1]) if len(scene.timestamps) else 0
    ends = sorted({(g.t_end, g.instance) for g in scene.gt if g.t_end < last})
    return [(i, t) for t, i in ends[:MAX_BREAKS]]


def sheet_rows(scene: PlotScene) -> list[tuple[str, int | None, list[int]]]:
    """Rows of the contact sheet: ``(title, instance or None for all, frame indices)``: the frames
    :data:`SHEET_OFFSETS_S` around each break, or without a break frames spread over the recording."""
    ts = np.asarray(scene.timestamps, dtype=np.int64)
    n = len(ts)
    rows = []
    for inst, t_end in breaks(scene):
        frames = []
        for off in SHEET_OFFSETS_S:
            target = t_end + int(round(off * TICKS_PER_SECOND))
            frames.append(int(np.clip(np.searchsorted(ts, target), 0, n - 1)))
        rows.append((f"break of {inst} {scene.name(inst)} at {(t_end - ts[0]) / TICKS_PER_SECOND:.1f} s", inst,
                     frames))
    if not rows and n:
        frames = sorted({int(round(x)) for x in np.linspace(0, n - 1, len(SHEET_OFFSETS_S))})
        rows.append(("no break: frames across the recording", None, frames))
    return rows


def sheet_height_in(n_rows: int) -> float:
    return 0.9 + TILE_IN * max(n_rows, 1)


def plot_contact_sheet(scene: PlotScene, trackers: Sequence[TrackerRun], scale: float = 0.25) -> bytes:
    """PV frames around each break (rows) with every tracker's prediction projected into them
    (one marker and colour per tracker) and the true centre (white cross) when a true interval
    covers the frame; a break's row shows its instance, the no-break row every instance. Frames
    are shown at ``scale`` of their size. PNG bytes."""
    import cv2
    from matplotlib.lines import Line2D

    pv = scene.pv
    rows = sheet_rows(scene)
    cols = len(SHEET_OFFSETS_S)
    fig = _figure(sheet_height_in(len(rows)))
    axes = fig.subplots(max(len(rows), 1), cols, squeeze=False)
    ts = np.asarray(scene.timestamps, dtype=np.int64)
    for r, (title, inst, frames) in enumerate(rows):
        for c in range(cols):
            ax = axes[r, c]
            ax.set_xticks([])
            ax.set_yticks([])
            if c >= len(frames):
                ax.set_axis_off()
                continue
            i = frames[c]
            img = pv.image(i) if pv is not None else None
            if img is None:
                ax.text(0.5, 0.5, "no PV image", ha="center", va="center", transform=ax.transAxes)
                ax.set_title(f"frame {i}", fontsize=8)
                continue
            small = cv2.resize(img, (int(img.shape[1] * scale), int(img.shape[0] * scale)),
                               interpolation=cv2.INTER_AREA)
            ax.imshow(small, interpolation="nearest")
            ax.set_xlim(0, small.shape[1])
            ax.set_ylim(small.shape[0], 0)
            ax.set_title(f"frame {i}, {(ts[i] - ts[0]) / TICKS_PER_SECOND:.2f} s", fontsize=8)
            if c == 0:
                ax.set_ylabel(title, fontsize=8)
            if not pv.valid[i]:
                continue
            world_to_cam = world_to_pv_matrix(pv.poses[i])

            def project(xyz):
                uv, depth = pv_project(transform_points(np.asarray(xyz, float)[None], world_to_cam), pv.intrinsics)
                return (uv[0] * scale) if depth[0] > 0 else None

            shown = [inst] if inst is not None else sorted({g.instance for g in scene.gt}
                                                           | {k for run in trackers for k in run.predictions})
            for k in shown:
                for g in scene.gt:
                    if g.instance == k and g.t_start <= ts[i] <= g.t_end:
                        uv = project(g.xyz)
                        if uv is not None:
                            ax.plot(*uv, marker="+", color="white", markersize=12, markeredgewidth=2)
                            left = uv[0] > small.shape[1] / 2  # the name inside the frame, not cut at its edge
                            ax.annotate(scene.name(k), tuple(uv), xytext=(-6 if left else 6, -11),
                                        textcoords="offset points", ha="right" if left else "left", color="white",
                                        fontsize=7)
                for m, run in enumerate(trackers):
                    xyz = run.predictions.get(k)
                    if xyz is None or not np.isfinite(xyz[i]).all():
                        continue
                    uv = project(xyz[i])
                    if uv is not None:
                        ax.plot(*uv, marker=_TRACKER_MARKERS[m % len(_TRACKER_MARKERS)], color=_tracker_colour(m),
                                markeredgecolor="white", markersize=7, linestyle="")
    handles = [Line2D([], [], marker="+", color="white", markeredgecolor="black", linestyle="", markersize=10,
                      label="true centre")]
    handles += [Line2D([], [], marker=_TRACKER_MARKERS[m % len(_TRACKER_MARKERS)], color=_tracker_colour(m),
                       linestyle="", label=run.name) for m, run in enumerate(trackers)]
    fig.suptitle(f"{scene.recording}: predictions projected into PV frames around each break")
    fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 4), fontsize=8, frameon=False)
    return png_bytes(fig)


# --------------------------------------------------------------------------- HTML


def slug(name: str) -> str:
    """A file-name-safe form of a tracker name."""
    s = re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._")
    return s or "tracker"


def evaluation_rows(trackers: Sequence[TrackerRun]) -> tuple[list[str], list[list[str]]]:
    """Header and rows of the evaluation table (P, R, PCL percent; L2 metres; angle radians;
    intervals recovered; median break-time error, seconds)."""
    reports = [r.report for r in trackers if r.report is not None]
    if not reports:
        return [], []
    labels = [threshold_label(t) for t in reports[0].thresholds]
    cols = [f"P@{x}" for x in labels] + [f"R@{x}" for x in labels] + ["L2 (m)", "angle (rad)", "PCL@0.3"]
    header = ["tracker"] + cols + ["intervals recovered", "median break error (s)"]
    rows = []
    for run in trackers:
        if run.report is None:
            continue
        cells = format_metric_cells(run.report.total)
        iv = run.report.intervals
        rec = f"{iv.n_recovered}/{iv.n_true}" if iv is not None else "n/a"
        med = iv.median_break_error_s if iv is not None else None
        rows.append([run.name] + [cells[c] for c in cols] + [rec, f"{med:.2f}" if med is not None else "n/a"])
    return header, rows


def html_report(scene: PlotScene, trackers: Sequence[TrackerRun], images: Mapping[str, Sequence[str]],
                notes: Sequence[str] = ()) -> str:
    """``index.html``: the evaluation table and every image (``section title -> file names``,
    relative links, so the folder opens from disk). No date or path in it: same inputs, same bytes."""
    e = html.escape
    out = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
           f"<title>egograph: {e(scene.recording)}</title>",
           "<style>body{font-family:sans-serif;margin:1.5em;max-width:1250px}"
           "table{border-collapse:collapse;font-size:90%}td,th{border:1px solid #ccc;padding:3px 6px}"
           "td{text-align:right}td:first-child{text-align:left}img{max-width:100%;border:1px solid #ddd}</style>",
           "</head>", "<body>", f"<h1>{e(scene.recording)}</h1>",
           f"<p>{len(scene.timestamps)} PV frames, {len(scene.labels)} instances; trackers: "
           f"{e(', '.join(r.name for r in trackers))}.</p>"]
    for note in notes:
        out.append(f"<p><em>{e(note)}</em></p>")
    header, rows = evaluation_rows(trackers)
    out.append("<h2>Evaluation (IT3DEgo protocol)</h2>")
    if rows:
        out.append("<p>Precision, recall and PCL in percent; L2 in metres; angle in radians; n/a = undefined.</p>")
        out.append("<table><tr>" + "".join(f"<th>{e(h)}</th>" for h in header) + "</tr>")
        out += ["<tr>" + "".join(f"<td>{e(c)}</td>" for c in row) + "</tr>" for row in rows]
        out.append("</table>")
    else:
        out.append("<p>No evaluation: the recording has no annotated 3D centres.</p>")
    header, rows = curve_rows(trackers)
    if rows:
        out.append("<h2>Average precision over confidence, and calibration</h2>")
        out.append("<p>Each tracker's answers sorted by confidence (the per-frame files' fifth column, or every "
                   "answer in answers.tsv): average precision in percent, all-point interpolated (the area under the "
                   "precision envelope, as PASCAL VOC 2010+ and COCO without the 101-point sampling); expected "
                   "calibration error of the confidence against the share of answers within 0.25 m (10 bins).</p>")
        out.append("<table><tr>" + "".join(f"<th>{e(h)}</th>" for h in header) + "</tr>")
        out += ["<tr>" + "".join(f"<td>{e(c)}</td>" for c in row) + "</tr>" for row in rows]
        out.append("</table>")
    for title, files in images.items():
        out.append(f"<h2>{e(title)}</h2>")
        out += [f'<p><a href="{e(f)}"><img src="{e(f)}" alt="{e(title)}: {e(f)}"></a></p>' for f in files]
    out += ["</body>", "</html>"]
    return "\n".join(out) + "\n"


def write_bytes(folder: Path, name: str, data: bytes) -> Path:
    """Write one output into a folder being built (a temporary folder before its rename)."""
    path = Path(folder) / name
    path.write_bytes(data)
    return path
