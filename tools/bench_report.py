#!/usr/bin/env python
"""Render docs/benchmarks.md from the benchmarks' own JSON files (docs/bench/*.json).

    .venv/bin/python tools/bench_report.py                 # write docs/benchmarks.md
    .venv/bin/python tools/bench_report.py --check         # exit 1, with a diff, when it differs
    .venv/bin/python tools/bench_report.py --commands      # every section's command (a shell script)
    .venv/bin/python tools/bench_report.py --commands --missing   # only those not yet recorded

Every ``tools/bench_*.py`` writes the tables it prints, with its command line, revision, machine and
wall time, to ``docs/bench/<tool>[-<tag>].json`` (tools/benchdoc.py). This script lays those files
out in the order of ``SECTIONS`` (a JSON file no section names is shown at the end), each section
with what it measures, the command that regenerates it and where its figures came from; a section
whose JSON is missing says so and gives the command. Same JSON files, same bytes: nothing here
reads the clock or the machine. No figure in docs/benchmarks.md is typed by hand.
"""

from __future__ import annotations

import argparse
import ast
import datetime as _dt
import difflib
import functools
import hashlib
import json
import os
import re
import subprocess
import sys
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path

import benchdoc

REPO = Path(__file__).resolve().parents[1]
BENCH_DIR = REPO / "docs" / "bench"
OUT = REPO / "docs" / "benchmarks.md"
PY = ".venv/bin/python"
REGEN_DIR_NAME = "regeneration"  # docs/bench/regeneration/<tier>.json: the last regeneration's log
REGEN_FORMAT = "egograph-regeneration/1"
LOG_DIR = REPO / ".cache" / "regenerate"  # each section's output while it regenerates


def section_log(stem: str) -> Path:
    """Where a section's command writes its output while it regenerates."""
    return LOG_DIR / f"{stem}.log"


@dataclass(frozen=True)
class Section:
    """One benchmark run: its JSON file's stem (``<tool>[-<tag>]``), a heading, what it measures
    (no figures: those come from the JSON), and the command that regenerates the file at the sizes
    the docs quote (the full tier).

    ``quick`` is the same benchmark on fewer or shorter recordings of the same held-out seeds (the
    quick tier: every section in about an hour on 2 cores); ``sizes`` says what each tier runs, as
    the page shows it. ``modules`` are the paths (folders or files, from the repository root) whose
    code the benchmark exercises besides its own tool: their digest is kept in the record, and the
    page says whether they changed since. ``quick_min`` is the quick tier's measured or estimated
    cost in minutes on this 2-core machine: regeneration runs cheap sections first. ``after``: the
    sections whose outputs this one reads (run first; a regeneration of this section alone runs them
    too when they are not current or their outputs are missing). ``outputs``: per tier, the paths
    (from the repository root) that this section writes for later sections to read; a record whose
    outputs for the tier are missing (a fresh checkout has no ``.cache``) is run again."""

    stem: str
    heading: str
    about: str
    command: str
    quick: str = ""
    sizes: tuple[tuple[str, str], ...] = ()
    modules: tuple[str, ...] = ()
    quick_min: float = 5.0
    after: tuple[str, ...] = ()
    outputs: tuple[tuple[str, str], ...] = ()

    @property
    def tool(self) -> str:
        return self.stem.split("-", 1)[0]

    def command_for(self, tier: str) -> str:
        return self.quick if tier == "quick" and self.quick else self.command

    def size(self, tier: str) -> str:
        return dict(self.sizes).get(tier, "")

    def missing_outputs(self, tier: str, repo: Path = REPO) -> list[str]:
        """The paths of ``outputs`` for ``tier`` that do not exist under ``repo``."""
        return [p for t, p in self.outputs if t == tier and not (repo / p).exists()]

    def paths(self) -> tuple[str, ...]:
        """What the module digest covers: the tool, tools/benchset.py when the tool reads the
        benchmark set, and ``modules``."""
        return (f"tools/{self.tool}.py", *self.modules)


TIERS = ("quick", "full")
"""Regeneration tiers, smallest first: a record of a later tier also counts as current for an earlier one."""

# The packages a benchmark exercises, for the staleness digest (configs: the defaults every run reads).
BASE = ("egograph/core", "egograph/io", "egograph/configs")
SYNTH = ("egograph/synth",)
LIFT = ("egograph/geometry",)
TRACK = ("egograph/track", "egograph/eval")
POSES = ("egograph/poses",)
FRONTEND = ("egograph/frontend",)
STEPS = ("egograph/steps",)
SET_TRACKING = BASE + SYNTH + LIFT + TRACK + STEPS

HELD_OUT_12 = "$(seq 301 312)"
HELD_OUT_5 = "$(seq 301 305)"
QUICK_HELD_OUT = "301 302"  # the quick tier: the first two held-out recordings, 1000 frames each
QUICK_SIZE = "2 held-out recordings x 1000 frames (seeds 301, 302)"
FULL_12 = "12 held-out recordings x 3000 frames (seeds 301-312)"
HELD_OUT_12_SIZES = (("quick", QUICK_SIZE), ("full", FULL_12))
HELD_OUT_5_SIZES = (("quick", QUICK_SIZE), ("full", "5 held-out recordings x 3000 frames (seeds 301-305)"))
JOINT_SIZES = (("quick", "1 held-out recording x 1000 frames (seed 301)"),
               ("full", "3 held-out recordings x 3000 frames (seeds 301-303)"))
RGB_SIZES = (("quick", "one RGB recording x 150 frames (seed 1)"), ("full", "one RGB recording x 300 frames (seed 1)"))
FRONTEND_SIZES = (("quick", "1 RGB recording x 300 frames (seed 21)"),
                  ("full", "4 RGB recordings x 1000 frames (seeds 21, 22, 25, 26)"))
DEVICE_FRONTEND_SIZES = (("quick", "1 device-world RGB recording x 300 frames (seed 21)"),
                         ("full", "6 device-world RGB recordings x 300 frames (seeds 21-26)"))
# bench_frontend_trackers on those recordings, per tier (both device-world end-to-end sections)
DEVICE_FRONTEND = f"{PY} tools/bench_frontend_trackers.py --world device --seeds 21 22 23 24 25 26 --frames 300"
DEVICE_FRONTEND_QUICK = f"{PY} tools/bench_frontend_trackers.py --world device --seeds 21 --frames 300"
# the verified front-end at configs/frontend-svoe.yaml's operating point (0.45, chosen on tuning recordings
# 27-29), for MVPE too: detector and trackers at one threshold
VERIFY_THRESHOLD = 0.45
VERIFY_SETS = (f"frontend.verify=all,frontend.verify_threshold={VERIFY_THRESHOLD},"
               f"graph.score_threshold={VERIFY_THRESHOLD},track.score_threshold={VERIFY_THRESHOLD}")
VERIFY_VARIANT = f"--variant verify:{VERIFY_SETS}"
# issue 39's proposals: selective search beside the segments, at the cap where it pays (docs/frontend.md, stop 63)
SELECTIVE = "frontend.image_selective=single"
SELECTIVE_VARIANT = f"--variant verify+selective:{VERIFY_SETS},{SELECTIVE},frontend.max_proposals=24"
# the held-out device-world RGB recordings bench_frontend_trackers-device builds, and the proposal variants
DEVICE_RGB = ".cache/bench_fe/device/f300"
MULTISCALE = "frontend.image_k_scales=[100,300,1000],frontend.image_per_scale=8"
RECALL_ARGS = ("--recall --recall-step 10 --recall-caps 12 24 48 --runs svoe --skip-vit --cache .cache/bench_fe/models "
               "--variant current: --variant source-order:frontend.proposal_order=source "
               "--variant no-mesh:frontend.proposals=geometry+image "
               f"--variant 'multiscale:{MULTISCALE}' --variant selective:{SELECTIVE}")
STRONG_POSE_ERROR = ("--synth-set pose_error.drift_trans=0.006 --synth-set pose_error.drift_rot=0.1 "
                     "--synth-set pose_error.jump_rate=0.3 --synth-set 'pose_error.jump_trans=[0.04,0.1]'")
CONFIDENCE_SIZES = (("quick", "2 held-out recordings x 900 frames (seeds 1, 301)"),
                    ("full", "6 held-out recordings x 900 frames (the demo's seeds 1-3, 301-303)"))
MILD_POSE_ERROR = ("--synth-set pose_error.drift_trans=0.004 --synth-set pose_error.drift_rot=0.06 "
                   "--synth-set pose_error.jump_rate=0.2")

def heldout_robust(world: str, seeds: str, frames: int, suffix: str = "") -> str:
    """bench_trackers' dominance run (memory, kf, graph, graph-causal on robust lifting) in ``world``;
    ``suffix`` tells a world's twin section apart (its json tag and its --out folder)."""
    return (f"{PY} tools/bench_trackers.py --world {world} --seeds {seeds} --frames {frames} --modes robust "
            f"--trackers memory kf graph graph-causal --no-oracle --jobs 1 --json-tag heldout-robust{suffix} "
            f"--out .cache/bench_trackers_robust{suffix.replace('-', '_')}")


def causal_lags(world: str, seeds: str, frames: int, suffix: str = "") -> str:
    """bench_causal's lag table without the latency stream, in ``world``."""
    return (f"{PY} tools/bench_causal.py --world {world} --seeds {seeds} --frames {frames} --no-latency "
            f"--json-tag heldout6{suffix}")


def confidence(world: str, seeds: str, frames: int, tag: str, jobs: bool) -> str:
    """bench_confidence on ``seeds`` x ``frames`` in ``world`` (``jobs``: two recordings at a time)."""
    return (f"{PY} tools/bench_confidence.py --world {world} --seeds {seeds} --frames {frames}"
            f"{' --jobs 2' if jobs else ''} --json-tag {tag}")


