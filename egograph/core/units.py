"""Time and image constants shared by every layer (one definition each)."""

TICKS_PER_SECOND = 10_000_000
"""HoloLens timestamps count 100 ns ticks; seconds = ticks / TICKS_PER_SECOND."""

PV_WIDTH = 1280
"""PV (RGB) image width, pixels."""

PV_HEIGHT = 720
"""PV (RGB) image height, pixels."""


def ticks_to_seconds(ticks, origin=0):
    """Seconds from ``origin`` (ticks) of ``ticks`` (int, or numpy array of int64)."""
    return (ticks - origin) / TICKS_PER_SECOND
