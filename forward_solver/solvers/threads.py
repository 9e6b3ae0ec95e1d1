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
"""

from __future__ import annotations

import contextvars
import os
import queue
import threading

__all__ = ["each", "helpers"]

_LOCK = threading.Lock()
_QUEUE: queue.SimpleQueue | None = None


def helpers() -> int:
    """Threads `each` adds to the caller: one where this process may run on a second core, else none."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # (not Linux)
        cores = os.cpu_count() or 1
    return 1 if cores > 1 else 0


def _helper() -> queue.SimpleQueue:
    """The helper thread's queue of tasks (the thread started on first use)."""
    global _QUEUE
    with _LOCK:
        if _QUEUE is None:
            tasks = queue.SimpleQueue()
            threading.Thread(target=_serve, args=(tasks,), name="bay-helper", daemon=True).start()
            _QUEUE = tasks
        return _QUEUE


def _serve(tasks: queue.SimpleQueue) -> None:
    while True:
        tasks.get()()


def each(function, count: int) -> list:
    """``[function(k) for k in range(count)]``, the items shared by the caller and the helper thread.

    The helper runs its items in a copy of the caller's context (its context
    variables); a thread-local setting (JAX's ``enable_x64``) is the item's
    own to make. An item's exception is raised here once both threads have
    stopped, and no item is begun after it or after the caller itself is
    interrupted. Without a second core, the caller runs every item.
    """
    if count < 2 or helpers() == 0:
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
