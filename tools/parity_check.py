"""Two checkouts of egograph on the same good input: the digests of their outputs, and the wall
time of ``egograph track`` interleaved (A B A B ...) in one run, reported as a ratio.

    python tools/parity_check.py --base /tmp/base004 --new . --recordings s1 s2 --timing r3000 --rounds 3

Each checkout runs as ``python -m egograph.cli.main`` with ``PYTHONPATH`` set to it, from inside it.
The digest of an output covers every file but ``egograph.json`` (it holds the command line and
the run record, whose recording entry may gain keys) in name order; observations ``.npz`` are
hashed array by array (provenance left out for the same reason).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

SKIP = {"egograph.json"}


def egograph(checkout: Path, *argv: str) -> float:
    env = dict(os.environ, PYTHONPATH=str(checkout), OMP_NUM_THREADS="1")
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "egograph.cli.main", *argv], cwd=checkout, env=env,
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"{checkout}: egograph {' '.join(argv)}: exit {r.returncode}: {r.stderr[-400:]}")
    return time.perf_counter() - t0


def digest(path: Path) -> str:
    h = hashlib.sha256()
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for f in files:
        if f.name in SKIP:
            continue
        h.update(f.name.encode())
        if f.suffix == ".npz":
            with np.load(f, allow_pickle=False) as z:
                for k in sorted(z.files):
                    if k != "provenance":
                        h.update(k.encode() + z[k].tobytes())
        else:
            h.update(f.read_bytes())
    return h.hexdigest()[:16]


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--base", type=Path, required=True)
    ap.add_argument("--new", type=Path, required=True)
    ap.add_argument("--recordings", type=Path, nargs="*", default=[])
    ap.add_argument("--trackers", default="graph,memory,kf")
    ap.add_argument("--timing", type=Path)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--work", type=Path, default=Path("/tmp/parity"))
    args = ap.parse_args()
    sides = {"base": args.base.resolve(), "new": args.new.resolve()}
    same = 0
    total = 0
    for rec in args.recordings:
        rec = rec.resolve()
        for side, checkout in sides.items():
            egograph(checkout, "lift", str(rec), "--detections", "svoe", "--quiet", "--overwrite", "--out",
                     str(args.work / side / rec.name / "obs.npz"))
        d = {s: digest(args.work / s / rec.name / "obs.npz") for s in sides}
        total += 1
        same += d["base"] == d["new"]
        print(f"{rec.name} lift (robust): base {d['base']} new {d['new']} {'same' if len(set(d.values())) == 1 else 'DIFFERENT'}",
              flush=True)
        for tracker in args.trackers.split(","):
            for side, checkout in sides.items():
                egograph(checkout, "track", str(rec), "--tracker", tracker, "--quiet", "--overwrite", "--out",
                         str(args.work / side / rec.name / tracker))
            d = {s: digest(args.work / s / rec.name / tracker) for s in sides}
            total += 1
            same += d["base"] == d["new"]
            print(f"{rec.name} track {tracker}: base {d['base']} new {d['new']} "
                  f"{'same' if len(set(d.values())) == 1 else 'DIFFERENT'}", flush=True)
    if args.recordings:
        print(f"digests equal: {same} of {total}")
    if args.timing:
        rec = args.timing.resolve()
        times = {s: [] for s in sides}
        for r in range(args.rounds):
            for side in (("base", "new") if r % 2 == 0 else ("new", "base")):
                t = egograph(sides[side], "track", str(rec), "--tracker", "graph", "--quiet", "--overwrite", "--out",
                             str(args.work / side / "timing"))
                times[side].append(t)
                print(f"round {r + 1} {side}: {t:.1f} s", flush=True)
        b, n = np.median(times["base"]), np.median(times["new"])
        print(f"track --tracker graph on {rec.name}: median base {b:.1f} s, new {n:.1f} s, new/base {n / b:.3f} "
              f"(base {', '.join(f'{t:.1f}' for t in times['base'])}; new {', '.join(f'{t:.1f}' for t in times['new'])})")
        d = {s: digest(args.work / s / "timing") for s in sides}
        print(f"{rec.name} track graph digests: base {d['base']} new {d['new']} "
              f"{'same' if len(set(d.values())) == 1 else 'DIFFERENT'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
