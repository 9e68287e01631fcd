"""Calibrating a simulated front-end against the paper's rows in seconds per setting, not minutes.

The synthetic front-ends are calibrated so that the paper's pipeline on them (the ``memory``
tracker on ``reference`` lifting) lands in bands around the published SAM + DINOv2 rows (design
§6). Checking one setting the direct way re-simulates the detections and re-lifts every box with
the reference rule: about 50 CPU-s per 3000-frame recording and set, so a search over
settings on a benchmark set of a dozen recordings would take days. Two facts make it a table
look-up instead (about 0.2 s per recording and setting):

* the front-end draws common random numbers (:class:`~egograph.synth.frontend.Draws`): the draws
  of a frame do not depend on the knobs, which only threshold or scale them;
* the box an instance's detection is written with depends on the knobs only through which
  candidate wins (its own box, another instance's, one of its clutter spots) and ``box_jitter``.

So :func:`candidate_tables` lifts, once per recording, every box each instance could be written
with at one ``box_jitter`` per set (the real reference rule, :func:`~egograph.geometry.lift.lift_recording`;
both sets in one pass over the depth frames, about 70 CPU-s per 3000 frames),
and :func:`simulate_observations` turns any other setting of the knobs into the observations the
generator + lift would give, by the generator's own top-1 rule (:meth:`FrontEnd.top1`). Then
:func:`memory_counts` runs the real ``memory`` baseline and scores it under the IT3DEgo protocol.
``tests/test_synth_calibrate.py`` pins that this equals generating the detections and lifting them.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from egograph.core.types import Box, Detection
from egograph.eval.loader import LoadedSequence, load_sequence
from egograph.eval.protocol import Counts, evaluate_sequence
from egograph.geometry.config import LiftConfig
from egograph.geometry.lift import lift_recording
from egograph.geometry.observations import Observations
from egograph.io.annotations import find_labels_file
from egograph.io.atomic import atomic_path
from egograph.synth.config import FrontEndConfig
from egograph.synth.frontend import (
    SOURCE_CLUTTER,
    SOURCE_OTHER,
    SOURCE_TRUE,
    SOURCE_TWIN,
    Draws,
    FrontEnd,
    jitter_boxes,
    written_score,
)
from egograph.synth.generate import PV_SHAPE, front_end
from egograph.track.baselines import memory_tracker
from egograph.track.config import BaselineConfig

SOURCES = (SOURCE_TRUE, SOURCE_TWIN, SOURCE_OTHER, SOURCE_CLUTTER)

PAPER = {
    "svoe": {"P@0.25": 23.3, "P@1.5": 59.4, "L2 (m)": 1.35},
    "mvpe": {"P@0.25": 56.0, "P@1.5": 74.3, "L2 (m)": 0.67},
}
"""The paper's memory rows with SAM + DINOv2 (design §6): P@0.25 and P@1.5 in %, L2 in metres."""

BANDS = {
    "svoe": {"P@0.25": (15, 32), "P@1.5": (48, 70), "L2 (m)": (0.9, 1.8)},
    "mvpe": {"P@0.25": (45, 66), "P@1.5": (65, 84), "L2 (m)": (0.45, 0.9)},
}
"""Where memory + reference lifting on a simulated front-end must land, pooled over the benchmark set."""


TABLE_KNOBS = ("box_jitter", "clutter_per_instance", "other_score", "min_written_score")
"""The front-end knobs a :class:`CandidateTable` is made for; every other knob is free."""


@dataclass
class CandidateTable:
    """Every box one instance could be written with in one detection set of one recording, lifted.

    ``index[f, i, j]`` is the row of ``obs`` holding candidate ``j`` of instance ``i`` at frame
    ``f`` (``j < K``: instance ``j``'s box; ``j >= K``: instance ``i``'s clutter spot ``j - K``),
    -1 where that candidate is not in view, or is another (not look-alike) instance whose score
    cannot reach ``min_written_score`` at the table's ``other_score`` whatever the other knobs.
    ``obs`` holds them lifted by the reference rule, boxes jittered with the instance's own draws.
    """

    seed: int
    det_set: str
    knobs: dict                # TABLE_KNOBS -> value the table was made with
    twins: np.ndarray          # (K,) look-alike twin of each instance, -1 none
    visible: np.ndarray        # (N, K) visible share 0-1
    boxes: np.ndarray          # (N, K, 4) amodal PV boxes, pixels, NaN out of view
    clutter: np.ndarray        # (N, K, C, 4) clutter spot boxes, pixels, NaN not in view
    motion: np.ndarray         # (N, K) image motion, deg/s
    draws: Draws               # stacked on the frame axis
    index: np.ndarray | None   # (N, K, K + C) int32 rows of obs, -1 none
    obs: Observations | None   # the lifted candidates (instance = the instance they are written for)


def table_knobs(cfg: FrontEndConfig) -> dict:
    return {name: getattr(cfg, name) for name in TABLE_KNOBS}


