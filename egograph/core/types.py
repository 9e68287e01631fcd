"""The records every layer passes around, in the field's words.

Units and frames: boxes in PV image pixels (1280x720, x right, y down); positions in the
recording's world frame, metres; covariances in m^2; timestamps in HoloLens ticks (100 ns,
exact Python ints; :data:`egograph.core.units.TICKS_PER_SECOND`). Instance ids are zero-based
(line order of ``labels.csv``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from egograph.core.values import as_finite, check_instance_id, format_number


@dataclass(frozen=True, slots=True)
class Box:
    """Axis-aligned image box in pixels: ``x_min <= x_max``, ``y_min <= y_max``, finite."""

    x_min: float
    y_min: float
    x_max: float
    y_max: float

    def __post_init__(self) -> None:
        for name in ("x_min", "y_min", "x_max", "y_max"):
            object.__setattr__(self, name, as_finite(getattr(self, name), f"box {name}"))
        if self.x_max < self.x_min:
            raise ValueError(f"box x_max {format_number(self.x_max)} < x_min {format_number(self.x_min)}")
        if self.y_max < self.y_min:
            raise ValueError(f"box y_max {format_number(self.y_max)} < y_min {format_number(self.y_min)}")

    @classmethod
    def from_xywh(cls, x: float, y: float, w: float, h: float) -> Box:
        """Box from top-left corner and size (pixels); negative sizes are refused."""
        if w < 0 or h < 0:
            raise ValueError(f"box width/height must not be negative, got w={w!r} h={h!r}")
        return cls(x, y, x + w, y + h)

    def to_xywh(self) -> tuple[float, float, float, float]:
        """``(x_min, y_min, width, height)`` in pixels."""
        return (self.x_min, self.y_min, self.width, self.height)

    @property
    def width(self) -> float:
        return self.x_max - self.x_min

    @property
    def height(self) -> float:
        return self.y_max - self.y_min

    @property
    def area(self) -> float:
        return self.width * self.height

    @property
    def center(self) -> tuple[float, float]:
        return (0.5 * (self.x_min + self.x_max), 0.5 * (self.y_min + self.y_max))

    def clip(self, width: float, height: float) -> Box | None:
        """The part inside the image ``[0, width] x [0, height]``; None if no area is left."""
        x0, y0 = max(self.x_min, 0.0), max(self.y_min, 0.0)
        x1, y1 = min(self.x_max, float(width)), min(self.y_max, float(height))
        if x1 <= x0 or y1 <= y0:
            return None
        return Box(x0, y0, x1, y1)


@dataclass(frozen=True, slots=True)
class Detection:
    """A 2D box (PV pixels) associated with ``instance``, with a finite ``score``."""

    instance: int
    box: Box
    score: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "instance", check_instance_id(self.instance))
        if not isinstance(self.box, Box):
            raise TypeError(f"box must be a Box, got {type(self.box).__name__}")
        object.__setattr__(self, "score", as_finite(self.score, "score"))


@dataclass(frozen=True, slots=True)
class Prediction:
    """Predicted centre of ``instance`` in the world frame (metres), with a finite ``score``."""

    instance: int
    xyz: tuple[float, float, float]
    score: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "instance", check_instance_id(self.instance))
        values = tuple(self.xyz)
        if len(values) != 3:
            raise ValueError(f"xyz must have 3 values, got {len(values)}")
        object.__setattr__(self, "xyz", tuple(as_finite(v, "xyz") for v in values))
        object.__setattr__(self, "score", as_finite(self.score, "score"))


def predictions_of(instance: int, xyz: np.ndarray, score: np.ndarray) -> list[Prediction]:
    """One instance's :class:`Prediction` per row of ``xyz`` (N, 3), world, metres, and ``score``
    (N,): equal to building each with ``Prediction(...)``, checked for all rows at once (a tracker
    answers every frame for every instance: 80,000 checks one by one cost more than the answers)."""
    instance = check_instance_id(instance)
    xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
    score = np.asarray(score, dtype=float).reshape(-1)
    if len(score) != len(xyz):
        raise ValueError(f"{len(xyz)} positions but {len(score)} scores")
    bad = ~(np.isfinite(xyz).all(axis=1) & np.isfinite(score))
    if bad.any():
        j = int(np.flatnonzero(bad)[0])
        raise ValueError(f"xyz and score must be finite, got {xyz[j].tolist()!r} and {score[j]!r} (row {j})")
    new, put = object.__new__, object.__setattr__
    out = []
    for (x, y, z), s in zip(xyz.tolist(), score.tolist()):
        p = new(Prediction)
        put(p, "instance", instance)
        put(p, "xyz", (x, y, z))
        put(p, "score", s)
        out.append(p)
    return out


@dataclass
class PositionInterval:
    instance: int
    t_start: int                 # first PV frame covered, 100 ns ticks
    t_end: int                   # last PV frame covered (inclusive), ticks
    xyz: tuple[float, float, float]  # world frame, metres
    covariance: list[list[float]]    # 3x3, m^2, world frame
    n_observations: int          # detections that support the position (inliers)
    confidence: float            # 0-1: belief that the object really stood here
    first_seen: int = 0          # timestamp of the first supporting detection (ticks)
    last_seen: int = 0           # timestamp of the last supporting detection (ticks)
    backfilled: bool = False     # t_start was extended to the start of the recording (offline)
    ended_by: str = ""           # what closed it: 'detection' elsewhere, 'negative' evidence, 'end' of recording
    extra: dict = field(default_factory=dict)

    @property
    def sigma_m(self) -> float:
        """Root of the largest covariance eigenvalue, metres."""
        return float(np.sqrt(np.linalg.eigvalsh(np.asarray(self.covariance)).max()))


@dataclass
class TrackResult:
    """What every tracker returns: a prediction per PV frame and, for trackers that estimate
    them, the position intervals behind those predictions.

    ``per_frame``: ``{timestamp: [Prediction]}`` for every PV frame (``[]`` where nothing is
    predicted). ``intervals``: ``None`` for per-frame trackers (``memory``, ``kf``), else the
    intervals the per-frame predictions were made from, which the evaluation scores as they are.
    ``metadata``: tracker name, its configuration and whatever it reports about its run.
    ``solutions``: tracker-specific per-instance detail (the graph's segments and switches).
    ``answers``: for trackers that answer every frame with a confidence (the graph trackers), every
    answer ``{timestamp: [Prediction]}``; ``per_frame`` then holds those of at least the operating
    point's confidence (``graph.answers.min_confidence``). None: ``per_frame`` is every answer.
    """

    per_frame: dict
    intervals: list | None = None
    metadata: dict = field(default_factory=dict)
    solutions: list = field(default_factory=list)
    answers: dict | None = None

    @property
    def n_predictions(self) -> int:
        return sum(len(v) for v in self.per_frame.values())
