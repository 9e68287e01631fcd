#!/usr/bin/env python
"""Fit the verification's logistic coefficients (``frontend.verify_coef_*``, ``verify_fallback_*``)
on tuning RGB recordings, and print them as configuration.

    .venv/bin/python tools/fit_verify.py --seeds 27 28 --frames 500 --stride 5 [--sets svoe mvpe] [--set KEY=VALUE]

Each recording (egograph.synth.benchset.rgb_benchmark_set, cached as tools/bench_frontend_trackers.py
caches them) runs ``egograph detect`` with verification on, collecting every shortlisted
(proposal, instance) pair's features (egograph.frontend.verify.FEATURES). A pair is labelled true
when the box is on the instance as the benchmarks count it: the instance at least a quarter visible
and IoU >= 0.3 with its true box or the box centre inside it. One L2-regularised logistic regression
per set for the crops with keypoints, one on the fallback features for the others. Prints the
training ECE and the share of true pairs; the held-out ECE is tools/bench_verify.py's.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def label_pairs(rec, collected: list) -> np.ndarray:
    """Whether each collected (frame, instance, box, ...) is on its instance (see module doc)."""
    with np.load(rec.synth_gt_dir / "instances.npz") as gt:
        boxes, visible = gt["boxes"], gt["visible"]
    out = np.zeros(len(collected), bool)
    for n, (i, inst, box, *_rest) in enumerate(collected):
        if inst >= boxes.shape[1] or visible[i, inst] < 0.25 or not np.isfinite(boxes[i, inst, 0]):
            continue
        tb = boxes[i, inst]
        out[n] = box_iou(box, tb) >= 0.3 or (tb[0] <= (box[0] + box[2]) / 2 <= tb[2] and tb[1] <= (box[1] + box[3]) / 2 <= tb[3])
    return out


def box_iou(a, b) -> float:
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def fit(x: np.ndarray, y: np.ndarray, c: float) -> list[float]:
    """[bias, weights...] of an L2-regularised logistic regression (scikit-learn, lbfgs)."""
    from sklearn.linear_model import LogisticRegression

    if len(np.unique(y)) < 2:
        raise SystemExit(f"only one label among {len(y)} pairs: nothing to fit")
    m = LogisticRegression(C=c, max_iter=2000).fit(x, y)
    return [round(float(m.intercept_[0]), 4), *(round(float(w), 4) for w in m.coef_[0])]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[27, 28])
    ap.add_argument("--frames", type=int, default=500)
    ap.add_argument("--cache", type=Path, default=REPO / ".cache" / "bench_fe")
    ap.add_argument("--sets", nargs="+", default=["svoe", "mvpe"], choices=["svoe", "mvpe"])
    ap.add_argument("--world", default="device", choices=("device", "legacy"),
                    help="generator world of the RGB recordings (default device; legacy: the world the verification "
                         "was fitted in, issue 39)")
    ap.add_argument("--stride", type=int, default=5, help="every this many PV frames (the machine is shared)")
    ap.add_argument("--c", type=float, default=1.0, help="inverse L2 regularisation strength")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    os.environ.setdefault("EGOGRAPH_CACHE", str(args.cache / "models"))

    from egograph.core.config import load_config
    from egograph.core.resources import default_config
    from egograph.frontend.verify import FALLBACK_FEATURES, FEATURES, expected_calibration_error, fallback_rows, probability
    from egograph.steps.detect import detect
    from egograph.steps.recording import open_recording
    from egograph.steps.settings import EgographConfig
    from egograph.synth.benchset import rgb_benchmark_set, world_config

    roots = rgb_benchmark_set(args.seeds, args.frames, config=world_config(args.world), cache=args.cache)
    cfg = load_config(EgographConfig, default_config(), ["frontend.verify=all", *args.overrides])
    for det_set in args.sets:
        xs, ys, tex = [], [], []
        for root in roots:
            rec = open_recording(root, cfg)
            got: list = []
            out = Path(tempfile.mkdtemp(prefix="fitverify")) / "det"
            report = detect(rec, det_set, cfg, out, overwrite=True, progress=False, collect=got,
                            frames=range(0, len(rec), args.stride))
            print(f"{root.name} {det_set}: {len(got)} shortlisted pairs\n{report.summary()}", flush=True)
            if got:
                xs.append(np.stack([g[4] for g in got]))
                tex.append(np.array([g[3] for g in got]))
                ys.append(label_pairs(rec, got))
        x, y, t = np.concatenate(xs), np.concatenate(ys), np.concatenate(tex)
        np.savez(args.cache / f"fit_verify_{det_set}.npz", x=x, y=y, textured=t)   # to refit without detecting
        full = fit(x[t], y[t], args.c)
        fb = fit(fallback_rows(x), y, args.c)   # the fallback model sees every crop: the more data, the steadier
        p = np.where(t, probability(x, full), probability(fallback_rows(x), fb))
        print(f"\n{det_set}: {len(y)} pairs ({t.sum()} with keypoints), {y.mean():.3f} true; training ECE "
              f"{expected_calibration_error(p, y):.3f} (textured {expected_calibration_error(p[t], y[t]):.3f}, "
              f"fallback {expected_calibration_error(p[~t], y[~t]):.3f})")
        print(f"  features {FEATURES}; fallback {FALLBACK_FEATURES}")
        print(f"  verify_coef_{det_set}: {full}\n  verify_fallback_{det_set}: {fb}", flush=True)


if __name__ == "__main__":
    main()
