"""The benchmark set: cached synthetic recordings, and the observations lifted from them.

Recordings (no RGB) live under ``CACHE/f<frames>[_<overrides>]/seed<seed>`` (the legacy world) or
``CACHE/device/f<frames>[_<overrides>]/seed<seed>`` (the device world: :data:`BENCH_WORLDS`). A cached recording is
reused when its seed, length and scene config match; when only the detection front-ends differ,
its detections are re-simulated (``redetect``) instead of re-rendering everything.

Observations lifted from a cached recording are kept beside it, in ``<root>/observations/``, under
a key of everything they depend on (:func:`observations_key`), so every benchmark shares them.
"""

from __future__ import annotations

import functools
import hashlib
import json
import shutil
from pathlib import Path
from typing import Sequence

import numpy as np

from egograph.core.config import load_config, to_dict
from egograph.core.errors import InputError
from egograph.core.provenance import code_digest, describe_change
from egograph.core.resources import synth_config
from egograph.geometry.observations import Observations
from egograph.io.recording import Recording
from egograph.synth.config import SynthConfig
from egograph.synth.frontend import FRONTEND_REVISION
from egograph.synth.generate import DEVICE_REVISION, GENERATOR_REVISION, PV_REVISION, generate, recorded_config, redetect

ORACLE = "oracle"
"""Observation source: the true boxes (:func:`egograph.synth.oracle.true_box_detections`)."""

ANNOTATED_BOXES = "boxes"
"""Observation source: the annotated 2D boxes (every 5th frame when at least a quarter visible)."""


# PV knobs that change how colour pixels are made and stored, not the scene, depth, poses or views:
# the renderers agree to a few pixels in 10,000 (tests/test_synth_render.py), so a cache made by the
# other renderer stays valid for everything but its RGB frames (rgb_benchmark_set checks those).
PIXEL_ONLY_PV_KNOBS = ("renderer", "png_compression")


def rendered_config(config: dict) -> dict:
    """A recording's config without its detection front-ends and the PV pixel knobs: what
    re-rendering the depth, poses and views depends on."""
    out = {k: v for k, v in config.items() if k != "detections"}
    if out.get("world", "legacy") == "legacy":  # recordings before the device world carry neither key
        out.pop("world", None)
        out.pop("device", None)
    if isinstance(out.get("pv"), dict):
        out["pv"] = {k: v for k, v in out["pv"].items() if k not in PIXEL_ONLY_PV_KNOBS}
    return out


BENCH_WORLDS = ("device", "legacy")
"""Worlds the benchmark sets are built in (``--world`` of the bench tools): ``device`` (the default
since issue 38: synth/device-svoe, device-mvpe) and ``legacy`` (synth/svoe, mvpe: the world every
record before issue 38 was made in, kept so that those records stay reproducible)."""


def world_config(world: str, primary: str = "svoe") -> Path:
    """The packaged synth config of a benchmark ``world`` (:data:`BENCH_WORLDS`) whose demo tracks the
    ``primary`` detection set (svoe or mvpe; both sets are written into every recording either way)."""
    if world not in BENCH_WORLDS:
        raise ValueError(f"benchmark world {world!r}: one of {', '.join(BENCH_WORLDS)}")
    return synth_config(primary if world == "legacy" else f"device-{primary}")


def add_world_argument(ap) -> None:
    """``--world {device,legacy}`` (default device) on a bench tool's argparse parser: the world its
    benchmark set is built in (:func:`world_config`)."""
    ap.add_argument("--world", default="device", choices=BENCH_WORLDS,
                    help="generator world of the benchmark set: device (the default: photographic surfaces, the PV "
                         "camera, hands) or legacy (the world of the records made before issue 38)")


