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


def test_one_core_runs_every_item_in_the_caller(monkeypatch):
    monkeypatch.setattr(threads, "helpers", lambda: 0)
    names = []
    assert threads.each(lambda k: names.append(threading.current_thread().name) or k, 5) == list(range(5))
    assert set(names) == {threading.current_thread().name}
