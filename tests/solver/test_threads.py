"""`forward_solver.solvers.threads.each`: independent items shared by the caller and one helper thread.

The items come back in order, both threads run at once (two items that wait for each other finish),
an item's exception is raised in the caller and stops the items not begun, and without a second core
the caller runs everything itself.
"""

import threading

import pytest

from forward_solver.solvers import threads


def test_the_items_come_back_in_order_and_two_run_at_once(monkeypatch):
    monkeypatch.setattr(threads, "helpers", lambda: 1)
    meet = threading.Barrier(2, timeout=10)  # (broken, and the items fail, unless two threads reach it)
    ran = []

    def item(k):
        if k < 2:
            meet.wait()
        ran.append(threading.current_thread().name)
        return k * k

    assert threads.each(item, 9) == [k * k for k in range(9)]
    assert "bay-helper" in ran and threading.current_thread().name in ran


def test_an_items_exception_reaches_the_caller_and_stops_the_rest(monkeypatch):
    monkeypatch.setattr(threads, "helpers", lambda: 1)
    begun = []

    def item(k):
        begun.append(k)
        if k == 0:
            raise ValueError("bay 0 is bad")
        return k

    with pytest.raises(ValueError, match="bay 0 is bad"):
        threads.each(item, 100)
    assert len(begun) < 100


def test_an_item_on_the_helper_runs_its_own_items_itself(monkeypatch):
    monkeypatch.setattr(threads, "helpers", lambda: 1)
    meet = threading.Barrier(2, timeout=10)

    def item(k):
        if k < 2:
            meet.wait()
        return threads.each(lambda j: (threading.current_thread().name, j), 3)

    names = {name for inner in threads.each(item, 4) for name, _ in inner}
    assert "bay-helper" in names  # (and no item on the helper waited for the helper)


def test_one_core_runs_every_item_in_the_caller(monkeypatch):
    monkeypatch.setattr(threads, "helpers", lambda: 0)
    names = []
    assert threads.each(lambda k: names.append(threading.current_thread().name) or k, 5) == list(range(5))
    assert set(names) == {threading.current_thread().name}


def test_what_the_helper_keeps_is_dropped_on_the_helper(monkeypatch):
    # SciPy's SuperLU frees a factor's memory only on the thread that made it: a factor made on the
    # helper is kept there and dropped there, whichever thread lets it go.
    monkeypatch.setattr(threads, "helpers", lambda: 1)
    dropped = []

    class Tracked:
        def __del__(self):
            dropped.append(threading.current_thread().name)

    meet = threading.Barrier(2, timeout=10)  # (both threads take an item)

    def item(k):
        if k < 2:
            meet.wait()
        return threads.keep(Tracked()) if threads.on_helper() else None

    keys = threads.each(item, 6)
    keys = [key for key in keys if key is not None]
    assert keys and all(isinstance(threads.kept(key), Tracked) for key in keys)
    for key in keys:
        threads.release(key)
    done = threading.Event()
    threads._helper().put(done.set)  # (after the releases, in order)
    assert done.wait(10)
    assert dropped == ["bay-helper"] * len(keys)


def test_a_script_that_solves_a_wing_on_two_threads_exits_cleanly(tmp_path):
    # A factor made on the helper and still held when the script ends is freed there, at the exit:
    # dropped by the main thread it leaked and left an error that made the exit fail (status 120).
    import subprocess
    import sys

    from support.command import environment

    script = tmp_path / "wing.py"
    script.write_text(
        "import jax\n"
        "from forward_solver import Fabric, Wing, solve_bays\n"
        "from forward_solver.solvers import bay_starts, threads\n"
        "from targets import naca\n"
        "bay_starts.helpers = threads.helpers = lambda: 1\n"
        "af = naca('2412')\n"
        "wing = Wing(airfoils=(af,) * 5, chords=(1.0, 0.9, 0.8, 0.7, 0.6), stations=(0.0, 0.25, 0.5, 0.75, 1.0))\n"
        "sol = solve_bays(wing.scenes(Fabric(), n_span=5, n_contour=32), 2e4, rtol=1e-8, method='relax+newton')\n"
        "assert sol.converged and sol.solutions[3].factor is not None\n"
        "print('solved')\n")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300,
                          env=environment())
    assert done.returncode == 0 and done.stdout.strip() == "solved", done.stderr
    assert "Exception ignored" not in done.stderr, done.stderr
