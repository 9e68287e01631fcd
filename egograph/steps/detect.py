"""Step ``detect``: PV frames + an enrollment (SVOE box or MVPE photos) -> per-frame detections.

For every PV frame: class-agnostic proposals (:mod:`egograph.frontend.proposals`), each cropped and
embedded by an ONNX image encoder (:mod:`egograph.frontend.encoder`), compared by cosine similarity
with every enrolled instance; per instance the most similar proposal at or above
``frontend.similarity_threshold`` is kept (top-1 per instance per frame, as the reference
pipeline); with ``frontend.exclusive`` (MVPE by default) only among the proposals that are more
similar to that instance than to any other; with ``frontend.whiten`` (SVOE by default) it must also pass the
whitened gate (:mod:`egograph.frontend.whiten`, statistics from the proposals of ``whiten_frames``
sampled frames) and the best whitened score is kept; with ``guide_world`` (``--guide``) the proposal
nearest the instance's projected 3D estimate is kept (within ``guidance_radius_px``). The output
folder holds one ``<ts>.txt`` per PV frame in the reference association format ``instance x1 y1
x2 y2 det_conf similarity`` (PV pixels; empty without detections), which ``egograph lift/track
--detections DIR`` read, plus ``config.yaml`` and ``egograph.json``; it is committed by one rename.
"""

from __future__ import annotations

import contextlib
import hashlib
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from egograph.core.config import to_dict
from egograph.core.errors import EgographError, InputError
from egograph.core.values import format_number
from egograph.io.recording import Recording, report_problem
from egograph.steps import outputs
from egograph.steps.recording import labels as read_labels
from egograph.steps.recording import require_annotations

ENROLLMENTS = ("svoe", "mvpe")
RUN_LEVEL_ADAPT_KNOBS = ("rounds", "stop_change", "holdback_drop")   # egograph run's, not one detect's
STORED = np.zeros((1, 1, 3), np.uint8)   # stands in for a PV image whose proposals' embeddings are stored
STAGES = ("background", "read", "proposals", "crops", "encoder", "matching", "write")


@dataclass
class DetectReport:
    """What ``detect`` did: frames, detections per instance (id -> count), what was skipped and
    why, proposals encoded, and the seconds spent per stage."""

    frames: int = 0
    skipped_frames: list[str] = field(default_factory=list)       # PV images missing or unreadable
    enrolled: dict[int, int] = field(default_factory=dict)        # instance -> views embedded
    not_enrolled: dict[int, tuple[str, str]] = field(default_factory=dict)   # instance -> (path, why)
    detections: dict[int, int] = field(default_factory=dict)
    proposals: int = 0
    seconds: dict[str, float] = field(default_factory=lambda: dict.fromkeys(STAGES, 0.0))
    names: list[str] = field(default_factory=list)
    adaptation: object = None    # the head used (egograph.steps.adapt.Adaptation), if adapted
    stored_from: str | None = None   # proposals and embeddings read from this file (the encoder not run)
    enrolled_size_m: dict[int, float] = field(default_factory=dict)   # instance -> its size at enrollment (verification)
    size_not_used: str = ""      # the enrolled sizes outside frontend.verify_size_range_m, which the verification ignores
    size_note: str = ""          # why the verification scored boxes without their size at depth
    # instance -> (head turn rate at its SVOE box, deg/s; PV frames of the views added; the object
    # point's source or why there is none): frontend.svoe_sharp_views
    sharp_views: dict[int, tuple[float, list[int], str]] = field(default_factory=dict)

    def name(self, inst: int) -> str:
        return self.names[inst] if inst < len(self.names) else str(inst)

    def summary(self) -> str:
        total = sum(self.seconds.values())
        # with stored embeddings this pass only scores and writes: its speed is not the front-end's
        how = f"read with their embeddings from {self.stored_from}" if self.stored_from else "encoded"
        speed = "frames/s scoring the stored proposals" if self.stored_from else "frames/s"
        lines = [f"{self.frames} PV frames, {self.proposals} proposals {how} ({self.proposals / max(self.frames, 1):.1f}"
                 f"/frame), {self.frames / max(total, 1e-9):.2f} {speed}; ms/frame: "
                 + ", ".join(f"{k} {1000 * v / max(self.frames, 1):.0f}" for k, v in self.seconds.items())]
        for inst in sorted(set(self.enrolled) | set(self.not_enrolled)):
            if inst in self.enrolled:
                n = self.detections.get(inst, 0)
                lines.append(f"  {inst} {self.name(inst)}: {n} detections in {self.frames} frames "
                             f"({100 * n / max(self.frames, 1):.0f} %), {self.enrolled[inst]} enrollment views")
            else:
                lines.append(f"  {inst} {self.name(inst)}: not enrolled ({': '.join(self.not_enrolled[inst])})")
        if self.enrolled_size_m:
            known = {k: v for k, v in self.enrolled_size_m.items() if np.isfinite(v)}
            lines.append(f"  sizes at enrollment (verification's 3D plausibility): {len(known)} of "
                         f"{len(self.enrolled_size_m)} instances had depth behind their box"
                         + (" (" + ", ".join(f"{k} {100 * v:.0f} cm" for k, v in sorted(known.items())) + ")"
                            if known else ""))
        if self.sharp_views:
            lines.append("  SVOE boxes drawn while the head turned fast, views added from sharp frames "
                         "(frontend.svoe_sharp_views): " + "; ".join(
                             f"{k} at {rate:.0f} deg/s: " + (
                                 f"{len(fr)} (frames {', '.join(map(str, fr))}; point from {how})" if fr else
                                 "none (no sharp frame nearby holds the box)" if how in ("depth", "mesh") else
                                 f"none ({how})")
                             for k, (rate, fr, how) in sorted(self.sharp_views.items())))
        if self.size_not_used:
            lines.append(f"  {self.size_not_used}")
        if self.size_note:
            lines.append(f"  {self.size_note}")
        if self.adaptation is not None:
            lines.append(self.adaptation.summary())
        if self.skipped_frames:
            lines.append(f"  {len(self.skipped_frames)} PV frames skipped (no image or unreadable), e.g. "
                         + ", ".join(self.skipped_frames[:3]))
        return "\n".join(lines)


# --------------------------------------------------------------------------- enrollment


