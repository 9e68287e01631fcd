"""Step ``track``: observations -> a :class:`~egograph.core.types.TrackResult`, written as one
results folder (``<ts>.txt`` per PV frame in the reference format, ``intervals.json`` for the
interval trackers, ``config.yaml``, ``egograph.json``), committed by one rename."""

from __future__ import annotations

from pathlib import Path

from egograph.core.config import to_dict
from egograph.core.types import TrackResult
from egograph.geometry.observations import Observations
from egograph.io.detections import ANSWERS_FILE, answers_text, read_answers_file, read_results_dir, write_results_dir
from egograph.io.recording import Recording
from egograph.steps import outputs
from egograph.steps.recording import labels
from egograph.track.registry import get_tracker

INTERVALS_FILE = "intervals.json"


def tracker_sections(cfg) -> dict:
    """The configuration sections a tracker's result depends on."""
    return {k: to_dict(getattr(cfg, k)) for k in ("track", "graph", "joint", "refine") if hasattr(cfg, k)}


def observations_id(obs: Observations) -> dict:
    """Provenance and a content digest of observations (content: they may come from anywhere)."""
    return {"provenance": obs.provenance,
            "digest": outputs.digest(obs.timestamps, obs.instance, obs.score, obs.world, obs.candidates)}


def results_files(rec: Recording, result: TrackResult, record: dict, cfg) -> dict[str, str]:
    """The metadata files of a results folder (run record, configuration, intervals)."""
    from egograph.track.intervals import intervals_json_text

    files = outputs.run_files(record, cfg)
    if result.intervals is not None:
        files[INTERVALS_FILE] = intervals_json_text(result.intervals, result.metadata, timestamps=rec.timestamps,
                                                    labels=labels(rec), sequence=rec.name)
    if result.answers is not None:
        files[ANSWERS_FILE] = answers_text(result.answers)
    return files


def write_result(out: str | Path, rec: Recording, result: TrackResult, record: dict, cfg) -> Path:
    """Write a results folder atomically (one rename for the per-frame files and the metadata)."""
    write_results_dir(out, result.per_frame, [int(t) for t in rec.timestamps],
                      extra_files=results_files(rec, result, record, cfg))
    return Path(out)


def write_results(out: str | Path, rec: Recording, per_frame: dict, answers: dict | None = None) -> None:
    """Only the per-frame files (the reference format) and, when given, every answer
    (``answers.tsv``), for callers that keep no run record."""
    extra = {ANSWERS_FILE: answers_text(answers)} if answers is not None else None
    write_results_dir(out, per_frame, [int(t) for t in rec.timestamps], extra_files=extra)


def read_result(path: str | Path, rec: Recording) -> TrackResult:
    """A results folder read back: per-frame predictions, and the intervals when it holds them."""
    from egograph.track.intervals import read_intervals_json

    path = Path(path)
    outputs.check_results_belong(rec, path)
    per_frame = read_results_dir(path, rec.timestamps)
    intervals, metadata = None, {}
    if (path / INTERVALS_FILE).is_file():
        intervals, metadata = read_intervals_json(path / INTERVALS_FILE)
    prev = outputs.previous_record(path)
    if prev is not None:
        metadata = {**metadata, "run": {k: prev.get(k) for k in ("step", "command", "egograph_version")}}
    answers = read_answers_file(path / ANSWERS_FILE) if (path / ANSWERS_FILE).is_file() else None
    return TrackResult(per_frame=per_frame, intervals=intervals, metadata=metadata, answers=answers)


def track(rec: Recording, tracker: str, obs: Observations, cfg, out: str | Path | None = None, *,
          overwrite: bool = False, progress: bool = False) -> TrackResult:
    """Run the named tracker on ``obs`` (lifted from ``rec``); with ``out``, write the results folder,
    or read it back when it already holds this exact run (same tracker, observations, configuration)."""
    run = get_tracker(tracker)
    record = outputs.run_record("track", cfg, {"tracker": tracker, "recording": outputs.recording_digest(rec),
                                               "observations": observations_id(obs)},
                                depends_on=tracker_sections(cfg))
    if outputs.up_to_date(out, record, overwrite):
        return read_result(out, rec)
    result = run(rec, obs, cfg, progress=progress)
    result.metadata.setdefault("tracker", tracker)
    if out is not None:
        write_result(out, rec, result, record, cfg)
    return result
