"""IT3DEgo annotation files: read, validate, write.

Layout of one sequence's annotation folder (all tables accept comma and/or
whitespace separators, see :mod:`egograph.io.textio`)::

    labels.csv               one instance name per line; line k is instance id k (zero-based)
                             (``label.csv`` is read too: the release's text spells it so)
    3d_center_annot.txt      t_start t_end instance_id x y z location_id
    motion_state_annot.txt   instance_id t_start t_end          (stationary intervals)
    2d_bbox_annot/<k>.txt    ts x_min y_min x_max y_max         (boxes of instance k)
    svoe.txt                 instance_id ts x_min y_min x_max y_max   (enrollment box; it may
                             also sit in a separate enrollment tree, see
                             :func:`egograph.io.recording.locate_svoe`)

Conventions: timestamps are HoloLens ticks (100 ns, ~18 digits) kept as exact
Python ints; time intervals are inclusive at both ends; 3D centres are in the
world frame, in metres; boxes are in pixels of the PV image (1280x720), held
as ``x_min y_min x_max y_max``. Because some users read the box columns as
``x y w h``, every box reader and writer takes ``box_format`` ("xyxy" or
"xywh"); conversion happens at the file boundary only.

Readers refuse, naming file and line, what would be read wrong: a label name given twice, an
instance id beyond ``labels.csv`` (when the number of labels is known), two centre rows of one
instance for the same interval, overlapping stationary intervals of one instance.

Writers write single-space separated rows, newline-terminated, through an
atomic rename, so an existing file is never left half-written.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping, Sequence

from egograph.core.errors import InputError
from egograph.core.types import Box
from egograph.core.values import as_finite, as_int, check_instance_id, format_number
from egograph.io.atomic import atomic_write_text
from egograph.io.textio import (
    int_stem,
    iter_lines,
    iter_rows,
    listed_files,
    make_record,
    parse_float,
    parse_int,
    write_text_dir,
)

LABELS_FILE = "labels.csv"
# The release's tree says labels.csv, its text label.csv: both are read, labels.csv first.
LABELS_FILES = (LABELS_FILE, "label.csv")
CENTERS_FILE = "3d_center_annot.txt"
MOTION_FILE = "motion_state_annot.txt"
BBOX_DIR = "2d_bbox_annot"
SVOE_FILE = "svoe.txt"

PV_WIDTH = 1280  # pixels
PV_HEIGHT = 720  # pixels

BOX_FORMATS = ("xyxy", "xywh")
_PHOTO_SUFFIXES = {".jpg", ".jpeg"}


# --------------------------------------------------------------------------- records


def _check_interval(t_start: int, t_end: int) -> None:
    if t_end < t_start:
        raise ValueError(f"t_end {t_end} is before t_start {t_start}")


@dataclass(frozen=True, slots=True)
class CenterAnnotation:
    """3D centre (world frame, metres) of ``instance`` over ``[t_start, t_end]`` (ticks, inclusive).

    ``location_id`` counts the instance's previous moves: 0 at its first place,
    1 after it was first carried somewhere else, and so on.
    """

    t_start: int
    t_end: int
    instance: int
    xyz: tuple[float, float, float]
    location_id: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_start", as_int(self.t_start, "t_start"))
        object.__setattr__(self, "t_end", as_int(self.t_end, "t_end"))
        _check_interval(self.t_start, self.t_end)
        object.__setattr__(self, "instance", check_instance_id(self.instance))
        object.__setattr__(self, "xyz", _as_xyz(self.xyz))
        object.__setattr__(self, "location_id", as_int(self.location_id, "location_id"))
        if self.location_id < 0:
            raise ValueError(f"location_id {self.location_id} is negative")


@dataclass(frozen=True, slots=True)
class MotionInterval:
    """``instance`` is stationary over ``[t_start, t_end]`` (ticks, inclusive)."""

    instance: int
    t_start: int
    t_end: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "instance", check_instance_id(self.instance))
        object.__setattr__(self, "t_start", as_int(self.t_start, "t_start"))
        object.__setattr__(self, "t_end", as_int(self.t_end, "t_end"))
        _check_interval(self.t_start, self.t_end)


@dataclass(frozen=True, slots=True)
class SvoeEnrollment:
    """Single-view online enrollment: the box (pixels) of ``instance`` in PV frame ``ts``."""

    instance: int
    ts: int
    box: Box

    def __post_init__(self) -> None:
        object.__setattr__(self, "instance", check_instance_id(self.instance))
        object.__setattr__(self, "ts", as_int(self.ts, "ts"))
        if not isinstance(self.box, Box):
            raise TypeError(f"box must be a Box, got {type(self.box).__name__}")


@dataclass
class Annotations:
    """Everything in one sequence's annotation folder; instance ids index ``labels``.

    ``boxes`` maps instance id to its ``(ts, Box)`` rows, sorted by ts.
    """

    labels: list[str] = field(default_factory=list)
    centers: list[CenterAnnotation] = field(default_factory=list)
    motion: list[MotionInterval] = field(default_factory=list)
    boxes: dict[int, list[tuple[int, Box]]] = field(default_factory=dict)
    svoe: list[SvoeEnrollment] = field(default_factory=list)


def _as_xyz(xyz) -> tuple[float, float, float]:
    values = tuple(xyz)
    if len(values) != 3:
        raise ValueError(f"xyz must have 3 values, got {len(values)}")
    return tuple(as_finite(v, "xyz") for v in values)  # type: ignore[return-value]


# --------------------------------------------------------------------------- box columns


def check_box_format(box_format: str) -> str:
    if box_format not in BOX_FORMATS:
        raise ValueError(f"box_format must be one of {BOX_FORMATS}, got {box_format!r}")
    return box_format


def box_layout(box_format: str) -> str:
    """Column names of a box in ``box_format``, for messages and docs."""
    return "x_min y_min x_max y_max" if check_box_format(box_format) == "xyxy" else "x y w h"


def parse_box(tokens: Sequence[str], path: str | Path, lineno: int, box_format: str) -> Box:
    """A Box from 4 text fields in ``box_format``; InputError at ``lineno`` if invalid."""
    names = box_layout(box_format).split()
    a, b, c, d = (parse_float(t, path, lineno, n) for t, n in zip(tokens, names))
    factory = Box if box_format == "xyxy" else Box.from_xywh
    return make_record(path, lineno, factory, a, b, c, d)


def box_fields(box: Box, box_format: str) -> list[str]:
    """The 4 text fields of ``box`` in ``box_format`` (shortest exact float text)."""
    values = (box.x_min, box.y_min, box.x_max, box.y_max) if box_format == "xyxy" else box.to_xywh()
    return [format_number(v) for v in values]


def _lines_text(rows: Iterable[Iterable[str]]) -> str:
    return "".join(" ".join(row) + "\n" for row in rows)


def _check_overlaps(path: Path, rows: list[tuple[int, int, int, int]], what: str) -> None:
    """InputError when two intervals of one instance share a tick; ``rows`` are
    ``(instance, t_start, t_end, lineno)`` (ticks, inclusive). Identical rows are overlaps too:
    the evaluation would count the frames twice."""
    last: dict[int, tuple[int, int, int]] = {}
    for inst, t0, t1, lineno in sorted(rows):
        prev = last.get(inst)
        if prev is not None and t0 <= prev[1]:
            raise InputError(path, f"instance {inst}: {what} [{t0}, {t1}] overlaps [{prev[0]}, {prev[1]}] "
                                   f"on line {min(lineno, prev[2])}", max(lineno, prev[2]))
        if prev is None or t1 > prev[1]:
            last[inst] = (t0, t1, lineno)


def _check_duplicates(path: Path, rows: list[tuple[int, int, int, int]], what: str) -> None:
    """InputError when one instance has two rows for the same interval (the same ``t_start`` and
    ``t_end``, ticks): a repeated row, or two places for the same time; ``rows`` are
    ``(instance, t_start, t_end, lineno)``."""
    seen: dict[tuple[int, int, int], int] = {}
    for inst, t0, t1, lineno in rows:
        first = seen.setdefault((inst, t0, t1), lineno)
        if first != lineno:
            raise InputError(path, f"instance {inst}: {what} [{t0}, {t1}] also on line {first}", lineno)


def _check_limit(path: Path, lineno: int | None, instance: int, num_instances: int | None) -> None:
    if num_instances is not None and instance >= num_instances:
        raise InputError(
            path, f"instance id {instance} out of range: labels.csv has {num_instances} labels", lineno
        )


# --------------------------------------------------------------------------- finding files


def ci_child(parent: str | Path, name: str) -> Path:
    """``parent/name``; when that does not exist, the one entry of ``parent`` whose name equals
    ``name`` ignoring case (``Annotations`` for ``annotations`` on a case-sensitive file system).
    ``parent/name`` again when there is none or more than one, so callers test ``exists()``."""
    parent = Path(parent)
    path = parent / name
    if path.exists() or not parent.is_dir():
        return path
    try:
        same = [c for c in parent.iterdir() if c.name.lower() == name.lower()]
    except OSError:
        return path
    return same[0] if len(same) == 1 else path


def find_labels_file(folder: str | Path) -> Path | None:
    """The labels file of an annotation folder: ``labels.csv`` or ``label.csv`` (either case), or None."""
    for name in LABELS_FILES:
        path = ci_child(folder, name)
        if path.is_file():
            return path
    return None


# --------------------------------------------------------------------------- labels.csv


def read_labels(path: str | Path) -> list[str]:
    """Instance names; list index = instance id. With commas, the name is the first field.

    A name given twice is an InputError (two ids for one name: results could not be told apart).
    """
    labels = []
    seen: dict[str, int] = {}
    for lineno, line in iter_lines(path):
        name = line.split(",", 1)[0].strip()
        if not name:
            raise InputError(path, "empty instance name", lineno)
        if name in seen:
            raise InputError(path, f"instance name {name!r} also on line {seen[name]}", lineno)
        seen[name] = lineno
        labels.append(name)
    return labels


def _labels_text(labels: Sequence[str]) -> str:
    for name in labels:
        # Refuse names that would not read back as themselves.
        if not isinstance(name, str) or not name or name != name.strip():
            raise ValueError(f"instance name {name!r} is empty or has surrounding whitespace")
        if "," in name or "\n" in name or "\r" in name or name.startswith("#"):
            raise ValueError(f"instance name {name!r} contains ',', a line break or starts with '#'")
    return "".join(name + "\n" for name in labels)


def write_labels(path: str | Path, labels: Sequence[str]) -> None:
    atomic_write_text(path, _labels_text(labels))


# --------------------------------------------------------------------------- 3d_center_annot.txt

_CENTER_LAYOUT = "t_start t_end instance_id x y z location_id"


def read_centers(path: str | Path, num_instances: int | None = None) -> list[CenterAnnotation]:
    """Rows of ``3d_center_annot.txt``, sorted by (instance, t_start).

    If ``num_instances`` is given, ids must be below it (InputError otherwise). Two rows of one
    instance for the same interval (a repeated row, or two places at once) are an InputError;
    intervals of one instance that overlap otherwise are kept (the protocol counts each).
    """
    path = Path(path)
    out = []
    lines = []
    for n, tok in iter_rows(path, 7, layout=_CENTER_LAYOUT):
        t0 = parse_int(tok[0], path, n, "t_start")
        t1 = parse_int(tok[1], path, n, "t_end")
        inst = parse_int(tok[2], path, n, "instance_id")
        xyz = tuple(parse_float(t, path, n, a) for t, a in zip(tok[3:6], "xyz"))
        loc = parse_int(tok[6], path, n, "location_id")
        rec = make_record(path, n, CenterAnnotation, t0, t1, inst, xyz, loc)
        _check_limit(path, n, rec.instance, num_instances)
        out.append(rec)
        lines.append((rec.instance, rec.t_start, rec.t_end, n))
    _check_duplicates(path, lines, "interval")
    out.sort(key=lambda c: (c.instance, c.t_start))
    return out


def centers_text(centers: Iterable[CenterAnnotation]) -> str:
    rows = sorted(centers, key=lambda c: (c.instance, c.t_start))
    return _lines_text(
        [str(as_int(c.t_start, "t_start")), str(as_int(c.t_end, "t_end")), str(as_int(c.instance, "instance"))]
        + [format_number(v) for v in c.xyz]
        + [str(as_int(c.location_id, "location_id"))]
        for c in rows
    )


def write_centers(path: str | Path, centers: Iterable[CenterAnnotation]) -> None:
    """Write ``3d_center_annot.txt`` sorted by (instance, t_start)."""
    atomic_write_text(path, centers_text(centers))


# --------------------------------------------------------------------------- motion_state_annot.txt


def read_motion_states(path: str | Path, num_instances: int | None = None) -> list[MotionInterval]:
    """Stationary intervals (inclusive ticks), sorted by (instance, t_start); two of one instance
    that overlap are an InputError."""
    path = Path(path)
    out = []
    lines = []
    for n, tok in iter_rows(path, 3, layout="instance_id t_start t_end"):
        inst = parse_int(tok[0], path, n, "instance_id")
        t0 = parse_int(tok[1], path, n, "t_start")
        t1 = parse_int(tok[2], path, n, "t_end")
        rec = make_record(path, n, MotionInterval, inst, t0, t1)
        _check_limit(path, n, rec.instance, num_instances)
        out.append(rec)
        lines.append((rec.instance, rec.t_start, rec.t_end, n))
    _check_overlaps(path, lines, "stationary interval")
    out.sort(key=lambda m: (m.instance, m.t_start))
    return out


def _motion_text(motion: Iterable[MotionInterval]) -> str:
    rows = sorted(motion, key=lambda m: (m.instance, m.t_start))
    return _lines_text(
        (str(as_int(m.instance, "instance")), str(as_int(m.t_start, "t_start")), str(as_int(m.t_end, "t_end")))
        for m in rows
    )


def write_motion_states(path: str | Path, motion: Iterable[MotionInterval]) -> None:
    """Write ``motion_state_annot.txt`` sorted by (instance, t_start)."""
    atomic_write_text(path, _motion_text(motion))


# --------------------------------------------------------------------------- 2d_bbox_annot/<k>.txt


def read_bbox_annot(path: str | Path, box_format: str = "xyxy") -> list[tuple[int, Box]]:
    """``(ts, Box)`` rows of one instance's box file, sorted numerically by ts."""
    path = Path(path)
    check_box_format(box_format)
    layout = "ts " + box_layout(box_format)
    out = []
    for n, tok in iter_rows(path, 5, layout=layout):
        ts = parse_int(tok[0], path, n, "ts")
        out.append((ts, parse_box(tok[1:5], path, n, box_format)))
    out.sort(key=lambda row: row[0])
    return out


