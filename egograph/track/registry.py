"""One registry of trackers: name -> ``run(rec, obs, cfg) -> TrackResult``.

``cfg`` is the pipeline configuration (any object with the ``track``, ``graph``, ``joint`` and
``refine`` sections of :class:`egograph.steps.settings.EgographConfig`); ``rec`` the
:class:`~egograph.io.recording.Recording` the observations were lifted from (the graph reads its
depth frames and mesh for negative evidence and the support test). Every tracker returns a
:class:`~egograph.core.types.TrackResult`; per-frame trackers leave ``intervals`` None.
"""

from __future__ import annotations

from typing import Callable

from egograph.core.errors import ConfigError
from egograph.core.types import TrackResult


def _baseline(name: str) -> Callable:
    def run(rec, obs, cfg, progress: bool = False) -> TrackResult:
        from egograph.track.baselines import kalman_tracker, memory_tracker

        fn = {"memory": memory_tracker, "kf": kalman_tracker}[name]
        return TrackResult(per_frame=fn(obs, rec.timestamps, cfg.track), metadata={"tracker": name})
    return run


def _graph(causal: bool) -> Callable:
    def run(rec, obs, cfg, progress: bool = False) -> TrackResult:
        return graph_with_scene(rec, obs, cfg, causal=causal, progress=progress)
    return run


def graph_with_scene(rec, obs, cfg, causal: bool = False, progress: bool = False) -> TrackResult:
    """The factor-graph tracker with negative evidence from the recording's depth
    (``cfg.graph.negative_evidence``) and the support test against its mesh
    (``cfg.graph.max_support_gap_m``)."""
    from egograph.track.graph import graph_tracker
    from egograph.track.negative import NegativeEvidence

    scene = None
    if cfg.graph.negative_evidence or cfg.graph.max_support_gap_m > 0:
        scene = NegativeEvidence(rec, obs, cfg.graph.negative, cfg.graph.score_threshold)
    negative = scene if cfg.graph.negative_evidence else None
    support = None
    if scene is not None and scene.scene is not None and cfg.graph.max_support_gap_m > 0:
        gap = cfg.graph.max_support_gap_m
        support = lambda xyz: scene.supported(xyz, gap)  # noqa: E731
    result = graph_tracker(obs, rec.timestamps, cfg.graph, causal=causal, negative=negative, support=support,
                           progress=progress)
    if negative is not None:
        result.metadata["negative_depth_frames_read"] = negative.n_frames_read
    return result


TRACKERS: dict[str, Callable] = {
    "graph": _graph(causal=False),
    "graph-causal": _graph(causal=True),
    "memory": _baseline("memory"),
    "kf": _baseline("kf"),
}
"""Every tracker egograph runs, by the name ``--tracker`` takes."""

INTERVAL_TRACKERS = ("graph", "graph-causal")
"""Trackers that estimate position intervals (the others predict per frame only)."""

DESCRIPTIONS = {
    "graph": "factor graph, offline (switchable motion breaks, LM smoother)",
    "graph-causal": "factor graph, online (iSAM2, egograph.track.online; a frame's answer uses the frames up to "
                    "it, or up to graph.lag_s / --lag seconds later)",
    "memory": "the paper's memory baseline (last accepted 3D position)",
    "kf": "the paper's constant-velocity Kalman filter (reset beyond 0.15 m)",
}


def get_tracker(name: str) -> Callable:
    """The tracker called ``name``; ConfigError listing the choices otherwise."""
    try:
        return TRACKERS[name]
    except KeyError:
        raise ConfigError(f"--tracker {name}: unknown; choose one of {', '.join(TRACKERS)}") from None
