"""egograph: offline factor-graph tracking of object instances in egocentric HoloLens 2 recordings."""

__version__ = "0.1.0"
