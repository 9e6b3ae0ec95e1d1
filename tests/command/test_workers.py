"""The report's worker processes (`inverse_design.app.workers.ReportWorkers`): every task is done once,
by a worker or by the caller, and nothing of the pool outlives it."""

import multiprocessing
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from inverse_design.app import workers as report_workers
from support.command import environment

ROOT = Path(__file__).resolve().parents[2]


def write_text(path, text, delay=0.0):
    """A task: ``text`` into ``path`` (after ``delay`` seconds), with the writing process's id."""
    time.sleep(delay)
    Path(path).write_text(f"{text} {os.getpid()}")


def write_slowly(path, started, delay):
    """A task that says it has begun (the file ``started``), then writes ``path`` after ``delay`` s."""
    Path(started).write_text("")
    write_text(path, "slow", delay)


def fail(path, started):
    Path(started).write_text("")
    raise RuntimeError("this task fails")


def _wait_for(path, timeout=120.0):
    deadline = time.monotonic() + timeout
    while not Path(path).exists() and time.monotonic() < deadline:
        time.sleep(0.05)


def _tasks(tmp_path, n, delay=0.0):
    return [(tmp_path / f"file_{k}.txt", write_text, (f"task {k}", delay), {}) for k in range(n)]


def test_workers_write_the_files_and_the_caller_those_no_worker_took(tmp_path):
    """One worker held up by its first task: the caller writes the rest itself, from the last, and
    every file is written once."""
    workers = report_workers.ReportWorkers.start(count=1)
    try:
        started = tmp_path.parent / f"{tmp_path.name}.started"
        slow = [(tmp_path / "slow.txt", write_slowly, (started, 2.0), {})]
        assert workers.submit(slow) and workers.submit(_tasks(tmp_path, 3))
        _wait_for(started)  # (the worker has taken the slow task)
        done = workers.finish()
    finally:
        workers.close()
    assert done == {0, 1, 2, 3}
    writers = {p.name: p.read_text().split()[-1] for p in tmp_path.iterdir()}
    assert set(writers) == {"slow.txt", "file_0.txt", "file_1.txt", "file_2.txt"}
    assert writers["slow.txt"] != str(os.getpid())  # the worker's
    assert {writers[f"file_{k}.txt"] for k in range(3)} == {str(os.getpid())}  # the caller's
    assert not multiprocessing.active_children()


def test_a_failed_task_is_left_to_the_caller_and_an_unpicklable_one_is_refused(tmp_path):
    workers = report_workers.ReportWorkers.start(count=1)
    try:
        assert workers.submit([(tmp_path / "x", fail, (tmp_path / "started",), {})])
        assert not workers.submit([(tmp_path / "y", lambda path: None, (), {})])  # (does not pickle)
        _wait_for(tmp_path / "started")  # (the worker took it, and failed)
        assert workers.finish() == set()
    finally:
        workers.close()
    assert not workers.submit(_tasks(tmp_path, 1))  # closed: the caller writes it
    assert not multiprocessing.active_children()


def test_closing_stops_workers_busy_or_idle(tmp_path):
    workers = report_workers.ReportWorkers.start(count=2)
    started = tmp_path.parent / f"{tmp_path.name}.started"
    workers.submit([(tmp_path / "slow.txt", write_slowly, (started, 300.0), {}), *_tasks(tmp_path, 1, delay=300.0)])
    _wait_for(started)  # (a worker is busy with its task, the other idle or busy)
    workers.close()
    workers.close()  # (twice is harmless)
    assert not multiprocessing.active_children()
    assert list(tmp_path.iterdir()) == []  # the busy workers were stopped, not waited for


def test_no_workers_on_one_core(monkeypatch):
    monkeypatch.setattr(report_workers, "_cores", lambda: 1)
    assert report_workers.ReportWorkers.start() is None


_EXIT_AT_ONCE = r"""
import os, sys
from pathlib import Path
from inverse_design.app import workers as report_workers
from tests.command.test_workers import _wait_for, write_slowly, write_text

workers = report_workers.ReportWorkers.start(count=1)
out, delay = Path(sys.argv[1]), float(sys.argv[2])
workers.submit([(out / "x.txt", write_slowly, (out / "started", delay), {}), (out / "y.txt", write_text, ("y",), {})])
_wait_for(out / "started")  # (a worker has taken the first task)
print(sorted(workers.finish(timeout=2.0)))
sys.stdout.flush()
os._exit(0)  # as the command ends: no exit functions
"""


