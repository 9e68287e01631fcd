"""Step ``run``: every stage on every sequence of a dataset, as tasks on a Dask cluster.

A run is a plan of tasks, one per (sequence, stage[, tracker]), each depending on the tasks whose
outputs it reads::

    refine ──► detect ──► lift ──► track/<tracker> ──► eval/<tracker>
       └─────► regt

``refine``, when asked for, feeds its poses to every later stage of that sequence. ``detect``,
when asked for, runs the appearance front-end (``egograph detect``, enrollment ``--detections``:
svoe or mvpe) on the sequence's PV frames, and ``lift`` then reads those detections instead of the
recording's own detection set of that name. A stage asked for brings the ones it needs (``eval``
needs ``track``, which needs ``lift``; ``detect`` is never brought, it replaces the recording's
detections only when asked for); a stage whose output is already there for the same inputs and
configuration is not computed again, so adding them costs nothing.

Outputs (``RUNS`` is ``--out``)::

    RUNS/cache/<seq>/refine-<key>/            refined poses (egograph refine's folder)
    RUNS/cache/<seq>/detect-<set>-<key>/      detections (egograph detect's folder: <ts>.txt per PV frame)
    RUNS/cache/<seq>/lift-<key>.npz           observations
    RUNS/cache/<seq>/track-<tracker>-<key>/   results folder (reference format + intervals.json)
    RUNS/cache/<seq>/eval-<tracker>-<key>/    eval.json (the ``egograph eval --json`` format)
    RUNS/cache/<seq>/regt-<key>/              re-estimated centres and their audit
    RUNS/cache/<seq>/adapt-r<r>-<key>/        --stages ...,adapt: round r's head (head.npz, adapt.json), taught by
                                              round r-1's graph results; then detect-<set>-r<r>-<key>/,
                                              lift-r<r>-<key>.npz, track-<t>-r<r>-<key>/, eval-<t>-r<r>-<key>/
    RUNS/cache/<seq>/proposals-<key>.npz      with rounds: round 0's proposals and their embeddings, re-scored
    RUNS/<name>/config.yaml                   the resolved configuration
    RUNS/<name>/run.json                      what ran: command, tasks, outputs, status, seconds
    RUNS/<name>/summary.json                  pooled evaluation per tracker, per-sequence rows, failures
    RUNS/<name>/<seq>/{refined,detections,lifted.npz,<tracker>,eval-<tracker>.json,regt}  links into the cache
    RUNS/latest -> <name>

``<key>`` is a digest of the configuration sections a stage depends on and the key of the stage it
reads (``detect``'s: the ``frontend`` and ``io`` sections and the detection set), so a later run with
another tracker set or other graph knobs reuses the lifted observations, and a front-end knob change
detects again;
inside, each step's own fingerprint (``egograph.json``, the ``.npz`` provenance) decides whether
its output is current. ``<name>`` is ``<dataset folder>-<digest>`` of the dataset path, its
sequences, the stages, trackers, detection set and resolved configuration: the same command names
the same run, and run again resumes it. Nothing written holds a wall-clock time except
``run.json``'s seconds; ``summary.json`` holds no output path, so a resumed run's summary equals an
uninterrupted one's byte for byte.

Tasks run :func:`run_task` (importable, for pickling) on Dask workers. A task gets paths and
names, never arrays: workers read the dataset and write the shared ``RUNS`` folder themselves, so
``RUNS`` and the dataset must be at the same path on every worker. An error in a task is caught
and returned as its status (the tasks after it on that sequence are skipped); a worker that dies
has its task run again on another worker by the scheduler (up to
``distributed.scheduler.allowed-failures`` times, default 3).
"""

from __future__ import annotations

import json
import os
import time
import traceback
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from egograph import __version__
from egograph.core.config import to_dict
from egograph.core.errors import ConfigError, EgographError, InputError
from egograph.steps import outputs
from egograph.steps.dataset import DatasetSequence, list_dataset

STAGES = ("refine", "detect", "lift", "track", "eval", "adapt", "regt")
"""Stages in pipeline order."""

PLANNED_STAGES: dict[str, str] = {}
"""Stages of the issue that have no step yet (none now): refused with this reason."""

DEFAULT_STAGES = ("lift", "track", "eval")
NEEDS = {"track": "lift", "eval": "track", "adapt": "track"}
"""The stage a stage reads the output of (``refine`` and ``regt`` need none)."""

RUN_FILE = "run.json"
SUMMARY_FILE = "summary.json"
LATEST = "latest"
CACHE = "cache"

