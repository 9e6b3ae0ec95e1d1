"""``optimise-pressure``: the command line, a thin layer over the public API.

It reads the options (and a TOML case file, ``--config``) into one checked
`inverse_design.app.case.Case` and runs it (`inverse_design.app.run.run_case`:
the design by `inverse_design.optimise_wing`, or with ``--evaluate`` one
equilibrium, and the output folder). No physics lives here.

Exit codes (docs/command.md): 0 success; 1 the run failed (a forward solve
did not converge: nothing written; or the design did not succeed: the folder
is written and says so); 2 bad input, one line on stderr (docs/errors.md);
130 interrupted (Ctrl-C); 143 terminated (SIGTERM: `main` makes it unwind
like Ctrl-C, so the staging folder is removed). The design and the report
run on a thread of their own while the main thread waits, free to take a
signal whatever the work computes (`interrupts.run_stoppable`): a stop ends
the command within about a second (`interrupts.UNWIND_GRACE_S`), without
waiting for the work's compiled call to return. A stop that Python loses
(raised inside a garbage-collection callback) is recorded and raised again at
the next safe point (`inverse_design.app.interrupts`), at the latest before
the folder's files are put in place.

Unlike the library, the command turns on JAX's persistent compilation cache
for its own process (`compilation_cache_dir`: ``$INFLATABLE_WING_CACHE``,
else ``$JAX_COMPILATION_CACHE_DIR``, else
``$XDG_CACHE_HOME/inflatable-wing/jax``, else ``~/.cache/inflatable-wing/jax``;
``--no-compilation-cache`` turns it off), and keeps the solver's top-level
programs exported in its ``programs`` sub-folder
(`forward_solver.compilation`): a second run of a grid neither
traces, lowers nor compiles them. A cache folder that cannot be used (the
command never creates a user's home) or whose entries JAX cannot read gets
one ``warning:`` line, and the run goes on without it. It also compiles with
XLA's faster-compiling CPU loop emitters
(`forward_solver.compilation.enable_fast_compilation`, unless ``XLA_FLAGS``
chooses otherwise: about 40% less compile time, the same results); starts
the report's worker processes, which import matplotlib and ezdxf while the
design runs (`inverse_design.app.workers.ReportWorkers`); runs BLAS on one
thread (``threadpoolctl``: its solves are too small to gain from threads, and
on a busy 2-core machine OpenBLAS's waiting threads made the default case's
panels take 29 s instead of 0.1 s); and collects cyclic garbage less often (`GC_THRESHOLD`). It
imports JAX once the options are read and the report's workers started, not
when this module is imported: bad input and ``--help`` answer without it,
and a report worker, started by ``spawn``, imports the command's module
again as its main module.

Every Python warning of the run (an `targets.AirfoilWarning` among them) is
shown as one ``optimise-pressure: warning: ...`` line. A failure line is kept
to `CONSOLE_WIDTH` characters, a refusal of bad input to `REFUSAL_WIDTH`, so
that its reason and its fix stay whole: its first clause and its last; the
whole text is in the summary's ``results.message`` where a report is written,
and on stdout as ``{"error": ...}`` under ``--json``. A JAX platform that the
machine does not have (``JAX_PLATFORMS=cuda`` without one) is bad input.
"""

from __future__ import annotations

import gc
import json
import os
import signal
import sys
import time
import warnings
from pathlib import Path

from threadpoolctl import threadpool_limits


from . import interrupts
from .case import Case
from .console import describe
from .interrupts import Terminated
from .options import PROG, InputError
from .workers import ReportWorkers, worker_modules

__all__ = ["CONSOLE_WIDTH", "REFUSAL_WIDTH", "EXIT_INTERRUPTED", "EXIT_TERMINATED", "InputError", "Terminated", "main", "command"]

#: Exit codes of a run stopped by Ctrl-C (SIGINT) or SIGTERM: 128 + the signal number, as a shell reports it.
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143
#: Most characters of a message in a failure line, and of a refusal's (module docstring).
CONSOLE_WIDTH = 200
REFUSAL_WIDTH = 600


