"""The causal (and lagged) graph tracker over a whole recording: the observations replayed
frame by frame through :class:`egograph.track.online.OnlineTracker`.

A frame's answer uses only the observations and depth frames up to that frame (lag 0), or up
to ``lag_s`` seconds after it. World frame, metres; PV frame indices and 100 ns ticks.
"""

from __future__ import annotations

import numpy as np

from egograph.core.types import PositionInterval, Prediction
from egograph.geometry.observations import Observations
from egograph.track.config import GraphConfig
from egograph.track.online import run_online
from egograph.track.segments import InstanceSolution, NegativeFn, SupportFn


def causal_tracker(obs: Observations, t_frames: np.ndarray, cfg: GraphConfig, ids: list[int], *,
                   lag_s: float | None = None, negative: NegativeFn | None = None,
                   support: SupportFn | None = None,
                   ) -> tuple[dict[int, list[Prediction]], list[PositionInterval], list[InstanceSolution], list[float]]:
    """Per-frame answers (ticks -> predictions), the stands' intervals, one
    :class:`InstanceSolution` per instance of ``ids`` (its switches and counts) and the detection
    noise scales used, in order (one unless ``graph.noise.online_auto``); ``obs`` are the
    observations of every instance (the tracker applies ``cfg.score_threshold``)."""
    sub = obs.select(np.isin(obs.instance, np.asarray(ids, dtype=obs.instance.dtype)))
    per_frame, trk = run_online(sub, t_frames, cfg, lag_s=lag_s, negative=negative, support=support)
    intervals = trk.intervals()
    solutions = []
    for i in ids:
        st = trk.inst.get(i)
        ivs = [iv for iv in intervals if iv.instance == i]
        if st is None:
            solutions.append(InstanceSolution(i, ivs))
        else:
            solutions.append(InstanceSolution(i, ivs, np.zeros(0), st.n_rows, len(st.places), places=list(st.places)))
    return per_frame, intervals, solutions, list(trk.scales)
