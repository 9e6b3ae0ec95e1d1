"""The one command path: a parsed case to a design (or one equilibrium) and its output folder.

`run` checks the grid, loads the sections, builds the bays, calls the design
library (`inverse_design.optimise_pressure`, `inverse_design.optimise_wing`,
`inverse_design.refine_design`; ``--evaluate``: `inverse_design.evaluate_design`,
one equilibrium) and the aerodynamic comparison of each bay, and hands the
result to the report writer, for one bay or a wing alike. No physics lives here.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import threading
import time

from . import interrupts
from .case import check_equilibrium_method, design_inputs, ignored_options, load_section, report_may_write
from .options import PROG, InputError
from ..memory import design_tangents
from .resources import check_design_memory, check_flat_panels, check_grid
from .tolerance import check_tolerance_options, run_tolerance

__all__ = ["NOT_FOR_A_WING", "WORKER_MODULES", "plausibility", "run", "safe_point"]

#: Options that a wing's case file gives per rib instead, and where.
NOT_FOR_A_WING = {
    "chord": "give each rib's chord in its [[rib]] table",
    "rib_spacing": "give each rib's station in its [[rib]] table",
    "rib": "give each rib's section in its [[rib]] table",
}


def safe_point(entry=None) -> None:
    """The optimiser's per-iterate callback: raise a stop that was recorded but lost (`interrupts.check`)."""
    interrupts.check()


#: The report's libraries, imported ahead (`_import_report_modules_meanwhile`).
REPORT_MODULES = ("matplotlib.figure", "matplotlib.backends.backend_agg", "ezdxf")
#: What the report's workers (`workers.ReportWorkers`) import while the design runs: the libraries of
#: the figures and of the DXF patterns they write, and the modules their tasks name.
WORKER_MODULES = ("matplotlib.figure", "matplotlib.backends.backend_agg", "ezdxf", "inverse_design.app.cut_files")


def _import_report_modules() -> None:
    for name in REPORT_MODULES:
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001 - the report imports it again and says what failed
            pass


def _import_report_modules_meanwhile() -> None:
    """Import the report's libraries (matplotlib, ezdxf: 0.4 s) on a second thread while the design
    runs: the design's compiling and computing release Python's lock, the import takes it then
    (measured: the design slows by about what the report saves)."""
    if (os.cpu_count() or 1) > 1:
        threading.Thread(target=_import_report_modules, name="import-report", daemon=True).start()


def run(args: argparse.Namespace, sources: dict | None = None, progress: bool = False,
        started: float | None = None, workers=None) -> dict:
    """Run the case described by ``args`` (one bay, or a wing of ``[[rib]]`` tables), write the output
    folder and return its summary.

    One path for any number of bays: the sections are loaded and checked
    before JAX is imported, the output folder is checked before the long
    work, the design runs (`optimise_pressure` for a bay given by options,
    `optimise_wing` for ``[[rib]]`` tables; every method where the physics
    allows it, ``--refine``, the solver options) or, with ``--evaluate``, one
    equilibrium is measured (`evaluate_design`), ``--aero`` compares each
    bay's sections with its target, and `report.write_report` writes the
    folder. A wing refuses the options of `NOT_FOR_A_WING` and, on several
    bays, ``--method root``, with one line that says why. The whole run holds the output folder's lock
    (`export.output_lock`): a second run into the same ``--out`` meanwhile is
    refused at once (ValueError, exit 2) instead of racing this one.

    ``started`` (a `time.perf_counter` value) dates the ``setup`` timing back, e.g. to the
    start of `main`, so that it includes importing JAX. ``workers`` (a
    `workers.ReportWorkers`, the command's, which import `WORKER_MODULES`) write figures and
    DXF patterns (`report.write_report`).

    Raises:
        ValueError: bad input (`InputError` among them).
        forward_solver.ConvergenceError: a forward solve failed (nothing written).
    """
    from .export import output_lock

    with output_lock(args.out):
        return _run(args, sources, progress=progress, started=started, workers=workers)