def _say(line: str, stdout: bool = False) -> OSError | None:
    """Print ``line`` on stderr (``stdout``: on stdout, flushed), if the process has it (a closed one is
    None); returns the error of a stream that cannot take it (a full device, a broken pipe), else None."""
    stream = sys.stdout if stdout else sys.stderr
    if stream is None:
        return None
    try:
        print(line, file=stream)
        if stdout:
            stream.flush()
    except (OSError, ValueError) as exc:  # (ValueError: a stream closed under us)
        return exc if isinstance(exc, OSError) else OSError(str(exc))
    return None


def _flush_streams() -> None:
    for stream in (sys.stdout, sys.stderr):
        try:
            if stream is not None:
                stream.flush()
        except (OSError, ValueError):  # (a closed pipe: nothing more can be said)
            pass


def _exit_now(code: int) -> None:
    """End the process at once (``os._exit``) after flushing the output.

    An interruption can abandon an XLA compilation that goes on in a thread
    of JAX's own; the interpreter's normal shutdown then destroys the CPU
    client under it and the process dies of SIGSEGV instead of exiting with
    ``code`` (seen with JAX 0.10.2, Ctrl-C and SIGTERM alike). At the end of
    a run it also skips the interpreter's teardown of JAX, SciPy and
    matplotlib (0.5 s on the 2-core development machine). Every file of the
    run is closed and its workers have ended by then.
    """
    _flush_streams()
    os._exit(code)


def shorten(text: str, width: int = CONSOLE_WIDTH) -> str:
    """``text`` on one line of at most about ``width`` characters: whole if it fits, else its first
    clause and its last (a message's reason and its fix), joined by " ... ", or its start."""
    text = " ".join(str(text).split())
    if len(text) <= width:
        return text
    clauses = text.split("; ")
    if len(clauses) > 1 and len(clauses[0]) + len(clauses[-1]) + 5 <= width:
        return f"{clauses[0]}; ... {clauses[-1]}"
    return text[:width - 4].rstrip() + " ..."


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """``warnings.showwarning`` of the command: one ``warning:`` line (module docstring)."""
    text = str(message)
    if "persistent compilation cache" in text or "compilation_cache" in text:
        _cache_failed(text)
        return
    _say(f"{PROG}: warning: {' '.join(text.split())}")  # (whole: the summary keeps the same text)


_CACHE_WARNED = False


def _cache_failed(text: str) -> None:
    """JAX could not read or write an entry of the compilation cache: one line, once, and the cache off."""
    global _CACHE_WARNED
    if not _CACHE_WARNED:
        _CACHE_WARNED = True
        folder = _cache_in_use()
        _say(f"{PROG}: warning: the compilation cache in {folder} could not be used "
             f"({shorten(text.splitlines()[0], 100)}): running without it; delete the folder to rebuild it")
    import jax

    jax.config.update("jax_enable_compilation_cache", False)


def _cache_in_use() -> str:
    import jax

    return str(jax.config.jax_compilation_cache_dir)


def main(argv: list[str] | None = None) -> int:
    """The ``optimise-pressure`` command's work on ``argv`` (default the command line); returns the exit code.

    While it runs, SIGTERM raises `Terminated`, which unwinds like Ctrl-C
    (the staging folder is removed): exit code 143, or 130 for Ctrl-C. Both
    are recorded too (`interrupts.install`), so that one lost inside a
    callback is raised again at the next safe point. The previous handlers
    (and Python's warning display) are restored on return. Run as the
    command (``argv`` None), an interrupted or terminated run ends the process
    itself with that code (see `_exit_now`); otherwise it returns (the console script,
    `command`, then ends the process).
    """
    global _CACHE_WARNED, _HOMELESS
    started = time.perf_counter()
    collection = gc.get_threshold()
    gc.set_threshold(GC_THRESHOLD)  # (before importing JAX: the import alone ran two full collections)
    previous = interrupts.install()
    ended = {}  # "out": the folder, once its report is complete (`_main`)
    flags = os.environ.get("XLA_FLAGS")
    store = _program_store()
    config = None
    try:
        _CACHE_WARNED = False
        config = _config_without_home()
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            code = _main(argv, started, ended)
    except KeyboardInterrupt as exc:  # before the run (importing JAX), or once its report was complete
        if "out" in ended:
            code = _stopped_after(exc, ended["out"])
        else:
            terminated = isinstance(exc, Terminated)
            _say(f"{PROG}: {'terminated' if terminated else 'interrupted'}")
            code = EXIT_TERMINATED if terminated else EXIT_INTERRUPTED
    finally:
        interrupts.hold()  # (a stop from here on is recorded: `_main` may have returned already)
        gc.set_threshold(*collection)
        late = interrupts.received() if "out" in ended else None
        interrupts.restore(previous)
        if config is not None:
            _HOMELESS = None
            for variable in _CONFIG_VARIABLES:
                os.environ.pop(variable, None)
            config.cleanup()
        _program_store(store)  # (a library caller's own programs are jitted as before)
        if flags is None:  # (read by XLA when its backend started: a caller's later children see theirs)
            os.environ.pop("XLA_FLAGS", None)
        else:
            os.environ["XLA_FLAGS"] = flags
    if late is not None and code not in (EXIT_INTERRUPTED, EXIT_TERMINATED):  # a stop once the report was complete
        code = _stopped_after(late, ended["out"])
    if argv is None and code in (EXIT_INTERRUPTED, EXIT_TERMINATED):
        _exit_now(code)
    return code


