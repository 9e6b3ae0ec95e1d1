"""A stop (SIGTERM, Ctrl-C) ends the command whatever its work is computing, without waiting for it.

Python runs a signal's handler only on the main thread, between two of its
bytecodes: a main thread inside one long compiled call (XLA, LAPACK, SLSQP)
took a SIGTERM only when the call returned (more than a minute on a 40-bay
wing). The command's work now runs on a thread of its own
(`interrupts.run_stoppable`, docs/command.md). How soon a stop lands is
measured by ``benchmarks/signal_latency.py``; these tests check that the
command ends, with its code and nothing written, long before the work it
abandons would (their timeouts only keep a failure from hanging).

The test launcher's ``--native-call S`` (`support.command`) makes the
command sit about S seconds in compiled XLA calls just before its design,
after its first progress line (shown on a terminal: the command's stderr
here is a pseudo-terminal).
"""

import os
import pty
import select
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest

from inverse_design.app import interrupts, output_folder
from support.cases import SMALL
from support.command import environment, launch

#: Seconds the launched command sits in compiled calls before its design: far longer than the tests wait
#: for it to end (`STOP_TIMEOUT_S`), so that a command that waited for its work would fail them.
NATIVE_CALL_S = 600.0
#: Seconds a stopped command has to end before the test fails (not a measure of its speed).
STOP_TIMEOUT_S = 60.0


def _leftovers(folder: Path) -> list[str]:
    """Staging folders and lock files of a run in ``folder`` (hidden names)."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def _read_until(fd: int, text: str, process, limit: float = 300.0) -> str:
    """What the pseudo-terminal ``fd`` shows until ``text`` appears (fails if the process ends first)."""
    seen, deadline = "", time.monotonic() + limit
    while text not in seen:
        assert process.poll() is None, f"the command ended before {text!r}: {seen}"
        assert time.monotonic() < deadline, f"no {text!r} after {limit} s: {seen}"
        if select.select([fd], [], [], 0.1)[0]:
            seen += os.read(fd, 4096).decode(errors="replace")
    return seen


def _drain(fd: int) -> str:
    """The rest of what the pseudo-terminal ``fd`` holds (its writer has ended)."""
    text = ""
    while select.select([fd], [], [], 0.2)[0]:
        try:
            chunk = os.read(fd, 4096)
        except OSError:  # (Linux: EIO once the other end is closed)
            break
        if not chunk:
            break
        text += chunk.decode(errors="replace")
    return text


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pseudo-terminal (POSIX)")
@pytest.mark.parametrize("signum, code, word", [(signal.SIGTERM, 143, "terminated"),
                                                (signal.SIGINT, 130, "interrupted")])
def test_a_stop_inside_a_long_compiled_call_ends_the_command(tmp_path, signum, code, word):
    # Before the work ran on its own thread, the main thread sat in the compiled call and the process
    # ended only after it (measured: 21 s from the signal to the end of a 20 s call).
    main, terminal = pty.openpty()
    out = tmp_path / "out"
    process = subprocess.Popen(launch("--native-call", NATIVE_CALL_S, *SMALL, "--no-compilation-cache", "--out", out),
                               cwd=tmp_path, env=environment(), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                               stderr=terminal, text=True)
    os.close(terminal)
    try:
        shown = _read_until(main, "the first wing solve compiles", process)
        time.sleep(0.5)  # (well inside the compiled calls, which follow the line)
        process.send_signal(signum)
        process.wait(timeout=STOP_TIMEOUT_S)  # (the calls last NATIVE_CALL_S: the command did not wait for them)
        shown += _drain(main)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        os.close(main)
    assert process.returncode == code, shown
    assert process.stdout.read() == ""
    assert shown.rstrip().splitlines()[-1].strip() == f"optimise-pressure: {word}; nothing was written to {out}"
    assert not out.exists() and _leftovers(tmp_path) == []


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads /proc (Linux)")
@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_stop_in_a_cold_runs_compilation_ends_the_command(tmp_path, signum, code):
    # 2 s into a cold run the work sits in XLA's compiler (it is abandoned after the grace period) and
    # the report's worker, its imports done, waits for a task holding the task queue's lock. Killing the
    # workers before the pool's termination left that lock taken: the command never ended.
    from tests.command.test_cli import _sigterm_handler_installed

    env = environment(INFLATABLE_WING_CACHE=str(tmp_path / "cache"))  # (an empty cache: the run compiles)
    process = subprocess.Popen(launch("--report-workers", *SMALL, "--out", "out"), cwd=tmp_path, env=env,
                               stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not _sigterm_handler_installed(process.pid) and process.poll() is None and time.monotonic() < deadline:
            time.sleep(0.005)
        time.sleep(2.0)
        process.send_signal(signum)
        _, stderr = process.communicate(timeout=STOP_TIMEOUT_S)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    lines = [line for line in stderr.splitlines() if "span nodes, fewer than" not in line]
    assert process.returncode == code, stderr
    assert len(lines) == 1 and lines[0].startswith("optimise-pressure: "), stderr
    assert not (tmp_path / "out").exists() and _leftovers(tmp_path) == []


def test_a_work_that_does_not_unwind_is_abandoned_and_its_folder_removed(tmp_path):
    # The work sits in a call that takes no signal and reaches no safe point (a worker thread's wait)
    # inside its staging folder, under the output folder's lock: the stop is raised in the main thread
    # after the grace period, before the work wakes; the staging folder and the lock file are removed at
    # once, and the work, when it wakes, writes nothing (its next safe point raises).
    out = tmp_path / "out"
    entered, wake, woke = threading.Event(), threading.Event(), []

    def work():
        with output_folder.output_lock(out), output_folder.staged_folder(out) as staging:
            (staging / "half.txt").write_text("half")
            entered.set()
            wake.wait(STOP_TIMEOUT_S)
            woke.append(True)
            interrupts.check()
            (staging / "summary.json").write_text("{}")

    threading.Timer(0.3, lambda: entered.wait(10) and os.kill(os.getpid(), signal.SIGTERM)).start()
    state = interrupts.install()
    try:
        with pytest.raises(interrupts.Terminated):
            interrupts.run_stoppable(work)
        assert woke == [] and interrupts.abandoned()  # (the stop did not wait for the work)
        assert _leftovers(tmp_path) == [] and not out.exists()  # (removed before the stop was raised)
    finally:
        wake.set()
        interrupts.restore(state)
    for thread in threading.enumerate():  # the abandoned work wakes and ends without writing
        if thread.name == "optimise-pressure":
            thread.join(10)
    assert woke == [True] and not out.exists() and _leftovers(tmp_path) == []


def test_a_work_that_reaches_a_safe_point_unwinds_itself():
    # The usual case: the stop is raised at the work's next safe point, which unwinds it (no abandon).
    def work():
        for _ in range(200):
            interrupts.check()
            time.sleep(0.01)
        return "finished"

    threading.Timer(0.2, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
    state = interrupts.install()
    try:
        with pytest.raises(KeyboardInterrupt) as stop:
            interrupts.run_stoppable(work)
        assert not isinstance(stop.value, interrupts.Terminated) and not interrupts.abandoned()
    finally:
        interrupts.restore(state)


def test_without_the_handlers_the_work_runs_in_the_calling_thread():
    assert interrupts.run_stoppable(threading.current_thread) is threading.current_thread()