def set_dir(cache: str | Path, frames: int, overrides: Sequence[str] = (), world: str = "legacy") -> Path:
    """The folder of one benchmark set: ``CACHE/f<frames>`` plus a tag of the generator overrides;
    under ``CACHE/device/`` in the device world (legacy sets keep the folders they always had)."""
    tag = "_".join(o.replace("=", "-").replace(".", "_") for o in overrides)
    return Path(cache) / ("device" if world == "device" else "") / f"f{frames}{'_' + tag if tag else ''}"


CODE_FILE = "code.json"
"""Beside a cached recording: the :func:`egograph.core.provenance.code_digest` of the code that made
it (``recording``: the generator without the detection front-ends; ``detections``: the front-ends),
checked on every reuse, so that a change of code or of a package version the generator imports
rebuilds the recording instead of serving figures made by other code."""


@functools.lru_cache(maxsize=1)
def generator_code() -> dict:
    """``{"recording": ..., "detections": ...}``: the code digests a cached recording is checked against
    (computed once per process: the code a process runs does not change under it)."""
    return {"recording": code_digest("egograph.synth.generate", exclude=("egograph.synth.frontend",)),
            "detections": code_digest("egograph.synth.frontend")}


def _read_code(root: Path) -> dict:
    path = root / CODE_FILE
    try:
        return json.loads(path.read_text()) if path.exists() else {}
    except (OSError, ValueError):
        return {}


def _write_code(root: Path, code: dict) -> None:
    from egograph.io.atomic import atomic_write_text

    atomic_write_text(root / CODE_FILE, json.dumps(code, indent=1, sort_keys=True) + "\n")


def benchmark_set(seeds: Sequence[int], frames: int, *, config: str | Path, cache: str | Path,
                  overrides: Sequence[str] = (), progress: bool = True) -> list[Path]:
    """Roots of the cached benchmark recordings, one per seed: generated from the synth ``config``
    (plus ``frames``, no PV RGB and ``overrides``) when missing or when the scene config or the
    generator revision changed, or the code that made it (:data:`CODE_FILE`); detections
    re-simulated when only the front-ends (their config, revision or code) changed."""
    cfg = load_config(SynthConfig, config, [f"frames={frames}", "pv.rgb=false", *overrides])
    want = to_dict(cfg)
    code = generator_code()
    roots = []
    for seed in seeds:
        root = set_dir(cache, frames, overrides, cfg.world) / f"seed{seed}"
        meta_path = root / "recording.json"
        meta = json.loads(meta_path.read_text()) if meta_path.exists() else None
        have = meta["config"] if meta else None
        made = _read_code(root)
        if meta is None or meta.get("seed") != seed or meta.get("revision") != GENERATOR_REVISION \
                or meta.get("device_revision") != (DEVICE_REVISION if cfg.world == "device" else None) \
                or rendered_config(have) != rendered_config(want) or made.get("recording") != code["recording"]:
            why = "" if meta is None or made.get("recording") == code["recording"] else \
                f" (generator: {describe_change(made.get('recording'), code['recording'])})"
            print(f"generating benchmark recording seed {seed} ({frames} frames) -> {root}{why}", flush=True)
            generate(root, cfg, seed=seed, progress=progress)
            _write_code(root, code)
        elif have.get("detections") != want["detections"] or meta.get("frontend_revision", 1) != FRONTEND_REVISION \
                or made.get("detections") != code["detections"]:
            print(f"re-simulating detections of seed {seed} (front-end config, revision or code changed)", flush=True)
            redetect(root, cfg)
            _write_code(root, code)
        roots.append(root)
    return roots


