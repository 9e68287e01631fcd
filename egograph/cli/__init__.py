"""``egograph`` command line: one sub-command per use (see :mod:`egograph.cli.main`)."""

from egograph.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
