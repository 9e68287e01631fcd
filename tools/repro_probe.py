#!/usr/bin/env python
"""Where do two machines' benchmark figures part? A digest of every stage, to compare across CPUs.

    .venv/bin/python tools/repro_probe.py [--seeds 1 2 3 301 302 303] [--frames 900] [--world legacy] [--json PATH]
    .venv/bin/python tools/repro_probe.py --compare docs/bench/oneoff/repro_probe-amd-epyc.json
    .venv/bin/python tools/repro_probe.py --frontend --compare docs/bench/oneoff/repro_probe-frontend-amd-epyc.json

The same code and seeds gave the demo set's SVOE graph ECE 0.060 on an AMD EPYC and 0.109 on an Intel
Xeon (docs/experiments.md, stops 65-66), while each machine repeats its own figures to the byte. This
tool says at which stage two machines first differ. It generates the recordings afresh into a cache of
its own (``--cache``; the benchmark cache may hold recordings another machine made), and digests
(sha256, 16 hex digits), in pipeline order:

1. ``libraries``: fixed inputs through each library kernel that picks its code by the CPU: numpy's
   transcendental loops, OpenBLAS (numpy's and scipy's: matrix products, solve, SVD, eigh),
   Open3D's ray casting and closest points (Embree), OpenCV's resampling and blur, a GTSAM solve.
2. per recording, ``generate/<part>``: the generator's files (poses, AHAT depth, mesh, truth,
   detections, MVPE photos' list);
3. ``lift/<set>/<mode>``: the lifted observations (SVOE and MVPE; reference and robust lifting);
4. ``track/<set>/<tracker>``: every answer and interval of ``memory``, ``kf`` (both liftings),
   ``memory+graph``, ``graph`` and ``graph-causal`` (as ``tools/bench_confidence.py`` runs them);
5. ``eval/<set>/<tracker>``: the scored answers the curves and the ECE are made of.

With ``--frontend``, on the device world's RGB recordings instead (by default the proposal recall
benchmark's, seeds 21-26 at 300 frames, every 10th frame): the generator's files and PV frames, each
proposal source's boxes, the plausible ones, their rank and the boxes kept at the cap.

The record goes to ``docs/bench/oneoff/repro_probe[-TAG].json`` unless ``--json`` says otherwise
(a one-off record, not a section of docs/benchmarks.md). ``--compare RECORD`` reads another run's
record (this tool's JSON, e.g. the one kept from another machine in docs/bench/oneoff/) and prints,
per recording, the first stage that differs and how many differ, and which library probes differ;
each record's ``machine`` block names its CPU (vendor, family, model, instruction sets), the
variables that choose kernels (OPENBLAS_CORETYPE, ...) and the BLAS kernels chosen. Exit status 0
either way: a difference is a finding, not a failure.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import sys
import time
from pathlib import Path

import benchdoc
import numpy as np

from egograph.core.config import load_config
from egograph.steps.evaluate import evaluate
from egograph.steps.recording import open_recording
from egograph.steps.settings import EgographConfig
from egograph.steps.track import track as track_step
from egograph.synth.benchset import BENCH_WORLDS, benchmark_set, rgb_benchmark_set, source_detections, world_config
from egograph.core.resources import default_config
from egograph.track.registry import graph_with_scene
from egograph.track.smooth import smooth_predictions

REPO = Path(__file__).resolve().parents[1]
SETS = ("svoe", "mvpe")
BASELINES = ("memory", "kf")
GENERATOR_PARTS = {  # part -> path patterns under the recording's root (glob, sorted; SEQ: its sequence folder)
    "poses": ["SEQ/pv_pose.json", "SEQ/depth_ahat_pose.json"],
    "depth": ["SEQ/depth_ahat/*"],
    "mesh": ["SEQ/mesh/*"],
    "truth": ["synth_gt/**/*"],
    "detections": ["detections/**/*"],
    "annotations": ["annotations/**/*", "mvpe/**/*"],
    "calibrations": ["calibrations/**/*"],
}


# --------------------------------------------------------------------------- digests

def _feed(h, value) -> None:
    """Feed ``value`` into ``h`` by content: arrays by dtype, shape and bytes; floats by their exact
    hexadecimal; dataclasses, dicts (sorted keys), lists and tuples element by element."""
    if isinstance(value, np.ndarray):
        h.update(f"a{value.dtype.str}{value.shape}".encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, (bool, np.bool_)) or value is None:
        h.update(repr(value).encode())
    elif isinstance(value, (int, np.integer)):
        h.update(b"i" + str(int(value)).encode())
    elif isinstance(value, (float, np.floating)):
        h.update(b"f" + float(value).hex().encode())
    elif isinstance(value, str):
        h.update(b"s" + value.encode() + b"\0")
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        h.update(b"D" + type(value).__name__.encode())
        for f in dataclasses.fields(value):
            if f.compare:   # provenance and such: where the rows came from, not what they are
                h.update(f.name.encode())
                _feed(h, getattr(value, f.name))
    elif isinstance(value, dict):
        h.update(b"{")
        for k in sorted(value, key=str):
            _feed(h, str(k))
            _feed(h, value[k])
        h.update(b"}")
    elif isinstance(value, (list, tuple)):
        h.update(b"[")
        for v in value:
            _feed(h, v)
        h.update(b"]")
    else:
        raise TypeError(f"cannot digest a {type(value).__name__} by content")


def digest(value) -> str:
    """sha256 (16 hex digits) of ``value`` by content (:func:`_feed`)."""
    h = hashlib.sha256()
    _feed(h, value)
    return h.hexdigest()[:16]


def files_digest(root: Path, patterns: list[str]) -> tuple[str, int]:
    """sha256 of the files under ``root`` that match ``patterns`` (relative path and bytes, sorted)
    and their count."""
    files = sorted({p for pat in patterns for p in root.glob(pat) if p.is_file()})
    h = hashlib.sha256()
    for p in files:
        h.update(p.relative_to(root).as_posix().encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()[:16], len(files)


def generator_digests(root: Path, pv: bool = False) -> dict[str, str]:
    """``generate/<part>`` -> the digest and count of the generator's files of each part of
    :data:`GENERATOR_PARTS` (and with ``pv`` its PV frames) in the recording ``root``."""
    seq = next((p.parent.name for p in sorted(root.glob("*/pv_pose.json"))), "synth_seq")
    parts = {**GENERATOR_PARTS, **({"pv": ["SEQ/pv/*"]} if pv else {})}
    out = {}
    for part, patterns in parts.items():
        d, n = files_digest(root, [pat.replace("SEQ", seq) for pat in patterns])
        out[f"generate/{part}"] = f"{d} ({n} files)"
    return out


def result_digest(res) -> str:
    """A tracker's output by content: every answer (the per-frame predictions when it answers only
    those) and its intervals; not its metadata (timings)."""
    return digest({"answers": res.answers if res.answers is not None else res.per_frame,
                   "per_frame": res.per_frame, "intervals": res.intervals or []})


# --------------------------------------------------------------------------- stages

def library_probes() -> dict[str, str]:
    """Digests of fixed inputs through the library kernels that choose their code by the CPU."""
    import cv2
    import gtsam
    import open3d as o3d
    import scipy.linalg

    rng = np.random.default_rng(0)
    out = {}
    x = rng.uniform(-10, 10, 100_000)
    out["numpy sin cos exp log arctan2"] = digest([np.sin(x), np.cos(x), np.exp(x / 4), np.log(np.abs(x) + 1e-3),
                                                   np.arctan2(x, x[::-1])])
    a, b = rng.normal(size=(300, 300)), rng.normal(size=(300, 40))
    spd = a @ a.T + 300 * np.eye(300)
    out["numpy OpenBLAS matmul"] = digest([a @ b, a @ a, (a[:, :3] @ rng.normal(size=(3, 3)))])
    out["numpy OpenBLAS solve svd eigh"] = digest([np.linalg.solve(spd, b), np.linalg.svd(a[:60, :40])[1],
                                                  np.linalg.eigh(spd[:50, :50])[0]])
    out["scipy OpenBLAS cholesky lstsq"] = digest([scipy.linalg.cho_solve(scipy.linalg.cho_factor(spd), b),
                                                  scipy.linalg.lstsq(a[:, :20], b[:, 0])[0]])
    mesh = o3d.t.geometry.TriangleMesh.from_legacy(o3d.geometry.TriangleMesh.create_sphere(1.0, 60))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh)
    origin = rng.normal(size=(50_000, 3)) * 0.3 + np.array([0.0, 0.0, -3.0])
    target = rng.normal(size=(50_000, 3)) * 0.4
    direction = (target - origin) / np.linalg.norm(target - origin, axis=1, keepdims=True)
    rays = o3d.core.Tensor(np.hstack([origin, direction]).astype(np.float32))
    out["Open3D cast_rays (Embree)"] = digest(scene.cast_rays(rays)["t_hit"].numpy())
    pts = o3d.core.Tensor((rng.normal(size=(20_000, 3)) * 1.5).astype(np.float32))
    out["Open3D closest points, distance"] = digest([scene.compute_closest_points(pts)["points"].numpy(),
                                                    scene.compute_distance(pts).numpy()])
    img = rng.uniform(0, 1, (240, 320)).astype(np.float32)
    mx, my = np.meshgrid(np.linspace(0.3, 318.7, 320, dtype=np.float32), np.linspace(0.6, 238.4, 240, dtype=np.float32))
    out["OpenCV resize blur remap"] = digest([cv2.resize(img, (157, 113), interpolation=cv2.INTER_LINEAR),
                                             cv2.resize(img, (80, 60), interpolation=cv2.INTER_AREA),
                                             cv2.GaussianBlur(img, (7, 7), 1.3),
                                             cv2.remap(img, mx, my * 0.97, cv2.INTER_LINEAR)])
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.full(6, 0.1))
    graph.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), noise))
    for i in range(1, 60):
        step = gtsam.Pose3(gtsam.Rot3.Rodrigues(*(rng.normal(size=3) * 0.05)), rng.normal(size=3) * 0.2)
        graph.add(gtsam.BetweenFactorPose3(i - 1, i, step, noise))
        if i > 5:
            graph.add(gtsam.BetweenFactorPose3(i - 5, i, gtsam.Pose3(gtsam.Rot3(), rng.normal(size=3) * 0.5), noise))
        values.insert(i, gtsam.Pose3(gtsam.Rot3(), rng.normal(size=3)))
    values.insert(0, gtsam.Pose3())
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    out["GTSAM Levenberg-Marquardt"] = digest([result.atPose3(i).matrix() for i in range(60)])
    return out


def recording_digests(root: Path, lags: list[float]) -> dict[str, str]:
    """Every stage's digest of one recording, in pipeline order (generate, lift, track, eval)."""
    from egograph.geometry.lift import lift_recording

    out = generator_digests(root)
    cfg = load_config(EgographConfig, default_config(), [])
    rec = open_recording(root, cfg)
    results: dict = {}
    for det_set in SETS:
        for mode in ("reference", "robust"):
            cfg.lift.mode = mode
            dets, n_instances = source_detections(rec, det_set, cfg)
            obs, _ = lift_recording(rec, dets, cfg.lift, progress=False, n_instances=n_instances)
            out[f"lift/{det_set}/{mode}"] = digest(obs)
            for b in BASELINES:
                results[(det_set, f"{b} ({mode})")] = track_step(rec, b, obs, cfg)
                if mode == "robust" and b == "memory":
                    results[(det_set, "memory+graph")] = smooth_predictions(rec, results[(det_set, "memory (robust)")]
                                                                            .per_frame, cfg.graph)
        results[(det_set, "graph")] = graph_with_scene(rec, obs, cfg, causal=False)
        for lag in lags:
            cfg.graph.lag_s = lag
            results[(det_set, f"graph-causal lag {lag:g}")] = graph_with_scene(rec, obs, cfg, causal=True)
    for (det_set, name), res in results.items():
        out[f"track/{det_set}/{name}"] = result_digest(res)
    for (det_set, name), res in results.items():
        a = evaluate(rec, res).sequences[rec.name].answers
        out[f"eval/{det_set}/{name}"] = digest([a.score, a.tp, a.n_gt])
    return out


