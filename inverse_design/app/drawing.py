"""Writing a report's files on several cores: forked processes draw figures while the parent writes the rest.

Two ways. `ReportWorkers` are forked when the command starts and import the
report's libraries while the design runs; they then write whole files
(figures, DXF patterns) from picklable tasks (class docstring). `FigureSaver`,
below, forks one child after the caller has built its figures.

Saving a figure (``Figure.savefig``: the layout engine, the Agg rasteriser,
the PNG encoder) is Python-bound work that holds Python's lock, so threads
do not overlap it (README, "Compilation": four figures on two or four
threads, 1.20 -> 1.06-1.14 s). A second process does. `FigureSaver` forks
one child after the caller has built every figure: the child already holds
the figures and their data (no start-up, no pickling: the separate drawing
process measured before spent 1.1 s of CPU importing and unpickling, which
slowed the design's compilation), saves figures from the front of the list
and exits; the parent does the caller's other work (the report's npz, mesh
and pattern files) inside the ``with`` block, then saves figures from the
back. Each takes the next figure that neither has taken (`_Claims`), so the
two finish together whatever the mix of figures and other work (a single
bay: the child draws two or three of the four figures; a wing of forty bays,
whose patterns take seconds: the child draws both figures).

The result never depends on the child: on leaving the block the parent
waits for it (at most `CHILD_TIMEOUT_S` seconds, then kills it), and saves
again itself every figure of a child that did not exit with status 0 (an
error, a signal, the deadline), over whatever the child left in the file.
The parent's copy of such a figure was never drawn, so it saves the same
bytes as a serial run (a figure's second drawing can differ from its
first: constrained layout starts from the first one's result). An
exception leaving the block, KeyboardInterrupt included, kills and reaps
the child before it propagates, so no child writes into a folder that the
caller then removes, and none is left as a zombie.

Forking a process that runs JAX is safe *here*, though JAX warns against
it (the warning is silenced around this one fork): JAX's threads do not
exist in the child, so a child that called into JAX could wait forever on a
lock one of them held; this child never does. It only rasterises figures
that the parent built completely, from numpy data, resets SIGINT and SIGTERM
to their defaults (a Ctrl-C, sent to the whole process group, ends it),
turns the garbage collector off (JAX registers a collection callback, and
nothing the child allocates needs collecting before it exits), and leaves
with `os._exit`: no interpreter teardown, no exit functions, no flushing of
the parent's buffers a second time. The deadline covers anything not
foreseen (e.g. a lock another of the caller's threads held at the fork).

One library in the parent is not safe across a fork: OpenBLAS before
0.3.31 (scipy 1.16-1.17 wheels bundle 0.3.30) shuts its thread pool down
at every fork and restarts it at the next threaded call, and that restart
can leave the calling thread spinning forever (OpenBLAS issue 5520, scipy
issue 23686). Here it hung the parent in the panels' banded Cholesky
(``solveh_banded``: ``dpbtf2`` -> a threaded ``dsyr``) twice in about 230
forked reports. So before forking, every such OpenBLAS loaded in the
process that runs more than one thread is set to one thread, for the rest
of the process (`_make_blas_fork_safe`; the package's sparse and banded
solves are too small to gain from its threads: the default case took the
same time either way), and the child runs every OpenBLAS on one thread; an
OpenBLAS whose version or thread count cannot be read (an unknown build)
makes the figures save serially.

Off by default: the ``optimise-pressure`` command turns it on for its own
run (`inverse_design.app.cli.main`, `set_parallel_figures`), so that the
one-thread OpenBLAS above stays in the command's process and never changes
a notebook's or design tool's threads behind its back; a library caller may
turn it on too. Then it is used on Linux with more than one core and at
least `MIN_FIGURES` figures; elsewhere, or when turned off
(``INFLATABLE_WING_SERIAL_FIGURES=1`` in the environment, or
`set_parallel_figures(False)`), the parent saves every figure itself on
leaving the block: the same files either way.
"""

from __future__ import annotations

import gc
import os
import signal
import struct
import sys
import tempfile
import threading
import time
import warnings
from functools import partial

__all__ = ["CHILD_TIMEOUT_S", "MIN_FIGURES", "SERIAL_VARIABLE", "FigureSaver", "ReportWorkers",
           "parallel_figures_enabled", "run_task", "save_figure", "set_parallel_figures"]

