"""Checked scalar values: the one place that says what an id, a count or a score may be."""

from __future__ import annotations

import math
import operator


def as_int(value, what: str) -> int:
    """An exact int from an int-like value (int, numpy integer); floats are refused
    because a float cannot hold an 18-digit timestamp exactly."""
    try:
        return int(operator.index(value))
    except TypeError:
        raise TypeError(f"{what} must be an integer, got {value!r}") from None


def as_finite(value, what: str) -> float:
    """A finite float; NaN/inf would not read back."""
    x = float(value)
    if not math.isfinite(x):
        raise ValueError(f"{what} must be finite, got {value!r}")
    return x


def check_instance_id(instance: int) -> int:
    """An instance id as a non-negative int (ValueError/TypeError otherwise)."""
    instance = as_int(instance, "instance id")
    if instance < 0:
        raise ValueError(f"instance id {instance} is negative")
    return instance


def format_number(x: float) -> str:
    """Shortest text that reads back to the same float; integers without a decimal point."""
    xf = float(x)
    if xf.is_integer() and abs(xf) < 1e15:
        return str(int(xf))
    return repr(xf)


def without_wall_clock(obj):
    """A copy of a JSON-able report without its wall-clock times (every key ending in ``seconds``):
    written outputs hold none, so the same inputs and command give the same bytes (timings are
    printed and kept in memory instead)."""
    if isinstance(obj, dict):
        return {k: without_wall_clock(v) for k, v in obj.items() if not str(k).endswith("seconds")}
    if isinstance(obj, (list, tuple)):
        return [without_wall_clock(v) for v in obj]
    return obj
