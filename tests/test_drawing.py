"""The report's figures saved on a forked child (`inverse_design.app.drawing.FigureSaver`).

The same files as saved in one process, whatever the child does (fails, is
killed, hangs past the deadline), no child left running or unreaped, and
the serial path wherever the fork is turned off. Small figures, no solves.
"""

import os
import signal
import sys
import threading
import time
import warnings

import numpy as np
import pytest

from inverse_design.app import drawing
from inverse_design.app.drawing import FigureSaver

needs_fork = pytest.mark.skipif(not (sys.platform.startswith("linux") and hasattr(os, "fork")),
                                reason="the forked saving is for Linux")
N_FIGURES = 4


def _figures(n: int = N_FIGURES) -> list:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figures = []
    for k in range(n):
        fig = Figure(figsize=(2.4, 1.6), layout="constrained")
        FigureCanvasAgg(fig)
        ax = fig.add_subplot()
        x = np.linspace(0.0, 1.0, 60)
        ax.plot(x, np.sin(6.0 * (k + 1) * x), color=f"C{k}")
        ax.set_title(f"figure {k}")
        figures.append(fig)
    return figures


def _save(fig, path) -> None:
    fig.savefig(path, dpi=72)


def _items(folder, n: int = N_FIGURES) -> list:
    folder.mkdir(exist_ok=True)
    return [(folder / f"figure_{k}.png", fig) for k, fig in enumerate(_figures(n))]


def _contents(folder) -> dict:
    return {path.name: path.read_bytes() for path in sorted(folder.iterdir())}


@pytest.fixture
def expected(tmp_path) -> dict:
    """The files saved one after another in this process."""
    for path, fig in _items(tmp_path / "serial"):
        _save(fig, path)
    return _contents(tmp_path / "serial")


def _assert_gone(pid: int) -> None:
    """Neither running nor a zombie: not a child of this process any more."""
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)


def _in_child_only(action):
    """A save function that does ``action(fig, path)`` in the child, and saves normally in this process."""
    parent = os.getpid()

    def save(fig, path):
        if os.getpid() != parent:
            action(fig, path)
        _save(fig, path)

    return save


def _wait_for(condition, seconds: float = 20.0) -> None:
    end = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.01)


@needs_fork
def test_the_child_draws_while_the_block_runs_and_the_files_are_those_saved_serially(tmp_path, expected):
    folder = tmp_path / "parallel"
    with FigureSaver(_items(folder), _save, parallel=True) as saver:
        assert saver.pid is not None and saver.pid != os.getpid()
        _wait_for(lambda: (folder / "figure_0.png").exists())  # drawn by the child: this process is here
    assert saver.child_exitcode == 0
    assert folder / "figure_0.png" in saver.saved_by_child
    assert _contents(folder) == expected  # (Agg's PNG output is deterministic: byte for byte)
    _assert_gone(saver.pid)


@needs_fork
@pytest.mark.parametrize("failure", ["raises", "killed", "exits 0 without saving"])
def test_a_failed_childs_figures_are_saved_again_by_the_parent(tmp_path, expected, failure):
    def fail(fig, path):
        path.write_bytes(b"half a figure")  # a file the parent must not trust
        if failure == "raises":
            raise OSError("disk full")
        if failure == "killed":
            os.kill(os.getpid(), signal.SIGKILL)
        os.unlink(path)
        os._exit(0)

    folder = tmp_path / "parallel"
    with FigureSaver(_items(folder), _in_child_only(fail), parallel=True) as saver:
        time.sleep(0.3)  # (the child takes its first figure before this process takes any)
    assert saver.child_exitcode == {"raises": 1, "killed": -signal.SIGKILL, "exits 0 without saving": 0}[failure]
    assert saver.saved_by_child == []
    assert _contents(folder) == expected
    _assert_gone(saver.pid)


@needs_fork
@pytest.mark.parametrize("error", [ValueError, KeyboardInterrupt])
def test_an_exception_in_the_block_kills_and_reaps_the_child_and_propagates(tmp_path, error):
    start = time.monotonic()
    with pytest.raises(error):
        with FigureSaver(_items(tmp_path), _in_child_only(lambda fig, path: time.sleep(120)),
                         parallel=True) as saver:
            _wait_for(lambda: saver.pid is not None and os.path.exists(f"/proc/{saver.pid}"))
            raise error("the caller's other work failed")
    assert time.monotonic() - start < 30
    assert saver.child_exitcode == -signal.SIGKILL
    _assert_gone(saver.pid)
    assert not os.path.exists(f"/proc/{saver.pid}")


