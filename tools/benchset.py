"""The benchmark set: synthetic recordings (no RGB) cached under ``.cache/``, shared by the
benchmarks in ``tools/``. A cached recording is reused when its seed, length and scene
config match; when only the detection front-ends differ, its detections are re-simulated
(``redetect``) instead of re-rendering everything.
"""

from __future__ import annotations

import json
from pathlib import Path

from egograph.core.config import load_config, to_dict
from egograph.synth.config import SynthConfig
from egograph.synth.frontend import FRONTEND_REVISION
from egograph.synth.generate import GENERATOR_REVISION, generate, redetect

REPO = Path(__file__).resolve().parents[1]
DEFAULT_CACHE = REPO / ".cache" / "bench"


def rendered_config(config: dict) -> dict:
    """A recording's config without its detection front-ends: what re-rendering depends on."""
    return {k: v for k, v in config.items() if k != "detections"}


def benchmark_set(seeds: list[int], frames: int, config: str | Path = REPO / "configs" / "synth" / "svoe.yaml",
                  overrides: list[str] = (), cache: Path = DEFAULT_CACHE, progress: bool = True) -> list[Path]:
    cfg = load_config(SynthConfig, config, [f"frames={frames}", "pv.rgb=false", *overrides])
    want = to_dict(cfg)
    tag = "_".join(o.replace("=", "-").replace(".", "_") for o in overrides)
    roots = []
    for seed in seeds:
        root = Path(cache) / f"f{frames}{'_' + tag if tag else ''}" / f"seed{seed}"
        meta_path = root / "recording.json"
        meta = json.loads(meta_path.read_text()) if meta_path.exists() else None
        have = meta["config"] if meta else None
        if meta is None or meta.get("seed") != seed or meta.get("revision") != GENERATOR_REVISION \
                or rendered_config(have) != rendered_config(want):
            print(f"generating benchmark recording seed {seed} ({frames} frames) -> {root}", flush=True)
            generate(root, cfg, seed=seed, progress=progress)
        elif have.get("detections") != want["detections"] or meta.get("frontend_revision", 1) != FRONTEND_REVISION:
            print(f"re-simulating detections of seed {seed} (front-end config or revision changed)", flush=True)
            redetect(root, cfg)
        roots.append(root)
    return roots


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description="build (or reuse) the cached benchmark set")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    a = ap.parse_args()
    for r in benchmark_set(a.seeds, a.frames, overrides=a.overrides):
        print(r)
