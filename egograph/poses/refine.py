"""``egograph refine``: pose-graph refinement of the HoloLens poses of a recording.

One trajectory is refined: the **PV camera -> world** pose at each PV timestamp (GTSAM keys
``symbol('x', i)``, see :mod:`egograph.poses.graph`). The AHAT poses follow it: every frame's
world-frame correction ``C_i = T_pv_refined · T_pv_reported⁻¹`` is applied to the reported
AHAT pose of the same frame (``depth_ahat_pose.json`` stays the rig node -> world pose at the
AHAT capture time). The reported PV and AHAT poses of a frame share the head-tracking error,
and their relative motion over the few ms between the captures is kept as HoloLens measured
it, so the two files stay consistent through the calibration extrinsics without having to
know the AHAT capture time. Frames with an invalid PV pose but a valid AHAT pose take the
correction of the nearest refined frame.

Sources (each switchable, ``--set refine.<source>=false``): HoloLens relative motion
(between-factors) + weak absolute prior, KISS-ICP odometry on AHAT clouds, frame-to-mesh
ICP, COLMAP on PV keyframes.
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from egograph.core.errors import InputError
from egograph.core.units import TICKS_PER_SECOND
from egograph.core.values import without_wall_clock
from egograph.geometry.hl2ss import invert_rigid
from egograph.poses.config import RefineConfig
from egograph.poses.constraints import Constraints, pv_columns, sigmas

SOURCES = ("hololens", "icp", "mesh", "colmap")


@dataclass
class RefinementGraph:
    """The refinement factors over PV pose keys, for the joint tracker mode or for solving.

    ``graph`` holds every factor; ``values`` the initial PV camera -> world poses (reported,
    keys ``symbol('x', i)``); ``frames`` the frame indices that have a variable;
    ``ahat_offsets[i]`` the AHAT camera -> PV camera transform (column 4x4) of frame i, so the
    AHAT camera -> world pose is ``x_i.compose(gtsam.Pose3(ahat_offsets[i]))``.
    """

    graph: object                    # gtsam.NonlinearFactorGraph
    values: object                   # gtsam.Values
    frames: np.ndarray
    ahat_offsets: np.ndarray
    constraints: list[Constraints]
    factor_counts: dict[str, int]
    stage_seconds: dict[str, float]
    stats: dict = field(default_factory=dict)
    initial: np.ndarray | None = None        # (N, 4, 4) column starting PV poses (spike-cleaned)
    world_initial: np.ndarray | None = None  # (N, 4, 4) column starting world corrections (None without hololens)
    points: object | None = None             # the AhatPointSource of the ICP stages (None without them)
    mesh: object | None = None               # the scene mesh the mesh ICP used
    spikes: np.ndarray | None = None         # (N,) bool: reported poses flagged as spikes

    def rebuild(self):
        """A fresh graph and starting values from the (possibly re-weighted) constraints."""
        from egograph.poses.graph import build_graph

        valid = np.zeros(len(self.initial), bool)
        valid[self.frames] = True
        graph, values, _ = build_graph(self.initial, valid, self.constraints, self.world_initial)
        return graph, values


@dataclass
class RefineResult:
    timestamps: np.ndarray
    pv_poses: np.ndarray             # (N, 4, 4) row-vector PV camera -> world, NaN where invalid
    depth_poses: np.ndarray          # (N, 4, 4) row-vector AHAT rig node -> world, NaN where invalid
    pv_valid: np.ndarray
    depth_valid: np.ndarray
    stage_seconds: dict[str, float]
    factor_counts: dict[str, int]
    stats: dict
    change: dict                     # how far the refinement moved the poses from the reported ones
    position_cov: np.ndarray | None = None   # (N, 3, 3) world-frame PV position covariance, m² (NaN: none)
    selfcheck: dict = field(default_factory=dict)   # held-out residuals, segments, what was kept and why
    solved_pv_poses: np.ndarray | None = None        # (N, 4, 4) row-vector: the solve before the no-harm rule
    colmap_model: dict | None = None  # refine.colmap: the bundle-adjusted model's files (name -> bytes), OUT/colmap/


# ------------------------------------------------------------------ HoloLens factors

def initial_poses(rec, cfg: RefineConfig) -> tuple[np.ndarray, np.ndarray]:
    """Starting PV poses (column (N, 4, 4)) and a spike mask.

    A reported pose that jumps away from the median of its +-5 valid neighbours by more than
    ``spike_trans`` (or ``spike_rot``) starts from the nearest non-spike frame instead, so
    that the optimiser does not start in the spike's local minimum; its HoloLens factor is
    then rejected by the robust kernel, not by this test.
    """
    pv = pv_columns(rec)
    idx = np.flatnonzero(rec.pv_valid)
    spike = np.zeros(len(rec), bool)
    if len(idx) >= 5:
        pos = pv[idx, :3, 3]
        half = 5
        pad = np.pad(pos, ((half, half), (0, 0)), mode="edge")
        win = np.lib.stride_tricks.sliding_window_view(pad, 2 * half + 1, axis=0)      # (M, 3, 11)
        med = np.median(win, axis=2)
        far = np.linalg.norm(pos - med, axis=1) > cfg.spike_trans
        # rotation against the frame whose position is nearest to the window median
        d = np.linalg.norm(win - med[:, :, None], axis=1)                              # (M, 11)
        ref = np.clip(np.arange(len(idx)) - half + d.argmin(axis=1), 0, len(idx) - 1)
        rel = np.einsum("nji,njk->nik", pv[idx, :3, :3], pv[idx[ref], :3, :3])
        ang = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
        spike[idx[far | (ang > cfg.spike_rot)]] = True
    init = pv.copy()
    good = np.flatnonzero(rec.pv_valid & ~spike)
    if spike.any() and len(good):
        for i in np.flatnonzero(spike):
            init[i] = pv[good[np.argmin(np.abs(good - i))]]
    return init, spike


def hololens_constraints(rec, cfg: RefineConfig) -> list[Constraints]:
    """The HoloLens error model as factors (valid PV frames only).

    With ``cfg.hololens``: ``reported_i = E_i · true_i`` with ``E_i`` a slowly drifting world
    error (random walk, occasional relocalisation jumps) times white jitter. Variables
    ``w_i = E_i⁻¹`` (world correction) and ``x_i`` (true PV pose):

    * jitter: ``BetweenFactor(w_i, x_i, reported_i)`` — ``w_i⁻¹ x_i ≈ reported_i`` (Cauchy);
    * drift: ``BetweenFactor(w_i, w_j, I)`` for consecutive valid frames, sigmas ``drift·sqrt(dt)``,
      loosened by the jump sigmas around the end of each fast head turn (where the HoloLens
      relocalises), Cauchy;
    * weak prior ``w_i ≈ I``.

    Without it, only the weak prior ``x_i ≈ reported_i`` (Cauchy) remains.
    """
    pv = pv_columns(rec)
    idx = np.flatnonzero(rec.pv_valid)
    n = len(idx)
    eye = np.tile(np.eye(4), (n, 1, 1))
    none = np.full(n, -1)
    prior_sig = sigmas(cfg.prior_sigma_rot, cfg.prior_sigma_trans, n)
    if not cfg.hololens:
        return [Constraints("prior", "absolute", idx, none, pv[idx], prior_sig, cfg.hololens_kernel)]
    out = [Constraints("hololens", "relative", idx, idx, pv[idx],
                       sigmas(cfg.hololens_sigma_rot, cfg.hololens_sigma_trans, n), cfg.hololens_kernel,
                       key_i="w", key_j="x"),
           Constraints("prior", "absolute", idx, none, eye, prior_sig, 0.0, key_i="w")]
    if n > 1:
        a, b = idx[:-1], idx[1:]
        dt = np.maximum((rec.timestamps[b] - rec.timestamps[a]) / TICKS_PER_SECOND, 1e-3)
        sig = sigmas(cfg.drift_rot, cfg.drift_trans, n - 1) * np.sqrt(dt)[:, None]
        loose = jump_links(pv[a], pv[b], dt, cfg)
        if cfg.jump_sigma_trans > 0 and loose.any():
            sig[loose] = np.sqrt(sig[loose] ** 2 + sigmas(cfg.jump_sigma_rot, cfg.jump_sigma_trans)[0] ** 2)
        tight = sigmas(cfg.drift_rot, cfg.drift_trans, n - 1) * np.sqrt(dt)[:, None]
        out.append(Constraints("drift", "relative", a, b, eye[:-1], sig, cfg.drift_kernel, key_i="w", key_j="w",
                               info={"jump_links": int(loose.sum()), "loose": loose, "tight_sigmas": tight}))
    return out


def jump_links(pa: np.ndarray, pb: np.ndarray, dt: np.ndarray, cfg: RefineConfig) -> np.ndarray:
    """Which consecutive-frame links (a -> b, column poses) may hold a relocalisation jump:
    within ``jump_window`` links of the end of a fast head turn (reported angular speed above
    ``jump_turn_rate``)."""
    rel = np.einsum("nji,njk->nik", pa[:, :3, :3], pb[:, :3, :3])
    ang = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    fast = ang / dt > cfg.jump_turn_rate
    ends = np.flatnonzero(fast[:-1] & ~fast[1:]) + 1
    loose = np.zeros(len(fast), bool)
    for e in ends:
        loose[max(0, e - cfg.jump_window):e + cfg.jump_window + 1] = True
    return loose


# ------------------------------------------------------------------ the graph

def _say(progress, msg: str) -> None:
    if progress:
        print(msg, flush=True)


def refinement_factors(rec, cfg: RefineConfig | None = None, progress: bool = False,
                       initial: np.ndarray | None = None, confirm_jumps_now: bool = True,
                       holdout: bool = False) -> RefinementGraph:
    """Every refinement factor of ``rec`` as one ``gtsam.NonlinearFactorGraph`` + initial ``gtsam.Values``.

    Keys: ``gtsam.symbol('x', i)`` = PV camera -> world ``Pose3`` of frame i (column
    convention, ``Pose3(pv_pose_row.T)``), for every frame with a valid reported PV pose;
    ``gtsam.symbol('w', i)`` = the HoloLens world correction of frame i (``x_i ≈ w_i ·
    reported_i``; only with ``cfg.hololens``). AHAT camera -> world is
    ``x_i.compose(gtsam.Pose3(result.ahat_offsets[i]))``.

    Two intermediate solves may run inside: the COLMAP stage triangulates with the poses
    solved from the other sources (``cfg.colmap``), and the jump test solves once to decide
    which relocalisation-jump candidates stay loose (``cfg.jump_confirm``); the returned
    ``values`` are then that first solution (a better start; the factors are the final
    ones). ``initial`` (N, 4, 4 column) overrides the starting poses of ICP/COLMAP
    (default: reported, spike-cleaned). Add more factors on the ``x`` keys (e.g. object
    landmarks) and solve with :func:`egograph.poses.graph.solve`. ``confirm_jumps_now=False``
    leaves the jump candidates loose, for a caller that tests them with more factors
    (:func:`confirm_jumps` on its own solution, then :meth:`RefinementGraph.rebuild`).
    ``holdout=True`` (with ``cfg.selfcheck``) keeps one mesh keyframe in ``cfg.selfcheck_every``
    out of the graph, for :mod:`egograph.poses.selfcheck`.
    """
    import gtsam  # noqa: F401  (fail early when missing)

    from egograph.poses.graph import build_graph, solve, values_to_columns

    cfg = cfg or RefineConfig()
    cfg.check()
    times: dict[str, float] = {}
    stats: dict = {}
    t = time.perf_counter()
    cons = hololens_constraints(rec, cfg)
    times["hololens"] = time.perf_counter() - t
    spike = None
    if initial is None:
        pv0, spike = initial_poses(rec, cfg)
        stats["spikes"] = int(spike.sum())
    else:
        pv0 = np.asarray(initial, dtype=np.float64)
    valid = rec.pv_valid & np.isfinite(pv0).all(axis=(1, 2))
    w0 = None
    if cfg.hololens:
        w0 = np.tile(np.eye(4), (len(rec), 1, 1))
    points = mesh = None
    if cfg.icp or cfg.mesh:
        t = time.perf_counter()
        mesh = rec.mesh() if (cfg.mesh or cfg.unwrap_with_mesh) else None
        from egograph.poses.points import AhatPointSource

        points = AhatPointSource.create(rec, cfg, mesh=mesh)
        times["setup"] = time.perf_counter() - t
    if cfg.icp:
        from egograph.poses.kiss import kiss_constraints

        t = time.perf_counter()
        c, st = kiss_constraints(rec, cfg, points, pv0, progress=progress)
        cons.append(c)
        stats["icp"] = st.__dict__
        times["icp"] = time.perf_counter() - t
        _say(progress, f"KISS-ICP: {len(c)} relative factors ({st.registered}/{st.frames} frames registered) "
                       f"in {times['icp']:.1f} s")
    if cfg.mesh:
        from egograph.poses.mesh_icp import mesh_constraints

        t = time.perf_counter()
        mcfg = cfg if holdout else dataclasses.replace(cfg, selfcheck=False)
        c, st = mesh_constraints(rec, mcfg, pv0, points, mesh, progress=progress)
        cons.append(c)
        stats["mesh"] = st.__dict__
        times["mesh"] = time.perf_counter() - t
        _say(progress, f"mesh ICP: {st.accepted}/{st.tried} keyframes accepted in {times['mesh']:.1f} s")
    if cfg.colmap:
        from egograph.poses.colmap import colmap_constraints

        t = time.perf_counter()
        g, v, _ = build_graph(pv0, valid, cons, w0)
        pre, _ = solve(g, v, cfg.max_iterations)
        times["solve_pre_colmap"] = time.perf_counter() - t
        t = time.perf_counter()
        c, st = colmap_constraints(rec, cfg, values_to_columns(pre, len(rec)), progress=progress)
        cons.append(c)
        stats["colmap"] = st
        times["colmap"] = time.perf_counter() - t
        _say(progress, f"COLMAP: {len(c)} relative factors in {times['colmap']:.1f} s")
    t = time.perf_counter()
    graph, values, counts = build_graph(pv0, valid, cons, w0)
    times["build"] = time.perf_counter() - t
    drift = [c for c in cons if c.source == "drift"]
    if confirm_jumps_now and cfg.jump_confirm and drift and drift[0].info["loose"].any():
        t = time.perf_counter()
        first, _ = solve(graph, values, cfg.max_iterations)
        stats["jumps"] = confirm_jumps(drift[0], first, cfg)
        graph, values, counts = build_graph(pv0, valid, cons, w0)
        values = first                       # start the final solve from the first one
        times["jump_test"] = time.perf_counter() - t
    from egograph.poses.constraints import ahat_offsets

    return RefinementGraph(graph, values, np.flatnonzero(valid), ahat_offsets(rec), cons, counts, times, stats,
                           pv0, w0, points, mesh, spike)


def confirm_jumps(drift: Constraints, values, cfg: RefineConfig) -> dict:
    """Tighten (in place) the loosened drift links whose estimated jump is below ``cfg.jump_confirm``."""
    import gtsam

    from egograph.poses.graph import world_key

    loose = drift.info["loose"]
    kept = groups = 0
    frames: list[list[int]] = []  # (first, last) frame of each confirmed jump's window
    idx = np.flatnonzero(loose)
    # consecutive loose links form one candidate (the window around one turn end): test the jump over it
    for grp in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
        groups += 1
        a = values.atPose3(world_key(drift.i[grp[0]]))
        b = values.atPose3(world_key(drift.j[grp[-1]]))
        d = a.between(b)
        big = np.linalg.norm(d.translation()) > cfg.jump_confirm[0] or \
            np.degrees(np.linalg.norm(gtsam.Rot3.Logmap(d.rotation()))) > cfg.jump_confirm[1]
        if big:
            kept += 1
            frames.append([int(drift.i[grp[0]]), int(drift.j[grp[-1]])])
        else:
            drift.sigmas[grp] = drift.info["tight_sigmas"][grp]
    return {"candidates": groups, "confirmed": kept, "frames": frames}


def refine_recording(rec, cfg: RefineConfig | None = None, progress: bool = False) -> RefineResult:
    """Refine the PV and AHAT poses of ``rec`` (nothing is written).

    With ``cfg.selfcheck`` (and mesh factors) held-out mesh keyframes decide per segment whether
    the refined or the input poses are output (:mod:`egograph.poses.selfcheck`); with
    ``cfg.covariance`` every frame gets the marginal position covariance (world frame, m²): the
    solve's where the refined pose is output, plus the outer product of the offset from the
    refined pose where the input (or a blend) is kept.
    """
    from egograph.poses.graph import solve, values_to_columns

    cfg = cfg or RefineConfig()
    rg = refinement_factors(rec, cfg, progress=progress, holdout=cfg.selfcheck)
    t = time.perf_counter()
    result, rep = solve(rg.graph, rg.values, cfg.max_iterations)
    rg.stage_seconds["solve"] = time.perf_counter() - t
    _say(progress, f"solved {rg.graph.size()} factors over {rg.values.size()} poses: error {rep['error_initial']:.1f} -> "
                   f"{rep['error_final']:.1f} in {rep['iterations']} iterations, {rep['seconds']:.1f} s")
    refined_col = values_to_columns(result, len(rec))
    cov = None
    if cfg.covariance:
        from egograph.poses.covariance import position_covariances

        t = time.perf_counter()
        cov = position_covariances(rg.graph, result, len(rec)) * cfg.covariance_scale
        rg.stage_seconds["covariance"] = time.perf_counter() - t
    pv_col, check = refined_col, {}
    if cfg.selfcheck:
        t = time.perf_counter()
        pv_col, check = apply_selfcheck(rec, cfg, rg, refined_col)
        rg.stage_seconds["selfcheck"] = time.perf_counter() - t
        _say(progress, f"self-check: {check['summary']}")
    if cov is not None and check.get("alpha") is not None:
        e = pv_col[:, :3, 3] - refined_col[:, :3, 3]            # the part of the refinement not applied
        cov = cov + np.where(np.isfinite(e)[:, :, None], e[:, :, None] * e[:, None, :], 0.0)
    pv_row = np.swapaxes(pv_col, 1, 2)
    depth_row, depth_valid = corrected_depth_poses(rec, pv_row)
    from egograph.poses.colmap import MODEL_KEY

    stats = dict(rg.stats, solver=rep)
    model = None
    if isinstance(stats.get("colmap"), dict) and MODEL_KEY in stats["colmap"]:
        stats["colmap"] = dict(stats["colmap"])
        model = stats["colmap"].pop(MODEL_KEY)   # files, not figures: OUT/colmap/, not report.json
    mesh = next((c for c in rg.constraints if c.source == "mesh"), None)
    if mesh is not None and "keyframes" in mesh.info:
        stats["mesh_keyframes"] = [dataclasses.asdict(k) for k in mesh.info["keyframes"]]
    return RefineResult(rec.timestamps.copy(), pv_row, depth_row, np.isfinite(pv_row).all(axis=(1, 2)), depth_valid,
                        rg.stage_seconds, rg.factor_counts, stats, pose_change(rec.pv_poses, pv_row), cov, check,
                        np.swapaxes(refined_col, 1, 2), model)


def apply_selfcheck(rec, cfg: RefineConfig, rg: RefinementGraph, refined_col: np.ndarray) -> tuple[np.ndarray, dict]:
    """The no-harm rule: output PV poses (column (N, 4, 4)) and the self-check's record.

    Without held-out keyframes (no mesh, or none with depth) no improvement can be shown and the
    input poses are kept everywhere (spikes excepted)."""
    from egograph.poses.selfcheck import blend_poses, blend_weights, decide_segments, holdout_residuals, seconds

    input_col = pv_columns(rec)
    mesh = next((c for c in rg.constraints if c.source == "mesh"), None)
    frames = mesh.info.get("held_out", np.zeros(0, int)) if mesh is not None else np.zeros(0, int)
    times = seconds(rec.timestamps)
    before = after = np.zeros(0)
    if len(frames) and rg.points is not None and rg.mesh is not None:
        from egograph.io.recording import mesh_raycasting_scene

        scene = mesh_raycasting_scene(rg.mesh)
        before, after = holdout_residuals(rg.points, scene, frames, rg.ahat_offsets, input_col, refined_col,
                                          cfg.selfcheck_truncate)
    else:
        frames = np.zeros(0, int)
    segments = decide_segments(times, frames, before, after, cfg)
    alpha = blend_weights(times, segments, cfg.selfcheck_blend)
    if rg.spikes is not None:
        alpha[rg.spikes] = 1.0                   # a reported spike is wrong without any ground truth
    out = blend_poses(input_col, refined_col, alpha)
    out[~np.isfinite(refined_col).all(axis=(1, 2))] = np.nan
    n_ref = sum(s.poses == "refined" for s in segments)
    covered = float(np.mean(alpha >= 1.0)) if len(alpha) else 0.0
    rb = float(np.sqrt(np.nanmean(before))) if np.isfinite(before).any() else float("nan")
    ra = float(np.sqrt(np.nanmean(after))) if np.isfinite(after).any() else float("nan")
    summary = (f"{n_ref} of {len(segments)} segments refined ({covered:.0%} of frames), "
               f"{len(segments) - n_ref} kept as input; held-out residual {rb * 1000:.1f} -> {ra * 1000:.1f} mm "
               f"over {int(np.isfinite(before).sum())} keyframes")
    return out, {"summary": summary, "helped": bool(n_ref > 0), "refined_share": covered,
                 "residual_input_m": rb, "residual_refined_m": ra,
                 "held_out": [{"frame": int(f), "input_m": float(np.sqrt(b)), "refined_m": float(np.sqrt(a))}
                              for f, b, a in zip(frames, before, after) if np.isfinite(b) and np.isfinite(a)],
                 "segments": [dataclasses.asdict(s) for s in segments], "alpha": alpha}


def world_corrections(rec, pv_refined_row: np.ndarray) -> np.ndarray:
    """Per frame the world-frame correction ``W_i = inv(reported_pv) @ refined_pv`` (row-vector,
    world -> world, so ``refined_pv = reported_pv @ W_i``). Frames without both poses take the
    nearest such frame's correction (identity everywhere when there is none)."""
    n = len(rec)
    ok = rec.pv_valid & np.isfinite(pv_refined_row).all(axis=(1, 2))
    w = np.tile(np.eye(4), (n, 1, 1))
    if not ok.any():
        return w
    w[ok] = invert_rigid(rec.pv_poses[ok]) @ pv_refined_row[ok]
    idx = np.flatnonzero(ok)
    near = idx[np.clip(np.searchsorted(idx, np.arange(n)), 0, len(idx) - 1)]
    prev = idx[np.clip(np.searchsorted(idx, np.arange(n)) - 1, 0, len(idx) - 1)]
    near = np.where(np.abs(prev - np.arange(n)) < np.abs(near - np.arange(n)), prev, near)
    return w[near]


