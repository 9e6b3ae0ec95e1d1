"""The optimisers behind `optimise_wing` and `optimise_pressure`: SLSQP, least squares, optax and brentq.

Each takes a `problem.DesignProblem` (of N >= 1 bays) and returns ``(u,
success, message)``: the scaled design vector it ends at, whether the method
reports convergence, and its message (the common checks of the result are
`optimise.optimise_wing`'s). ``root`` solves one bay's mid-bay condition.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import scipy.optimize

from .constraints import VIOLATION_TOLERANCE
from .objectives import section_points
from .problem import DesignProblem, key_of

__all__ = ["slsqp", "least_squares", "optax_descent", "root", "BRACKET_FACTOR", "OPTAX_GAIN",
           "OPTAX_LEARNING_RATE", "OPTAX_PATIENCE", "OPTAX_HALVINGS",
           "SLSQP_EVALUATIONS_PER_ITERATION", "SLSQP_SAME_POINT", "SLSQP_STALL_REPEATS"]

#: Geometric step of the automatic bracketing of ``method="root"``.
BRACKET_FACTOR = 2.0
#: Forward solves SLSQP may spend per allowed iteration (its line searches included).
SLSQP_EVALUATIONS_PER_ITERATION = 2
#: Two SLSQP trial points closer than this (scaled variables, max norm) are one point ...
SLSQP_SAME_POINT = 1e-9
#: ... and this many returns to an evaluated point end the run as stalled.
SLSQP_STALL_REPEATS = 3


class _EvaluationCap(Exception):
    """Raised inside SLSQP's callbacks when the forward-solve budget is spent."""


class _Stalled(Exception):
    """Raised inside SLSQP's callbacks when its line search keeps returning to one point."""


def slsqp(problem: DesignProblem, u0, max_iterations, tolerance):
    """SLSQP on the objective scaled to 1 at the start, with the smooth tension constraints.

    SLSQP caps its iterations but not its line-search evaluations, which an
    infeasible problem can spend by the hundred; each costs a forward solve,
    so they are capped too (`SLSQP_EVALUATIONS_PER_ITERATION` per allowed
    iteration), and on an infeasible problem its line search returns again
    and again to one point (differing in the last bits), which ends the run
    after `SLSQP_STALL_REPEATS` such returns to an infeasible point. Stopped either way, the result
    is the best iterate: the feasible one with the least error, else the
    least violating one.
    """
    cap = SLSQP_EVALUATIONS_PER_ITERATION * max_iterations
    f0 = max(problem.evaluate(u0)[0], np.finfo(float).tiny)
    visited = [np.asarray(u0, dtype=np.float64)]
    repeats = 0

    def evaluate(u):
        nonlocal repeats
        u = np.asarray(u, dtype=np.float64)
        if problem.cached(key_of(u)) is None:
            if len(visited) >= cap:
                raise _EvaluationCap()
            if min(np.max(np.abs(u - v)) for v in visited) <= SLSQP_SAME_POINT:
                repeats += 1
            visited.append(u)
        result = problem.evaluate(u)
        if repeats >= SLSQP_STALL_REPEATS and np.min(result[2], initial=0.0) < -VIOLATION_TOLERANCE:
            raise _Stalled(u)  # only where infeasible: a feasible point may be a slow optimum
        return result

    constraints = []
    if problem.evaluate(u0)[2].size:
        constraints.append({"type": "ineq", "fun": lambda u: evaluate(u)[2], "jac": lambda u: evaluate(u)[3]})
    design = problem.variables
    try:
        result = scipy.optimize.minimize(
            lambda u: evaluate(u)[0] / f0, u0, jac=lambda u: evaluate(u)[1] / f0,
            method="SLSQP", bounds=scipy.optimize.Bounds(design.lower, design.upper),
            constraints=constraints, options={"maxiter": max_iterations, "ftol": tolerance})
    except _EvaluationCap:
        return (problem.best_iterate(), False,
                f"stopped after {cap} evaluations ({cap} forward solves, the cap for max_iterations="
                f"{max_iterations}) without converging; the result is the best iterate")
    except _Stalled as stall:
        values = ", ".join(f"{n} {np.round(v, 6).tolist() if isinstance(v, list) else format(v, '.6g')}"
                           for n, v in design.values(stall.args[0]).items())
        return (problem.best_iterate(), False,
                f"SLSQP's line search kept returning to one point ({values}) after {len(visited)} "
                "evaluations: no step improves the objective while meeting the constraints there "
                "(typically no design within the bounds meets the limits); the result is the best "
                "iterate")
    return result.x, bool(result.success), str(result.message)


