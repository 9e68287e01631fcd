"""Step ``smooth``: another tracker's per-frame results as observations of the factor graph
(the "+graph" row beside the paper's "+KF")."""

from __future__ import annotations

import warnings
from pathlib import Path

from egograph.core.errors import InputError
from egograph.core.types import TrackResult
from egograph.io.recording import Recording
from egograph.steps import outputs
from egograph.steps.track import read_result, tracker_sections, write_result


def smooth(rec: Recording, results: str | Path | TrackResult, cfg, out: str | Path | None = None, *,
           causal: bool = False, overwrite: bool = False, progress: bool = False) -> TrackResult:
    """``results`` (a results folder or a TrackResult) smoothed into position intervals with
    ``cfg.graph``; with ``out``, written (or read back) as a results folder."""
    from egograph.track.smooth import smooth_predictions

    source = results if isinstance(results, TrackResult) else usable_results(results, rec)
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


def usable_results(results: str | Path, rec: Recording) -> TrackResult:
    """A results folder read for smoothing: lines for instances the recording's labels do not have
    are dropped, and PV frames without a file counted, each with a warning; no prediction left ->
    InputError (nothing to smooth)."""
    from egograph.steps.recording import n_instances

    path = Path(results)
    source = read_result(path, rec)
    n_inst = n_instances(rec)
    if n_inst is not None:
        unknown = sum(p.instance >= n_inst for v in source.per_frame.values() for p in v)
        if unknown:
            source.per_frame = {t: [p for p in v if p.instance < n_inst] for t, v in source.per_frame.items()}
            warnings.warn(f"{path}: {unknown} result line(s) for instance ids outside the {n_inst} labels ignored",
                          stacklevel=3)
    missing = [int(t) for t in rec.timestamps if not (path / f"{int(t)}.txt").is_file()]
    if not any(source.per_frame.values()):
        raise InputError(path, f"no usable prediction in any result file (<ts>.txt per PV frame, lines 'instance x y "
                               f"z score'; {len(missing)} of {len(rec.timestamps)} PV frames have no file): nothing "
                               f"to smooth")
    if missing:
        warnings.warn(f"{path}: {len(missing)} of {len(rec.timestamps)} PV frames have no result file (e.g. "
                      f"{missing[0]}.txt); smoothed as frames without predictions", stacklevel=3)
    return source
