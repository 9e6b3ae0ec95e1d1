"""The run of a case: a checked `case.Case` to a design (or one equilibrium) and its output folder.

`run_case` runs every case on one path, one bay and a wing of ``[[rib]]``
tables alike: the grid and the output folder are checked before the long
work, then the checks that need the solver (`design.check_wing`: ribs too
close for the grid, a design too large for the memory), the warnings about
the inputs, the design (`design.optimise`, `inverse_design.optimise_wing`;
``--refine``: `design.refine`) or one equilibrium (``--evaluate``:
`design.evaluate`), the aerodynamic comparison and the tolerance analysis,
and `folder.write_report` writes the folder. No physics lives here; every
call into the design library is in `design`.
"""

from __future__ import annotations

import importlib
import os
import sys
import threading
import time
import warnings
from contextlib import contextmanager

from ..fabric_range import FabricRangeWarning
from . import design, interrupts
from .case import Case
from .folder import ReportOptions, write_report
from .options import PROG
from .output_folder import changed_files, check_output_folder, output_lock
from .resources import check_grid
from .workers import report_modules

__all__ = ["run_case", "safe_point", "warn", "warnings_into"]

def safe_point(entry=None) -> None:
    """The optimiser's per-iterate callback: raise a stop that was recorded but lost (`interrupts.check`)."""
    interrupts.check()


def _import_report_modules(names: tuple) -> None:
    for name in names:
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001 - the report imports it again and says what failed
            pass


def _import_report_modules_meanwhile(case: Case) -> None:
    """Import the report's libraries (matplotlib, ezdxf: 0.4 s; those its files need: none of matplotlib
    with ``--no-figures``) on a second thread while the design runs: the design's compiling and computing
    release Python's lock, the import takes it then (measured: the design slows by about what the report
    saves)."""
    o = case.options
    names = report_modules(figures=not o.no_figures, drawings=not o.no_patterns or case.marker is not None)
    if names and (os.cpu_count() or 1) > 1:
        threading.Thread(target=_import_report_modules, args=(names,), name="import-report", daemon=True).start()


def run_case(case: Case, progress: bool = False, started: float | None = None, workers=None) -> dict:
    """Run ``case`` (one bay, or a wing of ``[[rib]]`` tables), write the output folder and return its summary.

    The whole run holds the output folder's lock (`output_folder.output_lock`): a second run into the same
    ``--out`` meanwhile is refused at once (ValueError, exit 2) instead of racing this one. ``started`` (a
    `time.perf_counter` value) dates the ``setup`` timing back, e.g. to the start of `cli.main`, so that it
    includes importing JAX. ``workers`` (a `workers.ReportWorkers`, the command's, which import
    `workers.WORKER_MODULES`) write figures and DXF patterns (`folder.write_report`).

    Raises:
        ValueError: bad input (`options.InputError` among them).
        forward_solver.ConvergenceError: a forward solve failed (nothing written).
    """
    with output_lock(case.options.out):
        return _run(case, progress, time.perf_counter() if started is None else started, workers)