@needs_fork
def test_a_child_past_the_deadline_is_killed_and_its_figures_saved_by_the_parent(tmp_path, expected, monkeypatch):
    monkeypatch.setattr(drawing, "CHILD_TIMEOUT_S", 0.5)
    folder = tmp_path / "parallel"
    start = time.monotonic()
    with FigureSaver(_items(folder), _in_child_only(lambda fig, path: time.sleep(120)), parallel=True) as saver:
        time.sleep(0.3)  # (the child takes its first figure, and hangs there)
    assert time.monotonic() - start < 30
    assert saver.child_exitcode == -signal.SIGKILL and saver.saved_by_child == []
    assert _contents(folder) == expected
    _assert_gone(saver.pid)


@pytest.mark.parametrize("switch", ["environment", "function", "not linux", "one core", "one figure"])
def test_a_switch_or_a_machine_without_the_fork_saves_every_figure_in_this_process(tmp_path, expected, monkeypatch,
                                                                                   switch):
    def no_fork():
        raise AssertionError("forked")

    monkeypatch.setattr(os, "fork", no_fork)
    monkeypatch.setattr(drawing, "_cores", lambda: 2)
    monkeypatch.delenv(drawing.SERIAL_VARIABLE, raising=False)
    monkeypatch.setattr(drawing, "_ENABLED", True)
    n = 1 if switch == "one figure" else N_FIGURES
    if switch == "environment":
        monkeypatch.setenv(drawing.SERIAL_VARIABLE, "1")
    elif switch == "function":
        assert drawing.set_parallel_figures(False) is True
    elif switch == "not linux":
        monkeypatch.setattr(sys, "platform", "darwin")
    elif switch == "one core":
        monkeypatch.setattr(drawing, "_cores", lambda: 1)
    assert not drawing.parallel_figures_enabled(n)
    items = _items(tmp_path / "out", n)
    with FigureSaver(items, _save) as saver:
        assert saver.pid is None
        assert not any(path.exists() for path, _ in items)  # (saved on leaving the block)
    assert saver.child_exitcode is None and saver.saved_by_child == []
    assert _contents(tmp_path / "out") == {name: expected[name] for name in sorted(expected)[:n]}


@needs_fork
def test_the_fork_is_the_commands_choice_on_linux_with_two_cores(monkeypatch):
    """Off for a library caller (its OpenBLAS threads are left alone), on while the command runs."""
    from inverse_design.app import cli

    monkeypatch.delenv(drawing.SERIAL_VARIABLE, raising=False)
    monkeypatch.setattr(drawing, "_cores", lambda: 2)
    assert not drawing.parallel_figures_enabled(N_FIGURES)
    seen = []
    monkeypatch.setattr(cli, "_main", lambda argv, started: seen.append(drawing.parallel_figures_enabled(N_FIGURES)) or 0)
    assert cli.main([]) == 0 and seen == [True]
    assert not drawing.parallel_figures_enabled(N_FIGURES)  # given back
    monkeypatch.setattr(drawing, "_ENABLED", True)
    assert drawing.parallel_figures_enabled(N_FIGURES)
    monkeypatch.setenv(drawing.SERIAL_VARIABLE, "0")
    assert drawing.parallel_figures_enabled(N_FIGURES)
    assert drawing.set_parallel_figures(False) is True and drawing.set_parallel_figures(True) is False


@needs_fork
def test_the_fork_does_not_warn_about_jax(tmp_path):
    import jax

    jax.devices()  # (JAX's backend started: its at-fork hook warns from now on)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pid = os.fork()
        if pid == 0:
            os._exit(0)
        os.waitpid(pid, 0)
    if not any("os.fork() was called" in str(w.message) for w in caught):
        pytest.skip("this JAX does not warn about a fork: nothing to silence")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with FigureSaver(_items(tmp_path), _save, parallel=True) as saver:
            assert saver.pid is not None
    assert [str(w.message) for w in caught if "fork" in str(w.message)] == []


