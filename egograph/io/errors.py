"""Errors for bad input: they always name the file, and the line when there is one."""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Malformed or missing input. ``str(err)`` reads ``path:line: message``."""

    def __init__(self, path: str | Path, message: str, line: int | None = None):
        self.path = Path(path)
        self.line = line
        self.message = message
        where = f"{self.path}:{line}" if line is not None else f"{self.path}"
        super().__init__(f"{where}: {message}")