OK, FAILED, SKIPPED = "ok", "failed", "skipped"

LOOPBACK = "127.0.0.1"
"""Where the local cluster's scheduler, nannies and workers listen: nothing is reachable from
another machine."""


# ------------------------------------------------------------------ the plan


@dataclass
class Task:
    """One (sequence, stage[, tracker]); ``spec`` is what the worker gets (paths and names only)."""

    key: str                  # "lift/seqA", "track/seqA/graph"
    stage: str
    sequence: str
    tracker: str | None
    out: Path                 # the output in the cache
    link: str                 # its name in RUNS/<name>/<seq>/
    deps: list[str] = field(default_factory=list)
    spec: dict = field(default_factory=dict)
    round: int = 0            # adaptation round (0: before any head; --stages ...,adapt)

    @property
    def label(self) -> str:
        """``lift``, ``track/graph``, ``track/graph@r1``: the stage column of the tables."""
        base = self.stage if self.tracker is None else f"{self.stage}/{self.tracker}"
        return base + (f"@r{self.round}" if self.round else "")


@dataclass
class RunPlan:
    dataset: Path
    runs: Path
    name: str
    stages: list[str]
    trackers: list[str]
    detections: str
    sequences: list[DatasetSequence]
    config_digest: str
    tasks: list[Task]

    @property
    def folder(self) -> Path:
        return self.runs / self.name

    @property
    def config_path(self) -> Path:
        return self.folder / outputs.CONFIG_FILE


def resolve_stages(stages) -> list[str]:
    """The stages asked for plus the ones they need, in pipeline order; ConfigError for an unknown
    or not yet available stage."""
    asked = [s.strip() for s in (stages or DEFAULT_STAGES) if s.strip()]
    if not asked:
        raise ConfigError("--stages: no stage given (choose from " + ", ".join(STAGES) + ")")
    for s in asked:
        if s in PLANNED_STAGES:
            raise ConfigError(f"--stages: {s}: not available yet ({PLANNED_STAGES[s]})")
        if s not in STAGES:
            raise ConfigError(f"--stages: unknown stage {s!r} (choose from {', '.join(STAGES)})")
    chosen = set(asked)
    for s in list(asked):
        while s in NEEDS:
            s = NEEDS[s]
            chosen.add(s)
    return [s for s in STAGES if s in chosen]


def resolve_trackers(trackers) -> list[str]:
    from egograph.track.registry import TRACKERS

    names = [t.strip() for t in (trackers or TRACKERS) if t.strip()]
    for t in names:
        if t not in TRACKERS:
            raise ConfigError(f"--trackers: unknown tracker {t!r} (choose from {', '.join(TRACKERS)})")
    if not names:
        raise ConfigError("--trackers: no tracker given (choose from " + ", ".join(TRACKERS) + ")")
    return list(dict.fromkeys(names))


def stage_keys(cfg, detections: str, refine: bool, trackers: list[str], detect: bool = False) -> dict:
    """Cache keys: a digest of what each stage's result depends on in the configuration and the key
    of the stage it reads (the step's own fingerprint then checks the inputs' contents). With
    ``detect``, lift's key is made of detect's (the frontend section, io, the set, refine's key)
    instead of the set name, so a front-end knob change re-runs detect and everything after it."""
    from egograph.steps.track import tracker_sections

    io = to_dict(cfg.io)
    k = {"refine": outputs.digest("refine", to_dict(cfg.refine), io)[:12] if refine else None}
    # detect reads the poses (geometry proposals cast AHAT rays against the mesh): refine's key too
    k["detect"] = outputs.digest("detect", detections, to_dict(cfg.frontend), io, k["refine"])[:12] if detect else None
    lift_input = ["detect", k["detect"]] if detect else detections
    k["lift"] = outputs.digest("lift", cfg.lift.result_knobs(), io, lift_input, k["refine"])[:12]
    sections = tracker_sections(cfg)
    for t in trackers:
        k[f"track/{t}"] = outputs.digest("track", t, sections, k["lift"])[:12]
        k[f"eval/{t}"] = outputs.digest("eval", k[f"track/{t}"])[:12]
    k["regt"] = outputs.digest("regt", to_dict(cfg), k["refine"])[:12]
    return k


TEACHER = "graph"
"""The tracker whose results teach the next round's head (``--stages ...,adapt``)."""


