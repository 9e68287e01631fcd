#!/usr/bin/env python
"""Calibrate the simulated front-ends: the paper's pipeline (memory + reference lifting) on the
benchmark set must land in bands around the published SAM + DINOv2 rows (design §6).

    .venv/bin/python tools/calibrate_frontend.py --seeds 1 2 3 4 5 6 7 8 --frames 3000 --tune svoe mvpe
    .venv/bin/python tools/calibrate_frontend.py --seeds 301 302 ... --frames 3000 --set detections.svoe.X=V

Each setting is scored through egograph.synth.calibrate: every candidate box lifted once per recording
(the reference rule), then any setting of the other knobs is a table look-up, the real `memory`
baseline and the IT3DEgo counts (identical to generating the detections and lifting them; tested).
Prints each recording's values, the pooled values (counts pooled over the set, as the reference
evaluator pools sequences) with their standard error (bootstrap over recordings), and against the
band: the centre, and whether the standard error is at most a third of the half-width.

``--tune SET...`` runs a coordinate search (step halving) over that set's free knobs, minimising the
squared distances of the pooled values to the band centres in band half-widths, and prints the
knobs it found as --set lines. Tune on one set of seeds, report on another.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path

import numpy as np

from egograph.core.config import load_config, to_dict
from egograph.core.resources import default_config
from egograph.steps.recording import open_recording
from egograph.steps.settings import EgographConfig
from egograph.synth.benchset import add_world_argument, benchmark_set, world_config
from egograph.synth.calibrate import (
    BANDS,
    PAPER,
    SOURCES,
    annotated_sequence,
    band_values,
    bootstrap_se,
    candidate_tables,
    load_table,
    memory_counts,
    pooled_values,
    save_table,
    simulate_observations,
    table_knobs,
)
from egograph.synth.config import SynthConfig

REPO = Path(__file__).resolve().parents[1]
# knob -> (index into a [mean, std] knob or None, lower bound, upper bound, first step)
FREE_KNOBS = {
    "detect_rate": (None, 0.05, 1.0, 0.1),
    "size_half_px": (None, 10.0, 200.0, 15.0),
    "size_exponent": (None, 0.5, 12.0, 1.0),
    "min_visible": (None, 0.0, 0.9, 0.05),
    "min_box_px": (None, 0.0, 120.0, 8.0),
    "true_score": (0, 0.4, 0.95, 0.04),
    "lookalike_score": (0, 0.2, 0.8, 0.04),
    "clutter_score": (0, 0.2, 0.8, 0.04),
    "clutter_rate": (None, 0.0, 1.0, 0.1),
}


def objective(values: dict[str, float], det_set: str) -> float:
    """Sum of squared distances to the band centres, in band half-widths."""
    out = 0.0
    for m, (lo, hi) in BANDS[det_set].items():
        out += ((values[m] - (lo + hi) / 2) / ((hi - lo) / 2)) ** 2
    return out


def get_knob(fe, name: str) -> float:
    idx = FREE_KNOBS[name][0]
    v = getattr(fe, name)
    return float(v[idx] if idx is not None else v)


def set_knob(fe, name: str, value: float) -> None:
    idx = FREE_KNOBS[name][0]
    if idx is None:
        setattr(fe, name, float(value))
    else:
        v = list(getattr(fe, name))
        v[idx] = float(value)
        setattr(fe, name, v)


class Scorer:
    """The tuning set's tables and sequences; scores a front-end setting in a second or two."""

    def __init__(self, tables, seqs, cfg):
        self.tables, self.seqs, self.cfg = tables, seqs, cfg

    def simulate(self, det_set: str, fe):
        """Per recording: the memory counts at ``fe``, and the sources of the observations it accepts."""
        for tables, seq in zip(self.tables, self.seqs):
            obs, src = simulate_observations(tables[det_set], fe)
            accepted = obs.valid & (obs.score >= np.float32(self.cfg.track.score_threshold))
            yield memory_counts(seq, obs, self.cfg.track), src[accepted]

    def counts(self, det_set: str, fe) -> list:
        return [c for c, _ in self.simulate(det_set, fe)]


def table_path(root: Path, det_set: str, fe) -> Path:
    key = hashlib.sha256(json.dumps(table_knobs(fe), sort_keys=True).encode()).hexdigest()[:12]
    return root / "calibration" / f"{det_set}_{key}"


def load_tables(roots, scfg, cfg) -> tuple[list, list]:
    tables, seqs = [], []
    for root in roots:
        rec = open_recording(root, cfg)
        want = {s: getattr(scfg.detections, s) for s in ("svoe", "mvpe")}
        have = {s: load_table(rec, table_path(root, s, fe), s, fe) for s, fe in want.items()}
        missing = {s: want[s] for s, t in have.items() if t is None}
        if missing:
            t0 = time.perf_counter()
            made = candidate_tables(rec, missing, cfg.lift)
            for s, t in made.items():
                save_table(t, table_path(root, s, want[s]))
                have[s] = t
            print(f"{root.name}: candidate tables {', '.join(missing)} in {time.perf_counter() - t0:.0f} s", flush=True)
        tables.append(have)
        seqs.append(annotated_sequence(rec))
    return tables, seqs


