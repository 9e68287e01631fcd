"""Step ``smooth``: another tracker's per-frame results as observations of the factor graph
(the "+graph" row beside the paper's "+KF")."""

from __future__ import annotations

from pathlib import Path

from egograph.core.types import TrackResult
from egograph.io.recording import Recording
from egograph.steps import outputs
from egograph.steps.track import read_result, tracker_sections, write_result


def smooth(rec: Recording, results: str | Path | TrackResult, cfg, out: str | Path | None = None, *,
           causal: bool = False, overwrite: bool = False, progress: bool = False) -> TrackResult:
    """``results`` (a results folder or a TrackResult) smoothed into position intervals with
    ``cfg.graph``; with ``out``, written (or read back) as a results folder."""
    from egograph.track.smooth import smooth_predictions

    source = results if isinstance(results, TrackResult) else read_result(results, rec)
    inputs = {"recording": outputs.recording_digest(rec), "causal": causal,
              "results": str(results) if not isinstance(results, TrackResult) else "in memory",
              "predictions": outputs.digest(sorted((t, [(p.instance, p.xyz, p.score) for p in v])
                                                   for t, v in source.per_frame.items()))}
    record = outputs.run_record("smooth", cfg, inputs, depends_on=tracker_sections(cfg))
    if outputs.up_to_date(out, record, overwrite):
        return read_result(out, rec)
    result = smooth_predictions(rec, source.per_frame, cfg.graph, causal=causal, progress=progress)
    if not isinstance(results, TrackResult):
        result.metadata["smoothed"] = str(results)
    if out is not None:
        write_result(out, rec, result, record, cfg)
    return result
