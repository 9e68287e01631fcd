"""Lift 2D detections (PV boxes) to 3D observations with AHAT depth (design §3, "Observations").

Two modes, chosen by :class:`LiftConfig` ``mode``:

``reference``
    The public IT3DEgo reference code's rule, reproduced exactly
    (:mod:`egograph.geometry.reference_lift`): one AHAT point per box, no unwrapping, so
    anything farther than the alias distance (1.055 m) comes out whole aliases too close.

``robust`` (default)
    Mesh-unwrapped, clustered box depth (:mod:`egograph.geometry.robust_lift`, with its
    limitations): per box, the AHAT pixels that can project into it, unwrapped with the
    HoloLens scene mesh and a size prior, registered into the PV image, and the nearest
    dominant range cluster's centroid pushed back to the object's centre.

Both modes keep the alias ambiguity as ``Observations.candidates``: the same ray at ranges
shifted by whole alias distances.

This module is the driver: per-frame chains (:mod:`egograph.geometry.chains`), depth frames
decoded ahead on other threads (:mod:`egograph.geometry.prefetch`), the rows of the output
and the :class:`LiftReport`.

Frames and units: AHAT camera (x right, y down, z forward), world (the recording's),
metres; PV image pixels (1280x720, continuous coordinates, pixel ``i`` covers
``[i, i+1)``). Points are row vectors multiplied on the right (``p_out = p_in @ M``); every
chain comes from :mod:`egograph.geometry.hl2ss`.

Partly bad input does not stop the lift: each detection that cannot be lifted is counted
under a reason in :class:`LiftReport`, as are the detection files that were skipped (read with
:func:`~egograph.io.detections.read_detection_dir`) and the PV frames without a usable pose.
Detections at a frame of the recording, for a known instance, stay in the output as unlifted
rows (``world`` NaN, ``chosen`` -1); detections at an unknown timestamp, for an unknown
instance, or that are not detections at all, are dropped (they have no frame / no instance to
file them under). Input with nothing usable raises :class:`~egograph.core.errors.InputError`
naming the file at fault: rig extrinsics that are not rigid transforms (checked first), or a lift
that lifted no detection at all (missing ``depth_ahat_pose.json``, no depth, no detections...).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from tqdm import tqdm

from egograph.core.errors import InputError
from egograph.core.types import Box, Detection, Prediction
from egograph.geometry.chains import FrameChains, frame_chains
from egograph.geometry.config import LiftConfig
from egograph.geometry.hl2ss import pose_validity, transform_points
from egograph.geometry.observations import Observations
from egograph.geometry.prefetch import prefetched
from egograph.geometry.reference_lift import (
    ReferenceSetup,
    reference_box,
    reference_frame_map,
    reference_pick,
    reference_setup,
)
from egograph.geometry.robust_lift import RobustContext, alias_shifts, robust_box_point, robust_context
from egograph.io.detections import write_results_dir

PREFETCH_PER_THREAD = 3  # depth frames decoded ahead per decoding thread (512 KB each)


# --------------------------------------------------------------------------- report

SKIP_REASONS = {
    "unknown_timestamp": "timestamp is not a frame of the recording",
    "unknown_instance": "instance id beyond labels.csv",
    "malformed": "not a detection with a box",
    "empty_box": "box has zero area",
    "box_outside_image": "box lies entirely outside the PV image",
    "reference_border": "box starts at the top-left corner (int(x1) <= 1 and int(y1) <= 1): the reference "
                        "code drops it",
    "invalid_pose": "NaN/invalid depth pose (or PV pose, for posed registration)",
    "no_depth_frame": "depth frame missing or unreadable",
    "no_depth_pixels": "too few valid depth pixels register into the box",
    "no_dominant_cluster": "no depth cluster holds enough of the box's pixels",
}


FILE_REASONS = {
    "misnamed": "detection file not named <ts>.txt",
    "not_pv_frame": "detection file for a timestamp that is not a PV frame",
}
"""Why detection files were skipped (not read): the ``files_skipped`` keys of :class:`LiftReport`."""


@dataclass
class SkipExample:
    reason: str
    timestamp: int | None
    instance: int | None
    detail: str = ""


@dataclass
class LiftReport:
    """What the lift did: detections seen and lifted, skips per reason with a few examples, the
    detection files skipped (not named for a PV frame) and the PV frames without a usable pose."""

    mode: str
    n_detections: int = 0
    n_lifted: int = 0
    n_frames: int = 0                      # frames whose depth was read
    skipped: dict[str, int] = field(default_factory=dict)
    examples: list[SkipExample] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0                   # whole lift, wall clock
    setup_seconds: float = 0.0             # of which per-recording set-up (rays, mesh ray-casting scene)
    examples_per_reason: int = 3
    source: str | None = None              # the detections folder, when read from one
    n_files: int = 0                       # detection files in it (read or skipped)
    files_skipped: dict[str, list[str]] = field(default_factory=dict)  # FILE_REASONS key -> file names
    n_pv_frames: int = 0                   # PV frames of the recording
    frames_without_file: int = 0           # PV frames without a detection file in ``source`` (read as none)
    frames_without_pose: dict[str, int] = field(default_factory=dict)  # pose file -> PV frames without a
    #                                        valid pose in it, for the poses the lift needs (only when > 0)

    def skip(self, reason: str, ts: int | None, instance: int | None, detail: str = "", count: int = 1) -> None:
        assert reason in SKIP_REASONS, reason
        seen = self.skipped.get(reason, 0)
        self.skipped[reason] = seen + count
        if seen < self.examples_per_reason:
            self.examples.append(SkipExample(reason, ts, instance, detail))

    @property
    def n_skipped(self) -> int:
        return sum(self.skipped.values())

    def summary(self) -> str:
        lines = [f"lift ({self.mode}): {self.n_lifted} of {self.n_detections} detections lifted "
                 f"over {self.n_frames} depth frames in {self.seconds:.1f} s (set-up {self.setup_seconds:.1f} s); "
                 f"{self.n_skipped} skipped"]
        for reason, n in sorted(self.skipped.items(), key=lambda kv: -kv[1]):
            lines.append(f"  {n:6d}  {reason}: {SKIP_REASONS[reason]}")
            for ex in self.examples:
                if ex.reason == reason:
                    what = f"ts {ex.timestamp}" + (f", instance {ex.instance}" if ex.instance is not None else "")
                    lines.append(f"            e.g. {what}" + (f" ({ex.detail})" if ex.detail else ""))
        if self.frames_without_file:
            lines.append(f"  PV frames without a detection file in {self.source}: {self.frames_without_file} of "
                         f"{self.n_pv_frames} (read as frames without detections)")
        if self.files_skipped:
            lines.append(f"  detection files: {sum(map(len, self.files_skipped.values()))} of {self.n_files} "
                         f"in {self.source} skipped")
            for reason, names in sorted(self.files_skipped.items()):
                eg = ", ".join(names[:self.examples_per_reason]) + (", ..." if len(names) > self.examples_per_reason
                                                                    else "")
                lines.append(f"  {len(names):6d}  {reason}: {FILE_REASONS[reason]} (e.g. {eg})")
        for name, n in self.frames_without_pose.items():
            lines.append(f"  PV frames without a valid pose in {name}: {n} of {self.n_pv_frames} (their "
                         f"detections count as invalid_pose)")
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


# --------------------------------------------------------------------------- per-recording context

@dataclass
class _Context:
    """A lift's per-recording state: the mode's set-up (one of ``reference``, ``robust``)."""

    rec: object
    cfg: LiftConfig
    alias_m: float
    reference: ReferenceSetup | None = None
    robust: RobustContext | None = None


def _context(rec, cfg: LiftConfig, report: LiftReport) -> _Context:
    ctx = _Context(rec, cfg, alias_m=float(rec.ahat.alias_m))
    if cfg.mode == "reference":
        ctx.reference = reference_setup(rec)
    else:
        ctx.robust = robust_context(rec, cfg, report.notes)
    return ctx


def _frame_matrices(ctx: _Context, i: int) -> FrameChains | None:
    """The frame's chains, or None when a pose it needs is invalid (posed registration: robust mode only)."""
    return frame_chains(ctx.rec, i, posed=_posed(ctx.cfg))


