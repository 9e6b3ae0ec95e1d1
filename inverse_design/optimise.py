"""`optimise_wing` and `optimise_pressure`: manufacturing parameters that make the inflated skin match a target.

One design over a wing of N >= 1 bays (`optimise_wing`; `optimise_pressure`
is the one-bay case of a `forward_solver.Scene`): one pressure, prestrain and
rib scales for every bay, and a rib shape shared by every rib or one per rib
(`variables`); the objective is the bays' distances from their row targets
weighted by planform area (`objectives`); the tension limits hold over every
cell of every bay (`constraints`); the ribs' manufacturability limits per rib
(`rib_design`). The method is a value of `methods` with its own knobs (the
strings are shortcuts: "auto", the default, runs `methods.GaussNewton`, or
`methods.SLSQP` for the objective "worst"; `methods.LeastSquares`,
`methods.Optax`, and `methods.Root` on one bay's mid-bay condition); the
objective, constraints and their derivatives are `problem.DesignProblem`'s.

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
from typing import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from forward_solver import ConvergenceError, Parameters, Scene, Solution, Wing, solve_bays
from forward_solver.model.bay import Bay
from forward_solver.solution import BaysConvergenceError, BaysSolution
from forward_solver.solvers.bays import check_rib_gaps
from targets import Airfoil

from .constraints import UNMET_ADVICE, cell_tensions, constraint_report, tension_scale
from .fabric_range import warn_outside_tested_range
from .objectives import DEFAULT_OBJECTIVE, WingTargets, same_section
from .problem import DesignProblem
from .progress import notify, progress_bar
from .result import DesignResult, LimitReport, PerBayResults
from .rib_design import RibGeometry, rib_crossings, rib_report
from .sensitivity import sensitivity
from .settings import MOVED_KEYWORDS, DesignRequest, Layout, Limits, SolverSettings, refuse_moved
from .variables import DEFAULT_START, VARIABLES, DesignVariables, concrete_rows

__all__ = ["evaluate_design", "optimise_pressure", "optimise_wing", "refine_design"]

#: The keywords of `optimise_wing` that `DesignRequest` holds now, and where the older ones went.
REQUEST_KEYWORDS = {**{name: f"request=DesignRequest({moved})" for name, moved in MOVED_KEYWORDS.items()
                       if name != "rib"},
                    **{name: f"request=DesignRequest({name}=...)" for name in
                       ("variables", "initial", "bounds", "objective", "method", "limits", "solver", "layout",
                        "tolerances")}}


def optimise_wing(wing: Wing, fabric, targets: Sequence | None = None, request: DesignRequest = DesignRequest(),
                  **moved) -> DesignResult:
    """One pressure (and prestrain, rib scales, rib shapes) for every bay of ``wing`` (module docstring).

    Args:
        wing: the ribs (`forward_solver.Wing`).
        fabric: the skin's `forward_solver.Fabric` (one for the whole wing).
        targets: the target section of each rib (N + 1 `targets.Airfoil`), one
            `targets.Airfoil` for every rib, or None: each rib's own section.
        request: what is asked (`settings.DesignRequest`: the variables, their start and bounds, the
            objective per bay, combined over bays weighted by planform area, the method, the limits,
            the tolerances of the objective "robust", the layout of the vector variables and every
            bay's grid, the solver settings).
        **moved: the keyword arguments that moved into ``request``: refused
            with a TypeError that names where each went.

    Returns:
        A `DesignResult` (``method`` names the method that ran).

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
    refuse_moved("optimise_wing", moved, REQUEST_KEYWORDS)
    if not isinstance(wing, Wing):
        raise ValueError(f"wing must be a forward_solver.Wing, got {type(wing).__name__}")
    if not isinstance(request, DesignRequest):
        raise ValueError(f"request must be an inverse_design.DesignRequest, got {request!r}")
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
    layout = request.layout
    return _optimise(wing.scenes(fabric, layout.n_span, layout.n_contour), targets, list(wing.sections), wing,
                     request, name="optimise_wing")


def optimise_pressure(
    scene: Scene,
    target,
    variables=("pressure",),
    *,
    initial: Parameters | Mapping | None = None,
    bounds: Mapping | None = None,
    objective: str = DEFAULT_OBJECTIVE,
    method="auto",
    limits: Limits = Limits(),
    solver: SolverSettings = SolverSettings(),
    tolerances=None,
    **moved,
) -> DesignResult:
    """Pressure, prestrain and rib geometry that bring one bay's inflated skin closest to ``target``.

    The one-bay case of `optimise_wing` on ``scene`` itself (its bay, fabric,
    physics switches and grid), with ``target`` at both ribs and one rib shape
    for both ribs, whose limits are measured against the rib sections the bay
    was built from (`forward_solver.Bay.from_airfoil`; a flat panel's against
    the target).

    Args:
        scene: bay, fabric and physics switches (`forward_solver.Scene`).
        target: the target section, a chord-normalised `targets.Airfoil`.
        variables: names to optimise, from `variables.VARIABLES`.
        initial: the starting `Parameters`, or ``{name: value}`` (Pa,
            fractions) over `variables.DEFAULT_START`; names that are not
            optimised stay at these values.
        bounds: ``{name: (lower, upper)}`` of optimised names (defaults
            `variables.DEFAULT_BOUNDS`; ``rib_shape``'s for every coefficient).
        objective: "mid_bay", "average" (default, `objectives.DEFAULT_OBJECTIVE`), "worst" or "robust".
        method: a method of `methods` or its shortcut: "auto" (default:
            "gauss_newton"; "slsqp" for the objective "worst"), "slsqp",
            "gauss_newton", "least_squares", "optax" or "root" (its condition:
            `methods.Root`).
        limits: the tension limits and the limits of a shaped rib (`settings.Limits`).
        solver: what every method shares (`settings.SolverSettings`).
        tolerances: the tolerances of ``objective="robust"`` (``{name: value}``
            or anything `tolerance.parse_tolerances` takes; None: every default,
            docs/tolerances.md); refused with another objective.
        **moved: the keyword arguments that moved into ``limits``, ``solver``
            and the method values: refused with a TypeError that names where each went.

    Returns:
        A `DesignResult` (its ``solution`` the bay's `Solution`).

    Raises:
        TypeError: if ``target`` is not a `targets.Airfoil` (None among them),
            or for a keyword that moved.
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
    layout = Layout(rib_shape="shared", cut_pattern="shared", n_span=bay.n_span, n_contour=bay.n_contour)
    request = DesignRequest(variables, initial, bounds, objective, method, limits, tolerances, layout, solver)
    ribs = [target, target] if wing is None else list(wing.sections)
    return _optimise([scene], [target, target], ribs, wing, request, name="optimise_pressure", check_gaps=False)


def _optimise(scenes, targets, ribs, wing, request: DesignRequest, *, name: str, check_gaps: bool = True
              ) -> DesignResult:
    """The design ``request`` of the bays ``scenes`` (ribs' targets ``targets``, starting sections ``ribs``;
    ``check_gaps``: refuse ribs of ``wing`` too close for the grid, `forward_solver.solvers.bays.check_rib_gaps`;
    ``name``: the progress bar's)."""
    method, objective, settings, layout = request.method, request.objective, request.solver, request.layout
    constraints, rib_limits = request.limits.tension, request.limits.ribs
    fabric = scenes[0].fabric
    if constraints is not None:
        constraints.check(fabric)
    n_bays = len(scenes)
    design = DesignVariables.build(request.variables, request.initial, request.bounds, n_ribs=n_bays + 1,
                                   rib_shape=layout.rib_shape, cut_pattern=layout.cut_pattern)
    if check_gaps:
        check_rib_gaps(wing, fabric, design.start, n_span=scenes[0].bay.n_span, n_contour=scenes[0].bay.n_contour,
                       rtol=settings.rtol)
    method.check(objective, design.names, n_bays)
    geometries = []
    if "rib_shape" in design.names and rib_limits is not None:
        if not method.rib_limits:
            raise ValueError(f"the rib limits (minimum thickness, curvature) are constraints that only "
                             f"method='slsqp' and 'gauss_newton' enforce, got method={method.name!r}: use one, or "
                             "pass Limits(ribs=None) to leave the rib shape free within its bounds")
        if design.rib_shapes is not None:  # each rib against its own starting section
            geometries = [(k, RibGeometry(section, rib_limits)) for k, section in enumerate(ribs)]
        else:  # one shape: against each distinct starting section
            firsts = [k for k, section in enumerate(ribs)
                      if not any(same_section(section, ribs[j]) for j in range(k))]
            geometries = [(k, RibGeometry(ribs[k], rib_limits)) for k in firsts]
    start = time.perf_counter()
    with jax.enable_x64(True), progress_bar(settings.progress, method.evaluations(settings.max_iterations),
                                            name) as bar:
        problem = DesignProblem(scenes, WingTargets([scene.bay for scene in scenes], targets, objective), design,
                                tension=constraints, ribs=geometries, solver=settings, tolerances=request.tolerances)
        problem.history.on_record = notify(bar, settings.callback, method)
        bar.set_postfix_str("initial equilibrium")
        u0 = design.start_vector()
        sol0 = method.start(problem, u0)
        before = problem.measure(sol0, u0)
        start_parameters = sol0.parameters if design.rib_shapes is not None else design.parameters(u0).as_floats()
        start_shapes = concrete_rows(design.rib_shapes_at(u0))
        start_fields = concrete_rows(design.cut_patterns_at(u0))
        violated_at_start = {
            **constraint_report(constraints, design, start_parameters, before["tensions"], fabric,
                                tension_scale(start_parameters, problem.chord), start_shapes, start_fields)[1],
            **rib_report(geometries, start_parameters, start_shapes)[1]}
        try:
            u, success, message = method.run(problem, u0, settings.max_iterations)
        except BaysConvergenceError as failure:
            # Stop at the best iterate whose forward solves converged ("objective" is the
            # mean square error, or for "root" the condition, whose size is what counts).
            best = problem.history.best()
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
            quantiles, quantile_broken = problem.robust.limits_report(u)
            report.update(quantiles)
            if quantile_broken:
                violated = {**violated, **quantile_broken[0]}
                success = False
                message = f"{message}; {'; '.join(quantile_broken[1])}{UNMET_ADVICE}"
        solves = problem.solves  # the design's; the sensitivity's own (none after Gauss-Newton) are its record's
        prices = _sensitivity(problem, method, sol, after, u, active, parameters, shapes, fields)
    per_bay = PerBayResults(
        scenes=tuple(scenes), targets=tuple(targets), weights=problem.targets.weights,
        rms_error=after["rms"], max_error=after["max"], initial_rms_error=before["rms"],
        initial_max_error=before["max"], min_tension=after["min_tension"], max_tension=after["max_tension"],
        rib_shapes=shapes, cut_patterns=fields, rib_limits=per_rib, sections=tuple(ribs))
    limits = LimitReport(active=active, violated=_largest(violated), violated_where=violated,
                         violated_at_start=_largest(violated_at_start), violated_at_start_where=violated_at_start,
                         values=report)
    result = DesignResult(
        parameters=parameters, rms_error=after["wing_rms"], max_error=float(np.max(after["max"])),
        initial_rms_error=before["wing_rms"], initial_max_error=float(np.max(before["max"])), wing_solution=sol,
        request=dataclasses.replace(request, variables=design.names), per_bay=per_bay, history=problem.history.entries,
        success=bool(success and sol.converged), message=message, limits=limits, solves=solves,
        wall_time=time.perf_counter() - start, wing=wing, sensitivity=prices)
    warn_outside_tested_range(result)
    return result


def _sensitivity(problem, method, sol, after, u, active, parameters, shapes, fields) -> dict | None:
    """`sensitivity.sensitivity` at the design, or None: after the method "root" (a root of a condition, not
    a minimum of the rms), at a design whose final solve or errors are not finite, or where the one wing
    solve of its linearisation (methods other than Gauss-Newton) fails (the design stands without it)."""
    if method.name == "root" or not (sol.converged and np.all(np.isfinite(after["rms"]))):
        return None
    try:
        return sensitivity(problem, u, active, parameters, shapes, fields)
    except BaysConvergenceError:
        return None


def evaluate_design(scenes, targets, parameters: Parameters | Mapping | None = None, *,
                    objective: str = DEFAULT_OBJECTIVE, wing: Wing | None = None, solver: SolverSettings | None = None,
                    solution: Solution | BaysSolution | None = None) -> DesignResult:
    """One equilibrium of N >= 1 bays at ``parameters``, measured as a design is (no variables, no history).

    The errors are those of `optimise_wing` (each bay's rows against the
    targets blended between its ribs, combined by planform area:
    `objectives.WingTargets`); the tensions are the unclamped cell tensions
    (`constraints.cell_tensions`), so a fibre that would be in compression
    shows as a negative tension. No limit is judged: ``limits.violated`` is
    empty and ``limits.values`` holds the measured extremes only.

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
    start = time.perf_counter()
    bays = [scene.bay for scene in scenes]
    measured = WingTargets(bays, targets, objective)
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
        errors = measured.errors([np.asarray(measured.distances(k, jnp.asarray(sol.nodes[k])))
                                  for k in range(len(scenes))])
        tensions = [np.asarray(cell_tensions(scene, jnp.asarray(sol.nodes[k]), sol.bay_solution(k).parameters))
                    for k, scene in enumerate(scenes)]
    low, high = np.array([t.min() for t in tensions]), np.array([t.max() for t in tensions])
    nan = np.full(len(scenes), np.nan)
    per_bay = PerBayResults(scenes=tuple(scenes), targets=tuple(targets), weights=measured.weights,
                            rms_error=errors["rms"], max_error=errors["max"], initial_rms_error=nan,
                            initial_max_error=nan, min_tension=low, max_tension=high)
    result = DesignResult(
        parameters=parameters.as_floats(), rms_error=errors["wing_rms"], max_error=float(np.max(errors["max"])),
        initial_rms_error=math.nan, initial_max_error=math.nan, wing_solution=sol,
        request=DesignRequest(variables=(), initial=parameters, objective=objective, method=None),
        per_bay=per_bay, success=bool(sol.converged),
        message=("a single equilibrium (no optimisation)" if sol.converged else
                 f"a single equilibrium that did not converge: {sol.bay_solution(sol.failed_bays()[0]).message}"),
        limits=LimitReport(values={"min_tension": float(low.min()), "max_tension": float(high.max())}),
        solves=1, wall_time=time.perf_counter() - start, wing=wing)
    if sol.converged:
        warn_outside_tested_range(result, "the equilibrium")
    return result


def refine_design(result: DesignResult, layout: Layout, solver: SolverSettings | None = None) -> DesignResult:
    """Confirm and polish a design on a finer grid, and record how far it moved.

    Runs what ``result.request`` asked (its variables, bounds, objective,
    method, limits, tolerances and the layout of its vector variables) again
    on the finer grid of every bay, from ``result``'s design, one bay and a
    wing alike: each bay rebuilt from its rib sections on the finer grid
    (`forward_solver.Bay.from_airfoil`), with the result's fabric, physics
    switches, targets and rib sections. A design that is converged in the grid
    moves little (and the method, starting at the optimum, stops in a few
    iterates); the move is the design's discretisation error, recorded in
    `DesignResult.grid_change`.

    Args:
        result: the design on the coarser grid (of bays built from airfoils).
        layout: the finer grid (``n_span``, ``n_contour`` of `settings.Layout`;
            the layout of the vector variables is the request's).
        solver: the settings of the finer design (None: the request's).

    Returns:
        The fine grid's `DesignResult` with ``grid_change`` filled in; its
        ``solves``, ``wall_time`` and ``history`` cover both grids, and its
        initial errors and the limits broken at the start are those of the
        start of the design (measured on the coarser grid).

    Raises:
        TypeError: for a finer grid that is not a `settings.Layout` (the scene and target of one bay,
            the bounds, limits and tolerances are the request's).
        ValueError: for a single equilibrium or a design of a flat panel (no rib sections to rebuild).
    """
    if not isinstance(layout, Layout):
        raise TypeError(f"refine_design takes the finer grid as layout=Layout(n_span=..., n_contour=...) (what was "
                        f"asked is result.request's), got {type(layout).__name__}")
    if not result.variables or result.wing is None:
        raise ValueError("refine_design refines a design of bays built from airfoils (result.wing); this result "
                         f"is {'a single equilibrium' if not result.variables else 'a flat panel'}")
    request = result.request
    rows = {n: v for n, v in (("rib_shape", result.per_bay.rib_shapes), ("cut_pattern", result.per_bay.cut_patterns))
            if v is not None}
    initial = result.parameters if not rows else {
        **{n: getattr(result.parameters, n) for n in VARIABLES
           if n not in rows and getattr(result.parameters, n) is not None}, **rows}
    fine_layout = dataclasses.replace(request.layout, n_span=layout.n_span, n_contour=layout.n_contour)
    scenes = [dataclasses.replace(scene, bay=_regrid(scene.bay, layout.n_span, layout.n_contour))
              for scene in result.per_bay.scenes]
    fine = _optimise(scenes, list(result.per_bay.targets), list(result.per_bay.sections), result.wing,
                     dataclasses.replace(request, initial=initial, layout=fine_layout,
                                         solver=request.solver if solver is None else solver),
                     name="refine_design")
    values = {n: [_value(result, n), _value(fine, n)] for n in result.variables}
    change = {n: (b - a) / a if n == "pressure" else float(np.max(np.abs(np.subtract(b, a))))
              for n, (a, b) in values.items()}
    grid_change = {"grids": [list(np.shape(result.wing_solution.nodes)[1:3]), [layout.n_span, layout.n_contour]],
                   "values": values, "change": change, "rms_error": [result.rms_error, fine.rms_error]}
    limits = dataclasses.replace(fine.limits, violated_at_start=result.limits.violated_at_start,
                                 violated_at_start_where=result.limits.violated_at_start_where)
    return dataclasses.replace(fine, grid_change=grid_change, solves=result.solves + fine.solves,
                               wall_time=result.wall_time + fine.wall_time, history=[*result.history, *fine.history],
                               initial_rms_error=result.initial_rms_error,
                               initial_max_error=result.initial_max_error, limits=limits)


def _regrid(bay: Bay, n_span: int, n_contour: int) -> Bay:
    """``bay`` built again from its rib sections on another grid (as `forward_solver.Bay.from_airfoil` made it)."""
    return Bay.from_airfoil(bay.airfoil, chord=bay.chord_root, rib_spacing=bay.rib_spacing, n_span=n_span,
                            n_contour=n_contour, fix_trailing_edge=bay.fix_trailing_edge, tip_airfoil=bay.tip_airfoil,
                            tip_chord=bay.chord_tip)


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
