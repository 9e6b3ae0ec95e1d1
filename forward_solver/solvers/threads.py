"""Independent host work two at a time: the caller and one helper thread (`each`).

A wing's warm bay solves are independent of one another, and most of each is
native code that releases Python's lock: SuperLU's factorisations and
back-solves, XLA's compiled residual and Jacobian. On a machine with a second
core, `each` shares such items between the calling thread and one helper
thread, so that one bay's LU runs while the other's Jacobian is computed
(`bays.Loop`; docs/architecture.md). The helper is one daemon thread, started
on the first call that can use it (never at import) and kept for the
process: it takes nothing from a stopped caller beyond the item it is in, and
never holds up the interpreter's exit.

The results are those of the items run one by one: each item is computed
whole by one thread, from the same inputs; which thread runs it does not
enter it.

SciPy's SuperLU (1.17) frees a factor's memory only on the thread that
allocated it: a factor made on the helper and dropped on another thread
leaked all of it (a 2000x2000 factor: 14 MB each time) and left an error
behind that made the interpreter's exit fail (status 120). So what the
helper makes and must also free there is kept by it (`keep`: the caller
holds a key, `kept` looks the value up) and dropped on it (`release`), and
at the interpreter's exit the helper drops what it still keeps.
"""

from __future__ import annotations

import atexit
import contextvars
import itertools
import os
import queue
import threading

__all__ = ["each", "helpers", "keep", "kept", "on_helper", "release"]

_LOCK = threading.Lock()
_QUEUE: queue.SimpleQueue | None = None
_HELPER: int | None = None  # the helper thread's ident
_KEPT: dict = {}  # key -> what the helper made and keeps (`keep`)
_KEYS = itertools.count()
_CLOSED = False  # (the interpreter's exit: the helper keeps nothing more)


def helpers() -> int:
    """Threads `each` adds to the caller: one where this process may run on a second core, else none."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # (not Linux)
        cores = os.cpu_count() or 1
    return 1 if cores > 1 else 0


def _helper() -> queue.SimpleQueue:
    """The helper thread's queue of tasks (the thread started on first use)."""
    global _QUEUE, _HELPER
    with _LOCK:
        if _QUEUE is None:
            tasks = queue.SimpleQueue()
            thread = threading.Thread(target=_serve, args=(tasks,), name="bay-helper", daemon=True)
            thread.start()
            _QUEUE, _HELPER = tasks, thread.ident
            atexit.register(_close)
        return _QUEUE


def _serve(tasks: queue.SimpleQueue) -> None:
    while True:
        task = tasks.get()
        task()
        del task  # (what it held is dropped here, on this thread)


def on_helper() -> bool:
    """Whether this is the helper thread."""
    return _HELPER is not None and threading.get_ident() == _HELPER


def keep(value) -> int:
    """On the helper thread: keep ``value`` there; returns its key for `kept` and `release`."""
    key = next(_KEYS)
    _KEPT[key] = value
    return key


def kept(key: int):
    """What `keep` keeps under ``key`` (any thread)."""
    return _KEPT[key]


def release(key: int) -> None:
    """Drop what `keep` keeps under ``key``, on the helper thread (any thread may ask; nothing at exit)."""
    if not _CLOSED and _QUEUE is not None:
        _QUEUE.put(lambda: _KEPT.pop(key, None))


def _close() -> None:
    """At the interpreter's exit: the helper drops all it keeps, on its own thread (at most 5 s)."""
    global _CLOSED
    done = threading.Event()

    def drop():
        _KEPT.clear()
        done.set()

    _QUEUE.put(drop)
    done.wait(5.0)
    _CLOSED = True


def each(function, count: int) -> list:
    """``[function(k) for k in range(count)]``, the items shared by the caller and the helper thread.

    The helper runs its items in a copy of the caller's context (its context
    variables); a thread-local setting (JAX's ``enable_x64``) is the item's
    own to make. An item's exception is raised here once both threads have
    stopped, and no item is begun after it or after the caller itself is
    interrupted. Without a second core, or called from an item on the helper
    itself (which would wait for itself), the caller runs every item.
    """
    if count < 2 or helpers() == 0 or on_helper():
        return [function(k) for k in range(count)]
    results = [None] * count
    errors: list = []
    lock = threading.Lock()
    remaining = iter(range(count))

    def take():
        with lock:
            return None if errors else next(remaining, None)

    def work():
        while (k := take()) is not None:
            try:
                results[k] = function(k)
            except BaseException as error:  # noqa: BLE001 - raised in the caller, below
                with lock:
                    errors.append(error)

    done = threading.Event()
    context = contextvars.copy_context()

    def helper():
        try:
            context.run(work)
        finally:
            done.set()

    _helper().put(helper)
    try:
        work()
    finally:
        with lock:
            errors.append(None)  # (the helper begins no further item)
        done.wait()
    raised = [error for error in errors if error is not None]
    if raised:
        raise raised[0]
    return results
