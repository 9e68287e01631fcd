"""Open an IT3DEgo recording (sequence folder) with its calibration and annotations.

Layout of a recording *root* as ``egograph synth`` writes it::

    ROOT/calibrations/{rm_depth_ahat,personal_video}/*.bin
    ROOT/<seq>/pv/<ts>.png  depth_ahat/<ts>.png  pv_pose.json  depth_ahat_pose.json  mesh/*.ply
    ROOT/annotations/<seq>/labels.csv ...     (or <seq>/annotations/)
    ROOT/detections/<seq>/<set>/<ts>.txt      (per-frame association files, e.g. set = svoe, mvpe)
    ROOT/mvpe/<seq>/<instance_name>/*.jpg     (multi-view pre-enrollment photos)
    ROOT/synth_gt/<seq>/...                   (synthetic truth only)

The IT3DEgo release and its notebooks lay the same files out differently; every variant is read
without flags::

    DATA/raw_video_seqs/<seq>/...             REC may be DATA (one sequence) or DATA/raw_video_seqs/<seq>
    DATA/annotations/<seq>/ or Annotations/<seq>/ or annotations/<seq with raw->annotation>/
    .../label.csv                             as well as labels.csv
    DATA/calibrations/calibrations_vid1_17/   one calibration folder per group of recordings (or
                                              DATA/calibrations_vid1_17/); the group whose name's
                                              range holds the sequence's number is taken
    DATA/<tree>/<seq>/svoe.txt                SVOE enrollment in its own tree (any <tree>, 1-2 levels)
    DATA/<tree>/<instance_name>/instance_image_*.jpg   MVPE photos, one folder for all sequences
    <seq>/pv/frame_<ts>.png                   frames named with a prefix (any non-digit prefix)
    depth_ahat_pose.json keyed by AHAT times  joined to PV frames by nearest timestamp (io.depth_sync_ms)
    all-zero poses (untracked frames)         skipped with a warning and a count (io.invalid_poses)

Whatever expected input is missing or partly unusable is warned about naming the paths and
patterns tried (``strict``: refused); ``Recording.lookups`` keeps what was found and tried, and
``egograph info`` lists it. ``REC`` on the command line may be the root (holding one sequence),
a dataset root holding a folder of sequences, or the sequence folder.
"""

from __future__ import annotations

import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from egograph.core.errors import InputError
from egograph.core.units import TICKS_PER_SECOND
from egograph.io.annotations import LABELS_FILE, LABELS_FILES, SVOE_FILE, ci_child, find_labels_file
from egograph.io.calibration import (
    AhatCalibration,
    PvCalibration,
    find_calibration_dir,
    read_ahat_calibration,
    read_pv_calibration,
)
from egograph.io.poses import interpolate_poses, read_pose_json


MIN_FRAME_STEP_S = 1e-3
"""The shortest median step between PV frames a HoloLens recording can have (its PV camera runs
at 15-60 fps: steps of 16-67 ms); shorter steps are frame numbers or other units, not 100 ns ticks."""


def check_hololens_ticks(ts: np.ndarray, path: Path) -> None:
    """Refuse PV timestamps that cannot be HoloLens 100 ns ticks (frame numbers, milliseconds): a
    median step between frames under :data:`MIN_FRAME_STEP_S`."""
    if len(ts) < 10:  # a hand-made test sequence of a few keys proves nothing either way
        return
    step = float(np.median(np.diff(ts))) / TICKS_PER_SECOND
    if step < MIN_FRAME_STEP_S:
        raise InputError(path, f"timestamps {int(ts[0])}, {int(ts[1])}, ... are {step * 1e3:.4g} ms apart "
                               "(median): not HoloLens 100 ns ticks (e.g. 133400700000000000, 333333 apart at "
                               "30 fps); frame numbers or other units?")


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


_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
_PLY_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
_PLY_HEADER_LINES = 10000   # more header lines than any mesh writer makes: not a PLY header


@dataclass
class PlyElement:
    """One ``element NAME COUNT`` of a PLY header and its properties: ``(name, dtype)`` for a
    scalar, ``(name, (count dtype, item dtype))`` for a list (numpy dtype codes without byte order)."""

    name: str
    count: int
    properties: list = field(default_factory=list)


