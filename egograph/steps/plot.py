"""Step ``plot``: pictures of one or more trackers' results on a recording, and an HTML page.

Reads the recording (poses, mesh, PV frames), its annotations (``3d_center_annot.txt``,
``motion_state_annot.txt``), its synthetic truth when it has one (``synth_gt/<seq>/instances.npz``
carries, ``detections_<set>.txt`` true/false detections), a detection set when asked, and each
results folder (per-frame files, ``intervals.json``); draws with :mod:`egograph.eval.plots` into
one output folder, committed by one rename:

* ``timeline_<tracker>.png``: one lane per instance (truth, intervals, predictions, detections);
* ``map_<tracker>.png``: the top-down x-z map;
* ``metrics.png``: error over time and precision/recall against threshold, every tracker;
* ``pv_sheet.png``: predictions projected into PV frames around each break (when there are PV frames);
* ``index.html``: the evaluation table and every picture; ``config.yaml``, ``egograph.json``.

Every results folder is checked before anything is read or written: a missing one is an
:class:`~egograph.core.errors.InputError` naming it.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from egograph.core.errors import ConfigError, InputError
from egograph.eval import plots
from egograph.eval.loader import load_gt_intervals
from egograph.geometry.hl2ss import camera_center
from egograph.io.annotations import read_motion_states
from egograph.io.atomic import atomic_dir
from egograph.io.recording import Recording
from egograph.steps import outputs
from egograph.steps.recording import labels as read_labels_of

CENTERS_FILE = "3d_center_annot.txt"
MOTION_FILE = "motion_state_annot.txt"
INDEX_FILE = "index.html"


@dataclass
class PlotOutput:
    """What the step wrote: ``folder``, ``images`` file name -> (width, height) pixels, ``notes``
    (inputs that were missing, so a picture lacks a part)."""

    folder: Path
    images: dict[str, tuple[int, int]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def check_results(results: Sequence[str | Path], names: Sequence[str] | None) -> list[str]:
    """The row names, after checking every results folder exists (InputError naming the first
    that does not) and the names are one distinct per folder (ConfigError)."""
    if not results:
        raise ConfigError("plot needs at least one results folder")
    for r in results:
        p = Path(r)
        if not p.exists():
            raise InputError(p, "results folder not found")
        if not p.is_dir():
            raise InputError(p, "not a results folder (a file, not a folder)")
    names = list(names) if names else [Path(r).name for r in results]
    if len(names) != len(results) or len(set(names)) != len(names):
        raise ConfigError(f"--names must give one distinct name per results folder ({len(results)}), got {names}")
    return names


def _predictions_array(per_frame: dict, timestamps: np.ndarray) -> dict[int, np.ndarray]:
    """``ts -> [Prediction]`` -> instance -> (N, 3) xyz (NaN where none; the last line wins)."""
    n = len(timestamps)
    out: dict[int, np.ndarray] = {}
    for i, t in enumerate(timestamps):
        for p in per_frame.get(int(t), ()):
            if p.instance not in out:
                out[p.instance] = np.full((n, 3), np.nan)
            out[p.instance][i] = p.xyz
    return out


def _carries(rec: Recording, notes: list[str]) -> np.ndarray | None:
    """(N, K) bool: instance k carried at PV frame i, from ``synth_gt/<seq>/instances.npz``."""
    gt = rec.synth_gt_dir
    if gt is None or not (gt / "instances.npz").is_file():
        return None
    with np.load(gt / "instances.npz") as data:
        if "moving" not in data or "timestamps" not in data:
            notes.append(f"{gt / 'instances.npz'}: no 'moving'/'timestamps' arrays: carries not shown")
            return None
        ts, moving = np.asarray(data["timestamps"], np.int64), np.asarray(data["moving"], bool)
    index = {int(t): i for i, t in enumerate(ts)}
    out = np.zeros((len(rec), moving.shape[1]), bool)
    for i, t in enumerate(rec.timestamps):
        j = index.get(int(t))
        if j is not None:
            out[i] = moving[j]
    return out


def _false_flags(rec: Recording, set_name: str) -> dict[tuple[int, int], bool] | None:
    """``(ts, instance) -> is_false`` from ``synth_gt/<seq>/detections_<set>.txt``, or None."""
    gt = rec.synth_gt_dir
    path = gt / f"detections_{set_name}.txt" if gt is not None else None
    if path is None or not path.is_file():
        return None
    flags = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        tok = line.split()
        if not tok or tok[0].startswith("#"):
            continue
        if len(tok) < 3:
            raise InputError(path, "expected 'ts instance is_false ...'", n)
        flags[(int(tok[0]), int(tok[1]))] = tok[2] != "0"
    return flags


def detection_ticks(rec: Recording, spec: str, cfg) -> plots.DetectionTicks:
    """The detections of set (or folder) ``spec`` as PV frame indices per instance, with their
    true/false flags when the synthetic truth has them."""
    from egograph.io.detections import read_detection_dir

    folder = rec.detections_dir(str(spec))
    dets = read_detection_dir(folder, rec.timestamps, box_format=cfg.io.box_format)
    flags = _false_flags(rec, Path(str(spec)).name)
    frames: dict[int, list[int]] = {}
    false: dict[int, list[bool]] = {}
    for i, t in enumerate(rec.timestamps):
        for d in dets.get(int(t), ()):
            frames.setdefault(d.instance, []).append(i)
            # a detection the truth file does not list is counted as false (as synth.truth does)
            false.setdefault(d.instance, []).append(True if flags is None else flags.get((int(t), d.instance), True))
    return plots.DetectionTicks(
        name=Path(str(spec)).name,
        frames={k: np.asarray(v, np.int64) for k, v in frames.items()},
        is_false=None if flags is None else {k: np.asarray(v, bool) for k, v in false.items()},
    )


def _mesh_xz(rec: Recording) -> np.ndarray | None:
    """x and z (metres) of the mesh's triangle centres, or None without a mesh."""
    if not rec.mesh_paths():
        return None
    mesh = rec.mesh()
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    return v[f].mean(axis=1)[:, [0, 2]]