def round_keys(cfg, keys: dict, trackers: list[str], rounds: int) -> dict:
    """Cache keys of the adaptation rounds 1..``rounds``: each round's adapt reads the round before's
    graph results (and detections), its detect the adapt folder, then lift, track and eval as in round 0."""
    from egograph.steps.track import tracker_sections

    k = dict(keys)
    sections, io = tracker_sections(cfg), to_dict(cfg.io)
    prev = "track/" + TEACHER
    for r in range(1, rounds + 1):
        k[f"adapt@r{r}"] = outputs.digest("adapt", r, k[prev], to_dict(cfg.adapt), to_dict(cfg.frontend))[:12]
        k[f"detect@r{r}"] = outputs.digest("detect", r, k[f"adapt@r{r}"])[:12]
        k[f"lift@r{r}"] = outputs.digest("lift", cfg.lift.result_knobs(), io, ["detect", k[f"detect@r{r}"]])[:12]
        for t in trackers:
            k[f"track/{t}@r{r}"] = outputs.digest("track", t, sections, k[f"lift@r{r}"])[:12]
            k[f"eval/{t}@r{r}"] = outputs.digest("eval", k[f"track/{t}@r{r}"])[:12]
        prev = f"track/{TEACHER}@r{r}"
    return k


def plan_run(dataset: str | Path, runs: str | Path, cfg, *, stages=None, trackers=None, detections: str = "svoe",
             name: str | None = None) -> RunPlan:
    """The tasks of ``egograph run`` (nothing is written): InputError when the dataset holds no
    sequence, ConfigError for an unknown stage or tracker."""
    stages = resolve_stages(stages)
    trackers = resolve_trackers(trackers) if "track" in stages else []
    from egograph.steps.detect import ENROLLMENTS

    if "detect" in stages and detections not in ENROLLMENTS:
        raise ConfigError(f"--detections {detections}: the detect stage produces one of {', '.join(ENROLLMENTS)} "
                          "(its enrollment: svoe.txt's box or the MVPE photos); without --stages detect any set "
                          "name or folder the recordings carry")
    dataset = Path(dataset).resolve()
    seqs = list_dataset(dataset)
    runs = Path(runs).resolve()
    cfg_digest = outputs.digest(to_dict(cfg))
    if name is None:
        name = f"{dataset.name}-" + outputs.digest(__version__, str(dataset), [s.id for s in seqs], stages, trackers,
                                                   detections, cfg_digest)[:10]
    if not name or name in (LATEST, CACHE) or "/" in name or name.startswith("."):
        raise ConfigError(f"--name {name!r}: not a usable run name (not empty, {LATEST}, {CACHE}, hidden or a path)")
    keys = stage_keys(cfg, detections, "refine" in stages, trackers, "detect" in stages)
    rounds = 0
    if "adapt" in stages:
        if "detect" not in stages:
            raise ConfigError("--stages adapt: the tracker teaches egograph detect's front-end; add detect to --stages")
        if TEACHER not in trackers:
            raise ConfigError(f"--stages adapt: the {TEACHER} tracker's results teach the head; add {TEACHER} to --trackers")
        rounds = cfg.adapt.rounds
        keys = round_keys(cfg, keys, trackers, rounds)
    tasks = []
    for seq in seqs:
        tasks += sequence_tasks(seq, runs / CACHE / seq.id, stages, trackers, keys, detections, rounds)
    plan = RunPlan(dataset, runs, name, stages, trackers, detections, seqs, cfg_digest, tasks)
    for t in tasks:
        t.spec.update(config=str(plan.config_path), log=str(plan.folder / "logs" / (t.key.replace("/", "-") + ".log")))
    return plan


