"""Compiling ahead: the programs a cold solve needs next, compiled on a second thread meanwhile.

JAX compiles one program at a time, on the thread that first calls it, and
a cold solve calls its programs one after another: the relaxation of each
grid-sequencing level (`solvers.sequencing.sequenced_start`), then Newton's residual and
Jacobian (`newton`). XLA's compiler releases Python's lock, so on a machine
with a second core the later programs can compile while the first one
compiles and runs. `Ahead` is that: a single worker thread that lowers and
compiles (``jitted.lower(...).compile()``, which fills the same in-process
cache as a call) or runs a short warm-up, in the order given; the solve
waits for a task only when it reaches the program the task prepares
(`Ahead.ready`), and a task not yet begun is cancelled and left to the
solve itself. Each task is keyed, so that a process prepares a program once
(a wing's forty bays on one grid share one compilation).

Nothing is computed ahead that the solve would not compute, and a task that
fails is dropped (the solve compiles the program itself and meets the same
error there, with its own message). Off on a single core, and switchable
(`set_compile_ahead`); the worker starts on the first task, never at import.
What it saves is measured by ``benchmarks/compilation.py`` (docs/performance.md).
"""

from __future__ import annotations

import concurrent.futures
import os
import threading

import jax

__all__ = ["set_compile_ahead", "compiling", "signature", "Ahead"]

_ENABLED = (os.cpu_count() or 1) > 1
_LOCK = threading.Lock()
_EXECUTOR = None
_SUBMITTED: set = set()


def set_compile_ahead(enabled: bool) -> bool:
    """Turn compiling ahead on or off for this process; returns the previous setting."""
    global _ENABLED
    previous, _ENABLED = _ENABLED, bool(enabled)
    return previous


def _executor():
    global _EXECUTOR
    with _LOCK:
        if _EXECUTOR is None:
            _EXECUTOR = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="compile-ahead")
        return _EXECUTOR


def _run(task):
    with jax.enable_x64(True):  # as the solve's own float64 scope (thread-local)
        try:
            task()
        except Exception:  # noqa: BLE001 - speculative: the solve meets any error itself
            return False
    return True


def compiling(jitted, *args, **kwargs):
    """A task that compiles ``jitted`` for ``args`` (``jitted.lower(...).compile()``: the program a
    call with arguments of the same shapes, types and static values then takes)."""
    def task():
        jitted.lower(*args, **kwargs).compile()
    return task


def signature(*trees) -> tuple:
    """A hashable key of the avals of ``trees`` (structure, and shape, dtype and weak type of each
    array leaf; other leaves as they are): what decides which compiled program a call takes."""
    leaves, treedef = jax.tree_util.tree_flatten(trees)
    return (str(treedef),) + tuple(
        (tuple(leaf.shape), str(leaf.dtype), bool(getattr(leaf, "weak_type", False)))
        if hasattr(leaf, "shape") and hasattr(leaf, "dtype") else leaf for leaf in leaves)


class Ahead:
    """The tasks one solve submitted; a context manager that cancels those not begun at its end.

    Usage::

        with Ahead() as ahead:
            fine = ahead.submit(key, lambda: relax_jit.lower(...).compile())
            ...                      # work on the first program meanwhile
            ahead.ready(fine)        # then wait for it (or take it over) before calling it
    """

    def __init__(self):
        self.submitted = []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        # What has not begun is dropped; what has is waited for, so that no work of this solve is
        # left running after it (a failed solve may skip a program it had prepared).
        begun = [future for key, future in self.submitted if not _cancel(key, future)]
        concurrent.futures.wait(begun)
        return False

    def submit(self, key, task):
        """Run ``task()`` (float64 on) on the worker unless ``key`` was submitted before in this
        process or compiling ahead is off; returns a handle for `ready`, or None."""
        if not _ENABLED:
            return None
        with _LOCK:
            if key in _SUBMITTED:
                return None
            _SUBMITTED.add(key)
        future = _executor().submit(_run, task)
        self.submitted.append((key, future))
        return key, future

    @staticmethod
    def ready(handle) -> None:
        """Before calling the program ``handle`` prepares: wait for its task if it has begun (or is
        done), else cancel it (the caller compiles the program itself)."""
        if handle is not None and not _cancel(*handle):
            concurrent.futures.wait([handle[1]])


def _cancel(key, future) -> bool:
    """Cancel a task not yet begun (its key may be submitted again); whether it was cancelled."""
    if not future.cancel():
        return False
    with _LOCK:
        _SUBMITTED.discard(key)
    return True
