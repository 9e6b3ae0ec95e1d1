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

The command's work runs on a thread of its own (`run_stoppable`), so that the
main thread is always free to take a signal: Python runs handlers only on the
main thread, between two of its bytecodes, and a main thread inside a long
compiled call (XLA, LAPACK, SciPy's SLSQP) would run none until the call
returned (more than a minute on a 40-bay wing). The main thread waits for the
work; on a stop the work raises it at its next safe point and unwinds (its
staging folder removed); if it does not within `UNWIND_GRACE_S`, the work is
*abandoned*: what it registered with `undo_if_abandoned` (its staging folder,
its lock file) is undone at once, its own later safe points raise the stop,
and the command ends (`abandoned`). A work inside `deferred` (a finished folder
moving into place) is waited for instead: the folder is then complete.

Whether the main thread can take the signal while the work computes depends
on the call releasing Python's lock (GIL). Measured on the 2-core development
machine (`benchmarks.signal_latency`: a thread in the call, the main thread
waking every 10 ms): NumPy's and SciPy's LAPACK, SuperLU, XLA's compiled calls
and its compiler release it (at a load of 9 the main thread waited at most
4 ms; at 13-18, 40-650 ms: the wait for a core); SciPy 1.17's SLSQP holds it
through each of its native steps, between its calls of the objective: with
500 variables (a 40-bay wing's cut field per bay) 0.3 s at a load of 9 and
2.3 s at 13-18, with 1000 variables 2.3 s and 8.3 s (the designs' constraints
are a few smooth aggregates, so the variables set the cost). A stop inside
such a step waits for it: the command's work could run in a child process
instead, but the console script's module imports JAX (3.3 s) and the child
would import it again and pickle the result back, on every run.

Nothing is installed at import, and `check` does nothing unless `install`
ran (library callers keep Python's own handling).
"""

from __future__ import annotations

import itertools
import signal
import sys
import threading
from contextlib import contextmanager

__all__ = ["UNWIND_GRACE_S", "Terminated", "abandoned", "check", "deferred", "hold", "install", "received",
           "restore", "run_stoppable", "undo_if_abandoned"]

#: Seconds a stopped work has to unwind by itself (to its next safe point) before `run_stoppable`
#: abandons it: a stop must end the command within 2 s.
UNWIND_GRACE_S = 1.0
#: Seconds the main thread sleeps between two looks at the work (a signal wakes it earlier).
_POLL_S = 0.1


class Terminated(KeyboardInterrupt):
    """SIGTERM received while the handlers of `install` are in place: unwinds like Ctrl-C."""


_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_received: int | None = None  # the first signal received since `install`
_installed = False  # whether the handlers of `install` are in place
_deferring = 0  # > 0 inside `deferred`: signals are only recorded
_stopping = False  # True while `run_stoppable` handles a stop: further signals are only recorded
_gave_up = False  # whether a work was abandoned since `install`
_abandoned: set[object] = set()  # the tokens of the works that `run_stoppable` abandoned
_undo: dict[int, tuple[object, object]] = {}  # `undo_if_abandoned`'s actions: key -> (work's token, action)
_local = threading.local()  # ``work``: the token of the `run_stoppable` work this thread runs
_keys = itertools.count()


def _exception(signum: int) -> KeyboardInterrupt:
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def _handler(signum, frame):
    global _received
    if _received is None:
        _received = signum
    if not (_deferring or _stopping):
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
    global _received, _installed, _gave_up
    if threading.current_thread() is not threading.main_thread():
        return None
    _received = None
    _installed = True
    _gave_up = False
    previous = {s: signal.getsignal(s) for s in _SIGNALS}
    for s in _SIGNALS:
        signal.signal(s, _handler)
    hook = sys.unraisablehook
    sys.unraisablehook = _unraisable(hook)
    return previous, hook


def hold() -> None:
    """From now until `restore`, a stop is only recorded (`received`), never raised: the command's end,
    once its report is complete, where a stop must neither cut the output short nor be lost."""
    global _deferring
    _deferring += 1


def received() -> int | None:
    """The first signal recorded since `install` (``signal.SIGINT`` or ``SIGTERM``), or None."""
    return _received


def restore(state) -> None:
    """Put back the handlers (and unraisable hook) that `install` replaced, and clear the record."""
    global _received, _installed, _deferring
    if state is None:
        return
    previous, hook = state
    for s, handler in previous.items():
        signal.signal(s, signal.SIG_DFL if handler is None else handler)  # None: installed outside Python
    sys.unraisablehook = hook
    _received = None
    _installed = False
    _deferring = 0


def check() -> None:
    """A safe point: raise the recorded stop (`Terminated` or `KeyboardInterrupt`), if any.

    Does nothing inside `deferred`, or when no signal was recorded; in a work
    that `run_stoppable` abandoned it always raises (the caller has moved on).
    """
    if getattr(_local, "work", None) in _abandoned:
        raise Terminated()
    if _received is not None and not _deferring:
        raise _exception(_received)


def abandoned() -> bool:
    """Whether a `run_stoppable` work was abandoned since `install` (it may still be computing: the
    command ends its process at once, without waiting for it or for JAX's teardown)."""
    return _gave_up


@contextmanager
def undo_if_abandoned(action):
    """A block whose work, if `run_stoppable` abandons it meanwhile, is undone by ``action()`` (called
    from the main thread: e.g. removing a staging folder, a lock file). Nothing is called otherwise."""
    key = next(_keys)
    _undo[key] = (getattr(_local, "work", None), action)
    try:
        yield
    finally:
        _undo.pop(key, None)


def run_stoppable(function, *args, **kwargs):
    """``function(*args, **kwargs)`` on a thread of its own while this (main) thread waits, free to
    take signals; returns its value or raises its exception (module docstring).

    On a stop (the handlers of `install` raise in this thread, or a signal
    was recorded): the work raises it at its next safe point (`check`); if
    it has ended within `UNWIND_GRACE_S`, this raises the stop (or returns
    the work's value if it finished its report meanwhile: a later `check`
    then says so). A work inside `deferred` is waited for to the end of it.
    Otherwise the work is abandoned: its `undo_if_abandoned` actions run here
    and the stop is raised (`abandoned` is then true). Called from another
    thread than the main one, or without `install`, it calls ``function``
    directly.
    """
    global _stopping
    if threading.current_thread() is not threading.main_thread() or not _installed:
        return function(*args, **kwargs)
    outcome, done, token = {}, threading.Event(), object()

    def work():
        _local.work = token
        try:
            outcome["value"] = function(*args, **kwargs)
        except BaseException as exc:  # noqa: BLE001 - handed to the main thread
            outcome["error"] = exc
        finally:
            _abandoned.discard(token)
            done.set()

    # (An Event, not `Thread.join`: a join that a handler's exception cuts short marks the thread
    # as ended while it still runs.)
    thread = threading.Thread(target=work, name="optimise-pressure", daemon=True)
    try:
        thread.start()
        while not done.wait(_POLL_S) and _received is None:
            pass
    except KeyboardInterrupt:  # a signal's handler raised it here
        pass
    finally:
        _stopping = True
    try:
        if not done.is_set():  # a stop: the work unwinds at its next safe point, or is abandoned
            done.wait(UNWIND_GRACE_S)
            while not done.is_set() and _deferring:  # (a finished folder moving into place)
                done.wait(_POLL_S)
            if not done.is_set():
                _abandon(token)
                if done.is_set():  # (it ended meanwhile)
                    _abandoned.discard(token)
                raise _exception(_received)
        if "error" in outcome:
            if _received is not None:
                raise _exception(_received) from None
            raise outcome["error"]
        return outcome["value"]
    finally:
        _stopping = False
        outcome.clear()


def _abandon(token: object) -> None:
    """Mark the work ``token`` abandoned and run its undo actions (newest first)."""
    global _gave_up
    _abandoned.add(token)
    _gave_up = True
    for key in sorted((k for k, (work, _) in list(_undo.items()) if work is token), reverse=True):
        _, action = _undo.pop(key, (None, None))
        if action is not None:
            try:
                action()
            except OSError:  # (what cannot be removed stays, as after a SIGKILL: the next run cleans up)
                pass


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