def _bbox_text(rows: Iterable[tuple[int, Box]], box_format: str) -> str:
    check_box_format(box_format)
    rows = sorted(((as_int(ts, "ts"), box) for ts, box in rows), key=lambda row: row[0])
    return _lines_text([str(ts)] + box_fields(box, box_format) for ts, box in rows)


def write_bbox_annot(path: str | Path, rows: Iterable[tuple[int, Box]], box_format: str = "xyxy") -> None:
    """Write one instance's ``(ts, Box)`` rows, sorted by ts."""
    atomic_write_text(path, _bbox_text(rows, box_format))


def read_bbox_annot_dir(
    path: str | Path, box_format: str = "xyxy", num_instances: int | None = None
) -> dict[int, list[tuple[int, Box]]]:
    """All ``<k>.txt`` files of a ``2d_bbox_annot`` folder, keyed by instance id k (sorted).

    A file not named ``<integer>.txt`` is an InputError (hidden files are ignored).
    """
    check_box_format(box_format)
    found: dict[int, Path] = {}
    for file in listed_files(path, "2d_bbox_annot"):
        k = int_stem(file, "instance_id")
        if k in found:  # e.g. "3.txt" and "03.txt"
            raise InputError(file, f"instance id {k} also given by {found[k].name}")
        _check_limit(file, None, k, num_instances)
        found[k] = file
    return {k: read_bbox_annot(found[k], box_format) for k in sorted(found)}


