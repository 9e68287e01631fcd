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
from egograph.io.atomic import atomic_write_text


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


def write_intervals_json(path: str | Path, intervals: Sequence[PositionInterval], metadata: dict) -> None:
    """``{"metadata": {...}, "intervals": [...]}`` written atomically."""
    doc = {"metadata": metadata, "intervals": [asdict(iv) for iv in intervals]}
    atomic_write_text(path, json.dumps(doc, indent=1) + "\n")


def read_intervals_json(path: str | Path) -> tuple[list[PositionInterval], dict]:
    """Read what :func:`write_intervals_json` wrote; errors name the file and the entry."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(path, "intervals file not found") from None
    except json.JSONDecodeError as exc:
        raise InputError(path, f"not JSON ({exc.msg})", exc.lineno) from None
    out = []
    for k, row in enumerate(doc.get("intervals", [])):
        try:
            iv = PositionInterval(**row)
            iv.xyz = tuple(float(v) for v in iv.xyz)
            cov = np.asarray(iv.covariance, dtype=float)
            if cov.shape != (3, 3) or int(iv.t_end) < int(iv.t_start):
                raise ValueError("covariance must be 3x3 and t_end >= t_start")
        except (TypeError, ValueError) as exc:
            raise InputError(path, f"interval {k}: {exc}") from None
        out.append(iv)
    return out, doc.get("metadata", {})
