"""What every sub-command shares: the console, the config and recording arguments, ``--show-config``."""

from __future__ import annotations

import argparse
from pathlib import Path

from egograph.core.config import describe

REPO = Path(__file__).resolve().parents[2]

DEFAULT_CONFIG = REPO / "configs" / "default.yaml"


def _console():
    from rich.console import Console

    return Console()


def _add_config_args(p: argparse.ArgumentParser, default: Path | None) -> None:
    p.add_argument("--config", type=Path, default=default, help=f"YAML config (default: {default})")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config knob (dotted key), e.g. --set lift.mode=reference; repeatable")
    p.add_argument("--show-config", action="store_true", help="print every knob with its value and documentation, then exit")


def _add_rec_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("rec", type=Path, help="recording: a sequence folder, or a root holding one (as `egograph synth` writes)")
    p.add_argument("--sequence", help="sequence name when REC holds several")
    p.add_argument("--calibration", type=Path, help="calibrations/ folder when not found beside/above the recording")
    p.add_argument("--annotations", type=Path, help="annotation folder when not found beside the recording")


def _show_config(cfg) -> None:
    from rich.table import Table

    t = Table(title="configuration")
    for col in ("knob", "value", "meaning"):
        t.add_column(col)
    for key, value, doc in describe(cfg):
        t.add_row(key, repr(value), doc)
    _console().print(t)