def corrected_depth_poses(rec, pv_refined_row: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """AHAT rig poses moved by each frame's world-frame correction of the PV pose
    (:func:`world_corrections`): ``refined_depth = reported_depth @ W_i``."""
    n = len(rec)
    out = np.full((n, 4, 4), np.nan)
    if not (rec.pv_valid & np.isfinite(pv_refined_row).all(axis=(1, 2))).any():
        return out, np.zeros(n, bool)
    w = world_corrections(rec, pv_refined_row)
    dv = rec.depth_valid.copy()
    out[dv] = rec.depth_poses[dv] @ w[dv]
    return out, dv


def pose_change(before_row: np.ndarray, after_row: np.ndarray) -> dict:
    """Translation (m) and rotation (deg) moved per frame: RMS and max over frames valid in both."""
    from egograph.poses.metrics import pose_differences

    tr, rot = pose_differences(after_row, before_row)
    ok = np.isfinite(tr) & np.isfinite(rot)
    if not ok.any():
        return {"n": 0}
    return {"n": int(ok.sum()), "trans_rms_m": float(np.sqrt(np.mean(tr[ok] ** 2))), "trans_max_m": float(tr[ok].max()),
            "rot_rms_deg": float(np.sqrt(np.mean(rot[ok] ** 2))), "rot_max_deg": float(rot[ok].max())}


# ------------------------------------------------------------------ output

def write_refined(result: RefineResult, out: str | Path, rec, cfg: RefineConfig, extra: dict | None = None,
                  run_files: dict[str, str] | None = None) -> Path:
    """Write OUT/{pv_pose.json, depth_ahat_pose.json, pv_pose.tum, depth_ahat_pose.tum, report.json, report.md}
    (and OUT/colmap/ with refine.colmap: the bundle-adjusted model in COLMAP's text format) atomically, with ``run_files`` (name -> text: run record, configuration) in the same rename.
    Refuses to write into the recording's own folder."""
    from egograph.core.config import to_dict
    from egograph.io.atomic import atomic_dir
    from egograph.io.poses import write_pose_json
    from egograph.poses.tum import write_tum

    out = Path(out)
    o, seq = out.resolve(), rec.seq_dir.resolve()
    if o == seq or o in seq.parents:
        raise InputError(out, "refusing to overwrite the input recording (the output folder is replaced as a "
                              "whole); choose another --out folder")
    if (out / "pv").is_dir() or (out / "depth_ahat").is_dir() or (out / "calibrations").is_dir():
        raise InputError(out, "looks like a recording; refusing to replace it")
    report = without_wall_clock({"recording": str(rec.seq_dir), "frames": len(rec), "stages": list(result.stage_seconds),
                                 "factors": result.factor_counts, "change": result.change, "stats": result.stats,
                                 "config": to_dict(cfg),
                                 "selfcheck": {k: v for k, v in result.selfcheck.items() if k != "alpha"},
                                 **(extra or {})})
    with atomic_dir(out) as tmp:
        write_pose_json(tmp / "pv_pose.json", result.timestamps, _invalid_as_zero(result.pv_poses))
        write_pose_json(tmp / "depth_ahat_pose.json", result.timestamps, _invalid_as_zero(result.depth_poses))
        write_tum(tmp / "pv_pose.tum", result.timestamps, result.pv_poses)
        rig = np.where(result.depth_valid[:, None, None], result.depth_poses, np.nan)
        write_tum(tmp / "depth_ahat_pose.tum", result.timestamps, rig)
        if result.position_cov is not None:
            from egograph.poses.covariance import write_position_covariance

            write_position_covariance(tmp / "pv_position_covariance.json", result.timestamps, result.position_cov)
        (tmp / "report.json").write_text(json.dumps(report, indent=1, default=_jsonable))
        (tmp / "report.md").write_text(report_markdown(report))
        if result.colmap_model:
            (tmp / "colmap").mkdir()
            for name, data in result.colmap_model.items():
                (tmp / "colmap" / name).write_bytes(data)
        for name, text in (run_files or {}).items():
            (tmp / name).write_text(text)
    return out


def _invalid_as_zero(poses: np.ndarray) -> np.ndarray:
    """hl2ss marks a frame without tracking with an all-zero pose (``M[3,3] == 0``)."""
    ok = np.isfinite(poses).all(axis=(1, 2))
    return np.where(ok[:, None, None], poses, 0.0)


def _jsonable(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if dataclasses.is_dataclass(o):
        return dataclasses.asdict(o)
    return str(o)


def report_markdown(report: dict) -> str:
    lines = [f"# Pose refinement of {report['recording']}", "", f"{report['frames']} frames; stages: "
             f"{', '.join(report['stages'])} (their times are printed by `egograph refine`, not written, so that "
             f"two runs write the same bytes).", ""]
    lines += ["| factors | count |", "|---|---|"] + [f"| {k} | {v} |" for k, v in report["factors"].items()]
    ch = report["change"]
    if ch.get("n"):
        lines += ["", f"Change against the reported PV poses: translation RMS {ch['trans_rms_m'] * 1000:.1f} mm "
                      f"(max {ch['trans_max_m'] * 1000:.1f} mm), rotation RMS {ch['rot_rms_deg']:.3f} deg "
                      f"(max {ch['rot_max_deg']:.3f} deg)."]
    if report.get("stretches"):
        from egograph.poses.stretches import stretches_markdown

        lines += stretches_markdown(report["stretches"], report.get("largest_move") or {})
    sc = report.get("selfcheck") or {}
    if sc.get("segments"):
        lines += ["", f"Self-check (mesh residual of keyframes held out of the solve): {sc['summary']}.", "",
                  "| segment (s) | held-out | residual input (mm) | residual refined (mm) | poses | why |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {g['start_s']:.0f}-{g['end_s']:.0f} | {g['held_out']} | {g['residual_input_m'] * 1000:.1f} | "
                  f"{g['residual_refined_m'] * 1000:.1f} | {g['poses']} | {g['reason']} |" for g in sc["segments"]]
    for name in ("eval_reported", "eval_refined"):
        if name in report:
            e = report[name]
            lines += [f"{name.replace('_', ' ')} vs synth_gt: ATE {e['ate_rmse_m'] * 100:.2f} cm "
                      f"(aligned {e['ate_rmse_aligned_m'] * 100:.2f} cm), RPE {e['rpe_trans_m'] * 1000:.2f} mm / "
                      f"{e['rpe_rot_deg']:.3f} deg"]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ using refined poses

def apply_poses(rec, poses_dir: str | Path):
    """A copy of ``rec`` whose ``pv_poses``/``depth_poses`` come from ``poses_dir`` (as ``egograph refine`` writes).

    ``poses_dir/pv_pose.json`` is required; ``depth_ahat_pose.json`` is optional (without it
    the recording's AHAT poses are kept). Timestamps must equal the recording's (same set);
    anything else is an :class:`InputError` naming the file. Frames invalid in the file
    (all-zero / NaN pose) become invalid.
    """
    from egograph.io.poses import read_pose_json

    d = Path(poses_dir)
    if not d.is_dir():
        raise InputError(d, "not a folder of refined poses (expected pv_pose.json inside)")
    pv_file = d / "pv_pose.json"
    ts, pv, pv_ok = read_pose_json(pv_file, "skip")
    pv = _align_to(rec, ts, pv, pv_ok, pv_file)
    new = dataclasses.replace(rec, pv_poses=pv[0], pv_valid=pv[1])
    depth_file = d / "depth_ahat_pose.json"
    if depth_file.is_file():
        dts, dp, d_ok = read_pose_json(depth_file, "skip")
        dp, dv = _align_to(rec, dts, dp, d_ok, depth_file)
        new = dataclasses.replace(new, depth_poses=dp, depth_valid=dv)
    return new


def _align_to(rec, ts: np.ndarray, poses: np.ndarray, ok: np.ndarray, path: Path) -> tuple[np.ndarray, np.ndarray]:
    want = np.asarray(rec.timestamps, dtype=np.int64)
    if len(ts) != len(want) or not np.array_equal(ts, want):
        missing = np.setdiff1d(want, ts)
        extra = np.setdiff1d(ts, want)
        parts = []
        if len(missing):
            parts.append(f"{len(missing)} recording timestamp(s) missing (first {missing[0]})")
        if len(extra):
            parts.append(f"{len(extra)} timestamp(s) not in the recording (first {extra[0]})")
        raise InputError(path, "timestamps do not match the recording " + rec.name + ": " + "; ".join(parts))
    return np.where(ok[:, None, None], poses, np.nan), ok.copy()
