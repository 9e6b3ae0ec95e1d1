"""`DesignProblem`: the objective, the constraints and their derivatives for one design of N >= 1 bays.

The bays are `forward_solver.Scene`s sharing one fabric and grid (a single
bay, or the bays of a `forward_solver.Wing`), solved together by
`forward_solver.solve_bays` (on a CPU a loop of `solve_equilibrium`, chord
Newton with its LU factor). Every forward solve warm-starts from the previous
iterate's equilibrium and is solved to the settings' ``rtol`` by the
``"auto"`` chain of `forward_solver.solve_equilibrium` (a failed warm solve is
retried cold, then by Newton; `forward_solver.solvers.chain`) unless the
settings name one equilibrium method (then a failed warm solve is retried
cold here). The bays are measured against their targets by one
`objectives.WingTargets`: the objective (each bay's `objectives.mean_square`,
weighted by area) and the smooth tension constraints
(`constraints.constraint_functions` over every cell of every bay) get their
gradients by reverse mode through the N-bay forward solve (one adjoint solve
per output); the penalty residuals and the Gauss-Newton rows their Jacobian by
forward mode (`forward_solver.derivatives.forward.value_and_jacobian`). Every
converged solve is archived, so the result is never re-solved. A bay whose
cold solve fails raises `BaysConvergenceError`; its NaN nodes never reach
the optimiser.
"""

from __future__ import annotations

import dataclasses
import math
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse

from forward_solver import solve_bays
from forward_solver.programs import mounted_compiled
from forward_solver.derivatives.forward import value_and_jacobian
from forward_solver.solution import BaysConvergenceError, BaysSolution
from forward_solver.solvers.bays import default_strategy

from .constraints import cell_constraints, cell_tensions, constraint_functions, penalty_residuals, tension_scale
from .history import History
from .memory import release_free_memory
from .methods.blocks import compressed_seeds, decompress, rib_columns
from .objectives import WingTargets
from .settings import SolverSettings
from .stacked import displacements, each_bay, prepend
from .tolerance.robust import RobustTerms, check_robust_tolerances
from .variables import DesignVariables, check_field_terms, concrete_rows, key_of

__all__ = ["DesignProblem"]


#: The design variables that move the ribs, and with them every bay's mounted shape.
RIB_VARIABLES = ("rib_thickness_scale", "rib_chord_scale", "rib_shape")


def _aux(sol) -> dict:
    """The arrays of a solve that a transformation hands back as its auxiliary output."""
    return {"nodes": sol.nodes, "result": sol.result, "residual": sol.residual, "steps": sol.steps,
            "mounted": sol.mounted}