def _ply_header(path: Path, data: bytes) -> tuple[str, list[PlyElement], int]:
    """``(format, elements, body offset)`` of a PLY file's bytes; InputError when the header is
    not a PLY header."""
    def bad(why: str) -> InputError:
        return InputError(path, f"unreadable PLY: {why}")

    if not data.startswith(b"ply"):
        raise bad("no 'ply' magic at the start" + (" (empty file)" if not data else ""))
    end = data.find(b"end_header")
    if end < 0:
        raise bad("the header has no end_header line (file truncated?)")
    body = data.find(b"\n", end)
    if body < 0:
        raise bad("the file ends after end_header (no data)" if data[end:].strip() == b"end_header"
                  else "the end_header line is not ended")
    try:
        lines = data[:end].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise bad("the header is not ASCII text") from None
    if len(lines) > _PLY_HEADER_LINES:
        raise bad(f"a header of {len(lines)} lines")
    fmt = None
    elements: list[PlyElement] = []
    for n, line in enumerate(lines[1:], 2):
        parts = line.split()
        if not parts or parts[0] in ("comment", "obj_info"):
            continue
        if parts[0] == "format" and len(parts) == 3 and parts[1] in _PLY_FORMATS:
            fmt = parts[1]
        elif parts[0] == "element" and len(parts) == 3 and parts[2].isdigit():
            elements.append(PlyElement(parts[1], int(parts[2])))
        elif parts[0] == "property" and elements and len(parts) == 3 and parts[1] in _PLY_TYPES:
            elements[-1].properties.append((parts[2], _PLY_TYPES[parts[1]]))
        elif (parts[0] == "property" and elements and len(parts) == 5 and parts[1] == "list"
              and parts[2] in _PLY_TYPES and parts[3] in _PLY_TYPES and _PLY_TYPES[parts[2]][0] in "iu"):
            elements[-1].properties.append((parts[4], (_PLY_TYPES[parts[2]], _PLY_TYPES[parts[3]])))
        else:
            raise bad(f"header line {n} is not PLY: {line[:60]!r}")
    if fmt is None:
        raise bad("no 'format ascii|binary_little_endian|binary_big_endian 1.0' line")
    return fmt, elements, body + 1


