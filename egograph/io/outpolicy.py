"""One output policy for every command: what an output path may be before anything is written.

A command writes only into the outputs it was given, and only when each is

* absent (its folder may be missing: it is made), or
* for a folder output: an empty folder, or a folder a previous egograph run made (its run record
  ``egograph.json`` says so) of a step this output may hold (a results folder is not replaced by
  pictures), or
* for a file output: a regular file (a report, an observations ``.npz`` carrying egograph's
  provenance).

Refused, with one line naming the path and the cause (:class:`InputError`, exit 2): an input of
the run itself, anything inside an input, or a folder holding an input; an existing file where a
folder goes and the reverse; a folder egograph did not make; a special file (device, FIFO,
socket); a symbolic link (the link would be replaced, not what it points to); a mount point (a
rename cannot replace it); a folder that is a file or missing parts of its path that cannot be made.

The checks are a few ``lstat`` calls per path, made once before a command starts its work.
"""

from __future__ import annotations

import json
import os
import stat
import zipfile
from dataclasses import dataclass
from pathlib import Path

from egograph.core.errors import InputError

RUN_FILE = "egograph.json"
"""The run record an output folder of egograph holds (:mod:`egograph.steps.outputs`)."""

RUNS_MARKERS = ("latest", "cache")
"""What an ``egograph run`` folder holds at its top (it has no run record of its own)."""


@dataclass(frozen=True)
class Output:
    """One output path of a command: ``kind`` ``dir`` or ``file``; ``steps`` the run-record steps a
    previous folder there may come from (empty: any egograph step; None: no record expected, e.g.
    a folder of per-frame points, or the runs folder of ``egograph run``)."""

    path: Path
    option: str
    kind: str
    steps: tuple[str, ...] | None = ()


def _real(p: Path) -> str:
    return os.path.realpath(os.path.abspath(p))


def _inside(a: str, b: str) -> bool:
    """Whether path ``a`` is ``b`` or lies under it (both real, absolute)."""
    return a == b or a.startswith(b.rstrip(os.sep) + os.sep)


def check_outputs(outputs: list[Output], inputs: list[Path]) -> None:
    """Refuse (InputError) the first output the policy does not allow; see the module docstring."""
    real_inputs = [(p, _real(p)) for p in inputs if p is not None and os.path.lexists(p)]
    own = {_real(o.path) for o in outputs}
    for out in outputs:
        check_output(out, real_inputs)
        _check_not_inside_an_output(out, own)


def _check_not_inside_an_output(out: Output, own: set[str]) -> None:
    """An output may not lie inside an earlier egograph output folder (other than one this run
    writes): that folder is replaced only as a whole, by its own step."""
    parent = Path(_real(out.path)).parent
    while True:
        if str(parent) not in own and _record(parent / RUN_FILE) is not None:
            step = _record(parent / RUN_FILE).get("step")
            raise InputError(out.path, f"{out.option} lies inside {parent}, the output of `egograph {step}`; "
                                       "egograph replaces an output folder only as a whole: choose another output")
        if parent.parent == parent:
            return
        parent = parent.parent


def check_output(out: Output, real_inputs: list[tuple[Path, str]]) -> None:
    path = Path(out.path)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        st = None
    except OSError as exc:  # a name too long, a path through a file, a loop of links
        raise InputError(path, f"{out.option}: {_why(exc)}") from None
    target = _real(path)
    for given, real in real_inputs:
        if _inside(target, real):
            what = "is" if target == real else "lies inside"
            raise InputError(path, f"{out.option} {what} the input {given}; egograph never writes into its "
                                   "inputs: choose another output")
        if out.kind == "dir" and _inside(real, target):
            raise InputError(path, f"{out.option} holds the input {given}; replacing it would delete it: "
                                   "choose another output")
    if st is None:
        _check_parent(path, out.option)
        return
    mode = st.st_mode
    if stat.S_ISLNK(mode):
        raise InputError(path, f"{out.option} is a symbolic link (to {os.readlink(path)}); egograph replaces its "
                               "outputs as a whole and would replace the link: give the real path")
    if not (stat.S_ISDIR(mode) or stat.S_ISREG(mode)):
        raise InputError(path, f"{out.option} is a special file ({_kind(mode)}), not an output egograph may "
                               "replace")
    if out.kind == "dir":
        if not stat.S_ISDIR(mode):
            raise InputError(path, f"{out.option} is an existing file where an output folder goes; "
                                   "choose another output")
        if os.path.ismount(path):
            raise InputError(path, f"{out.option} is a mount point; egograph replaces an output folder by a "
                                   "rename, which cannot replace a mount point: give a folder inside it")
        _check_folder(path, out)
    else:
        if stat.S_ISDIR(mode):
            raise InputError(path, f"{out.option} is an existing folder where an output file goes; "
                                   "choose another output")
        if path.suffix == ".npz" and not _egograph_npz(path):
            raise InputError(path, f"{out.option} exists and is not an observations file egograph wrote (no "
                                   "provenance inside); egograph replaces only its own outputs")