def _views(root: Path) -> tuple[dict, dict]:
    meta = json.loads((root / "recording.json").read_text())
    with np.load(root / "synth_gt" / meta["sequence"] / "instances.npz") as data:
        views = {k: data[k] for k in ("visible", "boxes", "clutter_boxes", "motion_dps", "twins", "timestamps")}
    return meta, views


def _stacked_draws(fe: FrontEnd, n: int, c: int) -> Draws:
    per = [fe.draws(f, c) for f in range(n)]
    return Draws(*(np.stack([getattr(d, name) for d in per]) for name in Draws.__dataclass_fields__))


def _table(seed: int, det_set: str, cfg: FrontEndConfig, v: dict, index: np.ndarray | None = None,
           obs: Observations | None = None) -> CandidateTable:
    """A table of ``det_set`` from a recording's views ``v`` (``instances.npz``), with the draws of
    its stream; ``index`` and ``obs`` filled in later when not given."""
    c = cfg.clutter_per_instance
    draws = _stacked_draws(front_end(seed, det_set, cfg, v["twins"]), len(v["timestamps"]), c)
    return CandidateTable(seed, det_set, table_knobs(cfg), v["twins"], v["visible"], v["boxes"],
                          v["clutter_boxes"][:, :, :c], v["motion_dps"], draws, index, obs)


def candidates(boxes: np.ndarray, clutter: np.ndarray) -> np.ndarray:
    """(N, K, K + C, 4) the candidate boxes of each instance: every instance's box, then its own
    clutter spots' (PV pixels, NaN not in view)."""
    n, k = boxes.shape[:2]
    return np.concatenate([np.broadcast_to(boxes[:, None], (n, k, k, 4)), clutter], axis=2)


def candidate_mask(draws: Draws, cand: np.ndarray, twins: np.ndarray, cfg: FrontEndConfig) -> np.ndarray:
    """(N, K, K + C) bool: the candidates (:func:`candidates`) a table holds (see :class:`CandidateTable`)."""
    k = len(twins)
    where = np.isfinite(cand[..., 0])
    other = np.ones((k, k), bool)
    np.fill_diagonal(other, False)
    other[np.flatnonzero(twins >= 0), twins[twins >= 0]] = False
    # an "other" candidate's score is other_score + noise minus a quality penalty >= 0: below
    # min_written_score without the penalty, it is never written
    reachable = cfg.other_score[0] + cfg.other_score[1] * draws.z_match >= cfg.min_written_score
    where[:, :, :k] &= ~other[None] | reachable
    return where


def candidate_boxes(draws: Draws, cand: np.ndarray, where: np.ndarray, box_jitter: float) -> np.ndarray:
    """The boxes (M, 4) the candidates ``where`` of ``cand`` (:func:`candidates`) would be written
    with, in (frame, instance, candidate) order. PV pixels."""
    f, i, _ = np.nonzero(where)
    return jitter_boxes(draws.z_box[f, i], cand[where], box_jitter, PV_SHAPE[1], PV_SHAPE[0])


def candidate_tables(rec, cfgs: dict[str, FrontEndConfig], lift: LiftConfig) -> dict[str, CandidateTable]:
    """Lift the candidate boxes of each detection set (``cfgs``: set name -> front-end knobs; only
    :data:`TABLE_KNOBS` matter here) of the synthetic recording ``rec`` with the reference rule
    (``lift`` with ``mode`` forced to ``reference``), all sets in one pass over the depth frames."""
    meta, v = _views(rec.root)
    seed, k = int(meta["seed"]), v["visible"].shape[1]
    ts = v["timestamps"]
    tables, wheres, frames = {}, [], []
    dets: dict[int, list[Detection]] = {int(t): [] for t in ts}
    # one detection list per frame: set after set, each in (instance, candidate) order
    for name, cfg in cfgs.items():
        table = tables[name] = _table(seed, name, cfg, v)
        cand = candidates(table.boxes, table.clutter)
        where = candidate_mask(table.draws, cand, table.twins, cfg)
        written = candidate_boxes(table.draws, cand, where, cfg.box_jitter)
        f, i, _ = np.nonzero(where)
        for ff, ii, b in zip(f, i, written):
            dets[int(ts[ff])].append(Detection(int(ii), Box(*map(float, b)), 1.0))
        wheres.append((where, written))
        frames.append(f)
    obs, _ = lift_recording(rec, dets, dataclasses.replace(lift, mode="reference"), progress=False, n_instances=k)
    # lift_recording keeps one row per detection of a known frame and instance, in frame and list
    # order: map each set's candidates to their rows, and check the boxes (so a change there
    # cannot silently mislabel candidates)
    set_of = np.concatenate([np.full(len(f), s) for s, f in enumerate(frames)])
    rank = np.lexsort((set_of, np.concatenate(frames)))  # stable: frame, then set, then the set's own order
    row = np.empty(len(rank), np.int64)
    row[rank] = np.arange(len(rank))
    offsets = np.cumsum([0] + [len(f) for f in frames])
    for s, (table, (where, written)) in enumerate(zip(tables.values(), wheres)):
        rows = row[offsets[s]:offsets[s + 1]]
        if len(obs) != len(rank) or not np.array_equal(obs.box[rows], written.astype(np.float32)):
            raise RuntimeError("lifted candidate rows do not line up with the candidate boxes")
        table.index = np.full(where.shape, -1, np.int32)
        table.index[where] = np.arange(len(rows), dtype=np.int32)
        table.obs = obs.select(rows)
    return tables