def _ply_binary_end(path: Path, data: bytes, order: str, elements: list[PlyElement], offset: int) -> None:
    """InputError when a binary PLY body is shorter than its header declares. Lists are walked:
    when every row of an element holds as many items as its first (triangles), all rows are
    checked at once; otherwise row by row."""
    size = len(data)
    for el in elements:
        scalars_only = all(isinstance(t, str) for _, t in el.properties)
        if scalars_only:
            row = sum(np.dtype(t).itemsize for _, t in el.properties)
            need = offset + el.count * row
            if need > size:
                raise InputError(path, f"unreadable PLY: truncated: {el.count} {el.name} rows of {row} bytes need "
                                       f"{need} bytes, the file has {size}")
            offset = need
            continue
        fields = []  # one dtype per property, lists with the item count of the first row
        pos = offset
        for _, t in el.properties:
            if isinstance(t, str):
                fields.append(np.dtype(order + t))
                pos += fields[-1].itemsize
                continue
            ct, it = np.dtype(order + t[0]), np.dtype(order + t[1])
            if el.count == 0:
                break
            if pos + ct.itemsize > size:
                raise InputError(path, f"unreadable PLY: truncated in the first {el.name} row")
            k = int(np.frombuffer(data, ct, 1, pos)[0])
            fields.append((ct, k, it))
            pos += ct.itemsize + k * it.itemsize
        if el.count == 0:
            continue
        row = sum(f.itemsize if isinstance(f, np.dtype) else f[0].itemsize + f[1] * f[2].itemsize for f in fields)
        fits = min(el.count, (size - offset) // row) if row else el.count
        uniform, at = True, 0
        for f in fields:
            if isinstance(f, np.dtype):
                at += f.itemsize
                continue
            ct, k, it = f
            view = np.ndarray((fits,), ct, data, offset + at, (row,)) if fits else np.zeros(0, ct)
            uniform &= bool((view == k).all())
            at += ct.itemsize + k * it.itemsize
        if uniform and fits == el.count:
            offset += el.count * row
            continue
        start = fits if uniform else 0  # rows before ``start`` are known to be ``row`` bytes each
        offset += start * row
        for r in range(start, el.count):
            for f in fields:
                if isinstance(f, np.dtype):
                    offset += f.itemsize
                    continue
                ct, _, it = f
                if offset + ct.itemsize > size:
                    raise InputError(path, f"unreadable PLY: truncated: the file ends in {el.name} row {r + 1} "
                                           f"of {el.count} ({size} bytes)")
                k = int(np.frombuffer(data, ct, 1, offset)[0])
                if k < 0:
                    raise InputError(path, f"unreadable PLY: {el.name} row {r + 1} has a list of {k} items")
                offset += ct.itemsize + k * it.itemsize
            if offset > size:
                raise InputError(path, f"unreadable PLY: truncated: the file ends in {el.name} row {r + 1} "
                                       f"of {el.count} ({size} bytes)")


def check_ply(path: str | Path) -> dict[str, int]:
    """Element counts (``{"vertex": V, "face": F, ...}``) of a PLY file whose header parses and
    whose body is as long as the header says (binary: byte for byte, lists walked; ASCII: a line
    per row at least), or InputError "unreadable PLY" naming the file: Open3D reads a broken PLY
    as an empty or partial mesh with a warning on stderr, never an error."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except IsADirectoryError:
        raise InputError(path, "unreadable PLY: a folder, not a mesh file") from None
    except OSError as err:
        raise InputError(path, f"unreadable PLY: {err.strerror or err}") from None
    fmt, elements, offset = _ply_header(path, data)
    if fmt == "ascii":
        rows = sum(el.count for el in elements)
        lines = sum(1 for ln in data[offset:].splitlines() if ln.strip())
        if lines < rows:
            raise InputError(path, f"unreadable PLY: truncated: the header declares {rows} rows, the file has "
                                   f"{lines} data lines")
    else:
        _ply_binary_end(path, data, _PLY_FORMATS[fmt], elements, offset)
    return {el.name: el.count for el in elements}


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


# --------------------------------------------------------------------------- looking inputs up


@dataclass
class Lookup:
    """Where one input of a recording was looked for: ``found`` (None: not found), the paths or
    patterns ``tried`` in order, and a ``note`` (counts, what was partly unusable)."""

    what: str
    found: Path | None
    tried: list[str] = field(default_factory=list)
    note: str = ""
    problem: bool = False   # missing or partly unusable (warned, or refused under strict)

    def to_json(self) -> dict:
        return {"what": self.what, "found": str(self.found) if self.found is not None else None,
                "tried": list(self.tried), "note": self.note, "problem": self.problem}


def report_problem(strict: bool, path: str | Path, message: str) -> None:
    """An expected input missing or partly unusable: a warning naming ``path`` (what was tried is in
    ``message``), or under ``strict`` an InputError (one line, CLI exit 2)."""
    if strict:
        raise InputError(path, message + " (--strict / io.strict)")
    warnings.warn(f"{path}: {message}", stacklevel=3)


def _tried_text(tried: list[str], n: int = 8) -> str:
    more = f" and {len(tried) - n} more" if len(tried) > n else ""
    return ", ".join(tried[:n]) + more


COMPANION_DIRS = {"synth_gt", "annotations", "detections", "mvpe", "results"}
"""Folders beside the sequences that are never searched for sequences (lower case)."""


def is_sequence_dir(path: Path) -> bool:
    return (path / "pv_pose.json").is_file()


def _child_dirs(path: Path) -> list[Path]:
    try:
        return sorted(p for p in path.iterdir() if p.is_dir() and not p.name.startswith("."))
    except OSError:
        return []


def _sequences_in(path: Path) -> list[Path]:
    """Sequence folders directly in ``path``; when there are none, those one level down (a dataset
    root holding ``raw_video_seqs/<seq>/`` and ``annotations/``)."""
    seqs = [p for p in _child_dirs(path) if is_sequence_dir(p)]
    if seqs:
        return seqs
    # not into the companions of a sequence: synth_gt/<seq>/ holds a pv_pose.json (the true poses)
    return [s for c in _child_dirs(path) if c.name.lower() not in COMPANION_DIRS
            for s in _child_dirs(c) if is_sequence_dir(s)]


def find_sequence_dir(path: str | Path, sequence: str | None = None) -> Path:
    """Resolve ``REC`` to one sequence folder (the one holding ``pv_pose.json``): the folder itself,
    a root holding sequences, or a dataset root holding a folder of them (``raw_video_seqs/``)."""
    path = Path(path)
    if not path.exists():
        raise InputError(path, "recording not found")
    if is_sequence_dir(path):
        return path
    if sequence is not None:
        cands = [path / sequence] + [c / sequence for c in _child_dirs(path)]
        for cand in cands:
            if is_sequence_dir(cand):
                return cand
        raise InputError(path / sequence, f"no sequence folder (with pv_pose.json) named {sequence}; tried "
                                          + _tried_text([str(c) for c in cands]))
    seqs = _sequences_in(path)
    if len(seqs) == 1:
        return seqs[0]
    if not seqs:
        raise InputError(path, "neither a sequence folder (pv_pose.json) nor a root holding one (tried "
                               f"{path}/pv_pose.json, {path}/*/pv_pose.json, {path}/*/*/pv_pose.json)")
    raise InputError(path, f"holds {len(seqs)} sequences ({', '.join(p.name for p in seqs[:5])}...); "
                           f"name one with --sequence")


def list_sequence_dirs(path: str | Path) -> list[Path]:
    """Every sequence folder under a root (or the folder itself), sorted by name."""
    path = Path(path)
    if is_sequence_dir(path):
        return [path]
    return _sequences_in(path)


def dataset_bases(seq_dir: Path) -> list[Path]:
    """Folders companions of a sequence may sit in: its parent (the root ``egograph synth`` writes,
    or ``raw_video_seqs/``) and the parent's parent (the release's dataset root)."""
    return [seq_dir.parent, seq_dir.parent.parent]


def annotation_names(seq_dir: Path) -> list[str]:
    """Names an annotation (or enrollment) folder of a sequence may have: the sequence's own, and as
    the reference code spells it, "raw" replaced by "annotation"."""
    return list(dict.fromkeys([seq_dir.name, seq_dir.name.replace("raw", "annotation")]))


def locate_annotations(seq_dir: Path, explicit: str | Path | None = None) -> Lookup:
    """The annotation folder of a sequence (one holding ``labels.csv`` or ``label.csv``): given
    (the folder, or a folder holding ``<seq>/``), ``<seq>/annotations``, or
    ``<base>/annotations/<name>`` for each of :func:`dataset_bases` (``Annotations/`` too) and
    :func:`annotation_names`. An explicit folder that is not one is an InputError."""
    names = annotation_names(seq_dir)
    if explicit is not None:
        p = Path(explicit)
        cands = [p] + [p / n for n in names]
    else:
        cands = [ci_child(seq_dir, "annotations")]
        for base in dataset_bases(seq_dir):
            cands += [ci_child(ci_child(base, "annotations"), n) for n in names]
    tried = []
    for c in dict.fromkeys(cands):
        labels = find_labels_file(c)
        # a folder that is there but lacks the labels file is most likely the one meant: say so
        there = " (the folder is there, without a labels file)" if labels is None and c.is_dir() else ""
        tried.append(f"{c}/{{{','.join(LABELS_FILES)}}}{there}")
        if labels is not None:
            note = f"labels from {labels.name}" if labels.name != LABELS_FILE else ""
            return Lookup("annotations", c, tried, note)
    if explicit is not None:
        raise InputError(explicit, "not an annotation folder: no labels file; tried " + _tried_text(tried))
    return Lookup("annotations", None, tried, "no annotation folder", problem=True)


def locate_svoe(seq_dir: Path, annotation_dir: Path | None, explicit: str | Path | None = None) -> Lookup:
    """``svoe.txt`` of a sequence: in ``explicit`` (``<dir>/svoe.txt`` or ``<dir>/<name>/svoe.txt``),
    in the annotation folder, in the sequence folder, or in a separate enrollment tree ``<base>/*/<name>/svoe.txt`` or
    ``<base>/*/*/<name>/svoe.txt`` (for :func:`dataset_bases` and :func:`annotation_names`)."""
    names = annotation_names(seq_dir)
    cands: list[Path] = []
    tried: list[str] = []
    if explicit:
        cands += [Path(explicit) / SVOE_FILE] + [Path(explicit) / n / SVOE_FILE for n in names]
        tried += [str(c) for c in cands]
    for folder in ([annotation_dir] if annotation_dir is not None else []) + [seq_dir]:
        cands.append(folder / SVOE_FILE)
        tried.append(str(folder / SVOE_FILE))
    for c in cands:
        if c.is_file():
            return Lookup("SVOE enrollment", c, tried)
    for base in dict.fromkeys(dataset_bases(seq_dir)):
        for pattern in [f"*/{n}/{SVOE_FILE}" for n in names] + [f"*/*/{n}/{SVOE_FILE}" for n in names]:
            tried.append(f"{base}/{pattern}")
            hits = sorted(h for h in base.glob(pattern) if h.is_file())
            if hits:
                note = f"{len(hits)} candidates, the first taken" if len(hits) > 1 else ""
                return Lookup("SVOE enrollment", hits[0], tried, note)
    return Lookup("SVOE enrollment", None, tried, "no svoe.txt", problem=True)


def _photos_in(folder: Path) -> bool:
    try:
        return any(p.suffix.lower() in (".jpg", ".jpeg") for p in folder.iterdir())
    except OSError:
        return False


def locate_mvpe(seq_dir: Path, labels: list[str] | None, explicit: str | Path | None = None) -> Lookup:
    """The folder of multi-view pre-enrollment photos, ``<folder>/<instance_name>/*.jpg``: given,
    ``<base>/mvpe/<seq>/`` (as ``egograph synth`` writes), or as released, one folder for every
    sequence: ``<base>/mvpe/``, or any folder ``<base>``, ``<base>/*``, ``<base>/*/*`` holding a
    subfolder named after one of the sequence's instances with photos (needs the labels)."""
    tried: list[str] = []
    cands: list[Path] = []
    if explicit:
        cands += [Path(explicit) / seq_dir.name, Path(explicit)]
    for base in dataset_bases(seq_dir):
        cands.append(ci_child(ci_child(base, "mvpe"), seq_dir.name))

    def holds_instances(folder: Path) -> bool:
        return bool(labels) and any(_photos_in(folder / name) for name in labels)

    for c in cands:
        tried.append(f"{c}/<instance_name>/*.jpg")
        if c.is_dir() and (holds_instances(c) or (not labels and any(_photos_in(d) for d in _child_dirs(c)))):
            return Lookup("MVPE photos", c, tried)
    if labels:
        for base in dict.fromkeys(dataset_bases(seq_dir)):
            tried += [f"{base}/<instance_name>/*.jpg", f"{base}/*/<instance_name>/*.jpg",
                      f"{base}/*/*/<instance_name>/*.jpg"]
            levels = [base] + _child_dirs(base)
            levels += [g for c in _child_dirs(base) if c != seq_dir.parent for g in _child_dirs(c)]
            for folder in levels:
                if folder != seq_dir and holds_instances(folder):
                    return Lookup("MVPE photos", folder, tried)
    note = "no MVPE photos" + ("" if labels else " (without labels only the per-sequence folders are searched)")
    return Lookup("MVPE photos", None, tried, note, problem=True)


