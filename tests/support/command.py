"""The command as the tests run it: ``python -m support.command [--report-workers] [--native-call S] ARGS``.

A subprocess of a test runs the command through this launcher, with
``tests/`` on ``PYTHONPATH`` (`environment`): it patches, in the command's
own process, what the test needs, then runs the command as its console
script does (`cli.command`). The production code reads no test variable.

* By default the report is written in the command's process (`NoWorkers`):
  the suite's many runs would each start report workers, fresh interpreters
  that import matplotlib and ezdxf (a few seconds of CPU each); the files are
  the same either way. ``--report-workers`` keeps the command's workers.
* ``--native-call S``: the command sits about S seconds in compiled XLA
  calls, which take no signal, just before its design (after its first
  progress line), as a large wing's first solve does.

The suite's runs in its own processes get the same `NoWorkers`, and run the
solver's plain jitted programs (`plain_programs`): tests/conftest.py.

Nothing here imports JAX at import: a report worker of ``--report-workers``
imports this module again as its main module.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from inverse_design.app import cli

__all__ = ["TEST_XLA_FLAGS", "NoWorkers", "environment", "launch", "main", "plain_programs"]

TESTS = Path(__file__).resolve().parents[1]
ROOT = TESTS.parent
#: The test run's programs compiled without LLVM's optimisations (XLA's default optimises): the same
#: programs, compiled in less time, which is most of a small test's (docs/architecture.md "Tests");
#: tests/conftest.py adds it to ``XLA_FLAGS``, which the run's subprocesses inherit. The command and the
#: library keep XLA's default.
TEST_XLA_FLAGS = ("--xla_backend_optimization_level=0",)


class NoWorkers:
    """`inverse_design.app.workers.ReportWorkers` of a command that writes its whole report itself."""

    @staticmethod
    def start(*args, **kwargs):
        return None


def plain_programs(use_compilation_cache):
    """`cli.use_compilation_cache` without the solver's exported programs (`forward_solver.compilation`):
    a run in a test process uses the plain jitted programs that the library tests there compile (the
    exported ones would compile again)."""
    from forward_solver.compilation import program_store, use_program_store  # (imports JAX: only once a test calls the command)

    def without_stored_programs(path):
        previous = program_store()
        on = use_compilation_cache(path)
        use_program_store(previous)
        return on

    return without_stored_programs


def environment(base=None, **changes) -> dict:
    """``base`` (default ``os.environ``) with the repository and ``tests/`` first on ``PYTHONPATH`` (the code
    under test, however the package is installed, and this launcher), and ``changes`` (None: removed)."""
    env = dict(os.environ if base is None else base)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), str(TESTS), env.get("PYTHONPATH", "")])
    for key, value in changes.items():
        if value is None:
            env.pop(key, None)
        else:
            env[key] = value
    return env


def launch(*args) -> list[str]:
    """The argument list of a subprocess that runs the command on ``args`` through this launcher."""
    return [sys.executable, "-m", "support.command", *map(str, args)]


def _sit_in_native_calls(seconds: float):
    """A wrapper of the command's design that first sits ``seconds`` in compiled XLA calls."""
    import jax

    from inverse_design.app import design

    optimise = design.optimise
    spin = jax.jit(lambda n: jax.lax.fori_loop(0, n, lambda i, x: x * 1.0000001 + 1e-9, 1.0))

    def sitting(*args, **kwargs):
        left = seconds
        while left > 0:  # (about 1e8 steps a second on a CPU core; at most 20 s a call, for int32 counts)
            spin(int(min(left, 20.0) * 1e8)).block_until_ready()
            left -= 20.0
        return optimise(*args, **kwargs)

    design.optimise = sitting


def main(argv: list[str] | None = None) -> None:
    """Take the launcher's options off the front of ``argv`` (default the command line), patch, run."""
    argv = list(sys.argv[1:] if argv is None else argv)
    workers = False
    while argv and argv[0] in ("--report-workers", "--native-call"):
        option = argv.pop(0)
        if option == "--report-workers":
            workers = True
        else:
            _sit_in_native_calls(float(argv.pop(0)))
    if not workers:
        cli.ReportWorkers = NoWorkers
    sys.argv[1:] = argv
    cli.command()


if __name__ == "__main__":
    main()
