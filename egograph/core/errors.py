"""Every error egograph shows a user: one line, naming the file (and line) or the config key.

``EgographError`` is the base; the CLI prints ``egograph: error: <message>`` and exits 2 for it.
"""

from __future__ import annotations

from pathlib import Path


class EgographError(ValueError):
    """An error a user can act on; ``str(err)`` is the whole one-line message."""


class InputError(EgographError):
    """Malformed or missing input. ``str(err)`` reads ``path:line: message``."""

    def __init__(self, path: str | Path, message: str, line: int | None = None):
        self.path = Path(path)
        self.line = line
        self.message = message
        where = f"{self.path}:{line}" if line is not None else f"{self.path}"
        super().__init__(f"{where}: {message}")


class ConfigError(EgographError):
    """A config file or override that does not fit the config schema (names the key)."""