def least_squares(problem: DesignProblem, u0, max_iterations, tolerance):
    result = scipy.optimize.least_squares(
        lambda u: problem.residuals_and_jacobian(u)[0], u0,
        jac=lambda u: problem.residuals_and_jacobian(u)[1],
        bounds=(problem.variables.lower, problem.variables.upper), method="trf",
        ftol=tolerance, xtol=tolerance, gtol=None, max_nfev=max_iterations, x_scale=1.0)
    return result.x, result.status > 0, result.message


#: optax: the default Adam's learning rate (scaled variables: 0.05 moves the pressure by about 5%
#: of its start per step).
OPTAX_LEARNING_RATE = 0.05
#: A step that does not lower the best loss by this fraction is no gain ...
OPTAX_GAIN = 1e-3
#: ... after this many such steps in a row the step size halves and the run restarts from the best
#: iterate ...
OPTAX_PATIENCE = 3
#: ... and once it has halved this many times the loss has levelled off: the run ends there.
OPTAX_HALVINGS = 6


def optax_descent(problem: DesignProblem, u0, max_iterations, tolerance, optimiser):
    """Gradient descent by an optax transformation (default Adam, `OPTAX_LEARNING_RATE`) on the penalty loss.

    The loss is scaled to 1 at the start, so ``tolerance`` bounds the
    projected gradient relative to the starting loss. A fixed-step method
    circles an optimum on a tension limit (the penalty's kink) instead of
    settling: measured on the default case (9x32), Adam at 0.02 hit its 50-step
    cap at rms 4.9e-3 chord, the loss going up and down by 40%, where SLSQP
    reached 3.7e-3 in 9 solves. So the step is halved (and the run restarted
    from the best iterate, with a fresh optimiser state) after
    `OPTAX_PATIENCE` steps without a gain of `OPTAX_GAIN` of the best loss,
    and after `OPTAX_HALVINGS` halvings the loss has levelled off: the run
    ends there, converged, at the best iterate.
    """
    import optax

    optimiser = optax.adam(OPTAX_LEARNING_RATE) if optimiser is None else optimiser

    lower, upper = problem.variables.lower, problem.variables.upper
    u = jnp.asarray(u0, jnp.float64)
    state = optimiser.init(u)
    message = f"the iteration cap ({max_iterations} steps) was hit before the loss levelled off"
    success = False
    f0 = None
    best_u, best, since, scale, halvings = u, np.inf, 0, 1.0, 0
    for _ in range(max_iterations):
        value, grad, sol = problem.loss_and_gradient(u)
        f0 = max(float(value), np.finfo(float).tiny) if f0 is None else f0
        grad_np = np.asarray(grad)
        # The projected gradient: components pushing into an active bound do not count.
        at_lower = (np.asarray(u) <= lower) & (grad_np > 0)
        at_upper = (np.asarray(u) >= upper) & (grad_np < 0)
        projected = np.where(at_lower | at_upper, 0.0, grad_np)
        problem.record(np.asarray(u), value, np.linalg.norm(projected), solution=sol)
        if float(value) < best:
            since = 0 if float(value) < best * (1.0 - OPTAX_GAIN) else since + 1
            best_u, best = u, float(value)
        else:
            since += 1
        if np.linalg.norm(projected) / f0 <= tolerance:
            message, success = "the projected gradient norm fell below the tolerance", True
            break
        if since >= OPTAX_PATIENCE:
            if halvings == OPTAX_HALVINGS:
                message, success = (f"the loss levelled off: no gain of {OPTAX_GAIN:.0e} of the best in "
                                    f"{OPTAX_PATIENCE} steps after {halvings} halvings of the step; the "
                                    "result is the best iterate"), True
                break
            scale, halvings, since = 0.5 * scale, halvings + 1, 0
            u, state = best_u, optimiser.init(best_u)
            continue
        updates, state = optimiser.update(grad / f0, state, u)
        u = jnp.clip(u + scale * (optax.apply_updates(u, updates) - u), lower, upper)
    return np.asarray(best_u if np.isfinite(best) else u), success, message


def root(problem: DesignProblem, condition, max_iterations, tolerance):
    design, target, chord = problem.variables, problem.targets[0], problem.chord
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
            sol = problem.solve(u)
            memo[key] = measure(sol.nodes[0])
            problem.record(u, memo[key], solution=sol)
        return memo[key]

    lo, hi = design.lower[0], design.upper[0]
    u0 = design.to_vector(design.start)[0]
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