def frontend_digests(root: Path, step: int) -> dict[str, str]:
    """The front-end's stages on one device-world RGB recording, every ``step``-th PV frame: the
    generator's PV frames, each proposal source's boxes (``frontend.proposals`` of SVOE, as ``detect``
    makes them), those the plausibility test keeps, their rank (``frontend.proposal_order``) and the
    boxes kept at the cap (``frontend.max_proposals``): where the proposal recall of
    ``bench_detect-recall`` parted between machines (docs/frontend.md, stop 65)."""
    from egograph.frontend.proposals import frame_proposals, nms, proposal_sources, rank_scores
    from egograph.steps.detect import read_pv

    out = generator_digests(root, pv=True)
    cfg = load_config(EgographConfig, default_config(), [])
    rec = open_recording(root, cfg)
    fcfg = cfg.frontend
    sources = proposal_sources(rec, fcfg, fcfg.proposals_for("svoe"))
    raw: dict[str, list] = {}
    plausible, ranks, kept = [], [], []
    for i in range(0, len(rec), step):
        rgb = read_pv(rec, i)
        if rgb is None:
            continue
        each, props = frame_proposals(sources, i, rgb, fcfg)
        for q in (q for got in each for q in got):   # by the source each box names (geometry, mesh, image, ...)
            raw.setdefault(q.source, []).append((i, tuple(map(float, q.box)), float(q.conf)))
        rank = rank_scores(props, rgb, fcfg)
        plausible.append([(tuple(map(float, q.box)), q.source, float(q.conf)) for q in props])
        ranks.append(np.zeros(0) if rank is None else np.asarray(rank, float))
        kept.append([tuple(map(float, q.box)) for q in nms(props, fcfg.nms_iou, fcfg.max_proposals, rank)])
    for name in sorted(raw):
        out[f"proposals/{name}"] = f"{digest(raw[name])} ({len(raw[name])} boxes)"
    out["proposals/plausible"] = digest(plausible)
    out["proposals/rank"] = digest(ranks)
    out["proposals/kept at the cap"] = digest(kept)
    return out


