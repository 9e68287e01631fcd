"""Places, and the place chain: where an instance can stand, and where it stands at every frame.

The landmark chain (:mod:`egograph.track.chain`) cuts an instance's timeline into *segments* at
motion breaks. With a sparse or noisy front-end a stand falls apart into many short segments (a
lone false match between two true ones is two breaks), so a segment alone is poor evidence. A
*place* pools every segment at one location across the whole recording (:func:`candidate_places`):
a segment joins a place when the place already explains (inlier gate) at least ``places.overlap``
of its inliers, or of the place's, or lies within ``merge_radius_m``; the place is then re-solved
as one landmark over all its inliers (GTSAM, robust). A place needs ``min_observations`` inliers
and, with fewer than ``places.support_min_inliers``, a surface under it: an object rests on
something, and a few alias-wrapped or hand-held detections in mid-air are not a place.

Two objects cannot stand in one place at once (:func:`claim_places`): a place within
``exclusion_radius_m`` of another instance's place with more inliers, over overlapping times,
belongs to that instance (a look-alike), and its detections become false-match evidence.

The *place chain* (:func:`place_chain`) is a hidden Markov chain over the PV frames whose states
are standing at each of the instance's places, carried (in hand: nothing to report) and
``UNSEEN_STATE`` (put down where it was never seen again: reported where the hand last held it,
at low confidence); :func:`stand_state`, :func:`carry_state` and ``ANY_CARRY`` number them.
Each accepted detection is, with probability ``places.true_share``, the object (near the place,
with the detection covariance plus the place's, the nearest AHAT alias candidate; near the head
when carried), otherwise a false match: spread over the scene (``places.false_density`` per m^3)
and, for ``places.lookalike_share`` of them, at another instance's place. Frames without a
detection say nothing. Transition rates per second: pick-ups (``pick_up_rate``), carries ending
(``1/carry_s``), a share of them at a place never seen again (``unseen_put_down``), moves nobody
saw (``unseen_move_rate``). Offline, the instance is where the most probable state sequence puts
it (:func:`map_path`: Viterbi in log space, the MPE of the same chain as a GTSAM
``DiscreteFactorGraph``, which the tests check), and each run of a state gets its posterior
probability (:func:`posterior`: forward-backward) as confidence. World frame, metres; PV frame
indices.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from egograph.track.config import GraphConfig
from egograph.track.detection_factor import detection_covariances
from egograph.track.segments import Segment, SupportFn, moves_with_camera, point_covariance, point_factors, robust_point

@dataclass(eq=False)  # identity: a place is one location, whatever its numbers
class Place:
    """One location an instance stood at: robust centre (world, metres), marginal covariance (m^2,
    without the floor) and the rows (into the instance's observations) it explains."""

    xyz: np.ndarray
    covariance: np.ndarray
    rows: np.ndarray                 # inlier rows, sorted
    frames: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # their PV frames

    @property
    def n_inliers(self) -> int:
        return len(self.rows)

    @property
    def span(self) -> tuple[int, int]:
        """First and last PV frame of its inlier detections."""
        return int(self.frames.min()), int(self.frames.max())

    def as_segment(self) -> Segment:
        """The place as a stationary segment of its inliers (for the noise-scale fit and joint mode)."""
        return Segment(self.rows, self.xyz, self.covariance, np.ones(len(self.rows), bool), stationary=True)


# --------------------------------------------------------------------------- places


def _gate(world: np.ndarray, cov: np.ndarray, xyz: np.ndarray, cfg: GraphConfig) -> np.ndarray:
    """Which of an instance's detections (all of them: hundreds to thousands) fall in the inlier gate
    of ``xyz``; closed form (:func:`mahalanobis2_3d`), a third of the batched LAPACK solves' time at
    that size."""
    return mahalanobis2_3d(world - xyz, cov)[0] <= cfg.inlier_chi2


def candidate_places(segments: Sequence[Segment], world: np.ndarray, cov: np.ndarray,
                     camera: np.ndarray, range_m: np.ndarray, frames: np.ndarray, cfg: GraphConfig,
                     support: SupportFn | None = None, factors: list | None = None) -> list[Place]:
    """An instance's places from its chain's segments (runs of chunks joined by switches that stayed
    on, as made by :func:`egograph.track.segments.make_segment` from ``world``/``cov``), strongest
    first. ``world``/``cov``: each detection after the alias re-choice and its covariance (m, m^2);
    ``camera``, ``range_m``: where it was seen from; ``factors``: every row's
    :func:`~egograph.track.segments.point_factors`, when made already."""
    pc = cfg.places
    if factors is None:
        factors = point_factors(world, cov, cfg)

    def centre(rows: np.ndarray, start: np.ndarray) -> np.ndarray:
        return robust_point(world[rows], cov[rows], cfg, start, False, [factors[j] for j in rows.tolist()])[0]

    segs = []
    for seg in segments:
        rows = seg.rows
        if seg.n_inliers >= pc.segment_min_inliers and not moves_with_camera(world[rows], camera[rows],
                                                                            range_m[rows], cfg):
            segs.append(seg)
    segs.sort(key=lambda s: (-s.n_inliers, int(s.rows[0])))
    # (xyz, the rows it was solved from, inlier mask); the marginal covariance only of what is kept
    pooled: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for seg in segs:
        mask = _gate(world, cov, seg.xyz, cfg)
        for k, (xyz, _, have) in enumerate(pooled):
            shared = int((have & mask).sum())
            if (shared >= pc.overlap * min(int(have.sum()), int(mask.sum()))
                    or np.linalg.norm(xyz - seg.xyz) <= cfg.merge_radius_m):
                rows = np.flatnonzero(have | mask)
                x = centre(rows, xyz)
                pooled[k] = (x, rows, _gate(world, cov, x, cfg))
                break
        else:
            core = seg.rows[seg.inliers]
            x = centre(core, seg.xyz)
            pooled.append((x, core, _gate(world, cov, x, cfg)))
    places = []
    for xyz, solved, mask in pooled:
        rows = np.flatnonzero(mask)
        if len(rows) < cfg.min_observations:
            continue
        if support is not None and len(rows) < pc.support_min_inliers and not support(xyz):
            continue
        c = point_covariance(world[solved], cov[solved], xyz, cfg, [factors[j] for j in solved.tolist()])
        places.append(Place(xyz, c, rows, frames[rows].astype(np.int64)))
    places.sort(key=lambda p: (-p.n_inliers, p.span[0]))
    # pooling can move two places onto one location: keep the stronger
    out: list[Place] = []
    for p in places:
        if all(np.linalg.norm(p.xyz - q.xyz) > cfg.merge_radius_m for q in out):
            out.append(p)
    return out


def carried_rows(segment_rows: Sequence[np.ndarray], world: np.ndarray, camera: np.ndarray, range_m: np.ndarray,
                 cfg: GraphConfig) -> np.ndarray:
    """(M,) bool: detections of segments the chain saw moving with the head (seen from within
    ``carry_range_m``, :func:`egograph.track.segments.moves_with_camera`) with at least
    ``min_carry_observations`` of them near: the evidence of a carry."""
    out = np.zeros(len(world), bool)
    for rows in segment_rows:
        near = rows[range_m[rows] <= cfg.carry_range_m]
        if len(near) >= cfg.min_carry_observations and moves_with_camera(world[rows], camera[rows], range_m[rows], cfg):
            out[near] = True
    return out


def claim_places(places: dict[int, list[Place]], radius_m: float) -> dict[int, list[Place]]:
    """Per instance, the places no other instance claims: another instance's place within
    ``radius_m`` with more inliers whose inliers span overlapping frames (two objects cannot stand
    in one place at once; the weaker claimant's detections there were look-alike matches)."""
    if radius_m <= 0:
        return {i: list(v) for i, v in places.items()}
    out = {}
    for i, mine in places.items():
        keep = []
        for a in mine:
            a0, a1 = a.span
            claimed = any(b.n_inliers > a.n_inliers and np.linalg.norm(a.xyz - b.xyz) <= radius_m
                          and b.span[0] <= a1 and a0 <= b.span[1]
                          for j, theirs in places.items() if j != i for b in theirs)
            if not claimed:
                keep.append(a)
        out[i] = keep
    return out


def place_reality(places: dict[int, list[Place]], scores: dict[int, np.ndarray], min_samples: int = 10
                  ) -> dict[int, list[float]]:
    """Per instance and place, the probability that the place is the object rather than a spot where
    false matches persist (a clutter object that looks like it), from the matcher scores of its
    inliers: the scores of every place's inliers and of every detection no place explains, each
    fitted with a normal, give a likelihood ratio per inlier (clipped to +-5 nats; prior odds 1).
    Without ``min_samples`` of each kind every place gets 1."""
    inl = [scores[i][p.rows] for i, ps in places.items() for p in ps]
    out_rows = []
    for i, ps in places.items():
        mask = np.ones(len(scores[i]), bool)
        for p in ps:
            mask[p.rows] = False
        out_rows.append(scores[i][mask])
    true = np.concatenate(inl) if inl else np.zeros(0)
    false = np.concatenate(out_rows) if out_rows else np.zeros(0)
    if len(true) < min_samples or len(false) < min_samples:
        return {i: [1.0] * len(ps) for i, ps in places.items()}

    def log_normal(x, sample):
        mu, sd = float(np.mean(sample)), max(float(np.std(sample)), 0.02)
        return -0.5 * ((x - mu) / sd) ** 2 - np.log(sd)

    result = {}
    for i, ps in places.items():
        result[i] = []
        for p in ps:
            s = np.asarray(scores[i][p.rows], float)
            llr = np.clip(log_normal(s, true) - log_normal(s, false), -5.0, 5.0).sum()
            result[i].append(float(1.0 / (1.0 + np.exp(-np.clip(llr, -50, 50)))))
    return result


def chance_of_place(place: Place, cov: np.ndarray, n_rows: int, cfg: GraphConfig) -> float:
    """Probability that ``place``'s inliers are a coincidence: that at least ``n_inliers`` of the
    instance's other ``n_rows`` detections, scattered as false matches at ``false_density`` per m^3,
    fall by chance in the place's gate (the ``inlier_chi2`` ellipsoid of its inliers' mean
    detection covariance ``cov`` (M, 3, 3) m^2): a Poisson tail. Three random matches that happen
    to meet make a place the chain would otherwise trust as much as thirty."""
    c = np.mean(cov[place.rows], axis=0)
    volume = 4.0 / 3.0 * np.pi * cfg.inlier_chi2 ** 1.5 * float(np.sqrt(max(np.linalg.det(c), 0.0)))
    lam = max(n_rows - place.n_inliers, 0) * volume * cfg.places.false_density
    k = np.arange(place.n_inliers)
    log_terms = -lam + k * np.log(max(lam, 1e-300)) - np.cumsum(np.log(np.maximum(k, 1)))
    return float(np.clip(1.0 - np.exp(np.logaddexp.reduce(log_terms)), 0.0, 1.0)) if lam > 0 else 0.0


# --------------------------------------------------------------------------- the place chain


FAR_LOG_DENSITY = -100.0
"""A detection-spot log density below this is left at its upper bound (:func:`log_gauss_spots`):
every use adds it to terms of log density above -20 (a false match lands anywhere), where e^-80
does not change a float64."""


def mahalanobis2_3d(d: np.ndarray, total: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Squared Mahalanobis length of offsets ``d`` (..., 3) under symmetric covariances ``total``
    (..., 3, 3), and their determinants, in closed form (adjugate over determinant): batched
    LAPACK solves and inverses cost several times more per tiny matrix. The entries are first
    gathered into contiguous rows: the arithmetic on strided views of (..., 3, 3) cost half as much again."""
    shape = np.broadcast_shapes(d.shape[:-1], total.shape[:-2])
    t = np.ascontiguousarray(np.broadcast_to(total, shape + (3, 3)).reshape(-1, 9).T)   # (9, N)
    xx, xy, xz, yy, yz, zz = t[0], t[1], t[2], t[4], t[5], t[8]
    a_xx, a_yy, a_zz = yy * zz - yz * yz, xx * zz - xz * xz, xx * yy - xy * xy
    a_xy, a_yz, a_xz = xz * yz - xy * zz, xy * xz - xx * yz, xy * yz - yy * xz
    det = xx * a_xx + xy * a_xy + xz * a_xz
    dx, dy, dz = np.ascontiguousarray(np.broadcast_to(d, shape + (3,)).reshape(-1, 3).T)   # (3, N)
    q = (dx * dx * a_xx + dy * dy * a_yy + dz * dz * a_zz
         + 2.0 * (dx * dy * a_xy + dy * dz * a_yz + dx * dz * a_xz)) / det
    return q.reshape(shape), det.reshape(shape)


def _log_gauss_3d(d: np.ndarray, total: np.ndarray) -> np.ndarray:
    """log N(d; 0, total), (...,) for offsets (..., 3) and covariances (..., 3, 3)."""
    q, det = mahalanobis2_3d(d, total)
    return -0.5 * q - 0.5 * np.log(det) - 1.5 * np.log(2.0 * np.pi)


SMALL_BATCH = 4096
"""Below this many detection-spot-candidate triples :func:`log_gauss_spots` evaluates every one (one
frame online); above, only those its upper bound keeps (every detection of a recording offline)."""


def log_gauss_spots(cands: np.ndarray, cov: np.ndarray, xyz: np.ndarray, spot_cov: np.ndarray) -> np.ndarray:
    """(M, P): per detection and spot, the largest log N(c; xyz_p, C_c + spot_cov_p) over the
    detection's alias candidates ``c`` (``cands`` (M, C, 3), NaN padded, world metres) with their
    covariances ``cov`` (M, C, 3, 3) m^2; ``xyz`` (P, 3), ``spot_cov`` (P, 3, 3): the candidate that
    best explains each spot.

    Offline this runs for every detection against every place of every instance, and most pairs
    are metres apart: beyond ``SMALL_BATCH`` triples an upper bound comes first (the largest
    eigenvalue of a covariance is at most its trace, and det(C_c + spot_cov) >= det(C_c)), and only
    pairs whose bound reaches ``FAR_LOG_DENSITY`` are evaluated; the others keep their bound."""
    m, c = cands.shape[:2]
    p = len(xyz)
    if p == 0 or m == 0:
        return np.full((m, p), -np.inf)
    ok = np.isfinite(cands[..., 0])                                   # (M, C)
    every = bool(ok.all())                                            # no padding (one frame online, mostly)
    x = cands if every else np.where(ok[..., None], cands, 0.0)
    cov = cov if every else np.where(ok[..., None, None], cov, np.eye(3))
    if m * p * c <= SMALL_BATCH:
        ll = _log_gauss_3d(x[:, None] - xyz[None, :, None], cov[:, None] + spot_cov[None, :, None])
        return (ll if every else np.where(ok[:, None, :], ll, -np.inf)).max(axis=2)
    d2 = np.maximum((x * x).sum(-1)[:, None] + (xyz * xyz).sum(-1)[None, :, None]
                    - 2.0 * np.einsum("mci,pi->mpc", x, xyz), 0.0)    # (M, P, C) squared distance
    trace = np.trace(cov, axis1=-2, axis2=-1)[:, None] + np.trace(spot_cov, axis1=-2, axis2=-1)[None, :, None]
    log_norm = -0.5 * np.linalg.slogdet(cov)[1] - 1.5 * np.log(2.0 * np.pi)                # (M, C)
    ll = -0.5 * d2 / trace + log_norm[:, None]                        # the bound
    i, j, k = np.nonzero(ok[:, None] & (ll > FAR_LOG_DENSITY))
    ll[i, j, k] = _log_gauss_3d(x[i, k] - xyz[j], cov[i, k] + spot_cov[j])
    return np.where(ok[:, None, :], ll, -np.inf).max(axis=2)


def candidate_covariances(cands: np.ndarray, camera: np.ndarray, cfg: GraphConfig) -> np.ndarray:
    """(M, C, 3, 3) detection covariance (m^2) of every alias candidate, at its own range from the
    depth camera ``camera`` (M, 3) (:func:`egograph.track.detection_factor.detection_covariances`)."""
    m, c, _ = cands.shape
    flat = cands.reshape(m * c, 3)
    flat = np.where(np.isnan(flat), 0.0, flat)
    return detection_covariances(flat, np.repeat(camera, c, axis=0), cfg.noise).reshape(m, c, 3, 3)


ANY_CARRY, UNSEEN_STATE = 0, 1
"""Fixed states of the place chain: carried, picked up at no known place; standing at a place not
(yet) among the instance's places. Place k adds :func:`stand_state` and :func:`carry_state`, so a
place found later (online) only appends states."""


def stand_state(k: int) -> int:
    """The state 'standing at place k'."""
    return 2 + 2 * k


def carry_state(k: int) -> int:
    """The state 'carried, picked up at place k'."""
    return 3 + 2 * k


def n_states(k: int) -> int:
    """States of the place chain of ``k`` places."""
    return 2 + 2 * k


def state_kind(state: int) -> int:
    """A state as a run kind: its place index (>= 0), -1 for any carry, -2 for UNSEEN."""
    if state == UNSEEN_STATE:
        return -2
    if state == ANY_CARRY or state % 2:
        return -1
    return (state - 2) // 2


def log_true_share(score: np.ndarray, cfg: GraphConfig) -> np.ndarray:
    """(M,) log prior probability that each accepted detection is the instance: ``true_share`` at a
    matcher score of at least ``confident_score``, ``weak_true_share`` below."""
    pc = cfg.places
    return np.log(np.where(np.asarray(score, float) >= pc.confident_score, pc.true_share, pc.weak_true_share))


def spot_arrays(places: Sequence[Place]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Places as the spots of :func:`row_log_likelihoods`: centres (P, 3), covariances (P, 3, 3),
    inliers (P,)."""
    return (np.array([p.xyz for p in places], float).reshape(-1, 3),
            np.array([p.covariance for p in places], float).reshape(-1, 3, 3),
            np.array([p.n_inliers for p in places], float))


def row_log_likelihoods(spots: tuple[np.ndarray, np.ndarray, np.ndarray], k: int, cands: np.ndarray,
                        cov: np.ndarray, log_true: np.ndarray, in_hand: np.ndarray, cfg: GraphConfig) -> np.ndarray:
    """(M, :func:`n_states` (k)) log-likelihood of each detection under each state.

    ``spots``: centres (P, 3), covariances (P, 3, 3) and inliers (P,) (:func:`spot_arrays`) of this
    instance's ``k`` places first, then the other instances' places (where look-alike matches
    gather; a spot of 0 inliers gathers none); ``cands`` (M, C, 3) alias candidates (world,
    metres, NaN padded) with covariances ``cov`` (M, C, 3, 3) m^2; ``log_true`` (M,) from
    :func:`log_true_share`; ``in_hand`` (M,) bool: seen moving with the head.

    A detection is the instance with probability pi (``log_true``): near the place (the alias
    candidate that fits best) when it stands, at the hand when carried; otherwise a false match,
    persistent like its cause (a look-alike, a clutter object): ``lookalike_share`` of them at one
    of the spots, in proportion to its inliers, or at a new spot (weight
    ``false_spot_concentration``), the rest anywhere (``false_density``). Under UNSEEN a detection
    is a false match."""
    with np.errstate(divide="ignore", invalid="ignore"):  # log(0) = -inf is meant: a spot of 0 inliers, no hand
        return _row_log_likelihoods(spots, k, cands, cov, log_true, in_hand, cfg)


def _row_log_likelihoods(spots, k, cands, cov, log_true, in_hand, cfg):
    """:func:`row_log_likelihoods`, under its error state (one per call: the online tracker calls it
    per detection, and each ``np.errstate`` costs as much as a small array operation)."""
    pc = cfg.places
    m = len(log_true)
    log_false_share = np.log1p(-np.exp(log_true))
    log_rho = np.log(pc.false_density)
    xyz, spot_cov, n = spots
    have = len(n) > 0
    at = log_gauss_spots(cands, cov, xyz, spot_cov) if have else np.zeros((m, 0))
    at_w = at + np.log(n)                                # log(n_j N_j); a spot of 0 inliers gathers none
    every = np.logaddexp.reduce(at_w, axis=1) if have else np.full(m, -np.inf)
    alpha = pc.false_spot_concentration
    log_alike_share = np.log(pc.lookalike_share) if pc.lookalike_share > 0 else -np.inf  # 0: no look-alikes

    def log_false(skip: int | None) -> np.ndarray:
        """log density of a false match when the object is not at spot ``skip`` (None: at none):
        at a spot in proportion to its inliers, or at a new one (``alpha``), as a Chinese restaurant
        process seats its guests."""
        if skip is None or n[skip] == 0:
            spot, total = every, n.sum()
        else:
            spot = every + np.log1p(-np.minimum(np.exp(at_w[:, skip] - every), 1.0))
            total = n.sum() - n[skip]
        alike = np.logaddexp(spot, np.log(alpha) + log_rho) - np.log(total + alpha)
        return log_false_share + np.logaddexp(np.log1p(-pc.lookalike_share) + log_rho,
                                              log_alike_share + alike)

    out = np.empty((m, n_states(k)))
    elsewhere = log_false(None)
    hand = np.where(in_hand, np.log(pc.carry_density), -np.inf)
    carried = np.logaddexp(log_true + hand, elsewhere)
    out[:, ANY_CARRY] = carried
    out[:, UNSEEN_STATE] = elsewhere
    if k:  # log_false(j) for every own place at once (the same sums, broadcast over j)
        nk = n[:k]
        spot = every[:, None] + np.log1p(-np.minimum(np.exp(at_w[:, :k] - every[:, None]), 1.0))
        spot = np.where(nk[None] == 0, every[:, None], spot)
        total = np.where(nk == 0, n.sum(), n.sum() - nk)
        alike = np.logaddexp(spot, np.log(alpha) + log_rho) - np.log(total + alpha)[None]
        false_k = log_false_share[:, None] + np.logaddexp(np.log1p(-pc.lookalike_share) + log_rho,
                                                          log_alike_share + alike)
        out[:, stand_state(0)::2] = np.logaddexp(log_true[:, None] + at[:, :k], false_k)  # stand_state(j)
        out[:, carry_state(0)::2] = carried[:, None]                                      # carry_state(j)
    return out


@functools.lru_cache(maxsize=256)
def carry_states(k: int) -> np.ndarray:
    """Indices of every carry state of a chain of ``k`` places (read-only: cached, as the online
    tracker asks for it every frame)."""
    out = np.array([ANY_CARRY] + [carry_state(j) for j in range(k)])
    out.flags.writeable = False
    return out


def emissions(places: Sequence[Place], others: Sequence[Place], cands: np.ndarray, cov: np.ndarray,
              score: np.ndarray, frames: np.ndarray, in_hand: np.ndarray, n_frames: int,
              cfg: GraphConfig) -> np.ndarray:
    """(n_frames, :func:`n_states`) log-likelihood of each frame's accepted detections under each
    state (:func:`row_log_likelihoods`; ``score`` (M,) matcher scores, ``frames`` (M,) PV indices).
    A frame without a detection in hand says little of where a standing object is, but a carried
    object is in front of the eyes: carry states pay ``log(1 - carry_detect_rate)`` on it."""
    k = len(places)
    per_row = row_log_likelihoods(spot_arrays(list(places) + list(others)), k, cands, cov,
                                  log_true_share(score, cfg), in_hand, cfg)
    out = np.zeros((n_frames, n_states(k)))
    np.add.at(out, frames, per_row)
    held = np.zeros(n_frames, bool)
    held[frames[in_hand]] = True
    out[np.ix_(~held, carry_states(k))] += np.log1p(-cfg.places.carry_detect_rate)
    return out


def transitions(k: int, cfg: GraphConfig, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Log transition matrix (from, to) between consecutive frames at ``fps`` and the log prior of
    the first frame over the :func:`n_states` states (rates per second: module doc). A carry
    remembers the place it began at: it ends back there with probability ``put_back``, at the
    object's other places, or (``unseen_put_down``) at a place it is never seen at."""
    pc = cfg.places
    dt = 1.0 / fps
    lift = pc.pick_up_rate * dt
    drop = dt / pc.carry_s
    move = pc.unseen_move_rate * dt if k > 1 else 0.0
    a = np.zeros((n_states(k), n_states(k)))
    stands = [stand_state(j) for j in range(k)]
    for j in range(k):
        sj, cj = stand_state(j), carry_state(j)
        if k > 1:
            a[sj, stands] = move / (k - 1)
        a[sj, sj] = 1.0 - lift - move
        a[sj, cj] = lift
        a[cj, cj] = 1.0 - drop
        a[cj, sj] = drop * pc.put_back
        elsewhere = drop * (1.0 - pc.put_back - pc.unseen_put_down)
        if k > 1:
            a[cj, [s for s in stands if s != sj]] = elsewhere / (k - 1)
            a[cj, UNSEEN_STATE] = drop * pc.unseen_put_down
        else:
            a[cj, UNSEEN_STATE] = drop * pc.unseen_put_down + elsewhere
    a[ANY_CARRY, ANY_CARRY] = 1.0 - drop
    if k:
        a[ANY_CARRY, stands] = drop * (1.0 - pc.unseen_put_down) / k
        a[ANY_CARRY, UNSEEN_STATE] = drop * pc.unseen_put_down
    else:
        a[ANY_CARRY, UNSEEN_STATE] = drop
    a[UNSEEN_STATE, UNSEEN_STATE] = 1.0 - lift
    a[UNSEEN_STATE, ANY_CARRY] = lift
    prior = np.zeros(n_states(k))
    prior[[ANY_CARRY, UNSEEN_STATE]] = pc.start_unknown / 2 if k else 0.5
    if k:
        prior[stands] = (1.0 - pc.start_unknown) / k
    with np.errstate(divide="ignore"):
        return np.log(a), np.log(prior)


def viterbi_step(v: np.ndarray, log_a_into: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One max-product step of the chain: from the best log score of each state ``v`` (..., S) and
    the log transitions *into* each state ``log_a_into`` (..., to, from: the transpose of
    :func:`transitions`' matrix, C order, so that each maximum runs along memory), the best score of
    reaching each state (before its emission) and the state it comes from (ties to the lower
    index). Leading axes are a batch."""
    m = log_a_into + v[..., None, :]
    return m.max(axis=-1), np.argmax(m, axis=-1)


def _chain_arrays(log_e: np.ndarray, log_a: np.ndarray, log_prior: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The chain as hmmlearn's recursions take it: first-frame and transition probabilities (C
    order), and each frame's emission log-likelihoods relative to its largest (the same path and
    posteriors, and scaled forward-backward cannot underflow on a likely state)."""
    top = np.max(log_e, axis=1, keepdims=True)
    frame_log_e = np.ascontiguousarray(log_e - np.where(np.isfinite(top), top, 0.0))
    return np.ascontiguousarray(np.exp(log_prior)), np.ascontiguousarray(np.exp(log_a)), frame_log_e


# The chain's recursions run in hmmlearn's compiled module, the one its models call: a frame is a
# (S, S) step, too small for numpy to pay its per-call cost on 10^4-10^5 frames. (The model classes
# would import scikit-learn, about a second per process, to reach the same functions.)


def map_path(log_e: np.ndarray, log_a: np.ndarray, log_prior: np.ndarray) -> np.ndarray:
    """The most probable state per frame of a chain with emission log-likelihoods ``log_e`` (T, S),
    log transitions ``log_a`` (from, to) and first-frame log prior ``log_prior`` (S,): (T,) state
    indices (Viterbi). Ties go to the lower state index (hmmlearn's backtrack takes the higher one,
    so the chain goes in with its states reversed)."""
    from hmmlearn import _hmmc

    rev = slice(None, None, -1)
    prior, a, frame_log_e = _chain_arrays(log_e[:, rev], log_a[rev, rev], log_prior[rev])
    with np.errstate(divide="ignore"):
        _, path = _hmmc.viterbi(prior, a, frame_log_e)
    return (log_e.shape[1] - 1 - np.asarray(path)).astype(np.int32)


def posterior(log_e: np.ndarray, log_a: np.ndarray, log_prior: np.ndarray) -> np.ndarray:
    """(T, S) posterior probability of each state per frame given every frame (forward-backward),
    as :func:`map_path`. In scaled probabilities; where those underflow (no state with a usable
    emission reachable), in log space."""
    from hmmlearn import _hmmc

    prior, a, frame_log_e = _chain_arrays(log_e, log_a, log_prior)
    with np.errstate(under="ignore", divide="ignore", invalid="ignore"):
        try:
            e = np.exp(frame_log_e)
            _, fwd, scaling = _hmmc.forward_scaling(prior, a, e)
            g = fwd * _hmmc.backward_scaling(prior, a, e, scaling)
            total = g.sum(axis=1, keepdims=True)
            if np.all(total > 0) and np.all(np.isfinite(g)):
                return g / total
        except ValueError:  # hmmlearn: "forward pass failed with underflow"
            pass
        _, fwd = _hmmc.forward_log(prior, a, frame_log_e)
        g = fwd + _hmmc.backward_log(prior, a, frame_log_e)
        return np.exp(g - np.logaddexp.reduce(g, axis=1, keepdims=True))


@dataclass
class PlaceRun:
    """A run of frames ``[start, end]`` (PV indices, inclusive) in one state of the place chain:
    ``place`` (index into the places) or -1 for a carry / -2 for UNSEEN; ``confidence``: the mean
    posterior probability of that state over the run."""

    start: int
    end: int
    place: int
    confidence: float


def state_runs(path: np.ndarray, post: np.ndarray | None, k: int) -> list[PlaceRun]:
    """Runs of one kind (a place, any carry, UNSEEN) of a place-chain path over ``k`` places, each
    with the mean posterior probability of its kind (every carry state summed)."""
    if len(path) == 0:
        return []
    kinds = np.array([state_kind(s) for s in range(n_states(k))])
    kind = kinds[path]
    cuts = np.flatnonzero(np.diff(kind)) + 1
    starts = np.concatenate([[0], cuts])
    ends = np.concatenate([cuts - 1, [len(path) - 1]])
    out = []
    for a, b in zip(starts, ends):
        c = int(kind[a])
        cols = np.flatnonzero(kinds == c)
        conf = float(post[a:b + 1][:, cols].sum(axis=1).mean()) if post is not None else 1.0
        out.append(PlaceRun(int(a), int(b), c, conf))
    return out


def place_chain(places: Sequence[Place], others: Sequence[Place], cands: np.ndarray, cov: np.ndarray,
                score: np.ndarray, frames: np.ndarray, in_hand: np.ndarray, n_frames: int, cfg: GraphConfig,
                fps: float) -> list[PlaceRun]:
    """An instance's place chain solved offline: its runs (MAP path) with their posterior confidence."""
    return place_chain_states(places, others, cands, cov, score, frames, in_hand, n_frames, cfg, fps)[0]


def place_chain_states(places: Sequence[Place], others: Sequence[Place], cands: np.ndarray, cov: np.ndarray,
                       score: np.ndarray, frames: np.ndarray, in_hand: np.ndarray, n_frames: int, cfg: GraphConfig,
                       fps: float) -> tuple[list[PlaceRun], np.ndarray, np.ndarray]:
    """:func:`place_chain`, with the MAP path (T,) and the posterior (T, S) it was read from (every
    frame's answer and its confidence: :mod:`egograph.track.answers`)."""
    log_e = emissions(places, others, cands, cov, score, frames, in_hand, n_frames, cfg)
    log_a, log_prior = transitions(len(places), cfg, fps)
    seen = np.zeros(n_frames, bool)
    seen[frames] = True
    post = posterior(log_e, log_a, log_prior)
    path = unseen_moves_at_crossing(map_path(log_e, log_a, log_prior), seen, post)
    return state_runs(path, post, len(places)), path, post


def unseen_moves_at_crossing(path: np.ndarray, seen: np.ndarray, post: np.ndarray) -> np.ndarray:
    """The path with each move from one place straight to another (a move nobody saw) set at the
    frame of its detection-free gap (``seen`` (T,) bool: frames with a detection) where the new
    place's posterior probability (``post`` (T, S)) first exceeds the old one's. In the gap both
    places emit nothing and stay with the same probability, so every frame of it is an equally
    probable moment for the move: Viterbi picks one by rounding. Per frame, the more probable
    place is the better answer."""
    path = path.copy()
    stand = (path >= 2) & (path % 2 == 0)
    seen_at = np.flatnonzero(seen)
    for t in np.flatnonzero(stand[1:] & stand[:-1] & (path[1:] != path[:-1])) + 1:
        a, b = int(path[t - 1]), int(path[t])
        i = np.searchsorted(seen_at, t)
        lo = int(seen_at[i - 1]) + 1 if i > 0 else 0
        hi = int(seen_at[i]) if i < len(seen_at) else len(path)
        if not ((path[lo:t] == a).all() and (path[t:hi] == b).all()):
            continue  # not a plain gap between the two (another change in it)
        later = np.flatnonzero(post[lo:hi, b] > post[lo:hi, a])
        cross = lo + int(later[0]) if len(later) else hi
        path[lo:cross], path[cross:hi] = a, b
    return path
