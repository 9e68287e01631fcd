"""A person-readable summary of a recording (``egograph info``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from egograph.core.errors import InputError
from egograph.geometry.ahat_model import ahat_model_summary
from egograph.io.annotations import load_annotations, read_mvpe_photos
from egograph.io.detections import read_detection_dir
from egograph.io.poses import read_pose_json
from egograph.io.recording import Lookup, Recording, check_ply, locate_mvpe, locate_svoe, report_problem
from egograph.io.textio import iter_lines, split_fields
from egograph.poses.metrics import error_summary, pose_differences
from egograph.steps.lift import warn_missing_detection_files
from egograph.steps.recording import labels as recording_labels
from egograph.synth.truth import NEVER_VISIBLE_SHARE, never_visible_intervals


def ply_face_count(path: Path) -> int:
    """Faces declared in a PLY file's header (``element face N``) of a file whose body is as long as
    the header says (:func:`~egograph.io.recording.check_ply`), without building the mesh;
    InputError "unreadable PLY" naming the file otherwise."""
    return check_ply(path).get("face", 0)


def mesh_triangle_count(rec: Recording) -> tuple[int | None, Lookup]:
    """Triangles of the recording's mesh files and the mesh's :class:`Lookup`; PLY files are checked
    and their headers read directly (``info`` stays light), other formats go through Open3D. None
    without a mesh or when a mesh file is unreadable (warned, naming it; refused under ``rec.strict``)."""
    folder = rec.seq_dir / "mesh"
    tried = [f"{folder}/*.{{ply,obj,stl,off}}"]
    paths = rec.mesh_paths()
    if not paths:
        return None, Lookup("scene mesh", None, tried, "no mesh (refine uses the depth frames alone)")
    try:
        if all(p.suffix.lower() == ".ply" for p in paths):
            count = sum(ply_face_count(p) for p in paths)
        else:
            count = len(rec.mesh().triangles)
    except InputError as err:
        report_problem(rec.strict, err.path, f"{err.message}; the mesh is left out")
        return None, Lookup("scene mesh", None, tried, f"unreadable: {err}", problem=True)
    return count, Lookup("scene mesh", folder, tried, f"{count} triangles in {len(paths)} file(s)")


def false_detection_count(path: Path) -> tuple[int, int]:
    """``(false, total)`` detections of a synthetic truth file ``synth_gt/<seq>/detections_<set>.txt``
    (rows ``ts instance is_false ...``, is_false 0 or 1); InputError naming the file and line."""
    false = total = 0
    for n, line in iter_lines(path):
        tok = split_fields(line)
        if len(tok) < 3 or tok[2] not in ("0", "1"):
            raise InputError(path, "expected ts instance is_false (0 or 1) ...", n)
        false += tok[2] == "1"
        total += 1
    return false, total


def enrollment_lookups(rec: Recording, labels: list[str] | None) -> tuple[Lookup, Lookup]:
    """Where the SVOE boxes and MVPE photos of ``rec`` are (``io.svoe_dir`` / ``io.mvpe_dir`` first);
    each not found is warned about naming what was tried (refused when ``rec.strict``)."""
    svoe = locate_svoe(rec.seq_dir, rec.annotation_dir, rec.svoe_dir or None)
    if svoe.found is None:
        report_problem(rec.strict, rec.seq_dir, "no SVOE enrollment (svoe.txt) found; tried " + ", ".join(svoe.tried)
                       + "; set io.svoe_dir")
    mvpe = locate_mvpe(rec.seq_dir, labels, rec.mvpe_dir or None)
    if mvpe.found is None:
        report_problem(rec.strict, rec.seq_dir, "no MVPE photos (<instance_name>/*.jpg) found; tried "
                       + ", ".join(mvpe.tried) + "; set io.mvpe_dir")
    return svoe, mvpe


def summarize(rec: Recording, depth_samples: int = 5, cfg=None) -> dict:
    """Frames, duration, instances, intervals, detections, depth validity, what inputs were found
    where and what was not (``inputs``), the fit of every candidate calibration folder when it was
    scored (``calibration_fit``; ``cfg`` gives the fit test's knobs) and, for synthetic recordings,
    the error of the reported poses against ``synth_gt/``."""
    out: dict = {
        "sequence": rec.name,
        "frames": len(rec),
        "duration_s": float(rec.times_s[-1]) if len(rec) else 0.0,
        "pv_frames_on_disk": len(rec._pv_files.files) if rec._pv_files is not None else 0,
        "depth_frames_on_disk": len(set(rec._depth_files.values())),
        "invalid_pv_poses": int((~rec.pv_valid).sum()),
        "invalid_depth_poses": int((~rec.depth_valid).sum()),
        "depth_factor": rec.depth_factor,
        "alias_m": rec.ahat.alias_m,
        "calibration": str(rec.calibration_dir),
        "mesh_triangles": None,
    }
    out["mesh_triangles"], mesh_lookup = mesh_triangle_count(rec)
    # the lens as its ray table has it (intrinsics.bin is a wide viewing pinhole, not the lens)
    out["ahat"] = ahat_model_summary(rec.ahat).to_dict()
    idx = np.linspace(0, len(rec) - 1, min(depth_samples, len(rec))).astype(int)
    shares = [float((d > 0).mean()) for d in (rec.depth_raw(int(i)) for i in idx) if d is not None]
    out["depth_valid_share"] = float(np.mean(shares)) if shares else None
    lookups = list(rec.lookups) + [mesh_lookup]
    labels = recording_labels(rec)
    svoe, mvpe = enrollment_lookups(rec, labels)  # MVPE photos are found by instance name
    if rec.annotation_dir is not None:
        ann = load_annotations(rec.annotation_dir, svoe_path=svoe.found)
        out["instances"] = ann.labels
        out["intervals"] = len(ann.centers)
        out["intervals_per_instance"] = {name: sum(1 for c in ann.centers if c.instance == i)
                                         for i, name in enumerate(ann.labels)}
        out["box_annotations"] = sum(len(v) for v in ann.boxes.values())
        out["svoe_enrolled"] = len(ann.svoe)
        if svoe.found is not None:
            svoe.note = f"{len(ann.svoe)} boxes for {len({e.instance for e in ann.svoe})} of {len(labels)} instances"
    if mvpe.found is not None:
        photos = read_mvpe_photos(mvpe.found)
        if labels:
            missing = [name for name in labels if not photos.get(name)]
            photos = {name: photos.get(name, []) for name in labels}
            mvpe.note = f"{sum(1 for v in photos.values() if v)} of {len(labels)} instances have photos"
            if missing:
                mvpe.note += f" (none for {', '.join(missing[:5])})"
                mvpe.problem = True
                report_problem(rec.strict, mvpe.found, f"no MVPE photos for {len(missing)} of {len(labels)} "
                                                       f"instances ({', '.join(missing[:5])}); tried "
                                                       f"{mvpe.found}/<instance_name>/*.jpg")
        out["mvpe_photos"] = {k: len(v) for k, v in photos.items()}
    lookups += [svoe, mvpe]
    sets = rec.detection_sets()
    if sets:
        out["detections"] = {}
        for name, d in sets.items():
            per_frame = read_detection_dir(d, rec.timestamps)
            warn_missing_detection_files(rec, per_frame.scan)
            out["detections"][name] = sum(len(v) for v in per_frame.values())
    lookups.append(Lookup("detections", next(iter(sets.values())).parent if sets else None,
                          [f"{b}/detections/{rec.name}/<set>/" for b in (rec.seq_dir.parent, rec.seq_dir.parent.parent)]
                          + [f"{rec.seq_dir}/detections/<set>/"], ", ".join(sets) if sets else
                          "none carried by the recording (pass --detections DIR to lift/track)"))
    out["inputs"] = [lk.to_json() for lk in lookups]
    fit = getattr(rec, "calibration_fit", None)
    if fit is not None and cfg is not None:
        out["calibration_fit"] = fit.to_json(cfg.calib_fit)
    gt = rec.synth_gt_dir
    if gt is not None:
        gt_ts, true_pv, _ = read_pose_json(gt / "pv_pose.json")
        # frames of the recording without a pose are not in rec: compare the frames both have
        _, i, j = np.intersect1d(rec.timestamps, gt_ts, return_indices=True)
        trans, rot = pose_differences(rec.pv_poses[i], true_pv[j])
        out["pose_error_vs_truth"] = error_summary(trans, rot)
        false_counts = {}
        for f in sorted(gt.glob("detections_*.txt")):
            false_counts[f.stem.removeprefix("detections_")] = false_detection_count(f)
        out["false_detections"] = {k: {"false": a, "total": b, "share": a / b if b else 0.0}
                                   for k, (a, b) in false_counts.items()}
        if (gt / "intervals.json").is_file() and (gt / "instances.npz").is_file():
            never, total = never_visible_intervals(rec)
            out["intervals_never_visible"] = {"count": never, "total": total,
                                              "share": never / total if total else 0.0,
                                              "min_visible_share": NEVER_VISIBLE_SHARE}
    return out


def print_summary(summary: dict, console=None, inputs: bool = True) -> None:
    """The summary table and, with ``inputs``, the table of inputs found and not found."""
    from rich.console import Console
    from rich.table import Table

    console = console or Console()
    t = Table(title=f"recording {summary['sequence']}", show_header=False)
    t.add_column("what", style="bold")
    t.add_column("value")
    t.add_row("frames", f"{summary['frames']} ({summary['duration_s']:.1f} s; {summary['pv_frames_on_disk']} PV png, "
                        f"{summary['depth_frames_on_disk']} AHAT png)")
    t.add_row("invalid poses", f"PV {summary['invalid_pv_poses']}, AHAT {summary['invalid_depth_poses']}")
    dv = summary.get("depth_valid_share")
    t.add_row("AHAT depth", f"raw unit {summary['depth_factor']:g} mm, alias {summary['alias_m']:.3f} m, "
                            f"valid pixels {dv * 100:.1f} %" if dv is not None else "no readable depth")
    lens = summary.get("ahat")
    if lens:
        t.add_row("AHAT lens", f"field of view {lens['fov_across_deg']:.0f}° x {lens['fov_down_deg']:.0f}°, focal "
                               f"{lens['focal_px'][0]:.0f} px at the centre, {lens['pixels_without_ray']} pixels "
                               "without a ray")
    t.add_row("mesh", f"{summary['mesh_triangles']} triangles" if summary["mesh_triangles"] else "none")
    if "instances" in summary:
        per = summary["intervals_per_instance"]
        t.add_row("instances", ", ".join(f"{k} ({v})" for k, v in per.items()))
        t.add_row("stationary intervals", f"{summary['intervals']} (box annotations {summary['box_annotations']}, "
                                          f"SVOE enrolled {summary['svoe_enrolled']})")
    if "mvpe_photos" in summary:
        t.add_row("MVPE photos", f"{sum(summary['mvpe_photos'].values())} for {len(summary['mvpe_photos'])} instances")
    for name, n in summary.get("detections", {}).items():
        extra = ""
        fd = summary.get("false_detections", {}).get(name)
        if fd:
            extra = f" ({fd['false']} false, {fd['share'] * 100:.1f} %)"
        t.add_row(f"detections {name}", f"{n}{extra}")
    nv = summary.get("intervals_never_visible")
    if nv:
        t.add_row("never visible (truth)", f"{nv['count']} of {nv['total']} true intervals never "
                                           f"{nv['min_visible_share'] * 100:.0f} % visible ({nv['share'] * 100:.1f} %)")
    pe = summary.get("pose_error_vs_truth")
    if pe and pe.get("n"):
        t.add_row("reported PV pose error", f"translation RMSE {pe['trans_rmse_m'] * 100:.1f} cm (max {pe['trans_max_m'] * 100:.1f}), "
                                            f"rotation RMSE {pe['rot_rmse_deg']:.2f}° (max {pe['rot_max_deg']:.2f})")
    console.print(t)
    if summary.get("calibration_fit"):
        print_calibration_fit(summary["calibration_fit"], console)
    if inputs:
        print_inputs(summary.get("inputs", []), console)


def print_calibration_fit(fit: dict, console) -> None:
    """Every candidate calibration folder's fit score, the one used marked (``summary["calibration_fit"]``)."""
    from rich.markup import escape
    from rich.table import Table

    if not fit["candidates"]:
        console.print(f"calibration fit: {escape(fit.get('note') or 'not scored')}")
        return
    t = Table(title=f"calibration fit: mean distance of AHAT depth edges to PV edges on {fit['frames']} frames "
                    "(lower fits better)")
    for col in ("", "folder", "score px", "spread", "best shift px", "fits"):
        t.add_column(col, overflow="fold" if col == "folder" else "ellipsis")
    for c in fit["candidates"]:
        mark = "used" if c["used"] else ""
        if c["by_number"] and not fit["explicit"]:
            mark += (" " if mark else "") + "(by number)"
        shift = ", ".join(f"{v:.0f}" for v in c["offset_px"])
        t.add_row(mark, escape(c["folder"]), f"{c['score_px']:.2f}", f"{c['spread_px']:.2f}",
                  f"({shift}) -{c['offset_gain_px']:.2f}", "yes" if c["fits"] else "NO")
    console.print(t)
    if fit.get("switched"):
        console.print("the folder named by the sequence's number fits clearly worse: the best-fitting one is used")


def print_inputs(inputs: list[dict], console) -> None:
    """What was found where, and what was not with the paths tried (``summary["inputs"]``)."""
    from rich.markup import escape
    from rich.table import Table

    t = Table(title="inputs: found / not found", show_header=True)
    t.add_column("input", style="bold")
    t.add_column("", width=3)
    t.add_column("where (or what was tried)", overflow="fold")
    for item in inputs:
        mark = "ok" if item["found"] and not item["problem"] else ("!" if item["found"] else "--")
        where = item["found"] or "not found; tried " + ", ".join(item["tried"])
        t.add_row(item["what"], mark, escape(where + (f" ({item['note']})" if item["note"] else "")))
    console.print(t)