class _Stop(Exception):
    pass


@needs_fork
@pytest.mark.skipif(threading.current_thread() is not threading.main_thread(),
                    reason="signal handlers are the main thread's")
def test_a_stop_arriving_during_the_fork_is_raised_after_it_and_the_child_reaped(tmp_path, monkeypatch):
    # Python raises a handler's exception at the first bytecode after os.fork() returns: before the
    # child's pid were stored, it could be neither killed nor reaped.
    forked = []
    real_fork = os.fork

    def fork_meeting_a_stop():
        pid = real_fork()
        if pid:
            forked.append(pid)
            signal.raise_signal(signal.SIGTERM)  # (its handler runs at the next bytecode)
        return pid

    def stop(signum, frame):
        raise _Stop()

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        monkeypatch.setattr(os, "fork", fork_meeting_a_stop)
        with pytest.raises(_Stop):
            with FigureSaver(_items(tmp_path), _save, parallel=True):
                pytest.fail("the stop was not raised")
        assert signal.getsignal(signal.SIGTERM) is stop  # (the handler is put back)
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert len(forked) == 1
    _assert_gone(forked[0])


@needs_fork
def test_an_openblas_that_a_fork_can_hang_is_set_to_one_thread_before_the_fork(tmp_path):
    # OpenBLAS before 0.3.31 (scipy's wheels: 0.3.30) restarts its thread pool after a fork in a way that
    # can spin forever; one thread never restarts it.
    import scipy.linalg  # noqa: F401 - (loads scipy's OpenBLAS, as the report's patterns do)

    libraries = drawing._openblas_libraries()
    if not libraries:
        pytest.skip("no OpenBLAS loaded")
    assert all(version is not None and get is not None for _, version, get, _ in libraries)
    with FigureSaver(_items(tmp_path), _save, parallel=True) as saver:
        assert saver.pid is not None
    for path, version, get, _ in drawing._openblas_libraries():
        if version < drawing._OPENBLAS_FORK_SAFE:
            assert get() == 1, path


def test_an_openblas_that_cannot_be_read_makes_the_figures_save_serially(tmp_path, expected, monkeypatch):
    def no_fork():
        raise AssertionError("forked")

    monkeypatch.setattr(os, "fork", no_fork)
    monkeypatch.setattr(drawing, "_openblas_libraries", lambda: [("libopenblas_unknown.so", None, None, None)])
    with FigureSaver(_items(tmp_path / "out"), _save, parallel=True) as saver:
        pass
    assert saver.pid is None
    assert _contents(tmp_path / "out") == expected


# ---------------------------------------------------------------------- workers forked before the design
_WORKERS = r"""
import json, os, sys, time
import numpy as np
from inverse_design.app import drawing

mode, folder = sys.argv[1], sys.argv[2]
PARENT = os.getpid()


def plot(k):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(2.4, 1.6), layout="constrained")
    FigureCanvasAgg(fig)
    x = np.linspace(0.0, 1.0, 60)
    fig.add_subplot().plot(x, np.sin(6.0 * (k + 1) * x), color=f"C{k}")
    return fig


def save(fig, path):
    path = str(path)
    if os.getpid() != PARENT and path.endswith("figure_1.png"):
        if mode == "fail":
            raise RuntimeError("a worker's figure failed")
        if mode == "hang":
            time.sleep(60)
    fig.savefig(path, dpi=72)


def write_text(path, text):
    with open(path, "w") as f:
        f.write(text)


drawing.set_parallel_figures(True)
workers = drawing.ReportWorkers.start(("matplotlib.figure",), count=2)
out = {"started": workers is not None, "modules": "matplotlib" in sys.modules}
if workers is not None:
    pids = list(workers.pids)
    os.makedirs(os.path.join(folder, "workers"))
    os.makedirs(os.path.join(folder, "serial"))
    tasks = [(os.path.join(folder, "workers", f"figure_{k}.png"), drawing.save_figure, (save, plot, (k,)), {})
             for k in range(4)]
    texts = [(os.path.join(folder, "workers", f"note_{k}.txt"), write_text, (f"note {k}",), {}) for k in range(2)]
    t = time.monotonic()
    if mode == "unused":
        workers.close()
        saved = set()
        assert not workers.submit(tasks)  # (closed: nothing handed over)
    else:
        assert workers.submit(tasks) and workers.submit(texts)  # two batches, numbered in order
        saved = workers.finish(timeout=3.0 if mode == "hang" else 60.0)
    out["seconds"] = time.monotonic() - t
    for k, task in enumerate(tasks + texts):
        if k not in saved:
            drawing.run_task(task)
    for k in range(4):
        save(plot(k), os.path.join(folder, "serial", f"figure_{k}.png"))
    out["notes"] = [open(path).read() for path, *_ in texts]
    workers.close()  # (twice: harmless)
    gone = []
    for pid in pids:
        try:
            os.waitpid(pid, os.WNOHANG)
            gone.append(False)
        except ChildProcessError:
            gone.append(True)

    def read(sub):
        return [open(os.path.join(folder, sub, f"figure_{k}.png"), "rb").read() for k in range(4)]

    out.update(saved=sorted(saved), gone=gone, same=read("workers") == read("serial"),
               exitcodes=sorted(workers.exitcodes.values()))
print(json.dumps(out))
"""


