"""The scipy methods of a design: `SLSQP`, `LeastSquares` and `Root` (brentq on one bay's pressure).

Each is a small frozen value with its own knobs that runs on a
`problem.DesignProblem` (`base.Method`); `optimise.optimise_wing` calls
``method.run(problem, u0, max_iterations)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize

from targets import Airfoil

from ..constraints import VIOLATION_TOLERANCE
from ..objectives import section_points
from ..variables import key_of
from .base import Method, check_tolerance

__all__ = ["SLSQP", "LeastSquares", "Root", "ROOT_CONDITIONS", "BRACKET_FACTOR", "SLSQP_EVALUATIONS_PER_ITERATION",
           "SLSQP_SAME_POINT", "SLSQP_STALL_REPEATS"]

#: The scalar conditions of `Root` at the mid-bay section.
ROOT_CONDITIONS = ("thickness", "mean_offset")
#: Geometric step of the automatic bracketing of `Root`.
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


@dataclass(frozen=True)
class SLSQP(Method):
    """`scipy.optimize.minimize` with SLSQP on the mean square distance (`objectives.mean_square`: for
    "worst" a smooth maximum over the rows), with the bounds, the tension limits
    (`constraints.constraint_functions`) and the rib limits as inequality constraints (`run`). The
    gradients come from reverse mode through the implicit equilibrium: one forward solve and one
    adjoint solve per function per iterate, whatever the number of variables.

    Args:
        tolerance: ``ftol`` on the objective relative to its starting value (1e-6: one part in a
            million of the mean square error, far below what the grid resolves).
    """

    tolerance: float = 1e-6
    name = "slsqp"
    rib_limits = True

    def __post_init__(self):
        check_tolerance(self.tolerance)

    def start(self, problem, u0):
        return problem.evaluate(u0)[-1]  # the first iterate's solve, with its gradients

    def evaluations(self, max_iterations: int) -> int:
        return SLSQP_EVALUATIONS_PER_ITERATION * max_iterations

    def run(self, problem, u0, max_iterations: int) -> tuple:
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
        tolerance = self.tolerance
        cap = self.evaluations(max_iterations)
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
            return (problem.history.best(), False,
                    f"stopped after {cap} evaluations ({cap} forward solves, the cap for max_iterations="
                    f"{max_iterations}) without converging; the result is the best iterate")
        except _Stalled as stall:
            values = ", ".join(f"{n} {np.round(v, 6).tolist() if isinstance(v, list) else format(v, '.6g')}"
                               for n, v in design.values(stall.args[0]).items())
            return (problem.history.best(), False,
                    f"SLSQP's line search kept returning to one point ({values}) after {len(visited)} "
                    "evaluations: no step improves the objective while meeting the constraints there "
                    "(typically no design within the bounds meets the limits); the result is the best "
                    "iterate")
        return result.x, bool(result.success), str(result.message)


@dataclass(frozen=True)
class LeastSquares(Method):
    """`scipy.optimize.least_squares` (trust-region reflective, with the bounds) on the vector of section
    distances (each bay's scaled by the square root of its weight) plus exterior tension penalties, its
    Jacobian by forward mode.

    Args:
        tolerance: its ``ftol`` and ``xtol`` (1e-8).
    """

    tolerance: float = 1e-8
    name = "least_squares"

    def __post_init__(self):
        check_tolerance(self.tolerance)

    def start(self, problem, u0):
        return problem.residuals_and_jacobian(u0)[-1]

    def run(self, problem, u0, max_iterations: int) -> tuple:
        result = scipy.optimize.least_squares(
            lambda u: problem.residuals_and_jacobian(u)[0], u0,
            jac=lambda u: problem.residuals_and_jacobian(u)[1],
            bounds=(problem.variables.lower, problem.variables.upper), method="trf",
            ftol=self.tolerance, xtol=self.tolerance, gtol=None, max_nfev=max_iterations, x_scale=1.0)
        return result.x, result.status > 0, result.message


@dataclass(frozen=True)
class Root(Method):
    """`scipy.optimize.brentq` on the pressure of one bay alone, for a scalar condition at its mid-bay
    section. The bracket is found by stepping the pressure geometrically (`BRACKET_FACTOR`) from its
    start towards both bounds; when the condition does not change sign inside the bounds a ValueError
    says so. A wing of several bays has no one mid-bay section: refused.

    Args:
        condition: "thickness" (the section's maximum thickness equal to the target's) or
            "mean_offset" (zero mean normal distance); `ROOT_CONDITIONS`.
        tolerance: brentq's relative pressure tolerance (1e-8).
    """

    condition: str = "thickness"
    tolerance: float = 1e-8
    name = "root"

    def __post_init__(self):
        if self.condition not in ROOT_CONDITIONS:
            raise ValueError(f"the root condition must be one of {ROOT_CONDITIONS}, got {self.condition!r}")
        check_tolerance(self.tolerance)

    def check(self, objective: str, names: tuple, n_bays: int) -> None:
        if n_bays > 1:
            raise ValueError(f"method='root' solves one scalar condition at one bay's mid-bay section; this "
                             f"wing has {n_bays} bays: use slsqp, gauss_newton, least_squares or optax")
        if names != ("pressure",):
            raise ValueError(f"method='root' solves for the pressure alone; got variables {names}")

    def shown(self, value: float) -> str:
        return f"condition={value:.3e}"

    def run(self, problem, u0, max_iterations: int) -> tuple:
        design, target, chord = problem.variables, problem.targets.targets[0], problem.chord
        condition, tolerance = self.condition, self.tolerance
        if condition == "thickness":
            goal = float(target.max_thickness)

            def measure(nodes):
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
                problem.history.record(u, memo[key], solution=sol)
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
