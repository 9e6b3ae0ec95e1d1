"""`optimise_pressure`: manufacturing parameters that make the inflated skin match a target.

Methods (DESIGN section 6; the loops are in `methods`, the objective,
constraints and their derivatives in `problem.DesignProblem`):

* ``"slsqp"`` (default): `scipy.optimize.minimize` with SLSQP on the mean
  square distance (`objectives.objective_value`: for "worst" a smooth maximum
  over the rows), with the bounds and the tension limits as inequality
  constraints (`constraints.constraint_functions`). The objective's and each
  constraint's gradient come from reverse mode through the implicit
  equilibrium (``jax.vjp`` of `forward_solver.solve_equilibrium`): one
  forward solve and one adjoint solve per function per iterate, whatever the
  number of variables.
* ``"least_squares"``: `scipy.optimize.least_squares` (trust-region
  reflective, with the bounds) on the vector of section distances
  (`objectives.objective_residuals`) plus exterior tension penalties; its
  Jacobian from forward mode (``jax.jacfwd``, one tangent solve per
  variable). Fast on unconstrained fits (inverse crimes).
* ``"optax"``: an optax optimiser (Adam by default) on the mean square
  error plus penalties, gradient from reverse mode, projection onto the
  bounds after every step; meant for many variables.
* ``"root"``: `scipy.optimize.brentq` on the pressure alone, for a scalar
  condition at mid-bay: ``root_condition="thickness"`` (maximum thickness of
  the mid-bay section equal to the target's) or ``"mean_offset"`` (zero mean
  normal distance). The bracket is found by stepping the pressure
  geometrically (factor 2) from its start towards both bounds; when the
  condition does not change sign inside the bounds a ValueError says so.

Every result is checked the same way: the design is a success only if the
method converged, the final solve converged, and no tension limit is broken
by more than `constraints.VIOLATION_TOLERANCE` (the result names the
constraint and the amount).

Every forward solve warm-starts from the previous iterate's equilibrium
(chord Newton with its LU factor) and is solved to
`forward_solver.adjoint.GRADIENT_RTOL`. All JAX work runs inside
``jax.enable_x64(True)`` (thread-local; the caller's configuration is
untouched).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Mapping

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from forward_solver import ConvergenceError, Parameters, Scene, Solution
from forward_solver.adjoint import GRADIENT_RTOL
from forward_solver.parameters import ParameterViews

from .constraints import Constraints, cell_tensions, constraint_report
from .methods import least_squares, optax_descent, root, slsqp
from .objectives import check_objective, design_errors
from .problem import DesignProblem
from .rib_design import RibGeometry, RibLimits, rib_report
from .variables import DesignVariables

__all__ = ["METHODS", "ROOT_CONDITIONS", "DesignResult", "optimise_pressure", "refine_design"]

METHODS = ("slsqp", "least_squares", "optax", "root")
ROOT_CONDITIONS = ("thickness", "mean_offset")

@dataclass(frozen=True, eq=False)
class DesignResult(ParameterViews):
    """Outcome of `optimise_pressure`.

    Attributes:
        parameters: the `forward_solver.Parameters` of the design.
        variables: the optimised names.
        rms_error, max_error: normal distance from the target over the
            objective's sections at the design, fractions of chord.
        initial_rms_error, initial_max_error: the same at the start.
        solution: the `Solution` at the design.
        history: one dict per iterate (forward solve): ``values`` (the
            optimised variables), ``objective`` (mean square distance, chord^2,
            as `objectives.objective_value` for slsqp; for "root" the
            condition's value), ``gradient_norm`` (of the
            objective in the scaled variables; NaN where not computed),
            ``constraints`` (the smooth constraint values, >= 0 feasible; slsqp
            only) and ``steps`` (forward-solve steps).
        success: the method converged, the final solve converged and no
            tension limit is violated.
        message: the method's message, and what was violated.
        active_constraints: names of bounds (``"pressure<=upper"``) and tension
            constraints (``"min_tension"``, ``"max_tension"``) at their limit
            (within `constraints.ACTIVE_TOLERANCE`).
        violated_constraints: ``{name: amount}``, N/m beyond the limit, of
            each tension limit broken by more than
            `constraints.VIOLATION_TOLERANCE`; for a shaped rib also
            ``rib_min_thickness`` (the thickness ratio's shortfall) and
            ``rib_min_radius`` (the radius's, chord) broken by more than
            `rib_design.RIB_TOLERANCE` of the limit.
        violated_at_start: the same for the starting design (empty when
            the start met every limit). A start that broke a limit may have
            a smaller error than a design that meets it: the error then
            rises, and this says why.
        constraint_values: the measured minimum and maximum fibre tension (N/m)
            and the limits; for a shaped rib the least thickness ratio and
            radius of curvature with their limits (`rib_design.rib_report`).
        method, objective: as requested.
        solves: forward solves.
        wall_time: s, compilation included.
        grid_change: after `refine_design`, how the design moved from the
            coarser grid: ``{"grids": [[n_span, n_contour], ...], "values":
            {name: [coarse, fine]}, "change": {name: relative change for the
            pressure, absolute otherwise (the largest component's for a
            vector)}, "rms_error": [coarse, fine]}``;
            None for a design on one grid.
    """

    parameters: Parameters
    variables: tuple
    rms_error: float
    max_error: float
    initial_rms_error: float
    initial_max_error: float
    solution: Solution
    history: list = field(default_factory=list)
    success: bool = False
    message: str = ""
    active_constraints: list = field(default_factory=list)
    violated_constraints: dict = field(default_factory=dict)
    constraint_values: dict = field(default_factory=dict)
    violated_at_start: dict = field(default_factory=dict)
    method: str = ""
    objective: str = ""
    solves: int = 0
    wall_time: float = 0.0
    grid_change: dict | None = None

    @property
    def values(self) -> dict:
        """``{name: value}`` of every design parameter (`variables.VARIABLES`)."""
        from .variables import VARIABLES

        return {name: getattr(self.parameters, name) for name in VARIABLES}


def optimise_pressure(
    scene: Scene,
    target,
    variables=("pressure",),
    *,
    initial: Parameters | Mapping | None = None,
    bounds: Mapping | None = None,
    objective: str = "mid_bay",
    constraints: Constraints | None = Constraints(),
    method: str = "slsqp",
    root_condition: str = "thickness",
    max_iterations: int = 50,
    tolerance: float | None = None,
    optimiser=None,
    rtol: float = GRADIENT_RTOL,
    progress: bool = False,
    callback=None,
    rib=None,
    rib_limits: RibLimits | None = RibLimits(),
) -> DesignResult:
    """Pressure, prestrain and rib geometry that bring the inflated skin closest to ``target``.

    Args:
        scene: bay, fabric and physics switches (`forward_solver.Scene`).
        target: the target section, a chord-normalised `targets.Airfoil`.
        variables: names to optimise, from `variables.VARIABLES`.
        initial: the starting `forward_solver.Parameters`, or ``{name:
            value}`` (Pa, fractions) over `variables.DEFAULT_START`; names that
            are not optimised stay at these values.
        bounds: ``{name: (lower, upper)}`` for optimised names (defaults:
            `variables.DEFAULT_BOUNDS`).
        objective: "mid_bay", "average" or "worst" (`objectives`).
        constraints: tension limits (`Constraints`; default a wrinkle-free
            skin below the fabric's allowable), or None.
        method: "slsqp" (default), "least_squares", "optax" or "root".
        root_condition: "thickness" or "mean_offset" (``method="root"``).
        max_iterations: cap on iterations (SLSQP iterations; least-squares
            Jacobian evaluations; optax steps; brentq iterations).
        tolerance: convergence tolerance: SLSQP's ``ftol`` on the objective
            relative to its starting value (default 1e-6: a change of one
            part in a million of the mean square error, far below what the
            grid resolves), ``ftol``/``xtol`` of least_squares (default 1e-8),
            the relative pressure tolerance of brentq (1e-8), the scaled
            gradient norm of optax (1e-8).
        optimiser: an ``optax.GradientTransformation`` (``method="optax"``;
            default ``optax.adam(0.02)`` on the scaled variables).
        rtol: relative residual of the forward solves.
        progress: show a tqdm progress bar on stderr, one tick per iterate
            (off by default: library code prints nothing unless asked).
        callback: called as ``callback(entry)`` after every iterate with the
            new `DesignResult.history` entry; an exception it raises stops the
            optimisation and propagates.
        rib: the rib's starting section (`targets.Airfoil`; default the
            target): what ``rib_limits`` are measured against. Give it when
            the scene's bay was built from another airfoil.
        rib_limits: manufacturability limits of a shaped rib
            (`rib_design.RibLimits`: minimum thickness, curvature bound), SLSQP
            inequality constraints when ``rib_shape`` is a variable; None
            leaves the shape free within its bounds.

    Returns:
        A `DesignResult`.

    Raises:
        ValueError: for an unknown method, objective, variable or condition,
            bad bounds, inconsistent tension limits, rib limits with a method
            other than SLSQP, or (``method="root"``) no sign change inside the
            pressure bounds.
        forward_solver.ConvergenceError: if the forward solve at the starting
            values fails. A solve that fails later stops the optimisation
            instead: the `DesignResult` holds the best iterate whose solve
            converged, with ``success=False`` and a message naming the
            failed solve.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    check_objective(objective)
    if not (isinstance(max_iterations, int) and max_iterations >= 1):
        raise ValueError(f"max_iterations must be a positive integer, got {max_iterations!r}")
    if tolerance is not None and not (isinstance(tolerance, float | int) and 0 < tolerance < 1):
        raise ValueError(f"tolerance must lie in (0, 1), got {tolerance!r}")
    if constraints is not None:
        if not isinstance(constraints, Constraints):
            raise ValueError(f"constraints must be an inverse_design.Constraints or None, got {constraints!r}")
        constraints.check(scene.fabric)
    design = DesignVariables.build(variables, initial, bounds)
    if method == "root":
        if design.names != ("pressure",):
            raise ValueError(f"method='root' solves for the pressure alone; got variables {design.names}")
        if root_condition not in ROOT_CONDITIONS:
            raise ValueError(f"root_condition must be one of {ROOT_CONDITIONS}, got {root_condition!r}")
    rib_geometry = None
    if "rib_shape" in design.names and rib_limits is not None:
        if method != "slsqp":
            raise ValueError(f"the rib limits (minimum thickness, curvature) are constraints that only "
                             f"method='slsqp' enforces, got method={method!r}: use slsqp, or pass "
                             "rib_limits=None to leave the rib shape free within its bounds")
        rib_geometry = RibGeometry(target if rib is None else rib, rib_limits)
    if tolerance is None:
        tolerance = 1e-6 if method == "slsqp" else 1e-8
    start = time.perf_counter()
    with jax.enable_x64(True), _progress_bar(progress, max_iterations) as bar:
        problem = DesignProblem(scene, target, design, objective, constraints, rtol, rib_geometry)
        problem.on_record = _notify(bar, callback, method)
        bar.set_postfix_str("initial equilibrium")
        u0 = design.to_vector(design.start)
        if method == "slsqp":
            sol0 = problem.evaluate(u0)[-1]  # the first iterate's solve, with its gradients
        elif method == "least_squares":
            sol0 = problem.residuals_and_jacobian(u0)[-1]
        else:
            sol0 = problem.solve(u0)
        initial_errors = design_errors(sol0.nodes, target, problem.chord, objective)
        violated_at_start = _violated(scene, constraints, design, design.parameters(u0).as_floats(), sol0,
                                      problem.tension_scale, rib_geometry)
        try:
            if method == "root":
                u, success, message = root(problem, root_condition, max_iterations, tolerance)
            elif method == "slsqp":
                u, success, message = slsqp(problem, u0, max_iterations, tolerance)
            elif method == "least_squares":
                u, success, message = least_squares(problem, u0, max_iterations, tolerance)
            else:
                u, success, message = optax_descent(problem, u0, max_iterations, tolerance, optimiser)
        except ConvergenceError as failure:
            # Stop at the best iterate whose forward solve converged ("objective" is the
            # mean square error, or for "root" the condition, whose size is what counts).
            best = problem.best_iterate()
            u = u0 if best is None else best
            success, message = False, _failed_solve_message(failure)
        u = np.clip(np.asarray(u, dtype=np.float64), design.lower, design.upper)
        parameters = design.parameters(u).as_floats()
        sol = problem.solve(u)
        rms, max_error = design_errors(sol.nodes, target, problem.chord, objective)
        if not (np.isfinite([rms, max_error]).all() and np.isfinite(sol.nodes).all()):
            success = False
            message = f"{message}; the shape errors at the result are not finite"
        tensions = np.asarray(cell_tensions(scene, jnp.asarray(sol.nodes), parameters))
        active, violated, report = constraint_report(constraints, design, parameters, tensions,
                                                     scene.fabric, problem.tension_scale)
        rib_active, rib_violated, rib_values = rib_report(rib_geometry, parameters)
        if violated or rib_violated:
            success = False
            message = f"{message}; {_violation_message(violated, report, rib_violated, rib_values)}"
        active, violated, report = active + rib_active, {**violated, **rib_violated}, {**report, **rib_values}
    return DesignResult(
        parameters=parameters,
        variables=design.names,
        rms_error=rms,
        max_error=max_error,
        initial_rms_error=initial_errors[0],
        initial_max_error=initial_errors[1],
        solution=sol,
        history=problem.history,
        success=bool(success and sol.converged),
        message=message,
        active_constraints=active,
        violated_constraints=violated,
        constraint_values=report,
        violated_at_start=violated_at_start,
        method=method,
        objective=objective,
        solves=problem.solves,
        wall_time=time.perf_counter() - start,
    )


def refine_design(result: DesignResult, scene: Scene, target, **options) -> DesignResult:
    """Confirm and polish a design on a finer grid, and record how far it moved.

    Runs `optimise_pressure` on ``scene`` (the same case on a finer grid)
    from ``result``'s design, with its variables, objective and method. A
    design that is converged in the grid moves little (and SLSQP, starting at
    the optimum, stops in a few iterates); the move is the design's
    discretisation error, recorded in `DesignResult.grid_change`.

    Args:
        result: the design on the coarser grid.
        scene: the finer scene.
        target: the target, as for the coarse design.
        **options: further `optimise_pressure` arguments (bounds,
            constraints, max_iterations, ...), as for the coarse design.

    Returns:
        The fine grid's `DesignResult` with ``grid_change`` filled in; its
        ``solves``, ``wall_time`` and ``history`` cover both grids, and its
        initial errors are those of the start of the design (measured on the
        coarser grid).
    """
    fine = optimise_pressure(scene, target, result.variables, initial=result.parameters,
                             objective=result.objective, method=result.method, **options)
    coarse_grid = list(result.solution.nodes.shape[:2])
    values = {n: [_plain(getattr(result.parameters, n)), _plain(getattr(fine.parameters, n))]
              for n in result.variables}
    change = {n: (b - a) / a if n == "pressure" else float(np.max(np.abs(np.subtract(b, a))))
              for n, (a, b) in values.items()}
    grid_change = {"grids": [coarse_grid, [scene.bay.n_span, scene.bay.n_contour]], "values": values,
                   "change": change, "rms_error": [result.rms_error, fine.rms_error]}
    return dataclasses.replace(fine, grid_change=grid_change, solves=result.solves + fine.solves,
                               wall_time=result.wall_time + fine.wall_time,
                               history=[*result.history, *fine.history],
                               initial_rms_error=result.initial_rms_error,
                               initial_max_error=result.initial_max_error,
                               violated_at_start=result.violated_at_start)


def _plain(value):
    """A float, or a list of floats for a vector variable."""
    return float(value) if np.ndim(value) == 0 else np.asarray(value, np.float64).tolist()


def _violated(scene, constraints, design, parameters, sol, scale, rib_geometry) -> dict:
    """``{name: amount}`` of the limits the design ``parameters`` (solved as ``sol``) breaks, as
    `DesignResult.violated_constraints` counts them."""
    tensions = np.asarray(cell_tensions(scene, jnp.asarray(sol.nodes), parameters))
    violated = constraint_report(constraints, design, parameters, tensions, scene.fabric, scale)[1]
    return {**violated, **rib_report(rib_geometry, parameters)[1]}


def _violation_message(violated: dict, report: dict, rib_violated: dict | None = None,
                       rib_values: dict | None = None) -> str:
    parts = []
    rib_violated, rib_values = rib_violated or {}, rib_values or {}
    if "rib_min_thickness" in rib_violated:
        parts.append(f"rib_min_thickness violated: the rib is {rib_values['rib_min_thickness']:.4g} of its "
                     f"starting thickness somewhere, below the limit {rib_values['rib_min_thickness_limit']:.4g}")
    if "rib_min_radius" in rib_violated:
        parts.append(f"rib_min_radius violated: the rib's smallest radius of curvature is "
                     f"{rib_values['rib_min_radius']:.4g} chord, below the limit "
                     f"{rib_values['rib_min_radius_limit']:.4g}")
    if "min_tension" in violated:
        parts.append(f"min_tension violated: the smallest fibre tension is {report['min_tension']:.4g} "
                     f"N/m, {violated['min_tension']:.4g} N/m below the floor "
                     f"{report['min_tension_floor']:.4g} N/m (the skin wrinkles)")
    if "max_tension" in violated:
        parts.append(f"max_tension violated: the largest fibre tension is {report['max_tension']:.4g} "
                     f"N/m, {violated['max_tension']:.4g} N/m above the ceiling "
                     f"{report['max_tension_ceiling']:.4g} N/m")
    return "; ".join(parts) + " (no design within the bounds meets the limits, or the optimiser " \
        "stopped early: widen the bounds or relax the limits)"


def _failed_solve_message(failure: ConvergenceError) -> str:
    sol = failure.solution
    return (f"stopped: the forward solve at pressure {sol.pressure:.6g} Pa, prestrain "
            f"({sol.prestrain[0]:.6g}, {sol.prestrain[1]:.6g}) failed ({sol.message}); the "
            "result is the best iterate whose solve converged; narrow the bounds to where the "
            "skin has an equilibrium")


# ------------------------------------------------------------------ progress
def _progress_bar(progress: bool, max_iterations: int):
    """A tqdm counter on stderr: iterates so far against the cap; a silent no-op when off.

    No percentage or ETA: the cap is an upper bound, not the expected count.
    """
    return tqdm(total=max_iterations, desc="optimise_pressure", unit="iterate", disable=not progress,
                leave=False, dynamic_ncols=True,
                bar_format="{desc}: iterate {n_fmt} (cap {total_fmt}), {elapsed} elapsed{postfix}")


def _notify(bar, callback, method: str):
    """The per-iterate hook: tick the bar, show the objective, call the user's callback."""

    def on_record(entry: dict) -> None:
        value = entry["objective"]
        shown = f"condition={value:.3e}" if method == "root" else f"rms={math.sqrt(max(value, 0.0)):.3e}"
        bar.set_postfix_str(shown, refresh=False)
        bar.update(1)
        if callback is not None:
            callback(entry)

    return on_record