SECTIONS: tuple[Section, ...] = (
    Section("bench_trackers", "Trackers on the held-out benchmark set",
            "Every tracker (`memory`, `kf`, `graph`, `graph-causal`, the `+graph` smoothing of memory and kf, and "
            "an oracle: true boxes lifted, true intervals) on the same observations of the 12 held-out benchmark "
            "recordings (generator revision 4, recalibrated front-ends; no knob was tuned on them), SVOE and MVPE, "
            "both lifting modes, under the IT3DEgo protocol; counts pooled over the recordings as the reference "
            "evaluator pools sequences; ratios against `kf` on `reference` lifting, the published pipeline. Then "
            "the intervals recovered, the lifting error, the graph's targets and the calibration bands of the "
            "simulated front-ends (memory + reference lifting).",
            f"{PY} tools/bench_trackers.py --world legacy --seeds {HELD_OUT_12} --frames 3000 --jobs 2",
            quick=f"{PY} tools/bench_trackers.py --world legacy --seeds {QUICK_HELD_OUT} --frames 1000 --jobs 2",
            sizes=HELD_OUT_12_SIZES, modules=SET_TRACKING, quick_min=6),
    Section("bench_trackers-device", "Trackers on simulated detections: device world against legacy world",
            "The same seeds built in both generator worlds in one run (issue 38: the device world changes the "
            "pixels, but also the geometry: category meshes at real sizes, hands in AHAT), the detections "
            "simulated by the same front-ends: memory, kf and the graph on both lifting modes. The tables are of "
            "the device world; the last table sets the calibration bands (memory + reference lifting) and the "
            "graph's targets of both worlds side by side: a tracker's figures on simulated detections should not "
            "depend on how the pixels look.",
            f"{PY} tools/bench_trackers.py --world device legacy --seeds {HELD_OUT_12} --frames 3000 --trackers "
            "memory kf graph --no-oracle --jobs 2 --json-tag device --out .cache/bench_trackers_device",
            quick=f"{PY} tools/bench_trackers.py --world device legacy --seeds {QUICK_HELD_OUT} --frames 1000 "
            "--trackers memory kf graph --no-oracle --jobs 2 --json-tag device --out .cache/bench_trackers_device",
            sizes=tuple((tier, f"{size} in each world") for tier, size in HELD_OUT_12_SIZES),
            modules=SET_TRACKING, quick_min=20),
    Section("bench_causal", "Causal and lagged tracking, online latency",
            "graph-causal (lag 0 and lagged) against memory, kf and the offline graph on the same robust "
            "observations of the 12 held-out recordings, pooled, every threshold; the causal ceiling is the true "
            "centre on every frame from each instance's first detection (no causal tracker can answer before it). "
            "Then recall at 0.25 m against lag, and the per-frame latency of the online API "
            "(`OnlineTracker.step` + `collect`) over a 50,000-frame stream of 8 instances.",
            f"{PY} tools/bench_causal.py --world legacy --seeds {HELD_OUT_12} --frames 3000 --plot .cache/lag.png",
            quick=f"{PY} tools/bench_causal.py --world legacy --seeds {QUICK_HELD_OUT} --frames 1000 --stream-frames 5000 "
            "--plot .cache/lag.png",
            sizes=(("quick", QUICK_SIZE + "; latency over a 5,000-frame stream"),
                   ("full", FULL_12 + "; latency over a 50,000-frame stream")), modules=SET_TRACKING, quick_min=5),
    Section("bench_trackers-heldout-robust", "Does every egograph tracker beat every baseline? (issue 29)",
            "`memory`, `kf`, `graph` and `graph-causal` on the same robust observations of the 12 held-out "
            "recordings (seeds 301-312; no knob was chosen on them), SVOE and MVPE: the tables pooled, then "
            "whether each egograph tracker's P and R at every threshold are at least memory's and kf's and its L2 "
            "below theirs, pooled and (offline graph) on every recording, with the figures that miss.",
            heldout_robust("legacy", HELD_OUT_12, 3000), quick=heldout_robust("legacy", QUICK_HELD_OUT, 1000),
            sizes=HELD_OUT_12_SIZES, modules=SET_TRACKING, quick_min=3),
    Section("bench_causal-heldout6", "Causal tracking against its ceiling, and P, R, L2 against lag (issue 29)",
            "graph-causal at lags 0, 1, 2, 5, 10 and 30 s against memory, kf, the offline graph and the causal "
            "ceiling on held-out recordings 301-306, robust lifting, pooled: issue 29's causal targets and the lag "
            "at which the causal answer reaches 95 % of the offline recall at 0.25 m.",
            causal_lags("legacy", "$(seq 301 306)", 3000), quick=causal_lags("legacy", QUICK_HELD_OUT, 1000),
            sizes=(("quick", QUICK_SIZE), ("full", "6 held-out recordings x 3000 frames (seeds 301-306)")),
            modules=SET_TRACKING, quick_min=3),
    Section("bench_trackers-heldout-robust-device", "Does every egograph tracker beat every baseline? Device world",
            "`bench_trackers-heldout-robust` on the device world's build of the same 12 held-out seeds (301-312; issue 38: "
            "photographic surfaces, category meshes at real sizes, hands in AHAT): `memory`, `kf`, `graph` and "
            "`graph-causal` on the same robust observations, SVOE and MVPE, pooled and per recording. The README's "
            "tracker table is rendered from this record; no knob was chosen on these recordings, nor in this world.",
            heldout_robust("device", HELD_OUT_12, 3000, "-device"),
            quick=heldout_robust("device", QUICK_HELD_OUT, 1000, "-device"),
            sizes=HELD_OUT_12_SIZES, modules=SET_TRACKING, quick_min=3),
    Section("bench_causal-heldout6-device", "Causal tracking against its ceiling, and P, R, L2 against lag: device world",
            "`bench_causal-heldout6` on the device world's build of held-out recordings 301-306: graph-causal at "
            "lags 0, 1, 2, 5, 10 and 30 s against memory, kf, the offline graph and the causal ceiling, robust "
            "lifting, pooled. The README's lag table is rendered from this record.",
            causal_lags("device", "$(seq 301 306)", 3000, "-device"),
            quick=causal_lags("device", QUICK_HELD_OUT, 1000, "-device"),
            sizes=(("quick", QUICK_SIZE), ("full", "6 held-out recordings x 3000 frames (seeds 301-306)")),
            modules=SET_TRACKING, quick_min=3),
    Section("bench_causal-latency", "Online API latency",
            "The per-frame latency of the online API (`OnlineTracker.step` + `collect`, lag 0) over a 20,000-frame "
            "synthetic stream of 8 instances (no rendering: lifted observations, each object seen on about a third "
            "of the frames, 3 % false matches, a carry every ~40 s): median, p99 and maximum over all frames and "
            "the first and last tenth (growth over the stream), wall and CPU time, resident memory. Compare "
            "revisions by running the same command from each checkout in one window: the machine is shared.",
            f"{PY} tools/bench_causal.py --latency-only --stream-frames 20000 --json-tag latency",
            quick=f"{PY} tools/bench_causal.py --latency-only --stream-frames 5000 --json-tag latency",
            sizes=(("quick", "a 5,000-frame stream of 8 instances"), ("full", "a 20,000-frame stream of 8 instances")),
            modules=BASE + LIFT + TRACK, quick_min=1),
    Section("bench_confidence-heldout", "Answers with a confidence: curves over confidence, operating point, calibration",
            "Every egograph tracker (`graph`, `graph-causal` at each lag, `memory+graph` smoothing) answers every "
            "frame with a calibrated confidence; per detection set and threshold, the average precision of its "
            "precision-recall curve over confidence (all-point interpolated), whether the curve passes at or above "
            "every baseline's point (`memory`, `kf`, both liftings; at the baseline's recall, precision at least "
            "the baseline's), pooled and on every recording; P and R at the default operating point "
            "(`graph.answers.min_confidence`) against the baselines'; the reliability table and expected "
            "calibration error at 0.25 m. Held out: the calibration and the operating point were fitted on tuning "
            "seeds (`--fit`). The demo's seeds 1-3 and held-out 301-303, all at 900 frames; the issue's 12 "
            "held-out recordings of 3000 frames are the next section.",
            confidence("legacy", "1 2 3 301 302 303", 900, "heldout", jobs=True),
            quick=confidence("legacy", "1 301", 900, "heldout", jobs=False),
            sizes=CONFIDENCE_SIZES, modules=BASE + SYNTH + LIFT + TRACK, quick_min=20),
    Section("bench_confidence-demo", "Answers with a confidence: the demo's recordings alone (seeds 1-3)",
            "The same measurement on the issue's second held-out set exactly as it names it, the demo's seeds 1-3 "
            "at 900 frames, without 301-303 (the section above pools all six). Added at stop 68: pooled ECE "
            "over six recordings let errors of opposite sign in one confidence bin (over-confident stands on "
            "1-3, under-confident on 301-303) partly cancel, so the six-recording figure is not the issue's.",
            confidence("legacy", "1 2 3", 900, "demo", jobs=True), quick=confidence("legacy", "1", 900, "demo", jobs=False),
            sizes=(("quick", "the demo's first recording x 900 frames (seed 1)"),
                   ("full", "the demo's 3 recordings x 900 frames (seeds 1-3)")),
            modules=BASE + SYNTH + LIFT + TRACK, quick_min=2),
    Section("bench_confidence-demo-device", "Answers with a confidence: the demo's recordings in the device world",
            "`bench_confidence-demo` on the device world's build of the demo's seeds 1-3 at 900 frames: the world "
            "`bash tools/demo.sh` renders by default, its detections simulated here as for every tracker-only "
            "section. The calibration and the operating point are those fitted on legacy-world tuning recordings.",
            confidence("device", "1 2 3", 900, "demo-device", jobs=True),
            quick=confidence("device", "1", 900, "demo-device", jobs=False),
            sizes=(("quick", "the demo's first recording x 900 frames (seed 1)"),
                   ("full", "the demo's 3 recordings x 900 frames (seeds 1-3)")),
            modules=BASE + SYNTH + LIFT + TRACK, quick_min=4),
    Section("bench_confidence-heldout12", "Answers with a confidence: the issue's held-out set at full length",
            "The same measurement on the 12 held-out recordings of 3000 frames the issue asks for (seeds "
            "301-312, legacy world, lag 0), none of which any knob of the calibration or the operating point "
            "was chosen on: pooled and per-recording curves against every baseline's point, P and R at the "
            "default operating point, reliability and ECE.",
            confidence("legacy", HELD_OUT_12, 3000, "heldout12", jobs=True),
            quick=confidence("legacy", QUICK_HELD_OUT, 1000, "heldout12", jobs=False),
            sizes=HELD_OUT_12_SIZES, modules=BASE + SYNTH + LIFT + TRACK, quick_min=2),
    Section("bench_confidence-heldout12-device", "Answers with a confidence: the held-out set in the device world",
            "`bench_confidence-heldout12` on the device world's build of the same 12 held-out seeds (301-312; "
            "issue 38: category meshes at real sizes, hands in AHAT), the calibration and the operating point as "
            "fitted on legacy-world tuning recordings: whether they carry over to the world the bench tools now "
            "default to. Pooled and per-recording curves against every baseline's point, P and R at the default "
            "operating point, reliability and ECE.",
            confidence("device", HELD_OUT_12, 3000, "heldout12-device", jobs=True),
            quick=confidence("device", QUICK_HELD_OUT, 1000, "heldout12-device", jobs=False),
            sizes=HELD_OUT_12_SIZES, modules=BASE + SYNTH + LIFT + TRACK, quick_min=2),
    Section("bench_confidence-heldout-lags", "Answers with a confidence: graph-causal with a lag",
            "The same held-out recordings with graph-causal at lags of 2 s and 30 s (its calibration was fitted "
            "at lag 0: a lagged answer's raw confidence is the place's support, so its ECE is not meant to hold).",
            f"{PY} tools/bench_confidence.py --world legacy --seeds 1 2 3 301 302 303 --frames 900 --lags 2 30 "
            "--json-tag heldout-lags",
            quick=f"{PY} tools/bench_confidence.py --world legacy --seeds 1 301 --frames 900 --lags 2 30 --json-tag heldout-lags",
            sizes=CONFIDENCE_SIZES, modules=BASE + SYNTH + LIFT + TRACK, quick_min=20),
    Section("bench_confidence-fit", "Answers with a confidence: the calibration fit (tuning seeds)",
            "The calibration fit per tracker family and front-end: the isotonic fit of calibrated against raw "
            "confidence of the stands, every other kind of answer's share within 0.25 m, the answers per kind, "
            "and the operating points at which each egograph tracker's P and R reach every baseline's, on "
            "tuning seeds only.",
            f"{PY} tools/bench_confidence.py --world legacy --seeds $(seq 4 20) --frames 900 3000 --fit --jobs 2 --json-tag fit",
            quick=f"{PY} tools/bench_confidence.py --world legacy --seeds 4 5 --frames 900 --fit --json-tag fit",
            sizes=(("quick", "2 tuning recordings x 900 frames (seeds 4, 5)"),
                   ("full", "17 tuning seeds (4-20) x 900 and 3000 frames: 34 recordings, the lengths of both "
                            "held-out sets")),
            modules=BASE + SYNTH + LIFT + TRACK, quick_min=20),
    Section("bench_causal-fixed-scale", "Causal tracking without the online noise-scale fit",
            "The same as above with the detection sigmas as configured (`graph.noise.online_auto=false`).",
            f"{PY} tools/bench_causal.py --world legacy --seeds {HELD_OUT_12} --frames 3000 --no-latency "
            "--set graph.noise.online_auto=false --json-tag fixed-scale",
            quick=f"{PY} tools/bench_causal.py --world legacy --seeds {QUICK_HELD_OUT} --frames 1000 --no-latency "
            "--set graph.noise.online_auto=false --json-tag fixed-scale",
            sizes=HELD_OUT_12_SIZES, modules=SET_TRACKING, quick_min=3),
    Section("bench_causal-given-scale", "Causal tracking with each front-end's scale given",
            "The same with the scale the offline graph fits on each front-end on tuning seeds 1-12, given "
            "instead of fitted online.",
            f"{PY} tools/bench_causal.py --world legacy --seeds {HELD_OUT_12} --frames 3000 --no-latency "
            "--set graph.noise.online_auto=false --set-svoe graph.noise.scale=2.75 --set-mvpe graph.noise.scale=0.58 "
            "--json-tag given-scale",
            quick=f"{PY} tools/bench_causal.py --world legacy --seeds {QUICK_HELD_OUT} --frames 1000 --no-latency "
            "--set graph.noise.online_auto=false --set-svoe graph.noise.scale=2.75 --set-mvpe graph.noise.scale=0.58 "
            "--json-tag given-scale",
            sizes=HELD_OUT_12_SIZES, modules=SET_TRACKING, quick_min=3),
    Section("bench_frontend_trackers", "Trackers on `egograph detect`'s own detections",
            "`egograph detect` on four RGB benchmark recordings (seeds 21, 22, 25, 26; none used to choose a "
            "knob), then the paper's pipeline (memory + reference lifting) against the graph (robust lifting) "
            "and graph-causal on the same detections, beside the simulated front-end's sets and the SOT (CSRT) "
            "baseline; the share of true detections (on the instance: IoU >= 0.3 or the box centre inside its "
            "true box), the 2D table against `2d_bbox_annot/` and the ratios graph / paper.",
            f"{PY} tools/bench_frontend_trackers.py --world legacy --seeds 21 22 25 26 --frames 1000",
            quick=f"{PY} tools/bench_frontend_trackers.py --world legacy --seeds 21 --frames 300",
            sizes=FRONTEND_SIZES, modules=SET_TRACKING + FRONTEND, quick_min=10),
    Section("bench_frontend_trackers-frontend-mvpe", "The same with `--config frontend-mvpe`",
            "The graph with the stricter stands of the packaged config `frontend-mvpe` (what "
            "`egograph detect --enroll mvpe` prints), on the same detections.",
            f"{PY} tools/bench_frontend_trackers.py --world legacy --seeds 21 22 25 26 --frames 1000 --config frontend-mvpe "
            "--json-tag frontend-mvpe",
            quick=f"{PY} tools/bench_frontend_trackers.py --world legacy --seeds 21 --frames 300 --config frontend-mvpe "
            "--json-tag frontend-mvpe",
            sizes=FRONTEND_SIZES, modules=SET_TRACKING + FRONTEND, quick_min=4, after=("bench_frontend_trackers",)),
    Section("bench_frontend_trackers-device", "Trackers on `egograph detect`'s own detections in the device world",
            "The same measurement on RGB recordings of the device world (issue 38: photographic surfaces, category "
            "meshes, the PV camera's exposure, noise, motion blur and compression, reaching hands; seeds 21-26, on "
            "which no knob was tuned in this world; the front-end's tuning seeds are 27-28): the share of true "
            "detections, the visible instance-frames found, and the graph against the paper's pipeline on those "
            "detections, with the opt-in verification (issue 39, `frontend.verify=all`, detector and trackers at "
            f"threshold {VERIFY_THRESHOLD}: for SVOE exactly `--config frontend-svoe`) as a second front-end row in the full tier (the "
            "quick tier has the current front-end only), and in the full tier a third: the verified front-end with "
            "OpenCV's selective search beside the image segments and 24 proposals a frame instead of 12 "
            "(`frontend.image_selective=single`, `max_proposals=24`; stop 63, opt-in). MVPE's proposals are `geometry+image` since stop 47 (before: `geometry`, 76 / 177 detections on "
            "the instance); SVOE's `geometry+mesh+image` since stop 55 (before: `geometry+image`). The README's first table (end to end from pixels) is this record's default rows.",
            f"{DEVICE_FRONTEND} --no-sot --no-guide --no-causal {VERIFY_VARIANT} {SELECTIVE_VARIANT} --json-tag device",
            quick=f"{DEVICE_FRONTEND_QUICK} --no-sot --no-guide --no-causal --json-tag device",
            sizes=DEVICE_FRONTEND_SIZES, modules=SET_TRACKING + FRONTEND, quick_min=15),
    Section("bench_frontend_trackers-device-frontend-mvpe", "The same in the device world with `--config frontend-mvpe`",
            "MVPE only: the graph with the stricter stands of the packaged config `frontend-mvpe` (what `egograph "
            "detect --enroll mvpe` prints, and what the README's real-sequence commands use; its two knobs were "
            "chosen on legacy-world RGB recordings 27-30), on the device world's held-out RGB recordings 21-26 as "
            "in the section above; the front-end's knobs are the defaults, so the detections are those of that "
            "section's default MVPE rows (stop 71).",
            f"{DEVICE_FRONTEND} --sets mvpe --no-sot --no-guide --no-causal --config frontend-mvpe "
            "--json-tag device-frontend-mvpe",
            quick=f"{DEVICE_FRONTEND_QUICK} --sets mvpe --no-sot --no-guide --no-causal --config frontend-mvpe "
            "--json-tag device-frontend-mvpe",
            sizes=DEVICE_FRONTEND_SIZES, modules=SET_TRACKING + FRONTEND, quick_min=3,
            after=("bench_frontend_trackers-device",)),
    Section("bench_detect", "`egograph detect`: speed and detections",
            "Frames/s end to end, CPU ms/frame and ms per stage (read = waiting for the PNG decode, which runs in "
            "a background thread; proposals; crops; encoder; matching; write) with the embedded "
            "EfficientNet-lite0, the share of true detections on a synthetic recording, and the per-crop cost of "
            "a ViT-S/14-sized ONNX encoder (random weights, built by the benchmark), on a 60-frame `synth/tiny` "
            "recording with PV RGB.",
            f"{PY} tools/bench_detect.py --runs mvpe:mean,svoe",
            quick=f"{PY} tools/bench_detect.py --runs mvpe:mean,svoe --frames 20",
            sizes=(("quick", "one 20-frame synth/tiny recording with PV RGB"),
                   ("full", "one 60-frame synth/tiny recording with PV RGB")),
            modules=BASE + SYNTH + FRONTEND + STEPS, quick_min=6),
    Section("bench_detect-recall", "Proposal recall in the device world",
            "Issue 39's item 0: the share of visible instances (at least half visible, true box short side >= 24 px) "
            "that a proposal covers at IoU >= 0.5, against the proposals per frame, at `detect`'s per-frame cap "
            "(`frontend.max_proposals`: 12, the default, 24 and 48), by the instance's size in the frame and by the "
            "head's turn over the PV exposure (motion blur; stop 68), on the "
            "held-out device-world RGB recordings (every 10th frame). Variants: the current default "
            "(`geometry+mesh+image` since stop 55, the cap filled by objectness and agreement between the "
            "sources since stop 58), the cap filled source by source as before stop 58 "
            "(`proposal_order=source`: geometry, mesh, image), without the objects standing in the scene mesh "
            "(`geometry+image`), the default with multi-scale image segments "
            "(`image_k_scales=[100,300,1000]`, 8 a scale), and the default with OpenCV's selective search beside "
            "the segments (`image_selective=single`, stop 63, opt-in). Then why the rest are not covered at a "
            "cap of 12 (stop 68): the plausible proposal overlapping an instance most is too large (merged with "
            "its surround), too small (a fragment), displaced, or none is near; by that proposal's source, the "
            "instance's range from the camera and whether it is carried.",
            f"{PY} tools/bench_detect.py --rec {DEVICE_RGB}/seed21 {DEVICE_RGB}/seed22 {DEVICE_RGB}/seed23 "
            f"{DEVICE_RGB}/seed24 {DEVICE_RGB}/seed25 {DEVICE_RGB}/seed26 {RECALL_ARGS} --json-tag recall",
            quick=f"{PY} tools/bench_detect.py --rec {DEVICE_RGB}/seed21 {RECALL_ARGS} --json-tag recall",
            sizes=(("quick", "1 device-world RGB recording x 300 frames (seed 21), every 10th frame"),
                   ("full", "6 device-world RGB recordings x 300 frames (seeds 21-26), every 10th frame")),
            modules=BASE + FRONTEND + STEPS, quick_min=3, after=("bench_frontend_trackers-device",)),
    Section("bench_graph_speed", "Graph solve time against recording length",
            "The offline graph solve (noise-scale fit included, negative evidence excluded) on the MVPE "
            "observations of benchmark recordings (1-5 in the full tier) laid end to end, 8 instances, with both "
            "motion-break factors (switchable CustomFactor, DCS), against the `kf` baseline in the same run.",
            f"{PY} tools/bench_graph_speed.py --world legacy --frames 1000 10000 50000",
            quick=f"{PY} tools/bench_graph_speed.py --world legacy --frames 1000 10000 --seeds {QUICK_HELD_OUT} --rec-frames 1000 "
            "--repeat 1",
            sizes=(("quick", "1000 and 10,000 frames from held-out recordings 301-302 (1000 frames each, the quick "
                             "tier's), best of 1"),
                   ("full", "1000, 10,000 and 50,000 frames from tuning recordings 1-5 (3000 frames each), best of 2")),
            modules=BASE + SYNTH + LIFT + TRACK, quick_min=2),
    Section("bench_lift-svoe", "Lifting: SVOE",
            "3D error of the lifted true detections against `synth_gt/`, reference and robust lifting, with the "
            "reported and with the true poses (the lifting error alone), on 5 held-out recordings; lifting speed "
            "of both modes in the same run next to the floor of decoding the depth PNGs.",
            f"{PY} tools/bench_lift.py --world legacy --frames 3000 --seeds {HELD_OUT_5} --cache .cache/bench --set svoe "
            "--json-tag svoe",
            quick=f"{PY} tools/bench_lift.py --world legacy --frames 1000 --seeds {QUICK_HELD_OUT} --cache .cache/bench --set svoe "
            "--json-tag svoe",
            sizes=HELD_OUT_5_SIZES, modules=BASE + SYNTH + LIFT + STEPS, quick_min=3),
    Section("bench_lift-mvpe", "Lifting: MVPE", "The same for the MVPE detections.",
            f"{PY} tools/bench_lift.py --world legacy --frames 3000 --seeds {HELD_OUT_5} --cache .cache/bench --set mvpe "
            "--json-tag mvpe",
            quick=f"{PY} tools/bench_lift.py --world legacy --frames 1000 --seeds {QUICK_HELD_OUT} --cache .cache/bench --set mvpe "
            "--json-tag mvpe",
            sizes=HELD_OUT_5_SIZES, modules=BASE + SYNTH + LIFT + STEPS, quick_min=3),
    Section("bench_regt", "Ground-truth re-estimation (`egograph regt`), reported poses",
            "Each annotated interval's centre re-estimated from its annotated boxes (robust lifting) on 5 held-out "
            "recordings, against the true centre; then the audit: a seeded 10 % of the given centres shifted by "
            "0.2 m in 20 independent draws, and the share of shifted and untouched centres it flags.",
            f"{PY} tools/bench_regt.py --world legacy --seeds {HELD_OUT_5}",
            quick=f"{PY} tools/bench_regt.py --world legacy --seeds {QUICK_HELD_OUT} --frames 1000",
            sizes=HELD_OUT_5_SIZES, modules=SET_TRACKING, quick_min=3),
    Section("bench_regt-joint", "Ground-truth re-estimation with `--joint-poses`",
            "The same with the poses solved together with the annotated intervals' landmarks and the "
            "refinement factors (`regt --joint-poses`).",
            f"{PY} tools/bench_regt.py --world legacy --seeds {HELD_OUT_5} --joint-poses --json-tag joint",
            quick=f"{PY} tools/bench_regt.py --world legacy --seeds {QUICK_HELD_OUT} --frames 1000 --joint-poses --json-tag joint",
            sizes=HELD_OUT_5_SIZES, modules=SET_TRACKING + POSES, quick_min=4),
    Section("bench_refine-f3000-mesh", "Pose refinement of the held-out recordings (refined poses for bench_regt)",
            "The default sources (HoloLens model + mesh ICP) on the 5 held-out recordings; also writes the refined "
            "poses that `bench_regt-refined` reads.",
            f"{PY} tools/bench_refine.py --world legacy --seeds {HELD_OUT_5} --frames 3000 --rows +mesh "
            "--out-dir .cache/bench/refined/f3000 --json-tag f3000-mesh",
            quick=f"{PY} tools/bench_refine.py --world legacy --seeds {QUICK_HELD_OUT} --frames 1000 --rows +mesh "
            "--out-dir .cache/bench/refined/f1000 --json-tag f3000-mesh",
            sizes=HELD_OUT_5_SIZES, modules=BASE + SYNTH + POSES + STEPS, quick_min=4,
            outputs=(("quick", ".cache/bench/refined/f1000"), ("full", ".cache/bench/refined/f3000"))),
    Section("bench_regt-refined", "Ground-truth re-estimation with refined poses",
            "The same re-estimation with the poses of `egograph refine` (run the section above first).",
            f"{PY} tools/bench_regt.py --world legacy --seeds {HELD_OUT_5} "
            "--poses .cache/bench/refined/f3000/seed{seed}/plus_mesh --json-tag refined",
            quick=f"{PY} tools/bench_regt.py --world legacy --seeds {QUICK_HELD_OUT} --frames 1000 "
            "--poses .cache/bench/refined/f1000/seed{seed}/plus_mesh --json-tag refined",
            sizes=HELD_OUT_5_SIZES, modules=SET_TRACKING + POSES, quick_min=3, after=("bench_refine-f3000-mesh",)),
    Section("bench_joint", "Joint mode: poses and landmarks in one graph",
            "Per held-out recording and detection set, the offline graph tracker with four pose sources: "
            "reported, refined (`egograph refine`), joint (`--joint-poses`: the refinement factors plus the "
            "landmarks of the tracker's stands) and joint without the mesh ICP; ATE of the PV poses and the "
            "tracker's P/R at 0.25 m.",
            f"{PY} tools/bench_joint.py --world legacy --seeds {HELD_OUT_5}",
            quick=f"{PY} tools/bench_joint.py --world legacy --seeds {QUICK_HELD_OUT} --frames 1000",
            sizes=HELD_OUT_5_SIZES, modules=SET_TRACKING + POSES, quick_min=6),
    Section("bench_joint-strong", "Joint mode under stronger pose error",
            "The same on 3 recordings generated with 3x the drift and 4x the relocalisation jumps.",
            f"{PY} tools/bench_joint.py --world legacy --seeds 301 302 303 {STRONG_POSE_ERROR} --json-tag strong",
            quick=f"{PY} tools/bench_joint.py --world legacy --seeds 301 --frames 1000 {STRONG_POSE_ERROR} --json-tag strong",
            sizes=JOINT_SIZES, modules=SET_TRACKING + POSES, quick_min=5),
    Section("bench_joint-mild", "Joint mode under milder pose error",
            "The same with 2x the drift.",
            f"{PY} tools/bench_joint.py --world legacy --seeds 301 302 303 {MILD_POSE_ERROR} --json-tag mild",
            quick=f"{PY} tools/bench_joint.py --world legacy --seeds 301 --frames 1000 {MILD_POSE_ERROR} --json-tag mild",
            sizes=JOINT_SIZES, modules=SET_TRACKING + POSES, quick_min=5),
    Section("bench_refine-heldout", "Pose refinement on held-out recordings",
            "The default `egograph refine` (mesh ICP + self-check + covariance) on recordings whose seeds were "
            "never used while tuning (301-308 at 3000 frames, 101-104 at 1000, 201-210 at 150-600), each also "
            "with its true poses as the reported ones: ATE ratio, whether the self-check's verdict agrees with "
            "the truth, NEES of the written covariance, time per frame.",
            f"{PY} tools/bench_refine.py --world legacy --heldout --sets 3000 1000 150 300 450 600 --json-tag heldout",
            quick=f"{PY} tools/bench_refine.py --world legacy --heldout --sets 150 300 --json-tag heldout",
            sizes=(("quick", "the held-out sets of 150 and 300 frames (5 recordings)"),
                   ("full", "every held-out set: 8 x 3000, 4 x 1000, 10 x 150-600 frames")),
            modules=BASE + SYNTH + POSES + STEPS, quick_min=5),
    Section("bench_refine-sources", "Pose refinement per source (one RGB recording)",
            "Each source of the pose graph (HoloLens model, KISS-ICP, mesh ICP, COLMAP) alone and combined, on "
            "one 300-frame RGB recording, the self-check off (it keeps the input where there are no mesh "
            "keyframes).",
            f"{PY} tools/bench_refine.py --world legacy --seeds 1 --frames 300 --rgb --rows hololens +kiss +mesh +colmap "
            "mesh+colmap all --set selfcheck=false --json-tag sources",
            quick=f"{PY} tools/bench_refine.py --world legacy --seeds 1 --frames 150 --rgb --rows hololens +kiss +mesh +colmap "
            "mesh+colmap all --set selfcheck=false --json-tag sources",
            sizes=RGB_SIZES, modules=BASE + SYNTH + POSES + STEPS, quick_min=6),
    Section("bench_refine-colmap-fixed", "COLMAP factors with fixed sigmas",
            "The COLMAP rows with the fixed 0.3 deg / 1 cm sigmas instead of the bundle adjustment's covariance "
            "(`refine.colmap_covariance=false`), on the same recording.",
            f"{PY} tools/bench_refine.py --world legacy --seeds 1 --frames 300 --rgb --rows +mesh +colmap mesh+colmap "
            "--set selfcheck=false --set colmap_covariance=false --json-tag colmap-fixed",
            quick=f"{PY} tools/bench_refine.py --world legacy --seeds 1 --frames 150 --rgb --rows +mesh +colmap mesh+colmap "
            "--set selfcheck=false --set colmap_covariance=false --json-tag colmap-fixed",
            sizes=RGB_SIZES, modules=BASE + SYNTH + POSES + STEPS, quick_min=3),
    Section("bench_refine-colmap-every-frame", "COLMAP with every frame a keyframe",
            "The COLMAP source alone with every frame of the same recording a keyframe "
            "(`refine.colmap_stride=1`): what the bundle adjustment adds at its densest, and what it costs.",
            f"{PY} tools/bench_refine.py --world legacy --seeds 1 --frames 300 --rgb --rows +colmap --set selfcheck=false "
            "--set colmap_stride=1 --json-tag colmap-every-frame",
            quick=f"{PY} tools/bench_refine.py --world legacy --seeds 1 --frames 150 --rgb --rows +colmap --set selfcheck=false "
            "--set colmap_stride=1 --json-tag colmap-every-frame",
            sizes=RGB_SIZES, modules=BASE + SYNTH + POSES + STEPS, quick_min=4),
    Section("bench_run", "`egograph run` on Dask: 2 workers against 1, and a kill",
            "Synthetic sequences with PV RGB through every stage a dataset run has (`egograph detect`'s front-end, "
            "lift, track with memory, kf and graph, eval), with one local worker and with two, alternately, three "
            "rounds (the speed-up is their median: one pair of runs moves by 0.1-0.2x between regenerations): wall "
            "time, throughput, CPU per stage per frame, peak memory per worker process, bytes written per frame; "
            "then a 2-worker run killed with SIGKILL (scheduler, nanny and workers) half way and started again "
            "(what it did again, and whether its summary equals the uninterrupted run's); and the projection of "
            "50 recordings x 10,000 frames on 16 workers from the measured per-stage costs.",
            f"{PY} tools/bench_run.py --sequences 8 --frames 3000 --stages detect,lift,track,eval --kill-after 0.5",
            quick=f"{PY} tools/bench_run.py --sequences 2 --frames 150 --stages detect,lift,track,eval "
            "--kill-after 0.5",
            sizes=(("quick", "2 sequences x 150 frames with PV RGB, stages detect, lift, track, eval"),
                   ("full", "8 sequences x 3000 frames with PV RGB, stages detect, lift, track, eval")),
            modules=SET_TRACKING + FRONTEND + ("egograph/cli",), quick_min=16),
    Section("bench_run-device", "`egograph run` on Dask in the device world: 8 recordings, 2 workers against 1, and a kill",
            "The dataset run of the section above at a larger size, on device-world recordings (issue 38: "
            "photographic surfaces, the PV camera model, hands) with PV RGB: 8 sequences through detect, lift, track "
            "(memory, kf, graph) and eval with one local worker and with two (three rounds, as above), a 2-worker "
            "run killed half way and "
            "resumed, and the projection of 50 recordings x 10,000 frames on 16 workers from these per-stage costs. "
            "The sequences are generated 2 at a time before the timed runs.",
            f"{PY} tools/bench_run.py --config synth/device-svoe --sequences 8 --frames 1000 "
            "--stages detect,lift,track,eval --kill-after 0.5 --parallel 2 --workdir .cache/bench_run --json-tag device",
            quick=f"{PY} tools/bench_run.py --config synth/device-svoe --sequences 2 --frames 150 "
            "--stages detect,lift,track,eval --kill-after 0.5 --parallel 2 --workdir .cache/bench_run --json-tag device",
            sizes=(("quick", "2 device-world sequences x 150 frames with PV RGB, stages detect, lift, track, eval"),
                   ("full", "8 device-world sequences x 1000 frames with PV RGB, stages detect, lift, track, eval")),
            modules=SET_TRACKING + FRONTEND + ("egograph/cli",), quick_min=16),
    Section("bench_synth", "Synthetic generator and reader speed",
            "Frames per CPU-second of the generator (one process, Mesa's rasteriser on one thread) without RGB and "
            "with RGB (OpenGL rasteriser and the ray-cast reference renderer), in the legacy world and the device "
            "world (issue 38: photographic surfaces, the PV camera model, hands) in the same run, the PV colour "
            "stage alone, and reading poses + depth; then the device world with RGB in 2 processes at once (one "
            "recording each, as a benchmark set of several recordings can be made): the wall frames/s on the "
            "machine's 2 cores, which other work may share (the load average is in the record).",
            f"LP_NUM_THREADS=1 {PY} tools/bench_synth.py --frames 600 --rgb-frames 200 --parallel 2",
            quick=f"LP_NUM_THREADS=1 {PY} tools/bench_synth.py --frames 150 --rgb-frames 50 --parallel 2",
            sizes=(("quick", "150 frames depth only, 50 with RGB"), ("full", "600 frames depth only, 200 with RGB")),
            modules=BASE + SYNTH, quick_min=6),
    Section("bench_calib_fit", "The calibration that fits: cost and refinement",
            "On a 300-frame RGB recording no knob of the fit was chosen on (seed 6): the fit score of one "
            "calibration on 100 PV frames, `egograph info` scoring two candidate folders on a 3000-frame "
            "recording (the 300 frames tiled), and `egograph info --refine-calibration` recovering an injected "
            "2 deg / 3 cm / 40 ms AHAT-PV error (the residual against the truth); the full tier also lifts the "
            "true SVOE detections with the chosen, the true and a perturbed folder.",
            f"{PY} tools/bench_calib_fit.py --seed 6 --frames 100 --refine-frames 200",
            quick=f"{PY} tools/bench_calib_fit.py --seed 6 --frames 100 --refine-frames 200 --skip-lift",
            sizes=(("quick", "1 RGB recording x 300 frames (seed 6): fit, info, refinement"),
                   ("full", "1 RGB recording x 300 frames (seed 6): fit, info, refinement, lifting")),
            modules=BASE + SYNTH + LIFT + STEPS, quick_min=5),
    Section("bench_calib_fit-seed8", "The calibration that fits: a second held-out recording",
            "The same fit, info and refinement on a second 300-frame RGB recording no knob was chosen on "
            "(seed 8; the refinement's knobs were tuned on seeds 3, 5 and 7): the spread of the refinement's "
            "residual over held-out recordings; the full tier also lifts the true SVOE detections.",
            f"{PY} tools/bench_calib_fit.py --seed 8 --frames 100 --refine-frames 200 --json-tag seed8",
            quick=f"{PY} tools/bench_calib_fit.py --seed 8 --frames 100 --refine-frames 200 --skip-lift --json-tag seed8",
            sizes=(("quick", "1 RGB recording x 300 frames (seed 8): fit, info, refinement"),
                   ("full", "1 RGB recording x 300 frames (seed 8): fit, info, refinement, lifting")),
            modules=BASE + SYNTH + LIFT + STEPS, quick_min=5),
)


