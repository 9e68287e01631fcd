"""Step ``adapt``: a tracker's results teach the front-end (:mod:`egograph.frontend.adapt`).

A *teacher* is a results folder of ``egograph track`` (its ``intervals.json``: the stands; the
detections it was tracked from, found through its run record or given) or the same in memory (a
:class:`~egograph.core.types.TrackResult` and its detections folder). :func:`fit_adaptation`
harvests the crops, embeds them with the front-end's encoder, fits the heads and checks them against
the held-back enrollment views; ``egograph detect --adapt`` scores proposals with the result.
:func:`adapt` writes it as a folder of its own (``egograph run``'s adapt stage)::

    ADAPT/head.npz        instances, weights (K, D), bias (K,) of the heads kept
    ADAPT/adapt.json      round, which results taught it (paths and digests), the confident stands,
                          per instance: crops, held-back check, head kept or why not; whether to stop
    ADAPT/config.yaml, egograph.json

Rounds: detections made without a head are round 0; a head taught by round r's results is round
r + 1, and so are the detections it makes (their ``egograph.json`` and ``adapt.json`` say so).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from egograph.core.config import to_dict
from egograph.core.errors import InputError
from egograph.frontend.adapt import (Harvest, Head, Stand, confident_stands, fit_heads, harvest_boxes,
                                     pooled_holdback, stands_changed)
from egograph.io.recording import Recording
from egograph.steps import outputs

ADAPT_FILE = "adapt.json"
HEAD_FILE = "head.npz"
INTERVALS_FILE = "intervals.json"


@dataclass
class Teacher:
    """What teaches one round: the stands of a tracker's results and the detections they came from."""

    stands: list[Stand]
    detections_dir: Path
    source: dict                      # results (path or "memory"), its digest, the detections and theirs
    round: int = 1                    # the round this teacher's head will be
    previous: dict | None = None      # adapt.json of the round that made the teacher's detections


def _frame_of(rec: Recording, ticks: int) -> int:
    ts = np.asarray(rec.timestamps, np.int64)
    return int(np.clip(np.searchsorted(ts, int(ticks), "left"), 0, len(ts) - 1))


def stands_from_intervals(rec: Recording, intervals) -> list[Stand]:
    """:class:`Stand` of each interval (``PositionInterval``), frames from its first/last supporting detection."""
    return [Stand(int(iv.instance), _frame_of(rec, iv.first_seen or iv.t_start), _frame_of(rec, iv.last_seen or iv.t_end),
                  np.asarray(iv.xyz, np.float64), int(iv.n_observations), float(iv.confidence)) for iv in intervals]


def detections_round(det_dir: Path) -> tuple[int, dict | None]:
    """(round, its adapt.json) of a detections folder: 0 and None when made without a head."""
    prev = outputs.previous_record(det_dir) or {}
    info = (prev.get("inputs") or {}).get("adapt") or None
    if not info:
        return 0, None
    doc = None
    f = Path(det_dir) / ADAPT_FILE
    if f.is_file():
        try:
            doc = json.loads(f.read_text())
        except (OSError, ValueError):
            doc = None
    return int(info.get("round", 0)), doc


def _check_same_recording(rec: Recording, path: Path, doc: dict) -> None:
    seq, n, t0 = doc.get("sequence"), doc.get("n_frames"), doc.get("first_frame_ticks")
    here_t0 = int(np.min(rec.timestamps)) if len(rec) else None
    if (seq is not None and seq != rec.name) or (n is not None and n != len(rec)) or (t0 is not None and t0 != here_t0):
        raise InputError(path, f"made for another recording (sequence {seq}, {n} frames from tick {t0}; this one: "
                               f"{rec.name}, {len(rec)} frames from tick {here_t0})")