def svoe_boxes(rec: Recording, report: DetectReport) -> dict[int, tuple[int, tuple[int, int, int, int], np.ndarray]]:
    """Each instance's ``svoe.txt`` box (its first usable line): (PV frame index, box clipped
    to the image, the frame's RGB); an instance whose box cannot be used is in
    ``report.not_enrolled`` with the file and why."""
    from egograph.io.annotations import load_annotations
    from egograph.steps.recording import require_svoe

    path = require_svoe(rec)
    out: dict = {}
    for e in load_annotations(rec.annotation_dir, svoe_path=path).svoe:
        if e.instance in out:
            continue   # one enrollment per instance: the first usable line
        try:
            i = rec.index_of(e.ts)
        except (KeyError, ValueError, EgographError):
            report.not_enrolled[e.instance] = (str(path), f"frame {e.ts} is no PV frame")
            continue
        rgb = rec.rgb(i)
        if rgb is None:
            report.not_enrolled[e.instance] = (str(rec.pv_path(i)), "PV image of the SVOE box missing or unreadable")
            continue
        rows, cols = rgb.shape[:2]
        b = e.box
        x1, y1, x2, y2 = max(b.x_min, 0), max(b.y_min, 0), min(b.x_max, cols), min(b.y_max, rows)
        if x2 - x1 < 2 or y2 - y1 < 2:
            report.not_enrolled[e.instance] = (str(path), f"box {b.x_min:g} {b.y_min:g} {b.x_max:g} {b.y_max:g} "
                                                           f"outside its {cols}x{rows} frame {e.ts}")
            continue
        out[e.instance] = (i, (x1, y1, x2, y2), rgb)
    return out


def enroll_svoe(rec: Recording, encoder, cfg, report: DetectReport, n_labels: int = 0,
                images: dict | None = None, boxes: dict | None = None, lift_cfg=None) -> dict[int, np.ndarray]:
    """Views of each instance's ``svoe.txt`` box (:func:`svoe_boxes`; see
    :func:`egograph.frontend.matching.svoe_views`), and, where the head turned fast at the box's
    frame, the box carried to nearby sharp frames (``frontend.svoe_sharp_views``, with ``lift_cfg``;
    :mod:`egograph.frontend.sharp_views`); ``images``, when given, receives each instance's view crops
    (RGB) for verification, ``boxes`` each instance's (PV frame index, box clipped to the image)."""
    from egograph.frontend.matching import crop, svoe_views
    from egograph.steps.recording import require_svoe

    views = {}
    sharp = _SharpEnrollment(rec, cfg, lift_cfg) if cfg.svoe_sharp_views > 0 and lift_cfg is not None else None
    for inst, (i, box, rgb) in svoe_boxes(rec, report).items():
        crops = svoe_views(rgb, box, cfg)
        if sharp is not None and crops and sharp.smeared(i):
            got = sharp.views(i, box, rgb.shape[:2])
            used = []
            for f, b in zip(got.frames, got.boxes):
                im = rec.rgb(f)
                c = crop(im, b, cfg.crop_margin) if im is not None else None
                if c is not None:
                    crops.append(c)
                    used.append(f)
            report.sharp_views[inst] = (float(sharp.rate[i]), used, got.point_from)
        views[inst] = encoder.embed(crops)
        if images is not None:
            images[inst] = crops
        if boxes is not None:
            boxes[inst] = (i, box)
    for inst in range(n_labels):
        if inst not in views and inst not in report.not_enrolled:
            report.not_enrolled[inst] = (str(require_svoe(rec)), "no box for this instance")
    return views


class _SharpEnrollment:
    """What :func:`enroll_svoe` needs for ``frontend.svoe_sharp_views``, made once per recording: the
    head's turn rate per PV frame and the robust lift's context (rays, the mesh)."""

    def __init__(self, rec: Recording, cfg, lift_cfg):
        from egograph.frontend.sharp_views import turn_rate_dps

        self.rec, self.cfg, self.lift_cfg = rec, cfg, lift_cfg
        self.rate = turn_rate_dps(rec.pv_poses, rec.timestamps)
        self._ctx = None   # the robust lift's context, built at the first smeared box

    def smeared(self, i: int) -> bool:
        """Whether the head turned faster than ``svoe_sharp_dps`` at PV frame ``i`` (unknown: no)."""
        return bool(self.rate[i] > self.cfg.svoe_sharp_dps)

    def views(self, i: int, box, shape):
        """:func:`egograph.frontend.sharp_views.sharp_views` of the box (none, with the reason, when the
        recording has no depth or mesh to place it by)."""
        from egograph.frontend.sharp_views import SharpViews, sharp_views
        from egograph.geometry.robust_lift import robust_context

        try:
            if self._ctx is None:
                self._ctx = robust_context(self.rec, self.lift_cfg, [])
            return sharp_views(self.rec, i, box, shape, self.cfg, self.lift_cfg, self.rate, self._ctx)
        except (EgographError, OSError, ValueError) as err:
            return SharpViews([], [], f"no object point: {err}")


def plausible_sizes(sizes: dict[int, float], size_range_m) -> dict[int, float]:
    """``sizes`` (instance -> metres at enrollment) with those outside ``size_range_m``
    (``frontend.verify_size_range_m``) made unknown (NaN): an enrollment box measured at 2 cm or 2 m
    measured something other than the object (the depth behind the box was not the object's), and a
    ratio against it would favour boxes of that wrong size (the verification then scores them against
    the range only)."""
    lo, hi = (float(v) for v in size_range_m)
    return {k: (v if lo <= v <= hi else float("nan")) for k, v in sizes.items()}


def sizes_not_used_note(measured: dict[int, float], used: dict[int, float], size_range_m) -> str:
    """The summary's line naming the instances whose measured size at enrollment
    :func:`plausible_sizes` made unknown ("" when none)."""
    dropped = sorted(k for k, v in measured.items() if np.isfinite(v) and not np.isfinite(used.get(k, np.nan)))
    if not dropped:
        return ""
    lo, hi = (100 * float(v) for v in size_range_m)
    return (f"not used, outside frontend.verify_size_range_m ({lo:g}-{hi:g} cm): the size at enrollment of "
            + ", ".join(map(str, dropped)) + " (their boxes are scored against the range only)")


