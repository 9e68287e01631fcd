"""``egograph sot`` and ``egograph eval-2d``: the paper's SOT baseline and its 2D table.

    egograph sot REC --out DETS [--method csrt|kcf]
    egograph eval-2d REC DETECTIONS [DETECTIONS2 ...] [--names a,b] [--json OUT]

``sot`` writes a detection folder (boxes of an OpenCV tracker started at each SVOE box);
``egograph track REC --tracker memory --lift reference --detections DETS`` then gives the SOT row.
``eval-2d`` scores detection folders (or the sets svoe, mvpe) against ``2d_bbox_annot/``: success
AUC, precision at 20 px and normalised precision, in percent.
"""

from __future__ import annotations

import json
from pathlib import Path


def add_parsers(sub, add_config_args, add_rec_args, default_config: Path) -> None:
    """Add the ``sot`` and ``eval-2d`` sub-commands."""
    s = sub.add_parser("sot", help="the paper's SOT baseline: an OpenCV tracker per instance from its SVOE box")
    add_rec_args(s)
    s.add_argument("--out", type=Path, required=True, help="detection folder to write (replaced as a whole)")
    s.add_argument("--method", default="csrt", help="csrt (default) or kcf")
    s.add_argument("--overwrite", action="store_true", help="run again even if --out holds this exact run")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    add_config_args(s, default_config)
    s.set_defaults(func=cmd_sot)

    e = sub.add_parser("eval-2d", help="2D tracking table (AUC, precision at 20 px, normalised precision) of "
                                       "detection folders against 2d_bbox_annot/")
    add_rec_args(e)
    e.add_argument("detections", nargs="+", help="detection folders, or set names (svoe, mvpe)")
    e.add_argument("--names", help="comma-separated row names (default: the folder names)")
    e.add_argument("--json", type=Path, help="also write the scores as JSON (pooled and per instance)")
    add_config_args(e, default_config)
    e.set_defaults(func=cmd_eval_2d)


def _open(args):
    from egograph.cli.common import open_rec, pipeline_config

    cfg = pipeline_config(args)
    return cfg, open_rec(args, cfg)


def cmd_sot(args) -> int:
    from egograph.cli.common import _console
    from egograph.steps.sot import sot

    cfg, rec = _open(args)
    report = sot(rec, cfg, args.out, method=args.method, overwrite=args.overwrite, progress=not args.quiet)
    con = _console()
    if report is None:
        con.print(f"{args.out} already holds this SOT run; --overwrite runs it again", soft_wrap=True)
        return 0
    con.print(f"SOT ({report.method}) detections -> {args.out}", soft_wrap=True)
    con.print(report.summary())
    return 0


def cmd_eval_2d(args) -> int:
    from egograph.cli.common import _console
    from egograph.core.errors import ConfigError
    from egograph.io.atomic import atomic_write_text
    from egograph.steps.sot import eval_2d

    names = [n.strip() for n in args.names.split(",")] if args.names else [Path(d).name for d in args.detections]
    if len(names) != len(args.detections) or len(set(names)) != len(names):
        raise ConfigError(f"--names must give one distinct name per detection folder, got {names}")
    cfg, rec = _open(args)
    rows = {n: eval_2d(rec, d, cfg) for n, d in zip(names, args.detections)}
    con = _console()
    con.print(f"{'detections':<16s} {'AUC':>6s} {'P@20px':>7s} {'P_norm':>7s} {'boxes':>7s} {'pairs':>6s}")
    for n, s in rows.items():
        con.print(f"{n[:16]:<16s} {s.auc:6.1f} {s.precision_20px:7.1f} {s.norm_precision:7.1f} "
                  f"{s.n_detected:7d} {s.n:6d}")
    if args.json:
        atomic_write_text(args.json, json.dumps({n: s.as_dict() for n, s in rows.items()}, indent=1) + "\n")
    return 0
