"""Step ``synth``: a synthetic recording in the IT3DEgo layout (truth in ``synth_gt/``)."""

from __future__ import annotations

import json
from pathlib import Path

from egograph.core.config import to_dict
from egograph.steps import outputs


def synth(out: str | Path, cfg, seed: int, *, overwrite: bool = False, progress: bool = True):
    """Generate (or, with ``overwrite=False``, keep) the recording of ``cfg`` and ``seed`` at
    ``out``. Returns the generator's :class:`~egograph.synth.generate.SynthResult`, or None when an
    identical recording (same seed, configuration and generator revision) is already there."""
    from egograph.synth.generate import GENERATOR_REVISION, generate

    out = Path(out)
    record = outputs.run_record("synth", cfg, {"seed": seed, "generator_revision": GENERATOR_REVISION})
    meta_path = out / "recording.json"
    if not overwrite and meta_path.is_file():
        try:
            meta = json.loads(meta_path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            meta = {}
        if meta.get("seed") == seed and meta.get("revision") == GENERATOR_REVISION and meta.get("config") == to_dict(cfg):
            return None
    return generate(out, cfg, seed=seed, progress=progress, extra_files=outputs.run_files(record, cfg))
