"""3D observations: detections lifted with depth, stored column-wise (one row per detection).

World frame = the recording's world (metres). ``candidates`` hold the AHAT alias
alternatives of each observation: the world points at ranges ``r + k·alias`` along the
same ray (NaN where beyond the sensor's reach); ``chosen`` is the index of the candidate
``world`` equals.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from egograph.core.errors import InputError
from egograph.io.atomic import atomic_path


@dataclass
class Observations:
    timestamps: np.ndarray   # (M,) int64 PV timestamp of the detection (100 ns ticks)
    frame: np.ndarray        # (M,) int32 frame index in the recording
    instance: np.ndarray     # (M,) int32 instance id (zero-based, labels.csv order)
    score: np.ndarray        # (M,) float32 matcher similarity
    box: np.ndarray          # (M, 4) float32 PV box x1 y1 x2 y2, pixels
    world: np.ndarray        # (M, 3) float64 lifted point, world frame, metres (NaN when not lifted)
    camera: np.ndarray       # (M, 3) float64 centre of the depth camera in world, metres
    range_m: np.ndarray      # (M,) float32 range from the depth camera to the point, metres
    candidates: np.ndarray   # (M, K, 3) float64 alias alternatives in world (NaN-padded)
    chosen: np.ndarray       # (M,) int8 index into candidates of ``world`` (-1 when not lifted)
    n_pixels: np.ndarray     # (M,) int32 depth pixels that supported the estimate
    provenance: dict = field(default_factory=dict, compare=False)
    """Where the rows came from: recording, detections, lift configuration and pose source (see
    :func:`egograph.steps.lift.provenance`); saved with the arrays, so a cache cannot mix poses."""

    def __len__(self) -> int:
        return len(self.timestamps)

    @property
    def valid(self) -> np.ndarray:
        """Rows with a lifted 3D point."""
        return np.isfinite(self.world).all(axis=1)

    def select(self, mask: np.ndarray) -> "Observations":
        return Observations(**{name: getattr(self, name)[mask] for name in _ARRAYS}, provenance=self.provenance)

    @classmethod
    def empty(cls, k: int = 1) -> "Observations":
        return cls(np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros(0, np.float32),
                   np.zeros((0, 4), np.float32), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.float32),
                   np.zeros((0, k, 3)), np.zeros(0, np.int8), np.zeros(0, np.int32))

    @classmethod
    def concatenate(cls, parts: list["Observations"]) -> "Observations":
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls.empty()
        k = max(p.candidates.shape[1] for p in parts)
        out = {}
        for name in _ARRAYS:
            arrs = []
            for p in parts:
                a = getattr(p, name)
                if name == "candidates" and a.shape[1] < k:
                    a = np.concatenate([a, np.full((len(a), k - a.shape[1], 3), np.nan)], axis=1)
                arrs.append(a)
            out[name] = np.concatenate(arrs)
        return cls(**out, provenance=parts[0].provenance)

    def save(self, path: str | Path) -> None:
        """Write as a compressed ``.npz`` (atomically)."""
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:
                arrays = {name: getattr(self, name) for name in _ARRAYS}
                if self.provenance:
                    arrays["provenance"] = np.array(json.dumps(self.provenance, sort_keys=True))
                np.savez_compressed(fh, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> "Observations":
        path = Path(path)
        try:
            with np.load(path) as data:
                missing = [name for name in _ARRAYS if name not in data]
                if missing:
                    raise InputError(path, f"not an observations file: missing {', '.join(missing)}")
                prov = json.loads(str(data["provenance"])) if "provenance" in data else {}
                return cls(**{name: data[name] for name in _ARRAYS}, provenance=prov)
        except FileNotFoundError:
            raise InputError(path, "observations file not found") from None
        except (ValueError, OSError) as exc:
            raise InputError(path, f"unreadable observations file ({exc})") from None

    @staticmethod
    def read_provenance(path: str | Path) -> dict | None:
        """The provenance saved in an observations file, without loading its arrays; None when the
        file is missing, unreadable or carries none."""
        try:
            with np.load(Path(path)) as data:
                return json.loads(str(data["provenance"])) if "provenance" in data else None
        except (OSError, ValueError, KeyError):
            return None


_ARRAYS = [f.name for f in fields(Observations) if f.name != "provenance"]