def _run_workers(mode, tmp_path) -> dict:
    import json
    import subprocess

    env = {k: v for k, v in os.environ.items() if k != drawing.SERIAL_VARIABLE}
    done = subprocess.run([sys.executable, "-c", _WORKERS, mode, str(tmp_path)], capture_output=True, text=True,
                          timeout=120, env=env)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout.strip().splitlines()[-1])
    if not out["started"]:
        pytest.skip("no figure workers on this machine (one core, or an OpenBLAS a fork could hang)")
    return out


@needs_fork
def test_workers_forked_first_draw_every_figure_as_this_process_would(tmp_path):
    """Forked before matplotlib was imported, the workers import it, take the tasks of two batches and
    save the same bytes."""
    out = _run_workers("ok", tmp_path)
    assert not out["modules"]  # (the parent imported matplotlib only to compare, after the workers)
    assert out["saved"] == [0, 1, 2, 3, 4, 5] and out["same"] and all(out["gone"]) and out["exitcodes"] == [0, 0]
    assert out["notes"] == ["note 0", "note 1"]


@needs_fork
def test_a_failed_workers_figures_are_drawn_by_the_caller(tmp_path):
    """The worker whose figure raised exits 1: none of its tasks counts as done, the caller runs them."""
    out = _run_workers("fail", tmp_path)
    assert 1 not in out["saved"] and len(out["saved"]) < 6 and out["same"] and all(out["gone"])
    assert out["notes"] == ["note 0", "note 1"]
    assert out["exitcodes"] == [0, 1]


@needs_fork
def test_a_hanging_worker_is_killed_at_the_deadline_and_its_figures_drawn_by_the_caller(tmp_path):
    out = _run_workers("hang", tmp_path)
    assert 1 not in out["saved"] and out["same"] and all(out["gone"]) and out["notes"] == ["note 0", "note 1"]
    assert -signal.SIGKILL in out["exitcodes"] and out["seconds"] < 10.0


@needs_fork
def test_unused_workers_are_killed_and_reaped_at_once(tmp_path):
    out = _run_workers("unused", tmp_path)
    assert out["saved"] == [] and out["same"] and all(out["gone"]) and out["seconds"] < 1.0


def test_no_workers_while_another_thread_runs_or_the_fork_is_off(monkeypatch):
    """A second thread at the fork could hold a lock the workers need: then, and with the fork off,
    `ReportWorkers.start` gives None and the report writes every file itself."""
    monkeypatch.setattr(drawing, "_ENABLED", False)
    assert drawing.ReportWorkers.start(count=2) is None
    monkeypatch.setattr(drawing, "_ENABLED", True)
    monkeypatch.setattr(drawing, "_cores", lambda: 2)
    monkeypatch.delenv(drawing.SERIAL_VARIABLE, raising=False)
    release = threading.Event()
    thread = threading.Thread(target=release.wait)
    thread.start()
    try:
        assert drawing.ReportWorkers.start(count=2) is None
    finally:
        release.set()
        thread.join()