@dataclass
class _FrameDepth:
    """What a frame's detections are lifted from: its chains, its raw depth, and (reference) its PV depth map."""

    frame: FrameChains
    raw: np.ndarray
    depth_map: np.ndarray | None = None


def _frame_state(ctx: _Context, frame: FrameChains, raw: np.ndarray | None) -> _FrameDepth | str:
    """A frame's chains and depth, or the reason none of its detections can be lifted."""
    if raw is None:
        return "no_depth_frame"
    out = _FrameDepth(frame, raw)
    if ctx.reference is not None:
        # The reference code registers through the static rig whatever the config says.
        out.depth_map = reference_frame_map(ctx.reference, raw)
    return out


def _lift_one(ctx: _Context, state: _FrameDepth, ts: int, i: int, det: Detection, box: np.ndarray, rows: _Rows,
              report: LiftReport) -> None:
    """Lift one detection (box clipped to the image) and add its row, lifted or not."""
    cfg = ctx.cfg
    if cfg.mode == "reference":
        # The reference rule works on the file's box (truncated corners, not clipped to the image).
        ref_box = reference_box((det.box.x_min, det.box.y_min, det.box.x_max, det.box.y_max))
        if ref_box is None:
            report.skip("reference_border", ts, det.instance, "box starts in the top-left corner (dropped "
                        "by the reference code's int(x1) <= 1 and int(y1) <= 1 rule)")
            rows.add(ts, i, det)
            return
        picked = reference_pick(state.depth_map, ref_box)
        if picked is None:
            report.skip("no_depth_pixels", ts, det.instance, "no pixel with depth in the box")
            rows.add(ts, i, det)
            return
        point, n = picked[0], 1
        shifts = np.arange(cfg.n_candidates)  # r + k·alias, k = 0..K-1, chosen k = 0
    else:
        res = robust_box_point(ctx.robust, state.raw, state.frame, box)
        if isinstance(res, str):
            report.skip(res, ts, det.instance)
            rows.add(ts, i, det)
            return
        point, n = res
        shifts = alias_shifts(float(np.linalg.norm(point)), ctx.alias_m, cfg.n_candidates, cfg.max_range_m)
    _add_lifted(rows, ctx, state.frame, ts, i, det, point, n, shifts)
    report.n_lifted += 1


