"""Position intervals: where an instance stood, from when to when, and how sure we are.

A :class:`PositionInterval` covers PV frames ``[t_start, t_end]`` (100 ns ticks,
inclusive) with a world-frame centre ``xyz`` (metres) and its 3x3 covariance (m^2).
:func:`per_frame_predictions` turns intervals into the reference per-frame results
(one :class:`~egograph.io.detections.Prediction` per instance whose interval covers
the frame); :func:`write_intervals_json` / :func:`read_intervals_json` round-trip them.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Sequence

import numpy as np

from egograph.core.errors import InputError
from egograph.core.types import PositionInterval, Prediction
from egograph.core.units import TICKS_PER_SECOND
from egograph.core.values import without_wall_clock
from egograph.io.atomic import atomic_write_text
from egograph.io.textio import read_json_checked


def per_frame_predictions(intervals: Sequence[PositionInterval], timestamps: Sequence[int]) -> dict[int, list[Prediction]]:
    """For every PV frame (ticks): one prediction per instance whose interval covers it,
    scored with the interval's confidence; ``[]`` where none does."""
    ts = np.asarray(sorted(int(t) for t in timestamps), dtype=np.int64)
    rows: list[list[tuple[int, Prediction]]] = [[] for _ in ts]
    for iv in intervals:
        lo, hi = np.searchsorted(ts, iv.t_start, "left"), np.searchsorted(ts, iv.t_end, "right")
        pred = Prediction(iv.instance, tuple(float(v) for v in iv.xyz), float(iv.confidence))
        for k in range(lo, hi):
            rows[k].append((iv.instance, pred))
    out = {}
    for t, row in zip(ts, rows):
        seen: dict[int, Prediction] = {}
        for inst, pred in row:  # overlapping intervals of one instance: the later one wins
            seen[inst] = pred
        out[int(t)] = [seen[i] for i in sorted(seen)]
    return out


SCHEMA_VERSION = 1
"""Version of the intervals JSON layout (:func:`intervals_json_text`); readers accept this one and
the unversioned files of egograph 0.1 (``{"metadata", "intervals"}`` only)."""

UNITS = {"xyz": "m, recording world frame", "covariance": "m^2, world frame", "sigma_m": "m",
         "t_start/t_end/first_seen/last_seen": "HoloLens ticks (100 ns), inclusive",
         "t_start_s/t_end_s": "s from the first PV frame", "frame_start/frame_end": "PV frame index, inclusive"}

_DERIVED = ("name", "t_start_s", "t_end_s", "frame_start", "frame_end", "sigma_m")


def intervals_json_text(intervals: Sequence[PositionInterval], metadata: dict, *,
                        timestamps: Sequence[int] | None = None, labels: Sequence[str] | None = None,
                        sequence: str | None = None) -> str:
    """The intervals document: ``schema_version``, ``units``, ``sequence``, the time base
    (``first_frame_ticks``, ``n_frames``), ``instances`` (names, index = id), ``metadata`` and one
    entry per interval with its ticks, seconds from the first frame, frame indices and name."""
    ts = np.asarray(sorted(int(t) for t in timestamps), np.int64) if timestamps is not None else None
    t0 = int(ts[0]) if ts is not None and len(ts) else None
    rows = []
    for iv in intervals:
        row = asdict(iv)
        if labels is not None and 0 <= iv.instance < len(labels):
            row["name"] = labels[iv.instance]
        if t0 is not None:
            row["t_start_s"] = (int(iv.t_start) - t0) / TICKS_PER_SECOND
            row["t_end_s"] = (int(iv.t_end) - t0) / TICKS_PER_SECOND
            row["frame_start"] = int(np.searchsorted(ts, int(iv.t_start), "left"))
            row["frame_end"] = int(np.searchsorted(ts, int(iv.t_end), "right")) - 1
        row["sigma_m"] = iv.sigma_m
        rows.append(row)
    doc = {"schema_version": SCHEMA_VERSION, "units": UNITS, "sequence": sequence,
           "first_frame_ticks": t0, "n_frames": None if ts is None else len(ts),
           "instances": list(labels) if labels is not None else None,
           "metadata": without_wall_clock(metadata), "intervals": rows}
    return json.dumps(doc, indent=1) + "\n"


def write_intervals_json(path: str | Path, intervals: Sequence[PositionInterval], metadata: dict, **context) -> None:
    """:func:`intervals_json_text` written atomically (``context``: timestamps, labels, sequence)."""
    atomic_write_text(path, intervals_json_text(intervals, metadata, **context))


def read_intervals_json(path: str | Path) -> tuple[list[PositionInterval], dict]:
    """Read what :func:`write_intervals_json` wrote; errors name the file and the entry."""
    path = Path(path)
    doc = read_json_checked(path, "intervals file")
    if not isinstance(doc, dict) or not isinstance(doc.get("intervals", []), list):
        raise InputError(path, "not an intervals file (a JSON object with an 'intervals' list)")
    version = doc.get("schema_version")
    if version is not None and version != SCHEMA_VERSION:
        raise InputError(path, f"intervals schema_version {version!r}: this egograph reads {SCHEMA_VERSION}")
    out = []
    for k, row in enumerate(doc.get("intervals", [])):
        try:
            if not isinstance(row, dict):
                raise TypeError("not a JSON object")
            iv = PositionInterval(**{key: v for key, v in row.items() if key not in _DERIVED})
            iv.xyz = tuple(float(v) for v in iv.xyz)
            cov = np.asarray(iv.covariance, dtype=float)
            if cov.shape != (3, 3) or int(iv.t_end) < int(iv.t_start):
                raise ValueError("covariance must be 3x3 and t_end >= t_start")
        except (TypeError, ValueError) as exc:
            raise InputError(path, f"interval {k}: {exc}") from None
        out.append(iv)
    return out, doc.get("metadata", {})
