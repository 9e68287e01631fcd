"""Tolerant reading (and folder writing) of the dataset's small text tables.

The IT3DEgo files are written with inconsistent separators: the public
description uses commas, the released reference code splits on whitespace, and
files in the wild mix both (``1, 2 ,3``). So a row is split on any run of
commas and/or whitespace. Blank lines and lines starting with ``#`` are skipped.
Anything that cannot be parsed raises :class:`InputError` naming the file and
its 1-based line number.
"""

from __future__ import annotations

import json
import math
import re
from decimal import Decimal
from pathlib import Path
from typing import Callable, Iterator, Mapping, TypeVar

from egograph.core.errors import InputError
from egograph.io.atomic import atomic_dir

T = TypeVar("T")

_SEPARATORS = re.compile(r"[,\s]+")
_INT = re.compile(r"[+-]?[0-9]+")
_DIGITS = re.compile(r"[0-9]+")
# A plain decimal number; used to accept integral values written as "3.0" or "1e3".
_DECIMAL = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?")
_BOM = b"\xef\xbb\xbf"


def split_fields(line: str) -> list[str]:
    """Split one line on any run of commas and/or whitespace (empty fields dropped)."""
    return [tok for tok in _SEPARATORS.split(line.strip()) if tok]


def read_bytes_checked(path: str | Path, what: str) -> bytes:
    """The bytes of ``path``, or InputError naming it and ``what`` it should be ("pose file"):
    missing, a folder, or otherwise unreadable."""
    path = Path(path)
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise InputError(path, f"{what} missing") from None
    except IsADirectoryError:
        raise InputError(path, f"{what} expected, found a folder") from None
    except OSError as err:
        raise InputError(path, f"cannot read {what}: {err.strerror or err}") from None


def read_text_checked(path: str | Path, what: str) -> str:
    """:func:`read_bytes_checked` decoded as UTF-8 (a byte order mark is allowed), or InputError."""
    raw = read_bytes_checked(path, what)
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise InputError(path, f"{what} is not UTF-8 text ({err.reason} at byte {err.start})") from None


class _DuplicateKey(Exception):
    pass


def _no_duplicate_keys(pairs: list) -> dict:
    out = dict(pairs)
    if len(out) != len(pairs):
        seen = set()
        for k, _ in pairs:
            if k in seen:
                raise _DuplicateKey(k)
            seen.add(k)
    return out


def read_json_checked(path: str | Path, what: str):
    """The JSON document of ``path`` (:func:`read_text_checked`), or InputError naming the file (and
    line) when it is not JSON or is nested too deeply to parse."""
    text = read_text_checked(path, what)
    try:
        return json.loads(text, object_pairs_hook=_no_duplicate_keys)
    except _DuplicateKey as exc:
        raise InputError(path, f"{what}: key {exc.args[0][:80]!r} given twice (JSON keeps only the last "
                               "copy; which one is meant?)") from None
    except json.JSONDecodeError as exc:
        raise InputError(path, f"not valid JSON: {exc.msg}", exc.lineno) from None
    except RecursionError:
        raise InputError(path, f"{what} is JSON nested too deeply to read") from None


