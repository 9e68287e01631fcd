"""Step ``export``: a recording and a tracker's results in files other tools open.

Writes one folder, committed by one rename:

* ``intervals.ply``: one vertex per position interval at its centre (world frame, metres),
  coloured by instance, with the properties ``instance``, ``t_start``/``t_end`` (seconds from the
  first PV frame), ``sigma_m`` and ``confidence``; Open3D and MeshLab read it as a point cloud;
* ``pv_reported.tum``: the recording's PV camera poses (camera -> world) as a TUM trajectory,
  timestamps in seconds of the HoloLens clock; ``pv_true.tum`` too when the recording carries its
  synthetic truth, so ``evo_ape tum pv_true.tum pv_reported.tum -a`` runs directly;
* ``recording.rrd`` (``rrd=True``, needs the ``viewer`` extra, ``rerun-sdk``): the mesh, the camera
  path and its pose over time, the AHAT points of every ``key_every``-th frame in the world frame,
  the tracker's predictions per frame and its intervals (each shown from its start to its end),
  all on one ``time`` timeline (seconds from the first PV frame);
* ``config.yaml``, ``egograph.json``: the resolved configuration and the run record.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from egograph.core.errors import InputError
from egograph.core.resources import require
from egograph.core.units import TICKS_PER_SECOND
from egograph.io.atomic import atomic_dir
from egograph.io.recording import Recording
from egograph.steps import outputs

PLY_FILE = "intervals.ply"
RRD_FILE = "recording.rrd"

# Instance colours (Okabe-Ito, colour-blind safe), cycled; 8-bit RGB.
PALETTE = np.array([(230, 159, 0), (86, 180, 233), (0, 158, 115), (240, 228, 66), (0, 114, 178), (213, 94, 0),
                    (204, 121, 167), (0, 0, 0)], np.uint8)


@dataclass
class ExportOutput:
    """What the step wrote: ``folder``, ``files`` name -> what it holds, ``notes`` (parts left out)."""

    folder: Path
    files: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def intervals_ply_text(intervals, t0: int) -> str:
    """ASCII PLY of interval centres (see the module doc); ``t0`` is the first PV frame's ticks."""
    rows = []
    for iv in intervals:
        r, g, b = PALETTE[iv.instance % len(PALETTE)]
        ts, te = (iv.t_start - t0) / TICKS_PER_SECOND, (iv.t_end - t0) / TICKS_PER_SECOND
        x, y, z = iv.xyz
        rows.append(f"{x!r} {y!r} {z!r} {r} {g} {b} {iv.instance} {ts!r} {te!r} {iv.sigma_m!r} {iv.confidence!r}")
    header = ["ply", "format ascii 1.0", "comment egograph position intervals: world frame, metres; t_start/t_end "
              "in seconds from the first PV frame", f"element vertex {len(rows)}",
              "property double x", "property double y", "property double z",
              "property uchar red", "property uchar green", "property uchar blue",
              "property int instance", "property double t_start", "property double t_end",
              "property double sigma_m", "property double confidence", "end_header"]
    return "\n".join(header + rows) + "\n"


def _true_pv_poses(rec: Recording) -> tuple[np.ndarray, np.ndarray] | None:
    gt = rec.synth_gt_dir
    if gt is None or not (gt / "pv_pose.json").is_file():
        return None
    from egograph.io.poses import read_pose_json

    ts, poses, ok = read_pose_json(gt / "pv_pose.json")
    poses = np.array(poses, np.float64)
    poses[~ok] = np.nan
    return ts, poses


def _pv_poses_nan(rec: Recording) -> np.ndarray:
    p = np.array(rec.pv_poses, np.float64)
    p[~rec.pv_valid] = np.nan
    return p


def export(rec: Recording, results: str | Path, out: str | Path, cfg, *, rrd: bool = False, key_every: int = 30,
           overwrite: bool = False) -> ExportOutput | None:
    """Write the export folder ``out`` for tracker results ``results`` on ``rec`` (see the module
    doc). ``key_every``: PV frames between the depth frames whose AHAT points go into the ``.rrd``.
    An ``out`` already holding this exact export is left as it is (returns None) unless ``overwrite``."""
    from egograph.poses.tum import write_tum
    from egograph.steps.track import read_result

    res = Path(results)
    if not res.is_dir():
        raise InputError(res, "results folder not found" if not res.exists() else "not a results folder (a file)")
    if key_every < 1:
        raise InputError(res, f"key_every must be at least 1, got {key_every}")
    rr = require("rerun", "viewer", "egograph export --rrd") if rrd else None
    result = read_result(res, rec)
    if not any(result.per_frame.values()) and not result.intervals:  # an empty export replaces no good one
        raise InputError(res, f"no prediction for any PV frame of {rec.seq_dir}: nothing to export ({out} left "
                              "as it is)")
    record = outputs.run_record("export", cfg, {"recording": outputs.recording_digest(rec),
                                                "results": outputs.folder_digest(res), "rrd": rrd,
                                                "key_every": key_every})
    if outputs.up_to_date(Path(out), record, overwrite):
        return None
    t0 = int(rec.timestamps[0])
    done = ExportOutput(Path(out))
    intervals = result.intervals
    if intervals is None:
        done.notes.append(f"{res}: no intervals.json (a per-frame tracker): {PLY_FILE} has no vertices")
        intervals = []
    truth = _true_pv_poses(rec)
    with atomic_dir(out) as tmp:
        (tmp / PLY_FILE).write_text(intervals_ply_text(intervals, t0))
        done.files[PLY_FILE] = f"{len(intervals)} interval centres"
        write_tum(tmp / "pv_reported.tum", rec.timestamps, _pv_poses_nan(rec))
        done.files["pv_reported.tum"] = f"{int(rec.pv_valid.sum())} reported PV poses"
        if truth is not None:
            write_tum(tmp / "pv_true.tum", truth[0], truth[1])
            done.files["pv_true.tum"] = f"{int(np.isfinite(truth[1][:, 0, 0]).sum())} true PV poses (synth_gt)"
        if rr is not None:
            counts = write_rrd(rr, tmp / RRD_FILE, rec, result, intervals, key_every, done.notes)
            done.files[RRD_FILE] = ", ".join(f"{v} {k}" for k, v in counts.items())
        outputs.write_run_files(tmp, record, cfg)
    for note in done.notes:
        warnings.warn(note, stacklevel=2)
    return done