def _run(args: argparse.Namespace, sources: dict | None, progress: bool, started: float | None, workers) -> dict:
    """`run`'s work, under the lock."""
    start = time.perf_counter() if started is None else started
    sources = dict(sources or {})
    wing_ribs = getattr(args, "wing", None)  # [[rib]] tables of a case file, or None: one bay
    if wing_ribs is not None:
        for option, why in NOT_FOR_A_WING.items():
            if option in sources:
                raise InputError(f"{option.replace('_', '-')} does not apply to a wing ([[rib]] tables in "
                                 f"{args.config}): {why}")
        if args.method == "root" and len(wing_ribs) > 2 and not args.evaluate:
            raise InputError(f"method root does not apply to a wing of {len(wing_ribs) - 1} bays ([[rib]] tables in "
                             f"{args.config}): root finding solves one scalar condition at one bay's mid-bay "
                             "section: use slsqp, gauss_newton, least_squares or optax")
    check_grid(args.n_span, args.n_contour, evaluate=args.evaluate, allow_large=args.allow_large_grid)
    if args.max_steps < 1:
        raise InputError(f"--max-steps must be a positive integer, got {args.max_steps}")
    if not args.seam_allowance >= 0:
        raise InputError(f"--seam-allowance must be 0 mm or more (the cut line lies outside the sewing line), "
                         f"got {args.seam_allowance:g}: give 0 or a positive number of mm")
    alphas = _aero_angles(args) if args.aero else None  # (before any solve: a missing package fails fast)
    # The sections, before importing JAX: bad input fails fast.
    if wing_ribs is None:
        target = load_section(args.target, "--target")
        rib = target if args.rib is None else load_section(args.rib, "--rib")
    else:
        where = args.config
        common = load_section(args.target, "--target") if "target" in sources else None
        sections = [load_section(r["section"], f"{where}: rib {k}: section") for k, r in enumerate(wing_ribs)]
        targets = [(load_section(r["target"], f"{where}: rib {k}: target") if "target" in r else
                    common if common is not None else sections[k]) for k, r in enumerate(wing_ribs)]
    from forward_solver import Bay, Fabric, Scene, Wing
    from forward_solver.derivatives.custom_jvp import GRADIENT_RTOL
    from forward_solver.solvers.bays import check_rib_gaps, default_strategy

    from .. import methods
    from ..optimise import evaluate_design, optimise_pressure, optimise_wing, refine_design
    from ..settings import DesignRequest, Layout, Limits, SolverSettings
    from .export import check_output_folder
    from .report import ReportOptions, write_report

    out = check_output_folder(args.out, replaces=report_may_write(args))  # before the long work, not after it
    check_equilibrium_method(args, default_strategy())
    _import_report_modules_meanwhile()  # (the figures are built here, also when workers save them)
    fabric = Fabric(stiffness_span=args.stiffness_span, stiffness_chord=args.stiffness_chord, poisson=args.poisson)
    initial, variables, rib_limits, bounds, constraints = design_inputs(args)
    tolerances = check_tolerance_options(args, fabric)  # (before any solve)
    solver = None if args.evaluate else SolverSettings(max_iterations=args.max_iterations,
                            equilibrium_method=args.equilibrium_method, max_steps=args.max_steps,
                            progress=progress, callback=safe_point)
    method = None if args.evaluate else methods.named(args.method, objective=args.objective, tolerance=args.tolerance,
                                                      condition=args.root_condition)
    # (a single equilibrium is solved to solve_equilibrium's default residual, not the gradients')
    equilibrium = SolverSettings(rtol=1e-8, equilibrium_method=args.equilibrium_method, max_steps=args.max_steps)
    options = dict(bounds=bounds, limits=Limits(tension=constraints, ribs=rib_limits), solver=solver)
    if args.objective == "robust":  # (designed for the tolerances the analysis then reports)
        options["tolerances"] = tolerances
    inputs = {"wing": None, **vars(args), "sources": sources}  # (the same keys for a bay and a case file's ribs)
    if wing_ribs is None:
        scene = Scene(Bay.from_airfoil(rib, chord=args.chord, rib_spacing=args.rib_spacing, n_span=args.n_span,
                                       n_contour=args.n_contour), fabric)
        bays = [(args.rib_spacing, args.chord)]

        def design():
            return optimise_pressure(scene, target, variables=variables, initial=initial, objective=args.objective,
                                     method=method, **options)

        def evaluate():
            return evaluate_design(scene, target, initial, objective=args.objective, wing=Wing.from_scene(scene),
                                   solver=equilibrium)
    else:
        try:
            wing = Wing(airfoils=tuple(sections), chords=tuple(r["chord"] for r in wing_ribs),
                        stations=tuple(r["station"] for r in wing_ribs), trailing_edge=args.trailing_edge)
        except ValueError as exc:
            raise InputError(f"{where}: {exc}") from None
        chords, stations = wing.chords, wing.stations
        # Ribs too close for the grid are refused before any warning about the inputs is shown.
        check_rib_gaps(wing, fabric, initial, n_span=args.n_span, n_contour=args.n_contour, rtol=GRADIENT_RTOL)
        if not args.evaluate:  # a design that would not fit in memory: refused before any solve
            check_design_memory(wing.n_bays, args.n_span, args.n_contour, design_tangents(
                variables, wing.n_bays, cut_pattern_terms=args.cut_pattern_terms, rib_shape_terms=args.rib_shape_terms,
                cut_pattern=args.cut_pattern_layout), allow_large=args.allow_large_grid)
        bays = [(stations[k + 1] - stations[k], 0.5 * (chords[k] + chords[k + 1])) for k in range(len(chords) - 1)]
        layout = Layout(cut_pattern=args.cut_pattern_layout, n_span=args.n_span, n_contour=args.n_contour)

        def design():
            return optimise_wing(wing, fabric, targets, DesignRequest(variables, initial, objective=args.objective,
                                                                      method=method, layout=layout, **options))

        def evaluate():
            return evaluate_design(wing.scenes(fabric, args.n_span, args.n_contour), targets, initial,
                                   objective=args.objective, wing=wing, solver=equilibrium)
    notes = plausibility(args, fabric, initial, bays, None if args.evaluate else bounds, sources)
    if not args.no_patterns:  # (before the design: the report would fail after it)
        check_flat_panels([scene] if wing_ribs is None else wing.scenes(fabric, n_span=args.n_span,
                                                                       n_contour=args.n_contour),
                          initial, wing=wing_ribs is not None)
    interrupts.check()  # (a stop during the checks: before the long work)
    timings = {"setup": time.perf_counter() - start}
    if progress:  # (a terminal: the progress bar's first line, before the first solve compiles)
        print(f"{PROG}: {_starting_line(args, len(bays))}", file=sys.stderr, flush=True)
    _native_call_for_tests()
    t = time.perf_counter()
    if args.evaluate:
        result = evaluate()
        timings["equilibrium"] = time.perf_counter() - t
    else:
        result = design()
        if args.refine:  # (the design again on twice the span rows)
            result = refine_design(result, Layout(n_span=2 * args.n_span - 1, n_contour=args.n_contour))
        timings["optimisation"] = time.perf_counter() - t
    aero = _aero(args, result, alphas, timings)
    tolerance = run_tolerance(args, result, tolerances, timings, notes) if tolerances else None
    interrupts.check()
    report = ReportOptions(bounds=None if args.evaluate else bounds, magnification=args.magnification,
                           rib_limits=rib_limits, patterns=not args.no_patterns,
                           seam_allowance_mm=args.seam_allowance, inputs=inputs, timings=timings, aero=aero,
                           warnings=notes, tolerance=tolerance)
    try:
        return write_report(out, result, options=report, workers=workers)
    finally:
        if tolerance is not None and tolerance.samples_file:
            os.unlink(tolerance.samples_file)