def enroll_mvpe(rec: Recording, encoder, cfg, names: list[str], report: DetectReport,
                images: dict | None = None) -> dict[int, np.ndarray]:
    """Embeddings of each instance's photos (``<mvpe>/<instance_name>/*.jpg``, at most ``mvpe_max_photos``);
    ``images``, when given, receives each instance's photos (RGB) for verification."""
    import cv2

    from egograph.frontend.matching import autocrop
    from egograph.io.annotations import read_mvpe_photos
    from egograph.io.recording import locate_mvpe

    look = locate_mvpe(rec.seq_dir, names, rec.mvpe_dir or None)
    if look.found is None:
        raise InputError(rec.seq_dir, "no MVPE photos found; tried " + ", ".join(look.tried[:6]) + "; set io.mvpe_dir")
    photos = read_mvpe_photos(look.found)
    views = {}
    for inst, name in enumerate(names):
        files = photos.get(name, [])[:cfg.mvpe_max_photos]
        crops, bad = [], []
        for f in files:
            img = cv2.imread(str(f), cv2.IMREAD_COLOR)
            if img is None:
                bad.append(f.name)
            else:
                rgb = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
                crops.append(autocrop(rgb, cfg.crop_margin) if cfg.mvpe_autocrop else rgb)
        if bad:
            warnings.warn(f"{Path(look.found) / name}: {len(bad)} unreadable photo(s) skipped, e.g. {bad[0]}",
                          stacklevel=2)
        if not crops:
            why = "no readable photos" if files else "no photos (*.jpg, *.jpeg) in this folder, or no such folder"
            report.not_enrolled[inst] = (str(Path(look.found) / name), why)
            continue
        views[inst] = encoder.embed(crops)
        if images is not None:
            images[inst] = crops
    return views


# --------------------------------------------------------------------------- frames


def project_guides(rec: Recording, guide_world: dict[int, np.ndarray] | None, i: int) -> dict[int, np.ndarray]:
    """PV pixel positions in frame ``i`` of the given 3D estimates (instance -> (N, 3) world, metres,
    NaN where none); only estimates in front of the camera."""
    from egograph.geometry.hl2ss import invert_rigid, pose_validity, pv_project, transform_points

    out = {}
    if not guide_world or not rec.pv_valid[i] or not pose_validity(rec.pv_poses[i]):
        return out
    inv = invert_rigid(rec.pv_poses[i])
    for inst, xyz in guide_world.items():
        p = np.asarray(xyz[i], float)
        if not np.isfinite(p).all():
            continue
        uv, depth = pv_project(transform_points(p[None], inv), rec.pv.intrinsics)
        if depth[0] > 0:
            out[inst] = uv[0]
    return out


def guides_from_results(rec: Recording, path: str | Path) -> dict[int, np.ndarray]:
    """3D guidance from a tracker's results folder (``egograph track --out``): instance -> (N, 3)
    world positions, metres, NaN where none. The guide for PV frame ``i`` is the instance's
    prediction at frame ``i - 1``, the last estimate an online loop would hold before detecting
    in frame ``i``; so the guidance from a causal track (``graph-causal``, ``memory``, ``kf``)
    uses no frame at or after ``i``, while an offline track's guidance looks ahead.

    A folder that is not there, or whose files hold no prediction for any PV frame of ``rec``,
    is an error naming the folder and the file names tried."""
    from egograph.io.detections import read_results_dir

    folder = Path(path)
    if not folder.is_dir():
        raise InputError(folder, "3D guidance: not a results folder (egograph track --out DIR)")
    outputs.check_results_belong(rec, folder)
    stamps = [int(t) for t in rec.timestamps]
    guide = guides_from_predictions(rec, read_results_dir(folder, stamps))
    if not guide:
        raise InputError(folder, f"3D guidance: no prediction for any of the {len(stamps)} PV frames "
                                 f"(tried {stamps[0]}.txt ... {stamps[-1]}.txt)" if stamps else
                                 "3D guidance: the recording has no PV frame")
    return guide


def guides_from_predictions(rec: Recording, per_frame: dict) -> dict[int, np.ndarray]:
    """:func:`guides_from_results` on a tracker's per-frame predictions in memory (``ts ->
    [Prediction]``, e.g. ``TrackResult.per_frame``): frame ``i``'s guide is frame ``i - 1``'s
    prediction; {} when there is none."""
    stamps = [int(t) for t in rec.timestamps]
    guide: dict[int, np.ndarray] = {}
    for i, ts in enumerate(stamps[:-1]):
        for p in per_frame.get(ts, ()):
            if p.instance not in guide:
                guide[p.instance] = np.full((len(stamps), 3), np.nan)
            guide[p.instance][i + 1] = p.xyz
    return guide


def guide_digest(guide_world: dict[int, np.ndarray] | None) -> str | None:
    """What the detections depend on of the guidance: a digest of its positions (None without;
    the run record says ``guided: false`` then, as before guidance could be given)."""
    if guide_world is None:
        return None
    h = hashlib.sha256()
    for inst in sorted(guide_world):
        h.update(str(inst).encode())
        h.update(np.ascontiguousarray(np.asarray(guide_world[inst], np.float64)).tobytes())
    return h.hexdigest()[:16]


def frame_text(rows: list[tuple[int, tuple, float, float]]) -> str:
    """``instance x1 y1 x2 y2 det_conf similarity`` lines (boxes to 0.1 px, scores to 1e-4)."""
    return "".join(" ".join([str(inst), *(format_number(round(v, 1)) for v in box),
                             format_number(round(min(max(conf, 0.0), 1.0), 4)),
                             format_number(round(min(max(sim, -1.0), 1.0), 4))]) + "\n"
                   for inst, box, conf, sim in rows)


class BoxSizes:
    """The metric size of PV boxes: the geometric mean of a box's sides (pixels) at the range of the
    object point behind it (the robust lift, :func:`egograph.geometry.robust_lift.robust_box_point`,
    which separates the object from what stands behind it), over the PV focal length. Metres; NaN
    where the frame has no depth or pose, or the box no depth pixels. One frame's depth is read once
    for all its boxes."""

    def __init__(self, rec: Recording, lift_cfg):
        from egograph.geometry.robust_lift import robust_context

        self.rec, self.posed = rec, lift_cfg.registration == "posed"
        self.ctx = robust_context(rec, lift_cfg, [])
        k = np.asarray(rec.pv.intrinsics, np.float64)
        self.focal_px = float(np.sqrt(abs(k[0, 0] * k[1, 1])))
        self._frame: tuple[int, object, object] | None = None

    def __call__(self, i: int, boxes) -> np.ndarray:
        from egograph.geometry.chains import frame_chains
        from egograph.geometry.robust_lift import robust_box_point

        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        out = np.full(len(boxes), np.nan)
        if self._frame is None or self._frame[0] != i:
            chains = frame_chains(self.rec, i, posed=self.posed)
            self._frame = (i, chains, self.rec.depth_raw(i) if chains is not None else None)
        _, chains, raw = self._frame
        if chains is None or raw is None:
            return out
        for n, b in enumerate(boxes):
            got = robust_box_point(self.ctx, raw, chains, b)
            if not isinstance(got, str):
                side = np.sqrt(max(b[2] - b[0], 1.0) * max(b[3] - b[1], 1.0))
                out[n] = side * float(np.linalg.norm(got[0])) / self.focal_px
        return out