def teacher_from_results(rec: Recording, results: str | Path, detections: str | Path | None = None) -> Teacher:
    """The teacher in a results folder of ``egograph track``: ``intervals.json`` (an interval tracker,
    e.g. graph) made for this recording, and its detections: ``detections``, else the folder its run
    record names. InputError naming the file otherwise."""
    from egograph.track.intervals import read_intervals_json

    folder = Path(results)
    f = folder / INTERVALS_FILE
    if not folder.is_dir():
        raise InputError(folder, "--adapt: not a results folder (egograph track --tracker graph --out DIR) "
                                 "nor an adapt folder (head.npz)")
    if not f.is_file():
        raise InputError(f, "--adapt: no intervals.json: the results of an interval tracker (graph) teach the head")
    try:
        doc = json.loads(f.read_text())
    except (OSError, ValueError) as e:
        raise InputError(f, f"unreadable intervals file ({e})") from None
    if isinstance(doc, dict):
        _check_same_recording(rec, f, doc)
    intervals, _ = read_intervals_json(f)
    det_dir = Path(detections) if detections is not None else None
    if det_dir is None:
        record = outputs.previous_record(folder) or {}
        spec = (((record.get("inputs") or {}).get("observations") or {}).get("provenance") or {}).get("detections", {})
        if spec.get("spec"):
            det_dir = rec.detections_dir(str(spec["spec"]))
        if det_dir is None or not Path(det_dir).is_dir():
            raise InputError(folder / outputs.RUN_FILE, "--adapt: cannot tell which detections these results were "
                                                        "tracked from (tried the observations' provenance"
                                                        + (f": {det_dir}" if det_dir is not None else "")
                                                        + "); give them with --adapt-detections DIR")
    det_dir = Path(det_dir)
    if not det_dir.is_dir():
        raise InputError(det_dir, "--adapt-detections: not a detections folder")
    rnd, prev = detections_round(det_dir)
    source = {"results": str(folder), "results_digest": outputs.digest(f.read_bytes().decode("utf-8", "replace")),
              "detections": str(det_dir), "detections_digest": outputs.folder_digest(det_dir)}
    return Teacher(stands_from_intervals(rec, intervals), det_dir, source, rnd + 1, prev)


def teacher_from_result(rec: Recording, result, detections_dir: str | Path) -> Teacher:
    """The teacher in memory: a :class:`~egograph.core.types.TrackResult` with intervals and the
    detections folder it was tracked from."""
    from egograph.track.intervals import intervals_json_text

    det_dir = Path(detections_dir)
    if result.intervals is None:
        raise InputError(det_dir, "adapt: the teaching results hold no intervals (an interval tracker, e.g. graph)")
    rnd, prev = detections_round(det_dir)
    text = intervals_json_text(result.intervals, {}, timestamps=rec.timestamps)
    source = {"results": "memory", "results_digest": outputs.digest(text), "detections": str(det_dir),
              "detections_digest": outputs.folder_digest(det_dir)}
    return Teacher(stands_from_intervals(rec, result.intervals), det_dir, source, rnd + 1, prev)


def projector(rec: Recording):
    """``(frame, xyz) -> PV pixel (u, v)`` of a world point, or None (no valid pose, behind the camera)."""
    from egograph.geometry.hl2ss import invert_rigid, pose_validity, pv_project, transform_points

    cache: dict[int, np.ndarray | None] = {}

    def project(i: int, xyz: np.ndarray):
        if i not in cache:
            ok = bool(rec.pv_valid[i]) and pose_validity(rec.pv_poses[i])
            cache[i] = invert_rigid(rec.pv_poses[i]) if ok else None
        inv = cache[i]
        if inv is None:
            return None
        uv, depth = pv_project(transform_points(np.asarray(xyz, float)[None], inv), rec.pv.intrinsics)
        return uv[0] if depth[0] > 0 else None

    return project


def harvest_teacher(rec: Recording, teacher: Teacher, cfg) -> tuple[Harvest, dict]:
    """Harvest boxes from a teacher (``cfg``: the full configuration). InputError naming the results
    when it has no confident stand. Returns the harvest and the detections' ``ts -> file`` map."""
    from egograph.steps.lift import load_detections

    stands = confident_stands(teacher.stands, cfg.adapt)
    if not stands:
        where = Path(teacher.source["results"]) / INTERVALS_FILE if teacher.source["results"] != "memory" else teacher.detections_dir
        raise InputError(where, f"no confident stand to learn from ({len(teacher.stands)} intervals; a stand teaches with "
                                f">= adapt.min_support {cfg.adapt.min_support} inliers and adapt.min_confidence "
                                f">= {cfg.adapt.min_confidence:g})")
    dets = load_detections(rec, str(teacher.detections_dir), cfg)
    scan = getattr(dets, "scan", None)
    index = {int(t): k for k, t in enumerate(rec.timestamps)}
    per_frame = {index[int(ts)]: [(d.instance, (d.box.x_min, d.box.y_min, d.box.x_max, d.box.y_max)) for d in row]
                 for ts, row in dets.items() if int(ts) in index and row}
    files = {index[int(ts)]: str(scan.matched[ts]) for ts in (scan.matched if scan is not None else {}) if int(ts) in index}
    return harvest_boxes(stands, per_frame, projector(rec), cfg.adapt), files


