"""Atomic output: build beside the target under a temporary name, then rename, so a failed or
killed run never leaves a half-written file or folder in place of a good one.

One run at a time per output. While a file or folder is built and renamed into place, its
writer holds an advisory lock (``fcntl.flock``) on a hidden ``.NAME.lock`` file beside it; a
second run on the same output fails at once with an :class:`~egograph.core.errors.InputError`
naming the holder's pid, or waits for it when asked to (``wait=`` seconds, or the environment
variable ``EGOGRAPH_LOCK_WAIT``; ``inf`` waits for ever). The lock file is removed when the lock is
released (a killed writer leaves it behind; the next run takes it over). :func:`output_lock` holds
the same lock around a longer stretch (a whole step); the writes inside it re-enter it.

Temporaries are named ``.NAME.<pid>.<random>.tmp`` after their writer. A run on NAME, holding the
lock, first removes the temporaries a killed run left behind (their pid is not alive) and says
so in one warning.

Replacing an existing folder swaps the new one in with one ``renameat2(RENAME_EXCHANGE)`` (Linux
3.15+, on ext4, xfs, btrfs, tmpfs and most local filesystems): at every instant NAME is either the
whole old folder or the whole new one. Where the exchange is unavailable the old folder is first
renamed to ``.NAME.old`` and the new one renamed in: a kill in the microseconds between the two
renames leaves no NAME, and the next run on NAME restores ``.NAME.old`` before anything else.
Kill safety is what this covers; surviving a power loss would also need fsyncs, which are not done.

The temporary files and folders come from ``tempfile`` (modes 0600 / 0700); each is given the
mode a plain ``open``/``mkdir`` would create under the process umask (0644 / 0755 under 0022)
before it is renamed into place.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import functools
import math
import os
import re
import shutil
import signal
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path
from typing import Iterator

from egograph.core import signals
from egograph.core.errors import ConfigError, InputError

try:
    import fcntl
except ImportError:  # not POSIX: no locking, the rest works
    fcntl = None

FILE_MODE = 0o666
DIR_MODE = 0o777
"""What ``open`` and ``mkdir`` ask for; the umask takes bits away."""

WAIT_ENV = "EGOGRAPH_LOCK_WAIT"
"""Seconds a run waits for another run writing the same output (default 0: fail at once)."""

POLL_SECONDS = 0.05
"""How often a waiting run retries the lock."""

_UNSUPPORTED = {errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EXDEV}
_NO_LOCKS = {errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EINVAL}
_TMP_TAIL = re.compile(r"(\d+)\.[A-Za-z0-9_]+\.tmp")


class LeftoverWarning(UserWarning):
    """Temporaries of interrupted runs were removed, or an interrupted replacement undone."""


def process_umask() -> int:
    """The process umask now, read without changing it: from ``/proc/self/status`` (Linux).

    Where that is missing it is read once, by setting and restoring it (another thread creating a
    file in that instant would see the wrong mask), and remembered.
    """
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    return _umask_by_swapping()


@functools.cache
def _umask_by_swapping() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


# ------------------------------------------------------------------ the lock


def lock_path(path: str | Path) -> Path:
    """The lock file of an output: ``.NAME.lock`` beside it."""
    path = Path(path)
    return path.with_name(f".{path.name}.lock")


def default_wait() -> float:
    """Seconds to wait for another writer: ``$EGOGRAPH_LOCK_WAIT`` (``inf`` = for ever), else 0."""
    text = os.environ.get(WAIT_ENV, "").strip()
    if not text:
        return 0.0
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not value >= 0:
        raise ConfigError(f"{WAIT_ENV}={text!r}: expected a number of seconds, 0 or more (inf: wait for ever)")
    return value


_held = threading.local()  # per thread: lock path -> [fd, depth]


def _held_locks() -> dict:
    if not hasattr(_held, "locks"):
        _held.locks = {}
    return _held.locks


@contextlib.contextmanager
def output_lock(path: str | Path, wait: float | None = None) -> Iterator[None]:
    """Hold the output lock of ``path`` (file or folder) for the ``with`` block.

    Re-entrant within a thread, so a step can hold it around its whole run while its writes take
    it again. Another holder (another process, or another thread) makes it wait up to ``wait``
    seconds (None: :func:`default_wait`), then raise :class:`InputError`. On filesystems without
    ``flock`` support the block runs unlocked.
    """
    lock = lock_path(path)
    key = os.path.abspath(lock)
    held = _held_locks()
    if key in held:
        held[key][1] += 1
        try:
            yield
        finally:
            held[key][1] -= 1
        return
    fd = _acquire(lock, default_wait() if wait is None else wait, Path(path))
    held[key] = [fd, 1]
    try:
        yield
    finally:
        del held[key]
        _release(lock, fd)


def _acquire(lock: Path, wait: float, target: Path) -> int | None:
    """Lock ``lock`` (created if missing) and write our pid in it; the fd, or None when unsupported."""
    if fcntl is None:
        return None
    lock.parent.mkdir(parents=True, exist_ok=True)
    deadline = time.monotonic() + wait
    while True:
        fd, writable = _open_lock(lock)
        try:
            got = _try_flock(fd)
            if got is None:  # the filesystem cannot lock: carry on without
                os.close(fd)
                return None
            if got:
                if _same_file(fd, lock):
                    if writable:
                        _write_pid(fd)
                    return fd
                # The holder we waited for removed this lock file on release; take the new one.
                os.close(fd)
                continue
            holder = _holder_pid(fd)
        except BaseException:
            os.close(fd)
            raise
        os.close(fd)
        if time.monotonic() >= deadline:
            raise InputError(target, f"another egograph run is writing this output (pid {holder}); "
                                     "wait for it or choose another --out")
        time.sleep(min(POLL_SECONDS, max(0.0, deadline - time.monotonic())))


def _open_lock(lock: Path) -> tuple[int, bool]:
    """The lock file opened (created when missing); read-only when it is another user's."""
    flags = os.O_CREAT | getattr(os, "O_CLOEXEC", 0)
    try:
        return os.open(lock, os.O_RDWR | flags, FILE_MODE), True
    except PermissionError:
        return os.open(lock, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0)), False