def _run(case: Case, progress: bool, start: float, workers) -> dict:
    """`run_case`'s work, under the lock."""
    o = case.options
    check_grid(o.n_span, o.n_contour, evaluate=o.evaluate, allow_large=o.allow_large_grid)
    alphas = design.aero_angles(case) if o.aero else None  # (before any solve: a missing package fails fast)
    out = check_output_folder(o.out, replaces=case.may_write)  # before the long work, not after it
    design.check_equilibrium_method(case)
    _import_report_modules_meanwhile(case)  # (the figures are built here, also when workers save them)
    tolerances = design.tolerances(case)  # (before any solve)
    design.check_wing(case)  # ribs too close for the grid are refused before any warning is shown
    notes = warn(case)
    if not o.no_patterns:  # (before the design: the report would fail after it)
        design.check_flat_panels(case)
    interrupts.check()  # (a stop during the checks: before the long work)
    timings = {"setup": time.perf_counter() - start}
    if progress:  # (a terminal: the progress bar's first line, before the first solve compiles)
        print(f"{PROG}: {_starting_line(case)}", file=sys.stderr, flush=True)
    t = time.perf_counter()
    with warnings_into(notes, o.quiet):
        if o.evaluate:
            result = design.evaluate(case)
            timings["equilibrium"] = time.perf_counter() - t
        else:
            result = design.optimise(case, tolerances, progress=progress, callback=safe_point)
            if o.refine:
                result = design.refine(case, result)
            timings["optimisation"] = time.perf_counter() - t
    marker = None
    if case.marker is not None and result.success:  # (the widest panel checked first, then nested)
        t = time.perf_counter()
        marker = design.marker(case, result, progress=progress, callback=safe_point)
        timings["marker"] = time.perf_counter() - t
    elif case.marker is not None:
        notes.append("no marker (--roll-width): a failed design is not to be cut")
    aero = None
    if alphas is not None:
        t = time.perf_counter()
        aero = design.compare_aero(case, result, alphas)
        timings["aero"] = time.perf_counter() - t
    with warnings_into(notes, o.quiet, only=FabricRangeWarning):  # (the samples' strains beyond the test)
        analysis = design.analyse_tolerances(case, result, tolerances, notes) if tolerances else None
    if analysis is not None:
        timings["tolerance"] = analysis.timings["tolerance"]
        timings["samples"] = analysis.timings.get("samples", 0.0)
    interrupts.check()
    report = ReportOptions(bounds=None if o.evaluate else case.bounds, magnification=o.magnification,
                           rib_limits=case.limits.ribs, patterns=not o.no_patterns, figures=not o.no_figures,
                           seam_allowance_mm=o.seam_allowance, inputs=case.inputs, timings=timings, aero=aero,
                           warnings=notes, tolerance=analysis)
    samples_file = analysis.samples_file if analysis is not None else None
    try:
        with interrupts.undo_if_abandoned(lambda: samples_file and os.unlink(samples_file)):
            return write_report(out, result, options=report, workers=workers, marker=marker)
    finally:
        if samples_file and os.path.exists(samples_file):  # (a stop that abandoned the work removed it)
            os.unlink(samples_file)


def _starting_line(case: Case) -> str:
    """What the run solves now, shown before its first solve (which compiles the solver: minutes for a
    large wing without a compilation cache, before the progress bar's first tick)."""
    o = case.options
    bays = f"{case.n_bays} bays" if case.n_bays > 1 else "1 bay"
    grid = f"{o.n_span} x {o.n_contour} nodes{' each' if case.n_bays > 1 else ''}"
    if o.evaluate:
        return f"solving the equilibrium of {bays} of {grid}"
    return (f"designing {bays} of {grid} ({', '.join(case.variables)}; method {o.method}, at most "
            f"{o.max_iterations} iterations): the first wing solve compiles the solver")


def warn(case: Case) -> list[str]:
    """The run's warning lines, each shown on stderr as one ``warning:`` line (unless ``--quiet``); the
    run records them in the summary: the inputs, the grid, the seam allowance, the terms of the designed
    fields, the Reynolds number (`design.warning_lines`), the options given that the run ignores
    (`case.Case.ignored_options`), and the earlier report's files that changed since and that this run
    keeps (`output_folder.changed_files`)."""
    o = case.options
    lines = design.warning_lines(case) + case.ignored_options()
    lines += [f"{name} in {o.out} changed since the earlier report wrote it: kept as it is (this run "
              f"writes no {name}), and no longer counted as a report file"
              for name in changed_files(o.out) if not case.may_write(name)]
    if not o.quiet:
        for line in lines:
            print(f"{PROG}: warning: {line}", file=sys.stderr)
    return list(case.notes) + lines  # (the case's own, `case.Case.notes`, were shown as it was read)


@contextmanager
def warnings_into(notes: list, quiet: bool, only: type | None = None):
    """Within: a warning of the library (``warnings.warn``; ``only``: of that category alone, the others
    shown as before) is one ``warning:`` line on stderr (unless ``quiet``), whole, and is appended to
    ``notes``, the summary's warnings."""
    before = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if only is not None and not issubclass(category, only):
            return before(message, category, filename, lineno, file, line)
        text = " ".join(str(message).split())
        if text not in notes:
            notes.append(text)
            if not quiet:
                print(f"{PROG}: warning: {text}", file=sys.stderr)

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield
