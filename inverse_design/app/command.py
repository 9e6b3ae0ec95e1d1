"""The one command path: a parsed case to a design (or one equilibrium) and its output folder.

`run` checks the grid, loads the sections, builds the bays, calls the design
library (`inverse_design.optimise_pressure`, `inverse_design.optimise_wing`,
`inverse_design.refine_design`; ``--evaluate``: `forward_solver.solve_equilibrium`
once) and the aerodynamic comparison, and hands the result to the report
writer. No physics lives here.
"""

from __future__ import annotations

import argparse
import time

from . import interrupts
from .case import design_inputs, load_section
from .options import InputError
from .resources import check_grid

__all__ = ["NOT_FOR_A_WING", "run", "run_wing", "safe_point"]

#: Options that mean nothing for a wing, and what to do instead.
NOT_FOR_A_WING = {
    "chord": "give each rib's chord in its [[rib]] table",
    "rib_spacing": "give each rib's station in its [[rib]] table",
    "rib": "give each rib's section in its [[rib]] table",
    "refine": "run the wing again on a finer grid (n-span, n-contour)",
    "evaluate": "optimise the wing, or solve it with forward_solver.solve_wing",
    "aero": "compare the sections of a single bay",
}


def safe_point(entry=None) -> None:
    """The optimiser's per-iterate callback: raise a stop that was recorded but lost (`interrupts.check`)."""
    interrupts.check()


def run(args: argparse.Namespace, sources: dict | None = None, progress: bool = False,
        started: float | None = None) -> dict:
    """Run the case described by ``args``, write the output folder and return its summary.

    ``started`` (a `time.perf_counter` value) dates the ``setup`` timing back, e.g. to the
    start of `main`, so that it includes importing JAX.

    Raises:
        ValueError: bad input (`InputError` among them).
        forward_solver.ConvergenceError: a forward solve failed (nothing written).
    """
    start = time.perf_counter() if started is None else started
    if getattr(args, "wing", None) is not None:  # a case file with [[rib]] tables
        return run_wing(args, sources, progress=progress, started=start)
    check_grid(args.n_span, args.n_contour, evaluate=args.evaluate, allow_large=args.allow_large_grid)
    if args.max_steps < 1:
        raise InputError(f"--max-steps must be a positive integer, got {args.max_steps}")
    alphas = _aero_angles(args) if args.aero else None  # (before any solve: a missing package fails fast)
    target = load_section(args.target, "--target")  # (before importing JAX: bad input fails fast)
    rib = target if args.rib is None else load_section(args.rib, "--rib")
    from forward_solver import Bay, ConvergenceError, Fabric, Scene, solve_equilibrium

    from ..optimise import optimise_pressure, refine_design
    from .export import check_output_folder
    from .summary import write_report

    out = check_output_folder(args.out)  # before the long work, not after it
    def scene_on(n_span: int) -> Scene:
        bay = Bay.from_airfoil(rib, chord=args.chord, rib_spacing=args.rib_spacing, n_span=n_span,
                               n_contour=args.n_contour)
        return Scene(bay, Fabric(stiffness_span=args.stiffness_span, stiffness_chord=args.stiffness_chord,
                                 poisson=args.poisson))

    scene = scene_on(args.n_span)
    parameters, variables, rib_limits, bounds, constraints = design_inputs(args)
    inputs = {**vars(args), "target_name": target.name, "rib_name": rib.name, "sources": dict(sources or {})}
    report = dict(target=target, objective=args.objective, inputs=inputs, magnification=args.magnification,
                  rib=rib, rib_limits=rib_limits)
    timings = {"setup": time.perf_counter() - start}
    if args.evaluate:
        t = time.perf_counter()
        result = solve_equilibrium(scene, parameters, max_steps=args.max_steps, method=args.equilibrium_method,
                                   throw=False)
        timings["equilibrium"] = time.perf_counter() - t
        if not result.converged:
            raise ConvergenceError(result)
        aero = _aero(args, result, target, alphas, timings)
        interrupts.check()
        return write_report(out, result, scene=scene, timings=timings, aero=aero, **report)
    options = dict(bounds=bounds, constraints=constraints, root_condition=args.root_condition,
                   max_iterations=args.max_iterations, tolerance=args.tolerance, progress=progress,
                   rib=rib, rib_limits=rib_limits, callback=safe_point,
                   solver_options={"method": args.equilibrium_method, "max_steps": args.max_steps})
    t = time.perf_counter()
    result = optimise_pressure(scene, target, variables=variables, initial=parameters,
                               objective=args.objective, method=args.method, **options)
    if args.refine:
        scene = scene_on(2 * args.n_span - 1)
        result = refine_design(result, scene, target, **options)
    timings["optimisation"] = time.perf_counter() - t
    aero = _aero(args, result.solution, target, alphas, timings)
    interrupts.check()
    return write_report(out, result, scene=scene, bounds=bounds, timings=timings, aero=aero, **report)


def run_wing(args, sources: dict | None = None, progress: bool = False, started: float | None = None) -> dict:
    """Optimise the wing of ``args.wing`` (from `read_ribs`), write the folder, return its summary.

    Raises:
        ValueError: bad input (`options.InputError` among them).
        forward_solver.ConvergenceError: a bay's solve at the start failed (nothing written).
    """
    start = time.perf_counter() if started is None else started
    sources = dict(sources or {})
    for option, instead in NOT_FOR_A_WING.items():
        if option in sources:
            raise InputError(f"{option.replace('_', '-')} does not apply to a wing ([[rib]] tables in "
                         f"{args.config}): {instead}")
    if args.method != "slsqp":
        raise InputError(f"method {args.method} is not available for a wing ([[rib]] tables in {args.config}); "
                     "use slsqp (the default)")
    if args.equilibrium_method not in ("auto", "relax"):
        raise InputError(f"equilibrium-method {args.equilibrium_method} is not available for a wing ([[rib]] tables "
                     f"in {args.config}): its bays are relaxed together; use auto or relax")
    if args.max_steps < 1:
        raise InputError(f"max-steps must be a positive integer, got {args.max_steps}")
    check_grid(args.n_span, args.n_contour, allow_large=args.allow_large_grid)  # (per bay)
    where = args.config
    common = load_section(args.target, "--target") if "target" in sources else None
    sections = [load_section(r["section"], f"{where}: rib {k}: section") for k, r in enumerate(args.wing)]
    targets = [(load_section(r["target"], f"{where}: rib {k}: target") if "target" in r else
                common if common is not None else sections[k]) for k, r in enumerate(args.wing)]
    from forward_solver import Fabric
    from forward_solver.wing import Wing

    from .export import check_output_folder
    from ..optimise import optimise_wing
    from .wing_report import write_wing_report

    out = check_output_folder(args.out)
    try:
        wing = Wing(airfoils=tuple(sections), chords=tuple(r["chord"] for r in args.wing),
                    stations=tuple(r["station"] for r in args.wing), trailing_edge=args.trailing_edge)
    except ValueError as exc:
        raise InputError(f"{where}: {exc}") from None
    fabric = Fabric(stiffness_span=args.stiffness_span, stiffness_chord=args.stiffness_chord,
                    poisson=args.poisson)
    initial, variables, rib_limits, bounds, constraints = design_inputs(args)  # (one shape per rib)
    timings = {"setup": time.perf_counter() - start}
    t = time.perf_counter()
    result = optimise_wing(wing, fabric, targets, variables, initial=initial, bounds=bounds,
                           objective=args.objective, constraints=constraints, rib_limits=rib_limits,
                           n_span=args.n_span, max_steps=args.max_steps,
                           n_contour=args.n_contour, max_iterations=args.max_iterations,
                           **({} if args.tolerance is None else {"tolerance": args.tolerance}),
                           progress=progress, callback=safe_point)
    timings["optimisation"] = time.perf_counter() - t
    inputs = {**vars(args), "sources": sources}
    safe_point()
    return write_wing_report(out, result, bounds=bounds, inputs=inputs, timings=timings,
                             magnification=args.magnification)


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


def _aero(args: argparse.Namespace, solution, target, alphas, timings: dict):
    """The `inverse_design.aero.AeroComparison` of ``--aero`` (None without it); times it."""
    if not args.aero:
        return None
    from ..aero import aerodynamic_cost

    t = time.perf_counter()
    comparison = aerodynamic_cost(solution, target, args.chord, reynolds=args.reynolds, alphas=alphas)
    timings["aero"] = time.perf_counter() - t
    return comparison
