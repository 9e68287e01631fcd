"""A person-readable summary of a recording (``egograph info``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from egograph.io.annotations import load_annotations, read_mvpe_photos
from egograph.io.detections import read_detection_dir
from egograph.io.poses import read_pose_json
from egograph.io.recording import Recording
from egograph.poses.metrics import error_summary, pose_differences


def ply_face_count(path: Path) -> int | None:
    """Faces declared in a PLY file's header (``element face N``), without reading the mesh; None
    when the file is not a readable PLY."""
    try:
        with open(path, "rb") as f:
            if f.readline().strip() != b"ply":
                return None
            for _ in range(200):
                line = f.readline()
                if not line or line.strip() == b"end_header":
                    break
                parts = line.split()
                if parts[:2] == [b"element", b"face"] and len(parts) == 3:
                    return int(parts[2])
    except (OSError, ValueError):
        return None
    return 0


def mesh_triangle_count(rec: Recording) -> int | None:
    """Triangles of the recording's mesh files; PLY headers are read directly (``info`` stays light),
    other formats through Open3D. None without a mesh."""
    paths = rec.mesh_paths()
    if not paths:
        return None
    counts = [ply_face_count(p) if p.suffix.lower() == ".ply" else None for p in paths]
    if any(c is None for c in counts):
        mesh = rec.mesh()
        return None if mesh is None else len(mesh.triangles)
    return sum(counts)


def summarize(rec: Recording, depth_samples: int = 5) -> dict:
    """Frames, duration, instances, intervals, detections, depth validity and, for synthetic
    recordings, the error of the reported poses against ``synth_gt/``."""
    out: dict = {
        "sequence": rec.name,
        "frames": len(rec),
        "duration_s": float(rec.times_s[-1]) if len(rec) else 0.0,
        "pv_frames_on_disk": sum(1 for _ in (rec.seq_dir / "pv").glob("*.png")) if (rec.seq_dir / "pv").is_dir() else 0,
        "depth_frames_on_disk": sum(1 for _ in (rec.seq_dir / "depth_ahat").glob("*.png"))
        if (rec.seq_dir / "depth_ahat").is_dir() else 0,
        "invalid_pv_poses": int((~rec.pv_valid).sum()),
        "invalid_depth_poses": int((~rec.depth_valid).sum()),
        "depth_factor": rec.depth_factor,
        "alias_m": rec.ahat.alias_m,
        "calibration": str(rec.calibration_dir),
        "mesh_triangles": None,
    }
    out["mesh_triangles"] = mesh_triangle_count(rec)
    idx = np.linspace(0, len(rec) - 1, min(depth_samples, len(rec))).astype(int)
    shares = [float((d > 0).mean()) for d in (rec.depth_raw(int(i)) for i in idx) if d is not None]
    out["depth_valid_share"] = float(np.mean(shares)) if shares else None
    if rec.annotation_dir is not None:
        ann = load_annotations(rec.annotation_dir)
        out["instances"] = ann.labels
        out["intervals"] = len(ann.centers)
        out["intervals_per_instance"] = {name: sum(1 for c in ann.centers if c.instance == i)
                                         for i, name in enumerate(ann.labels)}
        out["box_annotations"] = sum(len(v) for v in ann.boxes.values())
        out["svoe_enrolled"] = len(ann.svoe)
    mvpe = rec.root / "mvpe" / rec.name
    if mvpe.is_dir():
        photos = read_mvpe_photos(mvpe)
        out["mvpe_photos"] = {k: len(v) for k, v in photos.items()}
    det_root = rec.root / "detections" / rec.name
    if det_root.is_dir():
        out["detections"] = {}
        for d in sorted(p for p in det_root.iterdir() if p.is_dir()):
            per_frame = read_detection_dir(d, rec.timestamps)
            out["detections"][d.name] = sum(len(v) for v in per_frame.values())
    gt = rec.synth_gt_dir
    if gt is not None:
        gt_ts, true_pv, _ = read_pose_json(gt / "pv_pose.json")
        # frames of the recording without a pose are not in rec: compare the frames both have
        _, i, j = np.intersect1d(rec.timestamps, gt_ts, return_indices=True)
        trans, rot = pose_differences(rec.pv_poses[i], true_pv[j])
        out["pose_error_vs_truth"] = error_summary(trans, rot)
        false_counts = {}
        for f in sorted(gt.glob("detections_*.txt")):
            rows = [line.split() for line in f.read_text().splitlines() if line and not line.startswith("#")]
            false_counts[f.stem.removeprefix("detections_")] = (sum(int(r[2]) for r in rows), len(rows))
        out["false_detections"] = {k: {"false": a, "total": b, "share": a / b if b else 0.0}
                                   for k, (a, b) in false_counts.items()}
    return out


def print_summary(summary: dict, console=None) -> None:
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
    pe = summary.get("pose_error_vs_truth")
    if pe and pe.get("n"):
        t.add_row("reported PV pose error", f"translation RMSE {pe['trans_rmse_m'] * 100:.1f} cm (max {pe['trans_max_m'] * 100:.1f}), "
                                            f"rotation RMSE {pe['rot_rmse_deg']:.2f}° (max {pe['rot_max_deg']:.2f})")
    console.print(t)