def box_sizes(rec: Recording, lift_cfg, report: DetectReport | None = None) -> BoxSizes | None:
    """:class:`BoxSizes` of ``rec``, or None (said in ``report``) when the recording has no depth
    to size boxes with: the verification then scores every box as one without depth."""
    try:
        return BoxSizes(rec, lift_cfg)
    except (EgographError, OSError, ValueError) as err:
        if report is not None:
            report.size_note = f"boxes scored without their size at depth: {err}"
        return None


class FrameDetector:
    """Proposals -> crops -> embeddings -> top-1 per instance, for one PV frame at a time; after
    :meth:`use_whitening` a proposal must also pass the whitened gate and the best whitened score
    is kept."""

    def __init__(self, rec: Recording, cfg, encoder, enrollment, sources, report: DetectReport,
                 exclusive: bool = False):
        self.rec, self.cfg, self.encoder, self.enrollment, self.sources, self.report = (
            rec, cfg, encoder, enrollment, sources, report)
        self.exclusive = exclusive   # a proposal goes to the instance it is most similar to only
        self.whitening = None
        self.head = None             # adapted scoring (egograph.frontend.adapt), after use_head
        self.adapt_cfg = None
        self.stored: dict[int, tuple[list, np.ndarray]] | None = None   # every frame's, read from a file
        self.seen: dict[int, tuple[list, np.ndarray]] = {}              # what this pass embedded (to save)
        self.embedded: dict[int, tuple[list, np.ndarray]] = {}   # frame -> its proposals and embeddings, if done
        self.verifier = None         # verification (egograph.frontend.verify), after use_verification
        self.sizes: BoxSizes | None = None   # boxes' sizes at depth (the calibration's 3D plausibility)
        self.enrolled_size: dict[int, float] = {}   # instance -> its size at enrollment, metres (NaN: unknown)
        self.collect: list | None = None   # with a list: every verified pair's features (tools/fit_verify.py)

    def use_whitening(self, whitening) -> None:
        """Match with ``whitening`` (:mod:`egograph.frontend.whiten`; None: plain cosine only)."""
        from egograph.frontend.matching import Enrollment

        self.whitening = whitening
        if whitening is not None:
            self.white = Enrollment({k: whitening(v) for k, v in self.enrollment.views.items()},
                                    self.enrollment.pooling)

    def use_verification(self, images: dict[int, list[np.ndarray]], enroll: str, sizes: BoxSizes | None = None,
                         enrolled_size: dict[int, float] | None = None) -> None:
        """Verify shortlisted proposals against the enrollment ``images`` (instance -> RGB views) and
        write the calibrated probability (:mod:`egograph.frontend.verify`; ``enroll`` picks the
        coefficients); ``sizes`` measures the shortlisted boxes at depth, against ``enrolled_size``
        (instance -> metres) in the calibration map (None: every box scored as one without depth)."""
        from egograph.frontend.verify import Verifier, view_set

        self.sizes, self.enrolled_size = sizes, dict(enrolled_size or {})
        t0 = time.perf_counter()
        self.verifier = Verifier(self.cfg)
        self.verify_views, self.no_views = {}, view_set([])   # an instance without views verifies nothing
        for inst, ims in images.items():
            pick_ = np.unique(np.linspace(0, len(ims) - 1, min(len(ims), self.cfg.verify_max_views)).round().astype(int))
            self.verify_views[inst] = view_set(self.verifier.map(self.verifier.features, [ims[k] for k in pick_]))
        c = self.cfg   # (pair model, its fallback, calibration map) of the enrollment
        self.coef = (c.verify_coef_svoe, c.verify_fallback_svoe, c.verify_calib_svoe) if enroll == "svoe" else \
            (c.verify_coef_mvpe, c.verify_fallback_mvpe, c.verify_calib_mvpe)
        self.report.seconds["verify"] = self.report.seconds.get("verify", 0.0) + time.perf_counter() - t0

    def _verified_rows(self, i, rgb, kept, boxes, plain, white, guides) -> list:
        """Verification (see :mod:`egograph.frontend.verify`): per instance its ``verify_top_k``
        proposals by embedding; each verified against the instance's views; the pair model's
        probability; a proposal goes to the instance it is most probably (exclusive); the calibrated
        probability (:func:`~egograph.frontend.verify.calibrate`, with the boxes' sizes at depth against
        the instances' at enrollment); per instance the most probable at
        ``verify_threshold`` or more (or, with a guide, the nearest such)."""
        from egograph.frontend.matching import crop, pick
        from egograph.frontend.verify import (calibrate, fallback_rows, feature_rows, owned, probability, size_features,
                                              textured)

        cfg, t0 = self.cfg, time.perf_counter()
        ids = sorted(plain)
        table = np.stack([plain[k] for k in ids])                   # (K, P)
        rank = np.stack([white[k] for k in ids]) if white is not None else table
        n_p = table.shape[1]
        top = np.argsort(-rank, axis=1, kind="stable")[:, :cfg.verify_top_k]
        tex_p = np.zeros(n_p, bool)                 # per proposal: scored with its local features
        ks_top = np.unique(top)
        shortlisted = [int(k) for k in ks_top]
        crops = [crop(rgb, boxes[k], cfg.crop_margin) for k in shortlisted]
        feats = dict(zip(shortlisted, self.verifier.map(self.verifier.features, crops)))
        shapes = {k: c.shape[:2] for k, c in zip(shortlisted, crops)}
        for k in shortlisted:
            tex_p[k] = textured(feats[k], shapes[k], cfg)
        size_p = np.full(n_p, np.nan)               # per proposal: its size at depth, metres
        if self.sizes is not None:
            size_p[ks_top] = self.sizes(i, np.asarray([boxes[k] for k in shortlisted], np.float64))
        enrolled = np.array([self.enrolled_size.get(inst, np.nan) for inst in ids])
        inl = np.zeros((len(ids), n_p))
        spread = np.zeros((len(ids), n_p))
        colour = np.zeros((len(ids), n_p))
        pairs = [(a, int(k)) for a in range(len(ids)) for k in top[a]]
        got = self.verifier.map(self.verifier.best, [feats[k] for _, k in pairs],
                                [self.verify_views.get(ids[a], self.no_views) for a, _ in pairs])
        for (a, k), (n_in, spread_ak, colour_ak) in zip(pairs, got):
            inl[a, k], spread[a, k], colour[a, k] = n_in, spread_ak, colour_ak
        listed = np.zeros((len(ids), n_p), bool)
        listed[np.repeat(np.arange(len(ids)), top.shape[1]), top.ravel()] = True
        prob = np.zeros((len(ids), n_p))
        for a, inst in enumerate(ids):
            ks = top[a]
            others = np.delete(table, a, axis=0)
            cos_margin = table[a, ks] - (others[:, ks].max(axis=0) if len(others) else 0.0)
            other_inl = np.delete(np.where(listed, inl, 0.0), a, axis=0)
            inl_margin = inl[a, ks] - (other_inl[:, ks].max(axis=0) if len(other_inl) else 0.0)
            w = rank[a, ks] if white is not None else np.zeros(len(ks))
            x = feature_rows(table[a, ks], cos_margin, w, inl[a, ks], spread[a, ks], inl_margin, colour[a, ks])
            tex = tex_p[ks]
            prob[a, ks] = np.where(tex, probability(x, self.coef[0]), probability(fallback_rows(x), self.coef[1]))
            if self.collect is not None:
                for j, k in enumerate(ks):
                    self.collect.append((i, inst, tuple(boxes[k]), bool(tex[j]), x[j], feats[int(k)].n,
                                         min(shapes[int(k)]), float(size_p[k]), float(enrolled[a])))
        mine = owned(prob, listed)
        size_x = size_features(size_p[None, :], enrolled[:, None], cfg.verify_size_range_m)   # (K, P, 4)
        cal = np.where(np.isfinite(mine), calibrate(prob, tex_p[None, :], self.coef[2], size_x), -np.inf)
        rows = []
        for a, inst in enumerate(ids):
            k = pick(cal[a], boxes, cfg.verify_threshold, (guides or {}).get(inst), cfg.guidance_radius_px)
            if k is not None:
                rows.append((inst, kept[k].box, 1.0 if tex_p[k] else 0.0, float(cal[a, k])))
        self.report.seconds["verify"] = self.report.seconds.get("verify", 0.0) + time.perf_counter() - t0
        return rows

    def use_head(self, head, adapt_cfg) -> None:
        """Score proposals with the adapted logit (:func:`egograph.frontend.adapt.adapted_logits`):
        per instance the head's logit plus the cosine prior; a proposal passes at logit >= 0 and the
        score written is :func:`~egograph.frontend.adapt.adapted_score` (instances without a head keep
        the plain rule and write the plain cosine)."""
        self.head, self.adapt_cfg = head, adapt_cfg

    def embed_proposals(self, i: int, rgb: np.ndarray) -> tuple[list, np.ndarray]:
        """Frame ``i``'s proposals that give a crop, and their embeddings (P, D, unit rows)."""
        if self.stored is not None and i in self.stored:
            return self.stored[i]
        kept, emb = self._embed_proposals(i, rgb)
        self.seen[i] = (kept, emb)
        return kept, emb

    def _embed_proposals(self, i: int, rgb: np.ndarray) -> tuple[list, np.ndarray]:
        from egograph.frontend.matching import crop
        from egograph.frontend.proposals import frame_proposals, nms, rank_scores

        cfg, sec = self.cfg, self.report.seconds
        t0 = time.perf_counter()
        _, props = frame_proposals(self.sources, i, rgb, cfg)
        props = nms(props, cfg.nms_iou, cfg.max_proposals, rank_scores(props, rgb, cfg))
        t1 = time.perf_counter()
        crops, kept = [], []
        for p in props:
            c = crop(rgb, p.box, cfg.crop_margin)
            if c is not None:
                crops.append(c)
                kept.append(p)
        t2 = time.perf_counter()
        emb = self.encoder.embed(crops)
        sec["proposals"] += t1 - t0
        sec["crops"] += t2 - t1
        sec["encoder"] += time.perf_counter() - t2
        return kept, emb

    def _plain_rows(self, kept, boxes, plain, white, guides) -> list:
        from egograph.frontend.matching import pick

        cfg, rows = self.cfg, []
        score = plain if white is None else white
        owner = exclusive_owner(score) if self.exclusive else None
        for inst, sims in plain.items():
            g = (guides or {}).get(inst)
            s = sims if owner is None else np.where(owner == inst, sims, -np.inf)
            if white is None:
                k = pick(s, boxes, cfg.similarity_threshold, g, cfg.guidance_radius_px)
            else:   # both gates; among the proposals passing them the best whitened score
                w = np.where(s >= cfg.similarity_threshold, white[inst], -np.inf)
                k = pick(w, boxes, cfg.whiten_threshold, g, cfg.guidance_radius_px)
            if k is not None:
                rows.append((inst, kept[k].box, kept[k].conf, float(sims[k])))
        return rows

    def _adapted_rows(self, kept, boxes, emb, plain, white, guides) -> list:
        """Adapted scoring: the prior is the margin of the plain gates (the least of cosine -
        similarity_threshold and, under whitening, whitened cosine - whiten_threshold), so an
        instance without a head passes exactly the proposals the plain rule passes."""
        from egograph.frontend.adapt import adapted_logits, adapted_score
        from egograph.frontend.matching import pick

        cfg, rows = self.cfg, []
        margin = {k: v - cfg.similarity_threshold for k, v in plain.items()}
        if white is not None:
            margin = {k: np.minimum(margin[k], white[k] - cfg.whiten_threshold) for k in margin}
        z = adapted_logits(self.head, margin, emb, self.adapt_cfg, 0.0)
        if self.adapt_cfg.gate == "plain":   # the head re-ranks and vetoes the plain rule's proposals only
            z = {k: np.where(margin[k] >= 0, v, -np.inf) for k, v in z.items()}
        owner = exclusive_owner(z) if self.exclusive else None
        for inst, zi in z.items():
            g = (guides or {}).get(inst)
            s = zi if owner is None else np.where(owner == inst, zi, -np.inf)
            k = pick(s, boxes, 0.0, g, cfg.guidance_radius_px)
            if k is not None:
                score = float(adapted_score(zi[k], self.adapt_cfg)) if inst in self.head.weights else float(plain[inst][k])
                rows.append((inst, kept[k].box, kept[k].conf, score))
        return rows

    def __call__(self, i: int, rgb: np.ndarray, guides: dict | None = None) -> list[tuple[int, tuple, float, float]]:
        kept, emb = self.embedded.pop(i) if i in self.embedded else self.embed_proposals(i, rgb)
        t3 = time.perf_counter()
        v0 = self.report.seconds.get("verify", 0.0)
        rows = []
        if kept:
            boxes = [p.box for p in kept]
            plain = self.enrollment.similarity(emb)
            white = self.white.similarity(self.whitening(emb)) if self.whitening is not None else None
            if self.verifier is not None:
                rows = self._verified_rows(i, rgb, kept, boxes, plain, white, guides)
            elif self.head is not None:
                rows = self._adapted_rows(kept, boxes, emb, plain, white, guides)
            else:
                rows = self._plain_rows(kept, boxes, plain, white, guides)
        # verification is timed as its own stage
        self.report.seconds["matching"] += time.perf_counter() - t3 - (self.report.seconds.get("verify", 0.0) - v0)
        self.report.proposals += len(kept)
        return sorted(rows)