# --------------------------------------------------------------------------- staleness

DIGEST_SUFFIXES = (".py", ".yaml", ".yml", ".json", ".txt")


CONFIG_DIR = "egograph/configs"
DIGEST_SCHEME = 6
"""1: every file's bytes. 2: the same for code; a packaged YAML config counts by what the section's
code can read of it (:func:`config_view`): its parsed content, without comments or layout, and without
its ``frontend`` block when the section does not exercise ``egograph/frontend``. Under 1 a change of a
front-end default (``frontend.proposals``) marked every tracker section changed. 3: as 2, and a Python
file of egograph counts only when the section's tool can import it
(:func:`import_closure`). Under 2 a change of the verification in ``egograph/steps/detect.py`` marked
every section exercising ``egograph/steps`` changed, 29 of them, the tracker benchmarks on simulated
detections, which never import it, among them. 4: as 3, and a Python file counts by its syntax tree
without docstrings (:func:`code_view`, the normalised form egograph.core.provenance keys caches
by): a docstring, comment or layout edit runs nothing, a changed statement or knob text does. Under
3 correcting a docstring of ``egograph/steps/detect.py`` marked 9 sections changed. 5: as 4, and every
string standing alone as a statement is dropped too, not only a module's, class's or function's first:
the attribute docstrings under a constant or a dataclass field (``ANSWER_KINDS``), which Python
discards as it does comments. Under 4 correcting the count in ``ANSWER_KINDS``'s docstring marked the
24 tracking sections changed. 6: as 5, and a packaged front-end configuration (``frontend-*.yaml``: an
operating point of ``egograph detect`` and of the trackers on its detections) counts only for sections
that exercise ``egograph/frontend``: only front-end sections name such a file (``--config frontend-mvpe``).
Under 5 choosing ``frontend-svoe``'s operating point again (its ``graph`` and ``track`` score thresholds)
marked every tracking section on simulated detections changed."""


