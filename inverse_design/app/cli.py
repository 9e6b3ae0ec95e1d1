"""``optimise-pressure``: the command line, a thin layer over the public API.

It parses the options (and a TOML case file, ``--config``), builds the
`forward_solver.Scene`, calls `inverse_design.optimise_pressure` (or, with
``--evaluate``, `forward_solver.solve_equilibrium` once) and hands the result
to `inverse_design.app.report.write_report`, which writes the output folder. No
physics lives here.

Exit codes: 0 success; 1 the run failed (a forward solve did not converge:
nothing written; or the optimiser stopped without converging: the folder is
written and says so); 2 bad input (one line on stderr), a grid too large
for the machine among it (`inverse_design.app.resources.check_grid`); 130
interrupted (Ctrl-C); 143 terminated (SIGTERM: `main` makes it unwind like
Ctrl-C, so the staging folder is removed). A stop that Python loses (raised
inside a garbage-collection callback) is recorded and raised again at the
next safe point (`inverse_design.app.interrupts`), at the latest before the
folder's files are put in place.

The solvers run in their own thread-local float64 scope. Unlike the
library, the command turns on JAX's persistent compilation cache for its own
process (`compilation_cache_dir`: ``$INFLATABLE_WING_CACHE``, else JAX's own
``$JAX_COMPILATION_CACHE_DIR``, else ``$XDG_CACHE_HOME/inflatable-wing/jax``,
else ``~/.cache/inflatable-wing/jax``;
``--no-compilation-cache`` turns it off; deleting the folder clears it), so a
second run of a grid compiles nothing, and keeps the solver's main programs
in its ``programs`` sub-folder (`forward_solver.programs`), so a second run
loads them without tracing and lowering them again. It also compiles with
XLA's faster-compiling CPU loop emitters (`forward_solver.xla.enable_fast_compilation`,
unless ``XLA_FLAGS`` chooses otherwise): about 40% less compile time, the
same results; and its report's figures and DXF patterns are written by
workers forked as it starts, which import matplotlib and ezdxf while the
design runs (`inverse_design.app.drawing.ReportWorkers`; a wing's figures by
a child forked after they are built), on for the command's own run only.
"""

from __future__ import annotations

import atexit
import gc
import json
import os
import sys
import time
from pathlib import Path

from forward_solver.xla import enable_fast_compilation

from . import interrupts
from .case import parse_arguments
from .console import describe
from .drawing import ReportWorkers, set_parallel_figures
from .interrupts import Terminated
from .options import PROG, InputError
from .command import WORKER_MODULES, run

__all__ = ["EXIT_INTERRUPTED", "EXIT_TERMINATED", "InputError", "Terminated", "main", "command"]

#: Exit codes of a run stopped by Ctrl-C (SIGINT) or SIGTERM: 128 + the signal number, as a shell reports it.
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143


def _exit_now(code: int) -> None:
    """End the process at once (``os._exit``) after flushing the output.

    An interruption can abandon an XLA compilation that goes on in a thread
    of JAX's own; the interpreter's normal shutdown then destroys the CPU
    client under it and the process dies of SIGSEGV instead of exiting with
    ``code`` (seen with JAX 0.10.2, Ctrl-C and SIGTERM alike). The output
    folder's staging has been cleaned up by then (the exception unwound it).
    """
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def _finish(code: int) -> None:
    """End the command's process with ``code`` once its work is done: the exit functions run
    (``atexit``), then `_exit_now` skips the interpreter's teardown of its modules and of XLA's
    client (0.5 s of every run with JAX, SciPy and matplotlib loaded, on the 2-core development
    machine: 8% of the default case). Every file of the run is closed by then."""
    atexit._run_exitfuncs()
    _exit_now(code)