def report(scorer: Scorer, det_set: str, fe, seeds) -> dict:
    runs = list(scorer.simulate(det_set, fe))
    counts = [c for c, _ in runs]
    per = [band_values(c) for c in counts]
    pool, se = pooled_values(counts), bootstrap_se(counts)
    print(f"\n### {det_set.upper()}: memory + reference lifting\n")
    print("| seed | " + " | ".join(BANDS[det_set]) + " |")
    print("|---|" + "---|" * len(BANDS[det_set]))
    for seed, v in zip(seeds, per):
        print(f"| {seed} | " + " | ".join(f"{v[m]:.2f}" for m in BANDS[det_set]) + " |")
    print("| **pooled** | " + " | ".join(f"**{pool[m]:.2f}** ± {se[m]:.2f}" for m in BANDS[det_set]) + " |")
    print("| per-seed SD | " + " | ".join(f"{np.std([v[m] for v in per], ddof=1):.2f}" for m in BANDS[det_set]) + " |")
    print("| band (centre) | " + " | ".join(f"{lo}-{hi} ({(lo + hi) / 2:g})" for m, (lo, hi) in BANDS[det_set].items()) + " |")
    print("| paper | " + " | ".join(f"{PAPER[det_set][m]:g}" for m in BANDS[det_set]) + " |")
    inside = all(lo <= pool[m] <= hi for m, (lo, hi) in BANDS[det_set].items())
    se_ok = all(se[m] <= (hi - lo) / 6 for m, (lo, hi) in BANDS[det_set].items())
    print(f"\n{det_set}: pooled values inside every band: {inside}; standard error <= a third of every "
          f"half-width: {se_ok} (" + ", ".join(f"{m} {se[m]:.2f} vs {(hi - lo) / 6:.2f}"
                                             for m, (lo, hi) in BANDS[det_set].items()) + ")")
    accepted = np.concatenate([src for _, src in runs])
    src = {s: int((accepted == s).sum()) for s in SOURCES}
    tot = max(len(accepted), 1)
    print(f"{det_set}: accepted observations by source: " + ", ".join(f"{s} {100 * n / tot:.1f} %" for s, n in src.items()))
    return {"pooled": pool, "se": se, "per_seed": per, "inside": inside, "se_ok": se_ok}


def implausible(dets) -> str | None:
    """Why a setting of both front-ends is not one a real matcher could have, or None: a look-alike
    or clutter that matches better on average than the instance itself, or a multi-view enrollment
    (MVPE) that finds the instance less often than a single view (SVOE)."""
    for name in ("svoe", "mvpe"):
        fe = getattr(dets, name)
        for other in ("lookalike_score", "clutter_score"):
            if getattr(fe, other)[0] > fe.true_score[0]:
                return f"{name}.{other} above its true_score"
    if dets.mvpe.detect_rate < dets.svoe.detect_rate:
        return "mvpe.detect_rate below svoe.detect_rate"
    return None


def tune(scorer: Scorer, det_set: str, dets, knobs: list[str], rounds: int) -> None:
    fe = getattr(dets, det_set)
    best = objective(pooled_values(scorer.counts(det_set, fe)), det_set)
    print(f"\ntuning {det_set} over {', '.join(knobs)}: start objective {best:.4f}", flush=True)
    steps = {k: FREE_KNOBS[k][3] for k in knobs}
    for r in range(rounds):
        improved = False
        for k in knobs:
            _, lo, hi, _ = FREE_KNOBS[k]
            for sign in (1, -1):
                while True:
                    old = get_knob(fe, k)
                    new = float(np.clip(round(old + sign * steps[k], 4), lo, hi))
                    if new == old:
                        break
                    set_knob(fe, k, new)
                    if implausible(dets):
                        set_knob(fe, k, old)
                        break
                    val = objective(pooled_values(scorer.counts(det_set, fe)), det_set)
                    if val < best - 1e-9:
                        best, improved = val, True
                        print(f"  {k} = {new:g}: objective {val:.4f}", flush=True)
                    else:
                        set_knob(fe, k, old)
                        break
        if not improved:
            steps = {k: s / 2 for k, s in steps.items()}
        print(f" round {r + 1}: objective {best:.4f}", flush=True)
    print(f"\n{det_set} knobs found:")
    for k in knobs:
        print(f"  --set detections.{det_set}.{k}={json.dumps(getattr(fe, k))}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--cache", type=Path, default=REPO / ".cache" / "bench")
    add_world_argument(ap)
    ap.add_argument("--set", dest="synth_overrides", action="append", default=[],
                    help="front-end knob to score at (e.g. detections.svoe.clutter_rate=0.2); tables are made for "
                         "the box_jitter, clutter_per_instance, other_score and min_written_score it gives")
    ap.add_argument("--tune", nargs="*", default=[], choices=["svoe", "mvpe"], help="detection sets to tune")
    ap.add_argument("--knobs", nargs="+", default=list(FREE_KNOBS), choices=list(FREE_KNOBS))
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--json", type=Path, help="write the report here")
    args = ap.parse_args()

    roots = benchmark_set(args.seeds, args.frames, config=world_config(args.world), cache=args.cache, progress=False)
    scfg = load_config(SynthConfig, world_config(args.world), [f"frames={args.frames}", *args.synth_overrides])
    cfg = load_config(EgographConfig, default_config(), ["lift.mode=reference"])
    why = implausible(scfg.detections)
    if why:
        raise SystemExit(f"the starting front-ends are implausible: {why}")
    scorer = Scorer(*load_tables(roots, scfg, cfg), cfg)
    out = {"seeds": args.seeds, "frames": args.frames, "detections": to_dict(scfg.detections)}
    for det_set in ("svoe", "mvpe"):
        fe = getattr(scfg.detections, det_set)
        if det_set in args.tune:
            tune(scorer, det_set, scfg.detections, args.knobs, args.rounds)
        out[det_set] = report(scorer, det_set, fe, args.seeds)
    out["detections"] = to_dict(scfg.detections)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
