#!/usr/bin/env python
"""Benchmark ``egograph detect``: PV frames/s end to end and ms per stage, and the cost per crop of
a ViT-S/14-sized ONNX encoder.

    .venv/bin/python tools/bench_detect.py                         # 60-frame synth/tiny recording, seed 11
    .venv/bin/python tools/bench_detect.py --frames 120 --runs mvpe:mean,mvpe:max,svoe --proposals geometry+image
    .venv/bin/python tools/bench_detect.py --rec REC               # an existing recording (with pv/)
    .venv/bin/python tools/bench_detect.py --rec REC --skip-vit --variant old:frontend.input_size=224 --variant new:

Part 1 generates a synthetic recording with PV RGB (``synth/tiny``, kept in ``--workdir``), runs
``detect`` with the embedded EfficientNet-lite0 (converted into ``--cache``, by default a fresh
folder, the conversion timed apart) and prints frames/s and ms/frame per stage (read = PNG decode,
proposals, crops = cut + resize + normalise, encoder = onnxruntime, matching, write), proposals per
frame, and -- on a synthetic recording -- the share of visible instance-frames (visible share >=
0.5) with a true detection (IoU >= 0.3 with the true box), the share of detections that are true,
and the false ones split into "other instance" (the box is another visible instance's) and
"clutter". ``--variant NAME:KEY=VALUE,...`` (repeatable) runs the same recording again with
configuration overrides, back to back, e.g. ``--variant base:frontend.input_size=224,frontend.threads=2``.

Part 2 builds a ViT-S/14-sized encoder with onnx.helper and random weights (patch 14, 224 px ->
256 patches + a class token, 12 blocks, width 384, 6 heads, MLP 1536; ~22 M parameters, DINOv2
ViT-S/14's shape; nothing is downloaded) and times it per crop at batch 1 and 8 on onnxruntime.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
import time
from pathlib import Path

import benchdoc
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def vit_s14(path: Path, seed: int = 0, depth: int = 12, width: int = 384, heads: int = 6, size: int = 224) -> Path:
    """A random-weight ViT-S/14-shaped ONNX encoder: input ``image`` (N, 3, size, size), output
    ``embedding`` (N, width), the class token after the last block's layer norm."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(seed)
    inits, nodes = [], []
    n_tok = (size // 14) ** 2 + 1

    def const(name, arr):
        inits.append(numpy_helper.from_array(np.asarray(arr, np.float32 if np.asarray(arr).dtype.kind == "f"
                                                        else np.int64), name))
        return name

    def rand(name, *shape):
        return const(name, rng.normal(0, 0.02, shape).astype(np.float32))

    def node(op, ins, **kw):
        out = f"t{len(nodes)}"
        nodes.append(helper.make_node(op, ins, [out], **kw))
        return out

    def ln(x, p):
        return node("LayerNormalization", [x, const(p + "g", np.ones(width)), const(p + "b", np.zeros(width))],
                    axis=-1, epsilon=1e-6)

    x = node("Conv", ["image", rand("patch_w", width, 3, 14, 14), rand("patch_b", width)],
             kernel_shape=[14, 14], strides=[14, 14])
    x = node("Reshape", [x, const("s1", [0, width, -1])])
    x = node("Transpose", [x], perm=[0, 2, 1])                               # (N, 256, D)
    shape = node("Shape", ["image"], start=0, end=1)
    cls = node("Expand", [rand("cls", 1, 1, width), node("Concat", [shape, const("one_d", [1, width])], axis=0)])
    x = node("Add", [node("Concat", [cls, x], axis=1), rand("pos", 1, n_tok, width)])
    hd = width // heads
    for b in range(depth):
        p = f"b{b}_"
        h = ln(x, p + "ln1")
        qkv = node("Add", [node("MatMul", [h, rand(p + "qkv", width, 3 * width)]), rand(p + "qkvb", 3 * width)])
        qkv = node("Reshape", [qkv, const(p + "s", [0, 0, 3, heads, hd])])
        qkv = node("Transpose", [qkv], perm=[2, 0, 3, 1, 4])                 # (3, N, H, T, hd)
        q, k, v = (node("Gather", [qkv, const(f"{p}i{j}", j)], axis=0) for j in range(3))
        att = node("Softmax", [node("Mul", [node("MatMul", [q, node("Transpose", [k], perm=[0, 1, 3, 2])]),
                                            const(p + "sc", hd ** -0.5)])], axis=-1)
        o = node("Reshape", [node("Transpose", [node("MatMul", [att, v])], perm=[0, 2, 1, 3]),
                             const(p + "s2", [0, 0, width])])
        x = node("Add", [x, node("Add", [node("MatMul", [o, rand(p + "proj", width, width)]), rand(p + "pb", width)])])
        h = ln(x, p + "ln2")
        h = node("Add", [node("MatMul", [h, rand(p + "fc1", width, 4 * width)]), rand(p + "f1b", 4 * width)])
        h = node("Mul", [h, node("Sigmoid", [node("Mul", [h, const(p + "g", 1.702)])])])   # GELU (sigmoid form)
        x = node("Add", [x, node("Add", [node("MatMul", [h, rand(p + "fc2", 4 * width, width)]), rand(p + "f2b", width)])])
    x = ln(x, "final")
    cls_out = node("Gather", [x, const("zero", 0)], axis=1)
    nodes.append(helper.make_node("Identity", [cls_out], ["embedding"]))
    graph = helper.make_graph(nodes, "vit_s14_random",
                              [helper.make_tensor_value_info("image", TensorProto.FLOAT, ["N", 3, size, size])],
                              [helper.make_tensor_value_info("embedding", TensorProto.FLOAT, ["N", width])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, path)
    return path


def truth_score(rec, det_dir) -> str:
    """Detections against the generator's true boxes (synthetic recordings only)."""
    t = truth_counts(rec, det_dir)
    if t is None:
        return "no synth_gt: no truth"
    n_vis, true, n, other, clutter = t
    return (f"visible instance-frames {n_vis}, true detections {true} ({true / max(n_vis, 1):.2f} of visible; "
            f"{true / max(n, 1):.2f} of {n} detections), false {other + clutter} (other instance {other}, "
            f"clutter {clutter})")


def truth_counts(rec, det_dir) -> tuple[int, int, int, int, int] | None:
    """(visible instance-frames, true detections, detections, false on another instance, false on
    clutter) against the generator's true boxes; None without synth_gt."""
    from egograph.synth.truth import detections_against_truth, own_column

    if rec.synth_gt_dir is None:
        return None
    with np.load(rec.synth_gt_dir / "instances.npz") as gt:
        n_vis = int((gt["visible"] >= 0.5).sum())
    m = detections_against_truth(rec, det_dir)
    on_own = (own_column(m, "visible") >= 0.5) & (own_column(m, "iou") >= 0.3)
    on_any = ((m["visible"] >= 0.5) & (m["iou"] >= 0.3)).any(axis=1)
    true, other = int(on_own.sum()), int((on_any & ~on_own).sum())
    n = len(on_own)
    return n_vis, true, n, other, n - true - other


SIDE_BANDS = ((24, 40), (40, 80), (80, 10_000))   # true box short side, PV pixels
TURN_BANDS = ((0, 30), (30, 100), (100, np.inf))   # the head's turn over the PV exposure, deg/s (motion blur)
MISS_CAUSES = ("covered", "lost to the cap or NMS", "too large", "too small", "displaced", "nothing near")


def miss_cause(truth: np.ndarray, plausible: np.ndarray, kept: np.ndarray) -> tuple[int, int]:
    """Why one visible instance (true box ``truth`` (4,), PV pixels) is or is not covered at IoU >=
    0.5: an index into :data:`MISS_CAUSES` and the row of ``plausible`` (N, 4: every plausible
    proposal of the frame, before NMS and the cap) that says so (-1 for "nothing near").
    ``kept``: the proposals left after NMS and the cap. Not covered by any plausible proposal, the
    one overlapping it most (largest IoU, if >= 0.1) says why: "too large" when it holds >= 80 % of
    the true box (merged with its surround, its support or the hand), "too small" when >= 80 % of it
    lies inside the true box (a fragment), "displaced" otherwise. Below IoU 0.1 a segment can still
    swallow the instance whole (the smallest such: "too large") or be a sliver of it (the largest
    such: "too small"); else "nothing near"."""
    from egograph.frontend.proposals import iou_matrix

    t = np.asarray(truth, np.float64).reshape(4)
    plausible = plausible.reshape(-1, 4)
    iou_all = iou_matrix(t[None], plausible)[0]
    if len(kept) and iou_matrix(t[None], kept.reshape(-1, 4))[0].max() >= 0.5:
        return 0, int(np.argmax(iou_all)) if len(plausible) else -1
    if not len(plausible):
        return 5, -1
    inter = (np.clip(np.minimum(t[2], plausible[:, 2]) - np.maximum(t[0], plausible[:, 0]), 0, None)
             * np.clip(np.minimum(t[3], plausible[:, 3]) - np.maximum(t[1], plausible[:, 1]), 0, None))
    area_p = (plausible[:, 2] - plausible[:, 0]) * (plausible[:, 3] - plausible[:, 1])
    holds = inter >= 0.8 * (t[2] - t[0]) * (t[3] - t[1])    # the proposal holds the true box
    inside = inter >= 0.8 * np.maximum(area_p, 1e-9)        # the proposal lies inside it
    best = int(np.argmax(iou_all))
    if iou_all[best] >= 0.5:
        return 1, best
    if iou_all[best] >= 0.1:
        return (2 if holds[best] else 3 if inside[best] else 4), best
    if holds.any():
        return 2, int(np.flatnonzero(holds)[np.argmin(area_p[holds])])
    if inside.any():
        return 3, int(np.flatnonzero(inside)[np.argmax(area_p[inside])])
    return 5, -1


def cause_row(name: str, source: str, causes: list, reach_m: float) -> list:
    """One row of the miss table: the share of instances per cause, and of those not covered the
    shares farther than ``reach_m`` and carried (``causes`` as :func:`proposal_recall` gives them)."""
    kind = np.array([c[0] for c in causes], int)
    rng = np.array([c[2] for c in causes], float)
    carried = np.array([c[3] for c in causes], bool)
    n, miss = len(kind), kind > 0
    share = [100 * float(np.mean(kind == j)) if n else float("nan") for j in range(len(MISS_CAUSES))]
    far = 100 * float(np.mean(rng[miss] > reach_m)) if miss.any() else float("nan")
    held = 100 * float(np.mean(carried[miss])) if miss.any() else float("nan")
    return [name, source, n, *share, far, held]


def cause_detail(causes: list) -> list:
    """Rows (cause, source of the best proposal, count, share of all %, median range, carried) of the
    instances not covered, the largest groups first."""
    groups: dict = {}
    for kind, src, rng, carried in causes:
        if kind > 0:
            groups.setdefault((MISS_CAUSES[kind], src or "-"), []).append((rng, carried))
    rows = [[cause, src, len(v), 100 * len(v) / max(len(causes), 1), float(np.median([r for r, _ in v])),
             int(sum(c for _, c in v))] for (cause, src), v in groups.items()]
    return sorted(rows, key=lambda r: (-r[2], r[0], r[1]))


def proposal_recall(rec, cfg, source_name: str, caps: list[int], step: int) -> dict:
    """Per per-frame cap, counts over every ``step``-th PV frame (they add over recordings):
    ``[covered, proposals, frames, instances, covered per short-side band of SIDE_BANDS...,
    instances per band..., covered per band of TURN_BANDS..., instances per band...]`` (the turn
    bands read ``synth_gt``'s ``device.npz``: none without it), and under ``"setup"`` the CPU
    seconds making the sources (the mesh segmentation). Instances: at least half visible, true box short side >= 24 px;
    covered: some proposal (as ``detect`` makes them: plausible boxes, NMS, the cap) at IoU >= 0.5.
    Under ``"causes"``, at the first cap, one row per instance: (index into :data:`MISS_CAUSES`, source
    of the best plausible proposal or "", true range from the PV camera in metres, carried)."""
    from egograph.frontend.proposals import frame_proposals, iou, nms, proposal_sources, rank_scores
    from egograph.io.poses import read_pose_json
    from egograph.steps.detect import read_pv

    with np.load(rec.synth_gt_dir / "instances.npz") as gt:
        boxes, visible, positions, moving = gt["boxes"], gt["visible"], gt["positions"], gt["moving"]
    eye = read_pose_json(rec.synth_gt_dir / "pv_pose.json")[1][:, 3, :3]   # true PV camera centres, world
    device = rec.synth_gt_dir / "device.npz"
    turn = np.full(len(rec), np.nan)
    if device.is_file():
        with np.load(device) as dev:
            if "pv_exposure_turn_dps" in dev.files:
                turn = dev["pv_exposure_turn_dps"]
    turn_hit = {c: np.zeros(len(TURN_BANDS), int) for c in caps}
    turn_n = np.zeros(len(TURN_BANDS), int)
    causes = []
    t0 = time.process_time()
    sources = proposal_sources(rec, cfg.frontend, source_name)
    setup = time.process_time() - t0
    hit = {c: 0 for c in caps}
    count = {c: 0 for c in caps}
    band_hit = {c: np.zeros(len(SIDE_BANDS), int) for c in caps}
    band_n = np.zeros(len(SIDE_BANDS), int)
    n_inst = 0
    for i in range(0, len(rec), step):
        rgb = read_pv(rec, i)
        if rgb is None:
            continue
        _, props = frame_proposals(sources, i, rgb, cfg.frontend)
        ks = [k for k, (b, v) in enumerate(zip(boxes[i], visible[i])) if v >= 0.5 and np.isfinite(b[0])
              and min(b[2] - b[0], b[3] - b[1]) >= 24]
        want = [boxes[i][k] for k in ks]
        n_inst += len(want)
        band = [next(j for j, (lo, hi) in enumerate(SIDE_BANDS) if lo <= min(b[2] - b[0], b[3] - b[1]) < hi)
                for b in want]
        np.add.at(band_n, band, 1)
        tb = [j for j, (lo, hi) in enumerate(TURN_BANDS) if lo <= turn[i] < hi]   # none when NaN
        turn_n[tb] += len(want)
        rank = rank_scores(props, rgb, cfg.frontend)
        for c in caps:
            kept = nms(props, cfg.frontend.nms_iou, c, rank)
            count[c] += len(kept)
            if c == caps[0]:
                plausible = np.array([p.box for p in props], np.float64).reshape(-1, 4)
                kept_boxes = np.array([p.box for p in kept], np.float64).reshape(-1, 4)
                for k, b in zip(ks, want):
                    cause, best = miss_cause(b, plausible, kept_boxes)
                    causes.append((cause, props[best].source if best >= 0 else "",
                                   float(np.linalg.norm(positions[i, k] - eye[i])), bool(moving[i, k])))
            covered = [any(iou(b, p.box) >= 0.5 for p in kept) for b in want]
            hit[c] += sum(covered)
            np.add.at(band_hit[c], band, np.asarray(covered, int))
            turn_hit[c][tb] += sum(covered)
    frames = len(range(0, len(rec), step))
    return {c: np.array([hit[c], count[c], frames, n_inst, *band_hit[c], *band_n, *turn_hit[c], *turn_n], float)
            for c in caps} | \
        {"setup": setup, "causes": causes}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rec", type=Path, nargs="+", help="an existing recording with pv/ (default: generate one); "
                                                         "--recall pools several")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--runs", default="mvpe:mean", help="comma-separated enrollment[:mvpe pooling] runs, e.g. "
                                                        "mvpe:mean,mvpe:max,svoe")
    ap.add_argument("--proposals", default=None, help="default frontend.proposals (MVPE: frontend.mvpe_proposals)")
    ap.add_argument("--workdir", type=Path, default=Path(tempfile.gettempdir()) / "egograph_bench_detect")
    ap.add_argument("--skip-vit", action="store_true")
    ap.add_argument("--cache", type=Path, help="EGOGRAPH_CACHE for the converted encoder (default: a fresh folder)")
    ap.add_argument("--variant", action="append", default=[],
                    help="NAME:KEY=VALUE,... configuration overrides run after each other (repeatable; "
                         "default one run at the defaults)")
    ap.add_argument("--recall", action="store_true",
                    help="only proposal recall against proposals per frame, per variant (synthetic recordings)")
    ap.add_argument("--recall-caps", type=int, nargs="+", default=[12, 24, 48])
    ap.add_argument("--recall-step", type=int, default=10, help="every this many PV frames")
    benchdoc.add_arguments(ap, __file__)
    args = ap.parse_args(argv)
    benchdoc.start(__file__, args, argv)

    from egograph.core.config import load_config
    from egograph.core.resources import default_config
    from egograph.steps.detect import detect
    from egograph.steps.recording import open_recording
    from egograph.steps.settings import EgographConfig

    args.workdir.mkdir(parents=True, exist_ok=True)
    rec_roots = args.rec or []
    rec_root = rec_roots[0] if rec_roots else None
    if rec_root is None:
        rec_root = args.workdir / f"tiny_{args.frames}_{args.seed}"
        if not (rec_root / "recording.json").is_file():
            from egograph.core.resources import synth_config
            from egograph.synth.config import SynthConfig
            from egograph.synth.generate import generate

            generate(rec_root, load_config(SynthConfig, synth_config("tiny"), [f"frames={args.frames}"]),
                     seed=args.seed, progress=False)
    cfg = load_config(EgographConfig, default_config())
    rec = open_recording(rec_root, cfg)
    cache = args.cache or Path(tempfile.mkdtemp(prefix="cache", dir=args.workdir))
    os.environ["EGOGRAPH_CACHE"] = str(cache)
    from egograph.frontend import effnet

    t = time.perf_counter()
    effnet.embedded_model_path()
    print(f"EfficientNet-lite0 conversion (first use): {time.perf_counter() - t:.2f} s")
    variants = [v.partition(":") for v in args.variant] or [("defaults", ":", "")]
    if args.recall:
        from egograph.frontend.proposals import _MESH_OBJECTS

        rows, cause_rows, detail = [], [], {}
        for name, _, sets in variants:
            overrides = [kv for kv in re.split(r",(?![^\[]*\])", sets) if kv]
            vcfg = load_config(EgographConfig, default_config(), overrides)
            for run in args.runs.split(","):
                enroll = run.partition(":")[0]
                source = args.proposals or vcfg.frontend.proposals_for(enroll)
                total = {c: 0.0 for c in args.recall_caps}
                per_rec = {c: [] for c in args.recall_caps}
                cpu, setup, causes = 0.0, [], []
                for root in rec_roots or [rec_root]:
                    r = rec if root == rec_root else open_recording(root, cfg)
                    _MESH_OBJECTS.clear()     # each recording pays its mesh segmentation
                    t = time.process_time()
                    res = proposal_recall(r, vcfg, source, args.recall_caps, args.recall_step)
                    setup.append(res.pop("setup"))
                    causes += res.pop("causes")
                    cpu += time.process_time() - t - setup[-1]
                    for c, counts in res.items():
                        total[c] = total[c] + counts
                        per_rec[c].append(100 * counts[0] / max(counts[3], 1))
                nb, nt = len(SIDE_BANDS), len(TURN_BANDS)
                for c, k in total.items():
                    bands = [h / n if n else float("nan") for h, n in zip(k[4:4 + nb], k[4 + nb:4 + 2 * nb])]
                    turns = [h / n if n else float("nan")
                             for h, n in zip(k[4 + 2 * nb:4 + 2 * nb + nt], k[4 + 2 * nb + nt:])]
                    spread = f"{min(per_rec[c]):.0f}-{max(per_rec[c]):.0f}"
                    rows.append([name, source, c, k[1] / max(k[2], 1), 100 * k[0] / max(k[3], 1), spread,
                                 *(100 * b for b in bands), *(100 * b for b in turns), int(k[3]),
                                 1000 * cpu / max(k[2], 1),
                                 float(np.mean(setup))])
                    print(f"[{name}] {source} cap {c}: {k[1] / max(k[2], 1):.1f} proposals/frame, recall "
                          f"{100 * k[0] / max(k[3], 1):.1f} % (per recording {spread}) of {int(k[3])} instances",
                          flush=True)
                cause_rows.append(cause_row(name, source, causes, vcfg.frontend.max_range_m))
                if "rows" not in detail:   # the first variant's (and run's) instances only
                    detail["rows"] = cause_detail(causes)
        benchdoc.table("Proposal recall against proposals per frame",
                       ["variant", "proposals", "cap", "proposals/frame", "recall %", "per recording %",
                        *(f"short side {lo}-{hi} px %" if hi < 10_000 else f"short side >= {lo} px %"
                          for lo, hi in SIDE_BANDS),
                        *(f"head turn {lo}-{hi} deg/s %" if np.isfinite(hi) else f"head turn >= {lo} deg/s %"
                          for lo, hi in TURN_BANDS), "instances", "proposal CPU ms/frame", "set-up CPU s/recording"],
                       rows, ["", "", "d", ".1f", ".1f", "", ".1f", ".1f", ".1f", ".1f", ".1f", ".1f", "d", ".0f",
                              ".1f"],
                       note=f"Recordings {', '.join(r.name for r in rec_roots or [rec_root])}, every "
                            f"{args.recall_step}th PV frame, pooled; recall: instances at least half visible with a "
                            "true box short side >= 24 px covered by a proposal at IoU >= 0.5, also by the true box's "
                            "short side and by the head's turn over the PV exposure (`synth_gt`'s "
                            "`pv_exposure_turn_dps`: at 100 deg/s and more a 33 ms exposure smears the frame by "
                            "tens of pixels, and a small object can vanish into its surround); CPU (every thread): "
                            "the "
                            "proposal sources per frame counted (NMS at each cap included, shared by the caps), and "
                            "once per recording making them (the mesh segmentation).")
        cap0 = args.recall_caps[0]
        benchdoc.table(f"Why visible instances are not covered, at a cap of {cap0}",
                       ["variant", "proposals", "instances", *(f"{c} %" for c in MISS_CAUSES),
                        "not covered: farther than max_range_m %", "not covered: carried %"],
                       cause_rows, ["", "", "d", *[".1f"] * len(MISS_CAUSES), ".1f", ".1f"],
                       note="The instances of the recall table, each by the plausible proposal (before NMS and the "
                            "cap) overlapping it most: covered at the cap; lost to the cap or NMS (a plausible "
                            "proposal reaches IoU 0.5); too large (the best holds >= 80 % of the true box: merged "
                            "with its surround, its support or the hand); too small (>= 80 % of the best lies "
                            "inside the true box: a fragment); displaced (neither); nothing near (no proposal "
                            "reaches IoU 0.1). The last two columns: of the instances not covered, the share "
                            "farther from the PV camera than frontend.max_range_m (the geometry source's reach), "
                            "and the share being carried.")
        benchdoc.table(f"Not covered at a cap of {cap0}, by the source of the best proposal ({variants[0][0]})",
                       ["cause", "best proposal from", "instances", "share of all %", "median range (m)",
                        "carried"], detail.get("rows", []), ["", "", "d", ".1f", ".2f", "d"],
                       note="The first variant's instances not covered, by cause and by the source of the "
                            "plausible proposal that overlaps them most; range: true distance from the PV camera.")
        benchdoc.finish()
        return 0
    speed_rows, truth_rows, stages = [], [], []
    for name, _, sets in variants:
        overrides = [kv for kv in re.split(r",(?![^\[]*\])", sets) if kv]
        for run in args.runs.split(","):
            enroll, _, pooling = run.partition(":")
            cfg = load_config(EgographConfig, default_config(), overrides)
            cfg.frontend.mvpe_pooling = pooling or cfg.frontend.mvpe_pooling
            out = Path(tempfile.mkdtemp(prefix="det", dir=args.workdir)) / "out"
            t, cpu = time.perf_counter(), time.process_time()
            report = detect(rec, enroll, cfg, out, proposals=args.proposals, overwrite=True, progress=False)
            wall, cpu = time.perf_counter() - t, time.process_time() - cpu
            source = args.proposals or cfg.frontend.proposals_for(enroll)
            print(f"\n[{name}] {' '.join(overrides) or '(defaults)'}\ndetect --enroll {run} --proposals "
                  f"{source}: {len(rec)} frames in {wall:.1f} s = "
                  f"{len(rec) / wall:.2f} frames/s end to end (enrollment and model loading included); CPU "
                  f"{1000 * cpu / len(rec):.0f} ms/frame (all threads; load average {os.getloadavg()[0]:.1f}: "
                  "other processes slow the wall clock, not this)")
            print(report.summary())
            print(truth_score(rec, out), flush=True)
            stages += [k for k in report.seconds if k not in stages]
            per_stage = {k: 1000 * v / max(report.frames, 1) for k, v in report.seconds.items()}
            speed_rows.append(([name, run, source, len(rec), len(rec) / wall, 1000 * cpu / len(rec),
                                os.getloadavg()[0], report.proposals / max(report.frames, 1)], per_stage))
            t = truth_counts(rec, out)
            if t is not None:
                n_vis, true, n, other, clutter = t
                truth_rows.append([name, run, source, n_vis, [true, true / max(n_vis, 1)], [true, n, true / max(n, 1)],
                                   other, clutter])
    print()
    benchdoc.table("egograph detect: speed per run",
                   ["variant", "enroll", "proposals", "frames", "frames/s", "CPU ms/frame", "load",
                    "proposals/frame", *(f"{k} ms/frame" for k in stages)],
                   [[*row, *(per_stage.get(k) for k in stages)] for row, per_stage in speed_rows],
                   ["", "", "", "d", ".2f", ".0f", ".1f", ".1f", *[".0f"] * len(stages)],
                   note=f"Recording {rec_root.name} ({len(rec)} PV frames); frames/s end to end (enrollment and "
                        "model loading included); CPU ms/frame over all threads; load = load average after the run "
                        "(other processes slow the wall clock, not the CPU figure); read = waiting for the PNG decode.")
    if truth_rows:
        benchdoc.table("egograph detect: detections against the generator's true boxes",
                       ["variant", "enroll", "proposals", "visible instance-frames", "true (of visible)",
                        "true / all detections", "false: other instance", "false: clutter"], truth_rows,
                       ["", "", "", "d", "{0} ({1:.2f})", "{0}/{1} ({2:.2f})", "d", "d"],
                       note="true: IoU >= 0.3 with the instance's own true box where at least half visible.")

    if not args.skip_vit:
        from egograph.frontend.config import FrontendConfig
        from egograph.frontend.encoder import OnnxEncoder

        path = vit_s14(args.workdir / "vit_s14_random.onnx")
        enc = OnnxEncoder(path, FrontendConfig(batch=8))
        rng = np.random.default_rng(0)
        crops = [rng.integers(0, 255, (120, 90, 3), dtype=np.uint8) for _ in range(16)]
        enc.embed(crops[:8])
        vit_rows = []
        for b in (1, 8):
            enc.batch = b
            t = time.perf_counter()
            enc.embed(crops)
            dt = time.perf_counter() - t
            vit_rows.append([b, 1000 * dt / len(crops), os.getloadavg()[0]])
        benchdoc.table(f"ViT-S/14-sized random ONNX encoder ({path.stat().st_size / 1e6:.0f} MB): cost per crop",
                       ["batch", "ms per crop", "load"], vit_rows, ["d", ".0f", ".1f"])
    benchdoc.finish()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