class DesignProblem:
    """The objective, the constraints, their derivatives and the iterate history of one design.

    Args:
        scenes: the bays, root to tip (one fabric, switches and grid).
        targets: the bays' rows against their targets and the objective (`objectives.WingTargets`).
        variables: the `DesignVariables`.
        tension: the tension limits (`constraints.Constraints`), or None.
        ribs: ``(rib, RibGeometry)`` pairs whose limits are constraint rows (`rib_design.RibGeometry`):
            one per rib for a shape per rib, else one per distinct starting section of a shared shape.
        solver: the forward solves' residual, equilibrium method and step cap (`settings.SolverSettings`).
        tolerances: the manufacturing tolerances of the objective "robust"
            (`tolerance.robust.check_robust_tolerances`: None for every default).

    Attributes:
        seeds: ``(seeds, columns)`` of the Gauss-Newton Jacobian's forward pass (`blocks.compressed_seeds`).
        robust: the robust objective's terms (`tolerance.robust.RobustTerms`), or None.
        history: the iterates (`history.History`).
        solves: forward solves so far.

    The constraint vector is the tension rows (`constraints.Constraints.names`,
    over all bays), then every rib geometry's `rib_design.RibGeometry.functions`
    rows.
    """

    def __init__(self, scenes, targets: WingTargets, variables: DesignVariables, *, tension=None, ribs=(),
                 solver: SolverSettings = SolverSettings(), tolerances=None):
        self.scenes = list(scenes)
        check_field_terms(variables, self.scenes[0].bay.n_contour)
        self.fabric = self.scenes[0].fabric
        self.targets, self.variables, self.tension, self.solver = targets, variables, tension, solver
        self.ribs = list(ribs)
        self.chord = max(scene.bay.chord for scene in self.scenes)
        self.tension_scale = tension_scale(variables.start, self.chord)
        self.seeds = compressed_seeds(variables, len(self.scenes))
        # The loop (CPU): the chain, or the method named; the batch (accelerators) relaxes.
        self.method = solver.equilibrium_method
        if self.method == "auto" and default_strategy() == "batch":
            self.method = "relax"
        # Small design grids: one relaxation loop to compile beats grid sequencing.
        self.sequencing = self.scenes[0].bay.n_contour > 128
        self.previous: BaysSolution | None = None  # warm start (and its LU factors)
        self._previous_key = None
        # The displacements' tangents along the seeds at the last linearisation: ``(key_of(u), u, tangents)``,
        # ``tangents`` ``(n_bays, n_seeds, n_span, n_contour, 3)`` (`predicted_start`).
        self._tangents = None
        self.solves = 0
        self.history = History(variables)
        # The last evaluation with its derivatives, by ``(kind, key_of(u))``: `evaluate`'s, `nominal_linearised`'s
        # and `residuals_and_jacobian`'s tuples differ, so a design that reads one after another at the same
        # point (the sensitivity after SLSQP) never takes one for another.
        self._cache: dict = {}
        self._solved: dict = {}  # every converged solve by `key_of`, without its LU factors
        # The concrete distances and tensions an evaluation computed at a solve, by `key_of` (`measure`).
        self._measured: dict = {}
        self._recording: dict | None = None  # within a transformed evaluation: what it computes
        self._rows = None
        self.robust = (RobustTerms(self, check_robust_tolerances(tolerances)) if targets.objective == "robust"
                       else None)
        if self.ribs:  # no solve in them: their Jacobian by forward mode on the design vector alone
            def rib_rows(u):
                parameters, shapes = variables.parameters(u), variables.rib_shapes_at(u)
                return jnp.concatenate([g.functions(parameters if shapes is None
                                                    else parameters.replace(rib_shape=shapes[k]))
                                        for k, g in self.ribs])

            if variables.rib_shapes is None:  # a shared shape (few rows): every column, dense
                self._rib_rows = jax.jit(lambda u: (rib_rows(u), jax.jacfwd(rib_rows)(u)))
            else:  # a shape per rib: along the bays' seeds, each rib's rows in its own columns (`rib_columns`)
                seeds = jnp.asarray(self.seeds[0], jnp.float64)
                self._rib_rows = jax.jit(lambda u: (rib_rows(u), jax.vmap(
                    lambda t: jax.jvp(rib_rows, (u,), (t,))[1], out_axes=1)(seeds)))
                self._rib_columns = rib_columns(variables, self.seeds[0])

    # ------------------------------------------------------------ pieces
    def distances(self, nodes) -> list:
        """Per bay, the ``(n_rows, n_contour)`` distances of its rows (``nodes``: as `stacked.each_bay`)."""
        return self._record("distances", [self.targets.distances(k, x) for k, x in enumerate(self._bays(nodes))])

    def tensions(self, nodes, u) -> list:
        """Per bay, its unclamped cell tensions at ``u`` (span then chord), N/m, differentiable (``nodes``: above)."""
        parameters = self.variables.bays_parameters(u, len(self.scenes))
        return self._record("tensions", [cell_tensions(*a) for a in zip(self.scenes, self._bays(nodes), parameters)])

    def _bays(self, nodes) -> list:
        return each_bay(nodes, len(self.scenes))

    def _record(self, name: str, values: list) -> list:
        """``values``, kept as ``name`` when a transformed evaluation computes them (`measure` reads
        their primal values instead of compiling the plain programs again)."""
        if self._recording is not None:
            self._recording[name] = values
        return values

    def _limit_rows(self) -> int:
        """How many tension limits the constraint rows begin with."""
        return 0 if self.tension is None else len(self.tension.names(self.fabric))

    # ------------------------------------------------------------ solves
    def _solve(self, u, initial) -> BaysSolution:
        # The last step's and this solve's freed arrays back to the system: the heap stays level
        # (`memory.release_free_memory`; here and after each linearisation, `_transformed`).
        release_free_memory()
        sol = solve_bays(self.scenes, self.variables.parameters(u), rtol=self.solver.rtol,
                         max_steps=self.solver.max_steps, method=self.method, initial=initial,
                         rib_shapes=self.variables.rib_shapes_at(u), cut_patterns=self.variables.cut_patterns_at(u),
                         sequencing=self.sequencing)
        # The chain's tries count as solves (of its slowest bay); a named method's solve is one.
        self.solves += max([len(s.extra.get("attempts", [None])) for s in sol.solutions or []], default=1)
        release_free_memory()
        return sol

    def _concrete(self, sol: BaysSolution, aux: dict, u) -> BaysSolution:
        """``sol`` with the concrete arrays of ``aux`` (a JAX transformation's auxiliary output)."""
        u = np.asarray(u, np.float64)
        return dataclasses.replace(
            sol, nodes=np.asarray(aux["nodes"]), result=np.asarray(aux["result"]),
            residual=np.asarray(aux["residual"]), steps=np.asarray(aux["steps"]),
            mounted=np.asarray(aux["mounted"]), rib_shapes=concrete_rows(self.variables.rib_shapes_at(u)),
            cut_patterns=concrete_rows(self.variables.cut_patterns_at(u)),
            parameters=self.variables.parameters(u).resolved(self.fabric).as_floats())

    def solve_near(self, u, initial: BaysSolution) -> BaysSolution:
        """The concrete `BaysSolution` at the scaled vector ``u``, warm from ``initial``: counted among the
        solves, but neither archived nor the next warm start (a central difference's side, `tolerance.robust`).
        It may not have converged: check ``converged``."""
        sol = self._solve(u, initial)
        return self._concrete(sol, _aux(sol), u)

    def _transformed(self, transform, function, u):
        """``transform(wrapped)(u)`` and the concrete `BaysSolution`, where ``wrapped(v)`` solves every
        bay at ``v`` and returns ``(function(v, solution), aux)``; the warm start first, then cold.

        Raises:
            BaysConvergenceError: if a bay does not converge from the mounted shape.
        """
        # The chain retries cold itself; a named method is retried cold here.
        retry = self.previous is not None and self.method != "auto"
        warm = self.predicted_start(u)
        for initial in ([warm, None] if retry else [warm]):
            held = {}

            def wrapped(v):
                sol = self._solve(v, initial)
                held["sol"] = sol
                aux = _aux(sol)
                if not sol.converged:  # NaN nodes: stop here, nothing downstream is used
                    return jnp.zeros(0), aux
                self._recording = {}
                try:
                    out = function(v, sol)
                finally:
                    aux["measured"], self._recording = self._recording, None
                return out, aux

            out = transform(wrapped, jnp.asarray(u, jnp.float64))
            release_free_memory()
            sol = self._concrete(held["sol"], out[-1], u)
            if sol.converged:
                measured = out[-1].get("measured")
                if measured:  # their primal values (the transformation's auxiliary output)
                    self._measured[key_of(u)] = (sol.nodes, {name: [np.asarray(a) for a in values]
                                                             for name, values in measured.items()})
                return out[:-1], self.remember(sol, u)
        raise BaysConvergenceError(sol, sol.failed_bays()[0])

    def remember(self, sol: BaysSolution, u) -> BaysSolution:
        """Keep ``sol`` as the next warm start and in the archive of solves (without LU factors)."""
        self.previous, self._previous_key = sol, key_of(u)
        self._solved[key_of(u)] = sol.without_factors()
        return sol

    def predicted_start(self, u) -> BaysSolution | None:
        """The warm start of a solve at ``u``: the last solution, its displacements moved by their first-order
        change ``(dx/du) (u - u_last)`` where the last solve was linearised (the tangents a Gauss-Newton
        iterate's Jacobian computed anyway: no extra back-solve), so that the chord Newton iteration with its
        LU factor, or Newton proper where the step is beyond the chord's reach (`RelaxNewton`), starts within
        the step's second-order error (Panetta et al., 2021, warm-start each design iterate the same way; the
        tangents held are ``n_bays x n_seeds`` node arrays, 32 MB on the 40-cell wing with a cut field per bay
        and a shape per rib). Otherwise the last solution itself, or None before the first."""
        previous = self.previous
        if (previous is None or previous.solutions is None or self._tangents is None
                or self._tangents[0] != self._previous_key):
            return previous
        _, u_last, tangents = self._tangents
        step = np.asarray(u, np.float64) - u_last
        _, columns = self.seeds
        moved = []
        # A solve starts from its warm start's displacement on its own mounted shape (`solution.initial_nodes`):
        # where the ribs move, the nodes' tangents hold the mounted shape's change, which that adds again.
        ribs_move = any(name in RIB_VARIABLES for name in self.variables.names)
        for k, sol in enumerate(previous.solutions):
            nodes = np.asarray(sol.extra.get("primal_nodes", sol.nodes)) + np.tensordot(step[columns[k]], tangents[k],
                                                                                         axes=1)
            if ribs_move:
                scene = self.scenes[k]
                with jax.enable_x64(True):
                    mounted = mounted_compiled(scene.bay.geometry(),
                                               scene.params(self.variables.bay_parameters(np.asarray(u), k)))
                nodes = nodes - (np.asarray(mounted) - np.asarray(previous.mounted[k]))
            moved.append(sol.replace(nodes=nodes, extra={**sol.extra, "primal_nodes": nodes}))
        return dataclasses.replace(previous, solutions=moved)

    def final_solution(self, u) -> BaysSolution:
        """`solve` at ``u``, with each bay's LU factor when ``u`` was the last point solved (the
        archive keeps none): what a later implicit derivative at the design reuses (the tolerance
        analysis) instead of factorising again."""
        u = np.asarray(u, np.float64)
        if self.previous is not None and self._previous_key == key_of(u):
            return self.previous
        return self.solve(u)

    def solve(self, u) -> BaysSolution:
        """The concrete `BaysSolution` at the scaled vector ``u`` (from the archive if solved before).

        Raises:
            BaysConvergenceError: if a bay does not converge from the mounted shape.
        """
        u = np.asarray(u, np.float64)
        if key_of(u) in self._solved:
            return self._solved[key_of(u)]

        def plain(wrapped, v):
            return wrapped(v)

        return self._transformed(plain, lambda v, sol: jnp.zeros(0), u)[1]

    def cached(self, key):
        """The cached evaluation at ``key`` (`variables.key_of` a vector), or None."""
        return self._cache.get(("evaluate", key))

    def _with_rib_rows(self, u, g, jg, recorded):
        """The constraint rows ``g`` with the rib limits' rows appended (their Jacobian to ``jg``), and the
        history's ``recorded`` rows with the least thickness row and the least curvature row over the ribs."""
        if not self.ribs:
            return g, jg, recorded
        g_rib, jac_rib = (np.asarray(a) for a in self._rib_rows(jnp.asarray(u, jnp.float64)))
        per_rib = g_rib.reshape(len(self.ribs), -1)
        if self.variables.rib_shapes is not None:  # compressed: each rib's rows in its own columns
            row_ribs = np.repeat([k for k, _ in self.ribs], per_rib.shape[1])
            jac_rib = decompress(jac_rib, row_ribs, self._rib_columns, self.variables.size)
        jg = (scipy.sparse.vstack([jg, scipy.sparse.csr_matrix(jac_rib)], format="csr") if scipy.sparse.issparse(jg)
              else np.vstack([jg, jac_rib.toarray() if scipy.sparse.issparse(jac_rib) else jac_rib]))
        n_thick = self.ribs[0][1].upper.size
        recorded = np.concatenate([recorded, [per_rib[:, :n_thick].min(), per_rib[:, n_thick:].min()]])
        return np.concatenate([g, g_rib]), jg, recorded

    # ----------------------------------------------- smooth constraints (slsqp)
    def evaluate(self, u):
        """``(f, grad f, g, dg/du, solution)`` at ``u``: the objective (chord^2) and the smooth
        constraints ``g >= 0`` (tension limits; then the rib limits' rows, if any, by forward mode
        without a solve). Their derivatives come by forward mode (one tangent solve per variable,
        all in one batched back-solve) where there are no more variables than these outputs, else
        by reverse mode (one adjoint solve per output): forward mode compiles no transposed
        programs and runs no eager pullback per output (on the default case, one variable and two
        outputs, 0.4 s less of a fresh run).

        Raises:
            BaysConvergenceError: if a bay does not converge from the mounted shape.
        """
        key = ("evaluate", key_of(u))
        if key not in self._cache:

            def outputs(v, sol):
                nodes = self._bays(sol.nodes)
                f = self.targets.objective_value(self.distances(nodes))
                if self.tension is None:
                    return prepend(f, jnp.zeros(0, f.dtype))
                return prepend(f, constraint_functions(self.tension, self.tensions(nodes, v),
                                                        self.fabric, self.tension_scale))

            if self.variables.size <= 1 + self._limit_rows():
                (y, rows), sol = self._transformed(lambda w, v: value_and_jacobian(w, v), outputs, u)
                y, rows = np.asarray(y), np.asarray(rows)
            else:
                (y, pullback), sol = self._transformed(
                    lambda wrapped, v: jax.vjp(wrapped, v, has_aux=True), outputs, u)
                rows = np.stack([np.asarray(pullback(e)[0]) for e in jnp.eye(y.size, dtype=y.dtype)])
                y = np.asarray(y)
            g, jg, recorded = self._with_rib_rows(u, y[1:], rows[1:], y[1:])
            self._cache = {key: (y[0], rows[0], g, jg, sol)}
            self.history.record(u, y[0], np.linalg.norm(rows[0]), solution=sol, constraints=recorded)
        return self._cache[key]

    # ------------------------------------------------------- gauss-newton
    def linearised(self, u):
        """`nominal_linearised`, or for the objective "robust" its stacked residual and quantile rows
        (`tolerance.robust.RobustTerms.assemble`: ``r @ r`` the majoriser of the linearised 95th
        percentile of the mean square, less its constant)."""
        new = ("linearised", key_of(u)) not in self._cache
        r, jr, g, jg, sol = self.nominal_linearised(u)
        if self.robust is None:
            return r, jr, g, jg, sol
        stacked, jstacked, g, jg = self.robust.assemble(u, r, jr, g, jg, sol)
        if new and self.history.entries:  # the iterate's linearised 95th percentile of the rms, chord
            self.history.entries[-1]["robust_p95"] = math.sqrt(max(self.robust.quantile(r, self.robust.raw(u, sol)), 0.0))
        return stacked, jstacked, g, jg, sol

    def reweight(self, u) -> bool:
        """At an accepted iterate ``u`` (evaluated last): the robust majoriser's weight set there
        (`tolerance.robust.RobustTerms.reweight`); False (nothing changes) for the other objectives."""
        if self.robust is None:
            return False
        r, _, _, _, sol = self.nominal_linearised(u)
        self.robust.reweight(r, self.robust.raw(u, sol))
        return True

    def nominal_linearised(self, u):
        """``(r, dr/du, g, dg/du, solution)`` at ``u``: the shape residuals (`objectives.WingTargets.residuals`,
        ``r @ r`` the objective) and the constraints ``g >= 0``: every cell's fibre tensions against each
        limit (`constraints.cell_constraints`, not an aggregate: each row is smooth, so its linearisation
        holds over a longer step) and the rib limits' rows, with their Jacobians (``scipy.sparse``
        CSR) by forward mode through the implicit equilibrium, bay by bay: one wing solve, then per
        bay one back-solve with its own LU factor per variable that moves it (the shared ones, its
        row of a per-bay cut field, its two ribs' rows of per-rib shapes), all bays in one pass of
        compressed tangents (`seeds`); the rib limits' rows without a solve.

        Raises:
            BaysConvergenceError: if a bay does not converge from the mounted shape.
        """
        return self._linearise(u, record=True)

    def linearisation(self, u) -> tuple:
        """``(r, dr/du, g, dg/du, solves)``: `nominal_linearised` at ``u`` as a design's last look at its
        optimum (`sensitivity`), and the forward solves it cost: none where the method's last
        linearisation was at ``u`` (Gauss-Newton's at its accepted iterate), else one wing solve and its
        Jacobian, neither recorded in the history nor shown by the progress bar (no iterate of the design).

        Raises:
            BaysConvergenceError: if a bay does not converge from the mounted shape.
        """
        before = self.solves
        r, jr, g, jg, _ = self._linearise(u, record=False)
        return r, jr, g, jg, self.solves - before

    def _linearise(self, u, record: bool):
        """`nominal_linearised`, recording the iterate in the history when ``record``."""
        key = ("linearised", key_of(u))
        if key not in self._cache:
            seeds, columns = self.seeds
            (y, compressed), sol = self._transformed(partial(value_and_jacobian, basis=seeds),
                                                     self._outputs_and_displacements, u)
            n_out = y.size - sol.nodes.size
            y, compressed, moved = np.asarray(y)[:n_out], compressed[:n_out], compressed[n_out:]
            self._tangents = (key_of(u), np.array(u, np.float64),
                              np.moveaxis(moved.reshape(*sol.nodes.shape, -1), -1, 1))
            n = self.targets.residual_size
            jac = decompress(compressed, self._row_bays(y.size), columns, self.variables.size)
            r, jr, g, jg = y[:n], jac[:n], y[n:], jac[n:]
            n_limits = self._limit_rows()
            # history: the least row of each tension limit (as `evaluate`'s aggregates, >= 0 feasible)
            recorded = g.reshape(n_limits, -1).min(axis=1) if n_limits and g.size else np.zeros(0)
            g, jg, recorded = self._with_rib_rows(u, g, jg, recorded)
            self._cache = {key: (r, jr, g, jg, sol)}
            if record:
                self.history.record(u, r @ r, np.linalg.norm(2.0 * (jr.T @ r)), solution=sol,
                                    constraints=recorded,
                                    jacobian=f"{len(self.scenes)} bay blocks x {seeds.shape[0]} tangents")
        return self._cache[key]

    def _outputs_and_displacements(self, v, sol):
        """The shape residuals, every cell's tension rows (`constraints.cell_constraints`), then every bay's
        displacement from its mounted shape (their tangents: the next solve's warm start, `predicted_start`)."""
        nodes = self._bays(sol.nodes)
        tensions = None if self.tension is None else self.tensions(nodes, v)
        self._rows = self._rows or jax.jit(self._rows_of)  # (this problem's: its limits are constants)
        return self._rows(self.distances(nodes), tensions, sol.nodes, sol.mounted, np.float64(self.tension_scale))

    def _rows_of(self, distances, tensions, nodes, mounted, scale):  # (a divisor as an operand, as eagerly)
        shape = self.targets.residuals(distances)
        rows = [shape] if tensions is None else [shape, cell_constraints(self.tension, jnp.concatenate(tensions),
                                                                          self.fabric, scale)]
        return jnp.concatenate(rows + [displacements(nodes, mounted)])

    def _row_bays(self, n_rows: int) -> np.ndarray:
        """The bay of each row of `_outputs_and_displacements`: the shape residuals bay by bay, then each
        tension limit's rows over every bay's cells (span, then chord tensions of each bay)."""
        n_bays = len(self.scenes)
        shape = np.repeat(np.arange(n_bays), self.targets.residual_size // n_bays)
        n_limits = self._limit_rows()
        if not n_limits:
            return shape
        per_bay = (n_rows - shape.size) // (n_limits * n_bays)
        return np.concatenate([shape, np.tile(np.repeat(np.arange(n_bays), per_bay), n_limits)])

    # ------------------------------------------------------ penalty methods
    def residuals(self, v, sol):
        """Shape residuals (`objectives.WingTargets.residuals`) and tension penalties at ``v`` (a JAX
        value allowed) of the solution ``sol``."""
        nodes = self._bays(sol.nodes)
        shape = self.targets.residuals(self.distances(nodes))
        if self.tension is None:
            return shape
        t = jnp.concatenate(self.tensions(nodes, v))
        return jnp.concatenate([shape, penalty_residuals(self.tension, t, self.fabric, self.tension_scale)])

    def residuals_and_jacobian(self, u):
        """Residuals and their Jacobian in ``u`` (forward mode, one tangent solve per variable)."""
        key = ("residuals", key_of(u))
        if key not in self._cache:
            (r, jac), sol = self._transformed(lambda w, v: value_and_jacobian(w, v), self.residuals, u)
            r, jac = np.asarray(r), np.asarray(jac)
            self._cache = {key: (r, jac, sol)}
            self.history.record(u, np.sum(r**2), np.linalg.norm(2.0 * jac.T @ r), solution=sol)
        return self._cache[key]

    def loss_and_gradient(self, u):
        """The sum of squared residuals and its gradient (reverse mode), and the solution, at ``u``."""

        def value_and_grad(wrapped, v):
            def loss(w):
                r, aux = wrapped(w)
                return jnp.sum(r * r), aux

            (value, aux), grad = jax.value_and_grad(loss, has_aux=True)(v)
            return value, grad, aux

        (value, grad), sol = self._transformed(value_and_grad, self.residuals, u)
        return value, grad, sol

    # ------------------------------------------------------------ measurements
    def measure(self, sol: BaysSolution, u) -> dict:
        """Per-bay errors and tensions of a concrete converged solution at ``u``: ``rms``, ``max``
        (arrays over the bays, fractions of the local chord), ``wing_rms`` (`objectives.WingTargets.errors`),
        ``tensions`` (per bay, N/m) and their extremes."""
        nodes, kept = self._measured.get(key_of(u), (None, {}))
        if nodes is not sol.nodes:  # another solve at u than the evaluation's
            kept = {}
        d = kept.get("distances")
        if d is None:
            d = [np.asarray(x) for x in self.distances(jnp.asarray(sol.nodes))]
        t = kept.get("tensions")
        if t is None:
            t = [np.asarray(x) for x in self.tensions(jnp.asarray(sol.nodes), np.asarray(u, np.float64))]
        return {**self.targets.errors(d), "min_tension": np.array([x.min() for x in t]),
                "max_tension": np.array([x.max() for x in t]), "tensions": t}