# --------------------------------------------------------------------------- rows

class _Rows:
    """Column lists of the Observations being built."""

    def __init__(self, k: int):
        self.k = k
        self.cols: dict[str, list] = {n: [] for n in ("timestamps", "frame", "instance", "score", "box", "world",
                                                     "camera", "range_m", "candidates", "chosen", "n_pixels")}

    def add(self, ts: int, frame: int, det: Detection, world=None, camera=None, range_m=np.nan,
            candidates=None, chosen=-1, n_pixels=0) -> None:
        c = self.cols
        c["timestamps"].append(ts)
        c["frame"].append(frame)
        c["instance"].append(det.instance)
        c["score"].append(det.score)
        c["box"].append((det.box.x_min, det.box.y_min, det.box.x_max, det.box.y_max))
        c["world"].append(np.full(3, np.nan) if world is None else world)
        c["camera"].append(np.full(3, np.nan) if camera is None else camera)
        c["range_m"].append(range_m)
        c["candidates"].append(np.full((self.k, 3), np.nan) if candidates is None else candidates)
        c["chosen"].append(chosen)
        c["n_pixels"].append(n_pixels)

    def build(self) -> Observations:
        c = self.cols
        if not c["timestamps"]:
            return Observations.empty(self.k)
        return Observations(
            timestamps=np.asarray(c["timestamps"], np.int64), frame=np.asarray(c["frame"], np.int32),
            instance=np.asarray(c["instance"], np.int32), score=np.asarray(c["score"], np.float32),
            box=np.asarray(c["box"], np.float32), world=np.asarray(c["world"], np.float64),
            camera=np.asarray(c["camera"], np.float64), range_m=np.asarray(c["range_m"], np.float32),
            candidates=np.asarray(c["candidates"], np.float64), chosen=np.asarray(c["chosen"], np.int8),
            n_pixels=np.asarray(c["n_pixels"], np.int32))