def _bbox_files(boxes: Mapping[int, Iterable[tuple[int, Box]]], box_format: str) -> dict[str, str]:
    """File name -> text for a ``2d_bbox_annot`` folder."""
    return {f"{check_instance_id(k)}.txt": _bbox_text(rows, box_format) for k, rows in boxes.items()}


def write_bbox_annot_dir(
    path: str | Path, boxes: Mapping[int, Iterable[tuple[int, Box]]], box_format: str = "xyxy"
) -> None:
    """Write one ``<k>.txt`` per instance; the folder is replaced as a whole, atomically."""
    write_text_dir(path, _bbox_files(boxes, box_format))


# --------------------------------------------------------------------------- svoe.txt


def read_svoe(
    path: str | Path, box_format: str = "xyxy", num_instances: int | None = None
) -> list[SvoeEnrollment]:
    """Single-view enrollments, sorted by (instance, ts)."""
    path = Path(path)
    check_box_format(box_format)
    layout = "instance_id ts " + box_layout(box_format)
    out = []
    for n, tok in iter_rows(path, 6, layout=layout):
        inst = parse_int(tok[0], path, n, "instance_id")
        ts = parse_int(tok[1], path, n, "ts")
        box = parse_box(tok[2:6], path, n, box_format)
        rec = make_record(path, n, SvoeEnrollment, inst, ts, box)
        _check_limit(path, n, rec.instance, num_instances)
        out.append(rec)
    out.sort(key=lambda s: (s.instance, s.ts))
    return out


