"""What every sub-command shares: the console, the config and recording arguments, ``--show-config``,
and the tables a person reads after a run (sized for an 80-column terminal)."""

from __future__ import annotations

import argparse
from pathlib import Path

from egograph.core.config import describe, load_config
from egograph.core.resources import config_argument, default_config, synth_config
from egograph.core.units import TICKS_PER_SECOND

DEFAULT_CONFIG = default_config()
SYNTH_CONFIG = synth_config("svoe")


def _console():
    from rich.console import Console

    class _Console(Console):
        def on_broken_pipe(self) -> None:
            """The reader went away (``| head``): the CLI stops quietly (rich would exit 1)."""
            import errno

            self.quiet = True
            raise BrokenPipeError(errno.EPIPE, "Broken pipe")

    return _Console()


def _add_config_args(p: argparse.ArgumentParser, default: Path | None) -> None:
    p.add_argument("--config", type=config_argument, default=default,
                   help="YAML config: a file, or a packaged name such as 'default' or 'synth/tiny' "
                        f"(default: {Path(default).name if default else 'none'})")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config knob (dotted key, YAML value), e.g. --set lift.mode=reference; repeatable")
    p.add_argument("--show-config", action="store_true",
                   help="print every knob with its value and meaning, then exit (needs no other argument)")
    if not any("--format" in a.option_strings for a in p._actions):  # eval/compare have their own --format
        p.add_argument("--format", dest="config_format", choices=("table", "yaml"), default="table",
                       help="with --show-config: a table, or YAML that --config reads back")


def _add_rec_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("rec", type=Path, help="recording: a sequence folder, or a root holding one (as `egograph synth` writes)")
    p.add_argument("--sequence", help="sequence name when REC holds several")
    p.add_argument("--calibration", type=Path, help="calibrations/ folder when not found beside/above the recording")
    p.add_argument("--annotations", type=Path, help="annotation folder when not found beside the recording")
    p.add_argument("--strict", action="store_true",
                   help="refuse input that is missing, unreadable or partly unusable (labels, enrollments, frames, "
                        "invalid poses, depth sync; for eval also result files) instead of warning and counting "
                        "(sets io.strict)")


def open_rec(args, cfg):
    """The recording named by the arguments of :func:`_add_rec_args`, with ``--poses`` where the
    command has it (refined poses in place of the recording's)."""
    from egograph.steps.recording import open_recording

    return open_recording(args.rec, cfg, calibration=args.calibration, annotations=args.annotations,
                          sequence=args.sequence, poses=getattr(args, "poses", None))


def _show_config(cfg, fmt: str = "table") -> None:
    if fmt == "yaml":
        from egograph.steps.outputs import config_yaml

        print(config_yaml(cfg), end="")
        return
    from rich.table import Table

    t = Table(title="configuration", show_lines=False)
    t.add_column("knob", overflow="fold")
    t.add_column("value", overflow="fold", max_width=18)
    t.add_column("meaning", overflow="fold", ratio=1)
    for key, value, doc in describe(cfg):
        t.add_row(key, repr(value), doc)
    _console().print(t)


def pipeline_config(args):
    """The pipeline configuration of a command: ``--config`` <- ``--set`` <- ``--lift``."""
    from egograph.steps.settings import EgographConfig

    cfg = load_config(EgographConfig, args.config, args.overrides)
    if getattr(args, "strict", False):
        cfg.io.strict = True
    if getattr(args, "lift", None):
        cfg.lift.mode = args.lift
        cfg.lift.check()
    return cfg


def seconds(t: int, t0: int) -> str:
    return f"{(int(t) - int(t0)) / TICKS_PER_SECOND:.1f}"


