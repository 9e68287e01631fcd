#!/usr/bin/env python
"""How far an expected calibration error measured on a few recordings can be read: the pooled ECE
of every subset of K recordings of a set, for each egograph tracker and detection set.

    .venv/bin/python tools/ece_spread.py --seeds $(seq 4 20) --frames 900 --subset 3 [--json-tag TAG]
    .venv/bin/python tools/ece_spread.py --seeds $(seq 4 20) --frames 3000 --subset 12 --jobs 2

Each recording is tracked as ``tools/bench_confidence.py`` tracks it (its ``run_recording``: robust
lifting, the shipped calibration, graph-causal at lag 0) and reduced to its reliability table at
``graph.answers.distance_m`` (``egograph.eval.curves.reliability``: per confidence bin, how many
answers, their mean confidence and the share within). A subset's pooled table is the sum of its
recordings' (answers, confidence x answers, within x answers) per bin; its ECE is computed from
that, so it equals what ``bench_confidence`` prints for those recordings pooled. Over every subset
(or ``--max-subsets`` of them drawn with ``--seed`` when there are more): median, 90th percentile,
maximum, and the share above the issue's targets (0.05 offline, 0.08 causal).

Why: an answer's correctness is decided per place an instance stands at, not per frame (a wrong
place is wrong for hundreds of frames), so a set of a few recordings holds only a few dozen
independent outcomes, and an ECE on it is both noisy and biased upward. Run on the tuning
recordings (where the calibration was fitted) it gives the spread a calibrated tracker shows; the
record goes to ``docs/bench/oneoff/ece_spread[-TAG].json`` unless ``--json`` says otherwise.
"""

from __future__ import annotations

import argparse
import itertools
import math
import multiprocessing
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import benchdoc
import numpy as np

REPO = Path(__file__).resolve().parents[1]
TRACKERS = ("graph", "graph-causal lag 0", "memory+graph")
TARGETS = (0.05, 0.08)


def bin_sums(rel) -> np.ndarray:
    """(3, bins): answers, sum of confidence, sum of answers within, per bin of a
    :class:`egograph.eval.curves.Reliability` (empty bins 0)."""
    count = np.asarray(rel.count, np.float64)
    conf = np.nan_to_num(np.asarray(rel.confidence, np.float64)) * count
    within = np.nan_to_num(np.asarray(rel.share, np.float64)) * count
    return np.stack([count, conf, within])


def pooled_ece(sums: list[np.ndarray]) -> float:
    """The expected calibration error of recordings pooled, from their :func:`bin_sums`: the
    answer-weighted mean over bins of |mean confidence - share within| (0 without answers)."""
    s = np.sum(sums, axis=0)
    n = s[0].sum()
    return float(np.abs(s[1] - s[2]).sum() / n) if n > 0 else 0.0


def subset_eces(sums: list[np.ndarray], k: int, max_subsets: int, seed: int) -> np.ndarray:
    """:func:`pooled_ece` of every subset of ``k`` of the recordings, or of ``max_subsets`` subsets
    drawn without repetition of a subset (seeded) when there are more."""
    n = len(sums)
    if k > n:
        raise SystemExit(f"--subset {k}: only {n} recordings")
    if math.comb(n, k) <= max_subsets:
        combos = itertools.combinations(range(n), k)
    else:
        rng = np.random.default_rng(seed)
        seen: set = set()
        while len(seen) < max_subsets:
            seen.add(tuple(sorted(rng.choice(n, k, replace=False).tolist())))
        combos = sorted(seen)
    return np.array([pooled_ece([sums[i] for i in c]) for c in combos])


def recording_sums(root: str, overrides: list[str]) -> dict:
    """{"<set> <tracker>": bin sums} of one recording (in a worker process)."""
    import bench_confidence

    from egograph.core.config import load_config
    from egograph.core.resources import default_config
    from egograph.eval.curves import reliability
    from egograph.steps.settings import EgographConfig

    tau = load_config(EgographConfig, default_config(), overrides).graph.answers.distance_m
    out = bench_confidence.run_recording(Path(root), overrides, [0.0], False)
    return {f"{s} {t}": bin_sums(reliability(out[s][t], tau)) for s in ("svoe", "mvpe") for t in TRACKERS}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--frames", type=int, default=900)
    ap.add_argument("--subset", type=int, nargs="+", default=[3], help="recordings per subset (K; several allowed)")
    ap.add_argument("--max-subsets", type=int, default=5000)
    ap.add_argument("--seed", type=int, default=0, help="draws the subsets when there are more than --max-subsets")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="pipeline override")
    ap.add_argument("--cache", type=Path, default=REPO / ".cache" / "bench")
    ap.add_argument("--jobs", type=int, default=1, help="recordings tracked at once, each in a process of its own")
    from egograph.synth.benchset import add_world_argument

    add_world_argument(ap)
    benchdoc.add_arguments(ap, __file__)
    args = ap.parse_args(argv)
    if args.json is None:
        tag = f"-{args.json_tag}" if args.json_tag else ""
        args.json = str(REPO / "docs" / "bench" / "oneoff" / f"ece_spread{tag}.json")
    benchdoc.start(__file__, args, argv)

    from egograph.synth.benchset import benchmark_set, world_config

    roots = [str(r) for r in benchmark_set(args.seeds, args.frames, config=world_config(args.world),
                                           cache=args.cache)]
    n = len(roots)
    if args.jobs > 1:
        # spawn: a forked child would inherit the parent's thread pools (as bench_confidence --jobs)
        with ProcessPoolExecutor(min(args.jobs, n), mp_context=multiprocessing.get_context("spawn")) as pool:
            parts = list(pool.map(recording_sums, roots, [args.overrides] * n))
    else:
        parts = [recording_sums(r, args.overrides) for r in roots]
    rows = []
    for key in parts[0]:
        sums = [p[key] for p in parts]
        target = TARGETS[1] if "causal" in key else TARGETS[0]
        for k in args.subset:
            e = subset_eces(sums, k, args.max_subsets, args.seed)
            rows.append([key, k, len(e), pooled_ece(sums), float(np.median(e)), float(np.percentile(e, 90)),
                         float(e.max()), target, 100 * float(np.mean(e > target))])
    benchdoc.table(f"Pooled ECE at graph.answers.distance_m over subsets of the {n} recordings",
                   ["set and tracker", "recordings per subset", "subsets", f"all {n} pooled", "median",
                    "90th percentile", "max", "target", "subsets above the target %"], rows,
                   ["", "d", "d", ".3f", ".3f", ".3f", ".3f", ".2f", ".0f"],
                   note=f"Seeds {', '.join(map(str, args.seeds))} x {args.frames} frames ({args.world} world), "
                        "tracked as tools/bench_confidence.py tracks them (shipped calibration); a subset's ECE "
                        "from the sum of its recordings' reliability tables.")
    benchdoc.finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