@pytest.mark.parametrize("delay, done", [(0.0, "[0, 1]"), (30.0, "[1]")])
def test_a_process_that_exits_at_once_after_the_workers_leaks_nothing(tmp_path, delay, done):
    """The command ends with ``os._exit``: the pool's semaphores must be released before (else the
    resource tracker reports them as leaked on stderr), whether every task was answered (the pool
    goes with its last reference) or a worker's task outlasted the wait (it is killed, the pool
    collected)."""
    ran = subprocess.run([sys.executable, "-c", _EXIT_AT_ONCE, str(tmp_path), str(delay)], cwd=ROOT,
                         env=environment(), capture_output=True, text=True, timeout=120)
    time.sleep(0.5)
    assert ran.returncode == 0 and ran.stdout.strip() == done, ran.stderr
    assert "leaked" not in ran.stderr and ran.stderr.strip() == "", ran.stderr
    assert (tmp_path / "y.txt").exists() and (tmp_path / "x.txt").exists() == (delay == 0.0)


@pytest.mark.parametrize("name", ["ctypes", "/proc", "_run_exitfuncs", "gc.freeze", "os.fork"])
def test_the_command_carries_no_machinery_of_its_own(name):
    """The command's start, its workers and its end are the standard library's (docs/architecture.md)."""
    for module in ("cli", "run", "workers", "folder", "interrupts"):
        path = ROOT / "inverse_design" / "app" / f"{module}.py"
        assert name not in path.read_text(), path


def write_policy(path):
    Path(path).write_text(str(os.sched_getscheduler(0)))


@pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="Linux scheduling policies")
def test_a_worker_imports_on_idle_cores_and_runs_its_tasks_at_the_callers_priority(tmp_path):
    workers = report_workers.ReportWorkers.start(count=1)
    try:
        assert workers.submit([(tmp_path / "started", write_text, ("x",), {}),
                               (tmp_path / "policy", write_policy, (), {})])
        _wait_for(tmp_path / "policy")
        workers.finish()
    finally:
        workers.close()
    assert int((tmp_path / "policy").read_text()) == os.sched_getscheduler(0) == os.SCHED_OTHER


def test_a_worker_imports_neither_jax_nor_the_solver():
    """What a worker imports (`workers.WORKER_MODULES`, the workers module for its tasks, and the
    command's module, which a spawned worker imports again as its main module) leaves JAX, SciPy and
    the solver out: the report builds the figures and hands them over built."""
    from inverse_design.app.workers import WORKER_MODULES

    modules = WORKER_MODULES + ("inverse_design.app.workers", "inverse_design.app.cli")
    code = (f"import importlib, sys\nfor name in {modules!r}:\n"
            "    importlib.import_module(name)\n"
            "print(sorted(m for m in ('jax', 'scipy', 'forward_solver', 'targets') if m in sys.modules))")
    ran = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                         capture_output=True, text=True, timeout=120)
    assert ran.returncode == 0, ran.stderr
    assert ran.stdout.strip() == "[]"


def test_a_figure_saved_by_a_task_is_the_file_savefig_writes(tmp_path):
    # `save_figure` lays a constrained figure out once, at the saving dpi, where savefig lays it out twice:
    # the same bytes, or the layout (margins, the colorbar's room, ticks) came out otherwise. (Imported
    # here: the workers of this file's other tests import the module to run its tasks.)
    import pickle

    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(6, 4), layout="constrained")
    FigureCanvasAgg(figure)
    left, right = figure.subplots(1, 2)
    left.semilogy(np.arange(1, 9), 10.0 ** np.arange(8), label="merit")
    left.set(title="a long title that takes room", xlabel="iteration", ylabel="merit")
    left.legend()
    image = right.pcolormesh(np.arange(30).reshape(5, 6))
    figure.colorbar(image, ax=right, label="tension, N/m")
    figure.suptitle("a figure")
    blob, options = pickle.dumps(figure), {"dpi": 150, "pil_kwargs": {"compress_level": 3}}
    pickle.loads(blob).savefig(tmp_path / "savefig.png", **options)
    report_workers.save_figure(tmp_path / "task.png", pickle.loads(blob), **options)
    assert (tmp_path / "task.png").read_bytes() == (tmp_path / "savefig.png").read_bytes()
