"""Steps ``sot`` and ``eval-2d``: the paper's SOT re-purposing baseline as a detection folder, and
the 2D tracking table of any detection folder against ``2d_bbox_annot/``.

``sot`` writes one ``<ts>.txt`` per PV frame in the reference association format (``instance x1 y1
x2 y2 det_conf similarity``, both 1) from an OpenCV tracker per instance started at its
``svoe.txt`` box (:mod:`egograph.frontend.sot`); ``egograph track --tracker memory --detections
DIR --lift reference`` on it is the paper's SOT row.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

from egograph.core.errors import EgographError, InputError
from egograph.io.recording import Recording, report_problem
from egograph.steps import outputs
from egograph.steps.recording import require_annotations, require_svoe


@dataclass
class SotReport:
    """What ``sot`` did: ``started`` instance -> SVOE frame index, boxes per instance, frames whose
    image was missing, instances not started (why)."""

    method: str
    started: dict[int, int] = field(default_factory=dict)
    boxes: dict[int, int] = field(default_factory=dict)
    lost: dict[int, int] = field(default_factory=dict)
    skipped_frames: list[str] = field(default_factory=list)
    not_started: dict[int, str] = field(default_factory=dict)

    def summary(self) -> str:
        lines = [f"{'instance':>8s} {'from frame':>10s} {'boxes':>6s} {'lost':>6s}"]
        for k in sorted(self.started):
            lines.append(f"{k:8d} {self.started[k]:10d} {self.boxes.get(k, 0):6d} {self.lost.get(k, 0):6d}")
        for k, why in sorted(self.not_started.items()):
            lines.append(f"{k:8d} not started: {why}")
        return "\n".join(lines)


def sot(rec: Recording, cfg, out: str | Path, *, method: str = "csrt", overwrite: bool = False,
        progress: bool = True) -> SotReport | None:
    """Run the SOT baseline over every PV frame of ``rec`` into the detection folder ``out``
    (one rename); None when ``out`` already holds this exact run."""
    import cv2
    from tqdm import tqdm

    from egograph.frontend.sot import METHODS, SotState, step_frame
    from egograph.io.annotations import load_annotations
    from egograph.io.textio import write_text_dir

    if method not in METHODS:
        raise EgographError(f"--method {method}: one of {', '.join(METHODS)}")
    record = outputs.run_record("sot", cfg, {"recording": outputs.recording_digest(rec), "method": method})
    if outputs.up_to_date(Path(out), record, overwrite):
        return None
    require_annotations(rec, "the SVOE boxes the trackers start from")
    svoe = require_svoe(rec)
    ann = load_annotations(rec.annotation_dir, box_format=cfg.io.box_format, svoe_path=svoe)
    report = SotReport(method)
    states = []
    for e in ann.svoe:
        if any(s.instance == e.instance for s in states):
            continue  # one start per instance: its first line
        try:
            start = rec.index_of(e.ts)
        except (KeyError, ValueError, EgographError):
            report.not_started[e.instance] = f"{svoe}: frame {e.ts} is no PV frame"
            continue
        states.append(SotState(e.instance, start, (e.box.x_min, e.box.y_min, e.box.x_max, e.box.y_max)))
    if not states:
        raise InputError(svoe, "no SVOE box names a PV frame of this recording: nothing to track")
    first = min(s.start for s in states)
    files = {f"{int(t)}.txt": "" for t in rec.timestamps}
    for i in tqdm(range(first, len(rec)), desc=f"sot ({method})", unit="frame", disable=not progress,
                  mininterval=1.0):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # counted and named once below
            rgb = rec.rgb(i)
        if rgb is None:
            report.skipped_frames.append(str(rec.pv_path(i)))
            continue
        rows = step_frame(states, i, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), method)
        for s in states:
            if s.tracker is not None:
                report.started.setdefault(s.instance, s.start)
        files[f"{int(rec.timestamps[i])}.txt"] = "".join(
            f"{k} {b[0]:.2f} {b[1]:.2f} {b[2]:.2f} {b[3]:.2f} 1 1\n" for k, b in rows)
        for k, _ in rows:
            report.boxes[k] = report.boxes.get(k, 0) + 1
    for s in states:
        report.lost[s.instance] = s.lost_frames
        if s.tracker is None:
            report.not_started.setdefault(s.instance, f"its SVOE frame {rec.pv_path(s.start)} could not be read "
                                                      "or the box lies outside it")
    for k, why in report.not_started.items():
        report_problem(rec.strict, svoe, f"instance {k}: {why}")
    if not report.started:
        raise InputError(svoe, "no tracker could be started (every SVOE frame missing or box outside)")
    if report.skipped_frames:
        report_problem(rec.strict, report.skipped_frames[0], f"{len(report.skipped_frames)} PV images missing or "
                                                             "unreadable (this one first): no boxes in those frames")
    files.update(outputs.run_files(record, cfg))
    write_text_dir(out, files)
    return report


def eval_2d(rec: Recording, detections: str | Path, cfg):
    """The 2D table (:mod:`egograph.eval.tracking2d`) of the detection set or folder ``detections``
    against the recording's ``2d_bbox_annot/``."""
    from egograph.eval.tracking2d import evaluate_2d
    from egograph.io.annotations import ci_child, read_bbox_annot_dir
    from egograph.io.detections import read_detection_dir

    ann = require_annotations(rec, "2d_bbox_annot/ to score boxes against")
    folder = ci_child(ann, "2d_bbox_annot")
    if not folder.is_dir():
        raise InputError(folder, "no 2D box annotations (2d_bbox_annot/) to score against")
    boxes = read_bbox_annot_dir(folder, cfg.io.box_format)
    if not any(boxes.values()):
        raise InputError(folder, "2d_bbox_annot/ holds no boxes")
    dets = read_detection_dir(rec.detections_dir(str(detections)), rec.timestamps, box_format=cfg.io.box_format)
    return evaluate_2d(dets, boxes)
