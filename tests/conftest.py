"""Shared fixtures.

JAX compilation dominates small tests, so tests reuse a few grid shapes and
module- or session-scoped solutions. Tests that call kernels directly run
inside ``jax.enable_x64(True)`` through the ``x64`` fixture; the public API
enters it by itself.

One JAX persistent compilation cache serves the whole run: the test
processes (one per core, pytest-xdist) and every subprocess they start (the
command, README blocks, notebook kernels) share the programs any of them has
compiled. It is a fresh folder each run, removed at the end, so a run starts
cold as on CI, and no test writes to the user's own cache
(``~/.cache/inflatable-wing``).

The run compiles as the command does, with XLA's faster-compiling CPU loop
emitters (`forward_solver.compilation.enable_fast_compilation`, set before any test
starts JAX's backend; its subprocesses inherit it), and without LLVM's
optimisations (`support.command.TEST_XLA_FLAGS`), where compiling, most of a
small test's time, is shorter.

The command's runs in the test processes (`cli.main`) write their reports
serially (the same files; the tests of the workers themselves,
tests/command/test_workers.py, start their own) and use the plain jitted
programs that the library tests compile (`command_in_the_test_processes`);
its runs in subprocesses go through `support.command`, which does the same.

The test processes collect cyclic garbage as the command does (`cli.GC_THRESHOLD`), and freeze what is
alive after each test file (`gc.freeze`): the compiled programs, traces and caches that JAX keeps, over a
million objects by the end, which every full collection walked again (each process spent 6 s of a
two-minute share in 14 of them, and 5 to 12 s at its exit in pytest's last five: `pytest_unconfigure`).
Cyclic garbage left at a file's end stays in memory: the largest process peaked at 4.2 to 4.5 GB against
4.0 to 4.4 GB (docs/architecture.md "Tests").
"""

import gc
import os
import shutil
import tempfile

import jax
import pytest

from forward_solver.compilation import enable_fast_compilation
from inverse_design.app import cli
from support.command import TEST_XLA_FLAGS, NoWorkers, plain_programs

CACHE_VARIABLE = "INFLATABLE_WING_TEST_CACHE"


@pytest.fixture(scope="session", autouse=True)
def command_in_the_test_processes():
    """The command's runs in this process: the report written serially (its workers are fresh interpreters
    that import the report's libraries, a few seconds of CPU each, twice per run), and the solver's plain
    jitted programs, which the library tests compile (the exported ones, `forward_solver.compilation`,
    would compile again; the runs in subprocesses keep them in the run's cache: docs/compilation.md)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(cli, "ReportWorkers", NoWorkers)
        patch.setattr(cli, "use_compilation_cache", plain_programs(cli.use_compilation_cache))
        yield


@pytest.fixture
def x64():
    with jax.enable_x64(True):
        yield


def pytest_configure(config):
    gc.set_threshold(cli.GC_THRESHOLD)
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_backend_optimization_level" not in flags:  # (the caller's own choice stands)
        os.environ["XLA_FLAGS"] = " ".join([flags, *TEST_XLA_FLAGS]).strip()
    enable_fast_compilation()  # (the backend has not started: JAX has computed nothing yet)
    if not os.environ.get(CACHE_VARIABLE):  # the first process of the run (xdist's workers inherit it)
        os.environ[CACHE_VARIABLE] = tempfile.mkdtemp(prefix="inflatable-wing-tests-jax-")
        config.owned_cache = os.environ[CACHE_VARIABLE]
    cache = os.environ[CACHE_VARIABLE]
    # Subprocesses read the environment; this process's JAX was imported already, so configure it.
    os.environ.update(INFLATABLE_WING_CACHE=cache, JAX_COMPILATION_CACHE_DIR=cache,
                      JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0", JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="0")
    jax.config.update("jax_compilation_cache_dir", cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    config.addinivalue_line(
        "markers", "notebooks: executes the study notebooks in notebooks/ in their small mode "
        "(a few minutes); deselect with -m 'not notebooks'")


#: The longest files (seconds in a worker of the whole run, most first: docs/architecture.md "Tests"). They run
#: first: pytest-xdist's ``--dist loadfile`` hands whole files to its workers in collection order
#: (``--no-loadscope-reorder``: else in order of their number of tests, which put the notebooks, four
#: tests, near the end), so the short files at the end fill the gaps and neither worker waits alone
#: for one long file (with the list of 2026-11-26, two long files of solver/ and wing/ came last and
#: one worker ran 18 s alone).
LONGEST_FIRST = (
    "command/test_cli.py",  # 72 s (measured in a run of the whole suite, 2026-11-29, 2-core machine)
    "docs/test_readme.py",  # 57 s
    "docs/test_notebooks.py",  # 54 s
    "solver/test_solver_fallback.py",  # 30 s
    "reliability/test_stress.py",  # 28 s (2026-11-30, its grids test parameters; 40 s before)
    "design/test_cut_field.py",  # 25 s
    "design/test_design_matrix.py",  # 24 s
    "solver/test_closed_bays.py",  # 24 s
    "derivatives/test_transforms.py",  # 21 s
    "wing/test_solve_bays.py",  # 20 s
    "design/test_block_jacobian.py",  # 20 s
    "solver/test_fibre_law.py",  # 19 s
    "solver/test_equilibrium.py",  # 19 s
    "derivatives/test_gradients.py",  # 18 s
    "wing/test_wing_design.py",  # 17 s
    "design/test_fabric_law.py",  # 17 s
    "command/test_samples.py",  # 16 s
    "design/test_optimise.py",  # 16 s
    "command/test_signals.py",  # 15 s
    "solver/test_shear.py",  # 14 s
    "solver/test_fast_equilibrium.py",  # 14 s
    "command/test_report.py",  # 14 s
    "command/test_tolerance_cli.py",  # 13 s
    "design/test_rib_design.py",  # 13 s
)


def pytest_collection_modifyitems(session, config, items):
    def rank(item):
        path = item.nodeid.split("::")[0].removeprefix("tests/")
        return LONGEST_FIRST.index(path) if path in LONGEST_FIRST else len(LONGEST_FIRST)

    items.sort(key=rank)  # (stable: every file keeps its own order, the others their collection order)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_teardown(item, nextitem):
    """After a test file's last test and its fixtures' teardown, freeze what is still alive (module docstring)."""
    result = yield
    if nextitem is None or nextitem.module is not item.module:
        gc.freeze()
    return result


def pytest_unconfigure(config):
    gc.freeze()  # (pytest then runs five full collections, for errors in finalisers: of what is not frozen)
    owned = getattr(config, "owned_cache", None)
    if owned:
        shutil.rmtree(owned, ignore_errors=True)