@functools.lru_cache(maxsize=None)
def code_view(data: bytes, scheme: int = DIGEST_SCHEME) -> bytes:
    """A Python file as the digest counts it (scheme 4 and later): its syntax tree, docstrings removed
    (``ast.dump``: no comments, no layout); from scheme 5 also every string standing alone as a
    statement (:func:`_strip_bare_strings`); the bytes when it does not parse. Cached by content: a
    page render digests every section, twice, over the same files."""
    from egograph.core.provenance import _strip_docstrings

    try:
        tree = _strip_docstrings(ast.parse(data))
    except (SyntaxError, ValueError):
        return data
    return ast.dump(_strip_bare_strings(tree) if scheme >= 5 else tree).encode()


def _strip_bare_strings(tree: ast.AST) -> ast.AST:
    """``tree`` without any statement that is a string constant alone (an attribute docstring: Python
    evaluates it to nothing); a body left empty gets ``pass``."""
    for node in ast.walk(tree):
        for field in ("body", "orelse", "finalbody"):
            body = getattr(node, field, None)
            if isinstance(body, list) and body and isinstance(body[0], ast.stmt):
                kept = [b for b in body if not (isinstance(b, ast.Expr) and isinstance(b.value, ast.Constant)
                                                and isinstance(b.value.value, str))]
                if len(kept) != len(body):
                    setattr(node, field, kept or ([ast.Pass()] if field == "body" else []))
    return tree

