"""`optimise_pressure`: manufacturing parameters that make the inflated skin match a target.

Methods (DESIGN section 6):

* ``"root"``: `scipy.optimize.brentq` on the pressure alone, for a scalar
  condition at mid-bay: ``root_condition="thickness"`` (maximum thickness of
  the mid-bay section equal to the target's) or ``"mean_offset"`` (zero mean
  normal distance). The bracket is found automatically by stepping the
  pressure geometrically (factor 2) from its start towards both bounds; when
  the condition does not change sign inside the bounds a ValueError says so.
* ``"least_squares"``: `scipy.optimize.least_squares` (trust-region
  reflective, with the bounds) on the vector of section distances
  (`objectives.objective_residuals`), plus the tension-constraint penalties;
  its Jacobian comes from JAX in forward mode (one ``jax.jvp`` per variable)
  through the implicit equilibrium (`forward_solver.adjoint.Equilibrium`).
* ``"optax"``: an optax optimiser (Adam by default) on the mean square
  error, with the gradient from reverse mode (``jax.grad``) and a projection
  onto the bounds after every step; meant for many variables.

Every forward solve warm-starts from the previous iterate's equilibrium and
is solved to `forward_solver.adjoint.GRADIENT_RTOL`. All JAX work runs
inside ``jax.enable_x64(True)`` (thread-local; the caller's configuration is
untouched).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Mapping

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
from tqdm import tqdm

from forward_solver import ConvergenceError, Scene, Solution
from forward_solver.adjoint import GRADIENT_RTOL, Equilibrium

from .constraints import Constraints, cell_tensions, constraint_report, penalty_residuals, tension_scale
from .objectives import check_objective, design_errors, objective_residuals, section_points
from .variables import DesignVariables

__all__ = ["METHODS", "ROOT_CONDITIONS", "DesignResult", "optimise_pressure"]

METHODS = ("root", "least_squares", "optax")
ROOT_CONDITIONS = ("thickness", "mean_offset")
#: Geometric step of the automatic bracketing of ``method="root"``.
BRACKET_FACTOR = 2.0


@dataclass(frozen=True, eq=False)
class DesignResult:
    """Outcome of `optimise_pressure`.

    Attributes:
        pressure: Pa.
        prestrain: ``(span, chord)``.
        rib_thickness_scale, rib_chord_scale: rib geometry multipliers.
        values: every parameter value at the optimum.
        variables: the optimised names.
        rms_error, max_error: normal distance from the target over the
            objective's sections at the optimum, fractions of chord.
        initial_rms_error, initial_max_error: the same at the start.
        solution: the `Solution` at the optimum.
        history: one dict per iterate (forward solve): ``values`` (the
            optimised variables), ``objective`` (mean square distance, chord^2;
            for "root" the condition's value), ``gradient_norm`` (of the
            objective in the scaled variables; NaN where not computed) and
            ``steps`` (forward-solve steps).
        success: whether the method reports convergence and the final
            solve converged.
        message: the method's message.
        active_constraints: names of bounds (``"pressure<=upper"``) and tension
            constraints (``"min_tension"``, ``"max_tension"``) that are active
            or violated at the optimum.
        constraint_values: the measured minimum and maximum fibre tension (N/m)
            and the limits.
        method, objective: as requested.
        solves: forward solves.
        wall_time: s, compilation included.
    """

    pressure: float
    prestrain: tuple[float, float]
    rib_thickness_scale: float
    rib_chord_scale: float
    values: dict
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
    constraint_values: dict = field(default_factory=dict)
    method: str = ""
    objective: str = ""
    solves: int = 0
    wall_time: float = 0.0


class _Problem:
    """The objective, its derivatives and the iterate history of one optimisation."""

    def __init__(self, scene, target, variables: DesignVariables, objective, constraints, rtol):
        self.scene = scene
        self.target = target
        self.variables = variables
        self.objective = objective
        self.constraints = constraints
        self.chord = scene.bay.chord
        fixed = {k: v for k, v in variables.values.items() if k not in variables.names}
        # Small design grids: one relaxation loop to compile beats grid sequencing.
        self.equilibrium = Equilibrium(scene, fixed, rtol=rtol,
                                       sequencing=scene.bay.n_contour > 128)
        self.history: list[dict] = []
        self.on_record = None  # called with each new history entry (progress bar, callback)
        self.tension_scale = tension_scale(variables.values, self.chord)

    def residuals(self, u):
        """Shape residuals and penalties for the scaled vector ``u`` (a JAX value allowed)."""
        v = self.variables
        theta = {n: u[k] * v.scale(n) for k, n in enumerate(v.names)}
        nodes = self.equilibrium(theta)
        shape = objective_residuals(nodes, self.target, self.chord, self.objective)
        if self.constraints is None:
            return shape
        values = {**self.variables.values, **theta}
        tensions = cell_tensions(self.scene, nodes, values)
        penalties = penalty_residuals(self.constraints, tensions, self.scene.fabric, self.tension_scale)
        return jnp.concatenate([shape, penalties])

    def record(self, u, objective, gradient_norm=math.nan):
        sol = self.equilibrium.solution
        self.history.append({
            "values": {n: float(x) * self.variables.scale(n) for n, x in zip(self.variables.names, u)},
            "objective": float(objective),
            "gradient_norm": float(gradient_norm),
            "steps": int(sol.steps) if sol is not None else 0,
        })
        if self.on_record is not None:
            self.on_record(self.history[-1])

    def value_and_jacobian(self, u):
        """Residuals and their Jacobian in ``u`` (forward mode, one ``jax.jvp`` per variable)."""
        u = jnp.asarray(u, jnp.float64)
        columns = []
        r = None
        for k in range(u.size):
            r, col = jax.jvp(self.residuals, (u,), (jnp.zeros_like(u).at[k].set(1.0),))
            columns.append(np.asarray(col))
        r = np.asarray(r)
        return r, np.stack(columns, axis=1)


def optimise_pressure(
    scene: Scene,
    target,
    variables=("pressure",),
    *,
    initial: Mapping | None = None,
    bounds: Mapping | None = None,
    objective: str = "mid_bay",
    constraints: Constraints | None = Constraints(),
    method: str = "least_squares",
    root_condition: str = "thickness",
    max_iterations: int = 50,
    tolerance: float = 1e-8,
    optimiser=None,
    rtol: float = GRADIENT_RTOL,
    progress: bool = False,
    callback=None,
) -> DesignResult:
    """Pressure, prestrain and rib geometry that bring the inflated skin closest to ``target``.

    Args:
        scene: bay, fabric and physics switches (`forward_solver.Scene`).
        target: the target section, a chord-normalised `targets.Airfoil`.
        variables: names to optimise, from `variables.VARIABLES`.
        initial: starting values (Pa, fractions); names that are not
            optimised stay at these values (defaults:
            `variables.DEFAULT_VALUES`).
        bounds: ``{name: (lower, upper)}`` for optimised names (defaults:
            `variables.DEFAULT_BOUNDS`).
        objective: "mid_bay", "average" or "worst" (`objectives`).
        constraints: tension constraints (`Constraints`; default a
            wrinkle-free skin below the fabric's allowable), or None.
        method: "root", "least_squares" or "optax".
        root_condition: "thickness" or "mean_offset" (``method="root"``).
        max_iterations: cap on iterations (least-squares Jacobian
            evaluations; optax steps; brentq iterations).
        tolerance: convergence tolerance: ``ftol``/``xtol``/``gtol`` of
            least_squares (scipy's own default, 1e-8: tighter only walks
            along the flat valley of a constrained optimum), the relative
            pressure tolerance of brentq, the scaled gradient norm of optax.
        optimiser: an ``optax.GradientTransformation`` (``method="optax"``;
            default ``optax.adam(0.02)`` on the scaled variables).
        rtol: relative residual of the forward solves.
        progress: show a tqdm progress bar on stderr, one tick per iterate
            (off by default: library code prints nothing unless asked).
        callback: called as ``callback(entry)`` after every iterate with the
            new `DesignResult.history` entry; an exception it raises stops the
            optimisation and propagates.

    Returns:
        A `DesignResult`.

    Raises:
        ValueError: for an unknown method, objective, variable or condition,
            bad bounds, or (``method="root"``) no sign change inside the
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
    if constraints is not None and not isinstance(constraints, Constraints):
        raise ValueError(f"constraints must be an inverse_design.Constraints or None, got {constraints!r}")
    design = DesignVariables.build(variables, initial, bounds)
    if method == "root":
        if design.names != ("pressure",):
            raise ValueError(f"method='root' solves for the pressure alone; got variables {design.names}")
        if root_condition not in ROOT_CONDITIONS:
            raise ValueError(f"root_condition must be one of {ROOT_CONDITIONS}, got {root_condition!r}")
    start = time.perf_counter()
    with jax.enable_x64(True), _progress_bar(progress, max_iterations) as bar:
        problem = _Problem(scene, target, design, objective, constraints, rtol)
        problem.on_record = _notify(bar, callback, method)
        bar.set_postfix_str("initial equilibrium")
        u0 = design.to_vector(design.values)
        sol0 = problem.equilibrium.solve(design.from_vector(u0))
        initial_errors = design_errors(sol0.nodes, target, problem.chord, objective)
        try:
            if method == "root":
                u, success, message = _root(problem, root_condition, max_iterations, tolerance)
            elif method == "least_squares":
                u, success, message = _least_squares(problem, u0, max_iterations, tolerance)
            else:
                u, success, message = _optax(problem, u0, max_iterations, tolerance, optimiser)
        except ConvergenceError as failure:
            # Stop at the best iterate whose forward solve converged ("objective" is the
            # mean square error, or for "root" the condition, whose size is what counts).
            best = min(problem.history, key=lambda h: abs(h["objective"]), default=None)
            u = design.to_vector(best["values"]) if best is not None else u0
            success, message = False, _failed_solve_message(failure)
        values = design.from_vector(u)
        sol = problem.equilibrium.solve(values)
        rms, max_error = design_errors(sol.nodes, target, problem.chord, objective)
        if not (np.isfinite([rms, max_error]).all() and np.isfinite(sol.nodes).all()):
            success = False
            message = f"{message}; the shape errors at the result are not finite"
        tensions = np.asarray(cell_tensions(scene, jnp.asarray(sol.nodes), values))
        active, report = constraint_report(constraints, design, values, tensions, scene.fabric,
                                           problem.tension_scale)
    return DesignResult(
        pressure=values["pressure"],
        prestrain=(values["prestrain_span"], values["prestrain_chord"]),
        rib_thickness_scale=values["rib_thickness_scale"],
        rib_chord_scale=values["rib_chord_scale"],
        values=values,
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
        constraint_values=report,
        method=method,
        objective=objective,
        solves=problem.equilibrium.solves,
        wall_time=time.perf_counter() - start,
    )


def _failed_solve_message(failure: ConvergenceError) -> str:
    sol = failure.solution
    return (f"stopped: the forward solve at pressure {sol.pressure:.6g} Pa, prestrain "
            f"({sol.prestrain[0]:.6g}, {sol.prestrain[1]:.6g}) failed ({sol.message}); the "
            "result is the best iterate whose solve converged; narrow the bounds to where the "
            "skin has an equilibrium")


# ------------------------------------------------------------------ methods
def _least_squares(problem: _Problem, u0, max_iterations, tolerance):
    cache = {}

    def evaluate(u):
        key = tuple(np.asarray(u, dtype=np.float64))
        if key not in cache:
            r, jac = problem.value_and_jacobian(np.asarray(u, dtype=np.float64))
            cache.clear()
            cache[key] = (r, jac)
            problem.record(u, np.sum(r**2), np.linalg.norm(2.0 * jac.T @ r))
        return cache[key]

    result = scipy.optimize.least_squares(
        lambda u: evaluate(u)[0], u0, jac=lambda u: evaluate(u)[1],
        bounds=(problem.variables.lower, problem.variables.upper), method="trf",
        ftol=tolerance, xtol=tolerance, gtol=None, max_nfev=max_iterations, x_scale=1.0)
    return result.x, result.status > 0, result.message


def _optax(problem: _Problem, u0, max_iterations, tolerance, optimiser):
    import optax

    optimiser = optax.adam(0.02) if optimiser is None else optimiser

    def loss(u):
        r = problem.residuals(u)
        return jnp.sum(r * r)

    lower, upper = problem.variables.lower, problem.variables.upper
    u = jnp.asarray(u0, jnp.float64)
    state = optimiser.init(u)
    message = f"the iteration cap ({max_iterations} steps) was hit"
    success = False
    for _ in range(max_iterations):
        value, grad = jax.value_and_grad(loss)(u)
        grad_np = np.asarray(grad)
        # The projected gradient: components pushing into an active bound do not count.
        at_lower = (np.asarray(u) <= lower) & (grad_np > 0)
        at_upper = (np.asarray(u) >= upper) & (grad_np < 0)
        projected = np.where(at_lower | at_upper, 0.0, grad_np)
        problem.record(np.asarray(u), value, np.linalg.norm(projected))
        if np.linalg.norm(projected) <= tolerance:
            message, success = "the projected gradient norm fell below the tolerance", True
            break
        updates, state = optimiser.update(grad, state, u)
        u = jnp.clip(optax.apply_updates(u, updates), lower, upper)
    return np.asarray(u), success, message


def _root(problem: _Problem, condition, max_iterations, tolerance):
    design, target, chord = problem.variables, problem.target, problem.chord
    if condition == "thickness":
        goal = float(target.max_thickness)

        def measure(nodes):
            from targets import Airfoil

            section = np.asarray(section_points(np.asarray(nodes), 0.5, chord))
            closed = np.concatenate([section, section[:1]], axis=0)
            return Airfoil(closed[:, 0], closed[:, 1], name="mid-bay").max_thickness - goal
    else:

        def measure(nodes):
            section = np.asarray(section_points(np.asarray(nodes), 0.5, chord))
            return float(np.mean(target.distance(section)))

    memo = {}  # brentq re-evaluates the bracket ends: keep one value per pressure

    def f(pressure_scaled):
        key = float(pressure_scaled)
        if key not in memo:
            u = np.array([key])
            sol = problem.equilibrium.solve(design.from_vector(u))
            memo[key] = measure(sol.nodes)
            problem.record(u, memo[key])
        return memo[key]

    lo, hi = design.lower[0], design.upper[0]
    u0 = design.to_vector(design.values)[0]
    bracket = _bracket(f, u0, lo, hi)
    if bracket is None:
        raise ValueError(
            f"no pressure in the bounds {design.bounds['pressure']} Pa makes the mid-bay "
            f"{'maximum thickness equal to the target' if condition == 'thickness' else 'mean offset zero'}"
            ": the condition keeps one sign over the whole range (with ribs equal to the target the "
            "bulge only adds thickness; make the ribs thinner or widen the bounds)"
        )
    a, b = bracket
    if a == b:  # the condition vanished exactly at a trial pressure
        return np.array([a]), True, "the condition vanished exactly while bracketing"
    u, info = scipy.optimize.brentq(f, a, b, xtol=1e-14, rtol=max(tolerance, 4 * np.finfo(float).eps),
                                    maxiter=max_iterations, full_output=True, disp=False)
    return np.array([u]), bool(info.converged), info.flag


def _bracket(f, u0, lo, hi):
    """A sign change of ``f`` in ``[lo, hi]`` by geometric steps from ``u0``, or None."""
    f0 = f(u0)
    if f0 == 0.0:
        return u0, u0
    points = [u0]
    up, down = u0, u0
    while up < hi or down > lo:
        if up < hi:
            up = min(up * BRACKET_FACTOR, hi)
            fu = f(up)
            if fu == 0.0:
                return up, up
            if np.sign(fu) != np.sign(f0):
                return max(x for x in points if x < up), up
            points.append(up)
        if down > lo:
            down = max(down / BRACKET_FACTOR, lo)
            fd = f(down)
            if fd == 0.0:
                return down, down
            if np.sign(fd) != np.sign(f0):
                return down, min(x for x in points if x > down)
            points.append(down)
    return None


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
