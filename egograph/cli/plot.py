"""``egograph plot``: pictures of trackers' results on a recording, and an HTML page.

    egograph plot REC RESULTS [RESULTS2 ...] [--names a,b] [--detections svoe] [--out DIR]

Writes DIR (default ``RESULTS.plots`` beside the first results folder) as a whole: per tracker a
timeline per instance and a top-down map, one figure of error over time and precision/recall,
a PV contact sheet around each break when the recording has PV frames, and ``index.html``.
"""

from __future__ import annotations

from pathlib import Path


def add_parser(sub, add_config_args, add_rec_args, default_config: Path) -> None:
    """Add the ``plot`` sub-command."""
    s = sub.add_parser("plot", help="pictures of results folders (timelines, map, errors, PV frames) and index.html")
    add_rec_args(s)
    s.add_argument("results", nargs="+", type=Path, help="results folders (per-frame files; intervals.json when "
                                                         "present)")
    s.add_argument("--names", help="comma-separated tracker names (default: the folder names)")
    s.add_argument("--detections", help="also show this detection set (svoe, mvpe) or folder as ticks; true/false "
                                        "when synth_gt/ says which are false")
    s.add_argument("--out", type=Path, help="output folder (default: RESULTS.plots beside the first results folder); "
                                            "replaced as a whole when complete")
    add_config_args(s, default_config)
    s.set_defaults(func=cmd_plot)


def cmd_plot(args) -> int:
    from egograph.cli.common import _console, open_rec, pipeline_config
    from egograph.steps.plot import check_results, plot

    names = [n.strip() for n in args.names.split(",")] if args.names else None
    check_results(args.results, names)  # before the recording is opened: a wrong path fails at once
    cfg = pipeline_config(args)
    rec = open_rec(args, cfg)
    out = args.out or Path(args.results[0]).with_name(Path(args.results[0]).name + ".plots")
    result = plot(rec, args.results, out, cfg, names=names, detections=args.detections)
    _console().print(f"wrote {len(result.images)} pictures and index.html -> {out}", soft_wrap=True)
    return 0