# a module named in a string: a subprocess the tool starts (``-m egograph.cli.main``, ``-c "from
# egograph.cli.main import main; ..."``) runs code the tool's own imports do not reach
MODULE_IN_STRING = re.compile(r"\begograph(?:\.[A-Za-z_]\w*)+")


def _module_file(name: str, read) -> str | None:
    """The file of module ``name`` (``egograph.x.y``, or a sibling tool ``benchset``) that ``read``
    (relative path -> bytes | None) finds: the package's ``__init__.py`` or the module's ``.py``."""
    parts = name.split(".")
    base = "/".join(parts) if parts[0] == "egograph" else "tools/" + "/".join(parts)
    for rel in (base + "/__init__.py", base + ".py"):
        if read(rel) is not None:
            return rel
    return None


@functools.lru_cache(maxsize=None)
def _imported_names(rel: str, data: bytes) -> frozenset[str]:
    """Every module file ``rel`` may import: each import statement, those inside functions included,
    relative ones resolved (egograph.core.provenance's reading, as for the cache keys); and, in a
    tool, the module names in its strings other than docstrings (the subprocesses it starts;
    egograph itself starts none, and its docstrings and messages name modules they do not import).
    Cached by path and content, as :func:`code_view`."""
    from egograph.core.provenance import _imports, _strip_docstrings

    try:
        tree = ast.parse(data.decode())
    except (SyntaxError, UnicodeDecodeError, ValueError):
        return frozenset()
    is_package = rel.endswith("/__init__.py")
    module = ".".join(Path(rel[:-len("/__init__.py")] if is_package else rel[:-len(".py")]).parts)
    out = _imports(tree, module, is_package)
    if rel.startswith("tools/"):
        out.update(m for n in ast.walk(_strip_docstrings(tree)) if isinstance(n, ast.Constant)
                   and isinstance(n.value, str) for m in MODULE_IN_STRING.findall(n.value))
    return frozenset(out)


def import_closure(roots: list[str], read) -> set[str]:
    """The files (relative paths) the Python files ``roots`` can import, transitively, through
    egograph and the sibling tools (:func:`_imported_names`; importing ``a.b.c`` runs ``a`` and
    ``a.b`` too), read by ``read`` (relative path -> bytes | None). Static: a module imported by a
    name computed at run time is not followed (egograph does so only for optional third-party
    packages, egograph.core.resources.require)."""
    seen: set[str] = set()
    files: dict[str, str | None] = {}   # module name -> its file: most modules are imported from many files
    todo = [r for r in roots if read(r) is not None]
    while todo:
        rel = todo.pop()
        if rel in seen:
            continue
        seen.add(rel)
        for name in _imported_names(rel, read(rel)):
            parts = name.split(".")
            for k in range(1, len(parts) + 1):
                module = ".".join(parts[:k])
                if module not in files:
                    files[module] = _module_file(module, read)
                f = files[module]
                if f is not None and f not in seen:
                    todo.append(f)
    return seen


def exercises(paths: tuple[str, ...] | list[str], package: str) -> bool:
    """Whether ``paths`` cover ``package`` (a folder from the repository root)."""
    return any(p == package or p.startswith(package + "/") or package.startswith(p + "/") for p in paths)


def is_frontend_config(name: str) -> bool:
    """Whether ``name`` (relative to the repository) is a packaged front-end configuration
    (``egograph/configs/frontend-*.yaml``), counted by :data:`DIGEST_SCHEME` 6 only for front-end sections."""
    p = Path(name)
    return p.parent.as_posix() == CONFIG_DIR and p.name.startswith("frontend-") and p.suffix in (".yaml", ".yml")


def config_view(data: bytes, paths: tuple[str, ...] | list[str]) -> bytes:
    """The part of a packaged YAML config that code under ``paths`` can read, canonical (sorted JSON):
    a section that does not exercise ``egograph/frontend`` reads no ``frontend`` block."""
    return _config_view(data, exercises(paths, "egograph/frontend"))


@functools.lru_cache(maxsize=None)
def _config_view(data: bytes, with_frontend: bool) -> bytes:
    """:func:`config_view`, cached by content as :func:`code_view`."""
    import yaml

    doc = yaml.safe_load(data.decode())
    if isinstance(doc, dict) and not with_frontend:
        doc = {k: v for k, v in doc.items() if k != "frontend"}
    return json.dumps(doc, sort_keys=True, default=str).encode()


def _tree_files(rel: str, repo: Path, commit: str | None, read) -> dict[str, bytes] | None:
    """The digest's files under ``rel`` (path -> bytes) in the working tree, or at ``commit`` (git);
    None when ``rel`` does not exist. ``read``: the working tree's reader (:func:`_reader`), shared
    with the import closure so a digest reads each file once."""
    if commit is None:
        p = repo / rel
        if p.is_dir():
            files = sorted(f for f in p.rglob("*") if f.is_file() and f.suffix in DIGEST_SUFFIXES
                           and "__pycache__" not in f.parts)
        else:
            files = [p] if p.is_file() else []
        return {name: read(name) for name in (f.relative_to(repo).as_posix() for f in files)} or None
    return _commit_files(str(repo), commit, rel)


@functools.lru_cache(maxsize=None)
def _commit_files(repo: str, commit: str, rel: str) -> dict[str, bytes] | None:
    """:func:`_tree_files` at ``commit``, read once: a commit's files never change, and both digest
    schemes of every record made at one commit read the same ones (:func:`upgrade_digest`); each
    file through :func:`_commit_file`, which the import closure reads too."""
    names = subprocess.run(["git", "-C", repo, "ls-tree", "-r", "--name-only", commit, "--", rel],
                           capture_output=True, text=True, check=True).stdout.split()
    names = sorted(n for n in names if Path(n).suffix in DIGEST_SUFFIXES and "__pycache__" not in Path(n).parts)
    return {n: _commit_file(repo, commit, n) for n in names} or None


def _reader(repo: Path, commit: str | None):
    """relative path -> bytes | None, of the working tree or of ``commit``. The working tree's files
    are read once per reader (one digest): the import closure asks for each file many times, once per
    import of it and of its parents (566,000 reads and 11 s a page render before)."""
    if commit is None:
        @functools.lru_cache(maxsize=None)
        def read(rel: str) -> bytes | None:
            p = repo / rel
            return p.read_bytes() if p.is_file() else None
        return read
    return functools.partial(_commit_file, str(repo), commit)


@functools.lru_cache(maxsize=None)
def _commit_file(repo: str, commit: str, rel: str) -> bytes | None:
    """One file at ``commit`` (None when it has none), read once."""
    proc = subprocess.run(["git", "-C", repo, "show", f"{commit}:{rel}"], capture_output=True)
    if proc.returncode == 0:
        return proc.stdout
    if subprocess.run(["git", "-C", repo, "cat-file", "-e", commit], capture_output=True).returncode:
        raise subprocess.CalledProcessError(proc.returncode, proc.args, proc.stdout, proc.stderr)
    return None


def modules_digest(paths: tuple[str, ...] | list[str], repo: Path = REPO, *, scheme: int = DIGEST_SCHEME,
                   commit: str | None = None) -> str:
    """sha256 (16 hex digits) of the files under ``paths`` (folders or files, relative to ``repo``):
    each file's relative path and content, in sorted order (content and which files count: see
    :data:`DIGEST_SCHEME`; under 3 the import closure starts from the tools in ``paths``); a path that
    does not exist counts as such. The working tree's files, or those of ``commit``. The same code
    gives the same digest in every clone."""
    h = hashlib.sha256()
    closure = None
    read = _reader(repo, commit)
    if scheme >= 3:
        closure = import_closure([p for p in paths if p.startswith("tools/") and p.endswith(".py")], read)
    for rel in paths:
        files = _tree_files(rel, repo, commit, read)
        if not files:
            h.update(f"missing {rel}\0".encode())
            continue
        for name, data in files.items():
            if closure is not None and name.startswith("egograph/") and name.endswith(".py") and name not in closure:
                continue   # egograph code the section cannot import
            if scheme >= 6 and is_frontend_config(name) and not exercises(paths, "egograph/frontend"):
                continue   # a front-end operating point, read only by runs that detect
            if scheme >= 2 and name.startswith(CONFIG_DIR + "/") and Path(name).suffix in (".yaml", ".yml"):
                data = config_view(data, paths)
            elif scheme >= 4 and name.endswith(".py"):
                data = code_view(data, scheme)
            h.update(name.encode() + b"\0" + data + b"\0")
    return h.hexdigest()[:16]


def upgrade_digest(doc: dict, repo: Path = REPO) -> bool:
    """Rewrite a record's module digest in the current scheme (:data:`DIGEST_SCHEME`), when its
    commit's files give the digest it keeps in its own scheme (so that commit is the code it was made
    on): True when rewritten. A record whose digest its commit does not reproduce (made on
    uncommitted code) keeps it, and counts as changed."""
    reg = regeneration_of(doc)
    commit = (doc.get("egograph") or {}).get("commit")
    old = reg.get("digest_scheme", 1)
    if not reg.get("modules_digest") or old >= DIGEST_SCHEME or not commit:
        return False
    paths = reg.get("modules") or []
    try:
        if modules_digest(paths, repo, scheme=old, commit=commit) != reg["modules_digest"]:
            return False
        reg["modules_digest"] = modules_digest(paths, repo, commit=commit)
    except subprocess.CalledProcessError:   # the commit is not in this clone
        return False
    reg["digest_scheme"] = DIGEST_SCHEME
    return True


def regeneration_of(doc: dict) -> dict:
    """The record's regeneration block (tier, sizes, modules and their digest), {} for a record made by
    running a tool by hand."""
    reg = doc.get("regeneration")
    return reg if isinstance(reg, dict) else {}


def modules_changed(section: Section, doc: dict, repo: Path = REPO) -> bool | None:
    """Whether the code ``section`` exercises changed since ``doc`` was made (None: the record keeps no
    digest)."""
    reg = regeneration_of(doc)
    if not reg.get("modules_digest"):
        return None
    return reg["modules_digest"] != modules_digest(section.paths(), repo, scheme=reg.get("digest_scheme", 1))


def is_current(section: Section, doc: dict | None, tier: str, repo: Path = REPO) -> bool:
    """A record that a regeneration of ``tier`` keeps: made by a regeneration of this tier or a larger
    one, on the same code of every module the section exercises."""
    if doc is None:
        return False
    reg = regeneration_of(doc)
    if reg.get("tier") not in TIERS or TIERS.index(reg["tier"]) < TIERS.index(tier):
        return False
    return modules_changed(section, doc, repo) is False


def stamp(path: Path, section: Section, tier: str, command: str) -> dict:
    """Add the regeneration block to the record a section's benchmark just wrote."""
    from egograph.io.atomic import atomic_write_text

    doc = json.loads(path.read_text())
    doc["regeneration"] = {"tier": tier, "sizes": section.size(tier), "section_command": command,
                           "modules": list(section.paths()), "modules_digest": modules_digest(section.paths()),
                           "digest_scheme": DIGEST_SCHEME}
    atomic_write_text(path, benchdoc.dumps(doc) + "\n")
    return doc