def save_table(table: CandidateTable, path: str | Path) -> None:
    """Keep a table (``<path>.obs.npz``, ``<path>.index.npz``); the views and draws are read again
    from the recording by :func:`load_table`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    table.obs.save(path.with_name(path.name + ".obs.npz"))
    meta = json.dumps({"seed": table.seed, "det_set": table.det_set, "knobs": table.knobs}, sort_keys=True)
    with atomic_path(path.with_name(path.name + ".index.npz")) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, index=table.index, meta=np.array(meta))


def load_table(rec, path: str | Path, det_set: str, cfg: FrontEndConfig) -> CandidateTable | None:
    """The table :func:`save_table` kept at ``path`` when it was made from ``rec``'s seed for
    ``det_set`` at ``cfg``'s :data:`TABLE_KNOBS`, else None."""
    path = Path(path)
    idx_path, obs_path = path.with_name(path.name + ".index.npz"), path.with_name(path.name + ".obs.npz")
    if not (idx_path.exists() and obs_path.exists()):
        return None
    meta, v = _views(rec.root)
    with np.load(idx_path) as data:
        saved, index = json.loads(str(data["meta"])), data["index"]
    want = json.loads(json.dumps({"seed": int(meta["seed"]), "det_set": det_set, "knobs": table_knobs(cfg)}))
    if saved != want:
        return None
    return _table(want["seed"], det_set, cfg, v, index, Observations.load(obs_path))


def simulate_observations(table: CandidateTable, cfg: FrontEndConfig) -> tuple[Observations, np.ndarray]:
    """The reference-lifted observations the front-end ``cfg`` would give on the table's recording,
    and the source of each row (``true``/``twin``/``other``/``clutter``). ``cfg`` must keep the
    table's :data:`TABLE_KNOBS`."""
    if table_knobs(cfg) != table.knobs:
        raise ValueError(f"the candidate table was made for {table.knobs}; asked for {table_knobs(cfg)}")
    fe = front_end(table.seed, table.det_set, cfg, table.twins)  # its clutter bias; the draws are the table's
    best, top = fe.top1(table.visible, table.boxes, table.motion, table.clutter, table.draws)
    f, i = np.nonzero(top >= cfg.min_written_score)
    j = best[f, i]
    rows = table.index[f, i, j]
    if (rows < 0).any():
        raise RuntimeError("a written candidate is not in the table")
    obs = table.obs.select(rows)
    obs.score = np.array([written_score(s) for s in top[f, i]], np.float32)
    return obs, fe.sources(i, j)


def annotated_sequence(rec) -> LoadedSequence:
    """The recording's poses and GT intervals, read as the evaluation reads them."""
    ann = rec.annotation_dir
    return load_sequence(rec.seq_dir / "pv_pose.json", ann / "3d_center_annot.txt", None, find_labels_file(ann))


def memory_counts(seq: LoadedSequence, obs: Observations, cfg: BaselineConfig) -> Counts:
    """IT3DEgo counts (precision / recall at every threshold, L2, angle) of the ``memory`` baseline
    on ``obs``: the paper's pipeline, scored as ``egograph eval`` scores it."""
    per_frame = memory_tracker(obs, seq.timestamps, cfg)
    preds = {int(t): {p.instance: np.asarray(p.xyz, np.float64) for p in frame} for t, frame in per_frame.items()}
    return evaluate_sequence(seq.timestamps, seq.gt, preds, seq.camera_centers).total


def band_values(c: Counts) -> dict[str, float]:
    """The three calibrated values of one result: P@0.25 and P@1.5 (%), L2 (m)."""
    return {"P@0.25": 100 * float(c.precision[0]), "P@1.5": 100 * float(c.precision[-1]), "L2 (m)": c.l2_m}


def pooled_values(counts: list[Counts]) -> dict[str, float]:
    """:func:`band_values` of counts pooled over recordings (as the reference evaluator pools sequences)."""
    return band_values(sum(counts[1:], counts[0]))


def bootstrap_se(counts: list[Counts], draws: int = 2000, seed: int = 0) -> dict[str, float]:
    """Standard error of :func:`pooled_values`: its spread over sets of recordings drawn from
    ``counts`` with replacement (the set's recordings are the sample)."""
    rng = np.random.default_rng(seed)
    vals = [pooled_values([counts[i] for i in rng.integers(len(counts), size=len(counts))]) for _ in range(draws)]
    return {m: float(np.std([v[m] for v in vals], ddof=1)) for m in vals[0]}