def iter_lines(path: str | Path) -> Iterator[tuple[int, str]]:
    """Yield ``(lineno, stripped_line)`` for every line that is not blank or a ``#`` comment.

    ``lineno`` is 1-based and counts every physical line of the file.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(path, "file not found") from None
    except OSError as err:
        raise InputError(path, f"cannot read file: {err.strerror or err}") from None
    if data.startswith(_BOM):  # files saved by Windows tools
        data = data[len(_BOM):]
    # Decode line by line so an encoding error can be reported with its line number.
    for lineno, raw in enumerate(data.splitlines(), 1):
        try:
            line = raw.decode("utf-8").strip()
        except UnicodeDecodeError as err:
            raise InputError(path, f"not UTF-8 text ({err.reason})", lineno) from None
        if not line or line.startswith("#"):
            continue
        yield lineno, line


def iter_rows(
    path: str | Path,
    min_cols: int,
    max_cols: int | None = None,
    layout: str | None = None,
) -> Iterator[tuple[int, list[str]]]:
    """Yield ``(lineno, tokens)`` for each data row of a text table.

    Rows must have between ``min_cols`` and ``max_cols`` fields; ``max_cols=None``
    means exactly ``min_cols`` (every format here has a fixed width, so extra
    columns are an error rather than silently ignored). ``layout`` (e.g.
    ``"ts x_min y_min x_max y_max"``) is quoted in column-count errors.
    """
    hi = min_cols if max_cols is None else max_cols
    for lineno, line in iter_lines(path):
        tokens = split_fields(line)
        if not min_cols <= len(tokens) <= hi:
            want = str(min_cols) if hi == min_cols else f"{min_cols} to {hi}"
            hint = f" ({layout})" if layout else ""
            raise InputError(path, f"expected {want} columns{hint}, got {len(tokens)}", lineno)
        yield lineno, tokens


def parse_int(tok: str, path: str | Path, lineno: int | None, what: str) -> int:
    """Parse an exact integer field (timestamps are ~18 digits, so never via float).

    Integral decimals such as ``3.0`` are accepted (numpy writes ids that way);
    ``3.5``, ``nan`` and words are not.
    """
    if _INT.fullmatch(tok):
        return int(tok)
    if _DECIMAL.fullmatch(tok):
        try:
            value = Decimal(tok)  # exact, unlike float(), for long timestamps
            # The exponent bound keeps "1e999999999" from building a giant int.
            if value.adjusted() < 40 and value == value.to_integral_value():
                return int(value)
        except ArithmeticError:  # decimal.InvalidOperation and friends
            pass
    raise InputError(path, f"{what}: expected an integer, got {tok!r}", lineno)


def parse_float(tok: str, path: str | Path, lineno: int | None, what: str) -> float:
    """Parse a finite float field; NaN and infinities are rejected."""
    try:
        value = float(tok)
    except ValueError:
        raise InputError(path, f"{what}: expected a number, got {tok!r}", lineno) from None
    if not math.isfinite(value):
        raise InputError(path, f"{what}: expected a finite number, got {tok!r}", lineno)
    return value


def make_record(path: str | Path, lineno: int | None, factory: Callable[..., T], *args) -> T:
    """Build a record, turning its validation ``ValueError`` into an :class:`InputError` at ``lineno``."""
    try:
        return factory(*args)
    except InputError:
        raise
    except (ValueError, TypeError) as err:
        raise InputError(path, str(err), lineno) from None


def int_stem(path: Path, what: str) -> int:
    """The non-negative integer a file is named after (``123.txt`` -> 123); InputError otherwise."""
    if path.suffix != ".txt" or not _DIGITS.fullmatch(path.stem):
        raise InputError(path, f"file name must be <{what}>.txt with {what} a non-negative integer")
    return int(path.stem)


def listed_files(folder: str | Path, what: str) -> list[Path]:
    """Non-hidden regular files of a folder; hidden ones (e.g. leftover ``.tmp``
    files of an interrupted atomic write, ``.DS_Store``) are skipped."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(folder, f"{what} folder not found")
    return [p for p in folder.iterdir() if not p.name.startswith(".") and p.is_file()]


def write_text_dir(path: str | Path, files: Mapping[str, str]) -> None:
    """Write a whole folder of text files (name -> text), replacing ``path`` atomically.

    Files inside the temporary folder need no fsync or rename each: the folder
    only takes the real name once every file is written, which keeps writing
    thousands of per-frame files fast.
    """
    with atomic_dir(path) as tmp:
        for name, text in files.items():
            with open(tmp / name, "w", encoding="utf-8", newline="\n") as f:
                f.write(text)
