"""The Gauss-Newton trust-region SQP of a design (`GaussNewton`), with its block Jacobian (`blocks`) and
step QP (`step_qp`) beside it.

Each iterate is one wing solve with the Jacobian of the stacked row distances
and of every cell's tension rows by forward mode through the implicit
equilibrium (`problem.DesignProblem.linearised`: per bay one back-solve per
variable that moves it, with the solve's own LU factor, `blocks`); the step
solves a small QP of the linearised fit with the linearised tension and rib
limits as constraints, without a forward solve (`step_qp`). Its number of
solves barely grows with the number of variables. Not for the objective
"worst" (no sum of squares).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse

from forward_solver.solution import BaysConvergenceError

from ..constraints import FLOOR_MARGIN, VIOLATION_TOLERANCE
from .base import Method, check_tolerance
from .step_qp import reachable_rows, solve_working_set

__all__ = ["GaussNewton", "GN_TOLERANCE", "GN_PENALTY", "GN_QP_PENALTY", "GN_SLACK", "GN_RADIUS", "GN_MAX_RADIUS",
           "GN_DAMPING", "GN_RESOLUTION", "levenberg_damping", "merit_model", "trust_region_step"]

#: Default tolerance of `GaussNewton`: the model's predicted fall of the merit, relative to it (1e-3 of
#: the mean square is 5e-4 of the rms error, against the 1.3-3% that re-solving on 33x64 moves it). Measured
#: while the step QP stopped short of its minimum (`step_qp.QP_TOLERANCE`): near the optimum a step gained
#: 0.2-0.5% of the merit per wing solve on the 40-cell wing, and 1e-4 spent up to 8 more solves there for
#: 0.27% of the rms, and on the design matrix 197 solves against 165 for at most 0.11% of it.
GN_TOLERANCE = 1e-3

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


@dataclass(frozen=True)
class GaussNewton(Method):
    """Trust-region SQP with the Gauss-Newton Hessian on the stacked row distances (`run`).

    Args:
        tolerance: converged when the model predicts a fall of the merit of at most this fraction of
            it (`GN_TOLERANCE`).
    """

    tolerance: float = GN_TOLERANCE
    name = "gauss_newton"
    robust = True
    rib_limits = True

    def __post_init__(self):
        check_tolerance(self.tolerance)

    def check(self, objective: str, names: tuple, n_bays: int) -> None:
        if objective == "worst":
            raise ValueError("method='gauss_newton' fits the rows in the least-squares sense; the objective "
                             "'worst' is a smooth maximum over rows: use method='slsqp' for it, or objective "
                             "'average' or 'mid_bay'")

    def start(self, problem, u0):
        return problem.linearised(u0)[-1]

    def run(self, problem, u0, max_iterations: int) -> tuple:
        """Trust-region SQP with the Gauss-Newton Hessian on the stacked row distances (Sl-infinity QP).

        Each iterate is one wing solve with the Jacobian of the shape residuals
        ``r`` (`problem.DesignProblem.linearised`) and of the constraints ``g >=
        0`` (tension limits, rib limits) by forward mode through the implicit
        equilibrium: one back-solve per variable with the solve's own LU factor.
        The step ``d`` minimises the model::

            m(d) = |r + J d|^2 / f0 + GN_PENALTY * max(0, max_i -(g_i + G_i d))

        within the bounds and the trust box ``|d|_inf <= radius`` (a convex QP,
        solved without forward solves: `trust_region_step`), and is accepted when the merit
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
        squares) is refused (`check`).
        """
        tolerance = self.tolerance
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
        rows = None  # the limit rows that bound at the last step: the next QP's working set starts with them
        while True:
            lo = np.maximum(lower - u, -radius)
            hi = np.minimum(upper - u, radius)
            # Past the margin that wrinkle-free floors keep (`constraints.FLOOR_MARGIN`) but inside the merit's
            # slack, a skin the report finds wrinkled: there the QP's step, which aims at g >= 0, is taken at
            # a would-be stop whatever it costs the fit, and kept while it lowers the violation.
            may_restore = violation(g) > FLOOR_MARGIN and not restored and solves < max_iterations
            d, predicted, reachable, kept, rows = trust_region_step(r / np.sqrt(f0), jr / np.sqrt(f0), g, jg, lo, hi,
                                                                    penalty, GN_QP_PENALTY, restore=may_restore,
                                                                    rows=rows)
            entry = problem.history.at(u)
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



def levenberg_damping(jr) -> float:
    """`GN_DAMPING` relative to the largest diagonal entry of ``jr^T jr`` (dense or sparse ``jr``)."""
    squares = (np.asarray(jr.multiply(jr).sum(axis=0)).reshape(-1) if scipy.sparse.issparse(jr)
               else np.sum(jr * jr, axis=0))
    return GN_DAMPING * max(float(np.max(squares, initial=0.0)), 1e-300)


def merit_model(r, jr, g, jg, penalty):
    """The Gauss-Newton model ``m(d)`` of the merit (`GaussNewton.run`)."""

    def model(d):
        fit = r + jr @ d
        return float(fit @ fit) + penalty * max(0.0, -float(np.min(g + jg @ d, initial=0.0)) - GN_SLACK)

    return model


def trust_region_step(r, jr, g, jg, lo, hi, penalty, qp_penalty, restore=False, rows=None):
    """The step ``d`` in ``[lo, hi]`` minimising ``|r + jr d|^2 + qp_penalty * max(0, max -(g + jg d))``
    (the linearised limits all but hard), the fall of the model with ``penalty`` (the merit's)
    from ``d = 0``, how many limit rows a step in the box can reach (the QP's rows), how many
    of them the QP's working set kept, and those of the set that bind at the step (a boolean mask
    of the rows of ``g``: the next step's ``rows``). A step the model counts as a loss is zero,
    unless ``restore``.

    ``jr`` and ``jg`` are dense or ``scipy.sparse``. Rows that no step in the box can bring below zero
    cannot bind and are dropped (`step_qp.reachable_rows`); the QP with one slack for the largest
    violation is solved sparse by Clarabel on a working set of the rest (`step_qp.solve_working_set`:
    the rows at their limit, those of ``rows`` (a mask of ``g``'s rows: where the last step bound)
    and those a step breaks), without forward solves.
    """
    n = jr.shape[1]
    near = reachable_rows(g, jg, lo, hi)
    start = None if rows is None or np.size(rows) != np.size(g) else np.asarray(rows, bool)[near]
    g, jg = g[near], jg[near]
    model = merit_model(r, jr, g, jg, penalty)
    d, _, _, kept, binding = solve_working_set(r, jr, g, jg, lo, hi, levenberg_damping(jr), qp_penalty, start=start)
    used = np.zeros(near.size, bool)
    used[np.flatnonzero(near)[binding]] = True
    if d is None:
        return np.zeros(n), 0.0, int(g.size), kept, used
    predicted = model(np.zeros(n)) - model(d)
    if not predicted > 0.0 and not restore:
        return np.zeros(n), 0.0, int(g.size), kept, used
    return d, predicted, int(g.size), kept, used
