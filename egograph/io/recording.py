"""Open an IT3DEgo recording (sequence folder) with its calibration and annotations.

Layout of a recording *root* as ``egograph synth`` writes it (a real IT3DEgo download
fits the same lookup rules)::

    ROOT/calibrations/{rm_depth_ahat,personal_video}/*.bin
    ROOT/<seq>/pv/<ts>.png  depth_ahat/<ts>.png  pv_pose.json  depth_ahat_pose.json  mesh/*.ply
    ROOT/annotations/<seq>/labels.csv ...     (or <seq>/annotations/)
    ROOT/detections/<seq>/<set>/<ts>.txt      (per-frame association files, e.g. set = svoe, mvpe)
    ROOT/mvpe/<seq>/<instance_name>/*.jpg     (multi-view pre-enrollment photos)
    ROOT/synth_gt/<seq>/...                   (synthetic truth only)

``REC`` on the command line may be the root (holding one sequence) or the sequence folder.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from egograph.core.errors import InputError
from egograph.core.units import TICKS_PER_SECOND
from egograph.io.calibration import (
    AhatCalibration,
    PvCalibration,
    find_calibration_dir,
    read_ahat_calibration,
    read_pv_calibration,
)
from egograph.io.poses import read_pose_json


def mesh_raycasting_scene(mesh):
    """An Open3D ``RaycastingScene`` of a legacy triangle mesh (world frame, metres): ray casts
    (``t_hit`` in metres along unit rays) and closest points; None without a mesh or triangles.

    The one builder of the scene mesh's ray-casting scene; :meth:`Recording.mesh_scene` caches it.
    """
    if mesh is None or len(mesh.triangles) == 0:
        return None
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return scene


def check_depth_png(path: str | Path, img: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A decoded AHAT depth PNG as (H, W) uint16 raw depth, or InputError naming the file.

    The calibration's ray table fixes the size (``shape``, rows x columns: 512 x 512); the
    sensor's raw values need 16 bits. An 8-bit image (a preview, a normalised export) or one of
    another size is not AHAT depth: reading it as depth would give wrong points, not missing ones.
    """
    if img.ndim != 2:
        raise InputError(path, f"not an AHAT depth image: {img.shape[2] if img.ndim == 3 else img.ndim} "
                               f"channels (expected one channel, 16-bit {shape[1]}x{shape[0]})")
    if img.dtype != np.uint16:
        raise InputError(path, f"not an AHAT depth image: {img.dtype} pixels (expected 16-bit raw depth, "
                               f"{shape[1]}x{shape[0]})")
    if img.shape != tuple(shape):
        raise InputError(path, f"not an AHAT depth image: {img.shape[1]}x{img.shape[0]} pixels (the calibration "
                               f"gives {shape[1]}x{shape[0]})")
    return img


def is_sequence_dir(path: Path) -> bool:
    return (path / "pv_pose.json").is_file()


def find_sequence_dir(path: str | Path, sequence: str | None = None) -> Path:
    """Resolve ``REC`` (a sequence folder, or a root holding sequences) to one sequence folder."""
    path = Path(path)
    if not path.exists():
        raise InputError(path, "recording not found")
    if is_sequence_dir(path):
        return path
    if sequence is not None:
        cand = path / sequence
        if is_sequence_dir(cand):
            return cand
        raise InputError(cand, "no pv_pose.json: not a sequence folder")
    seqs = sorted(p for p in path.iterdir() if p.is_dir() and is_sequence_dir(p))
    if len(seqs) == 1:
        return seqs[0]
    if not seqs:
        raise InputError(path, "neither a sequence folder (pv_pose.json) nor a root holding one")
    raise InputError(path, f"holds {len(seqs)} sequences ({', '.join(p.name for p in seqs[:5])}...); name one")


def list_sequence_dirs(path: str | Path) -> list[Path]:
    """Every sequence folder under a root (or the folder itself), sorted by name."""
    path = Path(path)
    if is_sequence_dir(path):
        return [path]
    return sorted(p for p in path.iterdir() if p.is_dir() and is_sequence_dir(p))


