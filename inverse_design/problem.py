"""`DesignProblem`: the objective, the constraints and their derivatives for one design.

Every forward solve warm-starts from the previous iterate's equilibrium
(chord Newton with its LU factor) and is solved to the optimiser's ``rtol``
by the ``"auto"`` chain of `forward_solver.solve_equilibrium` (a failed warm
solve is retried cold, then by Newton; `forward_solver.fallback`) unless
``solver_options`` name one method. The objective (`objectives.objective_value`)
and the smooth tension constraints (`constraints.constraint_functions`) get
their gradients by reverse mode through `forward_solver.solve_equilibrium`
(one adjoint solve each); the penalty residuals their Jacobian by forward
mode. Every converged solve is archived, so the result is never re-solved.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from forward_solver import ConvergenceError, Parameters, Solution, solve_equilibrium

from .constraints import cell_tensions, constraint_functions, penalty_residuals, tension_scale
from .objectives import objective_residuals, objective_value
from .variables import DesignVariables

__all__ = ["DesignProblem", "with_rib_rows", "check_solver_options"]

#: The forward solves' options when none are given.
DEFAULT_SOLVER_OPTIONS = {"method": "auto", "max_steps": 200_000}


class DesignProblem:
    """The objective, the constraints, their derivatives and the iterate history of one design."""

    def __init__(self, scene, target, variables: DesignVariables, objective, constraints, rtol,
                 rib_geometry=None, solver_options=None):
        self.scene = scene
        self.target = target
        self.variables = variables
        self.objective = objective
        self.constraints = constraints
        self.rtol = rtol
        self.chord = scene.bay.chord
        # Small design grids: one relaxation loop to compile beats grid sequencing.
        self.sequencing = scene.bay.n_contour > 128
        # {"method": ..., "max_steps": ...} of every forward solve (`check_solver_options`).
        self.solver_options = check_solver_options(solver_options)
        self.previous: Solution | None = None  # warm start (and its LU factor)
        self.solves = 0
        self.history: list[dict] = []
        self.on_record = None  # called with each new history entry (progress bar, callback)
        self.tension_scale = tension_scale(variables.start, self.chord)
        self._cache: dict = {}  # the last evaluation with its derivatives
        self._solved: dict = {}  # every converged solve by `_key`, without its LU factor
        # The rib's manufacturability limits (`rib_design.RibGeometry`): no solve in them, so their
        # Jacobian comes from forward mode on the design vector alone.
        self.rib_geometry = rib_geometry
        if rib_geometry is not None:
            def rib_rows(u):
                return rib_geometry.functions(variables.parameters(u))

            self._rib_rows = jax.jit(lambda u: (rib_rows(u), jax.jacfwd(rib_rows)(u)))

    # ------------------------------------------------------------ solves
    def _solve(self, parameters: Parameters) -> Solution:
        options = dict(rtol=self.rtol, sequencing=self.sequencing, **self.solver_options)
        if options["method"] == "auto":  # the chain retries cold itself, then falls back to Newton
            try:
                sol = solve_equilibrium(self.scene, parameters, initial=self.previous, **options)
            except ConvergenceError as failure:
                self.solves += len(failure.solution.extra.get("attempts", [None]))
                raise
            self.solves += len(sol.extra.get("attempts", [None]))
            return sol
        self.solves += 1
        try:
            return solve_equilibrium(self.scene, parameters, initial=self.previous, **options)
        except ConvergenceError:
            if self.previous is None:
                raise
        # A warm start far from this iterate (a long trial step) may fail where a cold start
        # converges: only a cold failure means the skin has no equilibrium here.
        self.solves += 1
        return solve_equilibrium(self.scene, parameters, initial=None, **options)

    def _remember(self, sol: Solution) -> Solution:
        """Keep ``sol`` as the next warm start (as numpy arrays: the auxiliary output of a
        JAX transformation comes back as JAX arrays) and in the archive of solves."""
        self.previous = jax.tree_util.tree_map(np.asarray, sol)
        key = key_of(self.variables.to_vector(sol.parameters))
        self._solved[key] = dataclasses.replace(self.previous, factor=None)
        return self.previous

    def solve(self, u) -> Solution:
        """The concrete `Solution` at the scaled vector ``u`` (from the archive if solved before)."""
        key = key_of(self.variables.to_vector(self.variables.parameters(np.asarray(u, np.float64))))
        if key in self._solved:
            return self._solved[key]
        return self._remember(self._solve(self.variables.parameters(np.asarray(u, np.float64))))

    def _solve_with_tensions(self, u):
        """The solution at ``u`` (a JAX value allowed) and its unclamped cell tensions (None
        without tension constraints)."""
        parameters = self.variables.parameters(u)
        sol = self._solve(parameters)
        tensions = cell_tensions(self.scene, sol.nodes, parameters) if self.constraints else None
        return sol, tensions

    def cached(self, key):
        """The cached evaluation at ``key`` (`_key` of a vector), or None."""
        return self._cache.get(key)

    def best_iterate(self) -> np.ndarray | None:
        """Scaled vector of the best recorded iterate (None before any): the feasible one (every
        smooth constraint >= 0) with the least objective in size, else the least violating one."""

        def violation(entry):
            return max([0.0] + [-c for c in entry.get("constraints", [])])

        if not self.history:
            return None
        best = min(self.history, key=lambda h: (violation(h), abs(h["objective"])))
        return self.variables.from_values(best["values"])

    # ----------------------------------------------- smooth constraints (slsqp)
    def evaluate(self, u):
        """``(f, grad f, g, dg/du, solution)`` at ``u``: mean square error (chord^2) and
        the smooth constraints ``g >= 0`` (tension limits, gradients by reverse mode, one adjoint
        solve each; then the rib limits' rows, if any)."""
        key = key_of(u)
        if key not in self._cache:

            def outputs(v):
                sol, tensions = self._solve_with_tensions(v)
                f = objective_value(sol.nodes, self.target, self.chord, self.objective)
                if tensions is None:
                    return f[None], sol
                g = constraint_functions(self.constraints, tensions, self.scene.fabric, self.tension_scale)
                return jnp.concatenate([f[None], g]), sol

            y, pullback, sol = jax.vjp(outputs, jnp.asarray(u, jnp.float64), has_aux=True)
            rows = np.stack([np.asarray(pullback(e)[0]) for e in jnp.eye(y.size, dtype=y.dtype)])
            y = np.asarray(y)
            recorded = y[1:]
            if self.rib_geometry is not None:
                y, rows, g_rib = with_rib_rows(y, rows, self._rib_rows, u)
                n_thick = self.rib_geometry.upper.size  # history: the least row of each rib limit
                recorded = np.concatenate([recorded, [g_rib[:n_thick].min(), g_rib[n_thick:].min()]])
            self._cache = {key: (y[0], rows[0], y[1:], rows[1:], self._remember(sol))}
            self.record(u, y[0], np.linalg.norm(rows[0]), solution=sol, constraints=recorded)
        return self._cache[key]

    # ------------------------------------------------------ penalty methods
    def residuals(self, u):
        """Shape residuals and penalties at ``u`` (a JAX value allowed), and the solution."""
        sol, tensions = self._solve_with_tensions(u)
        shape = objective_residuals(sol.nodes, self.target, self.chord, self.objective)
        if tensions is None:
            return shape, sol
        penalties = penalty_residuals(self.constraints, tensions, self.scene.fabric, self.tension_scale)
        return jnp.concatenate([shape, penalties]), sol

    def residuals_and_jacobian(self, u):
        """Residuals and their Jacobian in ``u`` (forward mode, one tangent solve per variable)."""
        key = key_of(u)
        if key not in self._cache:

            def residuals_twice(v):  # the value comes back as the auxiliary output
                r, sol = self.residuals(v)
                return r, (r, sol)

            u = jnp.asarray(u, jnp.float64)
            jac, (r, sol) = jax.jacfwd(residuals_twice, has_aux=True)(u)
            r, jac = np.asarray(r), np.asarray(jac)
            self._cache = {key: (r, jac, self._remember(sol))}
            self.record(u, np.sum(r**2), np.linalg.norm(2.0 * jac.T @ r), solution=sol)
        return self._cache[key]

    def record(self, u, objective, gradient_norm=math.nan, *, solution: Solution,
               constraints=None):
        entry = {
            "values": self.variables.values(np.asarray(u, dtype=np.float64)),
            "objective": float(objective),
            "gradient_norm": float(gradient_norm),
            "steps": int(solution.steps),
        }
        if constraints is not None:
            entry["constraints"] = [float(c) for c in constraints]
        self.history.append(entry)
        if self.on_record is not None:
            self.on_record(entry)


def with_rib_rows(y, rows, rib_rows, u):
    """``(y, rows, g_rib)``: the outputs and their gradient rows with the rib limits' rows appended.

    ``rib_rows(u)`` returns the rib-limit values and their Jacobian (no solve in them).
    """
    g_rib, jac_rib = (np.asarray(a) for a in rib_rows(jnp.asarray(u, jnp.float64)))
    return np.concatenate([y, g_rib]), np.vstack([rows, jac_rib]), g_rib


def check_solver_options(options) -> dict:
    """``{"method", "max_steps"}`` of the design's forward solves, checked, over the defaults.

    ``method`` is one of `forward_solver.fallback.EQUILIBRIUM_METHODS` ("auto":
    the fallback chain), ``max_steps`` the step cap of each relaxation.
    """
    from forward_solver.fallback import EQUILIBRIUM_METHODS

    if options is None:
        return dict(DEFAULT_SOLVER_OPTIONS)
    if not isinstance(options, dict):
        raise ValueError(f"solver_options must be a dict with keys method, max_steps, got {options!r}")
    unknown = set(options) - set(DEFAULT_SOLVER_OPTIONS)
    if unknown:
        raise ValueError(f"solver_options: unknown key(s) {sorted(unknown)}; the keys are method, max_steps")
    merged = {**DEFAULT_SOLVER_OPTIONS, **options}
    if merged["method"] not in EQUILIBRIUM_METHODS:
        raise ValueError(f"solver_options: method must be one of {EQUILIBRIUM_METHODS}, got {merged['method']!r}")
    steps = merged["max_steps"]
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise ValueError(f"solver_options: max_steps must be a positive integer, got {steps!r}")
    return merged


def key_of(u) -> tuple:
    """A hashable key of a scaled vector (its float values)."""
    return tuple(float(x) for x in np.asarray(u, dtype=np.float64).reshape(-1))