# --------------------------------------------------------------------------- frame files

_FRAME_NAME = re.compile(r"^(?P<prefix>\D*?)(?P<ts>\d+)$")


@dataclass
class FrameFiles:
    """The PNG frames of one stream folder (``pv/``, ``depth_ahat/``), keyed by the integer
    timestamp in their names: ``<ts>.png`` or ``<prefix><ts>.png`` (``frame_<ts>.png``)."""

    folder: Path
    files: dict[int, str]          # timestamp (ticks) -> file name
    prefixes: dict[str, int]       # name prefix -> count ("" for <ts>.png)
    other: int                     # files whose name holds no timestamp (ignored)

    @classmethod
    def scan(cls, folder: Path) -> "FrameFiles":
        files: dict[int, str] = {}
        prefixes: dict[str, int] = {}
        other = 0
        try:
            entries = sorted(e.name for e in os.scandir(folder) if e.is_file())
        except OSError:
            entries = []
        for name in entries:
            stem, dot, ext = name.rpartition(".")
            m = _FRAME_NAME.match(stem) if dot and ext.lower() == "png" else None
            if m is None:
                other += not name.startswith(".")
                continue
            ts = int(m.group("ts"))
            if ts in files and m.group("prefix") and not _FRAME_NAME.match(files[ts].rpartition(".")[0]).group(1):
                continue  # <ts>.png wins over <prefix><ts>.png
            files[ts] = name
            prefixes[m.group("prefix")] = prefixes.get(m.group("prefix"), 0) + 1
        return cls(folder, files, prefixes, other)

    def patterns(self) -> str:
        """The naming patterns found, e.g. ``frame_<ts>.png``."""
        return ", ".join(f"{p}<ts>.png" for p in sorted(self.prefixes, key=lambda k: -self.prefixes[k])) or "none"

    def sorted_timestamps(self) -> np.ndarray:
        return np.array(sorted(self.files), dtype=np.int64)