def _svoe_text(svoe: Iterable[SvoeEnrollment], box_format: str) -> str:
    check_box_format(box_format)
    rows = sorted(svoe, key=lambda s: (s.instance, s.ts))
    return _lines_text(
        [str(as_int(s.instance, "instance")), str(as_int(s.ts, "ts"))] + box_fields(s.box, box_format)
        for s in rows
    )


def write_svoe(path: str | Path, svoe: Iterable[SvoeEnrollment], box_format: str = "xyxy") -> None:
    """Write ``svoe.txt`` sorted by (instance, ts)."""
    atomic_write_text(path, _svoe_text(svoe, box_format))


# --------------------------------------------------------------------------- MVPE photos

_DIGIT_RUNS = re.compile(r"([0-9]+)")


def _natural_key(name: str) -> list:
    # "img2.jpg" before "img10.jpg": numbers compare as numbers, not text.
    return [(0, int(part), "") if part.isdigit() else (1, 0, part) for part in _DIGIT_RUNS.split(name)]


def read_mvpe_photos(path: str | Path) -> dict[str, list[Path]]:
    """Multi-view pre-enrollment photos: instance name -> its ``*.jpg`` paths.

    One subfolder per instance name; names and photos are sorted (numbers in
    file names compared numerically). Hidden entries are ignored.
    """
    path = Path(path)
    if not path.is_dir():
        raise InputError(path, "MVPE photo folder not found")
    out: dict[str, list[Path]] = {}
    for sub in sorted(path.iterdir(), key=lambda p: _natural_key(p.name)):
        if sub.name.startswith(".") or not sub.is_dir():
            continue
        photos = [
            p for p in sub.iterdir()
            if not p.name.startswith(".") and p.suffix.lower() in _PHOTO_SUFFIXES and p.is_file()
        ]
        out[sub.name] = sorted(photos, key=lambda p: _natural_key(p.name))
    return out


