#!/usr/bin/env python
"""Fit the verification's score (``frontend.verify_coef_*``, ``verify_fallback_*``, ``verify_calib_*``)
on tuning RGB recordings, print it as configuration, and its calibration error by cross-validation
over the recordings.

    .venv/bin/python tools/fit_verify.py --seeds 27 28 --frames 300 --stride 1 --world device \\
        [--sets svoe mvpe] [--set KEY=VALUE] [--from-collected]

Each recording (egograph.synth.benchset.rgb_benchmark_set of the ``--world``'s SVOE config, cached under
``--cache``) runs ``egograph detect`` with verification on, collecting every shortlisted (proposal,
instance) pair's features (egograph.frontend.verify.FEATURES). A pair is labelled true when the box is
on the instance as the benchmarks count it: the instance at least a quarter visible and IoU >= 0.3
with its true box or the box centre inside it. Two stages, both L2-regularised logistic regressions:

1. the pair model, on every shortlisted pair: one on the crops with keypoints, one on the fallback
   features (every pair: the more data, the steadier);
2. the calibration map (egograph.frontend.verify.calibrate), on each instance's most probable owned
   proposal per frame (the detections, before the threshold) by the pair model of stage 1, with the
   boxes' 3D plausibility (egograph.frontend.verify.size_features: each box's size at its depth
   against the instance's at enrollment and against ``frontend.verify_size_range_m``).

Cross-validation: each recording is scored by the two stages fitted on the others, the detections
selected as ``egograph detect`` selects them (``verify_top_k``, ``verify_threshold``, one instance per
proposal); prints their calibration error (ECE), how many are on the instance and how many
instance-frames they find. The printed coefficients are fitted on every recording. The collected
pairs are saved (``fit_verify_<set>.npz`` in the cache) so that ``--from-collected`` refits without
detecting (pairs saved before the sizes were collected get them measured on the recordings of
``--seeds``, as ``egograph detect`` measures them).
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def box_hits(box, true_boxes: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """(K,) whether ``box`` (x1, y1, x2, y2, PV pixels) is on each instance: at least a quarter visible,
    and IoU >= 0.3 with its true box or the box centre inside it."""
    b = np.asarray(box, float)
    ok = np.isfinite(true_boxes[:, 0]) & (visible >= 0.25)
    t = np.nan_to_num(true_boxes.astype(float))
    w = np.clip(np.minimum(b[2], t[:, 2]) - np.maximum(b[0], t[:, 0]), 0, None)
    h = np.clip(np.minimum(b[3], t[:, 3]) - np.maximum(b[1], t[:, 1]), 0, None)
    inter = w * h
    union = (b[2] - b[0]) * (b[3] - b[1]) + (t[:, 2] - t[:, 0]) * (t[:, 3] - t[:, 1]) - inter
    iou = np.where(union > 0, inter / np.maximum(union, 1e-12), 0.0)
    cx, cy = (b[0] + b[2]) / 2, (b[1] + b[3]) / 2
    inside = (t[:, 0] <= cx) & (cx <= t[:, 2]) & (t[:, 1] <= cy) & (cy <= t[:, 3])
    return ok & ((iou >= 0.3) | inside)


def collected_arrays(rec, got: list, rec_id: int) -> dict[str, np.ndarray]:
    """The collected pairs of one recording as arrays: recording, frame, instance, box, textured,
    features, rank in the instance's shortlist (pairs arrive in rank order), on the instance (``own``),
    on another instance (``other``); plus, per frame processed, the visible instances."""
    with np.load(rec.synth_gt_dir / "instances.npz") as gt:
        boxes, visible = gt["boxes"], gt["visible"]
    frame = np.array([g[0] for g in got], np.int64)
    inst = np.array([g[1] for g in got], np.int64)
    rank = np.zeros(len(got), np.int64)
    for n in range(1, len(got)):
        rank[n] = rank[n - 1] + 1 if (frame[n], inst[n]) == (frame[n - 1], inst[n - 1]) else 0
    own, other = np.zeros(len(got), bool), np.zeros(len(got), bool)
    for n, g in enumerate(got):
        h = box_hits(g[2], boxes[g[0]], visible[g[0]])
        own[n] = g[1] < len(h) and bool(h[g[1]])
        other[n] = bool(np.delete(h, g[1]).any()) if g[1] < len(h) else bool(h.any())
    return {"rec": np.full(len(got), rec_id), "frame": frame, "instance": inst,
            "box": np.array([g[2] for g in got], float).reshape(-1, 4), "textured": np.array([g[3] for g in got], bool),
            "x": np.stack([g[4] for g in got]) if got else np.zeros((0, 7)), "rank": rank, "own": own, "other": other,
            "size": np.array([g[7] for g in got], float), "enrolled": np.array([g[8] for g in got], float)}


def measure_sizes(d: dict, roots: list, cfg) -> None:
    """Add ``size`` and ``enrolled`` (metres, as ``egograph detect`` measures them under verification:
    each box, and each instance's SVOE box, at the depth behind it) to pairs collected without them;
    ``roots``: the recordings in the order of ``d["rec"]``."""
    from egograph.steps.detect import BoxSizes, DetectReport, svoe_boxes
    from egograph.steps.recording import open_recording

    d["size"], d["enrolled"] = np.full(len(d["rec"]), np.nan), np.full(len(d["rec"]), np.nan)
    for r, root in enumerate(roots):
        rec = open_recording(root, cfg)
        sizes = BoxSizes(rec, cfg.lift)
        enrolled = {k: float(sizes(i, [box])[0]) for k, (i, box, _) in svoe_boxes(rec, DetectReport()).items()}
        for n in np.flatnonzero(d["rec"] == r):
            d["size"][n] = sizes(int(d["frame"][n]), [d["box"][n]])[0]
            d["enrolled"][n] = enrolled.get(int(d["instance"][n]), np.nan)


def with_size_terms(d: dict, size_range_m) -> dict:
    """``d`` with ``size_x``, each pair's 3D-plausibility terms (egograph.frontend.verify.size_features)
    as ``egograph detect`` computes them: an enrolled size outside ``size_range_m`` is unknown
    (egograph.steps.detect.plausible_sizes)."""
    from egograph.frontend.verify import size_features
    from egograph.steps.detect import plausible_sizes

    used = plausible_sizes(dict(enumerate(d["enrolled"].tolist())), size_range_m)   # in pair order
    return {**d, "size_x": size_features(d["size"], np.fromiter(used.values(), float, len(used)), size_range_m)}


def visible_frames(rec, frames) -> int:
    """Instance-frames at least a quarter visible with a true box among ``frames``."""
    with np.load(rec.synth_gt_dir / "instances.npz") as gt:
        vis = (gt["visible"] >= 0.25) & np.isfinite(gt["boxes"][..., 0])
    return int(vis[list(frames)].sum())


def fit(x: np.ndarray, y: np.ndarray, c: float) -> list[float] | None:
    """[bias, weights...] of an L2-regularised logistic regression (scikit-learn, lbfgs); None when
    ``y`` holds one label only."""
    from sklearn.linear_model import LogisticRegression

    if len(np.unique(y)) < 2:
        return None
    m = LogisticRegression(C=c, max_iter=5000).fit(x, y)
    return [round(float(m.intercept_[0]), 4), *(round(float(w), 4) for w in m.coef_[0])]


def fit_monotone(x: np.ndarray, y: np.ndarray, c: float) -> list[float] | None:
    """:func:`fit` with every weight >= 0 (the bias free): the same objective as scikit-learn's
    (``c`` x the summed log loss + half the squared weights), minimised by L-BFGS-B under bounds.
    Why: each pair feature (a similarity, a margin, inliers, their spread, colour) can only speak
    for the instance. Fitted freely on the renderer's pairs, the SVOE model of stop 58 weighted the
    inliers' spread and margin negatively and the cosine too: on a real photograph pair
    (tests/test_frontend_verify.py) it then ranked a clutter crop above the object verified with
    dozens of inliers."""
    from scipy.optimize import minimize
    from scipy.special import expit

    if len(np.unique(y)) < 2:
        return None
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)

    def loss(w):
        z = w[0] + x @ w[1:]
        p = expit(z)   # no overflow where the pair is far from the boundary
        nll = np.sum(np.logaddexp(0.0, z) - y * z)
        g = p - y
        return c * nll + 0.5 * w[1:] @ w[1:], np.concatenate([[c * g.sum()], c * (x.T @ g) + w[1:]])

    w0 = np.zeros(x.shape[1] + 1)
    res = minimize(loss, w0, jac=True, method="L-BFGS-B", bounds=[(None, None)] + [(0.0, None)] * x.shape[1],
                   options={"maxiter": 5000})
    return [round(float(v), 4) for v in res.x]


def size_terms(d: dict) -> np.ndarray:
    """The pairs' 3D-plausibility terms (:func:`with_size_terms`)."""
    return d["size_x"]


def pair_probability(d: dict, full, fallback) -> np.ndarray:
    from egograph.frontend.verify import fallback_rows, probability

    pf = probability(fallback_rows(d["x"]), fallback)
    return pf if full is None else np.where(d["textured"], probability(d["x"], full), pf)


def candidates(d: dict, score: np.ndarray) -> np.ndarray:
    """Indices of the pairs ``egograph detect`` would emit at threshold 0: per frame, one instance per
    proposal (the most probable), per instance its most probable owned proposal."""
    from egograph.frontend.verify import owned

    out = []
    keys = np.column_stack([d["rec"], d["frame"]])
    order = np.lexsort((d["frame"], d["rec"]))
    cuts = np.flatnonzero(np.any(np.diff(keys[order], axis=0) != 0, axis=1)) + 1
    for rows in np.split(order, cuts) if len(order) else []:
        insts = np.unique(d["instance"][rows])
        _, prop = np.unique(d["box"][rows].round(3), axis=0, return_inverse=True)
        prop = prop.ravel()
        prob = np.zeros((len(insts), prop.max() + 1))
        listed = np.zeros_like(prob, bool)
        where = {}
        for r, k, p in zip(rows, np.searchsorted(insts, d["instance"][rows]), prop):
            prob[k, p], listed[k, p], where[(k, p)] = score[r], True, r
        mine = owned(prob, listed)
        for k in range(len(insts)):
            if np.isfinite(mine[k]).any():
                out.append(where[(k, int(np.argmax(mine[k])))])
    return np.array(sorted(out), np.int64)


def fit_stages(d: dict, top_k: int, c: float, pair_model=None, monotone: bool = True):
    """(pair model full, fallback, calibration map) fitted on the pairs of ``d`` within ``top_k``
    (the pair model's weights non-negative with ``monotone``, :func:`fit_monotone`); with
    ``pair_model`` (full, fallback) given, only the calibration map is fitted."""
    from egograph.frontend.verify import fallback_rows

    s = {k: v[d["rank"] < top_k] for k, v in d.items()}
    t = s["textured"]
    if pair_model is not None:
        full, fb = pair_model
    else:
        pair_fit = fit_monotone if monotone else fit
        full = pair_fit(s["x"][t], s["own"][t], c)
        fb = pair_fit(fallback_rows(s["x"]), s["own"], c)
    if fb is None:
        raise SystemExit(f"only one label among {len(t)} shortlisted pairs: nothing to fit")
    p = pair_probability(s, full, fb)
    cand = candidates(s, p)
    calib = calibration(p[cand], s["textured"][cand], size_terms(s)[cand], s["own"][cand])
    return full, fb, calib, s


def calibration(p: np.ndarray, textured: np.ndarray, size_x: np.ndarray, y: np.ndarray) -> list[float]:
    """[a, b, c, d...] of :func:`egograph.frontend.verify.calibrate`, fitted on candidates; the
    identity when they carry one label only. Weakly regularised (C = 100): seven coefficients,
    hundreds of rows."""
    q = np.clip(p, 1e-9, 1 - 1e-9)
    got = fit(np.column_stack([np.log(q / (1 - q)), textured, size_x]), y, 100.0)
    return [0.0, 1.0, 0.0, *[0.0] * size_x.shape[1]] if got is None else got


def emitted(d: dict, stages, threshold: float) -> np.ndarray:
    """Indices of the pairs emitted under ``stages`` at ``threshold``, and their probabilities."""
    from egograph.frontend.verify import calibrate

    full, fb, calib = stages
    q = calibrate(pair_probability(d, full, fb), d["textured"], calib, size_terms(d))
    cand = candidates(d, q)
    keep = cand[q[cand] >= threshold]
    return keep, q[keep]


def main() -> None:
    from egograph.synth.benchset import add_world_argument, rgb_benchmark_set, world_config

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[27, 28])
    ap.add_argument("--frames", type=int, default=300)
    add_world_argument(ap)   # the tuning recordings' world (the first verification was fitted in legacy)
    ap.add_argument("--cache", type=Path, default=REPO / ".cache" / "fe_device")
    ap.add_argument("--sets", nargs="+", default=["svoe", "mvpe"], choices=["svoe", "mvpe"])
    ap.add_argument("--stride", type=int, default=1, help="every this many PV frames (the machine is shared)")
    ap.add_argument("--c", type=float, default=1.0, help="inverse L2 regularisation strength of the pair model")
    ap.add_argument("--signed", action="store_true",
                    help="let the pair model's weights take either sign (before stop 58; default: non-negative)")
    ap.add_argument("--calibration-only", action="store_true",
                    help="keep the configured pair model (verify_coef_*, verify_fallback_*), fit the "
                         "calibration map only")
    ap.add_argument("--from-collected", action="store_true",
                    help="refit on the pairs the last run saved in the cache (no detection)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    os.environ.setdefault("EGOGRAPH_CACHE", str(args.cache / "models"))

    from egograph.core.config import load_config
    from egograph.core.resources import default_config
    from egograph.frontend.verify import FALLBACK_FEATURES, FEATURES, expected_calibration_error
    from egograph.steps.detect import detect
    from egograph.steps.recording import open_recording
    from egograph.steps.settings import EgographConfig

    cfg = load_config(EgographConfig, default_config(), ["frontend.verify=all", *args.overrides])
    fc = cfg.frontend
    for det_set in args.sets:
        saved = args.cache / f"fit_verify_{det_set}.npz"
        if args.from_collected:
            if not saved.is_file():
                raise SystemExit(f"--from-collected: {saved} not found (run without it first)")
            with np.load(saved) as z:
                d = {k: z[k] for k in z.files if k != "visible"}
                n_visible = z["visible"]
            if "size" not in d:   # collected before the sizes were: measured on the recordings, and saved
                roots = rgb_benchmark_set(args.seeds, args.frames, config=world_config(args.world), cache=args.cache)
                if len(roots) != len(np.unique(d["rec"])):
                    raise SystemExit(f"--from-collected: {saved} holds {len(np.unique(d['rec']))} recordings, "
                                     f"--seeds names {len(roots)}")
                measure_sizes(d, roots, cfg)
                np.savez(saved, visible=n_visible, **d)
        else:
            roots = rgb_benchmark_set(args.seeds, args.frames, config=world_config(args.world), cache=args.cache)
            parts, n_visible = [], []
            for r, root in enumerate(roots):
                rec = open_recording(root, cfg)
                got: list = []
                frames = range(0, len(rec), args.stride)
                out = Path(tempfile.mkdtemp(prefix="fitverify")) / "det"
                report = detect(rec, det_set, cfg, out, overwrite=True, progress=False, collect=got, frames=frames)
                print(f"{root.name} {det_set}: {len(got)} shortlisted pairs\n{report.summary()}", flush=True)
                parts.append(collected_arrays(rec, got, r))
                n_visible.append(visible_frames(rec, frames))
            d = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
            n_visible = np.array(n_visible)
            np.savez(saved, visible=n_visible, **d)
        d = with_size_terms(d, fc.verify_size_range_m)
        # cross-validation over the recordings
        keep_pair = ((fc.verify_coef_svoe, fc.verify_fallback_svoe) if det_set == "svoe" else
                     (fc.verify_coef_mvpe, fc.verify_fallback_mvpe)) if args.calibration_only else None
        recs = np.unique(d["rec"])
        ps, ys, n_true, n_emit, found, conf = [], [], 0, 0, 0, 0
        for r in recs:
            train = {k: v[d["rec"] != r] for k, v in d.items()}
            test = {k: v[d["rec"] == r] for k, v in d.items()}
            full, fb, calib, _ = fit_stages(train, fc.verify_top_k, args.c, keep_pair, not args.signed)
            test = {k: v[test["rank"] < fc.verify_top_k] for k, v in test.items()}
            keep, q = emitted(test, (full, fb, calib), fc.verify_threshold)
            ps.append(q)
            ys.append(test["own"][keep])
            n_true += int(test["own"][keep].sum())
            n_emit += len(keep)
            found += len({(int(f), int(k)) for f, k, o in zip(test["frame"][keep], test["instance"][keep],
                                                              test["own"][keep]) if o})
            conf += int((test["other"][keep] & ~test["own"][keep]).sum())
        p, y = np.concatenate(ps), np.concatenate(ys)
        full, fb, calib, s = fit_stages(d, fc.verify_top_k, args.c, keep_pair, not args.signed)
        print(f"\n{det_set}: {len(s['own'])} shortlisted pairs (top {fc.verify_top_k}; {int(s['textured'].sum())} with "
              f"keypoints), {s['own'].mean():.3f} true; {int(n_visible.sum())} visible instance-frames")
        print(f"  cross-validated over {len(recs)} recordings at verify_threshold {fc.verify_threshold}: {n_emit} "
              f"detections, {n_true} on the instance, {found} instance-frames found, {conf} on another instance; "
              f"ECE {expected_calibration_error(p, y):.3f} (mean p {p.mean() if len(p) else float('nan'):.3f}, "
              f"share true {y.mean() if len(y) else float('nan'):.3f})")
        print(f"  features {FEATURES}; fallback {FALLBACK_FEATURES}")
        print(f"  verify_coef_{det_set}: {full}\n  verify_fallback_{det_set}: {fb}\n  verify_calib_{det_set}: {calib}",
              flush=True)


if __name__ == "__main__":
    main()
