"""Signals as exceptions, so a run stopped by Ctrl-C, ``kill`` (SIGTERM) or a closed terminal
(SIGHUP) unwinds like an error: every ``with`` block removes its temporary and releases its lock,
and the command exits 130 / 143 / 129 with one line.

:func:`interrupted` says whether such a signal has arrived in this process: a library that turns
the ``KeyboardInterrupt`` raised inside its own import into an ``ImportError`` (Open3D's pybind
module does: "initialization failed") must not make the run carry on without it.
"""

from __future__ import annotations

import signal
import threading

_received: list[int] = []


class Stopped(BaseException):
    """A run stopped by SIGTERM or SIGHUP (a BaseException: ``except Exception`` does not catch it)."""

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(signal.Signals(signum).name)


def _handler(signum, frame):
    _received.append(signum)
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Stopped(signum)


def _record_sigint(signum, frame):
    _received.append(signum)
    raise KeyboardInterrupt


def record_early() -> None:
    """Remember a SIGINT from the first import of the command line on (it still raises
    KeyboardInterrupt, as Python's own handler does): a library that turns it into an ImportError
    while egograph's modules import cannot make the run go on. Only where Python's own handler is
    in place, in the main thread."""
    if threading.current_thread() is threading.main_thread() and \
            signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _record_sigint)


def install() -> dict:
    """Raise on SIGINT, SIGTERM and SIGHUP in the main thread (no-op elsewhere); the handlers it
    replaced, for :func:`restore`. A signal ignored by the parent (``nohup``) stays ignored."""
    previous = {}
    if threading.current_thread() is not threading.main_thread():
        return previous
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is None:
            continue
        old = signal.getsignal(sig)
        if old is signal.SIG_IGN or old is None:
            continue
        previous[sig] = old
        signal.signal(sig, _handler)
    return previous


def restore(previous: dict) -> None:
    """Put back the handlers :func:`install` replaced; forget the signals received (the run is over)."""
    for sig, old in previous.items():
        signal.signal(sig, old)
    _received.clear()


def interrupted() -> int | None:
    """The first stopping signal this process received since :func:`install`, or None."""
    return _received[0] if _received else None


def reraise_if_interrupted() -> None:
    """Re-raise a signal a library swallowed (call it where an ImportError is caught)."""
    sig = interrupted()
    if sig == signal.SIGINT:
        raise KeyboardInterrupt
    if sig is not None:
        raise Stopped(sig)


def exit_code(signum: int) -> int:
    return 128 + int(signum)
