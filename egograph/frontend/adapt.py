"""The tracker teaches the front-end: a per-recording, per-instance appearance head learned from the
graph's own confident stands.

The offline graph knows, per recording, where each instance stood and which of its detections
supported that (its *stands*); an ImageNet encoder's cosine to the enrollment photos cannot tell an
instance's object in the PV frames from a look-alike or a clutter object, but crops of the same
recording can. So, per instance (in the spirit of the exemplar-SVM of Malisiewicz et al., ICCV 2011,
and of online discriminative trackers such as DiMP's learned target model):

1. **Harvest** (:func:`harvest_boxes`): positives are the detections that are inliers of the
   instance's confident stands; hard negatives are the crops at the other instances' confident
   stands and the instance's own rejected detections (detections elsewhere while its stand holds),
   plus background proposals; the enrollment views are positives too, less a held-back share.
   Two instances' confident stands at one place and time show one object: it goes to the instance
   whose enrollment its crops match best (:func:`contest_owners`), and is a negative of the other.
2. **Learn** (:func:`fit_heads`): one-vs-rest L2-regularised logistic regression on the encoder's
   unit embeddings (scikit-learn, lbfgs; deterministic), class-balanced.
3. **Score** (:func:`adapted_logits`): ``z = head(x) + prior_weight * (cosine - similarity_threshold)``;
   a proposal passes when ``z >= 0``; an instance without a head keeps exactly the plain rule.
4. **Guard against confirmation**: a head trained on a wrong stand learns the wrong object. A head
   fitted on the instance's stand crops alone (no enrollment view) must rank the held-back
   enrollment views above the harvested negatives (rank AUC at least ``min_holdback``); otherwise
   the stands show another object, and the instance keeps the plain cosine. (Scored by the head
   with the training views among its positives, held-back views rank high whatever the stands
   show: they resemble the training views.)

Everything here works on boxes, frame indices and embeddings; reading results folders and PV frames is
:mod:`egograph.steps.adapt`'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from egograph.frontend.config import AdaptConfig

STAND, OUTLIER = "stand", "outlier"


@dataclass
class Stand:
    """One interval of the graph: ``instance`` stood at ``xyz`` (world, metres), supported by
    ``n_observations`` inlier detections from PV frame ``first`` to ``last`` (indices, inclusive)."""

    instance: int
    first: int
    last: int
    xyz: np.ndarray
    n_observations: int
    confidence: float

    def key(self) -> dict:
        return {"instance": int(self.instance), "first": int(self.first), "last": int(self.last),
                "xyz": [round(float(v), 4) for v in self.xyz], "n_observations": int(self.n_observations),
                "confidence": round(float(self.confidence), 4)}


def confident_stands(stands: list[Stand], cfg: AdaptConfig) -> list[Stand]:
    """The stands that teach: at least ``min_support`` inliers and ``min_confidence``."""
    return [s for s in stands if s.n_observations >= cfg.min_support and s.confidence >= cfg.min_confidence]


@dataclass
class Harvest:
    """Boxes to crop, one row each: PV frame index, box (x1, y1, x2, y2, PV pixels), the instance
    whose evidence it is, its kind (``stand``: a supporting detection of stand ``stand``;
    ``outlier``: a rejected detection of ``instance``), and the file it came from."""

    frames: np.ndarray
    boxes: np.ndarray
    instance: np.ndarray
    kind: np.ndarray
    stand: np.ndarray
    stands: list[Stand] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.frames)

    def counts(self) -> dict[int, dict[str, int]]:
        out: dict[int, dict[str, int]] = {}
        for inst, kind in zip(self.instance.tolist(), self.kind.tolist()):
            out.setdefault(int(inst), {STAND: 0, OUTLIER: 0})[kind] += 1
        return out


def _inside(box, uv, margin: float) -> bool:
    x1, y1, x2, y2 = (float(v) for v in box)
    mx, my = margin * (x2 - x1), margin * (y2 - y1)
    return x1 - mx <= uv[0] <= x2 + mx and y1 - my <= uv[1] <= y2 + my


def _spread(rows: list, limit: int) -> list:
    """At most ``limit`` of ``rows``, evenly spread (deterministic)."""
    if len(rows) <= limit:
        return rows
    return [rows[k] for k in np.linspace(0, len(rows) - 1, limit).round().astype(int)]


def harvest_boxes(stands: list[Stand], detections: dict[int, list[tuple[int, tuple]]],
                  project: Callable[[int, np.ndarray], np.ndarray | None], cfg: AdaptConfig) -> Harvest:
    """Positives and hard negatives of the confident ``stands`` (already filtered).

    ``detections``: PV frame index -> ``[(instance, box)]`` (the detections the graph was run on);
    ``project(frame, xyz)``: the PV pixel of a world point in that frame, or None (behind the camera,
    no pose). A detection of a stand's instance in a frame between the stand's first and last
    supporting detection is an inlier when the stand's centre projects inside its box (enlarged by
    ``box_margin``); otherwise, when no other confident stand of its instance claims it, it is a
    rejected detection: the object stood elsewhere then (an outlier, a hard negative)."""
    by_inst: dict[int, list[int]] = {}
    for k, s in enumerate(stands):
        by_inst.setdefault(s.instance, []).append(k)
    inliers: dict[int, list] = {k: [] for k in range(len(stands))}
    outliers: dict[int, list] = {}
    for f in sorted(detections):
        for inst, box in detections[f]:
            live = [k for k in by_inst.get(inst, ()) if stands[k].first <= f <= stands[k].last]
            if not live:
                continue
            hit = None
            for k in live:
                uv = project(f, stands[k].xyz)
                if uv is not None and _inside(box, uv, cfg.box_margin):
                    hit = k
                    break
            if hit is not None:
                inliers[hit].append((f, box))
            else:
                outliers.setdefault(inst, []).append((f, box))
    frames, boxes, insts, kinds, stand_of = [], [], [], [], []
    for k in range(len(stands)):
        for f, box in _spread(inliers[k], cfg.max_per_stand):
            frames.append(f), boxes.append(box), insts.append(stands[k].instance), kinds.append(STAND), stand_of.append(k)
    for inst in sorted(outliers):
        for f, box in _spread(outliers[inst], cfg.max_outliers):
            frames.append(f), boxes.append(box), insts.append(inst), kinds.append(OUTLIER), stand_of.append(-1)
    return Harvest(np.asarray(frames, np.int64), np.asarray(boxes, np.float64).reshape(-1, 4),
                   np.asarray(insts, np.int64), np.asarray(kinds, dtype=object), np.asarray(stand_of, np.int64),
                   list(stands))


def unit(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, np.float64)
    return x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)


def contest_owners(harvest: Harvest, emb: np.ndarray, means: dict[int, np.ndarray], cfg: AdaptConfig) -> np.ndarray:
    """Per stand of ``harvest.stands``, the instance whose positive it is: its own, unless confident
    stands of several instances lie within ``contest_radius_m`` of each other and overlap in time
    (one object cannot stand for two instances); then all of them go to the instance whose
    enrollment mean (``means``: instance -> unit vector) the group's crops match best on average.
    A group without crops keeps its owners."""
    st = harvest.stands
    owner = np.array([s.instance for s in st], np.int64)
    if cfg.contest_radius_m <= 0 or len(st) < 2:
        return owner
    parent = list(range(len(st)))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a in range(len(st)):
        for b in range(a + 1, len(st)):
            sa, sb = st[a], st[b]
            if (sa.instance != sb.instance and sa.first <= sb.last and sb.first <= sa.last
                    and np.linalg.norm(np.asarray(sa.xyz) - np.asarray(sb.xyz)) <= cfg.contest_radius_m):
                parent[find(a)] = find(b)
    groups: dict[int, list[int]] = {}
    for k in range(len(st)):
        groups.setdefault(find(k), []).append(k)
    for members in groups.values():
        insts = sorted({st[k].instance for k in members})
        if len(insts) < 2:
            continue
        rows = np.isin(harvest.stand, members) & (harvest.kind == STAND)
        cands = [i for i in insts if i in means]
        if not rows.any() or not cands:
            continue
        x = unit(emb[rows])
        score = [float((x @ means[i]).mean()) for i in cands]
        owner[members] = cands[int(np.argmax(score))]
    return owner


@dataclass
class Head:
    """Per-instance linear heads on unit embeddings: ``logit = emb @ weights[k] + bias[k]``."""

    weights: dict[int, np.ndarray] = field(default_factory=dict)
    bias: dict[int, float] = field(default_factory=dict)

    def logits(self, emb: np.ndarray) -> dict[int, np.ndarray]:
        x = np.asarray(emb, np.float64)
        return {k: x @ w + self.bias[k] for k, w in self.weights.items()}

    def to_arrays(self) -> dict[str, np.ndarray]:
        ids = sorted(self.weights)
        dim = len(next(iter(self.weights.values()))) if ids else 0
        return {"instances": np.asarray(ids, np.int64),
                "weights": np.asarray([self.weights[k] for k in ids], np.float64).reshape(len(ids), dim),
                "bias": np.asarray([self.bias[k] for k in ids], np.float64)}

    @classmethod
    def from_arrays(cls, a) -> "Head":
        ids = [int(k) for k in a["instances"]]
        return cls({k: np.asarray(a["weights"][j], np.float64) for j, k in enumerate(ids)},
                   {k: float(a["bias"][j]) for j, k in enumerate(ids)})


def adapted_logits(head: Head | None, plain: dict[int, np.ndarray], emb: np.ndarray, cfg: AdaptConfig,
                   similarity_threshold: float) -> dict[int, np.ndarray]:
    """Per instance, the adapted logit of each proposal: ``head(x) + prior_weight * (cosine -
    similarity_threshold)`` (``plain``: instance -> cosines); without a head only the prior, so the
    decision ``z >= 0`` is the plain rule ``cosine >= similarity_threshold``."""
    h = head.logits(emb) if head is not None and len(emb) else {}
    out = {}
    for inst, cos in plain.items():
        z = cfg.prior_weight * (np.asarray(cos, np.float64) - similarity_threshold)
        out[inst] = z + h[inst] if inst in h else z
    return out


def adapted_score(z: np.ndarray, cfg: AdaptConfig) -> np.ndarray:
    """The score written for an adapted detection: ``sigmoid(z + logit(threshold))`` (at least
    ``threshold`` exactly when ``z >= 0``)."""
    a = np.asarray(z, np.float64) + math.log(cfg.threshold / (1.0 - cfg.threshold))
    return 1.0 / (1.0 + np.exp(-np.clip(a, -50, 50)))


def rank_auc(pos: np.ndarray, neg: np.ndarray) -> float:
    """Share of (positive, negative) pairs the positive outranks (ties count half); NaN without pairs."""
    pos, neg = np.asarray(pos, np.float64), np.asarray(neg, np.float64)
    if not len(pos) or not len(neg):
        return float("nan")
    neg = np.sort(neg)
    below = np.searchsorted(neg, pos, "left")
    upto = np.searchsorted(neg, pos, "right")
    return float(((below + upto) / 2.0).sum() / (len(pos) * len(neg)))


def split_views(views: dict[int, np.ndarray], share: float, seed: int) -> tuple[dict, dict]:
    """Each instance's enrollment views split into (training, held back): ``floor(share * V)`` held
    back at random (seeded per instance), at least one left for training."""
    train, held = {}, {}
    for inst in sorted(views):
        v = np.asarray(views[inst])
        n_hold = min(int(math.floor(share * len(v))), len(v) - 1)
        order = np.random.default_rng([seed, inst]).permutation(len(v))
        held[inst], train[inst] = v[np.sort(order[:n_hold])], v[np.sort(order[n_hold:])]
    return train, held


def view_means(views: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
    return {k: unit(np.asarray(v, np.float64).mean(axis=0)) for k, v in views.items() if len(v)}


@dataclass
class InstanceFit:
    """What the fit did for one instance (one row of ``adapt.json``)."""

    positives: int = 0           # crops of its (won) confident stands
    negatives: int = 0           # other stands' crops + its rejected detections + background
    views_train: int = 0
    views_held: int = 0
    holdback_auc: float = float("nan")        # held-back views against the negatives, head of the stands alone
    holdback_auc_plain: float = float("nan")  # the same with the plain cosine (for reference)
    holdback_pass: float = float("nan")       # share of held-back views the adapted rule accepts
    head: bool = False
    why: str = ""

    def to_json(self) -> dict:
        def num(v):
            return None if v is None or (isinstance(v, float) and math.isnan(v)) else round(float(v), 4)

        return {"positives": self.positives, "negatives": self.negatives, "views_train": self.views_train,
                "views_held": self.views_held, "holdback_auc": num(self.holdback_auc),
                "holdback_auc_plain": num(self.holdback_auc_plain), "holdback_pass": num(self.holdback_pass),
                "head": self.head, "why": self.why}


def fit_one(pos: np.ndarray, neg: np.ndarray, cfg: AdaptConfig) -> tuple[np.ndarray, float]:
    """Logistic regression positives vs negatives (unit rows) -> (weights, bias); class-balanced."""
    from sklearn.linear_model import LogisticRegression

    x = np.concatenate([pos, neg]).astype(np.float64)
    y = np.concatenate([np.ones(len(pos)), np.zeros(len(neg))])
    clf = LogisticRegression(C=cfg.regularization, class_weight="balanced", max_iter=500, tol=1e-6)
    clf.fit(x, y)
    return clf.coef_[0].astype(np.float64), float(clf.intercept_[0])


def fit_heads(harvest: Harvest, emb: np.ndarray, views: dict[int, np.ndarray], background: np.ndarray,
              cfg: AdaptConfig, similarity_threshold: float, pooling: str = "mean") -> tuple[Head, dict[int, InstanceFit], np.ndarray]:
    """The heads of every enrolled instance (``views``: instance -> (V, D) unit enrollment
    embeddings) from the harvested crops' embeddings ``emb`` (one row per harvest row) and the
    ``background`` proposals' (B, D). Returns (head, per-instance report, stand owners)."""
    emb = unit(emb) if len(emb) else np.zeros((0, 0))
    background = unit(background) if len(background) else np.zeros((0, emb.shape[1] if emb.ndim == 2 else 0))
    train, held = split_views(views, cfg.holdback, cfg.seed)
    means = view_means(train)
    owners = contest_owners(harvest, emb, means, cfg)
    owner_row = np.where(harvest.kind == STAND, owners[np.maximum(harvest.stand, 0)] if len(owners) else -1, -1)
    head, report = Head(), {}
    for inst in sorted(views):
        r = InstanceFit(views_train=len(train[inst]), views_held=len(held[inst]))
        report[inst] = r
        pos_rows = owner_row == inst
        neg_rows = ((harvest.kind == STAND) & (owner_row != inst)) | ((harvest.kind == OUTLIER) & (harvest.instance == inst))
        neg = np.concatenate([emb[neg_rows], background]) if len(background) else emb[neg_rows]
        r.positives, r.negatives = int(pos_rows.sum()), len(neg)
        if r.positives < cfg.min_positives:
            r.why = f"{r.positives} crops of confident stands (< adapt.min_positives {cfg.min_positives})"
            continue
        if not len(neg):
            r.why = "no negatives"
            continue
        pos = np.concatenate([emb[pos_rows], unit(train[inst])])
        w, b = fit_one(pos, neg, cfg)
        if len(held[inst]):
            # the check: a head fitted on the stands' crops alone (no enrollment view) must rank the
            # held-back views above the negatives; a head fitted on a wrong object's crops does not
            # (with the training views among its positives any head would: they resemble the held-back)
            ws, bs = fit_one(emb[pos_rows], neg, cfg)
            hv = unit(held[inst])
            r.holdback_auc = rank_auc(hv @ ws + bs, neg @ ws + bs)
            r.holdback_auc_plain = rank_auc(hv @ means[inst], neg @ means[inst])
            one = Head({inst: w}, {inst: b})
            r.holdback_pass = float((adapted_logits(one, {inst: hv @ means[inst]}, hv, cfg, similarity_threshold)[inst]
                                     >= 0).mean())
            if r.holdback_auc < cfg.min_holdback:
                r.why = (f"held-back enrollment views rank AUC {r.holdback_auc:.2f} under a head of the stands' crops "
                         f"alone (< adapt.min_holdback {cfg.min_holdback:g}): the stands show another object; "
                         "keeps the plain cosine")
                continue
        head.weights[inst], head.bias[inst] = w, b
        r.head = True
    return head, report, owners


def pooled_holdback(report: dict[int, InstanceFit]) -> float:
    """Mean held-back rank AUC over the instances that have one (NaN when none)."""
    v = [r.holdback_auc for r in report.values() if r.head and not math.isnan(r.holdback_auc)]
    return float(np.mean(v)) if v else float("nan")


def stands_changed(before: list[dict], after: list[dict], radius_m: float) -> float:
    """Share of ``after``'s confident stands (``Stand.key()`` dicts) with no stand of the same
    instance within ``radius_m`` in ``before`` (1.0 when ``after`` is empty and ``before`` is not)."""
    if not after:
        return 0.0 if not before else 1.0
    moved = 0
    for a in after:
        near = [b for b in before if b["instance"] == a["instance"]
                and np.linalg.norm(np.subtract(a["xyz"], b["xyz"])) <= radius_m]
        moved += not near
    return moved / len(after)