def embed_harvest(rec: Recording, harvest: Harvest, encoder, fcfg, files: dict, detections_dir: Path) -> np.ndarray:
    """Embeddings (N, D) of the harvested boxes' crops, frame by frame. A box with no pixel inside
    its frame, or a frame whose PV image is missing, is an InputError naming the detection file."""
    from egograph.frontend.matching import crop
    from egograph.steps.detect import read_pv

    out = np.zeros((len(harvest), getattr(encoder, "dim", 0)), np.float32)
    for f in np.unique(harvest.frames):
        rows = np.nonzero(harvest.frames == f)[0]
        where = files.get(int(f), str(Path(detections_dir) / f"{int(rec.timestamps[int(f)])}.txt"))
        rgb = read_pv(rec, int(f))
        if rgb is None:
            raise InputError(rec.pv_path(int(f)), f"PV image of a detection in {where} missing or unreadable")
        crops = []
        for k in rows:
            c = crop(rgb, harvest.boxes[k], fcfg.crop_margin)
            if c is None:
                b = harvest.boxes[k]
                raise InputError(where, f"box {b[0]:g} {b[1]:g} {b[2]:g} {b[3]:g} of instance {harvest.instance[k]} "
                                        f"is outside its {rgb.shape[1]}x{rgb.shape[0]} PV frame")
            crops.append(c)
        out[rows] = encoder.embed(crops)
    return out


@dataclass
class Adaptation:
    """A fitted head and what made it: ``record`` is ``adapt.json``'s content."""

    head: Head
    record: dict
    seconds: dict = field(default_factory=dict)

    @property
    def round(self) -> int:
        return int(self.record["round"])

    @property
    def stopped(self) -> str:
        return self.record.get("stop") or ""

    def digest(self) -> str:
        return outputs.digest(self.head.to_arrays()["weights"], self.head.to_arrays()["bias"],
                              self.head.to_arrays()["instances"])

    def summary(self) -> str:
        r = self.record
        lines = [f"adapt round {r['round']} (taught by {r['taught_by']['results']}): {r['harvest']['crops']} crops from "
                 f"{len(r['stands'])} confident stands, {r['harvest']['background']} background crops; "
                 f"held-back rank AUC {_fmt(r['holdback_auc'])}; fit {r['seconds']['fit']:.1f} s, "
                 f"crops {r['seconds']['crops']:.1f} s"]
        for inst, row in sorted(r["instances"].items(), key=lambda kv: int(kv[0])):
            lines.append(f"  {inst}: {'head' if row['head'] else 'plain cosine'}, {row['positives']} positives, "
                         f"{row['negatives']} negatives, held-back AUC {_fmt(row['holdback_auc'])} (plain "
                         f"{_fmt(row['holdback_auc_plain'])})" + (f": {row['why']}" if row["why"] else ""))
        if r.get("stop"):
            lines.append(f"  stop: {r['stop']}")
        return "\n".join(lines)


def _fmt(v) -> str:
    return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.2f}"


def fit_adaptation(rec: Recording, teacher: Teacher, cfg, encoder, views: dict[int, np.ndarray], detector,
                   enroll: str) -> Adaptation:
    """Harvest, embed and fit (see the module doc). ``detector``: the detect step's FrameDetector,
    whose proposals of the background frames are embedded once and left for the detection pass."""
    from egograph.steps.detect import read_pv

    acfg, fcfg = cfg.adapt, cfg.frontend
    t0 = time.perf_counter()
    harvest, files = harvest_teacher(rec, teacher, cfg)
    emb = embed_harvest(rec, harvest, encoder, fcfg, files, teacher.detections_dir)
    t1 = time.perf_counter()
    picks = np.unique(np.linspace(0, len(rec) - 1, min(acfg.background_frames, len(rec))).round().astype(int)) \
        if acfg.background_frames else np.zeros(0, int)
    bg = []
    for i in picks:
        if int(i) in detector.embedded:
            bg.append(detector.embedded[int(i)][1])
            continue
        rgb = read_pv(rec, int(i))
        if rgb is not None:
            detector.embedded[int(i)] = detector.embed_proposals(int(i), rgb)
            bg.append(detector.embedded[int(i)][1])
    background = np.concatenate(bg) if bg else np.zeros((0, emb.shape[1]), np.float32)
    t2 = time.perf_counter()
    head, report, owners = fit_heads(harvest, emb, views, background, acfg, fcfg.similarity_threshold,
                                     fcfg.mvpe_pooling)
    t3 = time.perf_counter()
    stands = [dict(s.key(), owner=int(o)) for s, o in zip(harvest.stands, owners)]
    record = {"round": teacher.round, "enroll": enroll, "taught_by": teacher.source,
              "recording": outputs.recording_digest(rec),
              "harvest": {"crops": len(harvest), "by_instance": {str(k): v for k, v in harvest.counts().items()},
                          "background": len(background)},
              "stands": stands, "instances": {str(k): v.to_json() for k, v in report.items()},
              "holdback_auc": _num(pooled_holdback(report)),
              "seconds": {"crops": round(t1 - t0, 3), "background": round(t2 - t1, 3), "fit": round(t3 - t2, 3)},
              "stop": stop_reason(teacher.previous, stands, pooled_holdback(report), acfg)}
    adaptation = Adaptation(head, record, record["seconds"])
    record["head"] = adaptation.digest()
    return adaptation