def sequence_tasks(seq: DatasetSequence, cache: Path, stages: list[str], trackers: list[str], keys: dict,
                   detections: str, rounds: int = 0) -> list[Task]:
    """The tasks of one sequence, each after the tasks it depends on."""
    tasks: list[Task] = []
    base = {"sequence": seq.id, "sequence_dir": str(seq.path)}
    refine_key = None
    poses = None
    if "refine" in stages:
        out = cache / f"refine-{keys['refine']}"
        refine_key, poses = f"refine/{seq.id}", str(out)
        tasks.append(Task(refine_key, "refine", seq.id, None, out, "refined", spec={**base, "stage": "refine"}))
    pre = [refine_key] if refine_key else []
    base["poses"] = poses
    lift_pre, lift_detections = list(pre), detections
    if "detect" in stages:
        dets = cache / f"detect-{detections}-{keys['detect']}"
        tasks.append(Task(f"detect/{seq.id}", "detect", seq.id, None, dets, "detections", list(pre),
                          {**base, "stage": "detect", "enroll": detections}))
        if rounds:   # the rounds detect again on the same proposals: their embeddings are kept
            tasks[-1].spec["embeddings"] = str(cache / f"proposals-{keys['detect']}.npz")
        lift_pre, lift_detections = [f"detect/{seq.id}"], str(dets)  # refine, if any, comes before detect
    if "lift" in stages:
        obs = cache / f"lift-{keys['lift']}.npz"
        tasks.append(Task(f"lift/{seq.id}", "lift", seq.id, None, obs, "lifted.npz", lift_pre,
                          {**base, "stage": "lift", "detections": lift_detections}))
        for t in trackers if "track" in stages else []:
            res = cache / f"track-{t}-{keys[f'track/{t}']}"
            tasks.append(Task(f"track/{seq.id}/{t}", "track", seq.id, t, res, t, [f"lift/{seq.id}"],
                              {**base, "stage": "track", "tracker": t, "observations": str(obs)}))
            if "eval" in stages:
                ev = cache / f"eval-{t}-{keys[f'eval/{t}']}"
                tasks.append(Task(f"eval/{seq.id}/{t}", "eval", seq.id, t, ev, f"eval-{t}", [f"track/{seq.id}/{t}"],
                                  {**base, "stage": "eval", "tracker": t, "results": str(res)}))
    for r in range(1, rounds + 1):
        tasks += round_tasks(seq, cache, base, stages, trackers, keys, detections, r)
    if "regt" in stages:
        tasks.append(Task(f"regt/{seq.id}", "regt", seq.id, None, cache / f"regt-{keys['regt']}", "regt", list(pre),
                          {**base, "stage": "regt"}))
    for t in tasks:
        t.spec.update(key=t.key, out=str(t.out))
    return tasks


def round_tasks(seq: DatasetSequence, cache: Path, base: dict, stages: list[str], trackers: list[str], keys: dict,
                detections: str, r: int) -> list[Task]:
    """Round ``r`` of adaptation on one sequence: adapt (taught by round r - 1's graph results and
    the detections they came from) -> detect -> lift -> track -> eval, every output its own."""
    p = "" if r == 1 else f"@r{r - 1}"
    prev_det = f"detect/{seq.id}{p}"
    prev_track = f"track/{seq.id}/{TEACHER}{p}"
    prev_det_out = cache / (f"detect-{detections}-{keys['detect']}" if r == 1
                            else f"detect-{detections}-r{r - 1}-{keys[f'detect@r{r - 1}']}")
    teacher = cache / (f"track-{TEACHER}-{keys['track/' + TEACHER]}" if r == 1
                       else f"track-{TEACHER}-r{r - 1}-{keys[f'track/{TEACHER}@r{r - 1}']}")
    sfx = f"@r{r}"
    ad = cache / f"adapt-r{r}-{keys['adapt' + sfx]}"
    dets = cache / f"detect-{detections}-r{r}-{keys['detect' + sfx]}"
    obs = cache / f"lift-r{r}-{keys['lift' + sfx]}.npz"
    tasks = [Task(f"adapt/{seq.id}{sfx}", "adapt", seq.id, None, ad, f"adapt-r{r}", [prev_track, prev_det],
                  {**base, "stage": "adapt", "enroll": detections, "results": str(teacher),
                   "detections": str(prev_det_out)}, r),
             Task(f"detect/{seq.id}{sfx}", "detect", seq.id, None, dets, f"detections-r{r}", [f"adapt/{seq.id}{sfx}"],
                  {**base, "stage": "detect", "enroll": detections, "adapt": str(ad),
                   "embeddings": str(cache / f"proposals-{keys['detect']}.npz")}, r),
             Task(f"lift/{seq.id}{sfx}", "lift", seq.id, None, obs, f"lifted-r{r}.npz", [f"detect/{seq.id}{sfx}"],
                  {**base, "stage": "lift", "detections": str(dets)}, r)]
    for t in trackers:
        res = cache / f"track-{t}-r{r}-{keys[f'track/{t}{sfx}']}"
        tasks.append(Task(f"track/{seq.id}/{t}{sfx}", "track", seq.id, t, res, f"{t}-r{r}", [f"lift/{seq.id}{sfx}"],
                          {**base, "stage": "track", "tracker": t, "observations": str(obs)}, r))
        if "eval" in stages:
            ev = cache / f"eval-{t}-r{r}-{keys[f'eval/{t}{sfx}']}"
            tasks.append(Task(f"eval/{seq.id}/{t}{sfx}", "eval", seq.id, t, ev, f"eval-{t}-r{r}",
                              [f"track/{seq.id}/{t}{sfx}"], {**base, "stage": "eval", "tracker": t, "results": str(res)},
                              r))
    return tasks


