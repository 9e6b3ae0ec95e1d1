"""Stop requests (Ctrl-C, SIGTERM) that cannot be lost: recorded, raised, and raised again at safe points.

Python runs a signal handler between two bytecodes of the main thread,
wherever that is. When that is inside a garbage-collection callback (JAX
registers ``_xla_gc_callback``), a ``__del__`` method or a weak-reference
callback, the exception the handler raises is printed as "Exception ignored
in ..." and lost, and the run goes on. So the handlers that `install`
puts in place first *record* the signal, then raise (`Terminated` for
SIGTERM, `KeyboardInterrupt` for SIGINT); `check`, called at safe points (each
optimiser iterate, before a report is written, before its folder is moved
into place), raises it again if it was recorded. A swallowed exception thus
delays the stop to the next safe point, never past the writing of a folder.
`install` also silences the "Exception ignored" report of a swallowed stop,
so that the run ends with one line.

Nothing is installed at import, and `check` does nothing unless `install`
ran (library callers keep Python's own handling).
"""

from __future__ import annotations

import signal
import sys
import threading
from contextlib import contextmanager

__all__ = ["Terminated", "check", "deferred", "install", "received", "restore"]


class Terminated(KeyboardInterrupt):
    """SIGTERM received while the handlers of `install` are in place: unwinds like Ctrl-C."""


_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_received: int | None = None  # the first signal received since `install`
_deferring = 0  # > 0 inside `deferred`: signals are only recorded


def _exception(signum: int) -> KeyboardInterrupt:
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def _handler(signum, frame):
    global _received
    if _received is None:
        _received = signum
    if not _deferring:
        raise _exception(signum)


def _unraisable(previous):
    """A ``sys.unraisablehook`` that drops a swallowed stop (recorded already) and passes the rest on."""

    def hook(unraisable):
        if isinstance(unraisable.exc_value, KeyboardInterrupt) and _received is not None:
            return
        previous(unraisable)

    return hook


def install():
    """Put the recording handlers of SIGINT and SIGTERM in place; returns what `restore` takes back.

    Only from the main thread (where Python runs signal handlers); elsewhere
    nothing changes and None is returned. Clears any earlier record.
    """
    global _received
    if threading.current_thread() is not threading.main_thread():
        return None
    _received = None
    previous = {s: signal.getsignal(s) for s in _SIGNALS}
    for s in _SIGNALS:
        signal.signal(s, _handler)
    hook = sys.unraisablehook
    sys.unraisablehook = _unraisable(hook)
    return previous, hook


def restore(state) -> None:
    """Put back the handlers (and unraisable hook) that `install` replaced, and clear the record."""
    global _received
    if state is None:
        return
    previous, hook = state
    for s, handler in previous.items():
        signal.signal(s, signal.SIG_DFL if handler is None else handler)  # None: installed outside Python
    sys.unraisablehook = hook
    _received = None


def received() -> int | None:
    """The signal number recorded since `install` (None if none)."""
    return _received


def check() -> None:
    """A safe point: raise the recorded stop (`Terminated` or `KeyboardInterrupt`), if any.

    Does nothing inside `deferred`, or when no signal was recorded.
    """
    if _received is not None and not _deferring:
        raise _exception(_received)


@contextmanager
def deferred():
    """A section that must not be cut short (moving a finished folder into place).

    A stop recorded before it is raised on entry (`check`); one that arrives
    inside it is only recorded, and raised at the next `check` after it.
    """
    global _deferring
    check()
    _deferring += 1
    try:
        yield
    finally:
        _deferring -= 1
