"""``egograph export``: a tracker's results on a recording in files other tools open.

    egograph export REC RESULTS [--out DIR] [--rrd] [--key-every N]

Writes DIR (default ``RESULTS.export`` beside the results folder) as a whole: ``intervals.ply``
(interval centres for Open3D or MeshLab), ``pv_reported.tum`` and, for synthetic recordings,
``pv_true.tum`` (for ``evo_ape``), and with ``--rrd`` a rerun recording ``recording.rrd``
(``pip install 'egograph[viewer]'``; open it with ``rerun DIR/recording.rrd``).
"""

from __future__ import annotations

from pathlib import Path


def add_parser(sub, add_config_args, add_rec_args, default_config: Path) -> None:
    """Add the ``export`` sub-command."""
    s = sub.add_parser("export", help="interval centres as .ply, poses as TUM, and a rerun .rrd (--rrd)")
    add_rec_args(s)
    s.add_argument("results", type=Path, help="results folder (per-frame files; intervals.json when present)")
    s.add_argument("--out", type=Path, help="output folder (default: RESULTS.export beside the results folder); "
                                            "replaced as a whole when complete")
    s.add_argument("--rrd", action="store_true", help="also write recording.rrd for the rerun viewer "
                                                      "(needs the viewer extra: rerun-sdk)")
    s.add_argument("--key-every", type=int, default=30, metavar="N",
                   help="AHAT points of every N-th frame go into the .rrd (default 30: one per second)")
    s.add_argument("--overwrite", action="store_true", help="write again even if --out holds this exact export")
    add_config_args(s, default_config)
    s.set_defaults(func=cmd_export)


def cmd_export(args) -> int:
    from egograph.cli.common import _console, open_rec, pipeline_config
    from egograph.core.errors import InputError
    from egograph.steps.export import export

    if not Path(args.results).is_dir():  # before the recording is opened: a wrong path fails at once
        raise InputError(args.results, "results folder not found")
    cfg = pipeline_config(args)
    rec = open_rec(args, cfg)
    out = args.out or Path(args.results).with_name(Path(args.results).name + ".export")
    result = export(rec, args.results, out, cfg, rrd=args.rrd, key_every=args.key_every, overwrite=args.overwrite)
    con = _console()
    if result is None:
        con.print(f"{out}: already holds this export (--overwrite to write it again)", soft_wrap=True)
        return 0
    for name, what in result.files.items():
        con.print(f"  {name}: {what}", soft_wrap=True)
    con.print(f"wrote {len(result.files)} files -> {out}", soft_wrap=True)
    return 0
