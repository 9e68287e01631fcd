"""``egograph`` command line: one sub-command per use (see :mod:`egograph.cli.main`)."""

from egograph.core import signals as _signals

_signals.record_early()  # a Ctrl-C while the command's modules import is remembered (see core.signals)

from egograph.cli.main import build_parser, main  # noqa: E402

__all__ = ["build_parser", "main"]
