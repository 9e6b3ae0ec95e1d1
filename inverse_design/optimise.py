"""`optimise_wing` and `optimise_pressure`: manufacturing parameters that make the inflated skin match a target.

One design over a wing of N >= 1 bays (`optimise_wing`; `optimise_pressure`
is the one-bay case of a `forward_solver.Scene`): one pressure, prestrain and
rib scales for every bay, and a rib shape shared by every rib or one per rib
(`variables`); the objective is the bays' distances from their row targets
weighted by planform area (`objectives`); the tension limits hold over every
cell of every bay (`constraints`); the ribs' manufacturability limits per rib
(`rib_design`). Methods (the loops are in `methods`, the objective,
constraints and their derivatives in `problem.DesignProblem`):

* ``"auto"`` (default): ``"gauss_newton"`` for one bay and for a wing,
  whatever the variables; ``"slsqp"`` for the objective "worst", which
  gauss_newton refuses. On the design matrix (every documented variable set
  on the default bay, the built-in wing, a NACA 0012 bay and a bay of a
  ``.dat`` section, 17x64: ``benchmarks/design_matrix.py``) gauss_newton
  converges on every cell, in as many forward solves as SLSQP or fewer (3
  against 7 on the default case, at the same optimum), and where SLSQP
  stops at its iteration cap (a cut pattern, a rib shape on the wing and
  on a ``.dat`` section, the prestrains with a rib shape); where both
  converge its rms error is SLSQP's within 0.01% or lower (its largest
  error at most 0.21% above SLSQP's).
* ``"slsqp"``: `scipy.optimize.minimize` with SLSQP on the mean
  square distance (`objectives.mean_square`: for "worst" a smooth maximum
  over the rows), with the bounds, the tension limits
  (`constraints.constraint_functions`) and the rib limits as inequality
  constraints. The objective's and each constraint's gradient come from
  reverse mode through the implicit equilibrium (``jax.vjp`` of
  `forward_solver.solve_bays`): one forward solve and one adjoint solve per
  function per iterate, whatever the number of variables.
* ``"gauss_newton"``: trust-region SQP with the Gauss-Newton Hessian
  (`methods.gauss_newton`): each iterate is one forward solve with the
  Jacobian of the stacked row distances and of every cell's tension rows by
  forward mode through the implicit equilibrium (``jax.jacfwd``: per bay one
  back-solve per variable with the solve's own LU factor); the step solves a
  small QP of the linearised fit with the linearised tension and rib limits
  as constraints, without a forward solve. Its number of solves barely grows
  with the number of variables (SLSQP learns its Hessian one iterate at a
  time). Not for the objective "worst" (no sum of squares).
* ``"least_squares"``: `scipy.optimize.least_squares` (trust-region
  reflective, with the bounds) on the vector of section distances
  (`objectives.distance_residuals`, each bay's scaled by the square root of
  its weight) plus exterior tension penalties; its Jacobian from forward mode
  (``jax.jacfwd``, one tangent solve per variable). Fast on unconstrained
  fits (inverse crimes).
* ``"optax"``: an optax optimiser (Adam by default) on the mean square
  error plus penalties, gradient from reverse mode, projection onto the
  bounds after every step; meant for many variables.
* ``"root"``: `scipy.optimize.brentq` on the pressure of one bay alone, for a
  scalar condition at mid-bay: ``SolverSettings(root_condition="thickness")`` (maximum
  thickness of the mid-bay section equal to the target's) or
  ``"mean_offset"`` (zero mean normal distance). The bracket is found by
  stepping the pressure geometrically (factor 2) from its start towards both
  bounds; when the condition does not change sign inside the bounds a
  ValueError says so. A wing of several bays has no one mid-bay section:
  refused.

Every result is checked the same way: the design is a success only if the
method converged, every bay's final solve converged, and no tension or rib
limit is broken by more than its tolerance (the result names the constraint,
the bay or rib, and the amount).

Every forward solve warm-starts from the previous iterate's equilibrium
(chord Newton with its LU factor) and is solved to
`forward_solver.derivatives.custom_jvp.GRADIENT_RTOL`. All JAX work runs inside
``jax.enable_x64(True)`` (thread-local; the caller's configuration is
untouched).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from forward_solver import ConvergenceError, Fabric, Parameters, Scene, Solution, Wing, solve_bays
from forward_solver.model.parameters import ParameterViews
from forward_solver.solution import Result
from forward_solver.solution import BaysSolution
from forward_solver.solvers.bays import check_rib_gaps
from targets import Airfoil

from .constraints import UNMET_ADVICE, cell_tensions, constraint_report, tension_scale
from .methods import SLSQP_EVALUATIONS_PER_ITERATION, gauss_newton, least_squares, optax_descent, root, slsqp
from .objectives import (bay_distances, bay_weights, check_objective, distance_errors, local_chords,
                         row_targets, same_section, station_etas)
from .problem import DesignProblem
from forward_solver.solution import BaysConvergenceError
from .rib_design import RibGeometry, rib_crossings, rib_report
from .settings import (AUTO, AUTO_FOR_WORST, METHODS, ROOT_CONDITIONS, DesignRequest, Layout, Limits,
                       SolverSettings, refuse_moved)
from .variables import DEFAULT_START, VARIABLES, DesignVariables, concrete_rows

__all__ = ["AUTO", "AUTO_FOR_WORST", "METHODS", "ROOT_CONDITIONS", "DesignRequest", "DesignResult", "Layout",
           "Limits", "PerBayResults", "SolverSettings", "WingDesignResult",
           "evaluate_design", "optimise_wing", "optimise_pressure", "refine_design"]

#: Default tolerance of ``method="gauss_newton"``: the model's predicted fall of the merit, relative to
#: it (1e-3 of the mean square is 5e-4 of the rms error, against the 1.3-3% that re-solving on 33x64
#: moves it). Near the optimum a step gains 0.2-0.5% of the merit per wing solve on the 40-cell wing
#: (linear convergence: the fit's residuals do not vanish); 1e-4 spent up to 8 more solves there for
#: 0.27% of the rms, and on the design matrix 197 solves against 165 for at most 0.11% of it.
GN_TOLERANCE = 1e-3


@dataclass(frozen=True, eq=False)
class PerBayResults:
    """The per-bay (and per-rib) arrays of a `DesignResult`, root to tip.

    Attributes:
        scenes: the `Scene` of each bay.
        targets: the target section of each rib.
        weights: ``(n_bays,)`` bay weights of the objective (planform area).
        rms_error, max_error: ``(n_bays,)`` RMS and largest normal distance
            of each bay's objective rows from their targets at the design,
            fractions of the local chord.
        initial_rms_error, initial_max_error: the same at the start (NaN
            for a single equilibrium).
        min_tension, max_tension: ``(n_bays,)`` smallest and largest
            unclamped fibre tension of each bay at the design, N/m.
        rib_shapes: ``(n_ribs, 2 K)`` rib-shape coefficients of a shape per
            rib, else None.
        cut_patterns: ``(n_bays, 2 K)`` cut-field coefficients of a field per
            bay, else None.
        rib_limits: per shaped rib, ``{"rib": k, ...}`` its measured
            manufacturability limits (`rib_design.RibGeometry.measure`).
    """

    scenes: tuple
    targets: tuple
    weights: np.ndarray
    rms_error: np.ndarray
    max_error: np.ndarray
    initial_rms_error: np.ndarray
    initial_max_error: np.ndarray
    min_tension: np.ndarray
    max_tension: np.ndarray
    rib_shapes: np.ndarray | None = None
    cut_patterns: np.ndarray | None = None
    rib_limits: list = field(default_factory=list)


@dataclass(frozen=True, eq=False)
class DesignResult(ParameterViews):
    """Outcome of `optimise_wing` and `optimise_pressure`: what was found, what was asked
    (``request``) and the per-bay arrays (``per_bay``).

    Attributes:
        parameters: the shared `forward_solver.Parameters` of the design
            (with a shared rib shape its ``rib_shape``); ``pressure``,
            ``prestrain`` and the other parameters read through.
        rms_error, max_error: normal distance from the target over the
            objective's sections at the design, fractions of the local chord:
            the square root of the bays' area-weighted mean squares, and the
            largest over the bays (one bay: its own).
        initial_rms_error, initial_max_error: the same at the start.
        wing_solution: the `forward_solver.solvers.bays.BaysSolution` at the design
            (``solution``: one bay's `Solution`, or the wing's).
        history: one dict per iterate (forward solve): ``values`` (the
            optimised variables), ``objective`` (mean square distance, chord^2,
            as `objectives.mean_square` for slsqp; for "root" the
            condition's value), ``gradient_norm`` (of the
            objective in the scaled variables; NaN where not computed),
            ``constraints`` (the smooth constraint values, >= 0 feasible,
            with the least thickness and curvature row of the rib limits;
            slsqp; for gauss_newton each tension limit's least cell row)
            and ``steps`` (forward-solve steps of the slowest bay); gauss_newton adds
            ``jacobian`` (its bay blocks and tangents) and, at each accepted iterate,
            ``qp_rows`` (the limit rows its step QP kept, `step_qp.solve_working_set`) and
            ``qp_reachable_rows`` (those a step in the trust box could reach, `step_qp.reachable_rows`).
        success: the method converged, every bay's final solve converged and
            no tension or rib limit is violated.
        message: the method's message, and what was violated.
        active_constraints: names of bounds (``"pressure<=upper"``,
            ``"rib_shape[1][3]<=upper"`` for rib 1's), tension
            constraints (``"min_tension"``, ``"max_tension"``) and rib limits
            (``"rib_min_thickness"``; ``"rib_min_thickness@rib 2"`` with a shape
            per rib) at their limit (within `constraints.ACTIVE_TOLERANCE`).
        violated_constraints: ``{name: amount}``: the amount beyond the
            limit (N/m for a tension limit, broken by more than
            `constraints.VIOLATION_TOLERANCE`; for a shaped rib
            ``rib_min_thickness``, the thickness ratio's shortfall, and
            ``rib_min_radius``, the radius's, chord, broken by more than
            `rib_design.RIB_TOLERANCE` of the limit), the largest over the
            bays or ribs.
        violated_where: ``{name: {index: amount}}``: the same amounts at
            each bay (tension limits) or rib (rib limits) that breaks them.
        violated_at_start, violated_at_start_where: the same for the
            starting design (empty when the start met every limit). A start
            that broke a limit may have a smaller error than a design that
            meets it: the error then rises, and this says why.
        constraint_values: the measured minimum and maximum fibre tension (N/m)
            over every bay and the limits; for a shaped rib the least thickness
            ratio and radius of curvature with their limits
            (`rib_design.rib_report`).
        method: the method that ran (``request.method`` is the one asked:
            "auto" resolves to one); "" for a single equilibrium.
        solves: forward solves (each solves every bay once).
        wall_time: s, compilation included.
        grid_change: after `refine_design`, how the design moved from the
            coarser grid: ``{"grids": [[n_span, n_contour], ...], "values":
            {name: [coarse, fine]}, "change": {name: relative change for the
            pressure, absolute otherwise (the largest component's for a
            vector)}, "rms_error": [coarse, fine]}``;
            None for a design on one grid.
        wing: the `forward_solver.Wing` designed (None for a flat panel).
        request: what was asked (`settings.DesignRequest`: variables, start,
            bounds, objective, method, limits).
        per_bay: the per-bay and per-rib arrays (`PerBayResults`).
    """

    parameters: Parameters
    rms_error: float
    max_error: float
    initial_rms_error: float
    initial_max_error: float
    wing_solution: BaysSolution
    request: DesignRequest
    per_bay: PerBayResults
    history: list = field(default_factory=list)
    success: bool = False
    message: str = ""
    active_constraints: list = field(default_factory=list)
    violated_constraints: dict = field(default_factory=dict)
    violated_where: dict = field(default_factory=dict)
    violated_at_start: dict = field(default_factory=dict)
    violated_at_start_where: dict = field(default_factory=dict)
    constraint_values: dict = field(default_factory=dict)
    method: str = ""
    solves: int = 0
    wall_time: float = 0.0
    grid_change: dict | None = None
    wing: Wing | None = None

    @property
    def variables(self) -> tuple:
        """The optimised names (``request.variables``; empty for a single equilibrium)."""
        return self.request.variables

    @property
    def objective(self) -> str:
        """The objective asked (``request.objective``)."""
        return self.request.objective

    @property
    def values(self) -> dict:
        """``{name: value}`` of every design parameter (`variables.VARIABLES`)."""
        return {name: getattr(self.parameters, name) for name in VARIABLES}

    @property
    def n_bays(self) -> int:
        return len(self.wing_solution.bays)

    @property
    def solution(self) -> Solution | BaysSolution:
        """One bay: its `Solution` at the design; a wing: the `BaysSolution` (``bay_solution(k)``)."""
        return self.wing_solution.bay_solution(0) if self.n_bays == 1 else self.wing_solution

    @property
    def bay_results(self) -> tuple:
        """``(n_bays,)`` `forward_solver.Result` names of the final solves."""
        return tuple(Result(int(r)).name for r in np.asarray(self.wing_solution.result))


#: The wing's name of the result (one class for one bay and a wing).
WingDesignResult = DesignResult


def optimise_wing(
    wing: Wing,
    fabric: Fabric,
    targets: Sequence | None = None,
    variables=("pressure",),
    *,
    initial: Parameters | Mapping | None = None,
    bounds: Mapping | None = None,
    objective: str = "average",
    method: str = "auto",
    limits: Limits = Limits(),
    solver: SolverSettings = SolverSettings(),
    layout: Layout = Layout(),
    tolerances=None,
    **moved,
) -> DesignResult:
    """One pressure (and prestrain, rib scales, rib shapes) for every bay of ``wing`` (module docstring).

    Args:
        wing: the ribs (`forward_solver.Wing`).
        fabric: the skin's `forward_solver.Fabric` (one for the whole wing).
        targets: the target section of each rib (N + 1 `targets.Airfoil`), one
            `targets.Airfoil` for every rib, or None: each rib's own section.
        variables: names to optimise, from `variables.VARIABLES`.
        initial: the starting `Parameters`, or ``{name: value}`` (Pa,
            fractions) over `variables.DEFAULT_START`; names that are not
            optimised stay at these values. A per-rib ``rib_shape`` start is one
            ``(2 K,)`` row for every rib or ``(n_ribs, 2 K)``; a per-bay
            ``cut_pattern`` start one ``(2 K,)`` row for every bay or ``(n_bays, 2 K)``.
        bounds: ``{name: (lower, upper)}`` of optimised names (defaults
            `variables.DEFAULT_BOUNDS`; ``rib_shape``'s for every coefficient).
        objective: per bay "mid_bay", "average" (default) or "worst"
            (`objectives`); combined over bays weighted by planform area; or
            "robust": the linearised 95th percentile of the "average" rms
            under ``tolerances``, with the tension limits at every cell's own
            5th / 95th percentile (`robust`; gauss_newton only).
        method: "auto" (default: "gauss_newton", whose forward solves hardly
            grow with the number of variables; "slsqp" for the objective
            "worst"), "slsqp", "gauss_newton", "least_squares", "optax" or
            "root" (a wing of one bay only: root finding solves one scalar
            condition at its mid-bay section). ``DesignResult.method`` names
            the one that ran.
        limits: the tension limits over every cell of every bay and the rib
            limits of shaped ribs (`settings.Limits`; rib limits need slsqp or
            gauss_newton).
        solver: iteration cap, tolerance, optimiser, the forward solves'
            tolerance, method and step cap, progress bar and callback
            (`settings.SolverSettings`).
        layout: a rib shape per rib or shared, a cut pattern shared or per
            bay, and the grid of every bay (`settings.Layout`).
        tolerances: with ``objective="robust"``, the manufacturing
            tolerances designed for (``{name: value}`` or anything
            `tolerance.parse_tolerances` takes; None: every default,
            docs/tolerances.md); refused with another objective.
        **moved: the keyword arguments that moved into ``limits``, ``solver``
            and ``layout``: refused with a TypeError that names where each went.

    Returns:
        A `DesignResult`.

    Raises:
        TypeError: for a target that is not a `targets.Airfoil`, or a keyword that moved.
        ValueError: for an unknown method, objective or variable, bad bounds,
            targets or limits, ribs too close for the grid, rib limits with a
            method other than slsqp or gauss_newton, ``method="root"`` on
            several bays, or gauss_newton with the objective "worst".
        BaysConvergenceError: (a `forward_solver.ConvergenceError`) if a bay's
            solve at the start (or the final solve at a clipped design never
            solved before) does not converge; a failure in between ends the
            optimisation at the best iterate whose solves converged, with
            ``success=False`` and a message naming the failed solve.
    """
    refuse_moved("optimise_wing", moved)
    if not isinstance(wing, Wing):
        raise ValueError(f"wing must be a forward_solver.Wing, got {type(wing).__name__}")
    if targets is None:
        targets = list(wing.airfoils)
    elif hasattr(targets, "distance"):  # one Airfoil for every rib
        targets = [targets] * len(wing.airfoils)
    else:
        targets = list(targets)
        if len(targets) != len(wing.airfoils):
            raise ValueError(f"give one target section per rib: the wing has {len(wing.airfoils)} ribs, got "
                             f"{len(targets)} targets (or one Airfoil for all, or None for the ribs' own)")
        for k, t in enumerate(targets):
            if not isinstance(t, Airfoil):
                raise TypeError(f"target {k} must be a targets.Airfoil, got {type(t).__name__}")
    request = DesignRequest(variables, initial, bounds, objective, method, limits, tolerances)
    return _optimise(wing.scenes(fabric, layout.n_span, layout.n_contour), targets, list(wing.sections), wing,
                     request, solver, layout, name="optimise_wing", check_gaps=True)


def optimise_pressure(
    scene: Scene,
    target,
    variables=("pressure",),
    *,
    initial: Parameters | Mapping | None = None,
    bounds: Mapping | None = None,
    objective: str = "mid_bay",
    method: str = "auto",
    limits: Limits = Limits(),
    solver: SolverSettings = SolverSettings(),
    rib=None,
    tolerances=None,
    **moved,
) -> DesignResult:
    """Pressure, prestrain and rib geometry that bring one bay's inflated skin closest to ``target``.

    The one-bay case of `optimise_wing` on ``scene`` itself (its bay, fabric,
    physics switches and grid), with ``target`` at both ribs and one rib shape
    for both ribs; the arguments are `optimise_wing`'s, and:

    Args:
        scene: bay, fabric and physics switches (`forward_solver.Scene`).
        target: the target section, a chord-normalised `targets.Airfoil`.
        objective: "mid_bay" (default), "average", "worst" or "robust".
        tolerances: the tolerances of ``objective="robust"`` (as `optimise_wing`).
        method: "auto" (default: "gauss_newton"; "slsqp" for the objective
            "worst"), "slsqp", "gauss_newton", "least_squares", "optax" or
            "root" (its condition: ``SolverSettings.root_condition``).
        rib: the rib's starting section (`targets.Airfoil`; default the
            target): what ``limits.ribs`` are measured against. Give it when
            the scene's bay was built from another airfoil.

    Returns:
        A `DesignResult` (its ``solution`` the bay's `Solution`).

    Raises:
        TypeError: if ``target`` is not a `targets.Airfoil` (None among them),
            or for a keyword that moved into ``limits`` or ``solver``.
        ValueError: as `optimise_wing`; for ``method="root"`` also variables
            other than the pressure, or no sign change inside the pressure bounds.
        forward_solver.ConvergenceError: if the forward solve at the starting
            values fails (a later failure stops the optimisation instead).
    """
    refuse_moved("optimise_pressure", moved)
    if not isinstance(scene, Scene):
        raise ValueError(f"scene must be a forward_solver.Scene, got {type(scene).__name__}")
    if not isinstance(target, Airfoil):
        raise TypeError(f"target must be a targets.Airfoil (e.g. targets.naca('2412') or "
                        f"targets.load_airfoil('file.dat')), got {type(target).__name__}")
    bay = scene.bay
    wing = Wing.from_scene(scene) if getattr(bay, "airfoil", None) is not None else None
    ribs = [target if rib is None else rib] * 2
    request = DesignRequest(variables, initial, bounds, objective, method, limits, tolerances)
    layout = Layout(rib_shape="shared", cut_pattern="shared", n_span=bay.n_span, n_contour=bay.n_contour)
    return _optimise([scene], [target, target], ribs, wing, request, solver, layout, name="optimise_pressure",
                     check_gaps=False)


def _optimise(scenes, targets, ribs, wing, request: DesignRequest, settings: SolverSettings, layout: Layout, *,
              name: str, check_gaps: bool) -> DesignResult:
    """The design ``request`` of the bays ``scenes`` (ribs' targets ``targets``, starting sections ``ribs``;
    ``check_gaps``: refuse ribs of ``wing`` too close for the grid, `forward_solver.solvers.bays.check_rib_gaps`;
    ``name``: the progress bar's)."""
    if not isinstance(settings, SolverSettings):
        raise ValueError(f"solver must be an inverse_design.SolverSettings, got {settings!r}")
    if not isinstance(layout, Layout):
        raise ValueError(f"layout must be an inverse_design.Layout, got {layout!r}")
    method, objective = request.method_to_run, request.objective
    constraints, rib_limits = request.limits.tension, request.limits.ribs
    rtol, max_iterations = settings.rtol, settings.max_iterations
    solver_options = settings.solver_options
    fabric = scenes[0].fabric
    if constraints is not None:
        constraints.check(fabric)
    n_bays = len(scenes)
    design = DesignVariables.build(request.variables, request.initial, request.bounds, n_ribs=n_bays + 1,
                                   rib_shape=layout.rib_shape, cut_pattern=layout.cut_pattern)
    if check_gaps:
        check_rib_gaps(wing, fabric, design.start, n_span=scenes[0].bay.n_span, n_contour=scenes[0].bay.n_contour,
                       rtol=rtol)
    if method == "root":
        if n_bays > 1:
            raise ValueError(f"method='root' solves one scalar condition at one bay's mid-bay section; this "
                             f"wing has {n_bays} bays: use slsqp, gauss_newton, least_squares or optax")
        if design.names != ("pressure",):
            raise ValueError(f"method='root' solves for the pressure alone; got variables {design.names}")
    geometries = []
    if method == "gauss_newton" and objective == "worst":
        raise ValueError("method='gauss_newton' fits the rows in the least-squares sense; the objective "
                         "'worst' is a smooth maximum over rows: use method='slsqp' for it, or objective "
                         "'average' or 'mid_bay'")
    if "rib_shape" in design.names and rib_limits is not None:
        if method not in ("slsqp", "gauss_newton"):
            raise ValueError(f"the rib limits (minimum thickness, curvature) are constraints that only "
                             f"method='slsqp' and 'gauss_newton' enforce, got method={method!r}: use one, or pass "
                             "Limits(ribs=None) to leave the rib shape free within its bounds")
        if design.rib_shapes is not None:  # each rib against its own starting section
            geometries = [(k, RibGeometry(section, rib_limits)) for k, section in enumerate(ribs)]
        else:  # one shape: against each distinct starting section
            firsts = [k for k, section in enumerate(ribs)
                      if not any(same_section(section, ribs[j]) for j in range(k))]
            geometries = [(k, RibGeometry(ribs[k], rib_limits)) for k in firsts]
    tolerance = settings.tolerance
    if tolerance is None:
        tolerance = {"slsqp": 1e-6, "gauss_newton": GN_TOLERANCE}.get(method, 1e-8)
    start = time.perf_counter()
    cap = SLSQP_EVALUATIONS_PER_ITERATION * max_iterations if method == "slsqp" else max_iterations
    with jax.enable_x64(True), _progress_bar(settings.progress, cap, name) as bar:
        problem = DesignProblem(scenes, targets, design, objective, constraints, rtol=rtol,
                                solver_options=solver_options,
                                rib_geometries=[g for _, g in geometries],
                                rib_indices=[k for k, _ in geometries], tolerances=request.tolerances)
        problem.on_record = _notify(bar, settings.callback, method)
        bar.set_postfix_str("initial equilibrium")
        u0 = design.start_vector()
        if method == "slsqp":
            sol0 = problem.evaluate(u0)[-1]  # the first iterate's solve, with its gradients
        elif method == "least_squares":
            sol0 = problem.residuals_and_jacobian(u0)[-1]
        elif method == "gauss_newton":
            sol0 = problem.linearised(u0)[-1]
        else:
            sol0 = problem.solve(u0)
        before = problem.measure(sol0, u0)
        start_parameters = sol0.parameters if design.rib_shapes is not None else design.parameters(u0).as_floats()
        start_shapes = concrete_rows(design.rib_shapes_at(u0))
        start_fields = concrete_rows(design.cut_patterns_at(u0))
        violated_at_start = {
            **constraint_report(constraints, design, start_parameters, before["tensions"], fabric,
                                tension_scale(start_parameters, problem.chord), start_shapes, start_fields)[1],
            **rib_report(geometries, start_parameters, start_shapes)[1]}
        try:
            if method == "root":
                u, success, message = root(problem, settings.root_condition, max_iterations, tolerance)
            elif method == "slsqp":
                u, success, message = slsqp(problem, u0, max_iterations, tolerance)
            elif method == "gauss_newton":
                u, success, message = gauss_newton(problem, u0, max_iterations, tolerance)
            elif method == "least_squares":
                u, success, message = least_squares(problem, u0, max_iterations, tolerance)
            else:
                u, success, message = optax_descent(problem, u0, max_iterations, tolerance, settings.optimiser)
        except BaysConvergenceError as failure:
            # Stop at the best iterate whose forward solves converged ("objective" is the
            # mean square error, or for "root" the condition, whose size is what counts).
            best = problem.best_iterate()
            u = u0 if best is None else best
            success, message = False, _failed_solve_message(failure)
        u = np.clip(np.asarray(u, dtype=np.float64), design.lower, design.upper)
        sol = problem.final_solution(u)
        parameters = sol.parameters if design.rib_shapes is not None else design.parameters(u).as_floats()
        after = problem.measure(sol, u)
        if not (np.all(np.isfinite(after["rms"])) and np.all(np.isfinite(after["max"]))
                and np.all(np.isfinite(sol.nodes))):
            success = False
            message = f"{message}; the shape errors at the result are not finite"
        shapes, fields = concrete_rows(design.rib_shapes_at(u)), concrete_rows(design.cut_patterns_at(u))
        active, violated, report, broken = constraint_report(constraints, design, parameters, after["tensions"], fabric,
                                                             tension_scale(parameters, problem.chord), shapes, fields)
        rib_active, rib_violated, rib_values, per_rib, rib_broken = rib_report(geometries, parameters, shapes)
        crossed, crossings = rib_crossings(ribs, parameters, shapes)
        rib_violated, rib_broken = {**rib_violated, **crossed}, rib_broken + crossings
        if violated or rib_violated:
            success = False
            message = f"{message}; {'; '.join(rib_broken + broken)}{UNMET_ADVICE}"
        active, violated, report = active + rib_active, {**violated, **rib_violated}, {**report, **rib_values}
        if problem.robust is not None:  # the limits at their percentile, and the quantile reached
            quantiles, quantile_broken = _robust_report(problem, u, constraints, fabric)
            report.update(quantiles)
            if quantile_broken:
                violated = {**violated, **quantile_broken[0]}
                success = False
                message = f"{message}; {'; '.join(quantile_broken[1])}{UNMET_ADVICE}"
    per_bay = PerBayResults(
        scenes=tuple(scenes), targets=tuple(targets), weights=problem.weights,
        rms_error=after["rms"], max_error=after["max"], initial_rms_error=before["rms"],
        initial_max_error=before["max"], min_tension=after["min_tension"], max_tension=after["max_tension"],
        rib_shapes=shapes, cut_patterns=fields, rib_limits=per_rib)
    return DesignResult(
        parameters=parameters,
        rms_error=after["wing_rms"],
        max_error=float(np.max(after["max"])),
        initial_rms_error=before["wing_rms"],
        initial_max_error=float(np.max(before["max"])),
        wing_solution=sol,
        request=dataclasses.replace(request, variables=design.names),
        per_bay=per_bay,
        history=problem.history,
        success=bool(success and sol.converged),
        message=message,
        active_constraints=active,
        violated_constraints=_largest(violated),
        violated_where=violated,
        violated_at_start=_largest(violated_at_start),
        violated_at_start_where=violated_at_start,
        constraint_values=report,
        method=method,
        solves=problem.solves,
        wall_time=time.perf_counter() - start,
        wing=wing,
    )


def evaluate_design(scenes, targets, parameters: Parameters | Mapping | None = None, *, objective: str = "mid_bay",
                    wing: Wing | None = None, solver: SolverSettings | None = None,
                    solution: Solution | BaysSolution | None = None) -> DesignResult:
    """One equilibrium of N >= 1 bays at ``parameters``, measured as a design is (no variables, no history).

    The errors are those of `optimise_wing` (each bay's rows against the
    targets blended between its ribs, combined by planform area); the
    tensions are the unclamped cell tensions (`constraints.cell_tensions`),
    so a fibre that would be in compression shows as a negative tension.
    No limit is judged: ``violated_constraints`` is empty and
    ``constraint_values`` holds the measured extremes only.

    Args:
        scenes: a `forward_solver.Scene`, or one per bay, root to tip
            (`forward_solver.Wing.scenes`).
        targets: one `targets.Airfoil` for every rib, or one per rib.
        parameters: a `Parameters` or ``{name: value}`` over
            `variables.DEFAULT_START` (Pa, fractions).
        objective: the rows measured, as `optimise_wing`.
        wing: the `forward_solver.Wing` the scenes belong to (for the report's stations).
        solver: the solve's ``rtol``, ``equilibrium_method`` and
            ``max_steps`` (`settings.SolverSettings`; None: the defaults with
            ``rtol`` 1e-8, `forward_solver.solve_equilibrium`'s).
        solution: an equilibrium of the bays solved already (a `Solution`
            of one bay, or a `BaysSolution`): measured as it is, not solved
            again (``parameters`` and ``solver`` are then not used; one that
            did not converge gives ``success`` False).

    Returns:
        A `DesignResult` with no variables and an empty history; its
        initial errors are NaN (there is no start).

    Raises:
        forward_solver.ConvergenceError: if a bay's solve does not converge (a
            `BaysConvergenceError` naming the bay for several bays).
        ValueError: for an unknown objective.
    """
    scenes = [scenes] if isinstance(scenes, Scene) else list(scenes)
    targets = [targets] * (len(scenes) + 1) if hasattr(targets, "distance") else list(targets)
    if len(targets) != len(scenes) + 1:
        raise ValueError(f"give one target section per rib: {len(scenes) + 1} ribs, got {len(targets)} targets")
    check_objective(objective)
    start = time.perf_counter()
    bays = [scene.bay for scene in scenes]
    etas = station_etas(objective, bays[0].n_span)
    weights = bay_weights(bays)
    if isinstance(solution, Solution):  # one bay's solve: the wing of that bay
        if len(scenes) != 1:
            raise ValueError(f"a Solution is one bay's equilibrium; got {len(scenes)} scenes")
        solution = BaysSolution(
            nodes=np.asarray(solution.nodes, np.float64)[None], result=np.asarray([int(solution.result)], np.int32),
            residual=np.asarray([float(solution.residual)]), steps=np.asarray([int(solution.steps)]),
            bays=bays, parameters=solution.parameters, fabric=scenes[0].fabric,
            tension_only=scenes[0].tension_only, solutions=[solution], scenes=scenes)
    with jax.enable_x64(True):
        if solution is None:
            solver = SolverSettings(rtol=1e-8) if solver is None else solver
            if not isinstance(parameters, Parameters):
                parameters = DEFAULT_START.replace(**dict(parameters or {}))
            sol = solve_bays(scenes, parameters, rtol=solver.rtol, max_steps=solver.max_steps,
                             method=solver.equilibrium_method, sequencing=bays[0].n_contour > 128)
            if not sol.converged:  # (one bay: its own failure, as solve_equilibrium's)
                raise (BaysConvergenceError(sol, sol.failed_bays()[0]) if len(scenes) > 1
                       else ConvergenceError(sol.bay_solution(0)))
        else:
            sol, parameters = solution, solution.parameters
        errors, mean_squares, tensions = [], [], []
        for k, (scene, bay) in enumerate(zip(scenes, bays)):
            rows = row_targets(targets[k], targets[k + 1], bay.chord_root, bay.chord_tip, etas)
            d = np.asarray(bay_distances(jnp.asarray(sol.nodes[k]), rows, etas, local_chords(bay, etas)))
            errors.append(distance_errors(d, objective))
            mean_squares.append(np.mean(d**2) if objective != "worst" else errors[-1][0] ** 2)
            tensions.append(np.asarray(cell_tensions(scene, jnp.asarray(sol.nodes[k]), sol.bay_solution(k).parameters)))
    rms = np.array([e[0] for e in errors])
    largest = np.array([e[1] for e in errors])
    low, high = np.array([t.min() for t in tensions]), np.array([t.max() for t in tensions])
    nan = np.full(len(scenes), np.nan)
    per_bay = PerBayResults(scenes=tuple(scenes), targets=tuple(targets), weights=weights, rms_error=rms,
                            max_error=largest, initial_rms_error=nan, initial_max_error=nan, min_tension=low,
                            max_tension=high)
    return DesignResult(
        parameters=parameters.as_floats(),
        rms_error=float(rms[0]) if len(scenes) == 1 else float(np.sqrt(np.sum(weights * np.array(mean_squares)))),
        max_error=float(np.max(largest)), initial_rms_error=math.nan, initial_max_error=math.nan,
        wing_solution=sol, request=DesignRequest(variables=(), initial=parameters, objective=objective, method=None),
        per_bay=per_bay, success=bool(sol.converged),
        message=("a single equilibrium (no optimisation)" if sol.converged else
                 f"a single equilibrium that did not converge: {sol.bay_solution(sol.failed_bays()[0]).message}"),
        constraint_values={"min_tension": float(low.min()), "max_tension": float(high.max())},
        solves=1, wall_time=time.perf_counter() - start, wing=wing)


def refine_design(result: DesignResult, scene: Scene | None = None, target=None, *, layout: Layout | None = None,
                  bounds: Mapping | None = None, limits: Limits = Limits(), solver: SolverSettings = SolverSettings(),
                  rib=None, tolerances=None) -> DesignResult:
    """Confirm and polish a design on a finer grid, and record how far it moved.

    Runs the design again on the finer grid from ``result``'s design, with its
    variables, objective and method: one bay by `optimise_pressure` on
    ``scene`` (the same case on a finer grid) with ``target``; a wing by
    `optimise_wing` on ``layout``'s grid with the result's wing, fabric and
    targets. A design that is converged in the grid moves little (and the
    method, starting at the optimum, stops in a few iterates); the move is
    the design's discretisation error, recorded in `DesignResult.grid_change`.

    Args:
        result: the design on the coarser grid.
        scene, target: one bay's finer scene and its target, as for the coarse design.
        layout: a wing's finer grid (`settings.Layout`; its ``cut_pattern``
            is the result's: "per_bay" when it has a cut pattern per bay).
        bounds, limits, solver: as for the coarse design.
        rib: one bay's starting rib section, as for the coarse design.
        tolerances: of a robust design (None: the coarse design's).

    Returns:
        The fine grid's `DesignResult` with ``grid_change`` filled in; its
        ``solves``, ``wall_time`` and ``history`` cover both grids, and its
        initial errors are those of the start of the design (measured on the
        coarser grid).

    Raises:
        ValueError: for a one-bay design without ``scene`` and ``target``, or
            a wing without ``layout``.
    """
    tolerances = result.request.tolerances if tolerances is None else tolerances
    if result.n_bays == 1 and scene is not None:
        if target is None:
            raise ValueError("refine_design of a one-bay design needs the finer scene and its target")
        fine = optimise_pressure(scene, target, result.variables, initial=result.parameters, bounds=bounds,
                                 objective=result.objective, method=result.method, limits=limits, solver=solver,
                                 rib=rib, tolerances=tolerances)
        grid = [scene.bay.n_span, scene.bay.n_contour]
    else:
        if layout is None or result.wing is None:
            raise ValueError("refine_design of a wing needs the finer grid as layout=Layout(n_span=..., "
                             "n_contour=...) (and a one-bay design its finer scene and target)")
        rows = {n: v for n, v in (("rib_shape", result.per_bay.rib_shapes),
                                  ("cut_pattern", result.per_bay.cut_patterns))
                if v is not None}
        initial = result.parameters if not rows else {
            **{n: getattr(result.parameters, n) for n in VARIABLES
               if n not in rows and getattr(result.parameters, n) is not None}, **rows}
        if result.per_bay.cut_patterns is not None:
            layout = dataclasses.replace(layout, cut_pattern="per_bay")
        fine = optimise_wing(result.wing, result.per_bay.scenes[0].fabric, list(result.per_bay.targets),
                             result.variables,
                             initial=initial, bounds=bounds, objective=result.objective, method=result.method,
                             limits=limits, solver=solver, layout=layout, tolerances=tolerances)
        grid = [layout.n_span, layout.n_contour]
    coarse_grid = list(np.shape(result.wing_solution.nodes)[1:3])
    values = {n: [_value(result, n), _value(fine, n)] for n in result.variables}
    change = {n: (b - a) / a if n == "pressure" else float(np.max(np.abs(np.subtract(b, a))))
              for n, (a, b) in values.items()}
    grid_change = {"grids": [coarse_grid, grid], "values": values,
                   "change": change, "rms_error": [result.rms_error, fine.rms_error]}
    return dataclasses.replace(fine, grid_change=grid_change, solves=result.solves + fine.solves,
                               wall_time=result.wall_time + fine.wall_time,
                               history=[*result.history, *fine.history],
                               initial_rms_error=result.initial_rms_error,
                               initial_max_error=result.initial_max_error,
                               violated_at_start=result.violated_at_start,
                               violated_at_start_where=result.violated_at_start_where)


def _robust_report(problem: DesignProblem, u, constraints, fabric) -> tuple[dict, tuple | None]:
    """A robust design's tension limits at each cell's own percentile (``min_tension_p5``, ``max_tension_p95``: the least
    ``t - 1.645 sigma`` and the largest ``t + 1.645 sigma`` over the cells, N/m; `robust`), and, where
    one is broken by more than `constraints.VIOLATION_TOLERANCE` of the tension scale, ``({name: {bay:
    amount}}, [sentence])``."""
    from .constraints import VIOLATION_TOLERANCE, floor_threshold
    from .robust import QUANTILE_Z

    values = {}
    if constraints is None:
        return values, None
    sol = problem.nominal_linearised(u)[-1]
    tensions = problem.measure(sol, u)["tensions"]
    raw = problem.robust.raw(u, sol, derivatives=False)
    where, sentences = {}, []
    scale = tension_scale(sol.parameters, problem.chord)
    floor, ceiling = constraints.min_tension, constraints.ceiling(fabric)
    for k, (t, a) in enumerate(zip(tensions, raw["tensions"])):
        sigma = np.sqrt(np.sum(a * a, axis=1))
        low, high = float(np.min(t - QUANTILE_Z * sigma)), float(np.max(t + QUANTILE_Z * sigma))
        values["min_tension_p5"] = min(values.get("min_tension_p5", math.inf), low)
        values["max_tension_p95"] = max(values.get("max_tension_p95", -math.inf), high)
        at = "" if len(tensions) == 1 else f" in bay {k}"
        if floor is not None and low < floor_threshold(floor, scale):
            where.setdefault("min_tension_p5", {})[k] = floor - low
            sentences.append(f"min_tension_p5 violated{at}: a cell's fibre tension at its 5th percentile is "
                             f"{low:.4g} N/m, {floor - low:.4g} N/m below the floor {floor:.4g} N/m (1 wing in 20 "
                             "wrinkles there)")
        if math.isfinite(ceiling) and high - ceiling > VIOLATION_TOLERANCE * scale:
            where.setdefault("max_tension_p95", {})[k] = high - ceiling
            sentences.append(f"max_tension_p95 violated{at}: a cell's fibre tension at its 95th percentile is "
                             f"{high:.4g} N/m, {high - ceiling:.4g} N/m above the ceiling {ceiling:.4g} N/m")
    return values, ((where, sentences) if where else None)


def _largest(where: dict) -> dict:
    """``{name: the largest amount}`` of ``{name: {bay or rib: amount}}``."""
    return {name: max(float(v) for v in amounts.values()) for name, amounts in where.items()}


def _value(result: DesignResult, name: str):
    """A design value as a float, or a list of floats (of lists, per rib) for a vector variable."""
    value = {"rib_shape": result.per_bay.rib_shapes, "cut_pattern": result.per_bay.cut_patterns}.get(name)
    value = getattr(result.parameters, name) if value is None else value
    return float(value) if np.ndim(value) == 0 else np.asarray(value, np.float64).tolist()


def _failed_solve_message(failure: BaysConvergenceError) -> str:
    sol = failure.solution
    where = "" if failure.n_bays == 1 else (f" in bay {failure.bay} ({len(failure.failed)} of {failure.n_bays} "
                                            "bays failed)")
    return (f"stopped: the forward solve at pressure {sol.pressure:.6g} Pa, prestrain "
            f"({sol.prestrain[0]:.6g}, {sol.prestrain[1]:.6g}) failed{where} ({sol.message}); the "
            "result is the best iterate whose solve converged; narrow the bounds to where the "
            "skin has an equilibrium")


# ------------------------------------------------------------------ progress
def _progress_bar(progress: bool, cap: int, name: str):
    """A tqdm counter on stderr: wing solves so far (one per iterate, every bay solved once) against the
    cap; a silent no-op when off.

    No percentage or ETA: the cap is an upper bound, not the expected count.
    """
    import os
    import sys

    try:
        size = os.get_terminal_size(sys.stderr.fileno())
    except (AttributeError, ValueError, OSError):
        size = None
    # A terminal that reports no size (0 x 0: a pseudo-terminal nobody sized, as under `script`) makes
    # tqdm print nothing at all: a fixed 80 x 24 there.
    shape = dict(dynamic_ncols=True) if size and size.lines and size.columns else dict(ncols=80, nrows=24)
    return tqdm(total=cap, desc=name, unit="wing solve", disable=not progress, leave=False, **shape,
                bar_format="{desc}: wing solve {n_fmt} (cap {total_fmt}), {elapsed} elapsed, "
                           "{rate_inv_fmt}{postfix}")


def _notify(bar, callback, method: str):
    """The per-iterate hook: tick the bar, show the objective, call the user's callback."""

    def on_record(entry: dict) -> None:
        value = entry["objective"]
        shown = f"condition={value:.3e}" if method == "root" else f"rms={math.sqrt(max(value, 0.0)):.3e}"
        if "jacobian" in entry:  # the Jacobian's bay blocks (gauss_newton: one pass of compressed tangents)
            shown += f", Jacobian {entry['jacobian']}"
        bar.set_postfix_str(shown, refresh=False)
        bar.update(1)
        if callback is not None:
            callback(entry)

    return on_record