def main(argv: list[str] | None = None) -> int:
    """The ``optimise-pressure`` command's work on ``argv`` (default the command line); returns the exit code.

    While it runs, SIGTERM raises `Terminated`, which unwinds like Ctrl-C
    (the staging folder is removed): exit code 143, or 130 for Ctrl-C. Both
    are recorded too (`interrupts.install`), so that one lost inside a
    callback is raised again at the next safe point. The previous handlers
    are restored on return. Run as the command
    (``argv`` None), an interrupted or terminated run ends the process
    itself with that code (see `_exit_now`); otherwise it returns (the console script,
    `command`, then ends the process).
    """
    started = time.perf_counter()
    previous = interrupts.install()
    flags = os.environ.get("XLA_FLAGS")
    enable_fast_compilation()  # before the run's first JAX computation
    figures = set_parallel_figures(True)  # the report's figures on a second core (`drawing`)
    try:
        code = _main(argv, started)
    except Terminated:  # before the run (importing JAX) or after its folder was written
        print(f"{PROG}: terminated", file=sys.stderr)
        code = EXIT_TERMINATED
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        code = EXIT_INTERRUPTED
    finally:
        interrupts.restore(previous)
        set_parallel_figures(figures)
        if flags is None:  # (read by XLA when its backend started: a caller's later children see theirs)
            os.environ.pop("XLA_FLAGS", None)
        else:
            os.environ["XLA_FLAGS"] = flags
    if argv is None and code in (EXIT_INTERRUPTED, EXIT_TERMINATED):
        _exit_now(code)
    return code


def command() -> None:
    """The ``optimise-pressure`` console script: `main` on the command line's arguments, then the
    process ends with its exit code (`_finish`)."""
    _finish(main())


def compilation_cache_dir() -> Path:
    """Where the command keeps JAX's compiled functions between runs (module docstring)."""
    for variable in ("INFLATABLE_WING_CACHE", "JAX_COMPILATION_CACHE_DIR"):
        if os.environ.get(variable):
            return Path(os.environ[variable])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "inflatable-wing" / "jax"


#: Environment variable that, set to "0", keeps the command from using the program store (JAX's
#: persistent cache alone), e.g. to measure what the store saves.
PROGRAM_STORE_VARIABLE = "INFLATABLE_WING_PROGRAM_STORE"


def use_compilation_cache(path: Path, profile: str | None = None) -> None:
    """Turn on JAX's persistent compilation cache in ``path`` for this process (every entry kept:
    the solver's functions compile in 0.3-6 s each and load in milliseconds), and the solver's
    program store in its ``programs`` sub-folder (`forward_solver.programs`: its main programs
    load without being traced and lowered again; ``INFLATABLE_WING_PROGRAM_STORE=0`` leaves it off).
    With a ``profile`` (`program_profile`), the store starts loading the programs that the last run
    of that profile used, on two threads (`forward_solver.programs.ProgramStore.prefetch`)."""
    import jax

    from forward_solver.programs import use_program_store

    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    if os.environ.get(PROGRAM_STORE_VARIABLE, "").strip() != "0":
        use_program_store(Path(path) / "programs")
        if profile is not None:
            from forward_solver.programs import program_store

            program_store().prefetch(profile)


def program_profile(args) -> str:
    """The kind of run whose compiled programs are alike (the grid, the number of bays, the
    variables, the methods and the objective), as the program store's profile: a run loads ahead
    what the last run of its profile used (`use_compilation_cache`)."""
    wing = getattr(args, "wing", None)
    return json.dumps({"grid": [args.n_span, args.n_contour], "bays": 1 if wing is None else len(wing) - 1,
                       "variables": args.variables, "method": args.method, "equilibrium": args.equilibrium_method,
                       "objective": args.objective, "evaluate": args.evaluate, "refine": args.refine,
                       "aero": args.aero}, sort_keys=True)


def _freeze_imports() -> bool:
    """Move every object the garbage collector tracks now to its permanent generation (``gc.freeze``)
    for the run, unless something else froze objects already; returns whether it did (then the
    caller unfreezes them after the run)."""
    if gc.get_freeze_count():
        return False
    gc.freeze()
    return True