def print_intervals(con, intervals, rec, metadata: dict, labels=None) -> None:
    """The position intervals as a table that fits 80 columns."""
    from rich.table import Table

    t0 = int(rec.timestamps[0])
    t = Table(title=f"position intervals ({metadata.get('tracker')}): {len(intervals)}")
    for col, kw in (("instance", {"overflow": "fold", "max_width": 14}), ("from s", {}), ("to s", {}),
                    ("x y z (m)", {}), ("σ cm", {}), ("dets", {}), ("conf", {}), ("ended by", {"overflow": "fold"})):
        t.add_column(col, justify="right" if col not in ("instance", "ended by") else "left", **kw)
    for iv in intervals:
        name = labels[iv.instance] if labels and iv.instance < len(labels) else str(iv.instance)
        t.add_row(name, seconds(iv.t_start, t0) + ("*" if iv.backfilled else ""), seconds(iv.t_end, t0),
                  " ".join(f"{v:.2f}" for v in iv.xyz), f"{100 * iv.sigma_m:.1f}", str(iv.n_observations),
                  f"{iv.confidence:.2f}", iv.ended_by)
    con.print(t)
    if metadata.get("backfilled"):
        con.print("* back-filled to the first frame (offline mode: before its first detection an instance is "
                  "reported at its first interval)")
    rounds = metadata.get("noise_scale_rounds") or []
    if len(rounds) > 1:
        con.print(f"detection noise scale fitted from the stands: {metadata['noise_scale']:.2f}x the configured "
                  f"sigmas ({' -> '.join(f'{r:g}' for r in rounds[:4])}{' -> ...' if len(rounds) > 4 else ''})")


def why_no_intervals(obs, rec, graph_cfg) -> str:
    """A person-readable reason why the graph found no position interval."""
    import numpy as np

    dur = (int(rec.timestamps[-1]) - int(rec.timestamps[0])) / TICKS_PER_SECOND if len(rec) else 0.0
    usable = obs.valid & (obs.score >= np.float32(graph_cfg.score_threshold))
    per = np.bincount(obs.instance[usable], minlength=1) if usable.any() else np.zeros(1, int)
    need = graph_cfg.min_observations
    if not len(obs):
        return "no detections at all (check --detections)"
    if not usable.any():
        return (f"none of the {len(obs)} detections is lifted with a score >= graph.score_threshold "
                f"({graph_cfg.score_threshold})")
    return (f"a stand needs at least {need} consistent detections (graph.min_observations); the best-seen instance "
            f"has {int(per.max())} usable ones over {dur:.1f} s of recording")


# ------------------------------------------------------------------ the output policy

OUTPUT_OPTIONS = {"json": "file", "markdown": "file", "csv": "file", "plot": "file", "intervals": "file",
                  "lifted_dir": "dir", "poses_out": "dir"}
"""Output options besides ``--out`` and the kind of path each names."""

OUT_STEPS = {"synth": ("synth",), "track": ("track",), "smooth": ("smooth",), "regt": ("regt",),
             "compare": ("compare",), "refine": ("refine",), "plot": ("plot",), "export": ("export",),
             "run": None}
"""The run-record steps a previous ``--out`` folder of a command may hold (others: any egograph step)."""

INPUT_OPTIONS = ("rec", "results", "observations", "detections", "poses", "guide", "adapt", "adapt_detections",
                 "calibration", "annotations", "config", "dataset", "encoder", "reference")
"""Arguments that name inputs: no output may be one of them, lie inside one or hold one."""


def command_outputs(args) -> list:
    """The outputs a parsed command line names, as :class:`egograph.io.outpolicy.Output`."""
    from egograph.io.outpolicy import Output

    outs = []
    out = getattr(args, "out", None)
    if out is not None and args.command != "demo":
        kind = "file" if args.command == "lift" else "dir"
        outs.append(Output(Path(out), "--out" if args.command != "synth" else "OUT", kind,
                           OUT_STEPS.get(args.command, ())))
    for name, kind in OUTPUT_OPTIONS.items():
        value = getattr(args, name, None)
        if isinstance(value, (str, Path)):
            outs.append(Output(Path(value), "--" + name.replace("_", "-"), kind, None if kind == "dir" else ()))
    return outs


def command_inputs(args) -> list[Path]:
    ins = []
    for name in INPUT_OPTIONS:
        value = getattr(args, name, None)
        for v in value if isinstance(value, list) else [value]:
            if isinstance(v, (str, Path)) and str(v):
                ins.append(Path(v))
    return ins


def check_output_policy(args) -> None:
    """Refuse (exit 2, one line) an output the policy of :mod:`egograph.io.outpolicy` forbids."""
    from egograph.io.outpolicy import check_outputs

    check_outputs(command_outputs(args), command_inputs(args))