#: Environment variable that, set to anything but "" or "0", makes every `FigureSaver` save serially.
SERIAL_VARIABLE = "INFLATABLE_WING_SERIAL_FIGURES"
#: Seconds the parent waits for the child once its own share is saved; then it kills the child and saves
#: the child's figures itself. A figure takes about 0.3 s: only a hang reaches this.
CHILD_TIMEOUT_S = 60.0
#: Fewest figures worth a fork (with one, nothing is drawn at the same time as another figure).
MIN_FIGURES = 2

_ENABLED = False  # (the command turns it on: module docstring)
_STOPS = (signal.SIGINT, signal.SIGTERM)
#: The warnings a fork of this process emits (message regular expression, category): JAX's at-fork hook,
#: and Python's own from 3.12 on (JAX's threads). Silenced for the fork of `FigureSaver` only (module
#: docstring: why it is safe).
_FORK_WARNINGS = ((r"os\.fork\(\) was called\. os\.fork\(\) is incompatible with multithreaded code",
                   RuntimeWarning),
                  (r"This process \(pid=\d+\) is multi-threaded, use of fork\(\) may lead to deadlocks",
                   DeprecationWarning))
#: The first OpenBLAS release whose thread pool restarts safely after a fork (module docstring).
_OPENBLAS_FORK_SAFE = (0, 3, 31)
#: Symbol (prefix, suffix) of OpenBLAS builds: plain, scipy's and numpy's wheels (``scipy_``), 64-bit integers.
_OPENBLAS_SYMBOLS = (("scipy_", ""), ("scipy_", "64_"), ("", ""), ("", "64_"))


def set_parallel_figures(enabled: bool) -> bool:
    """Turn the forked saving of figures on or off for this process; returns the previous setting.

    Off (the default outside the command), `FigureSaver` saves every figure
    in the calling process (as on one core). On, the process's OpenBLAS may
    be set to one thread for good (module docstring).
    ``INFLATABLE_WING_SERIAL_FIGURES=1`` turns it off whatever this says.
    """
    global _ENABLED
    previous, _ENABLED = _ENABLED, bool(enabled)
    return previous