# --------------------------------------------------------------------------- comparison

def compare(mine: dict, theirs: dict) -> list[str]:
    """Lines saying where two runs' digests (``data`` of two records) differ: the library probes that
    differ, then per recording both had, the first stage (pipeline order) that differs and how many
    stages differ in all."""
    lines = []
    lib_a, lib_b = mine.get("libraries", {}), theirs.get("libraries", {})
    differ = [k for k in lib_a if k in lib_b and lib_a[k] != lib_b[k]]
    same = [k for k in lib_a if k in lib_b and lib_a[k] == lib_b[k]]
    lines.append(f"library probes: {len(differ)} of {len(differ) + len(same)} differ"
                 + (": " + "; ".join(differ) if differ else ""))
    rec_a, rec_b = mine.get("recordings", {}), theirs.get("recordings", {})
    for name in rec_a:
        if name not in rec_b:
            lines.append(f"{name}: not in the other record")
            continue
        stages = [k for k in rec_a[name] if k in rec_b[name]]
        bad = [k for k in stages if rec_a[name][k] != rec_b[name][k]]
        if not bad:
            lines.append(f"{name}: all {len(stages)} stages the same")
        else:
            lines.append(f"{name}: first differs at {bad[0]}; {len(bad)} of {len(stages)} stages differ "
                         f"({', '.join(bad[:6])}{', ...' if len(bad) > 6 else ''})")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+",
                    help="recordings to probe (default: the demo's held-out set 1 2 3 301 302 303, where the "
                         "figures parted; with --frontend the recall benchmark's 21-26)")
    ap.add_argument("--frames", type=int, help="PV frames per recording (default 900; with --frontend 300)")
    ap.add_argument("--lags", type=float, nargs="+", default=[0.0])
    ap.add_argument("--cache", type=Path,
                    help="where the recordings are generated (default .cache/repro_probe, with --frontend "
                         ".cache/repro_probe_fe: a cache of the probe's own, never another machine's recordings)")
    ap.add_argument("--compare", type=Path, metavar="RECORD", help="another run's JSON record to compare with")
    ap.add_argument("--frontend", action="store_true",
                    help="probe the front-end's proposals instead of the tracking chain, on device-world RGB "
                         "recordings (default then: seeds 21-26 at 300 frames, the bench_detect-recall set)")
    ap.add_argument("--step", type=int, default=10, help="--frontend: every this many PV frames (as the recall "
                                                         "benchmark samples them)")
    ap.add_argument("--world", choices=BENCH_WORLDS,
                    help="generator world of the recordings (default legacy, the world of the records whose "
                         "figures parted between machines; with --frontend device: photographic surfaces, the PV "
                         "camera, hands)")
    benchdoc.add_arguments(ap, __file__)
    args = ap.parse_args(argv)
    # what is not given: the demo's held-out set, or with --frontend the recall benchmark's recordings
    fe = args.frontend
    args.seeds = args.seeds or ([21, 22, 23, 24, 25, 26] if fe else [1, 2, 3, 301, 302, 303])
    args.frames = args.frames or (300 if fe else 900)
    args.world = args.world or ("device" if fe else "legacy")
    args.cache = args.cache or REPO / ".cache" / ("repro_probe_fe" if fe else "repro_probe")
    if args.json is None:   # a one-off record, not a section of docs/benchmarks.md
        args.json = str(REPO / "docs" / "bench" / "oneoff" / f"repro_probe{'-' + args.json_tag if args.json_tag else ''}.json")
    theirs = None
    if args.compare is not None:
        try:
            theirs = json.loads(args.compare.read_text())
            if not isinstance(theirs, dict) or "data" not in theirs:
                raise ValueError("not a record of this tool (no 'data')")
        except (OSError, ValueError) as exc:
            print(f"repro_probe: cannot read the record to compare with, {args.compare}: {exc}", file=sys.stderr)
            return 2
    bench = benchdoc.start(__file__, args)
    t0 = time.perf_counter()
    libs = library_probes()
    if args.frontend:
        roots = rgb_benchmark_set(args.seeds, args.frames, config=world_config(args.world), cache=args.cache)
    else:
        roots = benchmark_set(args.seeds, args.frames, config=world_config(args.world), cache=args.cache,
                              progress=False)
    recs = {}
    for root in roots:
        recs[root.name] = frontend_digests(root, args.step) if args.frontend else recording_digests(root, args.lags)
        print(f"{root.name}: {len(recs[root.name])} stages digested ({time.perf_counter() - t0:.0f} s)", flush=True)
    bench.data = {"libraries": libs, "recordings": recs}
    benchdoc.table("Library kernels that choose their code by the CPU: digests of fixed inputs",
                   ["probe", "digest"], sorted(libs.items()))
    for name, stages in recs.items():
        benchdoc.table(f"{name}: each stage's digest, in pipeline order", ["stage", "digest"], list(stages.items()))
    here = benchdoc.machine()
    ident = here.get("cpu_id", {})
    benchdoc.text(f"CPU: {here.get('cpu')}, {ident.get('vendor')} family {ident.get('family')} "
                  f"model {ident.get('model')}; BLAS kernels: "
                  + ", ".join(f"{m.get('filepath')}: {m.get('architecture')}" for m in benchdoc.math_libraries()
                              if m.get("internal_api") == "openblas")
                  + "; kernel environment: "
                  + (", ".join(f"{k}={v}" for k, v in here.get("kernel_environment", {}).items()) or "none"))
    if theirs is not None:
        m = theirs.get("machine", {})
        benchdoc.text(f"Compared with {args.compare} (CPU: {m.get('cpu')}, {m.get('cpu_id', {}).get('vendor')} "
                      f"family {m.get('cpu_id', {}).get('family')} model {m.get('cpu_id', {}).get('model')}):\n"
                      + "\n".join("- " + line for line in compare(bench.data, theirs["data"])))
    benchdoc.finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