def _write_pid(fd: int) -> None:
    pid = f"{os.getpid()}\n".encode()
    os.pwrite(fd, pid, 0)
    if os.fstat(fd).st_size > len(pid):  # a killed holder's longer pid
        os.ftruncate(fd, len(pid))


def _try_flock(fd: int) -> bool | None:
    """True when locked, False when someone else holds it, None when locking is unsupported."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False
    except OSError as err:
        if err.errno in _NO_LOCKS:
            return None
        raise


def _same_file(fd: int, lock: Path) -> bool:
    """Whether the open lock file is still the one at ``lock`` (not unlinked by its last holder)."""
    try:
        st = os.stat(lock)
    except FileNotFoundError:
        return False
    mine = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (mine.st_dev, mine.st_ino)


def _holder_pid(fd: int) -> str:
    """The pid the lock's holder wrote, or ``unknown`` (it may not have written it yet)."""
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        return "unknown"
    return text if text.isdigit() else "unknown"


def _release(lock: Path, fd: int | None) -> None:
    """Remove the lock file while still holding it (waiters notice and retry), then unlock."""
    if fd is None:
        return
    try:
        if _same_file(fd, lock):
            lock.unlink(missing_ok=True)
    except OSError:
        pass  # a lock file left behind is harmless: the next run takes it over
    finally:
        os.close(fd)


# ------------------------------------------------------------------ leftovers


_in_use: set[str] = set()  # this process's temporaries being built (absolute paths)


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return False  # not in _in_use, and we hold the lock: a leftover of ours
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # someone else's live process
    except OverflowError:
        return False
    return True


def clean_leftovers(path: str | Path, folder: bool = True) -> list[str]:
    """Remove what interrupted runs on ``path`` left beside it; the names of what was done.

    Call it holding the output lock. Temporaries ``.NAME.<pid>.<random>.tmp`` whose writer is no
    longer alive are removed (files, folders, links; never followed). For a ``folder`` output, an
    interrupted replacement (no NAME but ``.NAME.old``) is undone and a ``.NAME.old`` beside a NAME
    is removed.
    """
    path = Path(path)
    parent = path.parent
    head = f".{path.name}."
    done = []
    try:
        names = sorted(os.listdir(parent))
    except OSError:
        return done
    for name in names:
        if not name.startswith(head):
            continue
        tail = name[len(head):]
        if tail == "old" and folder:
            old = parent / name
            if not os.path.lexists(path):
                with contextlib.suppress(OSError):
                    os.replace(old, path)
                    done.append(f"{name} restored as {path.name}")
            else:
                _remove(old)
                done.append(name)
            continue
        m = _TMP_TAIL.fullmatch(tail)
        if m and os.path.abspath(parent / name) not in _in_use and not _pid_alive(int(m.group(1))):
            _remove(parent / name)
            done.append(name)
    return done


