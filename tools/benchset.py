#!/usr/bin/env python
"""Build (or reuse) the cached benchmark set (egograph.synth.benchset) and print its recordings.

    .venv/bin/python tools/benchset.py --seeds 1 2 3 4 5 --frames 3000 [--world legacy] [--set detections.svoe.detect_rate=0.5]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from egograph.synth.benchset import add_world_argument, benchmark_set, world_config

REPO = Path(__file__).resolve().parents[1]
DEFAULT_CACHE = REPO / ".cache" / "bench"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="generator override")
    ap.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    add_world_argument(ap)
    a = ap.parse_args()
    for r in benchmark_set(a.seeds, a.frames, config=world_config(a.world), cache=a.cache, overrides=a.overrides):
        print(r)


if __name__ == "__main__":
    main()
