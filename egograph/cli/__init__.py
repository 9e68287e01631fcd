"""``egograph`` command line: one sub-command per use (see :mod:`egograph.cli.main`)."""

import sys as _sys
from pathlib import Path as _Path

from egograph.core import signals as _signals

_signals.record_early()  # a Ctrl-C while the command's modules import is remembered (see core.signals)

try:
    from egograph.cli.main import build_parser, main  # noqa: E402
except KeyboardInterrupt:
    if _Path(_sys.argv[0] if _sys.argv else "").name != "egograph":
        raise
    # Ctrl-C while the command starts (the `egograph` script imports this first): one line, exit 130.
    print("egograph: interrupted (SIGINT) while starting; nothing was written", file=_sys.stderr)
    raise SystemExit(130) from None

__all__ = ["build_parser", "main"]
