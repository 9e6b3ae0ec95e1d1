"""``--samples`` bounded and stoppable (docs/tolerances.md, docs/errors.md): a count the machine cannot hold
or solve in reasonable time is refused before any solve with one line (`resources.check_samples`); the
samples stream, and a stop while they are drawn and solved ends the command with its code and removes
the samples' temporary file. On 5x32 bays."""

import os
import re
import signal
import subprocess
import time
from pathlib import Path

import pytest

from inverse_design.app import cli, design, resources
from support.cases import IN_PROCESS, SMALL
from support.command import environment, launch

#: Seconds a stopped command has to end before the test fails (not a measure of its speed).
STOP_TIMEOUT_S = 60.0


@pytest.mark.parametrize("samples, message", [
    # 1e9 wings: 72 bytes each for the statistics (67 GiB, more than half of any test machine's memory
    # and than most machines' own) and 49 days of solves. Before: the design ran, then the draws of every
    # sample at once (24 GB), and no stop ended it (the run).
    ("1000000000", r"--samples 1,000,000,000 on 1 bay of 5 x 32 is too many for this machine: estimate [\d.]+ GiB "
                   r"of memory for their statistics and [\d,]+ days of solves on a 2-core machine, more than .*; give "
                   r"at most [\d,]+ --samples, a smaller --n-span or --n-contour, --scheduler ADDRESS"),
    # 1e7 wings: 690 MiB, but 12 hours of solves.
    ("10000000", r"--samples 10,000,000 on 1 bay of 5 x 32 is too many for this machine: estimate [\d.]+ MiB of "
                 r"memory for their statistics and [\d.]+ h of solves on a 2-core machine, more than the limit of "
                 r"60 min of solves in this process; give at most [\d,]+ --samples, a smaller --n-span or "
                 r"--n-contour, --scheduler ADDRESS to solve them on a Dask cluster, or --allow-large-grid"),
], ids=["memory", "time"])
def test_too_many_samples_are_refused_before_any_solve(samples, message, tmp_path, capsys, monkeypatch):
    solved = []

    def no_solve(*args, **kwargs):
        solved.append(True)
        raise AssertionError("the design ran before the samples were refused")

    monkeypatch.setattr(design, "optimise", no_solve)
    monkeypatch.chdir(tmp_path)
    code = cli.main(["--tolerance", "pressure=2%", "--samples", samples, *SMALL, *IN_PROCESS])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith("optimise-pressure: error: ")
    assert re.search(message, err), err
    assert solved == [] and list(tmp_path.iterdir()) == []