def _has_pv_images(rec: Recording) -> bool:
    return any(rec.pv_path(i).is_file() for i in range(len(rec)))


def build_scene(rec: Recording, cfg, detections: str | None = None) -> tuple[plots.PlotScene, list[str]]:
    """The recording's side of the pictures, and notes on what is missing."""
    notes: list[str] = []
    names = read_labels_of(rec)
    n = None if names is None else len(names)
    gt, stationary = [], []
    ann = rec.annotation_dir
    if ann is None:
        notes.append(f"{rec.seq_dir}: no annotation folder: no true intervals, no evaluation")
    else:
        if (ann / CENTERS_FILE).is_file():
            gt = load_gt_intervals(ann / CENTERS_FILE, n)
        else:
            notes.append(f"{ann / CENTERS_FILE}: not found: no true centres, no evaluation")
        if (ann / MOTION_FILE).is_file():
            stationary = [(m.instance, m.t_start, m.t_end) for m in read_motion_states(ann / MOTION_FILE, n)]
    centres = camera_center(rec.pv_poses)
    centres[~rec.pv_valid] = np.nan
    scene = plots.PlotScene(recording=rec.name, timestamps=np.asarray(rec.timestamps, np.int64),
                            labels=list(names or []), gt=gt, stationary=stationary, carries=_carries(rec, notes),
                            camera=centres, mesh_xz=_mesh_xz(rec))
    if scene.mesh_xz is None:
        notes.append(f"{rec.seq_dir / 'mesh'}: no mesh: the map has no outline")
    if detections is not None:
        scene.detections = detection_ticks(rec, detections, cfg)
    if _has_pv_images(rec):
        scene.pv = plots.PvFrames(image=rec.rgb, poses=rec.pv_poses, valid=rec.pv_valid,
                                  intrinsics=rec.pv.intrinsics)
    else:
        notes.append(f"{rec.seq_dir / 'pv'}: no PV images: no contact sheet")
    return scene, notes


def tracked_detections(path: Path) -> str | None:
    """The detection set (or folder) a results folder was tracked with, from its run record, or None."""
    prev = outputs.previous_record(path) or {}
    obs = (prev.get("inputs") or {}).get("observations") or {}
    spec = ((obs.get("provenance") or {}).get("detections") or {}).get("spec") if isinstance(obs, dict) else None
    return str(spec) if spec else None


