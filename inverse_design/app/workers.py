"""Writing a report's figures and DXF and SVG patterns in worker processes while the design runs.

Saving a figure (``Figure.savefig``: the layout engine, the Agg rasteriser,
the PNG encoder) and drawing a DXF pattern are Python-bound work that holds
Python's lock, so threads would not overlap them; and importing matplotlib
and ezdxf takes a process a few tenths of a second. `ReportWorkers` is a
standard-library pool of processes (`multiprocessing` with the ``spawn``
start method: fresh interpreters, nothing of the caller's JAX runtime or
threads inherited) started when the command starts: each worker imports the
report's libraries while the design runs, on idle cores only (Linux's
``SCHED_IDLE`` policy, given up once imported, so that a task runs at the
caller's priority: measured on the 2-core development machine, the imports
at normal priority slowed the cold default case by about 15%), then writes whole files from *tasks* ``(path, function, args,
kwargs)``: a module-level function (pickled by name) called as
``function(path, *args, **kwargs)`` with picklable arguments: NumPy arrays,
or a `matplotlib.figure.Figure` that the caller built (`save_figure`). No
task calls JAX, and a worker imports neither JAX nor the solver (the
``inverse_design`` package imports its submodules on first use): on the
2-core development machine that is about 1.2 s less CPU per worker, which
the worker spent while the design ran.

The result never depends on the workers. Each task is taken once, by a
worker (from the first) or by the caller (from the last): a shared flag per
task (`multiprocessing.Array`) says who took it. `ReportWorkers.finish`
runs in the caller every task that no worker has taken (workers still
importing, or starved by a busy machine, hold nobody up), waits at most
`WORKER_TIMEOUT_S` for the workers' own, stops the pool and returns the
tasks done; the caller writes the rest itself (`run_task`). A stop
(Ctrl-C, SIGTERM) unwinds the caller, whose `ReportWorkers.close` stops
the workers before the staging folder is removed. The workers leave the
caller's process group as they start (POSIX), so that a signal sent to the
group (a terminal's Ctrl-C, GNU ``timeout``'s SIGTERM, ``kill -TERM
-PGID``) reaches the caller alone: a worker killed by it while it waited for
a task held the task queue's lock, and the pool's termination then waited
for that lock for ever (the command printed its stop line and hung). Out of
the group, a worker ends when the caller does (`PARENT_POLL_S`); it also
ignores SIGINT.

Used by the ``optimise-pressure`` command for its report (one bay or a wing)
(`inverse_design.app.folder.write_report` takes its ``workers``); a library
caller writes every file in its own process (the same files either way).
"""

from __future__ import annotations

import gc
import multiprocessing
import os
import pickle
import signal
import threading
import time
from contextlib import contextmanager

__all__ = ["ANSWER_WAIT_S", "DRAWING_MODULES", "FIGURE_MODULES", "MAX_TASKS", "MAX_WORKERS", "PARENT_POLL_S",
           "REPORT_MODULES", "WORKER_MODULES", "WORKER_TIMEOUT_S", "ReportWorkers", "report_modules", "run_task",
           "save_figure", "saved_after", "worker_modules"]

#: The libraries of the report's figures (PNG) and of its DXF and SVG files (patterns, marker).
FIGURE_MODULES = ("matplotlib.figure", "matplotlib.backends.backend_agg")
DRAWING_MODULES = ("ezdxf",)
#: The report's libraries, imported ahead by the command's run (`run`) and by the workers.
REPORT_MODULES = (*FIGURE_MODULES, *DRAWING_MODULES)
#: What the report's workers (`workers.ReportWorkers`) import while the design runs: the libraries of
#: the figures and of the DXF and SVG patterns they write, and the modules their tasks name
#: (`worker_modules`: a report without figures or without patterns imports less).
WORKER_MODULES = (*REPORT_MODULES, "inverse_design.app.cut_files")


def report_modules(figures: bool, drawings: bool) -> tuple:
    """The part of `REPORT_MODULES` that a report of ``figures`` and of ``drawings`` (DXF, SVG) uses."""
    return (FIGURE_MODULES if figures else ()) + (DRAWING_MODULES if drawings else ())