def two_sigma_ellipsoid(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 2-sigma ellipsoid of a 3x3 covariance (m^2): half-axis lengths (m, at least 1 mm) along its
    principal axes, and the rotation taking the x, y, z axes onto them as a quaternion ``x y z w``."""
    from egograph.poses.tum import quat_from_matrix

    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    if np.linalg.det(v) < 0:  # a rotation, not a reflection
        v[:, 2] = -v[:, 2]
    return 2 * np.sqrt(np.clip(w, 1e-6 / 4, None)), quat_from_matrix(v[None])[0]


def _seconds(rec: Recording, ts: int) -> float:
    return (int(ts) - int(rec.timestamps[0])) / TICKS_PER_SECOND


def write_rrd(rr, path: Path, rec: Recording, result, intervals, key_every: int, notes: list[str]) -> dict[str, int]:
    """The ``.rrd`` of the module doc; returns how many of each kind of thing it logged.
    Entities: ``world/mesh``, ``world/camera_path``, ``world/camera`` (pose over time),
    ``world/depth`` (key frames), ``world/predictions/<instance>``, ``world/intervals/<instance>``."""
    from egograph.geometry.hl2ss import camera_center
    from egograph.poses.config import RefineConfig
    from egograph.poses.points import AhatPointSource

    stream = rr.RecordingStream("egograph", recording_id=f"egograph-{rec.name}")
    stream.save(str(path))
    counts = {"mesh triangles": 0, "camera poses": 0, "depth key frames": 0, "predictions": 0, "intervals": 0}
    # the HoloLens world is y up; rerun shows the right-handed y-up frame as it is
    stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Y_UP, static=True)
    if rec.mesh_paths():
        mesh = rec.mesh()
        v, f = np.asarray(mesh.vertices, np.float32), np.asarray(mesh.triangles, np.uint32)
        stream.log("world/mesh", rr.Mesh3D(vertex_positions=v, triangle_indices=f), static=True)
        counts["mesh triangles"] = len(f)
    else:
        notes.append(f"{rec.seq_dir / 'mesh'}: no mesh: the .rrd has none")
    centres = camera_center(rec.pv_poses)[rec.pv_valid]
    if len(centres) > 1:
        stream.log("world/camera_path", rr.LineStrips3D([centres.astype(np.float32)]), static=True)
    source = AhatPointSource.create(rec, RefineConfig(unwrap_with_mesh=bool(rec.mesh_paths())))
    by_ts = result.per_frame
    for i, ts in enumerate(rec.timestamps):
        stream.set_time("time", duration=_seconds(rec, ts))
        if rec.pv_valid[i]:
            m = np.asarray(rec.pv_poses[i])  # row-vector camera -> world: rotation rows, translation row 3
            stream.log("world/camera", rr.Transform3D(translation=m[3, :3], mat3x3=m[:3, :3].T))
            counts["camera poses"] += 1
        if i % key_every == 0 and rec.depth_valid[i]:
            pts = source.points(i)
            if pts is not None and len(pts):
                a2w = source.ahat_to_world(i)
                world = pts @ a2w[:3, :3] + a2w[3, :3]
                stream.log("world/depth", rr.Points3D(world.astype(np.float32), radii=0.005))
                counts["depth key frames"] += 1
        for p in by_ts.get(int(ts), ()):
            stream.log(f"world/predictions/{p.instance}", rr.Points3D([p.xyz], radii=0.03,
                                                                     colors=[PALETTE[p.instance % len(PALETTE)]]))
            counts["predictions"] += 1
    for iv in intervals:
        ent = f"world/intervals/{iv.instance}"
        half, quat = two_sigma_ellipsoid(np.asarray(iv.covariance, np.float64))
        stream.set_time("time", duration=_seconds(rec, iv.t_start))
        stream.log(ent, rr.Ellipsoids3D(centers=[iv.xyz], half_sizes=[half], quaternions=[rr.Quaternion(xyzw=quat)],
                                        colors=[PALETTE[iv.instance % len(PALETTE)]]))
        stream.set_time("time", duration=_seconds(rec, iv.t_end))
        stream.log(ent, rr.Clear(recursive=False))
        counts["intervals"] += 1
    stream.flush()
    stream.disconnect()
    return counts