def nearest_within(ts: np.ndarray, ref: np.ndarray, tol: int) -> np.ndarray:
    """For each of ``ts`` the index into sorted ``ref`` of its nearest value at most ``tol`` away
    (same units, ticks here), -1 when there is none. Equal values always match; a tie between an
    earlier and a later value goes to the earlier."""
    ts = np.asarray(ts, dtype=np.int64)
    ref = np.asarray(ref, dtype=np.int64)
    if not len(ref):
        return np.full(len(ts), -1, dtype=np.int64)
    j = np.searchsorted(ref, ts)
    lo = np.clip(j - 1, 0, len(ref) - 1)
    hi = np.clip(j, 0, len(ref) - 1)
    pick = np.where(np.abs(ref[hi] - ts) < np.abs(ts - ref[lo]), hi, lo)
    return np.where(np.abs(ref[pick] - ts) <= tol, pick, -1).astype(np.int64)


def _ms(ticks) -> str:
    return f"{float(ticks) * 1000.0 / TICKS_PER_SECOND:.1f} ms"


def find_annotation_dir(seq_dir: Path, explicit: str | Path | None = None) -> Path | None:
    """The annotation folder of a sequence, or None (:func:`locate_annotations`)."""
    return locate_annotations(seq_dir, explicit).found


def _invalid_note(valid: np.ndarray) -> str:
    bad = int((~valid).sum())
    return f"{bad} of {len(valid)} invalid (skipped)" if bad else f"{len(valid)} frames"