# --------------------------------------------------------------------------- regeneration


def merged_invocations(on_disk: dict | None, known: list[dict], inv: dict) -> list[dict]:
    """The invocations to save: those this process knows, with ``inv`` as it is now, and every other
    invocation as the disk has it: another regeneration of the same tier, running at the same time,
    saves its own invocation, so its copy on disk is newer than any this process read earlier (an
    invocation is known by its ``id``; one saved before ids, by its start and arguments), in the
    order they started. Without the merge the one that saves last would drop the other's sections;
    with this process's older copy preferred (before stop 71) a long regeneration saving after a short
    one had finished wrote back the short one's sections as they were at its start: empty."""
    key = lambda i: i.get("id") or (i.get("started"), tuple(i.get("argv") or ()))  # noqa: E731
    out = {key(i): i for i in known}
    if on_disk and on_disk.get("format") == REGEN_FORMAT and on_disk.get("tier") is not None:
        for i in on_disk.get("invocations") or []:
            out[key(i)] = i
    out[key(inv)] = inv
    return sorted(out.values(), key=lambda i: i.get("started") or "")


def run_command(command: str, cwd: str, env: dict, log: str) -> tuple[int, float, float]:
    """Run one section's shell command (its output to ``log``) -> exit code, wall s, CPU s of the
    children. Module level so that a Dask worker can run it."""
    Path(log).parent.mkdir(parents=True, exist_ok=True)
    t0, c0 = time.perf_counter(), os.times()
    with open(log, "w") as fh:
        fh.write(f"$ {command}\n")
        fh.flush()
        rc = subprocess.run(["bash", "-c", command], cwd=cwd, env=env, stdout=fh, stderr=subprocess.STDOUT).returncode
    c1 = os.times()
    cpu = (c1.children_user - c0.children_user) + (c1.children_system - c0.children_system)
    return rc, time.perf_counter() - t0, cpu


def named(only: list[str] | None, sections: tuple[Section, ...] = SECTIONS) -> set[str]:
    """The stems of the sections named by ``--only`` (stems or headings; every section without). An
    unknown name is an error listing the known ones."""
    stems = [s.stem for s in sections]
    if not only:
        return set(stems)
    heads = {s.heading: s.stem for s in sections}
    bad = [n for n in only if n not in stems and n not in heads]
    if bad:
        raise SystemExit(f"--only: unknown section {', '.join(bad)}; the sections: {', '.join(stems)}")
    return {heads.get(n, n) for n in only}


def select(only: list[str] | None, sections: tuple[Section, ...] = SECTIONS) -> list[Section]:
    """The sections :func:`named` by ``--only`` and the sections they read (``after``), cheap first,
    each after the sections it reads."""
    names = named(only, sections)
    chosen = [s for s in sections if s.stem in names]
    every = {s.stem: s for s in sections}
    reads = [a for s in chosen for a in s.after]
    while reads:   # and every section they read (a regeneration keeps those that are current)
        a = every[reads.pop()]
        if a not in chosen:
            chosen.append(a)
            reads.extend(a.after)

    def rank(s: Section) -> tuple[float, int]:   # after every section it reads, however cheap it is
        return max([(s.quick_min, 0)] + [(rank(every[a])[0], rank(every[a])[1] + 1) for a in s.after])

    return sorted(chosen, key=rank)


def _regen_path(bench_dir: Path, tier: str) -> Path:
    return bench_dir / REGEN_DIR_NAME / f"{tier}.json"


def load_regenerations(bench_dir: Path) -> dict[str, dict]:
    """The regeneration logs (tier -> log) under ``bench_dir/regeneration``."""
    out = {}
    for tier in TIERS:
        p = _regen_path(bench_dir, tier)
        if p.is_file():
            out[tier] = json.loads(p.read_text())
    return out


def last_wall_s(bench_dir: Path, tier: str) -> dict[str, float]:
    """Each section's wall time in its last successful run of ``tier`` (the regeneration log), s."""
    regen = load_regenerations(bench_dir).get(tier, {})
    out: dict[str, float] = {}
    for inv in regen.get("invocations", []):
        for stem, run in inv.get("sections", {}).items():
            if run.get("status") == "ok" and run.get("wall_s") is not None:
                out[stem] = float(run["wall_s"])
    return out


def longest_first(todo: list[Section], measured: dict[str, float]) -> list[Section]:
    """``todo`` with the longest sections first (their last measured wall time, else ``quick_min``
    minutes): with several slots the longest job no longer starts last and sets the end. A section
    still starts only after those it reads (the scheduler waits for them)."""
    return sorted(todo, key=lambda s: -measured.get(s.stem, s.quick_min * 60.0))


def regenerate(tier: str, only: list[str] | None, workers: int, scheduler: str | None, bench_dir: Path,
               out: Path, force: bool = False, sections: tuple[Section, ...] = SECTIONS,
               longest: bool = False) -> int:
    """Run every chosen section's benchmark for ``tier`` (cheap first; sections whose record is current
    for the tier and the code are skipped, so a killed regeneration resumes), stamp each record with
    its tier and module digest, log the run in ``docs/bench/regeneration/<tier>.json`` and re-render the
    page after each section. With ``scheduler`` every section runs as a task on that Dask cluster (the
    repository at the same path on every worker), as many at once as it has worker threads; else
    ``workers`` at once on this machine. ``longest``: the longest sections first (:func:`longest_first`).
    ``only``: these sections and those they read (:func:`select`; the latter run only when not current or
    their outputs are missing); ``force``: the sections of ``only`` (every section without) run even
    when current. A section refused by an output lock another section held (two sections generating one
    benchmark recording at once) runs once more, after every section running then has finished. Exit 0
    when every chosen section has a current record."""
    from egograph.io.atomic import atomic_write_text

    chosen = select(only, sections)
    forced = named(only, sections) if force else set()
    docs = load(bench_dir)
    todo = []
    for s in chosen:
        missing = s.missing_outputs(tier)
        if s.stem in forced or not is_current(s, docs.get(s.stem), tier):
            todo.append(s)
        elif missing:   # (a fresh checkout: the record came with the repository, its outputs did not)
            print(f"[{s.stem}] current, but {', '.join(missing)}, which a later section reads, is missing: "
                  f"run again", flush=True)
            todo.append(s)
    if longest:   # a time measured with another command (other sizes) says nothing of this one
        measured = {s.stem: t for s in todo if (t := last_wall_s(bench_dir, tier).get(s.stem)) is not None
                    and docs.get(s.stem, {}).get("regeneration", {}).get("section_command") == s.command_for(tier)}
        todo = longest_first(todo, measured)
    for s in chosen:
        if s not in todo:
            print(f"[{s.stem}] current for the {tier} tier and the code: kept", flush=True)
    client = None
    if scheduler:
        from distributed import Client

        client = Client(scheduler, timeout="30s")
        slots = max(1, sum(client.nthreads().values()))
    else:
        slots = max(1, workers)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH")) if p)}
    regen_file = _regen_path(bench_dir, tier)
    log = json.loads(regen_file.read_text()) if regen_file.is_file() else None
    if log is None or log.get("complete"):   # a new regeneration; else this invocation resumes the last one
        log = {"format": REGEN_FORMAT, "tier": tier, "complete": False, "invocations": []}
    inv = {"id": f"{os.getpid()}-{time.time_ns()}",
           "started": _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat(),
           "argv": sys.argv[1:], "commit": benchdoc.revision().get("commit"), "slots": slots,
           "scheduler": bool(scheduler), "load_average": {"start": [round(x, 2) for x in os.getloadavg()]},
           "sections": {}}
    log["invocations"].append(inv)
    lock = threading.Lock()
    t_start = time.perf_counter()

    def save() -> None:
        inv["wall_s"] = round(time.perf_counter() - t_start, 1)
        inv["load_average"]["end"] = [round(x, 2) for x in os.getloadavg()]
        regen_file.parent.mkdir(parents=True, exist_ok=True)
        on_disk = json.loads(regen_file.read_text()) if regen_file.is_file() else None
        log["invocations"] = merged_invocations(on_disk, log["invocations"], inv)
        atomic_write_text(regen_file, benchdoc.dumps(log) + "\n")

    def one(s: Section, attempt: int = 1) -> tuple[Section, int]:
        command = s.command_for(tier)
        path = bench_dir / f"{s.stem}.json"
        before = path.stat().st_mtime_ns if path.is_file() else None
        logfile = str(section_log(s.stem))
        print(f"[{s.stem}] {command}  (log {logfile})", flush=True)
        if client is not None:
            rc, wall, cpu = client.submit(run_command, command, str(REPO), env, logfile, pure=False).result()
        else:
            rc, wall, cpu = run_command(command, str(REPO), env, logfile)
        written = path.is_file() and path.stat().st_mtime_ns != before
        if rc == 0 and not written:
            rc = -1
            print(f"[{s.stem}] exited 0 but wrote no {path}", flush=True)
        with lock:
            if rc == 0:
                stamp(path, s, tier, command)
                if tier == "full" and s.stem in README_RECORDS and bench_dir.resolve() == BENCH_DIR.resolve():
                    from egograph.io.atomic import atomic_write_text

                    (bench_dir / README_DIR_NAME).mkdir(exist_ok=True)
                    atomic_write_text(bench_dir / README_DIR_NAME / path.name, path.read_text())
            inv["sections"][s.stem] = {"status": "ok" if rc == 0 else "failed", "exit": rc,
                                       "wall_s": round(wall, 1), "cpu_s": round(cpu, 1)}
            if attempt > 1:
                inv["sections"][s.stem]["attempt"] = attempt
            save()
            render_files(bench_dir, out, sections)
        print(f"[{s.stem}] {'done' if rc == 0 else f'FAILED (exit {rc}; see {logfile})'} in {wall / 60:.1f} min",
              flush=True)
        return s, rc

    save()
    pending, failed, running = list(todo), set(), {}
    # a section that lost a race for an output lock (two sections generating one benchmark recording):
    # run once more, after every section running when it failed has finished (the holder among them)
    retry_after: dict[str, set[str]] = {}
    try:
        with ThreadPoolExecutor(slots) as pool:
            while pending or running:
                busy = {s.stem for s in running.values()} | {s.stem for s in pending}
                for s in list(pending):
                    if len(running) >= slots:
                        break
                    if retry_after.get(s.stem, set()) & {r.stem for r in running.values()}:
                        continue
                    if any(d in failed for d in s.after):
                        pending.remove(s)
                        failed.add(s.stem)
                        inv["sections"][s.stem] = {"status": "skipped", "exit": None, "wall_s": 0.0,
                                                   "cpu_s": None, "reason": "needs " + ", ".join(s.after)}
                        print(f"[{s.stem}] skipped: it reads {', '.join(s.after)}, which failed", flush=True)
                    elif not any(d in busy for d in s.after):
                        pending.remove(s)
                        running[pool.submit(one, s, 2 if s.stem in retry_after else 1)] = s
                if not running:
                    continue
                finished, _ = wait(list(running), timeout=60, return_when=FIRST_COMPLETED)
                with lock:   # the wall time so far, should this invocation be killed
                    save()
                for f in finished:
                    s, rc = f.result()
                    del running[f]
                    if rc != 0 and s.stem not in retry_after and lost_output_lock(section_log(s.stem)):
                        retry_after[s.stem] = {r.stem for r in running.values()}
                        pending.insert(0, s)
                        print(f"[{s.stem}] another section held an output it writes: it runs again after "
                              f"{', '.join(sorted(retry_after[s.stem])) or 'nothing else'}", flush=True)
                    elif rc != 0:
                        failed.add(s.stem)
    finally:
        if client is not None:
            client.close()
    docs = load(bench_dir)
    log["complete"] = only is None and all(is_current(s, docs.get(s.stem), tier) for s in sections)
    save()
    render_files(bench_dir, out, sections)
    print(f"regeneration ({tier} tier): {len(todo) - len(failed)} of {len(todo)} sections run, "
          f"{len(chosen) - len(todo)} kept, {len(failed)} failed; {inv['wall_s'] / 60:.1f} min", flush=True)
    return 1 if failed else 0


LOCK_MESSAGE = "another egograph run is writing this output"   # egograph.io.atomic's refusal