def _remove(p: Path) -> None:
    """Remove a folder tree, a file or a link (never followed); errors are ignored."""
    try:
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
    except OSError:
        pass


def _clean_and_say(path: Path, folder: bool) -> None:
    done = clean_leftovers(path, folder)
    if done:
        shown = ", ".join(done[:3]) + (f" and {len(done) - 3} more" if len(done) > 3 else "")
        warnings.warn(f"{path}: cleaned up after an interrupted run: {shown}", LeftoverWarning, stacklevel=4)


def _tmp_prefix(path: Path) -> str:
    return f".{path.name}.{os.getpid()}."


def _name_the_output(exc: BaseException, path: Path) -> None:
    """An OSError without a file name (a write that filled the disk) names the output it was for."""
    if isinstance(exc, OSError) and exc.filename is None and exc.errno is not None:
        exc.filename = str(path)


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """Hold SIGINT, SIGTERM and SIGHUP back for the ``with`` block (main thread, POSIX); one that
    arrives meanwhile is delivered when it ends."""
    held = [getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n)]
    if not hasattr(signal, "pthread_sigmask") or threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


# ------------------------------------------------------------------ files


@contextlib.contextmanager
def atomic_path(path: str | Path, wait: float | None = None) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; rename it onto ``path`` on success.

    Holds the output lock of ``path`` throughout (``wait``: see :func:`output_lock`).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with output_lock(path, wait):
        _clean_and_say(path, folder=False)
        tmp_path = None
        try:
            with _signals_held():  # a signal between making the temporary and naming it here would leak it
                fd, tmp = tempfile.mkstemp(prefix=_tmp_prefix(path), suffix=".tmp", dir=path.parent)
                os.close(fd)
                tmp_path = Path(tmp)
                _in_use.add(os.path.abspath(tmp))
            yield tmp_path
            os.chmod(tmp_path, FILE_MODE & ~process_umask())
            signals.reraise_if_interrupted()  # a signal a library swallowed: never commit that run
            os.replace(tmp_path, path)
        except BaseException as exc:
            if tmp_path is not None:
                tmp_path.unlink(missing_ok=True)
            _name_the_output(exc, path)
            raise
        finally:
            if tmp_path is not None:
                _in_use.discard(os.path.abspath(tmp_path))


def atomic_write_text(path: str | Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


# ------------------------------------------------------------------ folders


@contextlib.contextmanager
def atomic_dir(path: str | Path, wait: float | None = None) -> Iterator[Path]:
    """Build a whole output folder under a temporary name, then swap it in.

    An existing folder at ``path`` is replaced only after the new one is complete, in one
    exchange where the filesystem allows (see the module docstring). Holds the output lock of
    ``path`` throughout (``wait``: see :func:`output_lock`).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with output_lock(path, wait):
        _clean_and_say(path, folder=True)
        tmp = None
        try:
            with _signals_held():  # a signal between making the temporary and naming it here would leak it
                tmp = Path(tempfile.mkdtemp(prefix=_tmp_prefix(path), suffix=".tmp", dir=path.parent))
                _in_use.add(os.path.abspath(tmp))
            os.chmod(tmp, DIR_MODE & ~process_umask())
            yield tmp
            signals.reraise_if_interrupted()  # a signal a library swallowed: never commit that run
            _commit_dir(tmp, path)
        except BaseException as exc:
            if tmp is not None:
                shutil.rmtree(tmp, ignore_errors=True)
            _name_the_output(exc, path)
            raise
        finally:
            if tmp is not None:
                _in_use.discard(os.path.abspath(tmp))


def _commit_dir(new: Path, path: Path) -> None:
    """Put the complete folder ``new`` at ``path``; what was there (if anything) is removed after."""
    if not os.path.lexists(path):
        os.replace(new, path)
    elif exchange(new, path):  # ``new`` now names the old folder (or file, or link)
        _remove(new)
    else:
        old = path.with_name(f".{path.name}.old")
        _remove(old)
        os.replace(path, old)
        try:
            os.replace(new, path)
        except BaseException:
            os.replace(old, path)  # put the old one back
            raise
        _remove(old)


@functools.cache
def _renameat2():
    if not sys.platform.startswith("linux"):
        return None
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):  # glibc < 2.28, other libcs
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    fn.restype = ctypes.c_int
    return fn


_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


def exchange(a: str | Path, b: str | Path) -> bool:
    """Swap the names ``a`` and ``b`` (both must exist) in one step; False when unsupported here."""
    fn = _renameat2()
    if fn is None:
        return False
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in _UNSUPPORTED:
        return False
    raise OSError(err, os.strerror(err), str(b))