def rgb_benchmark_set(seeds: Sequence[int], frames: int, *, config: str | Path, cache: str | Path,
                      overrides: Sequence[str] = ()) -> list[Path]:
    """Cached recordings with PV RGB, for pose refinement with COLMAP and the appearance front-end.
    Refinement never reads the simulated detections: a front-end change does not re-render; a
    change of the PV renderer or its revision does."""
    cfg = load_config(SynthConfig, config, [f"frames={frames}", *overrides])
    code = generator_code()
    out = []
    for seed in seeds:
        root = set_dir(cache, frames, overrides, cfg.world) / f"seed{seed}"
        meta = root / "recording.json"
        have = json.loads(meta.read_text()) if meta.exists() else {}
        ok = have.get("revision") == GENERATOR_REVISION and have.get("pv_revision") == PV_REVISION \
            and have.get("device_revision") == (DEVICE_REVISION if cfg.world == "device" else None) \
            and have["config"] == {**recorded_config(cfg), "detections": have["config"].get("detections")} \
            and _read_code(root).get("recording") == code["recording"]
        if not ok:
            print(f"generating RGB benchmark recording seed {seed} ({frames} frames) -> {root}", flush=True)
            generate(root, cfg, seed=seed, progress=True)
            _write_code(root, code)
        out.append(root)
    return out


# Folders of a cached recording that hold results derived from its poses (lifted observations,
# calibration tables). A view with other poses keeps its own: the observation key leaves the
# poses out whenever a recording carries the poses of its own files, which the view does too.
DERIVED_DIRS = ("observations", "calibration")


def exact_poses_view(root: Path) -> Path:
    """A view of a cached recording with the true poses as the reported ones (``<root>_exact``
    beside it): the generator's random streams are independent, so this equals generating it with
    ``pose_error.enabled=false``. Every input but the two pose files is a symlink; the derived
    folders (:data:`DERIVED_DIRS`) are the view's own."""
    seq = next(p for p in root.iterdir() if (p / "pv_pose.json").is_file())
    out = root.parent / f"{root.name}_exact"
    if (out / seq.name / "pv_pose.json").exists():
        for name in DERIVED_DIRS:  # views made before these were its own shared the original's
            if (out / name).is_symlink():
                (out / name).unlink()
        return out
    tmp = root.parent / f".{root.name}_exact.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    for p in root.iterdir():
        if p != seq and p.name not in DERIVED_DIRS:
            (tmp / p.name).symlink_to(p.resolve())
    (tmp / seq.name).mkdir()
    for p in seq.iterdir():
        if p.name not in ("pv_pose.json", "depth_ahat_pose.json"):
            (tmp / seq.name / p.name).symlink_to(p.resolve())
    for name in ("pv_pose.json", "depth_ahat_pose.json"):
        shutil.copy(root / "synth_gt" / seq.name / name, tmp / seq.name / name)
    tmp.rename(out)
    return out


# ---------------------------------------------------------------- observations


def poses_digest(rec: Recording) -> str:
    """sha256 (hex) of the poses a recording carries: timestamps, PV and AHAT validity and the
    valid row-vector poses (invalid ones hold NaN and are left out, so NaN bit patterns do not
    matter)."""
    h = hashlib.sha256()
    for a in (rec.timestamps, rec.pv_valid, rec.pv_poses[rec.pv_valid], rec.depth_valid,
              rec.depth_poses[rec.depth_valid]):
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def uses_reported_poses(rec: Recording, cfg) -> bool:
    """Whether ``rec`` carries the poses its files report, read with ``cfg.io``. Refined poses
    applied to it (``apply_poses``), or poses edited in place, make this False."""
    files = tuple((str(p), p.stat().st_mtime_ns, p.stat().st_size) if p.is_file() else (str(p), None, None)
                  for p in (rec.seq_dir / "pv_pose.json", rec.seq_dir / "depth_ahat_pose.json"))
    reported = _reported_digest(rec.seq_dir, rec.calibration_dir, cfg.io.invalid_poses, files)
    return reported is not None and reported == poses_digest(rec)


@functools.lru_cache(maxsize=32)
def _reported_digest(seq_dir: Path, calibration_dir: Path, invalid_poses: str, files: tuple) -> str | None:
    """:func:`poses_digest` of the poses in a sequence's files (``files``: their paths, mtimes and
    sizes, so an edited file is read again); None when they do not open with ``invalid_poses``."""
    try:
        reported = Recording.open(seq_dir, calibration=calibration_dir, invalid_poses=invalid_poses, depth_factor=1.0)
    except InputError:  # the files do not open with cfg.io: rec's poses came from elsewhere
        return None
    return poses_digest(reported)