def _add_lifted(rows: _Rows, ctx: _Context, frame: FrameChains, ts: int, i: int, det: Detection,
                point: np.ndarray, n_pixels: int, shifts: np.ndarray) -> None:
    """One lifted row: ``point`` (AHAT camera) to world, with candidates along its ray at ``shifts`` aliases."""
    r = float(np.linalg.norm(point))
    ranges = r + shifts * ctx.alias_m
    cands = np.full((rows.k, 3), np.nan)
    cands[:len(shifts)] = transform_points(point[None, :] * (ranges / r)[:, None], frame.ahat_to_world)
    chosen = int(np.flatnonzero(shifts == 0)[0])
    rows.add(ts, i, det, world=cands[chosen].copy(), camera=frame.ahat_to_world[3, :3].copy(), range_m=r,
             candidates=cands, chosen=chosen, n_pixels=n_pixels)


# --------------------------------------------------------------------------- validation

def _labels_count(rec, report: LiftReport) -> int | None:
    """Instances in the recording's labels.csv, or None (no annotations, or unreadable: noted)."""
    ann = getattr(rec, "annotation_dir", None)
    if ann is None or not (Path(ann) / "labels.csv").is_file():
        return None
    from egograph.io.annotations import read_labels

    try:
        return len(read_labels(Path(ann) / "labels.csv"))
    except InputError as exc:
        report.notes.append(f"instance ids not checked: {exc}")
        return None


def check_rig(rec) -> None:
    """InputError naming the calibration file when a rig extrinsics matrix is not a rigid transform
    (all zeros, NaN, scaled...): every chain goes through them, so no detection could be lifted."""
    calib = Path(getattr(rec, "calibration_dir", None) or ".")
    for sensor, folder in (("ahat", "rm_depth_ahat"), ("pv", "personal_video")):
        m = np.asarray(getattr(rec, sensor).extrinsics, dtype=np.float64)
        if m.shape != (4, 4) or not pose_validity(m):
            raise InputError(calib / folder / "extrinsics.bin",
                             "not a rigid transform (row-vector 4x4 rotation and translation, last column "
                             "0 0 0 1): no detection can be lifted")


def _frames_without_pose(rec, cfg: LiftConfig) -> dict[str, int]:
    """PV frames without a valid pose the lift needs, per pose file (when any): the depth pose,
    and under posed registration (robust mode) the PV pose too."""
    bad = {"depth_ahat_pose.json": int((~np.asarray(rec.depth_valid, bool)).sum())}
    if _posed(cfg):
        bad["pv_pose.json"] = int((~np.asarray(rec.pv_valid, bool)).sum())
    return {name: n for name, n in bad.items() if n}


def _posed(cfg: LiftConfig) -> bool:
    return cfg.mode == "robust" and cfg.registration == "posed"