def worker_modules(figures: bool, patterns: bool) -> tuple:
    """The part of `WORKER_MODULES` that a report's workers need to save its ``figures`` and write its
    ``patterns``: none (no worker to start) for a report of neither."""
    modules = report_modules(figures, patterns)
    return (*modules, "inverse_design.app.cut_files") if patterns else modules


#: Seconds `ReportWorkers.finish` waits for the workers' tasks; then the caller writes what is left. A
#: figure takes about 0.3 s: only a hang reaches this.
WORKER_TIMEOUT_S = 60.0
#: Seconds `ReportWorkers.finish` waits for a worker to answer the tasks the caller ran (a worker
#: still importing takes longer: the pool is then collected, `ReportWorkers.close`).
ANSWER_WAIT_S = 0.1
#: Most workers started (one per core beyond the caller's, at least one).
MAX_WORKERS = 2
#: Seconds between a worker's looks at its parent: out of the caller's process group, it ends when the
#: caller has ended (a SIGKILL of the caller, or of its group, no longer reaches it).
PARENT_POLL_S = 0.5


def _cores() -> int:
    """The cores this process may run on (its affinity, which a container or ``taskset`` narrows)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


#: Most tasks one `ReportWorkers` takes (a single bay's report hands over five figures, four DXF and two
#: SVG files, a 40-bay wing's its figures, 121 DXF and 80 SVG files); more are left to the caller.
MAX_TASKS = 512
_CLAIMED = None  # in a worker: the pool's shared claims (`multiprocessing.Array`), one flag per task


def _initialise(modules: tuple, claimed) -> None:
    """A worker's start: out of the caller's process group and SIGINT ignored (the caller stops the pool:
    module docstring), ``modules`` imported."""
    import importlib

    global _CLAIMED
    _CLAIMED = claimed
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(os, "setpgid"):
        parent = os.getppid()
        os.setpgid(0, 0)
        threading.Thread(target=_end_with, args=(parent,), name="watch-parent", daemon=True).start()
    idle = _schedule(getattr(os, "SCHED_IDLE", None))  # (the imports on idle cores only: module docstring)
    for name in modules:
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001 - a task that needs it fails, and the caller writes its file
            pass
    if idle:
        _schedule(os.SCHED_OTHER)


def _end_with(parent: int) -> None:
    """End this worker once its parent ``parent`` has (it is then another process's child)."""
    while os.getppid() == parent:
        time.sleep(PARENT_POLL_S)
    os._exit(0)


def _schedule(policy) -> bool:
    """Put this process under the scheduling ``policy`` (Linux); whether it was."""
    if policy is None or not hasattr(os, "sched_setscheduler"):
        return False
    try:
        os.sched_setscheduler(0, policy, os.sched_param(0))
    except OSError:
        return False
    return True


def _claim(claimed, k: int) -> bool:
    """Take task ``k`` unless another process has: whether this one did."""
    with claimed.get_lock():
        if claimed[k]:
            return False
        claimed[k] = 1
        return True


def _run_pickled(k: int, payload: bytes) -> bool:
    """A worker's task ``k``: run it if no one took it first; whether this worker ran it."""
    if not _claim(_CLAIMED, k):
        return False
    run_task(pickle.loads(payload))
    return True


class ReportWorkers:
    """Worker processes that import the report's libraries, then write files from tasks (module docstring).

    `start` returns None where no worker would help (one core). `submit` hands a batch of tasks
    over (or returns False: the caller writes them), `finish` waits for them
    and returns the indices of those done, `close` stops the workers (also
    unused ones; twice is harmless).
    """

    def __init__(self, pool, claimed):
        self._pool = pool
        self._claimed = claimed
        self._tasks: list = []  # every task handed over, in order
        self._results: list = []  # one `multiprocessing.pool.AsyncResult` per task handed over
        self.submitted = 0  # tasks handed over so far

    @classmethod
    def start(cls, modules=(), count: int | None = None) -> "ReportWorkers | None":
        """Start ``count`` workers (default one per core beyond this process's, at most `MAX_WORKERS`)
        that import ``modules`` while they wait; None where none would help (class docstring)."""
        if count is None:
            if _cores() < 2:
                return None
            count = max(1, min(_cores() - 1, MAX_WORKERS))
        context = multiprocessing.get_context("spawn")
        try:
            claimed = context.Array("b", MAX_TASKS)
            pool = context.Pool(int(count), _initialise, (tuple(modules), claimed))
        except OSError:  # (no processes to be had: the caller writes every file)
            return None
        return cls(pool, claimed)

    def submit(self, tasks: list) -> bool:
        """Hand ``tasks`` (module docstring) to the workers, numbered after the earlier ones (`finish`
        returns those indices). Returns False, handing nothing, if a task does not pickle or the
        workers are closed (the caller runs them itself)."""
        if self._pool is None or not tasks or self.submitted + len(tasks) > MAX_TASKS:
            return False
        try:
            payloads = [pickle.dumps((str(path), function, tuple(args), dict(kwargs)),
                                     protocol=pickle.HIGHEST_PROTOCOL) for path, function, args, kwargs in tasks]
        except (pickle.PicklingError, TypeError, AttributeError):
            return False
        self._results += [self._pool.apply_async(_run_pickled, (self.submitted + k, payload))
                          for k, payload in enumerate(payloads)]
        self._tasks += tasks
        self.submitted += len(tasks)
        return True

    def finish(self, timeout: float = WORKER_TIMEOUT_S) -> set:
        """Run here, from the last, every task that no worker has taken; wait for the workers' (at
        most ``timeout`` s in all); stop the workers; return the indices of the tasks done (here or
        by a worker). The caller runs the rest itself."""
        deadline = time.monotonic() + timeout
        done = set()
        for k in reversed(range(len(self._tasks))):  # (the workers take them from the first)
            if _claim(self._claimed, k):
                run_task(self._tasks[k])
                done.add(k)
        for k, result in enumerate(self._results):
            if k in done:
                continue
            result.wait(max(0.0, deadline - time.monotonic()))
            if result.ready() and result.successful():
                done.add(k)
        # A free worker answers the tasks run here at once (it finds them taken): waited for briefly,
        # so that the pool can end without a collection (`close`).
        answer_deadline = time.monotonic() + ANSWER_WAIT_S
        for result in self._results:
            result.wait(max(0.0, answer_deadline - time.monotonic()))
        answered = all(result.ready() for result in self._results)
        result = None  # (the last result holds the pool)
        self.close(answered=answered)
        return done

    def close(self, answered: bool = False) -> None:
        """Stop the workers (a task still running is killed, its file left to the caller) and wait
        for them to exit. The pool's semaphores are released when the pool goes: now, not at the
        interpreter's exit, which the command skips. A task's unanswered result and the pool refer
        to each other, so unless every task is ``answered`` (`finish`), the pool is collected here
        (a full collection: 0.13 s at the end of the default case's report)."""
        if self._pool is not None:
            pool, self._pool = self._pool, None
            pool.terminate()
            pool.join()
            del pool
            self._claimed, self._results, self._tasks = None, [], []
            if not answered:
                gc.collect()


def run_task(task) -> None:
    """Run one task ``(path, function, args, kwargs)`` here: ``function(path, *args, **kwargs)``."""
    path, function, args, kwargs = task
    function(path, *args, **kwargs)


def save_figure(path, figure, **options) -> None:
    """A figure task's function: ``figure.savefig(path, **options)`` (a `matplotlib.figure.Figure`,
    built by the caller and pickled: the worker imports matplotlib only, not the package's solver).

    A figure with a layout engine (the report's are constrained) saved at a given ``dpi`` is laid out
    once, at that dpi, and saved without the engine: ``savefig`` would run the layout twice, in a
    draw without rendering and again in the drawn one, for the same pixels (the same PNG files to the
    byte for the default case's five figures; saving them took 14% less, 2026-11-30, 2-core machine).
    """
    engine = figure.get_layout_engine()
    dpi = options.get("dpi")
    if engine is not None and isinstance(dpi, (int, float)) and "bbox_inches" not in options:
        from matplotlib import rc_context  # (loaded with the figure's own module: only where figures are saved)

        figure.set_dpi(dpi)
        engine.execute(figure)
        with rc_context({"figure.autolayout": False, "figure.constrained_layout.use": False}):
            figure.set_layout_engine(None)  # (None: no engine, so no draw before the drawn one)
    figure.savefig(path, **options)


@contextmanager
def saved_after(figures, save):
    """A block whose end saves ``figures`` (``(path, figure)`` pairs) with ``save(figure, path)``: the
    caller writes its other files inside it. An exception leaving the block saves none."""
    yield
    for path, figure in figures:
        save(figure, path)
