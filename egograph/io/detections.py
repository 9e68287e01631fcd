"""Per-frame detection (association) files and per-frame tracker result files.

Both live in a folder with one ``<ts>.txt`` per PV frame, ``ts`` being the
frame's HoloLens timestamp (100 ns ticks, exact int). Rows are separated by
commas and/or whitespace when read, single spaces when written.

Detection rows (boxes in PV image pixels, 1280x720)::

    instance x1 y1 x2 y2 score                   6 columns, what we write
    instance x1 y1 x2 y2                         5 columns, score = 1.0
    instance x1 y1 x2 y2 det_conf similarity     7 columns (reference code), score = similarity

The score is the matcher's cosine similarity, so any value in [-1, 1] is accepted (the trackers'
``score_threshold`` knobs have the same range); ``det_conf`` is a detector confidence in [0, 1].
Values outside are refused naming file and line.

Read against a recording's PV timestamps, a detection folder must hold at least one file named
for a PV frame, else :class:`InputError` (wrong folder, ``frame_<ts>.txt`` names, timestamps of
another recording). Files that are not named ``<ts>.txt`` or name no PV frame are counted in the
result's :attr:`DetectionFrames.scan`, warned about, and skipped.

Result rows (predicted instance centre, world frame, metres)::

    instance x y z score

The public reference evaluator opens the result file of every PV frame, so
:func:`write_results_dir` writes one file per timestamp, empty when nothing is
predicted.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence, TypeVar

from egograph.core.errors import InputError
from egograph.core.types import Detection, Prediction
from egograph.core.values import as_int, check_instance_id, format_number
from egograph.io.annotations import box_fields, box_layout, check_box_format, parse_box
from egograph.io.atomic import atomic_write_text
from egograph.io.textio import int_stem, iter_rows, listed_files, make_record, parse_float, parse_int, write_text_dir

T = TypeVar("T")

ANSWERS_FILE = "answers.tsv"
"""Every answer of a tracker that answers every frame with a confidence, one line each
(``ts instance x y z score``, tab-separated): the per-frame files hold only the operating point's
(:func:`answers_text`)."""

METADATA_FILES = frozenset({"intervals.json", "config.yaml", "egograph.json", "adapt.json", ANSWERS_FILE})
"""Files a results or detections folder may hold beside its per-frame ``<ts>.txt`` (the tracker's
intervals, the resolved configuration, the run record, see :mod:`egograph.steps.outputs`, an
adapted detection's head record, :mod:`egograph.steps.adapt`, and every answer with its confidence,
``answers.tsv``); readers skip them."""


# --------------------------------------------------------------------------- per-frame folders

SCORE_RANGE = (-1.0, 1.0)
"""Accepted matcher scores (cosine similarity)."""
DET_CONF_RANGE = (0.0, 1.0)
"""Accepted detector confidences (the 7-column format's ``det_conf``)."""
EXAMPLES = 3
"""File names quoted in messages about a folder."""


@dataclass
class FrameDirScan:
    """What a per-frame folder holds against a recording's PV timestamps (100 ns ticks).

    ``matched``: PV timestamp -> its file; ``not_pv_frame``: files named ``<ts>.txt`` whose ts is
    no PV frame; ``misnamed``: files not named ``<integer>.txt`` (metadata files and hidden files
    are not counted); ``missing``: PV timestamps without a file, in numeric order.
    """

    folder: Path
    matched: dict[int, Path] = field(default_factory=dict)
    not_pv_frame: list[Path] = field(default_factory=list)
    misnamed: list[Path] = field(default_factory=list)
    missing: list[int] = field(default_factory=list)

    @property
    def n_files(self) -> int:
        return len(self.matched) + len(self.not_pv_frame) + len(self.misnamed)

    @property
    def ignored(self) -> list[Path]:
        """Files that were not read (no PV frame to file them under), in name order."""
        return sorted(self.not_pv_frame + self.misnamed)

    def ignored_text(self) -> str:
        """``"2 not named <ts>.txt (e.g. a.txt), 1 for no PV frame (e.g. 5.txt)"``, or ``""``."""
        parts = []
        for files, what in ((self.misnamed, "not named <ts>.txt"), (self.not_pv_frame, "for no PV frame")):
            if files:
                parts.append(f"{len(files)} {what} (e.g. {', '.join(_names(files))})")
        return ", ".join(parts)


def _names(files: Sequence[Path], n: int = EXAMPLES) -> list[str]:
    names = sorted(f.name for f in files)
    return names[:n] + (["..."] if len(names) > n else [])


def scan_frame_dir(path: str | Path, timestamps: Iterable[int]) -> FrameDirScan:
    """Sort a per-frame folder's files against the PV ``timestamps`` (see :class:`FrameDirScan`).

    ``0100.txt`` names frame 100 as ``100.txt`` does; two files for one frame are an InputError.
    """
    path = Path(path)
    stamps = sorted({as_int(t, "timestamp") for t in timestamps})
    known = set(stamps)
    scan = FrameDirScan(path)
    for file in sorted(listed_files(path, "per-frame")):
        if file.name in METADATA_FILES:
            continue
        try:
            ts = int_stem(file, "ts")
        except InputError:
            scan.misnamed.append(file)
            continue
        if ts not in known:
            scan.not_pv_frame.append(file)
        elif ts in scan.matched:  # e.g. "100.txt" and "0100.txt"
            raise InputError(file, f"timestamp {ts} also given by {scan.matched[ts].name}")
        else:
            scan.matched[ts] = file
    scan.missing = [ts for ts in stamps if ts not in scan.matched]
    return scan


def _read_frame_dir(
    path: str | Path,
    timestamps: Iterable[int] | None,
    read_one: Callable[[Path], list[T]],
) -> dict[int, list[T]]:
    """``ts -> rows`` for a folder of ``<ts>.txt`` files, keys in numeric order.

    With ``timestamps``, exactly those keys are returned (missing file -> []) and
    other files are not read; without, every file must be named ``<integer>.txt``.
    """
    path = Path(path)
    if timestamps is not None:
        scan = scan_frame_dir(path, timestamps)
        out: dict[int, list[T]] = {}
        for ts in sorted([*scan.matched, *scan.missing]):
            out[ts] = read_one(scan.matched[ts]) if ts in scan.matched else []
        return out
    files = [f for f in listed_files(path, "per-frame") if f.name not in METADATA_FILES]
    found: dict[int, Path] = {}
    for file in files:
        ts = int_stem(file, "ts")
        if ts in found:  # e.g. "100.txt" and "0100.txt"
            raise InputError(file, f"timestamp {ts} also given by {found[ts].name}")
        found[ts] = file
    return {ts: read_one(found[ts]) for ts in sorted(found)}


# --------------------------------------------------------------------------- detections


def read_detection_file(path: str | Path, box_format: str = "xyxy") -> list[Detection]:
    """Detections of one frame, in file order (5, 6 or 7 columns, see module doc)."""
    path = Path(path)
    check_box_format(box_format)
    layout = f"instance {box_layout(box_format)} [score | det_conf similarity]"
    out = []
    for n, tok in iter_rows(path, 5, 7, layout=layout):
        inst = parse_int(tok[0], path, n, "instance")
        box = parse_box(tok[1:5], path, n, box_format)
        if len(tok) == 7:
            _in_range(parse_float(tok[5], path, n, "det_conf"), DET_CONF_RANGE, path, n, "det_conf")  # then dropped
            score = _in_range(parse_float(tok[6], path, n, "similarity"), SCORE_RANGE, path, n, "similarity")
        elif len(tok) == 6:
            score = _in_range(parse_float(tok[5], path, n, "score"), SCORE_RANGE, path, n, "score")
        else:
            score = 1.0
        out.append(make_record(path, n, Detection, inst, box, score))
    return out


def _in_range(value: float, bounds: tuple[float, float], path: Path, lineno: int, what: str) -> float:
    lo, hi = bounds
    if not lo <= value <= hi:
        raise InputError(path, f"{what} {value:g} outside [{lo:g}, {hi:g}]", lineno)
    return value


def _detections_text(dets: Iterable[Detection], box_format: str) -> str:
    check_box_format(box_format)
    return "".join(
        " ".join([str(check_instance_id(d.instance)), *box_fields(d.box, box_format), format_number(d.score)]) + "\n"
        for d in dets
    )


def write_detection_file(path: str | Path, dets: Iterable[Detection], box_format: str = "xyxy") -> None:
    """Write one frame's detections as ``instance x1 y1 x2 y2 score`` rows, atomically."""
    atomic_write_text(path, _detections_text(dets, box_format))


class DetectionFrames(dict):
    """``ts -> detections`` (numeric ts order), plus ``scan``: the folder's files against the PV
    timestamps (:class:`FrameDirScan`; None when read without timestamps)."""

    def __init__(self, *args, scan: FrameDirScan | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.scan = scan


def read_detection_dir(
    path: str | Path, timestamps: Iterable[int] | None = None, box_format: str = "xyxy"
) -> DetectionFrames:
    """``ts -> detections`` for a folder of ``<ts>.txt`` files, in numeric ts order.

    With ``timestamps`` (a recording's PV frames), every given timestamp is a key (missing file
    -> []); InputError when the folder has no file, or none named for a PV frame; files that
    name no PV frame are skipped with a warning and listed in the result's ``scan``. Without,
    every file must be named ``<integer>.txt`` and there must be at least one.
    """
    check_box_format(box_format)
    path = Path(path)
    read_one = lambda p: read_detection_file(p, box_format)  # noqa: E731
    if timestamps is None:
        out = DetectionFrames(_read_frame_dir(path, None, read_one))
        if not out:
            raise InputError(path, "no detection files (expected one <ts>.txt per PV frame)")
        return out
    stamps = sorted({as_int(t, "timestamp") for t in timestamps})
    scan = scan_frame_dir(path, stamps)
    check_detection_scan(scan, stamps)
    if scan.ignored:
        warnings.warn(f"{path}: {len(scan.ignored)} of {scan.n_files} detection files skipped: "
                      f"{scan.ignored_text()}", stacklevel=2)
    frames = {ts: read_one(scan.matched[ts]) if ts in scan.matched else [] for ts in stamps}
    _collapse_repeats(frames, scan)
    return DetectionFrames(frames, scan=scan)


def _collapse_repeats(frames: dict[int, list[Detection]], scan: FrameDirScan) -> None:
    """Identical lines repeated in one frame (a writer that appended twice) are one detection, not
    independent evidence: keep the first of each, with one warning counting them."""
    dropped, where = 0, None
    for ts, dets in frames.items():
        if len(dets) < 2:
            continue
        seen: set = set()
        kept = []
        for d in dets:
            key = (d.instance, d.box, d.score)
            if key in seen:
                continue
            seen.add(key)
            kept.append(d)
        if len(kept) < len(dets):
            dropped += len(dets) - len(kept)
            where = where or scan.matched.get(ts)
            frames[ts] = kept
    if dropped:
        warnings.warn(f"{scan.folder}: {dropped} repeated identical detection line(s) collapsed "
                      f"(e.g. in {where.name if where else '?'}); each counts once", stacklevel=3)


def check_detection_scan(scan: FrameDirScan, timestamps: Sequence[int]) -> None:
    """InputError when a detection folder has nothing for any PV frame (``timestamps``, sorted)."""
    if scan.matched:
        return
    if not scan.n_files:
        raise InputError(scan.folder, "no detection files (expected one <ts>.txt per PV frame)")
    eg = f" (e.g. {timestamps[0]}.txt)" if len(timestamps) else ""
    raise InputError(scan.folder, f"no detection file names a PV frame: expected <ts>.txt with ts a PV "
                                  f"timestamp{eg}; found {scan.n_files} files: "
                                  f"{', '.join(_names(scan.ignored))}")


def write_detection_dir(
    path: str | Path, per_frame: Mapping[int, Iterable[Detection]], box_format: str = "xyxy"
) -> None:
    """Write one ``<ts>.txt`` per key of ``per_frame``; the folder is replaced atomically."""
    files = {f"{as_int(ts, 'timestamp')}.txt": _detections_text(dets, box_format) for ts, dets in per_frame.items()}
    write_text_dir(path, files)


# --------------------------------------------------------------------------- tracker results


def read_results_lines(path: str | Path) -> list[tuple[int, Prediction]]:
    """``(line number, prediction)`` of one frame's results file, in file order (1-based lines)."""
    path = Path(path)
    out = []
    for n, tok in iter_rows(path, 5, layout="instance x y z score"):
        inst = parse_int(tok[0], path, n, "instance")
        xyz = tuple(parse_float(t, path, n, a) for t, a in zip(tok[1:4], "xyz"))
        score = parse_float(tok[4], path, n, "score")
        out.append((n, make_record(path, n, Prediction, inst, xyz, score)))
    return out


def read_results_file(path: str | Path) -> list[Prediction]:
    """Predictions of one frame (``instance x y z score``, world frame, metres), in file order."""
    return [p for _, p in read_results_lines(path)]


def _results_text(preds: Iterable[Prediction]) -> str:
    return "".join(
        " ".join([str(check_instance_id(p.instance)), *(format_number(v) for v in p.xyz), format_number(p.score)])
        + "\n"
        for p in preds
    )


def write_results_file(path: str | Path, preds: Iterable[Prediction]) -> None:
    """Write one frame's predictions, atomically (an empty list gives an empty file)."""
    atomic_write_text(path, _results_text(preds))


def read_results_dir(path: str | Path, timestamps: Iterable[int] | None = None) -> dict[int, list[Prediction]]:
    """``ts -> predictions`` for a result folder, in numeric ts order.

    With ``timestamps``, every given timestamp is a key (missing file -> []).
    """
    return _read_frame_dir(path, timestamps, read_results_file)


def answers_text(answers: Mapping[int, Iterable[Prediction]]) -> str:
    """Every answer, ``ts instance x y z score`` per line, tab-separated (ticks; world frame, metres; confidence), in
    timestamp order: the contents of :data:`ANSWERS_FILE`."""
    return "".join(f"{int(ts)}\t" + line.replace(" ", "\t") for ts in sorted(answers, key=int)
                   for line in _results_text(answers[ts]).splitlines(keepends=True))


def read_answers_file(path: str | Path) -> dict[int, list[Prediction]]:
    """``ts -> answers`` of an :data:`ANSWERS_FILE` (errors name the file and line)."""
    path = Path(path)
    out: dict[int, list[Prediction]] = {}
    for n, tok in iter_rows(path, 6, layout="ts instance x y z score"):
        ts = parse_int(tok[0], path, n, "ts")
        inst = parse_int(tok[1], path, n, "instance")
        xyz = tuple(parse_float(t, path, n, a) for t, a in zip(tok[2:5], "xyz"))
        score = parse_float(tok[5], path, n, "score")
        out.setdefault(ts, []).append(make_record(path, n, Prediction, inst, xyz, score))
    return out


def write_results_dir(
    path: str | Path, per_frame: Mapping[int, Iterable[Prediction]], timestamps: Sequence[int],
    extra_files: Mapping[str, str] | None = None,
) -> None:
    """Write a result folder with one ``<ts>.txt`` for EVERY PV frame timestamp.

    Frames without predictions get an empty file, because the reference
    evaluator opens every frame's file. Predictions for a timestamp that is not
    a PV frame are refused rather than silently dropped. ``extra_files`` (name -> text, names from
    :data:`METADATA_FILES`) land in the same folder, so the whole run is one rename.
    """
    stamps = {as_int(ts, "timestamp") for ts in timestamps}
    stray = sorted(as_int(ts, "timestamp") for ts in per_frame if as_int(ts, "timestamp") not in stamps)
    if stray:
        raise ValueError(f"predictions for {len(stray)} timestamps that are not PV frames, e.g. {stray[0]}")
    by_ts = {as_int(ts, "timestamp"): preds for ts, preds in per_frame.items()}
    files = {f"{ts}.txt": _results_text(by_ts.get(ts, ())) for ts in sorted(stamps)}
    for name, text in (extra_files or {}).items():
        if name not in METADATA_FILES:
            raise ValueError(f"{name}: not a results metadata file ({', '.join(sorted(METADATA_FILES))})")
        files[name] = text
    write_text_dir(path, files)