def test_check_samples_refuses_by_memory_time_and_the_machine_and_says_what_to_change():
    plenty = (1e15, "test")
    per_sample = resources.estimate_samples(1, 1, 9, 64)
    # memory: half of 2 GiB, less the design's 0.5 GiB
    over = int(0.5 * 2**30 / per_sample.memory) + 1
    with pytest.raises(ValueError, match=r"more than the limit of 512 MiB of memory \(half of the 2\.0 GiB "
                                         r"available, test, less the design's 512 MiB\); give at most [\d,]+ "
                                         r"--samples, or --allow-large-grid"):
        resources.check_samples(over, 1, 9, 64, base=2**29, scheduler=True, available=(2 * 2**30, "test"),
                                physical=2**40)
    assert resources.check_samples(over, 1, 9, 64, base=2**29, scheduler=True, allow_large=True,
                                   available=(2 * 2**30, "test"), physical=2**40).samples == over
    # time: an hour in this process; a cluster's time is its own
    slow = int(resources.MAX_SAMPLE_SECONDS / per_sample.seconds) + 1
    with pytest.raises(ValueError, match=r"limit of 60 min of solves in this process; give at most [\d,]+ --samples"):
        resources.check_samples(slow, 1, 9, 64, available=plenty, physical=2**40)
    assert resources.check_samples(slow, 1, 9, 64, scheduler=True, available=plenty, physical=2**40).samples == slow
    # more than the machine's memory: refused whatever the options
    with pytest.raises(ValueError, match=r"is too many for this machine: .* more than this machine's 1\.0 GiB of "
                                         r"memory with the design's 0 MiB; give at most [\d,]+ --samples$"):
        resources.check_samples(2**30 // 60, 1, 9, 64, allow_large=True, available=plenty, physical=2**30)
    # the memory unknown: the time limit still holds
    assert resources.check_samples(1000, 1, 9, 64, available=(None, "unknown"), physical=None).samples == 1000


def _samples_files(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("tolerance-samples-"))


def _children(pid: int) -> set[int]:
    """The processes ``pid`` started (Linux: /proc's task lists)."""
    found = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            found |= {int(c) for c in (task / "children").read_text().split()}
        except OSError:
            pass
    return found


def _cpu_and_state(pid: int) -> tuple[int, str]:
    """``(CPU ticks used, state letter)`` of ``pid`` (/proc/PID/stat)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(") ", 1)[1].split()
    return int(fields[11]) + int(fields[12]), fields[0]


def _wait_until_idle(pids: set[int], limit: float = 120.0) -> None:
    """Wait until every process of ``pids`` sleeps without using CPU for a second (the report workers
    have imported their libraries and wait for a task, holding the task queue's lock by turns)."""
    deadline = time.monotonic() + limit
    before = {pid: _cpu_and_state(pid) for pid in pids}
    while time.monotonic() < deadline:
        time.sleep(1.0)
        now = {pid: _cpu_and_state(pid) for pid in pids}
        if all(now[pid] == before[pid] and now[pid][1] == "S" for pid in pids):
            return
        before = now
    raise AssertionError(f"the report workers {sorted(pids)} did not settle")


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(") ")[1][0] != "Z"
    except (OSError, IndexError):
        return False


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="reads /proc (Linux)")
@pytest.mark.parametrize("signum, code, word, group", [
    (signal.SIGTERM, 143, "terminated", False), (signal.SIGINT, 130, "interrupted", False),
    (signal.SIGTERM, 143, "terminated", True)], ids=["SIGTERM", "SIGINT", "SIGTERM to the group"])
def test_a_stop_while_the_samples_are_solved_ends_the_command(tmp_path, signum, code, word, group):
    # 100,000 samples of 5x32 (minutes) about the given design (--evaluate: no optimisation before them, 3 to
    # 4 s of CPU less a run), stopped once their temporary file holds a sample's row: the
    # command ends with the stop's code and line, its temporary file removed, its report workers ended.
    # Before, nothing in the samples' loop took the stop: the work was abandoned after the grace period
    # and its temporary file of rows left behind. And a SIGTERM sent to the command's process group (as
    # GNU timeout sends it) killed the report workers too, and the pool's termination then waited for ever
    # for the task queue's lock that an idle worker held: the command printed its line and hung.
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    process = subprocess.Popen(launch("--report-workers", "--evaluate", "--tolerance", "pressure=2%", "--samples", "100000",
                                      *SMALL, "--no-compilation-cache", "--out", "out"),
                               cwd=tmp_path, env=environment(TMPDIR=str(temporary)), stdin=subprocess.DEVNULL,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    workers = set()
    try:
        deadline = time.monotonic() + 300
        while process.poll() is None and time.monotonic() < deadline:
            files = _samples_files(temporary)
            if files and (temporary / files[0]).read_text().count("\n") >= 2:  # (the header and a row)
                break
            time.sleep(0.05)
        assert process.poll() is None and _samples_files(temporary), "the samples did not start"
        workers = _children(process.pid)
        if group:  # (once they wait for a task: one of them then holds the task queue's lock)
            # The workers import at idle priority (SCHED_IDLE): while the command and the suite's other
            # processes keep every core busy they get no CPU (7 to 120 s measured), so the command is
            # paused until they have imported and wait, then resumed and stopped with its group.
            process.send_signal(signal.SIGSTOP)
            try:
                _wait_until_idle(workers)
            finally:
                process.send_signal(signal.SIGCONT)
            os.killpg(process.pid, signum)
        else:
            process.send_signal(signum)
        _, stderr = process.communicate(timeout=STOP_TIMEOUT_S)
    finally:
        if process.poll() is None:  # (the command and what of it is still in its group, which holds its pipes)
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate(timeout=STOP_TIMEOUT_S)
    assert process.returncode == code, stderr
    assert stderr.rstrip().splitlines()[-1] == f"optimise-pressure: {word}; nothing was written to out", stderr
    assert _samples_files(temporary) == [] and not (tmp_path / "out").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["tmp"]
    deadline = time.monotonic() + STOP_TIMEOUT_S
    while any(_alive(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert workers and not any(_alive(pid) for pid in workers), workers
