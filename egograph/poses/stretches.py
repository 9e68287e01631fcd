"""The refinement report per stretch of time: which sources constrained it, how far the poses moved,
and (with ground truth) the error before and after; and what moved most, and why.

A stretch is a segment of the self-check (``refine.selfcheck_segment`` seconds), or that grid when
the self-check is off. Frames are PV frame indices; distances are metres, times seconds from the
first frame.
"""

from __future__ import annotations

import numpy as np

NEAR_S = 2.0  # a mesh keyframe or a confirmed jump this close in time "explains" a frame's move


def stretch_bounds(n_frames: int, ts_s: np.ndarray, selfcheck: dict, segment_s: float) -> list[tuple[int, int]]:
    """(first, last) frame of each stretch: the self-check's segments, else a ``segment_s`` grid."""
    segs = (selfcheck or {}).get("segments") or []
    if segs:
        return [(int(g["first"]), int(g["last"])) for g in segs]
    cell = np.floor((ts_s - ts_s[0]) / max(segment_s, 1e-9)).astype(int)
    cuts = np.flatnonzero(np.diff(cell)) + 1
    starts = np.concatenate([[0], cuts])
    ends = np.concatenate([cuts - 1, [n_frames - 1]])
    return list(zip(starts.tolist(), ends.tolist()))


def _rms(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x ** 2))) if len(x) else None


def stretch_rows(ts_s: np.ndarray, bounds: list[tuple[int, int]], moved_m: np.ndarray, keyframes: list[dict],
                 jump_frames: list[list[int]], err_input_m: np.ndarray | None = None, err_refined_m: np.ndarray | None = None) -> list[dict]:
    """One row per stretch: mesh keyframes accepted / tried there (held-out ones aside) and their median constrained
    directions (of 6), confirmed relocalisation jumps, how far the output poses moved from the input
    (median and max), and with truth the camera-centre RMSE of input and output over the stretch."""
    keyframes = [k for k in keyframes if k["outcome"] != "held_out"]  # those are the self-check's
    kf = np.array([k["frame"] for k in keyframes], dtype=int) if keyframes else np.zeros(0, int)
    ok = np.array([k["outcome"] == "accepted" for k in keyframes], dtype=bool) if keyframes else np.zeros(0, bool)
    strong = np.array([k.get("strong", 0) or 0 for k in keyframes], dtype=float) if keyframes else np.zeros(0)
    rows = []
    for first, last in bounds:
        inside = (kf >= first) & (kf <= last)
        m = moved_m[first:last + 1]
        m = m[np.isfinite(m)]
        row = {"start_s": float(ts_s[first]), "end_s": float(ts_s[last]), "first": int(first), "last": int(last),
               "mesh_tried": int(inside.sum()), "mesh_accepted": int((inside & ok).sum()),
               "mesh_strong_median": float(np.median(strong[inside & ok])) if (inside & ok).any() else None,
               "jumps": [int(a) for a, b in jump_frames if first <= b and a <= last],
               "moved_median_m": float(np.median(m)) if len(m) else None,
               "moved_max_m": float(m.max()) if len(m) else None}
        if err_input_m is not None and err_refined_m is not None:
            row["ate_input_m"] = _rms(err_input_m[first:last + 1])
            row["ate_refined_m"] = _rms(err_refined_m[first:last + 1])
        rows.append(row)
    return rows


def largest_move(ts_s: np.ndarray, moved_m: np.ndarray, keyframes: list[dict], jump_frames: list[list[int]]) -> dict:
    """The frame whose pose moved most, and the nearest explanation: a confirmed relocalisation
    jump within ``NEAR_S`` (or the frame lies after one), accepted mesh keyframes within ``NEAR_S``
    (the mesh pulled it), or neither (the drift model carried a correction from farther away)."""
    if not np.isfinite(moved_m).any():
        return {}
    f = int(np.nanargmax(moved_m))
    t = float(ts_s[f])
    out = {"frame": f, "t_s": t, "moved_m": float(moved_m[f])}
    near_jumps = [int(a) for a, b in jump_frames if ts_s[a] - NEAR_S <= t <= ts_s[b] + NEAR_S]
    kf = [k for k in keyframes if k["outcome"] == "accepted" and abs(float(ts_s[k["frame"]]) - t) <= NEAR_S]
    if near_jumps:
        out["why"] = f"a relocalisation jump confirmed at {ts_s[near_jumps[0]]:.1f} s"
    elif kf:
        out["why"] = f"mesh ICP: {len(kf)} accepted keyframes within {NEAR_S:g} s pulled it"
    else:
        out["why"] = f"no accepted mesh keyframe or confirmed jump within {NEAR_S:g} s: drift carried from farther away"
    return out


def stretches_markdown(rows: list[dict], biggest: dict) -> list[str]:
    """Lines of the report: the stretch table and the largest move."""
    truth = any("ate_input_m" in r for r in rows)
    head = "| stretch (s) | mesh keyframes (accepted / tried) | directions | jumps | moved median / max (mm) |"
    rule = "|---|---|---|---|---|"
    if truth:
        head += " ATE input -> refined (cm) |"
        rule += "---|"
    lines = ["", "Sources per stretch (directions: median of the 6 that an accepted mesh keyframe constrains):", "",
             head, rule]
    f = lambda v, k: "-" if v is None else f"{v * k:.1f}"  # noqa: E731
    for r in rows:
        d = "-" if r["mesh_strong_median"] is None else f"{r['mesh_strong_median']:.0f}"
        s = (f"| {r['start_s']:.0f}-{r['end_s']:.0f} | {r['mesh_accepted']} / {r['mesh_tried']} | {d} | "
             f"{len(r['jumps']) or '-'} | {f(r['moved_median_m'], 1000)} / {f(r['moved_max_m'], 1000)} |")
        if truth:
            s += f" {f(r.get('ate_input_m'), 100)} -> {f(r.get('ate_refined_m'), 100)} |"
        lines.append(s)
    if biggest:
        lines += ["", f"Largest move: {biggest['moved_m'] * 1000:.1f} mm at {biggest['t_s']:.1f} s (frame "
                      f"{biggest['frame']}): {biggest['why']}."]
    return lines