# ------------------------------------------------------------------ on a worker


def run_task(spec: dict, *deps: dict) -> dict:
    """Run one task on a worker -> its status (small, JSON-able).

    ``deps`` are the statuses of the tasks it reads from (passed so that Dask runs it after them);
    when one of them did not end ``ok`` the task is skipped. Any exception is caught: a one-line
    ``error`` (an unexpected one also writes its traceback to ``spec["log"]``). ``reused`` says the
    output was already there for the same inputs (nothing computed).
    """
    key = spec["key"]
    bad = [d for d in deps if d.get("status") != OK]
    if bad:
        return {"key": key, "status": SKIPPED, "reused": False, "error": f"needs {bad[0]['key']} ({bad[0]['status']})",
                "warnings": [], "seconds": 0.0}
    t0, c0 = time.perf_counter(), time.process_time()
    before = _signature(spec["out"])
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            STAGE_FUNCTIONS[spec["stage"]](spec)
        status, error = OK, None
    except EgographError as exc:
        status, error, caught = FAILED, str(exc), []
    except Exception as exc:  # a bug: one line here, the traceback in the run's logs
        status, caught = FAILED, []
        error = f"internal error: {type(exc).__name__}: {' '.join(str(exc).split())[:300]}"
        log = Path(spec["log"])
        try:
            log.parent.mkdir(parents=True, exist_ok=True)
            log.write_text(f"egograph {__version__}\n{key}\n\n{traceback.format_exc()}")
            error += f" (traceback in logs/{log.name})"
        except OSError:
            pass
    after = _signature(spec["out"])
    lines = list(dict.fromkeys(str(w.message) for w in caught))
    return {"key": key, "status": status, "error": error, "reused": status == OK and before is not None and before == after,
            "warnings": lines[:5] + ([f"... {len(lines) - 5} more"] if len(lines) > 5 else []),
            "seconds": round(time.perf_counter() - t0, 3),
            "cpu_seconds": round(time.process_time() - c0, 3),  # the worker process's, every thread
            "worker_pid": os.getpid(), "worker_max_rss_mb": _max_rss_mb()}  # its peak resident memory so far


def _max_rss_mb() -> float | None:
    """The peak resident memory of this process so far (MB; Linux reports kB), None where unknown."""
    try:
        import resource

        return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    except (ImportError, OSError):  # pragma: no cover - not POSIX
        return None