def _note_inputs(rec, detections, cfg: LiftConfig, report: LiftReport) -> None:
    """The detection files skipped (when ``detections`` was read from a folder) and the PV frames
    without a pose, into ``report``."""
    scan = getattr(detections, "scan", None)
    if scan is not None:
        report.source = str(scan.folder)
        report.n_files = scan.n_files
        report.frames_without_file = len(scan.missing)
        for reason, files in (("misnamed", scan.misnamed), ("not_pv_frame", scan.not_pv_frame)):
            if files:
                report.files_skipped[reason] = sorted(f.name for f in files)
    report.n_pv_frames = len(rec.timestamps)
    report.frames_without_pose = _frames_without_pose(rec, cfg)


def _nothing_lifted(rec, report: LiftReport) -> InputError:
    """The error for a lift that lifted no detection, naming the input most likely at fault."""
    seq = Path(getattr(rec, "seq_dir", None) or ".")
    source = Path(report.source) if report.source else seq
    if not report.n_detections:
        where = f" in {report.n_files} files" if report.source else ""
        return InputError(source, f"no detections{where}: nothing to lift")
    counts = ", ".join(f"{n} {reason}" for reason, n in sorted(report.skipped.items(), key=lambda kv: -kv[1]))
    what = f"none of {report.n_detections} detections lifted ({counts})"
    top = max(report.skipped, key=report.skipped.get) if report.skipped else ""
    if top == "invalid_pose":
        pose_file = seq / "depth_ahat_pose.json"
        if not pose_file.is_file():
            return InputError(pose_file, f"missing: no AHAT pose for any PV frame; {what}")
        if "depth_ahat_pose.json" not in report.frames_without_pose:  # posed registration: the PV poses
            pose_file = seq / "pv_pose.json"
        n = report.frames_without_pose.get(pose_file.name, 0)
        return InputError(pose_file, f"no valid pose at the frames with detections ({n} of {report.n_pv_frames} "
                                     f"PV frames without one); {what}")
    if top == "unknown_instance":
        ann = getattr(rec, "annotation_dir", None)
        return InputError(Path(ann) / "labels.csv" if ann else source, f"every instance id is beyond the labels; {what}")
    if top in ("no_depth_frame", "no_depth_pixels", "no_dominant_cluster"):
        return InputError(seq / "depth_ahat", f"no usable depth in the detections' boxes (if the depth images hold "
                                              "ranges there, the likely cause is AHAT extrinsics in another axis "
                                              "convention: the boxes then map away from the depth camera's view); "
                                              f"{what}")
    return InputError(source, what)


def _usable_box(det, pv_shape: tuple[int, int], ts: int, report: LiftReport) -> np.ndarray | None:
    """The detection's box clipped to the PV image (x1, y1, x2, y2), or None (counted)."""
    b = det.box
    if not (b.x_max > b.x_min and b.y_max > b.y_min):
        report.skip("empty_box", ts, det.instance, f"box {b.x_min:g} {b.y_min:g} {b.x_max:g} {b.y_max:g}")
        return None
    clipped = b.clip(pv_shape[1], pv_shape[0])
    if clipped is None:
        report.skip("box_outside_image", ts, det.instance, f"box {b.x_min:g} {b.y_min:g} {b.x_max:g} {b.y_max:g}")
        return None
    return np.array([clipped.x_min, clipped.y_min, clipped.x_max, clipped.y_max])


def _frames_to_lift(rec, detections: Mapping[int, Sequence[Detection]], n_instances: int | None,
                    report: LiftReport) -> list[tuple[int, int, list[Detection]]]:
    """(frame index, timestamp, detections) per frame, in frame order; unknown ts/instance counted and dropped."""
    out = []
    for ts, dets in detections.items():
        dets = list(dets or ())
        if not dets:
            continue
        report.n_detections += len(dets)
        try:
            ts = int(ts)
            i = rec.index_of(ts)
        except (KeyError, TypeError, ValueError):
            report.skip("unknown_timestamp", ts if isinstance(ts, int) else None, None,
                        f"{len(dets)} detection(s) at {ts!r}", count=len(dets))
            continue
        keep = []
        for d in dets:
            if not isinstance(d, Detection) or not isinstance(d.box, Box):
                report.skip("malformed", ts, None, f"{type(d).__name__}")
            elif n_instances is not None and d.instance >= n_instances:
                report.skip("unknown_instance", ts, d.instance, f"{n_instances} instances in labels.csv")
            else:
                keep.append(d)
        if keep:
            out.append((i, ts, keep))
    out.sort(key=lambda x: x[0])
    return out