def _remember_programs(profile: str) -> None:
    """The program store's list of this run's programs, for the next run of ``profile`` to load ahead."""
    from forward_solver.programs import program_store

    store = program_store()
    if store is not None:
        store.remember(profile)


def _interrupted(exc: KeyboardInterrupt, out: str) -> int:
    """The one-line message and exit code of a run stopped by Ctrl-C or SIGTERM."""
    terminated = isinstance(exc, Terminated)
    print(f"{PROG}: {'terminated' if terminated else 'interrupted'}; nothing was written to {out}",
          file=sys.stderr)
    return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED


def _main(argv: list[str] | None, started: float) -> int:
    try:
        args, sources = parse_arguments(argv)
    except InputError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    progress = sys.stderr.isatty() and not (args.quiet or args.json)
    workers, frozen, profile = None, False, program_profile(args)
    try:
        from forward_solver import ConvergenceError  # (JAX, unless the package imported it already)

        # Everything imported so far lives as long as the process: out of the garbage collector's
        # way, a full collection during the run no longer walks it (one took 0.09 s of the cached
        # default case), and the workers forked next share those pages untouched (`_freeze_imports`).
        frozen = _freeze_imports()
        # A single bay's figures and DXF patterns: workers forked now, before any other thread (the
        # store's below) or JAX's backend starts, import matplotlib and ezdxf while the design runs
        # (`drawing.ReportWorkers`).
        if getattr(args, "wing", None) is None:
            workers = ReportWorkers.start(WORKER_MODULES)
        if not args.no_compilation_cache:
            use_compilation_cache(compilation_cache_dir(), profile)
    except BaseException as exc:  # (the workers and the frozen objects are given back whatever ends it)
        if workers is not None:
            workers.close()
        if frozen:
            gc.unfreeze()
        if isinstance(exc, KeyboardInterrupt):
            return _interrupted(exc, args.out)
        raise
    try:
        summary = run(args, sources, progress=progress, started=started, workers=workers)
        if not args.no_compilation_cache:
            _remember_programs(profile)
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (`Terminated`)
        return _interrupted(exc, args.out)
    except (ConvergenceError, ValueError, OSError) as exc:
        try:
            # An error raised while a stop unwound the run is the stop's doing: a Ctrl-C inside
            # np.savez_compressed leaves a zip member open, and closing the zip file then raises
            # ValueError in place of the KeyboardInterrupt.
            interrupts.check()
        except KeyboardInterrupt as stop:
            return _interrupted(stop, args.out)
        if isinstance(exc, ConvergenceError):  # a forward solve failed: the reason, exit 1
            print(f"{PROG}: failed: {exc}; nothing was written to {args.out}", file=sys.stderr)
            return 1
        if isinstance(exc, ValueError):  # bad input: one line, no traceback
            print(f"{PROG}: error: {exc}", file=sys.stderr)
            return 2
        # input files are read (and checked) before: this is the output
        print(f"{PROG}: failed: could not write {args.out}: {exc}", file=sys.stderr)
        return 1
    finally:
        if workers is not None:  # (unused, or left running by an error: killed and reaped)
            workers.close()
        if frozen:
            gc.unfreeze()
    try:
        interrupts.check()  # a stop that arrived while the files were put in place
    except KeyboardInterrupt as exc:
        terminated = isinstance(exc, Terminated)
        print(f"{PROG}: {'terminated' if terminated else 'interrupted'} after the report was complete "
              f"in {summary['out']}", file=sys.stderr)
        return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED
    if args.json:
        print(json.dumps(summary, indent=2))
    elif not args.quiet:
        print("\n".join(describe(summary)))
    if not summary["results"]["success"]:
        why = ("the design breaks its tension limits" if summary["constraints"]["violated"]
               else "the optimiser did not converge")
        patterns = "" if args.no_patterns else "; no panel or rib template (DXF, SVG) was written"
        print(f"{PROG}: failed: {why}: {summary['results']['message']} "
              f"(the results are in {summary['out']}{patterns})", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    command()