def _num(v):
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else round(float(v), 4)


def stop_reason(previous: dict | None, stands: list[dict], holdback: float, acfg) -> str | None:
    """Why iterating should stop after this round (None: go on): the held-back check fell below the
    previous round's by more than ``holdback_drop``, or at most ``stop_change`` of the confident
    stands moved or appeared since the previous round's."""
    if not previous:
        return None
    before = previous.get("holdback_auc")
    if before is not None and not math.isnan(holdback) and holdback < before - acfg.holdback_drop:
        return f"held-back rank AUC fell from {before:.2f} to {holdback:.2f}"
    changed = stands_changed(previous.get("stands") or [], stands, acfg.contest_radius_m or 0.3)
    if changed <= acfg.stop_change:
        return f"stands stopped changing ({100 * changed:.0f} % moved or new)"
    return None


def adapt_record_inputs(adaptation: Adaptation) -> dict:
    """What detections made with a head depend on of it (their run record's ``adapt`` input)."""
    return {"round": adaptation.round, "taught_by": adaptation.record["taught_by"], "head": adaptation.digest()}


def write_adapt_files(adaptation: Adaptation) -> dict[str, str]:
    return {ADAPT_FILE: json.dumps(adaptation.record, indent=1, sort_keys=True) + "\n"}


def load_adapt(rec: Recording, path: str | Path) -> Adaptation:
    """An adapt folder (``head.npz`` + ``adapt.json``) made for this recording; InputError naming the file."""
    folder = Path(path)
    f, h = folder / ADAPT_FILE, folder / HEAD_FILE
    if not f.is_file() or not h.is_file():
        raise InputError(folder, f"not an adapt folder: {ADAPT_FILE} and {HEAD_FILE} expected")
    try:
        record = json.loads(f.read_text())
        with np.load(h) as a:
            head = Head.from_arrays(a)
    except (OSError, ValueError, KeyError) as e:
        raise InputError(f, f"unreadable adapt folder ({e})") from None
    mine = outputs.recording_digest(rec)
    theirs = record.get("recording") or {}
    if theirs.get("sequence") != mine["sequence"] or theirs.get("frames") != mine["frames"] \
            or theirs.get("poses") != mine["poses"]:
        raise InputError(f, f"made for another recording ({theirs.get('sequence')}, {theirs.get('frames')} frames; "
                            f"this one: {mine['sequence']}, {mine['frames']} frames)")
    return Adaptation(head, record, record.get("seconds", {}))


def adapt(rec: Recording, enroll: str, teacher: Teacher, cfg, out: str | Path, *, encoder=None,
          overwrite: bool = False) -> Adaptation:
    """Fit the heads of ``teacher`` and write the adapt folder ``out`` (module doc); read it back when
    it already holds this exact fit."""
    from egograph.frontend.encoder import load_encoder
    from egograph.frontend.proposals import proposal_sources
    from egograph.io.atomic import atomic_dir
    from egograph.steps.detect import DetectReport, FrameDetector, encoder_id, enroll_views

    fcfg = cfg.frontend
    record = outputs.run_record("adapt", cfg, {"recording": outputs.recording_digest(rec), "enroll": enroll,
                                               "encoder": encoder_id(cfg, encoder), "taught_by": teacher.source},
                                depends_on={"frontend": to_dict(fcfg), "adapt": to_dict(cfg.adapt), "io": to_dict(cfg.io)})
    if outputs.up_to_date(Path(out), record, overwrite):
        return load_adapt(rec, out)
    report = DetectReport()
    enc = load_encoder(fcfg, encoder)
    views = enroll_views(rec, enroll, enc, cfg, report)
    det = FrameDetector(rec, fcfg, enc, None, proposal_sources(rec, fcfg, fcfg.proposals_for(enroll)), report)
    adaptation = fit_adaptation(rec, teacher, cfg, enc, views, det, enroll)
    with atomic_dir(out) as tmp:
        np.savez(tmp / HEAD_FILE, **adaptation.head.to_arrays())
        for name, text in {**write_adapt_files(adaptation), **outputs.run_files(record, cfg)}.items():
            (tmp / name).write_text(text)
    return adaptation
