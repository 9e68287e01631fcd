"""Per-frame detection (association) files and per-frame tracker result files.

Both live in a folder with one ``<ts>.txt`` per PV frame, ``ts`` being the
frame's HoloLens timestamp (100 ns ticks, exact int). Rows are separated by
commas and/or whitespace when read, single spaces when written.

Detection rows (boxes in PV image pixels, 1280x720)::

    instance x1 y1 x2 y2 score                   6 columns, what we write
    instance x1 y1 x2 y2                         5 columns, score = 1.0
    instance x1 y1 x2 y2 det_conf similarity     7 columns (reference code), score = similarity

Result rows (predicted instance centre, world frame, metres)::

    instance x y z score

The public reference evaluator opens the result file of every PV frame, so
:func:`write_results_dir` writes one file per timestamp, empty when nothing is
predicted.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence, TypeVar

from egograph.core.errors import InputError
from egograph.core.types import Detection, Prediction
from egograph.core.values import as_int, check_instance_id, format_number
from egograph.io.annotations import box_fields, box_layout, check_box_format, parse_box
from egograph.io.atomic import atomic_write_text
from egograph.io.textio import int_stem, iter_rows, listed_files, make_record, parse_float, parse_int, write_text_dir

T = TypeVar("T")

METADATA_FILES = frozenset({"intervals.json", "config.yaml", "egograph.json"})
"""Files a results folder may hold beside its per-frame ``<ts>.txt`` (the tracker's intervals, the
resolved configuration and the run record, see :mod:`egograph.steps.outputs`); readers skip them."""


# --------------------------------------------------------------------------- per-frame folders


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
    files = [f for f in listed_files(path, "per-frame") if f.name not in METADATA_FILES]
    if timestamps is not None:
        names = {f.name for f in files}
        out: dict[int, list[T]] = {}
        for ts in sorted({as_int(t, "timestamp") for t in timestamps}):
            name = f"{ts}.txt"
            out[ts] = read_one(path / name) if name in names else []
        return out
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
            parse_float(tok[5], path, n, "det_conf")  # validated, then dropped
            score = parse_float(tok[6], path, n, "similarity")
        elif len(tok) == 6:
            score = parse_float(tok[5], path, n, "score")
        else:
            score = 1.0
        out.append(make_record(path, n, Detection, inst, box, score))
    return out


def _detections_text(dets: Iterable[Detection], box_format: str) -> str:
    check_box_format(box_format)
    return "".join(
        " ".join([str(check_instance_id(d.instance)), *box_fields(d.box, box_format), format_number(d.score)]) + "\n"
        for d in dets
    )


def write_detection_file(path: str | Path, dets: Iterable[Detection], box_format: str = "xyxy") -> None:
    """Write one frame's detections as ``instance x1 y1 x2 y2 score`` rows, atomically."""
    atomic_write_text(path, _detections_text(dets, box_format))


def read_detection_dir(
    path: str | Path, timestamps: Iterable[int] | None = None, box_format: str = "xyxy"
) -> dict[int, list[Detection]]:
    """``ts -> detections`` for a folder of ``<ts>.txt`` files, in numeric ts order.

    With ``timestamps``, every given timestamp is a key (missing file -> []).
    """
    check_box_format(box_format)
    return _read_frame_dir(path, timestamps, lambda p: read_detection_file(p, box_format))


def write_detection_dir(
    path: str | Path, per_frame: Mapping[int, Iterable[Detection]], box_format: str = "xyxy"
) -> None:
    """Write one ``<ts>.txt`` per key of ``per_frame``; the folder is replaced atomically."""
    files = {f"{as_int(ts, 'timestamp')}.txt": _detections_text(dets, box_format) for ts, dets in per_frame.items()}
    write_text_dir(path, files)


# --------------------------------------------------------------------------- tracker results


def read_results_file(path: str | Path) -> list[Prediction]:
    """Predictions of one frame (``instance x y z score``, world frame, metres), in file order."""
    path = Path(path)
    out = []
    for n, tok in iter_rows(path, 5, layout="instance x y z score"):
        inst = parse_int(tok[0], path, n, "instance")
        xyz = tuple(parse_float(t, path, n, a) for t, a in zip(tok[1:4], "xyz"))
        score = parse_float(tok[4], path, n, "score")
        out.append(make_record(path, n, Prediction, inst, xyz, score))
    return out


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