def proposal_embeddings_key(rec: Recording, cfg, encoder, source_name: str) -> str:
    """What a frame's proposals and their embeddings depend on: the recording (poses included), the
    front-end knobs that shape proposals and crops (not matching's nor verification's), the encoder
    and the proposal source."""
    f = to_dict(cfg.frontend)
    matching = ("similarity_threshold", "whiten", "whiten_threshold", "whiten_shrink", "whiten_frames", "exclusive",
                "mvpe_pooling", "mvpe_max_photos", "mvpe_autocrop", "svoe_augment", "guidance_radius_px")
    return outputs.digest("proposal-embeddings", outputs.recording_digest(rec), encoder_id(cfg, encoder), source_name,
                          {k: v for k, v in f.items() if k not in matching and not k.startswith("verify")},
                          to_dict(cfg.io))


def load_proposal_embeddings(path: str | Path, key: str) -> dict[int, tuple[list, np.ndarray]] | None:
    """Every frame's proposals and embeddings from ``path`` when it holds them under ``key``, else None."""
    from egograph.frontend.proposals import Proposal

    p = Path(path)
    if not p.is_file():
        return None
    try:
        with np.load(p, allow_pickle=False) as a:
            if str(a["key"]) != key:
                return None
            frame, box, conf, src, emb = a["frame"], a["box"], a["conf"], a["source"], a["embedding"]
            done = a["frames_done"]
    except (OSError, ValueError, KeyError):
        return None
    out: dict[int, tuple[list, np.ndarray]] = {}
    order = np.argsort(frame, kind="stable")
    cuts = np.flatnonzero(np.diff(frame[order])) + 1
    for rows in np.split(order, cuts) if len(order) else []:
        out[int(frame[rows[0]])] = ([Proposal(tuple(float(v) for v in box[k]), str(src[k]), float(conf[k])) for k in rows],
                                    emb[rows].astype(np.float32))
    for i in done:
        out.setdefault(int(i), ([], np.zeros((0, emb.shape[1]), np.float32)))
    return out


def save_proposal_embeddings(path: str | Path, key: str, seen: dict[int, tuple[list, np.ndarray]]) -> None:
    """Write every embedded frame's proposals and embeddings to ``path`` atomically."""
    from egograph.io.atomic import atomic_path

    frames = sorted(seen)
    rows = [(i, p, e) for i in frames for p, e in zip(seen[i][0], seen[i][1])]
    dim = next((len(e) for _, _, e in rows), 0)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, key=np.array(key), frames_done=np.asarray(frames, np.int64),
                     frame=np.asarray([r[0] for r in rows], np.int64),
                     box=np.asarray([r[1].box for r in rows], np.float64).reshape(-1, 4),
                     conf=np.asarray([r[1].conf for r in rows], np.float64),
                     source=np.asarray([r[1].source for r in rows], dtype="U16"),
                     embedding=np.asarray([r[2] for r in rows], np.float32).reshape(-1, dim))


def exclusive_owner(scores: dict[int, np.ndarray]) -> np.ndarray:
    """Per proposal, the instance it is most similar to (``scores``: instance -> (P,) similarities):
    one proposal shows one object, so with ``frontend.exclusive`` it may be the detection of that
    instance only. Ties go to the smaller instance id."""
    ids = sorted(scores)
    table = np.stack([scores[k] for k in ids])            # (K, P)
    return np.asarray(ids)[np.argmax(table, axis=0)]


def read_pv(rec: Recording, i: int) -> np.ndarray | None:
    """PV frame ``i`` as RGB uint8, or None when missing or unreadable (counted and named by the
    caller in one warning, so none here: this runs in a thread)."""
    import cv2

    p = rec.pv_path(i)
    img = cv2.imread(str(p), cv2.IMREAD_COLOR) if p.is_file() else None
    return None if img is None else cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def detect_frame(rec: Recording, i: int, ts: int, rgb: np.ndarray | None, run: "FrameDetector",
                 guide_world, report: DetectReport, files: dict[str, str]) -> None:
    """One PV frame's detection file into ``files`` (empty, and the image counted as skipped, without it)."""
    if rgb is None:
        report.skipped_frames.append(str(rec.pv_path(i)))
        files[f"{ts}.txt"] = ""
        return
    rows = run(i, rgb, project_guides(rec, guide_world, i))
    report.frames += 1
    for inst, *_ in rows:
        report.detections[inst] = report.detections.get(inst, 0) + 1
    files[f"{ts}.txt"] = frame_text(rows)


def background_whitening(rec: Recording, run: FrameDetector, cfg, report: DetectReport):
    """Whitening (:func:`egograph.frontend.whiten.fit_whitening`) fitted to the proposals of
    ``cfg.whiten_frames`` PV frames evenly spread over ``rec`` (unreadable frames skipped); None,
    with a warning naming the recording, when they give fewer than 2 crops. The sampled frames'
    proposals and embeddings stay in ``run.embedded`` for the detection pass."""
    from egograph.frontend.whiten import fit_whitening

    t0 = time.perf_counter()
    saved = dict(report.seconds)
    picks = np.unique(np.linspace(0, len(rec) - 1, min(cfg.whiten_frames, len(rec))).round().astype(int))
    embs = []
    for i in picks:
        rgb = read_pv(rec, int(i))
        if rgb is not None:
            run.embedded[int(i)] = run.embed_proposals(int(i), rgb)
            embs.append(run.embedded[int(i)][1])
    report.seconds = saved      # the sample pass is timed as one stage of its own
    report.seconds["background"] += time.perf_counter() - t0
    emb = np.concatenate(embs) if embs else np.zeros((0, 0), np.float32)
    if len(emb) < 2:
        warnings.warn(f"{rec.seq_dir}: whitened matching off: the {len(picks)} sampled PV frames gave "
                      f"{len(emb)} proposal crop(s), too few for background statistics", stacklevel=2)
        return None
    return fit_whitening(emb, cfg.whiten_shrink)


def encoder_id(cfg, encoder_path: str | Path | None) -> dict:
    """What the detections depend on of the encoder: its file's size and a digest of its first MB."""
    path = encoder_path or cfg.frontend.encoder
    if not path:
        from egograph.frontend import effnet

        return {"embedded": "efficientnet_lite0", "converter": effnet.CONVERTER_VERSION}
    p = Path(path)
    try:
        with open(p, "rb") as f:
            head = hashlib.sha256(f.read(1 << 20)).hexdigest()[:16]
        return {"path": str(p), "size": p.stat().st_size, "head": head}
    except OSError:
        return {"path": str(p)}


def enroll_views(rec: Recording, enroll: str, enc, cfg, report: DetectReport,
                 images: dict | None = None, boxes: dict | None = None) -> dict[int, np.ndarray]:
    """The enrollment views of ``enroll`` (svoe | mvpe) embedded by ``enc``, instances that could not
    be enrolled reported (an error under ``--strict``); an error when none could be. ``images``, when
    given, receives the view images (RGB) per instance; ``boxes`` (SVOE) each instance's (PV frame
    index, box)."""
    require_annotations(rec, "instance labels for detection")
    names = read_labels(rec) or []
    report.names = names
    fcfg = cfg.frontend
    views = enroll_svoe(rec, enc, fcfg, report, len(names), images, boxes, cfg.lift) if enroll == "svoe" else \
        enroll_mvpe(rec, enc, fcfg, names, report, images)
    for inst, (where, why) in report.not_enrolled.items():
        report_problem(rec.strict, where, f"instance {inst} ({report.name(inst)}) not enrolled: {why}")
    if not views:
        raise EgographError(f"{rec.seq_dir}: no instance could be enrolled ({enroll}); nothing to detect")
    report.enrolled = {k: len(v) for k, v in views.items()}
    return views


def adapt_input(rec: Recording, adapt) -> tuple[object, dict | bool]:
    """``adapt`` (None, a path: an adapt folder with head.npz or a results folder of egograph track, a
    :class:`~egograph.steps.adapt.Teacher` or an :class:`~egograph.steps.adapt.Adaptation`) -> (the
    teacher or fitted adaptation, what the detections depend on of it: False without)."""
    if adapt is None:
        return None, False
    from egograph.steps.adapt import HEAD_FILE, Adaptation, adapt_record_inputs, load_adapt, teacher_from_results

    if isinstance(adapt, (str, Path)):
        adapt = load_adapt(rec, adapt) if (Path(adapt) / HEAD_FILE).is_file() else teacher_from_results(rec, adapt)
    if isinstance(adapt, Adaptation):
        return adapt, adapt_record_inputs(adapt)
    return adapt, {"round": adapt.round, "taught_by": adapt.source}