# --------------------------------------------------------------------------- driver

def lift_recording(rec, detections: dict[int, list[Detection]], cfg: LiftConfig, progress: bool = True,
                   n_instances: int | None = None) -> tuple[Observations, LiftReport]:
    """Lift every detection of a recording to a 3D observation (world frame, metres).

    ``detections`` maps PV timestamps to that frame's detections (as
    :func:`~egograph.io.detections.read_detection_dir` returns). ``n_instances`` bounds
    the instance ids; None reads it from the recording's ``labels.csv`` when it has
    annotations (no bound otherwise). Rows come out in frame order, detections in file
    order within a frame. Partly bad data is counted in the report; InputError when nothing
    can be lifted (see the module doc).
    """
    cfg.check()
    check_rig(rec)
    t0 = time.perf_counter()
    report = LiftReport(mode=cfg.mode)
    _note_inputs(rec, detections, cfg, report)
    if n_instances is None:
        n_instances = _labels_count(rec, report)
    frames = _frames_to_lift(rec, detections, n_instances, report)
    ctx = _context(rec, cfg, report)
    report.setup_seconds = time.perf_counter() - t0
    rows = _Rows(cfg.n_candidates)
    # Plan first (boxes, poses: cheap) so the depth frames that will be needed can be
    # decoded ahead, on the other core, while the current frame is lifted.
    plan = []
    for i, ts, dets in frames:
        boxes = [_usable_box(d, rec.pv.shape, ts, report) for d in dets]
        frame = None
        if any(b is not None for b in boxes):
            frame = _frame_matrices(ctx, i) or "invalid_pose"
        plan.append((i, ts, dets, boxes, frame))
    depth = prefetched(rec.depth_raw, [p[0] for p in plan if isinstance(p[4], FrameChains)],
                       PREFETCH_PER_THREAD * cfg.decode_threads, cfg.decode_threads)
    bar = tqdm(plan, desc=f"lift ({cfg.mode})", unit="frame", disable=not progress, mininterval=1.0)
    for i, ts, dets, boxes, frame in bar:
        state = _frame_state(ctx, frame, next(depth)[1]) if isinstance(frame, FrameChains) else frame
        if isinstance(state, _FrameDepth):
            report.n_frames += 1
        for d, box in zip(dets, boxes):
            if box is None:  # already counted
                rows.add(ts, i, d)
            elif isinstance(state, str):
                report.skip(state, ts, d.instance, SKIP_DETAILS.get(state, ""))
                rows.add(ts, i, d)
            else:
                _lift_one(ctx, state, ts, i, d, box, rows, report)
    report.seconds = time.perf_counter() - t0
    if not report.n_lifted:
        raise _nothing_lifted(rec, report)
    return rows.build(), report


SKIP_DETAILS = {"no_depth_frame": "missing or unreadable depth_ahat png"}


# --------------------------------------------------------------------------- output

def write_lifted_dir(path: str | Path, obs: Observations, timestamps: Sequence[int]) -> None:
    """The reference "lifted" format: one ``<ts>.txt`` per PV frame, rows ``instance x y z score``.

    Only lifted rows are written (world frame, metres); frames without any get an empty file.
    """
    per_frame: dict[int, list[Prediction]] = {}
    for j in np.flatnonzero(obs.valid):
        per_frame.setdefault(int(obs.timestamps[j]), []).append(
            Prediction(int(obs.instance[j]), tuple(float(x) for x in obs.world[j]), float(obs.score[j])))
    write_results_dir(path, per_frame, [int(t) for t in timestamps])