def _starting_line(args: argparse.Namespace, n_bays: int) -> str:
    """What the run solves now, shown before its first solve (which compiles the solver: minutes for a
    large wing without a compilation cache, before the progress bar's first tick)."""
    from .case import variable_names

    bays = f"{n_bays} bays" if n_bays > 1 else "1 bay"
    grid = f"{args.n_span} x {args.n_contour} nodes{' each' if n_bays > 1 else ''}"
    if args.evaluate:
        return f"solving the equilibrium of {bays} of {grid}"
    names = ", ".join(variable_names(args.variables))
    return (f"designing {bays} of {grid} ({names}; method {args.method}, at most {args.max_iterations} "
            "iterations): the first wing solve compiles the solver")


#: Test hook, read by `_native_call_for_tests`: set to a number of seconds, the command sits about that long
#: in one compiled XLA call (which takes no signal) just before its design or equilibrium, as a large
#: wing's first solve does (tests/command/test_signals.py).
NATIVE_CALL_VARIABLE = "INFLATABLE_WING_TEST_NATIVE_CALL_S"


def _native_call_for_tests() -> None:
    """The test hook of `NATIVE_CALL_VARIABLE` (nothing unless it is set)."""
    seconds = float(os.environ.get(NATIVE_CALL_VARIABLE) or 0.0)
    if seconds > 0:
        import jax

        spin = jax.jit(lambda n: jax.lax.fori_loop(0, n, lambda i, x: x * 1.0000001 + 1e-9, 1.0))
        spin(int(min(seconds, 20.0) * 1e8)).block_until_ready()  # (about 1e8 steps a second on a CPU core)