#: The command's first threshold of Python's cyclic garbage collector (`gc.set_threshold`; Python's
#: default is 700 allocations): importing JAX and the report's libraries, tracing and building figures
#: allocate millions of long-lived objects, and at the default the default case ran 5 full collections
#: (0.26 s) and 58 of the middle generation (0.05 s) on the 2-core development machine; at this one,
#: none and 3, with the same peak memory. Restored when `main` returns.
GC_THRESHOLD = 10_000


def _program_store(folder=False):
    """The program store in use (`forward_solver.compilation`; None if none or not imported yet), or, given a
    ``folder``, that store put back (if the module was imported since)."""
    stored = sys.modules.get("forward_solver.compilation")
    if stored is None:
        return None
    return stored.program_store() if folder is False else stored.use_program_store(folder)


#: The home folder that does not exist, while the command runs with temporary configuration folders.
_HOMELESS: Path | None = None
#: Where matplotlib and ezdxf keep their configuration and caches: under the home folder by default.
_CONFIG_VARIABLES = ("MPLCONFIGDIR", "XDG_CACHE_HOME")


def _config_without_home():
    """Temporary configuration folders for matplotlib and ezdxf (``MPLCONFIGDIR``, ``XDG_CACHE_HOME``,
    for this process and its workers) when the home folder does not exist: they would create it.
    Returns the `tempfile.TemporaryDirectory`, or None (a home folder, or those folders chosen)."""
    global _HOMELESS
    if any(os.environ.get(v) for v in _CONFIG_VARIABLES) or Path.home().is_dir():
        return None
    import tempfile

    folder = tempfile.TemporaryDirectory(prefix="optimise-pressure-")
    _HOMELESS = Path.home()
    for variable in _CONFIG_VARIABLES:
        os.environ[variable] = folder.name
    return folder


def command() -> None:
    """The ``optimise-pressure`` console script: `main` on the command line's arguments, then the
    process ends with its exit code (`_exit_now`: without the interpreter's teardown, so exit
    functions that other code registered with ``atexit`` do not run; a caller that needs them, e.g.
    a coverage or timing harness, calls `main` and exits itself)."""
    _exit_now(main())


def compilation_cache_dir() -> Path:
    """Where the command keeps JAX's compiled functions between runs (module docstring)."""
    for variable in ("INFLATABLE_WING_CACHE", "JAX_COMPILATION_CACHE_DIR"):
        if os.environ.get(variable):
            return Path(os.environ[variable])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "inflatable-wing" / "jax"


def _cache_problem(path: Path) -> str | None:
    """Why the compilation cache cannot be kept in ``path`` (None: it can; the folder is created,
    but never a home folder that does not exist)."""
    if not any(os.environ.get(v) for v in ("INFLATABLE_WING_CACHE", "JAX_COMPILATION_CACHE_DIR")):
        if _HOMELESS is not None:
            return f"the home folder {_HOMELESS} does not exist"
        if not os.environ.get("XDG_CACHE_HOME") and not Path.home().is_dir():
            return f"the home folder {Path.home()} does not exist"
    if path.exists() and not path.is_dir():
        return f"{path} is not a folder"
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return f"{path} cannot be created ({exc.strerror or exc})"
    if not os.access(path, os.W_OK | os.X_OK):
        return f"{path} is not writable"
    return None