@functools.lru_cache(maxsize=1)
def lift_code() -> dict:
    """The code digest (:func:`egograph.core.provenance.code_digest`) of lifting and of reading the
    detection sources, part of every observations key (computed once per process)."""
    return code_digest("egograph.geometry.lift", "egograph.synth.oracle", "egograph.track.regt")


def observations_key(rec: Recording, source: str, cfg) -> str:
    """Cache key (12 hex) of the observations of ``source`` lifted from ``rec`` with ``cfg``.

    Hashes, in order: for a detection set of the recording, its detection front-end config and
    front-end revision (``recording.json``); then the lifting knobs that change results
    (``cfg.lift.result_knobs()``) and the io config; then, only when ``rec`` does not carry its
    reported poses, a digest of the PV and AHAT poses it does carry. (With the reported poses, the
    detection sets' and the annotated boxes' keys are the ones earlier benchmark runs wrote, so their
    observations stay valid; the oracle's earlier key hashed the whole lift config.)
    """
    parts: list = []
    if source not in (ORACLE, ANNOTATED_BOXES):
        meta = json.loads((rec.root / "recording.json").read_text())
        parts += [meta["config"]["detections"], meta.get("frontend_revision", 1)]
    parts += [cfg.lift.result_knobs(), to_dict(cfg.io)]
    if not uses_reported_poses(rec, cfg):
        parts.append(poses_digest(rec))
    # the code that lifts and the packages it imports (stop 52: the keys before carried no code, so
    # observations lifted by other code or another numpy/OpenCV/Open3D were served as current)
    parts.append(lift_code())
    blob = json.dumps(parts, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:12]


def observations_path(rec: Recording, source: str, cfg) -> Path:
    """``<root>/observations/<source>[_<lift mode>]_<key>.npz`` (detection sets carry the mode in
    the name; the oracle's and the annotated boxes' names do not, their key holds it)."""
    name = source if source in (ORACLE, ANNOTATED_BOXES) else f"{source}_{cfg.lift.mode}"
    return rec.root / "observations" / f"{name}_{observations_key(rec, source, cfg)}.npz"


def source_detections(rec: Recording, source: str, cfg) -> tuple[dict, int | None]:
    """``(detections ts -> [Detection], instance bound or None)`` of an observation source."""
    if source == ORACLE:
        from egograph.synth.oracle import true_box_detections

        return true_box_detections(rec), None
    if source == ANNOTATED_BOXES:
        from egograph.io.annotations import load_annotations
        from egograph.track.regt import box_detections

        return box_detections(load_annotations(rec.annotation_dir)), None
    from egograph.io.annotations import read_labels
    from egograph.io.detections import read_detection_dir

    dets = read_detection_dir(rec.detections_dir(source), rec.timestamps, box_format=cfg.io.box_format)
    n = None if rec.annotation_dir is None else len(read_labels(rec.annotation_dir / "labels.csv"))
    return dets, n


def cached_observations(rec: Recording, source: str, cfg, relift: bool = False):
    """Observations of ``source`` (a detection set of the recording such as ``svoe``/``mvpe``,
    :data:`ORACLE` or :data:`ANNOTATED_BOXES`) lifted from ``rec`` with ``cfg.lift`` and the poses
    ``rec`` carries -> ``(Observations, LiftReport | None)``.

    Read from :func:`observations_path` when there (report None) unless ``relift``; else lifted
    and saved there.
    """
    from egograph.geometry.lift import lift_recording

    path = observations_path(rec, source, cfg)
    if path.exists() and not relift:
        return Observations.load(path), None
    dets, n_instances = source_detections(rec, source, cfg)
    obs, report = lift_recording(rec, dets, cfg.lift, progress=False, n_instances=n_instances)
    obs.save(path)
    return obs, report
