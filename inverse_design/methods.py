"""The optimisers behind `optimise_wing` and `optimise_pressure`: Gauss-Newton SQP, SLSQP, least squares, optax and brentq.

Each takes a `problem.DesignProblem` (of N >= 1 bays) and returns ``(u,
success, message)``: the scaled design vector it ends at, whether the method
reports convergence, and its message (the common checks of the result are
`optimise.optimise_wing`'s). ``root`` solves one bay's mid-bay condition.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import scipy.optimize
import scipy.sparse

from .constraints import FLOOR_MARGIN, VIOLATION_TOLERANCE
from .objectives import section_points
from .problem import DesignProblem, key_of
from .step_qp import reachable_rows, solve_working_set

__all__ = ["gauss_newton", "slsqp", "least_squares", "optax_descent", "root", "BRACKET_FACTOR", "OPTAX_GAIN",
           "OPTAX_LEARNING_RATE", "OPTAX_PATIENCE", "OPTAX_HALVINGS",
           "SLSQP_EVALUATIONS_PER_ITERATION", "SLSQP_SAME_POINT", "SLSQP_STALL_REPEATS",
           "GN_PENALTY", "GN_RADIUS", "GN_MAX_RADIUS", "GN_DAMPING"]

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


#: Gauss-Newton: weight of the largest constraint violation (beyond `GN_SLACK`) in the l-infinity merit
#: function, against the objective scaled to 1 at the start (above the constraints' multipliers, which
#: are of order one there: a tension limit moves by a tension scale when the objective moves by its own
#: size). Measured on the built-in 3-bay wing with per-rib shapes (17x64): at 100 the merit charged the
#: 2e-4 tension-scale overshoot of a step along the curved wrinkle limit more than the step gained, and
#: the run took 47 wing solves of shrinking steps; at 10, 6 solves to the same optimum (rms 2.855e-3).
GN_PENALTY = 10.0
#: ... and in the step's QP, where the linearised limits are all but hard.
GN_QP_PENALTY = 1e4
#: The merit function ignores a constraint violation up to this (tension limits: fraction of the tension
#: scale; a tenth of `constraints.VIOLATION_TOLERANCE`), while every step still aims at ``g >= 0``: the
#: smooth tension aggregate curves so sharply that a step along an active limit breaks it by 1e-7 to 1e-5,
#: which an exact penalty would charge more than the step gains (the Maratos effect: measured on 3 bays
#: at 5x32 with per-rib shapes, 114 wing solves of mostly rejected or tiny steps without this slack).
GN_SLACK = 0.1 * VIOLATION_TOLERANCE
#: Starting trust radius (scaled variables, max norm: the pressure in units of its start, prestrain
#: in percent, rib-shape coefficients in 0.01) ...
GN_RADIUS = 1.0
#: ... and its cap.
GN_MAX_RADIUS = 10.0
#: Levenberg-Marquardt damping of the subproblem, relative to the largest diagonal entry of J^T J:
#: it only keeps the model strictly convex where a variable barely moves the skin.
GN_DAMPING = 1e-8
#: A predicted fall below this fraction of the starting merit (1 in the scaled merit) is below what
#: the merit's float64 sum of squares resolves: converged, whatever ``tolerance`` asks of a merit
#: that has itself fallen to rounding (a target the design reaches exactly).
GN_RESOLUTION = 1e-15


def gauss_newton(problem: DesignProblem, u0, max_iterations, tolerance):
    """Trust-region SQP with the Gauss-Newton Hessian on the stacked row distances (Sl-infinity QP).

    Each iterate is one wing solve with the Jacobian of the shape residuals
    ``r`` (`problem.DesignProblem.linearised`) and of the constraints ``g >=
    0`` (tension limits, rib limits) by forward mode through the implicit
    equilibrium: one back-solve per variable with the solve's own LU factor.
    The step ``d`` minimises the model::

        m(d) = |r + J d|^2 / f0 + GN_PENALTY * max(0, max_i -(g_i + G_i d))

    within the bounds and the trust box ``|d|_inf <= radius`` (a convex QP,
    solved without forward solves: `_step`), and is accepted when the merit
    ``phi(u) = |r(u)|^2 / f0 + GN_PENALTY * max(0, -min g(u))`` falls by more
    than 1e-4 of the model's predicted fall; the radius shrinks to a quarter of the step after a poor
    ratio (< 0.25) or a failed solve and doubles after a good one (> 0.75)
    at the trust-box edge. At an infeasible iterate whose QP step the merit
    counts as a loss (a limit whose multiplier exceeds the penalty), the
    penalty grows tenfold, up to ``GN_QP_PENALTY``, without a solve.
    Converged when the model predicts a fall of at
    most ``tolerance`` times the merit (or below `GN_RESOLUTION`); where a row then lies further
    below its limit than `constraints.FLOOR_MARGIN` (inside the merit's slack, but a wrinkle the
    report counts), restoring steps first: the QP's step, kept while it lowers the violation.
    Because ``J^T J`` is the exact Hessian of the fit up to the residuals' curvature, the number of solves
    hardly grows with the number of variables (SLSQP learns its Hessian one
    iterate at a time). The objective "worst" (a smooth maximum, no sum of
    squares) is refused by `optimise.optimise_wing`.
    """
    from forward_solver.solution import BaysConvergenceError

    design = problem.variables
    lower, upper = design.lower, design.upper
    u = np.clip(np.asarray(u0, np.float64), lower, upper)
    r, jr, g, jg, _ = problem.linearised(u)
    f0 = max(float(r @ r), np.finfo(float).tiny)

    def violation(g):
        return max(0.0, -float(np.min(g, initial=0.0)))

    penalty = GN_PENALTY

    def merit(r, g):
        return float(r @ r) / f0 + penalty * max(0.0, violation(g) - GN_SLACK)

    phi = merit(r, g)
    radius = GN_RADIUS
    solves = 1
    restored = False  # whether a restoring step (below) failed to lower the violation since the last accepted step
    while True:
        lo = np.maximum(lower - u, -radius)
        hi = np.minimum(upper - u, radius)
        # Past the margin that wrinkle-free floors keep (`constraints.FLOOR_MARGIN`) but inside the merit's
        # slack, a skin the report finds wrinkled: there the QP's step, which aims at g >= 0, is taken at
        # a would-be stop whatever it costs the fit, and kept while it lowers the violation.
        may_restore = violation(g) > FLOOR_MARGIN and not restored and solves < max_iterations
        d, predicted, reachable, kept = _step(r / np.sqrt(f0), jr / np.sqrt(f0), g, jg, lo, hi, penalty,
                                              GN_QP_PENALTY, restore=may_restore)
        entry = problem.entry_at(u)
        if entry is not None:  # the limit rows the step's QP kept and could reach (of g.size), in the history
            entry["qp_rows"] = max(int(kept), int(entry.get("qp_rows", 0)))
            entry["qp_reachable_rows"] = max(int(reachable), int(entry.get("qp_reachable_rows", 0)))
        if (predicted <= max(tolerance * phi, GN_RESOLUTION) and violation(g) > GN_SLACK
                and penalty < GN_QP_PENALTY):
            # An infeasible iterate whose QP step (which all but enforces the linearised limits) the merit
            # counts as a loss: the limit's multiplier exceeds the penalty (measured: 24 on the built-in
            # wing's robust design, where the 5th-percentile tension row costs the fit that much).
            # The penalty grows tenfold, without a solve, until the step pays or it reaches the QP's.
            penalty = min(10.0 * penalty, GN_QP_PENALTY)
            phi = merit(r, g)
            continue
        at_stop = predicted <= max(tolerance * phi, GN_RESOLUTION)  # (a restoring step, if may_restore)
        if at_stop and not may_restore:
            return u, True, (f"converged: the Gauss-Newton model predicts a fall of {predicted:.2e} of the "
                             f"merit {phi:.4g} (tolerance {tolerance:g} of it) after {solves} wing solves")
        if solves >= max_iterations:
            return (u, False, f"stopped after {solves} wing solves (max_iterations={max_iterations}) "
                    f"without converging; the model still predicts a fall of {predicted:.2e} of the merit "
                    f"{phi:.4g}")
        trial = np.clip(u + d, lower, upper)
        solves += 1
        try:
            r1, jr1, g1, jg1, _ = problem.linearised(trial)
        except BaysConvergenceError:
            r1 = None
        if at_stop:
            restored = r1 is None or not violation(g1) < violation(g)
            if not restored:
                u, r, jr, g, jg = trial, r1, jr1, g1, jg1
                phi = merit(r, g)
            continue
        ratio = -np.inf if r1 is None else (phi - merit(r1, g1)) / predicted
        step = float(np.max(np.abs(d)))
        if ratio < 0.25:
            radius = 0.25 * step
        elif ratio > 0.75 and step >= 0.99 * radius:
            radius = min(2.0 * radius, GN_MAX_RADIUS)
        if ratio > 1e-4:
            u, r, jr, g, jg, restored = trial, r1, jr1, g1, jg1, False
            if problem.reweight(u):  # the robust objective's majoriser, tight again at the new iterate
                r, jr, g, jg, _ = problem.linearised(u)
            phi = merit(r, g)
        elif radius < 1e-9:
            return (u, False, f"the trust radius fell below 1e-9 after {solves} wing solves: no step "
                    "lowers the merit (objective and constraint violation)")


def _damping(jr) -> float:
    """`GN_DAMPING` relative to the largest diagonal entry of ``jr^T jr`` (dense or sparse ``jr``)."""
    squares = (np.asarray(jr.multiply(jr).sum(axis=0)).reshape(-1) if scipy.sparse.issparse(jr)
               else np.sum(jr * jr, axis=0))
    return GN_DAMPING * max(float(np.max(squares, initial=0.0)), 1e-300)


def _model(r, jr, g, jg, penalty):
    """The Gauss-Newton model ``m(d)`` of the merit (`gauss_newton`)."""

    def model(d):
        fit = r + jr @ d
        return float(fit @ fit) + penalty * max(0.0, -float(np.min(g + jg @ d, initial=0.0)) - GN_SLACK)

    return model


def _step(r, jr, g, jg, lo, hi, penalty, qp_penalty, restore=False):
    """The step ``d`` in ``[lo, hi]`` minimising ``|r + jr d|^2 + qp_penalty * max(0, max -(g + jg d))``
    (the linearised limits all but hard), the fall of the model with ``penalty`` (the merit's)
    from ``d = 0``, how many limit rows a step in the box can reach (the QP's rows) and how many
    of them the QP's working set kept. A step the model counts as a loss is zero, unless ``restore``.

    ``jr`` and ``jg`` are dense or ``scipy.sparse``. Rows that no step in the box can bring below zero
    cannot bind and are dropped (`step_qp.reachable_rows`); the QP with one slack for the largest
    violation is solved sparse by Clarabel on a working set of the rest (`step_qp.solve_working_set`:
    the rows at their limit and those a step breaks), without forward solves.
    """
    n = jr.shape[1]
    near = reachable_rows(g, jg, lo, hi)
    g, jg = g[near], jg[near]
    model = _model(r, jr, g, jg, penalty)
    d, _, _, kept = solve_working_set(r, jr, g, jg, lo, hi, _damping(jr), qp_penalty)
    if d is None:
        return np.zeros(n), 0.0, int(g.size), kept
    predicted = model(np.zeros(n)) - model(d)
    if not predicted > 0.0 and not restore:
        return np.zeros(n), 0.0, int(g.size), kept
    return d, predicted, int(g.size), kept


def _dense_step(r, jr, g, jg, lo, hi, penalty, qp_penalty):
    """`_step` by SLSQP on the dense QP (the former path, kept as the reference the tests and
    ``benchmarks/wing_cells.py`` measure the sparse QP against).

    The fit is rewritten by a QR factorisation of ``[jr; sqrt(damping) I]`` as ``|c + R d|^2``; in
    ``z = R d`` its Hessian is the identity, SLSQP's own starting Hessian, with one slack ``s >= 0``
    for the largest violation.
    """
    jr = jr.toarray() if scipy.sparse.issparse(jr) else np.asarray(jr)
    jg = jg.toarray() if scipy.sparse.issparse(jg) else np.asarray(jg)
    n = jr.shape[1]
    near = reachable_rows(g, jg, lo, hi)
    g, jg = g[near], jg[near]
    damping = _damping(jr)
    q, rr = np.linalg.qr(np.vstack([jr, np.sqrt(damping) * np.eye(n)]))
    c = q.T @ np.concatenate([r, np.zeros(n)])
    inverse = np.linalg.inv(rr)  # upper triangular, n x n: d = inverse @ z
    model = _model(r, jr, g, jg, penalty)
    # x = (z, s): 0.5 |c + z|^2 + 0.5 penalty s
    cons = [{"type": "ineq", "fun": lambda x: inverse @ x[:n] - lo, "jac": lambda x: np.hstack([inverse, np.zeros((n, 1))])},
            {"type": "ineq", "fun": lambda x: hi - inverse @ x[:n], "jac": lambda x: np.hstack([-inverse, np.zeros((n, 1))])}]
    if g.size:
        gi = jg @ inverse
        cons.append({"type": "ineq", "fun": lambda x: g + gi @ x[:n] + x[n],
                     "jac": lambda x: np.hstack([gi, np.ones((g.size, 1))])})
    s0 = max(0.0, -float(np.min(g, initial=0.0)))
    x0 = np.concatenate([np.zeros(n), [s0]])
    result = scipy.optimize.minimize(
        lambda x: 0.5 * float((c + x[:n]) @ (c + x[:n])) + 0.5 * qp_penalty * x[n], x0,
        jac=lambda x: np.concatenate([c + x[:n], [0.5 * qp_penalty]]), method="SLSQP",
        bounds=[(None, None)] * n + [(0.0, None)], constraints=cons,
        options={"maxiter": 500, "ftol": 1e-14})
    d = np.clip(inverse @ result.x[:n], lo, hi)
    predicted = model(np.zeros(n)) - model(d)
    if not predicted > 0.0:
        return np.zeros(n), 0.0, int(g.size)
    return d, predicted, int(g.size)


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