def use_compilation_cache(path: Path) -> bool:
    """Turn on JAX's persistent compilation cache in ``path`` for this process (every entry kept:
    the solver's functions compile in 0.3-6 s each and load in milliseconds), unless the folder
    cannot be used (`_cache_problem`: then one ``warning:`` line, and the run goes without).
    Returns whether the cache is on."""
    problem = _cache_problem(path)
    if problem is not None:
        _say(f"{PROG}: warning: {problem}: running without the compilation cache (set INFLATABLE_WING_CACHE "
             "to a folder you can write, or give --no-compilation-cache)")
        return False
    import jax

    jax.config.update("jax_enable_compilation_cache", True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    from forward_solver.compilation import use_program_store  # (worker: this module imports no JAX at the top)

    use_program_store(path / "programs")  # the solver's top-level programs, traced and lowered once
    return True


def check_platform() -> None:
    """Start JAX's backend; `InputError` naming the platform asked for (``JAX_PLATFORMS``) and those
    present if it cannot start (JAX itself ends in a bare AssertionError)."""
    import jax

    try:
        jax.devices()
    except (RuntimeError, AssertionError, ValueError) as exc:
        asked = os.environ.get("JAX_PLATFORMS") or str(jax.config.jax_platforms or "")
        present = ", ".join(_platforms_present())
        if asked:
            raise InputError(f"JAX_PLATFORMS={asked} asks for a platform this machine does not have (present: "
                             f"{present}): unset JAX_PLATFORMS, or set it to one of those (e.g. JAX_PLATFORMS=cpu)"
                             ) from None
        raise InputError(f"JAX could not start a platform ({shorten(str(exc).splitlines()[0] if str(exc) else type(exc).__name__, 120)}): "
                         f"set JAX_PLATFORMS to one of: {present}") from None


def _platforms_present() -> list[str]:
    """The platforms JAX could start here: the CPU, and each installed plugin (``jax_plugins``)."""
    import pkgutil

    names = ["cpu"]
    try:
        import jax_plugins

        names += [module.name.removeprefix("xla_").rstrip("0123456789") or module.name
                  for module in pkgutil.iter_modules(jax_plugins.__path__)]
    except ImportError:
        pass
    return list(dict.fromkeys(names))


def _interrupted(exc: KeyboardInterrupt, out: str) -> int:
    """The one-line message and exit code of a run stopped by Ctrl-C or SIGTERM."""
    terminated = isinstance(exc, Terminated)
    _say(f"{PROG}: {'terminated' if terminated else 'interrupted'}; nothing was written to {out}")
    return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED


def _error(options, kind: str, text: str, after: str = "") -> None:
    """An error line (`shorten`), and under ``--json`` (``options.json``) the whole text on stdout."""
    _say(f"{PROG}: {kind}: {shorten(text, REFUSAL_WIDTH if kind == 'error' else CONSOLE_WIDTH)}{after}")
    if options is not None and options.json:
        _say(json.dumps({"error": " ".join(str(text).split())}), stdout=True)


def _stopped_after(stop: KeyboardInterrupt | int, out) -> int:
    """The line and exit code of a stop (an exception, or a recorded signal number) that came once the
    report in ``out`` was complete."""
    terminated = isinstance(stop, Terminated) or stop == signal.SIGTERM
    _say(f"{PROG}: {'terminated' if terminated else 'interrupted'} after the report was complete in {out}")
    return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED


def _main(argv: list[str] | None, started: float, ended: dict) -> int:
    """`main`'s work; ``ended["out"]`` is set to the output folder once its report is complete."""
    try:
        with interrupts.deferred():  # (reading the case imports NumPy and SciPy: a stop inside an import breaks it)
            case = Case.from_arguments(argv)
    except InputError as exc:
        _error(None, "error", str(exc))
        return 2
    options = case.options
    if not options.quiet:  # (the case's warnings, at once: a later refusal must not hide them)
        for note in case.notes:
            _say(f"{PROG}: warning: {note}")
    progress = sys.stderr is not None and sys.stderr.isatty() and not (options.quiet or options.json)
    workers = None
    try:
        # A stop is held until the pool and JAX are whole (one inside a starting pool left its
        # semaphores behind, one inside JAX's import broke the import), then raised here.
        with interrupts.deferred():
            # The report's figures and DXF patterns: workers started now import matplotlib and ezdxf
            # while the design runs (`workers.ReportWorkers`); none for a report of neither.
            modules = worker_modules(figures=not options.no_figures, patterns=not options.no_patterns)
            workers = ReportWorkers.start(modules) if modules else None
            # (worker: a spawned report worker imports this module again and must not import JAX; these do)
            from forward_solver import ConvergenceError  # (worker: as above)
            from forward_solver.compilation import enable_fast_compilation  # (worker: as above)

            from .run import run_case  # (worker: as above)

            enable_fast_compilation()  # before the run's first JAX computation
        interrupts.check()
        check_platform()
        if not options.no_compilation_cache:
            use_compilation_cache(compilation_cache_dir())
    except BaseException as exc:  # (the workers are stopped whatever ends it)
        if workers is not None:
            workers.close()
        if isinstance(exc, KeyboardInterrupt):
            return _interrupted(exc, options.out)
        if isinstance(exc, InputError):
            _error(options, "error", str(exc))
            return 2
        raise
    try:
        # BLAS on one thread (module docstring): limited once NumPy's and SciPy's are loaded. On a thread
        # of its own: this one stays free to take a stop (`interrupts.run_stoppable`).
        with threadpool_limits(limits=1, user_api="blas"):
            summary = interrupts.run_stoppable(run_case, case, progress=progress, started=started, workers=workers)
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (`Terminated`)
        # (The workers end below, `ReportWorkers.close`, also those of an abandoned work: its pool is
        # terminated, which kills a busy worker. Killing them before hung the pool's termination: an idle
        # worker holds the task queue's lock while it waits, and a killed one never gives it back.)
        return _interrupted(exc, options.out)
    except (ConvergenceError, ValueError, OSError) as exc:
        try:
            # An error raised while a stop unwound the run is the stop's doing: a Ctrl-C inside
            # np.savez_compressed leaves a zip member open, and closing the zip file then raises
            # ValueError in place of the KeyboardInterrupt.
            interrupts.check()
        except KeyboardInterrupt as stop:
            return _interrupted(stop, options.out)
        if isinstance(exc, ConvergenceError):  # a forward solve failed: the reason, exit 1
            _error(options, "failed", str(exc), f"; nothing was written to {options.out}")
            return 1
        if isinstance(exc, ValueError):  # bad input: one line, no traceback
            _error(options, "error", str(exc))
            return 2
        # input files are read (and checked) before: this is the output
        _error(options, "failed", f"could not write {options.out}: {exc}")
        return 1
    finally:
        if workers is not None:  # (unused, or left running by an error: stopped)
            workers.close()
    ended["out"] = summary["out"]  # the report is complete
    try:
        interrupts.check()  # a stop that arrived while the files were put in place
    except KeyboardInterrupt as exc:
        return _stopped_after(exc, summary["out"])
    # From here on a stop is recorded, not raised (it would cut the output short, or arrive where
    # nothing checks it and end the run with 0), and said at the end (`main`).
    interrupts.hold()
    failed = None
    if options.json:
        failed = _say(json.dumps(summary, indent=2), stdout=True)
    elif not options.quiet:
        failed = _say("\n".join(describe(summary)), stdout=True)
    if failed is not None:
        _say(f"{PROG}: failed: could not print the summary on the standard output ({failed.strerror or failed}); "
             f"the report is complete in {summary['out']}")
        return 1
    if not summary["results"]["success"]:
        why = ("the design breaks its tension limits" if summary["constraints"]["violated"]
               else "the optimiser did not converge")
        patterns = "" if options.no_patterns else "; no panel or rib template (DXF, SVG) was written"
        message = str(summary["results"]["message"])
        whole = "" if shorten(message) == " ".join(message.split()) else "; the whole message is in summary.json"
        _say(f"{PROG}: failed: {why}: {shorten(message)} (the results are in {summary['out']}{patterns}{whole})")
        return 1
    return 0


if __name__ == "__main__":
    command()