def load_run(rec: Recording, path: Path, name: str, evaluate_it: bool, strict: bool = False,
             cfg=None, ticks: dict | None = None) -> plots.TrackerRun:
    """One results folder: per-frame predictions, intervals, the evaluation when asked and, with
    ``cfg``, the detections it was tracked with (``ticks``: a cache by detection set)."""
    from egograph.steps.evaluate import evaluate
    from egograph.steps.track import read_result

    result = read_result(path, rec)
    report = evaluate(rec, path, name, strict=strict) if evaluate_it else None
    dets = None
    spec = tracked_detections(path) if cfg is not None else None
    if spec is not None:
        if ticks is None:
            ticks = {}
        if spec not in ticks:
            try:
                ticks[spec] = detection_ticks(rec, spec, cfg)
            except (InputError, OSError) as exc:  # tracked from a folder since moved: say so, draw the rest
                warnings.warn(f"{path}: its detections {spec!r} cannot be read for the timeline: {exc}", stacklevel=2)
                ticks[spec] = None
        dets = ticks[spec]
    return plots.TrackerRun(name=name, predictions=_predictions_array(result.per_frame, rec.timestamps),
                            intervals=result.intervals, report=report, detections=dets)


def plot(rec: Recording, results: Sequence[str | Path], out: str | Path, cfg, *, names: Sequence[str] | None = None,
         detections: str | None = None) -> PlotOutput:
    """Draw every picture of ``results`` (results folders) on ``rec`` into the folder ``out``
    (replaced as a whole when complete). See the module doc for the files."""
    names = check_results(results, names)
    scene, notes = build_scene(rec, cfg, detections)
    ticks: dict = {}
    runs = [load_run(rec, Path(r), n, bool(scene.gt), strict=cfg.io.strict, cfg=None if detections else cfg,
                     ticks=ticks) for r, n in zip(results, names)]
    if not any(run.predictions or run.intervals for run in runs):  # pictures of nothing replace no good ones
        raise InputError(Path(results[0]), f"no prediction for any PV frame of {rec.seq_dir} in "
                                           f"{'any of the results folders' if len(runs) > 1 else 'the results folder'}"
                                           f": nothing to draw ({out} left as it is)")
    slugs = _unique([plots.slug(n) for n in names])
    record = outputs.run_record("plot", cfg, {"recording": outputs.recording_digest(rec),
                                              "results": dict(zip(names, map(str, results))),
                                              "detections": detections})
    result = PlotOutput(Path(out), notes=notes)
    for note in notes:
        warnings.warn(note, stacklevel=2)
    sections: dict[str, list[str]] = {"Timelines": [], "Maps": [], "Errors, precision and recall": []}
    with atomic_dir(out) as tmp:
        def put(section: str, file: str, data: bytes) -> None:
            plots.write_bytes(tmp, file, data)
            result.images[file] = _png_size(data)
            sections.setdefault(section, []).append(file)

        put("Errors, precision and recall", "metrics.png", plots.plot_metrics(scene, runs))
        curves = plots.plot_curves(scene, runs)
        if curves is not None:
            put("Errors, precision and recall", "curves.png", curves)
        for run, s in zip(runs, slugs):
            put("Timelines", f"timeline_{s}.png", plots.plot_timeline(scene, run))
            put("Maps", f"map_{s}.png", plots.plot_map(scene, run))
        if scene.pv is not None:
            put("PV frames around each break", "pv_sheet.png", plots.plot_contact_sheet(scene, runs))
        (tmp / INDEX_FILE).write_text(plots.html_report(scene, runs, sections, notes))
        outputs.write_run_files(tmp, record, cfg)
    return result


def _unique(names: list[str]) -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for s in names:
        k = seen.get(s, 0)
        seen[s] = k + 1
        out.append(s if k == 0 else f"{s}_{k + 1}")
    return out


def _png_size(data: bytes) -> tuple[int, int]:
    """(width, height) from a PNG's IHDR chunk."""
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
