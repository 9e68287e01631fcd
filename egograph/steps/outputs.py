"""Self-describing, reproducible outputs and the skip rule of every step.

Every output folder a step writes holds, beside its data, ``config.yaml`` (the resolved
configuration: ``--config config.yaml`` runs it again) and ``egograph.json`` (the run record:
step, egograph version, command line, inputs and the fingerprint of all of them). A step called
with ``overwrite=False`` whose output already carries the same fingerprint returns the result read
back from disk instead of computing it again. File outputs (observations ``.npz``) carry the same
record inside the file.

No wall-clock time is recorded: the same inputs, configuration and command give the same bytes.
"""

from __future__ import annotations

import hashlib
import json
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np

from egograph import __version__
from egograph.core.config import to_dict, to_yaml

RUN_FILE = "egograph.json"
CONFIG_FILE = "config.yaml"


def command_line(argv: list[str] | None = None) -> str:
    """The command that is running, as a shell line (``egograph track ...`` for the CLI)."""
    argv = list(sys.argv if argv is None else argv)
    if argv and Path(argv[0]).name in ("egograph", "__main__.py", "-c"):
        argv[0] = "egograph"
    return shlex.join(argv)


def digest(*parts: Any) -> str:
    """sha256 (hex, 16 chars) of JSON-able parts and numpy arrays, order-sensitive."""
    h = hashlib.sha256()
    for p in parts:
        if isinstance(p, np.ndarray):
            a = np.ascontiguousarray(p)
            h.update(f"{a.dtype}{a.shape}".encode())
            h.update(a.tobytes())
        else:
            h.update(json.dumps(p, sort_keys=True, default=str).encode())
    return h.hexdigest()[:16]


def recording_digest(rec) -> dict:
    """What of a recording every step depends on, cheaply: its name, frame timestamps and poses (so
    refined poses give a different digest); depth and PV images are not hashed (use overwrite=True
    after editing them in place)."""
    return {"sequence": rec.name, "path": str(rec.seq_dir), "frames": len(rec),
            "poses": digest(rec.timestamps, rec.pv_poses, rec.pv_valid, rec.depth_poses, rec.depth_valid),
            "timestamps": digest(rec.timestamps)}


def check_belongs(rec, recorded: dict | None, what: Path | str, kind: str) -> None:
    """Refuse (InputError) an earlier output ``what`` (results, observations, detections, poses)
    whose run record says it was made from another recording than ``rec``: another sequence, frame
    count or PV timestamps (refined poses of the same recording pass). ``recorded`` is the record's
    ``recording`` entry (:func:`recording_digest`); None (a third-party folder, no record) is
    accepted with a one-line warning of what could not be checked."""
    import warnings

    from egograph.core.errors import InputError

    if not isinstance(recorded, dict):
        # From this line (stacklevel 1), so the "default" filter says it once per run and input.
        warnings.warn(f"{what}: {kind} without an egograph run record: cannot check that they belong to "
                      f"recording {rec.seq_dir} (sequence {rec.name})", stacklevel=1)
        return
    mine = recording_digest(rec)
    keys = [k for k in ("sequence", "frames", "timestamps") if k in recorded]
    if "timestamps" not in recorded and recorded.get("poses") == mine["poses"]:
        return
    differ = [k for k in keys if recorded.get(k) != mine[k]]
    if not differ and "timestamps" not in recorded:
        # An older record: the same name and length, other poses (refined, or another recording).
        # A recorded sequence folder that exists and is not this one says which.
        theirs = Path(str(recorded.get("path", "")))
        if recorded.get("path") and theirs.is_dir() and theirs.resolve() != Path(rec.seq_dir).resolve():
            differ = ["path"]
    if not differ and "timestamps" not in recorded:
        warnings.warn(f"{what}: {kind} recorded by an older egograph; only its sequence name and frame count "
                      f"could be checked against {rec.seq_dir}", stacklevel=3)
        return
    if differ:
        theirs = f"{recorded.get('path', '?')} (sequence {recorded.get('sequence')}, {recorded.get('frames')} frames)"
        ours = f"{rec.seq_dir} (sequence {rec.name}, {len(rec)} frames)"
        why = "other PV timestamps" if differ == ["timestamps"] else "other " + ", ".join(differ)
        raise InputError(what, f"{kind} made from recording {theirs}, not from the recording given, {ours} "
                               f"({why}); give the recording they were made from")


def check_results_belong(rec, folder: Path | str, kind: str = "results") -> None:
    """:func:`check_belongs` for an output folder of egograph (its ``egograph.json``)."""
    folder = Path(folder)
    record = previous_record(folder)
    recorded = None
    if record is not None:
        inputs = record.get("inputs") or {}
        recorded = inputs.get("recording") if isinstance(inputs, dict) else None
    check_belongs(rec, recorded, folder, kind)


def folder_digest(path: Path) -> str:
    """Digest of a folder of small text files (names and contents), e.g. a detections folder."""
    path = Path(path)
    h = hashlib.sha256()
    for f in sorted(p for p in path.iterdir() if p.is_file() and not p.name.startswith(".")):
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def config_yaml(cfg) -> str:
    """The resolved configuration as YAML that ``load_config`` reads back (each knob's doc above it)."""
    return to_yaml(cfg)


def run_record(step: str, cfg, inputs: dict, depends_on: dict | None = None, argv: list[str] | None = None) -> dict:
    """The run record of a step: what made the output. ``fingerprint`` covers step, version, inputs
    and ``depends_on`` (the configuration sections the result depends on; default the whole
    configuration); the command line is recorded but not part of it."""
    config = to_dict(cfg) if cfg is not None else None
    deps = config if depends_on is None else depends_on
    return {"step": step, "egograph_version": __version__, "command": command_line(argv),
            "inputs": inputs, "config": config, "fingerprint": digest(step, __version__, inputs, deps)}


def run_files(record: dict, cfg) -> dict[str, str]:
    """``{config.yaml, egograph.json}`` texts for an output folder."""
    files = {RUN_FILE: json.dumps(record, indent=1, default=str) + "\n"}
    if cfg is not None:
        files[CONFIG_FILE] = config_yaml(cfg)
    return files


def write_run_files(folder: Path, record: dict, cfg) -> None:
    """Write the run files into a folder being built (a temporary folder before its rename)."""
    for name, text in run_files(record, cfg).items():
        (Path(folder) / name).write_text(text)


def previous_record(out: Path) -> dict | None:
    """The run record of an existing output folder, or None."""
    f = Path(out) / RUN_FILE
    if not f.is_file():
        return None
    try:
        record = json.loads(f.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None  # not a record this egograph wrote: the step runs again
    return record if isinstance(record, dict) else None


def up_to_date(out: Path | None, record: dict, overwrite: bool) -> bool:
    """Whether ``out`` already holds the output of exactly this run (same fingerprint)."""
    if out is None or overwrite:
        return False
    prev = previous_record(out)
    return prev is not None and prev.get("fingerprint") == record["fingerprint"]
