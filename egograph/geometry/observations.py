"""3D observations: detections lifted with depth, stored column-wise (one row per detection).

World frame = the recording's world (metres). ``candidates`` hold the AHAT alias
alternatives of each observation: the world points at ranges ``r + k·alias`` along the
same ray (NaN where beyond the sensor's reach); ``chosen`` is the index of the candidate
``world`` equals.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
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

    def __len__(self) -> int:
        return len(self.timestamps)

    @property
    def valid(self) -> np.ndarray:
        """Rows with a lifted 3D point."""
        return np.isfinite(self.world).all(axis=1)

    def select(self, mask: np.ndarray) -> "Observations":
        return Observations(**{f.name: getattr(self, f.name)[mask] for f in fields(self)})

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
        for f in fields(cls):
            arrs = []
            for p in parts:
                a = getattr(p, f.name)
                if f.name == "candidates" and a.shape[1] < k:
                    a = np.concatenate([a, np.full((len(a), k - a.shape[1], 3), np.nan)], axis=1)
                arrs.append(a)
            out[f.name] = np.concatenate(arrs)
        return cls(**out)

    def save(self, path: str | Path) -> None:
        """Write as a compressed ``.npz`` (atomically)."""
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, **{f.name: getattr(self, f.name) for f in fields(self)})

    @classmethod
    def load(cls, path: str | Path) -> "Observations":
        path = Path(path)
        try:
            with np.load(path) as data:
                missing = [f.name for f in fields(cls) if f.name not in data]
                if missing:
                    raise InputError(path, f"not an observations file: missing {', '.join(missing)}")
                return cls(**{f.name: data[f.name] for f in fields(cls)})
        except FileNotFoundError:
            raise InputError(path, "observations file not found") from None
        except (ValueError, OSError) as exc:
            raise InputError(path, f"unreadable observations file ({exc})") from None