def _join_depth_poses(seq_dir: Path, ts: np.ndarray, depth_files: FrameFiles, tol: int, policy: str, strict: bool,
                      sync_ms: float, offset_ms: float = 0.0):
    """AHAT poses joined to the PV frames ``ts`` by nearest timestamp within ``tol`` ticks ->
    ``(ahat timestamps, depth_poses (N,4,4), depth_valid (N,), depth_ts (N,) or -1, Lookup)``. Without
    ``depth_ahat_pose.json`` the AHAT frame files give the timestamps (and no pose). With the
    calibration's ``offset_ms`` (``AhatCalibration.time_offset_ms``) each joined frame takes the
    pose stream interpolated at its key plus the offset (:func:`~egograph.io.poses.interpolate_poses`)."""
    depth_file = seq_dir / "depth_ahat_pose.json"
    n = len(ts)
    depth_poses = np.full((n, 4, 4), np.nan)
    depth_valid = np.zeros(n, bool)
    if not depth_file.exists():  # anything else there (a folder) is an error of read_pose_json
        look = Lookup("AHAT poses", None, [str(depth_file)], "no AHAT pose file: nothing can be lifted", problem=True)
        report_problem(strict, depth_file, "AHAT pose file not found (needed to lift detections)")
        dts = depth_files.sorted_timestamps()
        j = nearest_within(ts, dts, tol)
        return dts, depth_poses, depth_valid, np.where(j >= 0, dts[np.maximum(j, 0)] if len(dts) else -1, -1), look
    dts, dposes, dvalid = read_pose_json(depth_file, policy)
    j = nearest_within(ts, dts, tol)
    has = j >= 0
    depth_ts = np.where(has, dts[np.maximum(j, 0)], -1).astype(np.int64)
    ok = has & dvalid[np.maximum(j, 0)]
    depth_poses[ok] = dposes[j[ok]]
    depth_valid[ok] = True
    if offset_ms:
        shifted, good = interpolate_poses(dts, dposes, dvalid, depth_ts[ok] + int(round(offset_ms * 1e4)))
        depth_poses[ok] = shifted
        depth_valid[ok] = good
    exact = int((depth_ts[has] == ts[has]).sum())
    offsets = (depth_ts[has] - ts[has]) if has.any() else np.zeros(0, np.int64)
    parts = [f"{int(has.sum())} of {n} PV frames joined within {sync_ms:g} ms"]
    if has.any() and exact < has.sum():
        parts.append(f"median AHAT-PV offset {_ms(np.median(offsets))}, max {_ms(np.abs(offsets).max())}")
    if (~dvalid).any():
        parts.append(f"{int((~dvalid).sum())} of {len(dvalid)} AHAT poses invalid (skipped)")
    look = Lookup("AHAT poses", depth_file, [f"{depth_file} (nearest timestamp within {sync_ms:g} ms)"],
                  "; ".join(parts), problem=not has.all())
    if not has.all():
        nearest = nearest_within(ts, dts, np.iinfo(np.int64).max // 4)
        far = np.abs(dts[nearest[~has]] - ts[~has]) if len(dts) else np.zeros(0)
        hint = f", which is {_ms(np.median(far))} away at the median" if len(far) else ""
        report_problem(strict, depth_file, f"{int((~has).sum())} of {n} PV frames have no AHAT pose within "
                                           f"{sync_ms:g} ms (tried the key nearest to each PV timestamp{hint}; "
                                           "io.depth_sync_ms sets the tolerance)")
    return dts, depth_poses, depth_valid, depth_ts, look


def _join_depth_files(ts: np.ndarray, depth_ts: np.ndarray, files: FrameFiles, tol: int) -> dict[int, str]:
    """PV index -> AHAT frame file: the file of the joined AHAT timestamp, else the file at the PV
    timestamp, else the nearest file within ``tol`` ticks."""
    out: dict[int, str] = {}
    if not files.files:
        return out
    fts = files.sorted_timestamps()
    near = nearest_within(ts, fts, tol)
    for i, t in enumerate(ts):
        name = files.files.get(int(depth_ts[i])) if depth_ts[i] >= 0 else None
        if name is None:
            name = files.files.get(int(t))
        if name is None and near[i] >= 0:
            name = files.files[int(fts[near[i]])]
        if name is not None:
            out[i] = name
    return out


def _depth_frames_lookup(rec: "Recording", files: FrameFiles, strict: bool) -> Lookup:
    folder = rec.seq_dir / "depth_ahat"
    tried = [f"{folder}/<ts>.png", f"{folder}/<prefix><ts>.png (frame_<ts>.png)",
             f"nearest timestamp within {rec.depth_sync_ms:g} ms"]
    n, got = len(rec), len(rec._depth_files)
    note = f"{got} of {n} PV frames have an AHAT frame ({files.patterns()})"
    if files.other:
        note += f"; {files.other} files without a timestamp in their name ignored"
    look = Lookup("AHAT frames", folder if got else None, tried, note, problem=got < n)
    if got == 0:
        what = (f"{len(files.files)} PNG frames ({files.patterns()}) but none within {rec.depth_sync_ms:g} ms of a PV "
                f"frame" if files.files else f"no frame files ({files.other} other files)" if folder.is_dir()
                else "folder missing")
        report_problem(strict, folder, f"no AHAT depth frame for any PV frame: {what}; tried " + _tried_text(tried))
    elif got < n:
        report_problem(strict, folder, f"{n - got} of {n} PV frames have no AHAT depth frame (no depth there); "
                                       "tried " + _tried_text(tried))
    return look


def _pv_frames_lookup(rec: "Recording") -> Lookup:
    """PV images are listed, never required: lifting, tracking and evaluation read detections, and
    ``refine`` says itself when COLMAP has no image."""
    files = rec._pv_files
    folder = rec.seq_dir / "pv"
    got = sum(1 for t in rec.timestamps if int(t) in files.files)
    note = f"{got} of {len(rec)} PV frames have an image ({files.patterns()})"
    return Lookup("PV images", folder if got else None, [f"{folder}/<ts>.png", f"{folder}/<prefix><ts>.png"], note)


@dataclass
class Recording:
    """One HoloLens 2 sequence: timestamps, poses, calibration, lazy frames.

    Poses are row-vector 4x4 (sensor -> world, metres); invalid frames hold NaN and
    ``*_valid`` is False there. ``depth_factor`` is the raw AHAT unit (4 = 4 mm units as
    in the hl2ss version IT3DEgo used, 1 = mm); ``None`` at open time means detect it.
    Everything is indexed by PV frame: the AHAT frame and pose of PV frame ``i`` are the ones
    nearest in time within ``depth_sync_ms`` (``depth_timestamps[i]``, -1 when none).
    ``lookups`` says where each input was found and what was tried (``egograph info`` lists it).
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
    depth_timestamps: np.ndarray | None = None   # (N,) int64 ticks of the AHAT frame joined to each PV frame, -1 none
    strict: bool = False
    depth_sync_ms: float = 15.0
    svoe_dir: str = ""               # io.svoe_dir / io.mvpe_dir: where to look first for enrollments
    mvpe_dir: str = ""
    lookups: list = field(default_factory=list, repr=False)
    # how well each candidate calibration folder fits (egograph.steps.calibration.CalibrationFit), set by
    # the step that chose the folder; None when nothing was scored
    calibration_fit: object = field(default=None, repr=False, compare=False)
    _index: dict = field(default_factory=dict, repr=False)
    _pv_files: FrameFiles | None = field(default=None, repr=False)
    _depth_files: dict = field(default_factory=dict, repr=False)   # PV index -> AHAT file name
    # Built on first use, keyed by sequence folder. ``dataclasses.replace`` copies (other poses, same
    # folder and mesh) share the dict, so lifting and tracking on them build the scene once.
    _mesh_scenes: dict = field(default_factory=dict, repr=False, compare=False)

    # ------------------------------------------------------------ opening
    @classmethod
    def open(cls, path: str | Path, *, sequence: str | None = None, calibration: str | Path | None = None,
             annotations: str | Path | None = None, invalid_poses: str = "skip",
             depth_factor: float | None = None, strict: bool = False, depth_sync_ms: float = 15.0,
             svoe_dir: str | Path | None = None, mvpe_dir: str | Path | None = None) -> "Recording":
        """Open the recording at ``path`` (see :func:`find_sequence_dir`). Inputs that are missing or
        partly unusable are warned about naming what was tried, or refused under ``strict``; the
        knobs are those of :class:`~egograph.io.config.IoConfig` (``io.*``)."""
        seq_dir = find_sequence_dir(path, sequence)
        policy = "error" if strict else invalid_poses
        lookups = [Lookup("sequence", seq_dir, [str(Path(path))])]
        ts, pv_poses, pv_valid = read_pose_json(seq_dir / "pv_pose.json", policy)
        check_hololens_ticks(ts, seq_dir / "pv_pose.json")
        lookups.append(Lookup("PV poses", seq_dir / "pv_pose.json", [str(seq_dir / "pv_pose.json")],
                              _invalid_note(pv_valid), problem=not pv_valid.all()))
        calib_dir = find_calibration_dir(seq_dir, calibration)
        lookups.append(Lookup("calibration", calib_dir, [str(calibration) if calibration else f"{seq_dir} and up to "
                                                         "3 parents: calibrations*/"]))
        ahat = read_ahat_calibration(calib_dir / "rm_depth_ahat")
        ann = locate_annotations(seq_dir, annotations)
        lookups.append(ann)
        if ann.found is None:
            report_problem(strict, seq_dir, "no annotation folder found (labels, intervals, SVOE boxes); tried "
                           + _tried_text(ann.tried) + "; pass --annotations DIR")
        tol = int(round(depth_sync_ms * TICKS_PER_SECOND / 1000.0))
        depth_files = FrameFiles.scan(seq_dir / "depth_ahat")
        dts, depth_poses, depth_valid, depth_ts, look = _join_depth_poses(
            seq_dir, ts, depth_files, tol, policy, strict, depth_sync_ms, ahat.time_offset_ms)
        lookups.append(look)
        rec = cls(
            seq_dir=seq_dir, timestamps=ts, pv_poses=pv_poses, pv_valid=pv_valid,
            depth_poses=depth_poses, depth_valid=depth_valid,
            ahat=ahat,
            pv=read_pv_calibration(calib_dir / "personal_video"),
            calibration_dir=calib_dir, annotation_dir=ann.found, depth_timestamps=depth_ts,
            strict=strict, depth_sync_ms=depth_sync_ms, svoe_dir=str(svoe_dir or ""), mvpe_dir=str(mvpe_dir or ""),
        )
        rec._index = {int(t): i for i, t in enumerate(ts)}
        rec._depth_files = _join_depth_files(ts, depth_ts, depth_files, tol)
        lookups.append(_depth_frames_lookup(rec, depth_files, strict))
        rec._pv_files = FrameFiles.scan(seq_dir / "pv")
        lookups.append(_pv_frames_lookup(rec))
        rec.lookups = lookups
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
        """PV image of frame i: the file named for its timestamp (``<ts>.png`` or ``frame_<ts>.png``
        as found at open), else ``pv/<ts>.png`` (which may not exist)."""
        ts = int(self.timestamps[i])
        name = self._pv_files.files.get(ts) if self._pv_files is not None else None
        return self.seq_dir / "pv" / (name or f"{ts}.png")

    def depth_path(self, i: int) -> Path:
        """AHAT frame joined to PV frame i (nearest in time, see :class:`Recording`), else
        ``depth_ahat/<ts>.png`` (which may not exist)."""
        name = self._depth_files.get(int(i))
        return self.seq_dir / "depth_ahat" / (name or f"{int(self.timestamps[i])}.png")

    def rgb(self, i: int) -> np.ndarray | None:
        """PV frame i as (720, 1280, 3) uint8 RGB, or None when missing/unreadable."""
        p = self.pv_path(i)
        if not p.is_file():
            return None
        img = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if img is None:
            warnings.warn(f"{p}: unreadable image, treated as missing", stacklevel=2)
            return None
        return cv2.cvtColor(self._calibrated_size(p, img), cv2.COLOR_BGR2RGB)

    def _calibrated_size(self, p: Path, img: np.ndarray) -> np.ndarray:
        """A PV frame at the calibration's size: detections are in the calibrated pixel scale. Another
        size of the same aspect ratio (a downscaled export) is rescaled with one warning per
        recording; another aspect ratio (a crop, another camera mode) is refused."""
        rows, cols = (int(v) for v in self.pv.shape)
        h, w = img.shape[:2]
        if (h, w) == (rows, cols):
            return img
        if abs(w * rows - h * cols) > max(w, h):  # not the same aspect ratio within a pixel
            raise InputError(p, f"PV frame is {w}x{h} pixels, the PV calibration {cols}x{rows} (another aspect "
                                "ratio: a crop or another camera mode?); give frames at the calibrated size")
        if not getattr(self, "_pv_rescale_noted", False):
            self._pv_rescale_noted = True
            warnings.warn(f"{p}: PV frames are {w}x{h} pixels, the PV calibration {cols}x{rows}: rescaled to the "
                          "calibrated size", stacklevel=3)
        return cv2.resize(img, (cols, rows), interpolation=cv2.INTER_LINEAR if w < cols else cv2.INTER_AREA)

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
            if p.suffix.lower() == ".ply" and not check_ply(p).get("face"):
                raise InputError(p, "mesh has no triangles (the PLY header declares no faces)")
            m = o3d.io.read_triangle_mesh(str(p))
            if len(m.triangles) == 0:
                raise InputError(p, "mesh has no triangles (or is not a mesh file Open3D reads)")
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
        cands = [ci_child(base, "detections") / self.name / name for base in dataset_bases(self.seq_dir)]
        cands.append(self.seq_dir / "detections" / name)
        for cand in cands:
            if cand.is_dir():
                return cand
        raise InputError(p, "neither a folder of detection files nor a detection set of this recording; tried "
                            + _tried_text([str(c) for c in cands]))

    def detection_sets(self) -> dict[str, Path]:
        """Detection sets the recording carries (name -> folder), from the first detections folder found."""
        for base in [*(ci_child(b, "detections") / self.name for b in dataset_bases(self.seq_dir)),
                     self.seq_dir / "detections"]:
            if base.is_dir():
                return {d.name: d for d in _child_dirs(base)}
        return {}

    @property
    def synth_gt_dir(self) -> Path | None:
        d = self.root / "synth_gt" / self.name
        return d if d.is_dir() else None