def lost_output_lock(log: Path) -> bool:
    """Whether a section's log ends in egograph's refusal to write an output another process holds
    (egograph.io.atomic), as when two sections generate one benchmark recording at once."""
    try:
        tail = log.read_bytes()[-4096:].decode("utf-8", "replace")
    except OSError:
        return False
    return LOCK_MESSAGE in tail


# --------------------------------------------------------------------------- rendering


def upgrade_digests(bench_dir: Path, repo: Path = REPO) -> tuple[int, int]:
    """:func:`upgrade_digest` on every record of ``bench_dir`` and its README copies, each rewritten
    atomically; prints and returns (rewritten, left as they were)."""
    from egograph.io.atomic import atomic_write_text

    done = kept = 0
    for p in sorted([*bench_dir.glob("*.json"), *(bench_dir / README_DIR_NAME).glob("*.json")]):
        doc = json.loads(p.read_text())
        if doc.get("format") == benchdoc.FORMAT and upgrade_digest(doc, repo):
            atomic_write_text(p, benchdoc.dumps(doc) + "\n")
            done += 1
        else:
            kept += 1
    print(f"module digests: {done} records rewritten to scheme {DIGEST_SCHEME}, {kept} left as they were")
    return done, kept


def load(bench_dir: Path) -> dict[str, dict]:
    """Every ``*.json`` in ``bench_dir`` by stem; a file that is not a benchmark record is an error
    naming it."""
    docs = {}
    for p in sorted(bench_dir.glob("*.json")):
        try:
            d = json.loads(p.read_text())
        except (OSError, ValueError) as e:
            raise SystemExit(f"{p}: not readable as JSON ({e})")
        if not isinstance(d, dict) or d.get("format") != benchdoc.FORMAT:
            raise SystemExit(f"{p}: not a benchmark record (format {benchdoc.FORMAT!r} expected)")
        docs[p.stem] = d
    return docs


def _duration(seconds: float | None) -> str:
    if seconds is None:
        return "n/a"
    s = int(round(seconds))
    if s < 60:
        return f"{seconds:.1f} s"
    h, rest = divmod(s, 3600)
    m, s = divmod(rest, 60)
    return f"{h} h {m} min" if h else f"{m} min {s} s"


def typed_command(doc: dict) -> str:
    """The command as typed from the repository root, with the environment and CPU binding it ran under."""
    prefix = [f"{k}={v}" for k, v in sorted(doc.get("environment", {}).items()) if k != "EGOGRAPH_CACHE"]
    m = doc.get("machine", {})
    aff, n = m.get("cpu_affinity"), m.get("nproc")
    if aff and n and len(aff) < n:
        prefix += ["taskset", "-c", ",".join(map(str, aff))]
    return " ".join([*prefix, PY, doc["command"]])


CONSTRAINTS = REPO / "tools" / "constraints.txt"


def _canonical(name: str) -> str:
    return name.lower().replace("_", "-").replace(".", "-")


def pinned_versions(path: Path = CONSTRAINTS) -> dict[str, str]:
    """``{distribution (canonical name): version}`` pinned in tools/constraints.txt (``name==version`` lines)."""
    out = {}
    if path.is_file():
        for line in path.read_text().splitlines():
            name, sep, version = line.split("#", 1)[0].strip().partition("==")
            if sep:
                out[_canonical(name)] = version.strip()
    return out


def packages_line(doc: dict, pins: dict[str, str]) -> str:
    """Whether a record was made with the pinned package versions, and which differ."""
    have = doc.get("packages")
    if not have:
        return "- packages: not recorded (a record made before records kept their package versions)"
    python = have.get("python")
    diff = [f"{name} {v} (pinned {pins[_canonical(name)]})" for name, v in sorted(have.items())
            if name != "python" and _canonical(name) in pins and pins[_canonical(name)] != v]
    where = "as pinned in `tools/constraints.txt`" if not diff else \
        "other versions than `tools/constraints.txt` pins: " + ", ".join(diff)
    return f"- packages: Python {python}, {where}"


def provenance(doc: dict, pins: dict[str, str] | None = None) -> list[str]:
    """Where a record came from: command, revision, package versions, machine, date, wall time."""
    rev, m = doc.get("egograph", {}), doc.get("machine", {})
    commit = rev.get("commit")
    revision = f"egograph {rev.get('version')}, commit `{commit[:10]}`" if commit else \
        f"egograph {rev.get('version')}, not a git checkout"
    if rev.get("dirty"):
        revision += " with uncommitted changes"
    load = m.get("load_average") or {}
    start, end = (load.get("start") or [None])[0], (load.get("end") or [None])[0]
    cpus = f"{m.get('nproc')} CPUs"
    if m.get("cpu_affinity") and m.get("nproc") and len(m["cpu_affinity"]) < m["nproc"]:
        cpus += f" (run on {len(m['cpu_affinity'])})"
    machine = f"{cpus}, {m.get('cpu') or 'CPU model unknown'}, {m.get('memory_gb')} GB; load average {start} " \
              f"at the start, {end} at the end"
    return [f"- command: `{typed_command(doc)}`",
            f"- revision: {revision}",
            packages_line(doc, pinned_versions() if pins is None else pins),
            f"- machine: {machine}",
            f"- run: {doc.get('started')}, wall time {_duration(doc.get('wall_s'))}"]


def render_record(doc: dict) -> list[str]:
    """The provenance list and every recorded item of one JSON record."""
    out = provenance(doc)
    for item in doc.get("items", []):
        out += ["", *benchdoc.item_lines(item, heading="####")]
    return out


def tier_line(section: Section, doc: dict, repo: Path = REPO) -> str:
    """The section's tier, sizes, commit and whether the code it exercises changed since."""
    reg = regeneration_of(doc)
    commit = (doc.get("egograph") or {}).get("commit")
    at = f"`{commit[:10]}`" if commit else "no commit"
    if not reg:
        return (f"- tier: none (run by hand, not by `tools/bench_report.py --regenerate`), at {at}; whether its code "
                "changed since is not known (the record keeps no module digest)")
    changed = modules_changed(section, doc, repo)
    mods = ", ".join(f"`{m}`" for m in section.paths())
    state = ("**changed since**: re-run `tools/bench_report.py --regenerate --only " + section.stem + "`"
             if changed else "unchanged since")
    sizes = reg.get("sizes") or "sizes not stated"
    return f"- tier: {reg.get('tier')} ({sizes}), at {at}; code exercised ({mods}): {state}"


def regeneration_header(regens: dict[str, dict], n_sections: int = len(SECTIONS),
                        current: dict[str, bool] | None = None) -> list[str]:
    """One paragraph per tier's last regeneration: its wall time on this machine, invocations (a killed
    one resumed), sections run and failed, the last invocation's own sections and wall time, load; and
    the last invocation that ran all ``n_sections`` sections at once (the tier's own wall time, which a
    log resumed over days does not measure). ``current``: per tier, whether every section has a record
    current for it (else the log's own ``complete`` says, which a later ``--only`` run leaves false)."""
    out = []
    for tier, log in regens.items():
        invs = log.get("invocations") or []
        if not invs:
            continue
        wall = sum(i.get("wall_s") or 0 for i in invs)
        ran = {k: v for i in invs for k, v in (i.get("sections") or {}).items()}
        ok = sum(v["status"] == "ok" for v in ran.values())
        bad = sorted(k for k, v in ran.items() if v["status"] != "ok")
        loads = [x for i in invs for x in ((i.get("load_average") or {}).get("start", [None])[0],
                                           (i.get("load_average") or {}).get("end", [None])[0]) if x is not None]
        slots = sorted({i.get("slots") for i in invs})
        text = (f"**Last {tier}-tier regeneration** (`tools/bench_report.py --regenerate --tier {tier}`, started "
                f"{invs[0].get('started')}, at `{str(invs[-1].get('commit'))[:10]}`): wall time "
                f"{_duration(wall)} on this machine in {len(invs)} invocation{'s' if len(invs) > 1 else ''}"
                f"{' (killed or stopped, then resumed)' if len(invs) > 1 else ''}, "
                f"{' / '.join(map(str, slots))} section{'s' if slots != [1] else ''} at a time; {ok} sections run")
        if bad:
            text += f", {len(bad)} failed ({', '.join(bad)})"
        if len(invs) > 1:   # a resumed log sums days of invocations; the last one alone is a measurement
            last = invs[-1]
            n_last = len(last.get("sections") or {})
            text += (f"; the last invocation ran {n_last} section{'s' if n_last != 1 else ''} in "
                     f"{_duration(last.get('wall_s') or 0)}, {last.get('slots')} at a time")
        if loads:
            text += f"; load average {min(loads):.1f}-{max(loads):.1f} (2 CPUs shared with other work)"
        done = log.get("complete") if current is None or tier not in current else current[tier]
        text += "." if done else "; not complete: the sections without a current record are below."
        whole = [i for i in invs if len(i.get("sections") or {}) >= n_sections
                 and all(v.get("status") == "ok" for v in i["sections"].values())]
        if whole:
            w = whole[-1]
            load = (w.get("load_average") or {}).get("start", [None])[0]
            text += (f" Every section of the tier in one invocation, last: {_duration(w.get('wall_s') or 0)}, "
                     f"{w.get('slots')} at a time, started {w.get('started')} at `{str(w.get('commit'))[:10]}`"
                     + (f", load average {load:.1f} at the start" if load is not None else "") + ".")
        out += [text, ""]
    return out


def render(docs: dict[str, dict], sections: tuple[Section, ...] = SECTIONS, regens: dict[str, dict] | None = None,
           repo: Path = REPO) -> str:
    """docs/benchmarks.md from the records ``docs`` (stem -> JSON) and the regeneration logs ``regens``;
    whether a section's code changed since its record is read from the checkout ``repo``."""
    known = {s.stem for s in sections}
    missing = [s for s in sections if s.stem not in docs]
    out = ["# Benchmarks", "",
           "<!-- Generated by tools/bench_report.py from docs/bench/*.json: do not edit; "
           "tests/test_bench_report.py checks it. -->", "",
           "Every figure on this page was written by the benchmark that measured it: each `tools/bench_*.py` "
           "prints its tables and writes them, with its command line, revision, machine and wall time, to "
           "`docs/bench/<tool>[-<tag>].json` (`--json PATH` elsewhere, `--json -` not at all); "
           "`.venv/bin/python tools/bench_report.py` renders this page from those files and `--check` "
           "says whether it is current. The synthetic recordings are generated into `.cache/` on first use, one "
           "after another; `tools/benchset.py --seeds ... --frames N [--rgb] --jobs 2` builds a set two at a time "
           "first.", "",
           "`.venv/bin/python tools/bench_report.py --regenerate [--tier quick|full] [--only SECTION ...] "
           "[--scheduler ADDR | --workers N]` runs every section's benchmark, cheap sections first, and re-renders "
           "this page after each: the quick tier on fewer or shorter recordings of the same held-out seeds (its "
           "sizes are stated in each section), the full tier at the sizes below, each section a task on the Dask "
           "cluster at ADDR when one is given. A section whose record is current for the tier and the code (the "
           "digest of the modules it exercises, kept in the record: of egograph's code only the modules its tool can "
           "import, found by reading their import statements, each by its syntax tree without docstrings or other "
           "strings standing alone, so a docstring, comment or layout edit changes nothing; a packaged YAML config by the settings the "
           "section can read: its front-end block only where the front-end is exercised) is not run again, so a killed regeneration "
           "resumes where it stopped. A section that reads another's outputs (the refined poses of "
           "`bench_refine-f3000-mesh`) runs after it; `--only` that section runs the other first when its record is "
           "not current or its outputs are missing (a fresh checkout has the records, not `.cache/`). Each section "
           "states its tier, the commit its record was made at and whether that code changed since.", ""]
    current = {tier: all(is_current(s, docs.get(s.stem), tier, repo) for s in sections) for tier in (regens or {})}
    out += regeneration_header(regens or {}, len(sections), current)
    out += ["The full tier's commands, from the repository root (`tools/bench_report.py --commands` prints them "
            "as a script, `--missing` only the sections not recorded yet; `--commands --tier quick` the quick "
            "tier's):", "", "```bash"]
    out += [s.command for s in sections]
    out += ["```", ""]
    out += [f"Recorded: {len(sections) - len(missing)} of {len(sections)} sections.", "",
            "| section | tier | recorded | code exercised since |", "|---|---|---|---|"]
    for s in sections:
        d = docs.get(s.stem)
        tier, when, since = "-", "not yet regenerated", "-"
        if d is not None:
            commit = (d.get("egograph") or {}).get("commit")
            when = f"{str(d.get('started'))[:10]}, `{commit[:10] if commit else 'no commit'}`"
            tier = regeneration_of(d).get("tier") or "by hand"
            changed = modules_changed(s, d, repo)
            since = "not known" if changed is None else "**changed**" if changed else "unchanged"
        out.append(f"| [{s.heading}](#{anchor(s.heading)}) | {tier} | {when} | {since} |")
    out.append("")
    for s in sections:
        out += [f"## {s.heading}", "", s.about, ""]
        if s.stem in docs:
            out += [tier_line(s, docs[s.stem], repo), *render_record(docs[s.stem])]
        else:
            out += [f"Not yet regenerated: run `{PY} tools/bench_report.py --regenerate --only {s.stem}` "
                    f"(quick tier: `{s.quick}`; full tier: `{s.command}`; writes `docs/bench/{s.stem}.json`)."]
        out.append("")
    extra = [k for k in docs if k not in known]
    if extra:
        out += ["## Other recorded runs", "", "Records in docs/bench/ that no section above names.", ""]
        for k in extra:
            out += [f"### {k}", "", *render_record(docs[k]), ""]
    return "\n".join(out).rstrip("\n") + "\n"