def find_annotation_dir(seq_dir: Path, explicit: str | Path | None = None) -> Path | None:
    """Annotations of a sequence: given, ``<seq>/annotations``, or ``<root>/annotations/<seq>``.

    The reference code also names annotation folders by replacing "raw" with "annotation"
    in the sequence name; that spelling is accepted too.
    """
    if explicit is not None:
        p = Path(explicit)
        if (p / "labels.csv").is_file():
            return p
        if (p / seq_dir.name / "labels.csv").is_file():
            return p / seq_dir.name
        raise InputError(p, "no labels.csv: not an annotation folder")
    names = [seq_dir.name, seq_dir.name.replace("raw", "annotation")]
    cands = [seq_dir / "annotations"]
    for base in [seq_dir.parent, seq_dir.parent.parent]:
        cands += [base / "annotations" / n for n in names]
    for c in cands:
        if (c / "labels.csv").is_file():
            return c
    return None


@dataclass
class Recording:
    """One HoloLens 2 sequence: timestamps, poses, calibration, lazy frames.

    Poses are row-vector 4x4 (sensor -> world, metres); invalid frames hold NaN and
    ``*_valid`` is False there. ``depth_factor`` is the raw AHAT unit (4 = 4 mm units as
    in the hl2ss version IT3DEgo used, 1 = mm); ``None`` at open time means detect it.
    """

    seq_dir: Path
    timestamps: np.ndarray           # (N,) int64, 100 ns ticks, sorted numerically
    pv_poses: np.ndarray             # (N, 4, 4) PV camera -> world
    pv_valid: np.ndarray             # (N,) bool
    depth_poses: np.ndarray          # (N, 4, 4) AHAT rig node -> world (at the AHAT capture time)
    depth_valid: np.ndarray          # (N,) bool
    ahat: AhatCalibration
    pv: PvCalibration
    calibration_dir: Path
    annotation_dir: Path | None
    depth_factor: float = 4.0
    _index: dict = field(default_factory=dict, repr=False)
    # Built on first use, keyed by sequence folder. ``dataclasses.replace`` copies (other poses, same
    # folder and mesh) share the dict, so lifting and tracking on them build the scene once.
    _mesh_scenes: dict = field(default_factory=dict, repr=False, compare=False)

    # ------------------------------------------------------------ opening
    @classmethod
    def open(cls, path: str | Path, *, sequence: str | None = None, calibration: str | Path | None = None,
             annotations: str | Path | None = None, invalid_poses: str = "error",
             depth_factor: float | None = None) -> "Recording":
        seq_dir = find_sequence_dir(path, sequence)
        ts, pv_poses, pv_valid = read_pose_json(seq_dir / "pv_pose.json", invalid_poses)
        depth_file = seq_dir / "depth_ahat_pose.json"
        if depth_file.is_file():
            dts, dposes, dvalid = read_pose_json(depth_file, invalid_poses)
            pos = {int(t): i for i, t in enumerate(dts)}
            depth_poses = np.full_like(pv_poses, np.nan)
            depth_valid = np.zeros(len(ts), bool)
            for i, t in enumerate(ts):
                j = pos.get(int(t))
                if j is not None and dvalid[j]:
                    depth_poses[i] = dposes[j]
                    depth_valid[i] = True
        else:
            depth_poses = np.full_like(pv_poses, np.nan)
            depth_valid = np.zeros(len(ts), bool)
        calib_dir = find_calibration_dir(seq_dir, calibration)
        rec = cls(
            seq_dir=seq_dir, timestamps=ts, pv_poses=pv_poses, pv_valid=pv_valid,
            depth_poses=depth_poses, depth_valid=depth_valid,
            ahat=read_ahat_calibration(calib_dir / "rm_depth_ahat"),
            pv=read_pv_calibration(calib_dir / "personal_video"),
            calibration_dir=calib_dir, annotation_dir=find_annotation_dir(seq_dir, annotations),
        )
        rec._index = {int(t): i for i, t in enumerate(ts)}
        rec.depth_factor = depth_factor if depth_factor is not None else rec.detect_depth_factor()
        return rec

    # ------------------------------------------------------------ basics
    @property
    def name(self) -> str:
        return self.seq_dir.name

    @property
    def root(self) -> Path:
        """The folder holding the sequence (where annotations/, detections/, synth_gt/ live)."""
        return self.seq_dir.parent

    def __len__(self) -> int:
        return len(self.timestamps)

    @property
    def times_s(self) -> np.ndarray:
        """Seconds since the first frame."""
        return (self.timestamps - self.timestamps[0]) / TICKS_PER_SECOND

    def index_of(self, ts: int) -> int:
        try:
            return self._index[int(ts)]
        except KeyError:
            raise KeyError(f"{self.name}: no frame with timestamp {ts}") from None

    # ------------------------------------------------------------ frames (lazy)
    def pv_path(self, i: int) -> Path:
        return self.seq_dir / "pv" / f"{int(self.timestamps[i])}.png"

    def depth_path(self, i: int) -> Path:
        return self.seq_dir / "depth_ahat" / f"{int(self.timestamps[i])}.png"

    def rgb(self, i: int) -> np.ndarray | None:
        """PV frame i as (720, 1280, 3) uint8 RGB, or None when missing/unreadable."""
        p = self.pv_path(i)
        if not p.is_file():
            return None
        img = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if img is None:
            warnings.warn(f"{p}: unreadable image, treated as missing", stacklevel=2)
            return None
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)

    def depth_raw(self, i: int) -> np.ndarray | None:
        """AHAT raw depth of frame i (512, 512) uint16, or None ("no depth") when missing or not a
        decodable image (warned); InputError when it decodes to anything but 16-bit, one channel,
        the calibration's size (:func:`check_depth_png`)."""
        p = self.depth_path(i)
        if not p.is_file():
            return None
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is None:
            warnings.warn(f"{p}: unreadable depth image, treated as no depth", stacklevel=2)
            return None
        return check_depth_png(p, img, self.ahat.shape)

    def detect_depth_factor(self, samples: int = 5) -> float:
        """Guess the raw AHAT unit from data: wrapped ranges ≤ ~1.06 m read ≤ ~264 in 4 mm units.

        Returns 4.0 when the 99.9th percentile of the sampled raw values is ≤ 300, else 1.0.
        Without readable depth the IT3DEgo value (4.0) is kept.
        """
        idx = np.linspace(0, len(self) - 1, min(samples, len(self))).astype(int)
        vals = []
        for i in idx:
            d = self.depth_raw(int(i))
            if d is not None and (d > 0).any():
                vals.append(d[d > 0])
        if not vals:
            return 4.0
        return 4.0 if np.percentile(np.concatenate(vals), 99.9) <= 300 else 1.0

    # ------------------------------------------------------------ mesh
    def mesh_paths(self) -> list[Path]:
        d = self.seq_dir / "mesh"
        if not d.is_dir():
            return []
        return sorted(p for p in d.iterdir() if p.suffix.lower() in (".ply", ".obj", ".stl", ".off"))

    def mesh(self):
        """The HoloLens scene mesh (all files under ``mesh/`` merged) as an Open3D TriangleMesh, or None."""
        import open3d as o3d

        paths = self.mesh_paths()
        if not paths:
            return None
        out = o3d.geometry.TriangleMesh()
        for p in paths:
            m = o3d.io.read_triangle_mesh(str(p))
            if len(m.triangles) == 0:
                raise InputError(p, "mesh has no triangles")
            out += m
        return out

    def mesh_scene(self):
        """The ray-casting scene of :meth:`mesh` (:func:`mesh_raycasting_scene`), or None without a
        mesh; built on the first call (importing Open3D then), the same object afterwards. A mesh
        that cannot be read raises on every call (nothing is cached)."""
        key = self.seq_dir
        if key not in self._mesh_scenes:
            self._mesh_scenes[key] = mesh_raycasting_scene(self.mesh())
        return self._mesh_scenes[key]

    # ------------------------------------------------------------ companions
    def detections_dir(self, name: str) -> Path:
        """Folder of per-frame detections: a path, or a set name carried by the recording."""
        p = Path(name)
        if p.is_dir():
            return p
        for cand in [self.root / "detections" / self.name / name, self.seq_dir / "detections" / name]:
            if cand.is_dir():
                return cand
        raise InputError(p, "neither a folder of detection files nor a detection set of this recording")

    @property
    def synth_gt_dir(self) -> Path | None:
        d = self.root / "synth_gt" / self.name
        return d if d.is_dir() else None