def plausibility(args: argparse.Namespace, fabric, parameters, bays, bounds, sources: dict | None = None) -> list[str]:
    """The run's warning lines, each shown on stderr as one ``warning:`` line (unless ``--quiet``);
    the caller records them in the summary: `inverse_design.plausibility.check_plausibility`'s (the
    inputs, the grid, the seam allowance, the terms of the designed fields, the Reynolds number),
    the options given that the run ignores (`case.ignored_options`), and the earlier report's files
    that changed since and that this run keeps (`export.changed_files`)."""
    from ..plausibility import LIMITS, check_plausibility
    from .case import variable_names
    from .export import changed_files

    names = variable_names(args.variables)
    terms = {name: getattr(args, f"{name}_terms") for name in ("cut_pattern", "rib_shape")
             if name in names and not args.evaluate}
    lines = check_plausibility(fabric, parameters, bays, bounds, grid=(args.n_span, args.n_contour),
                               design=not (args.evaluate or args.refine and 2 * args.n_span - 1 >= LIMITS["n_span"]),
                               seam_allowance_mm=None if args.no_patterns else args.seam_allowance,
                               terms=terms, reynolds=args.reynolds if args.aero else None, warn=False)
    lines += ignored_options(args, sources or {})
    may_write = report_may_write(args)
    lines += [f"{name} in {args.out} changed since the earlier report wrote it: kept as it is (this run "
              f"writes no {name}), and no longer counted as a report file"
              for name in changed_files(args.out) if not may_write(name)]
    if not args.quiet:
        for line in lines:
            print(f"{PROG}: warning: {line}", file=sys.stderr)
    return lines


def _aero_angles(args: argparse.Namespace):
    """The angles of ``--aero``, after checking that NeuralFoil is installed (`InputError` if not)."""
    from ..aero import AeroUnavailable, alpha_range, require_neuralfoil

    try:
        require_neuralfoil()
    except AeroUnavailable as exc:
        raise InputError(f"--aero: {exc}") from None
    try:
        return alpha_range(*args.alpha_range)
    except ValueError as exc:
        raise InputError(f"--alpha-range: {exc}") from None


def _aero(args: argparse.Namespace, result, alphas, timings: dict):
    """The `inverse_design.aero.AeroComparison` of each bay with ``--aero`` (None without it): its mid-bay
    and bay-average sections against its mid-bay target, at its mean chord; times it."""
    if not args.aero:
        return None
    from ..aero import aerodynamic_cost
    from .report import mid_bay_targets

    t = time.perf_counter()
    sol = result.wing_solution
    comparisons = [aerodynamic_cost(sol.bay_solution(k), target, float(sol.bays[k].chord), reynolds=args.reynolds,
                                    alphas=alphas) for k, target in enumerate(mid_bay_targets(result))]
    timings["aero"] = time.perf_counter() - t
    return comparisons