def render_files(bench_dir: Path, out: Path, sections: tuple[Section, ...] = SECTIONS) -> None:
    """Write the page and the README's score block from the records in ``bench_dir``."""
    from egograph.io.atomic import atomic_write_text

    docs = load(bench_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out, render(docs, sections, regens=load_regenerations(bench_dir)))
    if bench_dir.resolve() == BENCH_DIR.resolve() and README.is_file():
        old = README.read_text()
        new = with_readme_scores(old, readme_docs(bench_dir, docs))
        if new != old:
            atomic_write_text(README, new)


def anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    keep = "".join(c for c in heading.lower() if c.isalnum() or c in " -_")
    return keep.replace(" ", "-")


def commands(docs: dict[str, dict], only_missing: bool, tier: str = "full") -> str:
    lines = ["#!/usr/bin/env bash", "# The benchmarks of docs/benchmarks.md (tools/bench_report.py --commands"
             + (" --missing" if only_missing else "") + f" --tier {tier}); run from the repository root.",
             "set -euo pipefail"]
    lines += [s.command_for(tier) for s in SECTIONS if not (only_missing and s.stem in docs)]
    lines.append(f"{PY} tools/bench_report.py")
    return "\n".join(lines) + "\n"


README = REPO / "README.md"
README_BEGIN = "<!-- scores: generated by tools/bench_report.py from docs/bench/*.json; do not edit -->"
README_END = "<!-- scores: end -->"


def _table(doc: dict, title: str) -> dict:
    return next(it for it in doc["items"] if it["type"] == "table" and it["title"].startswith(title))


README_RECORDS = ("bench_frontend_trackers-device", "bench_trackers-heldout-robust-device",
                  "bench_causal-heldout6-device")
"""The records the README's score tables are rendered from, all of the device world (issue 38):
egograph end to end from pixels first (issue 39), then the trackers on simulated detections. The
README quotes them at the sizes the docs state (6 recordings x 300 frames; 12 and 6 held-out
recordings x 3000 frames), so it reads its own copies in ``docs/bench/readme/``: a full-tier
regeneration of these sections refreshes them; a quick-tier one changes only docs/benchmarks.md.
In that order: :func:`readme_scores` reads them as (end to end, trackers, lags)."""

README_DIR_NAME = "readme"


def readme_docs(bench_dir: Path, docs: dict[str, dict]) -> dict[str, dict]:
    """The README's records: the copies in ``bench_dir/readme/``, else the page's."""
    out = dict(docs)
    for stem in README_RECORDS:
        p = bench_dir / README_DIR_NAME / f"{stem}.json"
        if p.is_file():
            out[stem] = json.loads(p.read_text())
    return out


def pixels_rows(doc: dict) -> list[str]:
    """The README's first table: egograph end to end from pixels (``egograph detect``'s own
    detections: the default front-end, then the verified one of the record's ``verify`` variant, when
    it has one) against the paper's pipeline on the same detections, from
    the device-world front-end record: per set, the share of emitted detections on the instance and
    the IT3DEgo figures of memory + reference lifting (the paper) and the graph on robust lifting."""
    t = _table(doc, "Trackers on each detection source")
    col = {c: i for i, c in enumerate(t["columns"])}
    lines = ["| set | detections on the instance | tracker | P@0.25 | R@0.25 | P@1.5 | R@1.5 | L2 (m) |",
             "|---|---|---|---|---|---|---|---|"]
    for det_set, source in (("svoe", "detect"), ("svoe", "detect [verify]"), ("mvpe", "detect"),
                            ("mvpe", "detect [verify]")):
        for r in t["rows"]:
            if r[col["source"]] != source or r[col["set"]] != det_set:
                continue
            true, emitted, share = r[col["true / all detections"]]
            l2 = r[col["L2 (m)"]]
            cells = [f"{r[col[c]]:.1f}" for c in ("P@0.25", "R@0.25", "P@1.5", "R@1.5")] + \
                [f"{l2:.2f}" if isinstance(l2, (int, float)) else "-"]
            name = {"memory + reference (paper)": "memory (paper's pipeline)",
                    "graph + robust": "**graph** (offline)"}.get(r[col["tracker"]], r[col["tracker"]])
            label = det_set.upper() + (", verified" if source != "detect" else "")
            lines.append(f"| {label} | {true} / {emitted} ({share:.0f} %) | {name} | " + " | ".join(cells) + " |")
    return lines


def readme_scores(docs: dict[str, dict], repo: Path = REPO) -> str | None:
    """The README's score tables (issue 29): the trackers on the 12 held-out recordings and
    graph-causal against lag, from their records; None without those records. The last line gives
    each record's tier and commit, and whether the code its section exercises changed since (the
    page's staleness, :func:`modules_changed`): a quick-tier regeneration refreshes the page, not
    these copies."""
    fe, tr, ca = (docs.get(stem) for stem in README_RECORDS)
    if tr is None or ca is None or fe is None:
        return None
    lines = pixels_rows(fe) + [""]
    lines += ["| set | tracker | P@0.25 | R@0.25 | P@1.5 | R@1.5 | L2 (m) |", "|---|---|---|---|---|---|---|"]
    for det_set in ("SVOE", "MVPE"):
        t = _table(tr, det_set)
        col = {c: i for i, c in enumerate(t["columns"])}
        rows = {r[0].replace(" (robust lift)", ""): r for r in t["rows"]}
        for name in ("memory", "kf", "graph", "graph-causal"):
            if name in rows:
                r = rows[name]
                cells = [f"{r[col[c]]:.1f}" for c in ("P@0.25", "R@0.25", "P@1.5", "R@1.5")] + [f"{r[col['L2 (m)']]:.2f}"]
                label = {"graph": "**graph** (offline)", "memory": "memory (paper)", "kf": "kf (paper)"}.get(name, name)
                lines.append(f"| {det_set} | {label} | " + " | ".join(cells) + " |")
    lag = _table(ca, "P@0.25, R@0.25 and L2 against lag")
    names = list(dict.fromkeys(r[1] for r in lag["rows"]))
    lines += ["", "| lag | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for det_set in ("svoe", "mvpe"):
        by = {r[1]: r for r in lag["rows"] if r[0] == det_set}
        lines.append(f"| {det_set.upper()} P / R @0.25, L2 (m) | "
                     + " | ".join(f"{by[n][2]:.1f} / {by[n][3]:.1f}, {by[n][4]:.2f}" for n in names) + " |")
    made = []
    by_stem = {s.stem: s for s in SECTIONS}
    for stem, doc in zip(README_RECORDS, (docs[stem] for stem in README_RECORDS)):
        reg, commit = regeneration_of(doc), (doc.get("egograph") or {}).get("commit") or "no commit"
        changed = modules_changed(by_stem[stem], doc, repo) if stem in by_stem else None
        since = "" if changed is None else ", **code changed since**" if changed else ", code unchanged since"
        made.append((f"`{stem}` {reg.get('tier', 'by hand')} tier at `{commit[:10]}`" if reg
                     else f"`{stem}` by hand at `{commit[:10]}`") + since)
    lines += ["", "Records: " + "; ".join(made) + " (docs/bench/readme/)."]
    return "\n".join(lines)


def with_readme_scores(readme: str, docs: dict[str, dict]) -> str:
    """``readme`` with the block between the score markers rendered from the records."""
    block = readme_scores(docs)
    if block is None or README_BEGIN not in readme:
        return readme
    head, rest = readme.split(README_BEGIN, 1)
    _, tail = rest.split(README_END, 1)
    return f"{head}{README_BEGIN}\n{block}\n{README_END}{tail}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bench-dir", type=Path, default=BENCH_DIR, help="the JSON records (default docs/bench)")
    ap.add_argument("--out", type=Path, default=OUT, help="the page (default docs/benchmarks.md)")
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 with a diff when --out differs "
                                                         "from what the records render")
    ap.add_argument("--commands", action="store_true", help="print every section's command as a shell script")
    ap.add_argument("--missing", action="store_true", help="with --commands: only sections without a record")
    g = ap.add_argument_group("regeneration")
    g.add_argument("--regenerate", action="store_true",
                   help="run the sections' benchmarks (cheap first; a section whose record is current for the tier "
                        "and the code is kept, so a killed regeneration resumes), then render")
    g.add_argument("--tier", choices=TIERS, default="quick",
                   help="quick: fewer or shorter recordings of the same held-out seeds, every section in about an "
                        "hour on 2 cores; full: the sizes the docs quote (default quick)")
    g.add_argument("--only", nargs="+", metavar="SECTION", help="only these sections (record stems such as "
                                                                "bench_graph_speed, or headings)")
    where = g.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=1, metavar="N",
                       help="run N sections at once on this machine (default 1)")
    where.add_argument("--scheduler", metavar="ADDR", help="run each section as a task on the Dask cluster at ADDR "
                                                           "(the repository at the same path on every worker)")
    ap.add_argument("--upgrade-digests", action="store_true",
                    help="rewrite the module digests of records made under an older digest scheme "
                         "(DIGEST_SCHEME) from the files of the commit each was made at, where that commit "
                         "reproduces the old digest; then render")
    g.add_argument("--force", action="store_true", help="run the chosen sections even when their record is current")
    g.add_argument("--longest-first", action="store_true",
                   help="start the longest sections first (their last measured wall time in this tier): with "
                        "several workers the run ends sooner; without it cheap sections go first, so that a "
                        "killed run has finished the most")
    args = ap.parse_args(argv)
    if args.regenerate:
        if args.check or args.commands:
            ap.error("--regenerate writes records: not with --check or --commands")
        return regenerate(args.tier, args.only, args.workers, args.scheduler, args.bench_dir, args.out, args.force,
                          longest=args.longest_first)
    if args.upgrade_digests:
        upgrade_digests(args.bench_dir)
    docs = load(args.bench_dir)
    if args.commands:
        sys.stdout.write(commands(docs, args.missing, args.tier if "--tier" in (argv or sys.argv) else "full"))
        return 0
    text = render(docs, regens=load_regenerations(args.bench_dir))
    readme_old = README.read_text() if README.is_file() else ""
    readme_new = with_readme_scores(readme_old, readme_docs(args.bench_dir, docs))
    if args.check:
        old = args.out.read_text() if args.out.is_file() else ""
        if readme_old != readme_new:
            sys.stdout.writelines(difflib.unified_diff(readme_old.splitlines(True), readme_new.splitlines(True),
                                                       str(README), "rendered from " + str(args.bench_dir)))
            print(f"\n{README}'s score tables differ from what {args.bench_dir} renders: run {PY} "
                  "tools/bench_report.py", file=sys.stderr)
            return 1
        if old == text:
            print(f"{args.out} is current ({len(docs)} records)")
            return 0
        sys.stdout.writelines(difflib.unified_diff(old.splitlines(True), text.splitlines(True),
                                                   str(args.out), "rendered from " + str(args.bench_dir)))
        print(f"\n{args.out} differs from what {args.bench_dir} renders: run {PY} tools/bench_report.py",
              file=sys.stderr)
        return 1
    from egograph.io.atomic import atomic_write_text

    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out, text)
    if readme_new != readme_old:
        atomic_write_text(README, readme_new)
        print(f"updated the score tables of {README}")
    print(f"wrote {args.out} ({len(docs)} records, {sum(s.stem not in docs for s in SECTIONS)} sections "
          "not yet regenerated)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