def _cores() -> int:
    """The cores this process may run on (its affinity, which a container or ``taskset`` narrows)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def parallel_figures_enabled(n_figures: int = MIN_FIGURES) -> bool:
    """Whether `FigureSaver` forks a child to save ``n_figures`` figures (module docstring).

    True once turned on (`set_parallel_figures`: the command does), on Linux with ``os.fork``,
    more than one core and at least `MIN_FIGURES` figures, unless ``INFLATABLE_WING_SERIAL_FIGURES``
    says otherwise.
    """
    return (_ENABLED and os.environ.get(SERIAL_VARIABLE, "").strip() in ("", "0")
            and sys.platform.startswith("linux") and hasattr(os, "fork")
            and n_figures >= MIN_FIGURES and _cores() > 1)


def _openblas_libraries() -> list:
    """``(path, version, get_num_threads, set_num_threads)`` of every OpenBLAS loaded in this process.

    Found by name in ``/proc/self/maps`` and opened without loading anything
    (``RTLD_NOLOAD``); ``version`` is a tuple, and the three are None for a
    build whose symbols are not known (`_OPENBLAS_SYMBOLS`).

    Raises:
        OSError: if ``/proc/self/maps`` cannot be read.
    """
    import ctypes
    import re

    paths = []
    with open("/proc/self/maps") as maps:
        for line in maps:
            fields = line.split(maxsplit=5)
            name = os.path.basename(fields[5].strip()) if len(fields) == 6 else ""
            if "openblas" in name.lower() and ".so" in name and fields[5].strip() not in paths:
                paths.append(fields[5].strip())
    found = []
    for path in paths:
        try:
            library = ctypes.CDLL(path, mode=os.RTLD_NOLOAD | os.RTLD_LAZY)
        except OSError:  # (mapped but no longer loadable by name, e.g. deleted: unknown)
            found.append((path, None, None, None))
            continue
        for prefix, suffix in _OPENBLAS_SYMBOLS:
            try:
                config, get, set_ = (getattr(library, f"{prefix}openblas_{function}{suffix}")
                                     for function in ("get_config", "get_num_threads", "set_num_threads"))
            except AttributeError:
                continue
            config.restype, get.restype, set_.restype = ctypes.c_char_p, ctypes.c_int, None
            set_.argtypes = [ctypes.c_int]
            match = re.search(rb"OpenBLAS (\d+)\.(\d+)\.(\d+)", config() or b"")
            found.append((path, tuple(int(v) for v in match.groups()) if match else None, get, set_))
            break
        else:
            found.append((path, None, None, None))
    return found


def _make_blas_fork_safe() -> list | None:
    """Set every loaded OpenBLAS that a fork can hang to one thread (module docstring), before a fork.

    Returns:
        The ``set_num_threads`` functions of every OpenBLAS loaded (for the
        child, which runs each on one thread), or None if one could not be
        read or set: then the figures are saved serially.
    """
    try:
        libraries = _openblas_libraries()
    except OSError:
        return None
    setters = []
    for _, version, get, set_ in libraries:
        if get is None:
            return None
        if (version is None or version < _OPENBLAS_FORK_SAFE) and get() > 1:
            set_(1)  # (for the rest of the process: a pool restarted later could hang as well)
            if get() != 1:
                return None
        setters.append(set_)
    return setters


class _Claims:
    """The figures not taken yet, ``[front, back)`` of the list, shared by the parent and its child.

    Two counters in an unnamed temporary file, read and updated under a POSIX
    record lock (`fcntl.lockf`): the lock belongs to a process, so it excludes
    the parent from the child (the descriptor they share does not matter), and
    the kernel releases it when its holder dies, so a killed child never
    leaves it held.
    """

    _FORMAT = "<qq"
    _SIZE = struct.calcsize(_FORMAT)

    def __init__(self, n: int):
        import fcntl

        self._fcntl = fcntl
        self._file = tempfile.TemporaryFile()
        self._fd = self._file.fileno()
        os.pwrite(self._fd, struct.pack(self._FORMAT, 0, n), 0)

    def extend(self, n: int) -> None:
        """Add ``n`` figures at the back, untaken (`ReportWorkers.submit`)."""
        self._lock(None)
        try:
            front, back = struct.unpack(self._FORMAT, os.pread(self._fd, self._SIZE, 0))
            os.pwrite(self._fd, struct.pack(self._FORMAT, front, back + n), 0)
        finally:
            self._fcntl.lockf(self._fd, self._fcntl.LOCK_UN)

    def take(self, from_front: bool, deadline: float | None = None) -> int | None:
        """Take the next figure from the front (the child) or the back (the parent); None when none is left.

        Raises:
            TimeoutError: if the lock is still held at ``deadline`` (`time.monotonic`);
                without one, waits as long as it takes.
        """
        self._lock(deadline)
        try:
            front, back = struct.unpack(self._FORMAT, os.pread(self._fd, self._SIZE, 0))
            if front >= back:
                return None
            if from_front:
                taken, front = front, front + 1
            else:
                taken = back = back - 1
            os.pwrite(self._fd, struct.pack(self._FORMAT, front, back), 0)
            return taken
        finally:
            self._fcntl.lockf(self._fd, self._fcntl.LOCK_UN)

    def _lock(self, deadline: float | None) -> None:
        if deadline is None:
            self._fcntl.lockf(self._fd, self._fcntl.LOCK_EX)
            return
        # The parent never waits unbounded: the lock is held for microseconds, but a child stopped
        # while holding it (SIGSTOP) would otherwise stop the parent with it.
        while True:
            try:
                self._fcntl.lockf(self._fd, self._fcntl.LOCK_EX | self._fcntl.LOCK_NB)
                return
            except OSError:  # (EAGAIN or EACCES: held by the other process)
                if time.monotonic() >= deadline:
                    raise TimeoutError("the figure child holds its lock") from None
                time.sleep(0.001)

    def close(self) -> None:
        self._file.close()


def _fork_process(child, record) -> None:
    """Fork a child that runs ``child(held)`` and never returns into the caller's code; ``record(pid)``
    runs in the parent before any stop (SIGINT, SIGTERM) can raise here.

    Python raises a signal handler's exception at the first bytecode after
    the call that it arrived during: a stop arriving while ``os.fork()``
    copies the process would be raised before the pid were stored, and the
    child could be neither killed nor reaped. So the main thread's Python
    handlers are swapped for ones that only record the stop (in ``held``, which
    the child gets too) until ``record`` has run; a recorded stop is raised
    again afterwards. ``child`` ends the child with `os._exit`; an exception
    escaping it ends the child with status 1.
    """
    held, swapped = [], []
    if threading.current_thread() is threading.main_thread():
        for signum in _STOPS:
            handler = signal.getsignal(signum)
            if callable(handler):  # (SIG_DFL and SIG_IGN raise nothing)
                swapped.append((signum, handler))
                signal.signal(signum, lambda number, frame: held.append(number))
    parent = os.getpid()
    try:
        _flush_standard_streams()
        with warnings.catch_warnings():
            for message, category in _FORK_WARNINGS:
                warnings.filterwarnings("ignore", message=message, category=category)
            pid = os.fork()
            if pid == 0:
                child(held)  # never returns
                os._exit(1)
            record(pid)
    except BaseException:
        if os.getpid() != parent:  # an exception in the child before `child` took over: never
            os._exit(1)  # let it unwind into the caller's code (it would clean up the caller's files)
        raise
    finally:
        _restore_handlers(swapped)
    for signum in held:
        signal.raise_signal(signum)


def _child_setup(setters: list) -> None:
    """A forked child's first steps: the default SIGINT and SIGTERM (a Ctrl-C to the process group
    ends it), no garbage collector (JAX registers a collection callback; the child is short-lived),
    and every OpenBLAS on one thread (the pools are down after the fork: never restarted here)."""
    for signum in _STOPS:
        try:
            signal.signal(signum, signal.SIG_DFL)
        except (OSError, ValueError):
            pass
    gc.disable()
    for set_threads in setters:
        set_threads(1)


def _wait_children(pids: set, exitcodes: dict, timeout: float) -> None:
    """Wait at most ``timeout`` s for the children ``pids`` to end: each that ends leaves ``pids`` and
    gets its exit code (`os.waitstatus_to_exitcode`) in ``exitcodes``."""
    deadline = time.monotonic() + timeout
    delay = 0.0005
    while pids:
        for pid in list(pids):
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                pids.discard(pid)
                exitcodes[pid] = os.waitstatus_to_exitcode(status)
        remaining = deadline - time.monotonic()
        if not pids or remaining <= 0:
            return
        time.sleep(min(delay, remaining))
        delay = min(2 * delay, 0.005)


def _kill_children(pids: set, exitcodes: dict) -> None:
    """Kill every child in ``pids`` still running and reap it (as `_wait_children` records). A stop
    arriving meanwhile is raised once all are reaped (a SIGKILLed child is gone within milliseconds)."""
    stop = None
    for pid in list(pids):
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:  # (exited already; still to be reaped)
            pass
        while pid in pids:
            try:
                _, status = os.waitpid(pid, 0)
                pids.discard(pid)
                exitcodes[pid] = os.waitstatus_to_exitcode(status)
            except ChildProcessError:  # (reaped already: nothing left of it)
                pids.discard(pid)
            except KeyboardInterrupt as error:
                stop = error
    if stop is not None:
        raise stop


def _end_child(work, held: list) -> None:
    """A forked child's whole life: ``work()`` unless a stop arrived during the fork (the parent
    raises it), then the end of the process, status 0 if ``work`` returned and 1 if anything was
    raised (the parent then writes the child's share itself). Never returns."""
    code = 1
    try:
        if not held:
            work()
            code = 0
    except BaseException:  # noqa: BLE001 - any failure: the parent does this child's work
        code = 1
    finally:
        os._exit(code)


def _restore_handlers(handlers: list) -> None:
    """Put ``[(signal, handler)]`` back, each even if a stop is raised while an earlier one is put back."""
    if handlers:
        (signum, handler), rest = handlers[0], handlers[1:]
        try:
            signal.signal(signum, handler)
        finally:
            _restore_handlers(rest)


def _flush_standard_streams() -> None:
    """Flush stdout and stderr, so that text buffered before the fork is not written by both processes."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (AttributeError, OSError, ValueError):  # None, closed, or a stream that cannot flush
            pass


class FigureSaver:
    """Save figures that are already built, half on a forked child, while the caller writes other files.

    Use::

        with FigureSaver([(path, figure), ...], save) as saver:
            ...  # the caller's other files, written while the child draws
        # here every figure is saved

    Args:
        items: ``(path, figure)`` pairs; every figure built completely (the
            child only saves them).
        save: ``save(figure, path)``, e.g. a ``Figure.savefig`` call. It
            runs in the child for some figures: it must not call JAX (module
            docstring) and must write only ``path``.
        parallel: fork a child (True), or save every figure in the calling
            process (False); default `parallel_figures_enabled`. True still
            saves serially where no fork is possible.

    Attributes:
        pid: the child's process id, or None when no child was forked.
        child_exitcode: how the child ended (`os.waitstatus_to_exitcode`: 0
            success, a negative number the signal that ended it: -9 when the
            parent killed it), None without a child.
        saved_by_child: the paths whose files the child wrote and the parent
            kept (a child that did not exit 0 has none: the parent saved them again).
    """

    def __init__(self, items, save, *, parallel: bool | None = None):
        self._items = list(items)
        self._save = save
        self._parallel = parallel_figures_enabled(len(self._items)) if parallel is None else parallel
        self._claims = None
        self._blas = []
        self._alive: set = set()  # the child while it runs (its pid)
        self.pid = None
        self.child_exitcode = None
        self.saved_by_child = []

    # ------------------------------------------------------------------ the parent
    def __enter__(self) -> FigureSaver:
        if self._parallel and len(self._items) > 0 and hasattr(os, "fork"):
            self._blas = _make_blas_fork_safe()
            if self._blas is None:  # an OpenBLAS that a fork could hang: save serially
                return self
            try:
                self._claims = _Claims(len(self._items))
            except (ImportError, OSError):  # no fcntl, no temporary file: save serially
                return self
            try:
                self._fork()
            except BaseException as error:
                self._stop_child()
                if isinstance(error, OSError) and self.pid is None:
                    return self  # the fork itself failed (no memory, process limit): save serially
                raise
        return self

    def __exit__(self, exc_type, exc, traceback) -> bool:
        if exc_type is not None:
            self._stop_child()
            return False
        try:
            self._finish()
        except BaseException:
            self._stop_child()
            raise
        return False

    def _fork(self) -> None:
        """Fork the child (`_fork_process`) and record its pid before any stop can raise here."""

        def record(pid):
            self.pid, self._alive = pid, {pid}

        _fork_process(self._child, record)

    def _finish(self) -> None:
        """Save the parent's share, wait for the child, and save again whatever the child did not save."""
        if self.pid is None:
            for path, figure in self._items:
                self._save(figure, path)
            return
        mine = set()
        try:
            while (k := self._claims.take(from_front=False, deadline=time.monotonic() + CHILD_TIMEOUT_S)) is not None:
                self._save(self._items[k][1], self._items[k][0])
                mine.add(k)
            self.child_exitcode = self._wait(CHILD_TIMEOUT_S)
        except TimeoutError:  # (the child held the claims' lock until the deadline)
            pass
        self._stop_child()  # (kills a child still running after the deadline; reaps it)
        trusted = self.child_exitcode == 0
        for k, (path, figure) in enumerate(self._items):
            if k in mine:
                continue
            if trusted and os.path.exists(path):
                self.saved_by_child.append(path)
            else:
                self._save(figure, path)

    def _wait(self, timeout: float) -> int | None:
        """The child's exit code (`os.waitstatus_to_exitcode`) once it ends, or None after ``timeout`` s."""
        codes = {}
        _wait_children(self._alive, codes, timeout)
        return codes.get(self.pid)

    def _stop_child(self) -> None:
        """Kill the child if it still runs and reap it (`_kill_children`); close the claims."""
        codes = {}
        try:
            _kill_children(self._alive, codes)
        finally:
            if self.pid in codes:
                self.child_exitcode = codes[self.pid]
            if self._claims is not None:
                self._claims.close()
                self._claims = None

    # ------------------------------------------------------------------ the child
    def _child(self, held: list) -> None:
        """Save figures from the front of the list until none is left, then end the process: never returns."""

        def work():
            _child_setup(self._blas)
            while (k := self._claims.take(from_front=True)) is not None:
                self._save(self._items[k][1], self._items[k][0])

        _end_child(work, held)


# ---------------------------------------------------------------------- workers forked before the design
#: Most report workers (one per core, up to this many).
MAX_WORKERS = 4
#: How much lower than the command's the workers' scheduling priority is (``os.nice``).
WORKER_NICE = 10
_INT = struct.Struct("<q")  # a batch's length in the job file; a done task's index on a result pipe


class ReportWorkers:
    """Processes forked before the design that import the report's libraries meanwhile, then write files.

    `FigureSaver` forks after the figures are built, so the parent still
    imports matplotlib (0.28 s on the 2-core development machine) and ezdxf
    (0.14 s) and builds every figure (0.16 s on the default case) itself,
    holding Python's lock while the design runs (an import on a second thread
    slowed the design by as much as it saved: README, "Compilation"). Workers
    forked when the command starts, before JAX's backend and any thread of
    the process start, import those libraries (``modules``) at a lower
    priority (`WORKER_NICE`) on the cores the design leaves idle; the report
    then hands them *tasks* ``(path, function, args, kwargs)``: a module-level
    function (pickled by name) that writes ``path`` as
    ``function(path, *args, **kwargs)``, with picklable NumPy-only arguments
    (a `forward_solver.Bay` pickles without its device arrays), such as a
    figure (`save_figure`) or a DXF pattern. It never sends a function that
    calls JAX: the children never touch the parent's JAX runtime.

    Tasks come in batches (`submit`), appended to an unnamed temporary file
    the workers share; a byte on each worker's pipe says a batch was added,
    and closing the pipe (`finish`) that no more will come. Each worker takes
    the next task not taken (`_Claims`: the slowest first when the caller
    orders them so), runs it, and reports its index on its result pipe.

    The result never depends on them: `finish` waits at most
    `CHILD_TIMEOUT_S`, kills and reaps every worker still running, and
    returns the tasks a worker that exited 0 reported done; the caller runs
    the rest itself (`run_task`). `close` kills and reaps them (an unused
    worker too: a run that ends before its report, an error, Ctrl-C), and is
    safe to call twice.

    Started by the command for a single bay's report only (`start` returns
    None where `FigureSaver` would not fork: `parallel_figures_enabled`, an
    OpenBLAS that a fork could hang, a second thread already running).
    """

    def __init__(self, job, claims: "_Claims"):
        self.pids: list = []
        self._wake: list = []  # the write end of each worker's wake-up pipe
        self._results: list = []  # the read end of each worker's result pipe
        self._job = job  # the unnamed temporary file of the batches
        self._claims = claims
        self._alive: set = set()
        self._end = 0  # where the next batch goes in the job file
        self.submitted = 0  # tasks handed over so far
        self.exitcodes: dict = {}

    @classmethod
    def start(cls, modules=(), count: int | None = None) -> "ReportWorkers | None":
        """Fork ``count`` workers (default one per core, at most `MAX_WORKERS`, at least two) that
        import ``modules`` while they wait; None when forking is off or unsafe here (class docstring)."""
        if not parallel_figures_enabled() or threading.active_count() > 1:
            return None
        count = max(2, min(_cores(), MAX_WORKERS)) if count is None else int(count)
        setters = _make_blas_fork_safe()
        if setters is None:
            return None
        try:
            claims = _Claims(0)
            job = tempfile.TemporaryFile()
        except (ImportError, OSError):
            return None
        workers = cls(job, claims)
        try:
            for _ in range(count):
                wake_read, wake_write = os.pipe()
                result_read, result_write = os.pipe()
                workers._wake.append(wake_write)
                workers._results.append(result_read)

                def record(pid):
                    workers.pids.append(pid)
                    workers._alive.add(pid)

                # (the child closes the parent's ends of its own and earlier workers' pipes: a wake-up
                # pipe must end when the parent closes it, not live on in a sibling)
                work = partial(_worker, tuple(modules), wake_read, result_write, job.fileno(), claims, setters,
                               tuple(workers._wake + workers._results))
                child = partial(_end_child, work)
                _fork_process(child, record)
                os.close(wake_read)
                os.close(result_write)
        except BaseException as error:
            workers.close()
            if isinstance(error, OSError):
                return None
            raise
        return workers

    def submit(self, tasks: list) -> bool:
        """Hand a batch of ``tasks`` (class docstring) to the workers, numbered after the earlier
        batches' (`finish` returns those indices). Returns False, handing nothing, if the batch does
        not pickle or the workers are closed (the caller runs it itself)."""
        import pickle

        if self._job is None or not tasks:
            return False
        try:
            payload = pickle.dumps([(str(path), function, tuple(args), dict(kwargs))
                                    for path, function, args, kwargs in tasks], protocol=pickle.HIGHEST_PROTOCOL)
        except (pickle.PicklingError, TypeError, AttributeError):
            return False
        os.pwrite(self._job.fileno(), _INT.pack(len(payload)) + payload, self._end)
        self._end += _INT.size + len(payload)
        self._claims.extend(len(tasks))  # (the batch is in the file before any index of it can be taken)
        self.submitted += len(tasks)
        for fd in self._wake:
            try:
                os.write(fd, b"1")
            except OSError:  # (a worker that died already: `finish` leaves its tasks to the caller)
                pass
        return True

    def finish(self, timeout: float = CHILD_TIMEOUT_S) -> set:
        """Say that no batch will follow, wait for the workers (at most ``timeout`` s in all), kill any
        still running, and return the indices of the tasks done by a worker that exited 0."""
        for fd in self._wake:
            os.close(fd)
        self._wake = []
        _wait_children(self._alive, self.exitcodes, timeout)
        _kill_children(self._alive, self.exitcodes)
        done = set()
        for pid, fd in zip(self.pids, self._results):
            reported = _read_all(fd)
            if self.exitcodes.get(pid) == 0:
                done.update(_INT.unpack_from(reported, k)[0] for k in range(0, len(reported), _INT.size))
        self.close()
        return done

    def close(self) -> None:
        """Kill and reap every worker still running and close the pipes and files (twice is harmless)."""
        try:
            _kill_children(self._alive, self.exitcodes)
        finally:
            for fd in self._wake + self._results:
                try:
                    os.close(fd)
                except OSError:
                    pass
            self._wake, self._results = [], []
            if self._job is not None:
                self._job.close()
                self._job = None
            if self._claims is not None:
                self._claims.close()
                self._claims = None

    def __enter__(self) -> "ReportWorkers":
        return self

    def __exit__(self, *exc) -> bool:
        self.close()
        return False


def run_task(task) -> None:
    """Run one task ``(path, function, args, kwargs)`` here: ``function(path, *args, **kwargs)``."""
    path, function, args, kwargs = task
    function(path, *args, **kwargs)


def save_figure(path, save, plot, args=(), kwargs=None) -> None:
    """A figure task's function: ``save(plot(*args, **kwargs), path)`` (``save``, ``plot``: module-level)."""
    save(plot(*args, **(kwargs or {})), path)


def _lower_priority(increment: int = WORKER_NICE) -> None:
    """Run this process below the design (``os.nice``): its imports take only the cores the design
    leaves idle."""
    try:
        os.nice(increment)
    except (AttributeError, OSError):  # (no nice on this system: the same work, at the same priority)
        pass


def _read_all(fd: int) -> bytes:
    """Everything left in a pipe whose writers have all exited (EOF), non-blocking otherwise."""
    os.set_blocking(fd, False)
    chunks = []
    while True:
        try:
            chunk = os.read(fd, 65536)
        except BlockingIOError:
            break
        if not chunk:
            break
        chunks.append(chunk)
    return b"".join(chunks)


def _worker(modules: tuple, wake: int, result: int, job: int, claims: "_Claims", setters: list,
            parents: tuple) -> None:
    """A report worker's work (`ReportWorkers`; `_end_child` ends it): close the parent's pipe ends it
    inherited (``parents``), import ``modules``, then take and run tasks until the parent closes the
    wake-up pipe."""
    import importlib
    import pickle

    for fd in parents:
        os.close(fd)
    _child_setup(setters)
    _lower_priority()
    for name in modules:
        importlib.import_module(name)
    tasks, offset = [], 0
    while True:
        k = claims.take(from_front=True)
        if k is None:  # none left: wait for a batch (a byte) or the end (the pipe closed)
            if not os.read(wake, 1):
                return
            continue
        while k >= len(tasks):  # (the batch holding it is in the file: `submit` writes it first)
            (size,) = _INT.unpack(os.pread(job, _INT.size, offset))
            tasks += pickle.loads(os.pread(job, size, offset + _INT.size))
            offset += _INT.size + size
        run_task(tasks[k])
        os.write(result, _INT.pack(k))