def detect(rec: Recording, enroll: str, cfg, out: str | Path, *, encoder: str | Path | None = None,
           proposals: str | None = None, guide_world: dict[int, np.ndarray] | None = None,
           adapt=None, embeddings: str | Path | None = None, overwrite: bool = False,
           progress: bool = True, collect: list | None = None, frames=None) -> DetectReport | None:
    """Detect the instances enrolled by ``enroll`` (``svoe`` or ``mvpe``) in every PV frame of
    ``rec``, writing the folder ``out`` (see module doc). ``encoder``/``proposals`` override
    ``cfg.frontend.encoder``/``.proposals`` (``.mvpe_proposals`` for MVPE when set);
    ``guide_world``: optional 3D estimates per instance and frame (3D guidance,
    ``frontend.guidance_radius_px``); ``adapt``: a teacher or a fitted head (:func:`adapt_input`;
    :mod:`egograph.steps.adapt`): proposals are scored by the per-instance head with the cosine as a
    prior, and ``adapt.json`` in ``out`` says which round, taught by which results; ``embeddings``: a
    file of every frame's proposals and their embeddings (:func:`proposal_embeddings_key`), read when
    it holds this recording's under the same front-end knobs and encoder, else written after the pass
    (rounds of adaptation detect again on the same proposals: only the scoring changes). Returns the
    report, or None when ``out`` already holds this exact run. Nothing enrolled, no PV image, a bad
    encoder or a teacher with nothing to teach raise before anything is written. ``collect``: a list
    that receives, under verification, every shortlisted (frame, instance, box, textured, features,
    the crop's keypoints, its short side in PV pixels)
    (``tools/fit_verify.py`` fits the coefficients on it); ``frames``: detect in these PV frame
    indices only (benchmarks and fits on a sample; the other frames get no file)."""
    from tqdm import tqdm

    from egograph.frontend.encoder import load_encoder
    from egograph.frontend.matching import Enrollment
    from egograph.frontend.proposals import proposal_sources

    if enroll not in ENROLLMENTS:
        raise EgographError(f"--enroll {enroll}: one of {', '.join(ENROLLMENTS)}")
    fcfg = cfg.frontend
    source_name = proposals or fcfg.proposals_for(enroll)
    teacher, adapt_id = adapt_input(rec, adapt)
    inputs = {"recording": outputs.recording_digest(rec), "enroll": enroll, "encoder": encoder_id(cfg, encoder),
              "proposals": source_name, "guided": guide_digest(guide_world) or False}
    depends = {"frontend": to_dict(fcfg), "io": to_dict(cfg.io)}
    if frames is not None:   # a sample of the frames is another run than the whole recording
        inputs["frames"] = [int(i) for i in frames]
    verifying = fcfg.verify in ("all", enroll) and teacher is None
    if verifying or (enroll == "svoe" and fcfg.svoe_sharp_views > 0):   # boxes' sizes, points behind boxes
        depends["lift"] = to_dict(cfg.lift)
    if adapt_id:   # unadapted runs keep the fingerprint they had before adaptation existed
        inputs["adapt"] = adapt_id
        depends["adapt"] = {k: v for k, v in to_dict(cfg.adapt).items() if k not in RUN_LEVEL_ADAPT_KNOBS}
    record = outputs.run_record("detect", cfg, inputs, depends_on=depends)
    if outputs.up_to_date(Path(out), record, overwrite):
        return None
    report = DetectReport()
    enc = load_encoder(fcfg, encoder)
    images: dict | None = {} if verifying else None
    enrolled_at: dict = {}
    views = enroll_views(rec, enroll, enc, cfg, report, images, enrolled_at)
    enrollment = Enrollment(views, fcfg.mvpe_pooling)
    sources = proposal_sources(rec, fcfg, source_name)
    run = FrameDetector(rec, fcfg, enc, enrollment, sources, report, exclusive=fcfg.exclusive in ("all", enroll))
    emb_key = proposal_embeddings_key(rec, cfg, encoder, source_name) if embeddings is not None else None
    stored = load_proposal_embeddings(embeddings, emb_key) if embeddings is not None else None
    if stored is not None:
        run.stored = stored
        report.stored_from = Path(embeddings).name
    if fcfg.whiten in ("all", enroll):
        run.use_whitening(background_whitening(rec, run, fcfg, report))
    # the verification's threads stop however the run ends (an adaptation or a frame that fails)
    with contextlib.ExitStack() as stack:
        if verifying:
            sizes = box_sizes(rec, cfg.lift, report)
            report.enrolled_size_m = {k: float(sizes(i, [b])[0]) if sizes is not None else float("nan")
                                      for k, (i, b) in enrolled_at.items()}   # SVOE's boxes; MVPE's photos have no depth
            used = plausible_sizes(report.enrolled_size_m, fcfg.verify_size_range_m)
            report.size_not_used = sizes_not_used_note(report.enrolled_size_m, used, fcfg.verify_size_range_m)
            run.use_verification(images, enroll, sizes, used)
            stack.callback(run.verifier.close)
            run.collect = collect
        adaptation = None
        if teacher is not None:
            from egograph.steps.adapt import Adaptation, fit_adaptation

            t0 = time.perf_counter()
            saved = dict(report.seconds)
            adaptation = teacher if isinstance(teacher, Adaptation) else fit_adaptation(rec, teacher, cfg, enc, views, run, enroll)
            report.seconds = saved
            report.seconds["adapt"] = time.perf_counter() - t0
            report.adaptation = adaptation
            run.use_head(adaptation.head, cfg.adapt)
        files: dict[str, str] = {}
        from concurrent.futures import ThreadPoolExecutor

        # the next PV image is decoded in a thread (OpenCV releases the GIL) while this frame's
        # proposals and encoder run: "read" is only the time spent waiting for it
        with ThreadPoolExecutor(1) as pool:

            def read(i: int):   # a frame whose proposals are stored needs no image
                return STORED if run.stored is not None and i in run.stored and run.verifier is None else read_pv(rec, i)

            todo = list(range(len(rec))) if frames is None else sorted(int(i) for i in frames)
            if not todo:
                raise EgographError(f"{rec.seq_dir}: no PV frame to detect in")
            ahead = pool.submit(read, todo[0])
            for n, i in enumerate(tqdm(todo, desc=f"detect ({enroll})", unit="frame", disable=not progress, mininterval=1.0)):
                ts = int(rec.timestamps[i])
                t0 = time.perf_counter()
                rgb = ahead.result()
                if n + 1 < len(todo):
                    ahead = pool.submit(read, todo[n + 1])
                report.seconds["read"] += time.perf_counter() - t0
                detect_frame(rec, i, ts, rgb, run, guide_world, report, files)
    if report.frames == 0:
        raise InputError(rec.seq_dir / "pv", f"none of the {len(rec)} PV images could be read (e.g. "
                                             f"{report.skipped_frames[0] if report.skipped_frames else '-'})")
    if report.skipped_frames:
        report_problem(rec.strict, report.skipped_frames[0],
                       f"{len(report.skipped_frames)} of {len(rec)} PV images missing or unreadable (this one "
                       "first); their frames get empty detection files")
    from egograph.io.textio import write_text_dir

    t0 = time.perf_counter()
    if embeddings is not None and stored is None:
        save_proposal_embeddings(embeddings, emb_key, run.seen)
    files.update(outputs.run_files(record, cfg))
    if adaptation is not None:
        from egograph.steps.adapt import write_adapt_files

        files.update(write_adapt_files(adaptation))
    write_text_dir(out, files)
    report.seconds["write"] += time.perf_counter() - t0
    return report


def carry_detections(rec: Recording, adaptation, cfg, out: str | Path, *, overwrite: bool = False) -> bool:
    """Iterating stopped (``adaptation.stopped``): ``out`` gets the per-frame files of the detections
    that taught this round (the round before's) unchanged, its run record and ``adapt.json`` saying
    so. Returns False when ``out`` already holds exactly this."""
    from egograph.io.textio import write_text_dir
    from egograph.steps.adapt import write_adapt_files

    src = Path(adaptation.record["taught_by"]["detections"])
    stamps = [int(t) for t in rec.timestamps]
    record = outputs.run_record("detect", cfg, {"recording": outputs.recording_digest(rec),
                                                "carried": {"from": str(src), "digest": outputs.folder_digest(src)},
                                                "adapt": {"round": adaptation.round, "stop": adaptation.stopped,
                                                          "taught_by": adaptation.record["taught_by"]}},
                                depends_on={})
    if outputs.up_to_date(Path(out), record, overwrite):
        return False
    files = {}
    for ts in stamps:
        f = src / f"{ts}.txt"
        files[f.name] = f.read_text() if f.is_file() else ""
    files.update(outputs.run_files(record, cfg))
    files.update(write_adapt_files(adaptation))
    write_text_dir(out, files)
    return True