# --------------------------------------------------------------------------- whole folder


def load_annotations(path: str | Path, box_format: str = "xyxy", svoe_path: str | Path | None = None) -> Annotations:
    """Read a sequence's annotation folder.

    ``labels.csv`` (or ``label.csv``) is required; the other files are optional (missing -> empty;
    whoever needs one says so). ``svoe_path``: the ``svoe.txt`` to read when it is not in the folder
    (a separate enrollment tree). Instance ids beyond the labels are an InputError naming file and line.
    """
    path = Path(path)
    check_box_format(box_format)
    if not path.is_dir():
        raise InputError(path, "annotation folder not found")
    labels_path = find_labels_file(path)
    if labels_path is None:
        raise InputError(path, f"annotation folder has no labels file (tried {', '.join(LABELS_FILES)})")
    labels = read_labels(labels_path)
    n = len(labels)
    ann = Annotations(labels=labels)
    if (path / CENTERS_FILE).exists():
        ann.centers = read_centers(path / CENTERS_FILE, num_instances=n)
    if (path / MOTION_FILE).exists():
        ann.motion = read_motion_states(path / MOTION_FILE, num_instances=n)
    if (path / BBOX_DIR).exists():
        ann.boxes = read_bbox_annot_dir(path / BBOX_DIR, box_format, num_instances=n)
    svoe = Path(svoe_path) if svoe_path is not None else path / SVOE_FILE
    if svoe.exists():
        ann.svoe = read_svoe(svoe, box_format, num_instances=n)
    return ann


def save_annotations(path: str | Path, ann: Annotations, box_format: str = "xyxy") -> None:
    """Write every annotation file of ``ann`` into folder ``path``.

    All text is formatted and checked before anything is written, so a bad
    record leaves the folder untouched; each file is then replaced atomically.
    """
    path = Path(path)
    n = len(ann.labels)
    ids = [c.instance for c in ann.centers] + [m.instance for m in ann.motion]
    ids += list(ann.boxes) + [s.instance for s in ann.svoe]
    bad = [i for i in ids if not 0 <= i < n]
    if bad:
        raise ValueError(f"instance id {bad[0]} out of range for {n} labels")
    texts = {
        LABELS_FILE: _labels_text(ann.labels),
        CENTERS_FILE: centers_text(ann.centers),
        MOTION_FILE: _motion_text(ann.motion),
        SVOE_FILE: _svoe_text(ann.svoe, box_format),
    }
    box_texts = _bbox_files(ann.boxes, box_format)
    path.mkdir(parents=True, exist_ok=True)
    for name, text in texts.items():
        atomic_write_text(path / name, text)
    write_text_dir(path / BBOX_DIR, box_texts)