def _signature(path: str) -> tuple | None:
    """Identity of an output (file or folder): outputs are replaced by a rename, so a new inode
    (or mtime) means the step wrote it."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns


def _config(spec: dict):
    from egograph.core.config import load_config
    from egograph.steps.settings import EgographConfig

    return load_config(EgographConfig, spec["config"])


def _open(spec: dict, cfg):
    from egograph.steps.recording import open_recording

    return open_recording(spec["sequence_dir"], cfg, poses=spec.get("poses"))


def stage_refine(spec: dict) -> None:
    from egograph.steps.refine import refine

    cfg = _config(spec)
    if cfg.io.invalid_poses == "error":  # as `egograph refine`: frames with an invalid pose are refined around
        cfg.io.invalid_poses = "skip"
    refine(_open({**spec, "poses": None}, cfg), cfg, spec["out"])


def require_pv_images(rec) -> None:
    """InputError naming the PV folder and the file patterns tried when no PV frame of ``rec`` has
    an image (``detect`` reads nothing else of the frames' appearance)."""
    look = next((lk for lk in getattr(rec, "lookups", []) if lk.what == "PV images"), None)
    if look is None or look.found is not None:
        return
    folder = rec.seq_dir / "pv"
    why = "folder missing" if not folder.is_dir() else f"no image of any of its {len(rec)} PV frames ({look.note})"
    raise InputError(folder, f"detect needs the PV images: {why}; tried {', '.join(look.tried)}")


def worker_threads() -> int | None:
    """The core budget of the Dask worker running this task (its ``nthreads``: 1 on the local
    cluster, ``dask worker --nthreads N`` elsewhere); None outside a worker."""
    try:
        from distributed import get_worker

        worker = get_worker()
    except (ImportError, ValueError):
        return None
    state = getattr(worker, "state", worker)
    n = getattr(state, "nthreads", None)
    return int(n) if n else None


def stage_detect(spec: dict) -> None:
    from egograph.steps.detect import carry_detections, detect

    cfg = _config(spec)
    # A worker is a share of the machine's cores: onnxruntime's, OpenCV's and Open3D's own thread
    # pools would otherwise take every core in every worker (two workers on two cores ran 1.15x one
    # with onnxruntime's alone, 1.55x with OpenCV's and Open3D's left). The thread counts do not
    # change the detections (the embeddings are the same bits; OpenCV splits images by rows).
    n = worker_threads()
    if n is not None:
        import cv2
        import open3d as o3d

        cfg.frontend.threads = n
        cv2.setNumThreads(n)
        o3d.utility.set_max_threads(n)
    rec = _open(spec, cfg)
    require_pv_images(rec)
    if spec.get("adapt"):
        from egograph.steps.adapt import load_adapt

        adaptation = load_adapt(rec, spec["adapt"])
        if adaptation.stopped:   # iterating stopped: the detections of the round before, carried
            carry_detections(rec, adaptation, cfg, spec["out"])
            return
        detect(rec, spec["enroll"], cfg, spec["out"], adapt=adaptation, embeddings=spec.get("embeddings"),
               progress=False)
        return
    detect(rec, spec["enroll"], cfg, spec["out"], embeddings=spec.get("embeddings"), progress=False)


def stage_adapt(spec: dict) -> None:
    from egograph.steps.adapt import adapt, teacher_from_results

    cfg = _config(spec)
    rec = _open(spec, cfg)
    adapt(rec, spec["enroll"], teacher_from_results(rec, spec["results"], spec["detections"]), cfg, spec["out"])


def stage_lift(spec: dict) -> None:
    from egograph.steps.lift import lift

    cfg = _config(spec)
    lift(_open(spec, cfg), spec["detections"], cfg, spec["out"], progress=False)


def stage_track(spec: dict) -> None:
    from egograph.geometry.observations import Observations
    from egograph.steps.track import track

    cfg = _config(spec)
    track(_open(spec, cfg), spec["tracker"], Observations.load(spec["observations"]), cfg, spec["out"])


EVAL_FILE = "eval.json"


def eval_record(rec, results: Path, name: str) -> dict:
    """Run record of an evaluation: the recording, its annotation files, the results (their run's
    fingerprint, else their contents) and the sequence's name in the report."""
    from egograph.steps.recording import require_annotations

    ann = require_annotations(rec, "labels.csv, 3d_center_annot.txt")
    prev = outputs.previous_record(results)
    made_by = prev.get("fingerprint") if prev else None
    return outputs.run_record("eval", None, {"recording": outputs.recording_digest(rec), "name": name,
                                             "annotations": outputs.folder_digest(ann),
                                             "results": made_by or outputs.folder_digest(results)})


def stage_eval(spec: dict) -> None:
    from egograph.io.atomic import atomic_dir
    from egograph.steps.evaluate import evaluate

    cfg = _config(spec)
    rec = _open(spec, cfg)
    results = Path(spec["results"])
    record = eval_record(rec, results, spec["sequence"])
    if outputs.up_to_date(spec["out"], record, False):
        return
    report = evaluate(rec, results, name=spec["sequence"], strict=getattr(cfg.io, "strict", False))
    with atomic_dir(spec["out"]) as tmp:
        (tmp / EVAL_FILE).write_text(json.dumps(report.to_json_dict(), indent=2) + "\n")
        outputs.write_run_files(tmp, record, None)


def stage_regt(spec: dict) -> None:
    from egograph.steps.regt import regt

    cfg = _config(spec)
    rec = _open(spec, cfg)
    # the record egograph.steps.regt.write_regt writes (regt has no skip of its own)
    record = outputs.run_record("regt", cfg, {"recording": outputs.recording_digest(rec), "joint": False})
    if outputs.up_to_date(spec["out"], record, False):
        return
    regt(rec, cfg, spec["out"])


STAGE_FUNCTIONS = {"refine": stage_refine, "detect": stage_detect, "lift": stage_lift, "track": stage_track, "eval": stage_eval,
                   "adapt": stage_adapt, "regt": stage_regt}


# ------------------------------------------------------------------ the cluster


def open_client(workers: int = 2, scheduler: str | None = None):
    """A ``distributed.Client``: on the cluster at ``scheduler`` (its address, ``tcp://`` or
    ``tls://``; TLS settings come from Dask's configuration, ``distributed.comm.tls.*``), else on a
    new LocalCluster of ``workers`` single-threaded worker processes listening on 127.0.0.1 only,
    without a dashboard (no port opens beyond loopback)."""
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            return Client(scheduler, timeout="30s")
        except (OSError, TimeoutError, TypeError, ValueError) as exc:
            hint = ""
            if scheduler.startswith("tls://"):
                hint = ("; tls:// needs Dask's TLS settings: distributed.comm.tls.ca-file, .client.cert and "
                        ".client.key (a dask config file or DASK_DISTRIBUTED__COMM__TLS__* variables)")
            raise ConfigError(f"--scheduler {scheduler}: cannot connect ({type(exc).__name__}: "
                              f"{' '.join(str(exc).split())[:200]}){hint}") from None
    if workers < 1:
        raise ConfigError(f"--workers {workers}: need at least 1")
    # The scheduler serves HTTP (health, metrics; the dashboard when asked for) whatever its
    # dashboard setting: without a dashboard, on a free loopback port rather than 8787.
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host=LOOPBACK,
                           dashboard_address=None, worker_dashboard_address=None,
                           scheduler_kwargs={"dashboard": False, "dashboard_address": f"{LOOPBACK}:0"})
    return Client(cluster)


def close_client(client) -> None:
    """Close the client, and the local cluster it runs on (a remote cluster is left running)."""
    import logging

    cluster = getattr(client, "cluster", None)
    client.close()
    if cluster is not None:
        # a worker still tearing GTSAM/Open3D down is killed after a few seconds: not worth a warning
        nanny = logging.getLogger("distributed.nanny")
        level = nanny.level
        nanny.setLevel(logging.ERROR)
        try:
            cluster.close()
        finally:
            nanny.setLevel(level)


# ------------------------------------------------------------------ the run


@dataclass
class RunOutcome:
    plan: RunPlan
    results: dict            # task key -> status dict
    summary: dict

    @property
    def failed(self) -> list[dict]:
        return [r for r in self.results.values() if r["status"] != OK]

    @property
    def n_ok(self) -> int:
        return sum(r["status"] == OK for r in self.results.values())

    @property
    def n_reused(self) -> int:
        return sum(bool(r.get("reused")) for r in self.results.values())


def start_run(plan: RunPlan, cfg, command: str | None = None) -> None:
    """Write the run folder (config, run.json without results) and point ``latest`` at it."""
    import shutil

    from egograph.io.atomic import atomic_write_text

    plan.folder.mkdir(parents=True, exist_ok=True)
    shutil.rmtree(plan.folder / "logs", ignore_errors=True)  # tracebacks of an earlier attempt of this run
    atomic_write_text(plan.config_path, outputs.config_yaml(cfg))
    write_run_json(plan, {}, command)
    link(plan.runs / LATEST, plan.name)


def write_run_json(plan: RunPlan, results: dict, command: str | None = None) -> None:
    from egograph.io.atomic import atomic_write_text

    doc = {"egograph_version": __version__, "command": command or outputs.command_line(),
           "dataset": str(plan.dataset), "name": plan.name, "stages": plan.stages, "trackers": plan.trackers,
           "detections": plan.detections, "config_digest": plan.config_digest,
           "complete": len(results) == len(plan.tasks),
           "tasks": {t.key: {"output": os.path.relpath(t.out, plan.runs), "deps": t.deps, **results.get(t.key, {})}
                     for t in plan.tasks}}
    atomic_write_text(plan.folder / RUN_FILE, json.dumps(doc, indent=1) + "\n")


def link(path: Path, target: str) -> None:
    """Make ``path`` a symbolic link to ``target`` (relative), replacing what link was there in one rename."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.link")
    tmp.unlink(missing_ok=True)
    os.symlink(target, tmp)
    os.replace(tmp, path)


def link_output(plan: RunPlan, task: Task) -> None:
    folder = plan.folder / task.sequence
    folder.mkdir(parents=True, exist_ok=True)
    target = task.out / EVAL_FILE if task.stage == "eval" else task.out
    name = task.link + (".json" if task.stage == "eval" else "")
    link(folder / name, os.path.relpath(target, folder))


def execute(plan: RunPlan, client, progress=None) -> dict:
    """Submit every task (each after the ones it depends on) and wait for all -> key -> status.

    ``progress(task, status)`` is called as each one ends. A task whose worker died more often
    than the scheduler allows (``KilledWorker``), or whose result cannot be had, fails with that
    error; the others go on.
    """
    from distributed import as_completed

    futures, by_future = {}, {}
    for t in plan.tasks:
        fut = client.submit(run_task, t.spec, *[futures[d] for d in t.deps], key=f"egograph-{plan.name}-{t.key}",
                            pure=False, retries=0)
        futures[t.key] = fut
        by_future[fut.key] = t
    results = {}
    for fut in as_completed(list(futures.values())):
        t = by_future[fut.key]
        try:
            res = fut.result()
        except Exception as exc:  # KilledWorker, a lost scheduler, a dependency that could not run
            res = {"key": t.key, "status": FAILED, "reused": False, "warnings": [], "seconds": None,
                   "error": f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}"}
        results[t.key] = res
        if res["status"] == OK:
            link_output(plan, t)
        if progress is not None:
            progress(t, res)
    return {t.key: results[t.key] for t in plan.tasks}


def last_round(plan: RunPlan) -> int:
    return max((t.round for t in plan.tasks), default=0)


def pooled_reports(plan: RunPlan, results: dict, round: int | None = None) -> dict:
    """tracker -> EvalReport of every sequence whose evaluation succeeded, in sequence order:
    the counts of each sequence read back exactly (raw sums), pooled by summing them; of the last
    adaptation round unless ``round`` says which."""
    from egograph.eval.report import EvalReport

    r = last_round(plan) if round is None else round
    reports = {}
    for tracker in plan.trackers:
        pooled = EvalReport()
        for t in plan.tasks:
            if t.stage == "eval" and t.tracker == tracker and t.round == r and results[t.key]["status"] == OK:
                one = EvalReport.from_json_dict(json.loads((t.out / EVAL_FILE).read_text()))
                for name, s in one.sequences.items():
                    pooled.add(name, s.result, s.intervals, s.labels, s.frames_without_file, ap=s.ap)
        if "eval" in plan.stages:
            reports[tracker] = pooled
    return reports


def summarize(plan: RunPlan, results: dict) -> dict:
    """The run's summary: what ran, each task's status per sequence, the failures (one-line errors,
    the RUNS folder written as ``RUNS``), and per tracker the pooled evaluation in the ``egograph
    eval --json`` format with its per-sequence rows. No time and no output path."""
    status = {s.id: {} for s in plan.sequences}
    failures = []
    runs = str(plan.runs)
    for t in plan.tasks:
        r = results[t.key]
        status[t.sequence][t.label] = r["status"]
        if r["status"] != OK:
            failures.append({"sequence": t.sequence, "stage": t.label, "status": r["status"],
                             "error": (r.get("error") or "").replace(runs, "RUNS")})
    out = {"egograph_version": __version__, "dataset": str(plan.dataset), "stages": plan.stages,
           "trackers": plan.trackers, "detections": plan.detections, "config_digest": plan.config_digest,
           "sequences": status, "failures": failures,
           "evaluation": {k: r.to_json_dict() for k, r in pooled_reports(plan, results).items()}}
    if last_round(plan):
        out["rounds"] = {str(r): {"evaluation": {k: v.to_json_dict() for k, v in pooled_reports(plan, results, r).items()},
                                  "adapt": adapt_summaries(plan, results, r)}
                         for r in range(0, last_round(plan) + 1)}
    return out


def adapt_summaries(plan: RunPlan, results: dict, r: int) -> dict:
    """Per sequence, what round ``r``'s adapt did (its adapt.json: held-back check, heads, stop)."""
    out = {}
    for t in plan.tasks:
        if t.stage == "adapt" and t.round == r and results[t.key]["status"] == OK:
            try:
                doc = json.loads((t.out / "adapt.json").read_text())
            except (OSError, ValueError):
                continue
            out[t.sequence] = {"holdback_auc": doc.get("holdback_auc"), "stop": doc.get("stop"),
                               "heads": sorted(int(k) for k, v in doc.get("instances", {}).items() if v.get("head"))}
    return out


def finish_run(plan: RunPlan, results: dict, command: str | None = None) -> dict:
    from egograph.io.atomic import atomic_write_text

    summary = summarize(plan, results)
    atomic_write_text(plan.folder / SUMMARY_FILE, json.dumps(summary, indent=1) + "\n")
    write_run_json(plan, results, command)
    return summary


def run_dataset(plan: RunPlan, cfg, *, client=None, workers: int = 2, scheduler: str | None = None,
                progress=None, command: str | None = None) -> RunOutcome:
    """Run a plan (:func:`plan_run`) on ``client``, or on a cluster opened for it
    (:func:`open_client`, closed at the end) -> :class:`RunOutcome`."""
    own = client is None
    if own:
        client = open_client(workers, scheduler)
    try:
        start_run(plan, cfg, command)
        results = execute(plan, client, progress)
    finally:
        if own:
            close_client(client)
    return RunOutcome(plan, results, finish_run(plan, results, command))