def _check_folder(path: Path, out: Output) -> None:
    try:
        names = os.listdir(path)
    except OSError as exc:
        raise InputError(path, f"{out.option}: {_why(exc)}") from None
    if not names:
        return
    if out.steps is None:
        return
    record = _record(path / RUN_FILE)
    if record is None:
        raise InputError(path, f"{out.option} is a folder egograph did not make (no readable {RUN_FILE} in it); "
                               "egograph replaces only its own outputs: choose another output or remove it")
    step = record.get("step")
    if out.steps and step not in out.steps:
        raise InputError(path, f"{out.option} holds the output of `egograph {step}`, not of "
                               f"`egograph {' / '.join(out.steps)}`; choose another output")


def _record(f: Path) -> dict | None:
    try:
        with open(f, encoding="utf-8") as fh:
            record = json.load(fh)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if isinstance(record, dict) and "step" in record and "fingerprint" in record:
        return record
    return None


def _egograph_npz(path: Path) -> bool:
    try:
        with zipfile.ZipFile(path) as z:
            return "provenance.npy" in z.namelist()
    except (OSError, zipfile.BadZipFile):
        return False


def _check_parent(path: Path, option: str) -> None:
    """The nearest existing ancestor must be a folder (a missing one is made later)."""
    parent = path.absolute().parent
    while True:
        try:
            st = os.stat(parent)
        except FileNotFoundError:
            if parent.parent == parent:
                return
            parent = parent.parent
            continue
        except OSError as exc:
            raise InputError(path, f"{option}: {_why(exc)}") from None
        if not stat.S_ISDIR(st.st_mode):
            raise InputError(path, f"{option}: {parent} is not a folder")
        return


def _kind(mode: int) -> str:
    for test, word in ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return word
    return "not a regular file"


def _why(exc: OSError) -> str:
    return machine_fault_text(exc, with_path=False)


_HINTS = {
    "EROFS": "the filesystem is read-only",
    "ENOSPC": "no space left on the device",
    "EDQUOT": "disk quota exceeded",
    "ENAMETOOLONG": "file name too long",
    "EACCES": "permission denied",
    "EPERM": "operation not permitted",
    "EBUSY": "the path is busy (a mount point?)",
    "ENOTDIR": "a part of the path is not a folder",
    "EISDIR": "is a folder",
    "ELOOP": "too many levels of symbolic links",
    "EXDEV": "crosses filesystems",
    "EFBIG": "file too large",
    "EIO": "input/output error",
    "EMFILE": "too many open files",
    "ENFILE": "too many open files in the system",
    "ENOTEMPTY": "folder not empty",
    "EEXIST": "already exists",
}
MACHINE_ERRNOS = frozenset(getattr(__import__("errno"), n) for n in _HINTS)
"""The errors of the machine (not of egograph): the CLI reports them in one line, exit 2."""


def machine_fault_text(exc: OSError, with_path: bool = True) -> str:
    """One line for an OSError of the machine: ``PATH: cause`` (the path when it has one)."""
    import errno

    name = errno.errorcode.get(exc.errno or 0, "")
    cause = _HINTS.get(name) or exc.strerror or str(exc)
    path = exc.filename
    if with_path and path is not None:
        text = f"{os.fsdecode(path)}: {cause}"
        if exc.filename2 is not None:
            text += f" (to {os.fsdecode(exc.filename2)})"
        return text
    return cause
