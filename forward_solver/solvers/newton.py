"""Equilibrium by Newton's method on a coloured sparse Jacobian (docs/architecture.md, "Derivatives").

The static force residual ``R(x)`` of `forces.residual` is solved on the free
degrees of freedom with Newton's method. Its Jacobian ``J = dR/dx`` (N/m) is
assembled by `jacobian.assemble_jacobian` from a handful of coloured
Jacobian-vector products (the locality argument and the colouring are
documented there).

``J`` is not symmetric (measured on a 5x7 panel: ``max|J - J^T| / max|J|``
of 0.02 with ``nu = 0``, 0.08 with ``nu = 0.25``): the fibre forces act on
the current widths ``lambda h`` of eq. (14), eq. (10) couples the two fibre
directions, and the pressure is a follower load (eq. 15). The linear solves
therefore use SuperLU (`scipy.sparse.linalg.splu`), whose factor a caller
may reuse for adjoint solves (``J^T y = b`` is
``factor.solve(b, trans="T")``).

Zero shear stiffness and wrinkled cells (``tension_only``) can make ``J``
singular, and Newton from the start can fail: `newton` has a line search,
Levenberg shifts (which stiffen the tangent stiffness ``K = -J``) and load
continuation.

Known limit: an exactly flat panel with no prestrain is slack, and its
out-of-plane Jacobian block vanishes (zero tension, and the out-of-plane
motion changes the stretches only to second order); no Newton step leaves
it, so `newton` returns ``max_steps_reached`` ("stalled"). Start such a case
from a slightly bulged shape or from dynamic relaxation.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp

from .. import forces as fk
from ..precision import float64_scope
from ..programs import prepare_compiled, static_state
from ..solution import Result
from .jacobian import FreePattern, JacobianFactor, factorise, free_dofs, linearise, sparsity_pattern
from .loop import check_stop

__all__ = ["NewtonOptions", "NewtonResult", "newton", "chord_newton", "warm_up"]

#: Armijo constant of the line search: accept a step of length ``alpha`` when
#: ``||R(x + alpha dx)|| <= (1 - ARMIJO alpha) ||R(x)||``.
ARMIJO = 1e-4
#: Levenberg shifts tried in turn (multiples of ``|diag J|``) when the plain
#: Newton step fails; the first is small enough to keep quadratic convergence.
SHIFTS = (0.0, 1e-6, 1e-4, 1e-2, 1.0, 1e2)
#: Relative residual to which intermediate load steps are solved: they only
#: need to land in the next step's basin of attraction.
STAGE_RTOL = 1e-4
#: Iterations over which the residual must halve before a stage that has a
#: fallback (continuation, a smaller load step) gives up on it.
STAGNATION_WINDOW = 10
#: A chord step (the last iteration's factor, no new assembly and LU) is kept when it divides the
#: residual by at least 1 / CHORD_CONTRACTION (`_newton_stage`).
CHORD_CONTRACTION = 0.1
#: Smallest load increment (fraction of p) before continuation gives up.
MIN_LOAD_INCREMENT = 1.0 / 1024.0


class NewtonResult(NamedTuple):
    """Where a Newton solve stopped.

    Attributes:
        x: ``(n_span, n_contour, 3)`` node positions, m.
        result: `Result` code: ``converged``; ``max_steps_reached`` when the
            iteration cap was hit or the line search stalled (see
            ``message``); ``nonfinite`` when the residual at the initial
            shape is not finite; ``diverged`` when a node moved further than
            the divergence bound from its mounted position.
        iterations: Newton iterations (linear solves that gave an accepted
            step), over all load steps.
        residual: ``||R_free||_2 / (p A)`` at ``x`` (dimensionless, p the
            full pressure).
        factor, jacobian, shift, free_dofs, factor_current: the last
            factorised matrix, as `jacobian.JacobianFactor`'s ``lu``,
            ``jacobian``, ``shift``, ``free_dofs`` and ``current`` hold it
            (`jacobian_factor`); ``factor`` and ``jacobian`` None when none
            was made.
        load_steps: pressure levels solved by continuation (0 if plain Newton
            from ``x_init`` converged or continuation was off).
        message: why it stopped, in words.
        history: per iteration (numpy arrays of equal length):
            ``residual`` (relative residual after the step at that step's
            pressure), ``step_length`` (line-search fraction of the Newton
            step), ``shift`` (Levenberg ``mu``), ``pressure`` (Pa),
            ``wall_time`` (s since the start), ``chord`` (1.0 for a chord
            step with the previous iteration's factor, else 0.0).
    """

    x: jnp.ndarray
    result: Result
    iterations: int
    residual: float
    factor: object
    jacobian: sp.csc_matrix | None
    factor_current: bool
    shift: float
    free_dofs: np.ndarray
    load_steps: int
    message: str
    history: dict

    def jacobian_factor(self) -> JacobianFactor | None:
        """The factor as a `JacobianFactor` (for `Solution.factor`); None if none was made."""
        if self.factor is None:
            return None
        return JacobianFactor(self.factor, self.jacobian, np.asarray(self.free_dofs), float(self.shift),
                              bool(self.factor_current))


# -------------------------------------------------------------------- newton
def _factorise(matrix: sp.csc_matrix):
    """The LU of ``matrix`` (`jacobian.factorise`); raises RuntimeError when it is exactly singular."""
    return factorise(matrix)


def _shift_scale(jac: sp.csc_matrix) -> np.ndarray:
    """Per-dof scale ``D`` of the Levenberg shift, N/m.

    The mean ``|J_kk|`` over each node's three components, so the shift is
    the same in every direction at a node: on a slack flat panel the
    out-of-plane diagonal vanishes and a component-wise shift would not
    stiffen it at all. Floored at ``1e-12`` of the largest entry.
    """
    node = np.abs(jac.diagonal()).reshape(-1, 3).mean(axis=1)
    node = np.maximum(node, 1e-12 * max(node.max(initial=0.0), np.finfo(np.float64).tiny))
    return np.repeat(node, 3)


class _Log:
    """Per-iteration records of a solve."""

    def __init__(self):
        self.start = time.perf_counter()
        self.rows = []

    def add(self, residual, step_length, shift, pressure, chord=False):
        self.rows.append((residual, step_length, shift, pressure, time.perf_counter() - self.start, float(chord)))

    def arrays(self) -> dict:
        keys = ("residual", "step_length", "shift", "pressure", "wall_time", "chord")
        if not self.rows:
            return {k: np.zeros(0) for k in keys}
        cols = np.asarray(self.rows, dtype=np.float64).T
        return dict(zip(keys, cols))


class _Stage(NamedTuple):
    x: np.ndarray  # flat, float64
    code: Result
    iterations: int
    residual: float  # at this stage's pressure
    factor: object
    jacobian: sp.csc_matrix | None
    factor_x: np.ndarray | None  # the flat state at which `jacobian` was assembled
    shift: float
    message: str


class _Problem(NamedTuple):
    geometry: fk.Geometry
    ref: fk.Reference
    physics: fk.Physics
    pattern: FreePattern
    shape: tuple
    dtype: object
    x_mounted: np.ndarray  # flat
    bound: float


def _rel(problem: _Problem, params, x_flat) -> float:
    return _state(problem, params, x_flat)[0]


def _state(problem: _Problem, params, x_flat) -> tuple[float, np.ndarray]:
    """The relative residual at the flat nodes ``x_flat`` and the residual on the free dofs (N)."""
    x = jnp.asarray(x_flat.reshape(problem.shape), problem.dtype)
    f, rel = static_state(x, problem.geometry, params, problem.physics)
    return float(rel), np.asarray(f.total, dtype=np.float64).reshape(-1)[problem.pattern.free_dofs]


def _newton_stage(problem: _Problem, params, x, rtol, options: NewtonOptions, log, give_up_when_slow: bool) -> _Stage:
    """Newton iterations at one pressure from ``x`` (flattened, float64).

    With ``give_up_when_slow`` (there is a fallback: continuation or a
    smaller load step) the stage also stops when the residual has not halved
    over the last `STAGNATION_WINDOW` iterations.
    """
    pattern = problem.pattern
    free = pattern.free_dofs
    pressure = float(params.pressure)
    rel, r_x = _state(problem, params, x)
    factor = jac = factor_x = None
    shift = 0.0
    if not math.isfinite(rel):
        return _Stage(x, Result.nonfinite, 0, rel, None, None, None, 0.0,
                      "the residual at the starting shape is not finite")
    first_shift = 0  # index into SHIFTS: after a shifted step, retry one level lower
    past = [rel]
    max_iterations = options.max_iterations
    for k in range(max_iterations):
        if rel <= rtol:
            return _Stage(x, Result.converged, k, rel, factor, jac, factor_x, shift, "converged")
        if give_up_when_slow and k >= STAGNATION_WINDOW and rel > 0.5 * past[k - STAGNATION_WINDOW]:
            return _Stage(x, Result.max_steps_reached, k, rel, factor, jac, factor_x, shift,
                          f"slow progress: the residual did not halve in {STAGNATION_WINDOW} iterations")
        if options.chord_steps and factor is not None and shift == 0.0:
            # A chord step with the last iteration's factor first (one back-solve and one residual):
            # kept when it cuts the residual `CHORD_CONTRACTION`-fold, as it does close to the solution,
            # where J has hardly changed since that factor; else J is assembled and factorised afresh.
            trial = x.copy()
            trial[free] += factor.solve(-r_x)
            rel_trial, r_trial = _state(problem, params, trial)
            if math.isfinite(rel_trial) and rel_trial <= CHORD_CONTRACTION * rel:
                x, rel, r_x = trial, rel_trial, r_trial
                past.append(rel)
                log.add(rel, 1.0, 0.0, pressure, chord=True)
                if np.max(np.abs(x - problem.x_mounted)) > problem.bound:
                    return _Stage(x, Result.diverged, k + 1, rel, factor, jac, factor_x, shift,
                                  "diverged: a node moved further than the divergence bound")
                continue
        x_j = jnp.asarray(x.reshape(problem.shape), problem.dtype)
        jac, r_free = linearise(x_j, problem.ref, params, problem.physics, pattern)
        factor_x = x
        diag = _shift_scale(jac)
        accepted = False
        for level in range(first_shift, len(SHIFTS)):
            mu = SHIFTS[level]
            matrix = jac if mu == 0.0 else (jac - sp.diags(mu * diag, format="csc")).tocsc()
            try:
                lu = _factorise(matrix)
            except RuntimeError:  # exactly singular
                continue
            dx = lu.solve(-r_free)
            if not np.all(np.isfinite(dx)):
                continue
            factor, shift = lu, mu
            alpha = 1.0
            for _ in range(options.max_line_search):
                trial = x.copy()
                trial[free] += alpha * dx
                rel_trial, r_trial = _state(problem, params, trial)
                if math.isfinite(rel_trial) and rel_trial <= (1.0 - ARMIJO * alpha) * rel:
                    accepted = True
                    break
                alpha *= 0.5
            if accepted:
                first_shift = max(level - 1, 0)
                break
        if not accepted:
            return _Stage(x, Result.max_steps_reached, k, rel, factor, jac, factor_x, shift,
                          "stalled: no step reduced the residual, even with the largest shift")
        x, rel, r_x = trial, rel_trial, r_trial
        past.append(rel)
        log.add(rel, alpha, mu, pressure)
        if np.max(np.abs(x - problem.x_mounted)) > problem.bound:
            return _Stage(x, Result.diverged, k + 1, rel, factor, jac, factor_x, shift,
                          "diverged: a node moved further than the divergence bound")
    code = Result.converged if rel <= rtol else Result.max_steps_reached
    message = ("converged" if code == Result.converged else
               f"the iteration cap ({max_iterations} per pressure level) was hit")
    return _Stage(x, code, max_iterations, rel, factor, jac, factor_x, shift, message)


def _continuation(problem, params, x_start, rtol, options: NewtonOptions, log):
    """Load steps ``p_k = lambda_k p`` up to ``p``, each warm-started; adaptive increments."""
    p = params.pressure
    done, increment = 0.0, options.initial_load_fraction
    x = x_start
    iterations = levels = 0
    last = None
    for _ in range(options.max_load_steps):
        target = min(1.0, done + increment)
        at_full = target >= 1.0
        stage_params = params._replace(pressure=p * target)
        stage_rtol = rtol if at_full else max(rtol, STAGE_RTOL)
        stage = _newton_stage(problem, stage_params, x, stage_rtol, options, log, give_up_when_slow=True)
        iterations += stage.iterations
        if stage.code == Result.converged:
            x, done, levels, last = stage.x, target, levels + 1, stage
            if at_full:
                return stage, iterations, levels, 1.0
            increment = min(2.0 * increment, 1.0 - done)
        else:
            increment *= 0.5
            if increment < MIN_LOAD_INCREMENT:
                break
    return last, iterations, levels, done


def warm_up(x, geometry: fk.Geometry, params: fk.KernelInputs, physics: fk.Physics) -> None:
    """Compile (running each once) the programs of a `newton` solve on ``x``'s grid: the reference
    state, the residual and the Jacobian values, called as `newton` calls them (`compilation.Ahead`)."""
    with float64_scope():
        physics = fk.static_physics(physics)
        ref = prepare_compiled(geometry, params, physics)
        x = jnp.asarray(x, geometry.contour_root.dtype)
        static_state(x, geometry, params, physics)
        linearise(x, ref, params, physics, sparsity_pattern(geometry, physics.periodic))


@dataclass(frozen=True)
class NewtonOptions:
    """The knobs of a `newton` solve (the `methods.Newton` method is one of these).

    Args:
        max_iterations: cap on Newton iterations per pressure level; a solve
            runs at most ``max_iterations * (1 + max_load_steps)`` in all.
        continuation: fall back on load continuation when plain Newton fails.
        max_load_steps: cap on continuation levels tried (converged or not).
        initial_load_fraction: first continuation level, a fraction of p.
        max_line_search: cap on step halvings per shift.
        chord_steps: after an unshifted iteration, try a chord step with its
            factor before assembling and factorising afresh (`newton`).

    Raises:
        ValueError: for a cap or fraction out of range.
    """

    max_iterations: int = 50
    continuation: bool = True
    max_load_steps: int = 24
    initial_load_fraction: float = 0.25
    max_line_search: int = 12
    chord_steps: bool = True

    def __post_init__(self):
        check_stop(max_iterations=self.max_iterations, max_load_steps=self.max_load_steps,
                   max_line_search=self.max_line_search)
        if not 0.0 < self.initial_load_fraction <= 1.0:
            raise ValueError(f"initial_load_fraction must lie in (0, 1] (a fraction of the pressure), "
                             f"got {self.initial_load_fraction!r}")


def newton(x_init, geometry: fk.Geometry, params: fk.KernelInputs, physics: fk.Physics, rtol: float,
           options: NewtonOptions = NewtonOptions(), *, divergence_bound: float) -> NewtonResult:
    """Static equilibrium ``R(x) = 0`` on the free nodes by Newton's method.

    Each iteration assembles ``J = dR/dx`` (`assemble_jacobian`), solves
    ``J dx = -R`` with SuperLU and backtracks (halving, at most
    ``max_line_search`` times) until ``||R_free||`` falls by the Armijo
    factor; after an unshifted iteration it first tries a chord step with
    that factor, kept when it divides the residual by at least
    ``1 / CHORD_CONTRACTION`` (close to the solution J has hardly changed:
    on the 40-cell wing's warm design solves one assembly and LU and four
    chord steps now do what three assemblies and LUs did). If the
    factorisation fails or no step descends, it retries with the Levenberg
    shifts ``J - mu D`` of `SHIFTS` (``D`` the mean
    ``|diag J|`` of each node). If Newton from ``x_init`` does not converge
    (iteration cap, stall, or, when continuation is on, a residual that has
    not halved in `STAGNATION_WINDOW` iterations) and ``continuation`` is on,
    it restarts from ``x_init`` with load continuation: pressure levels ``lambda p`` with
    ``lambda`` starting at ``initial_load_fraction``, doubling the increment
    after a converged level and halving it after a failed one (intermediate
    levels are solved to `STAGE_RTOL`). After convergence it assembles and
    factorises the unshifted Jacobian at the returned ``x`` (one more
    assembly and LU), so ``factor`` serves adjoint solves at the equilibrium.

    Stop test: ``||R_free||_2 / (p A) <= rtol`` (`forces.relative_residual`),
    a non-finite state or residual counting as not converged. It runs in its
    own `precision.float64_scope`: the residual in the dtype of ``geometry``,
    the linear algebra in float64.

    Args:
        x_init: ``(n_span, n_contour, 3)`` starting node positions, m (held
            nodes should sit at their mounted positions).
        geometry: bay geometry (`forces.Geometry`).
        params: traced parameters; ``params.pressure`` > 0, Pa.
        physics: static switches (velocity terms are ignored).
        rtol: relative residual tolerance, in (0, 1).
        options: the iteration's knobs (`NewtonOptions`).
        divergence_bound: largest displacement from the mounted shape, m,
            before the solve stops as ``diverged`` (`Bay.divergence_bound`).

    Returns:
        A `NewtonResult`; never raises for a failed solve, and never returns
        a non-finite ``x`` (a non-finite trial is rejected by the line
        search).

    Raises:
        ValueError: for an ``rtol`` out of range or an ``x_init`` of the
            wrong shape.
    """
    check_stop(rtol)
    with float64_scope():
        physics = fk.static_physics(physics)
        shape = tuple(geometry.free.shape) + (3,)
        if tuple(np.shape(x_init)) != shape:
            raise ValueError(f"x_init has shape {np.shape(x_init)} but this bay's grid needs {shape}")
        dtype = geometry.contour_root.dtype
        ref = prepare_compiled(geometry, params, physics)
        problem = _Problem(geometry, ref, physics, sparsity_pattern(geometry, physics.periodic), shape, dtype,
                           np.asarray(ref.nodes, dtype=np.float64).reshape(-1), float(divergence_bound))
        log = _Log()
        x0 = np.array(x_init, dtype=np.float64).reshape(-1)
        stage = _newton_stage(problem, params, x0, rtol, options, log, give_up_when_slow=options.continuation)
        iterations, levels = stage.iterations, 0
        if stage.code != Result.converged and options.continuation and stage.code != Result.nonfinite:
            cont, cont_iterations, levels, reached = _continuation(
                problem, params, x0, rtol, options, log)
            iterations += cont_iterations
            if reached >= 1.0:
                stage = cont
            else:
                # Continuation stopped short of p: keep whichever shape is
                # closer to equilibrium at the full pressure.
                note = f"load continuation stopped at {reached:.4g} of the full pressure"
                full = math.inf if cont is None else _rel(problem, params, cont.x)
                if full < stage.residual:
                    stage = cont._replace(code=Result.max_steps_reached, residual=full, message=note)
                else:
                    stage = stage._replace(message=f"{stage.message}; {note}")
        factor, jac, factor_x, shift = stage.factor, stage.jacobian, stage.factor_x, stage.shift
        if stage.code == Result.converged:
            x_j = jnp.asarray(stage.x.reshape(shape), dtype)
            jac_new, _ = linearise(x_j, ref, params, physics, problem.pattern)
            try:
                factor, jac, factor_x, shift = _factorise(jac_new), jac_new, stage.x, 0.0
            except RuntimeError:  # singular at the solution: keep the last factor
                pass
        current = (factor is not None and shift == 0.0 and factor_x is not None
                   and np.array_equal(factor_x, stage.x))
        return NewtonResult(x=jnp.asarray(stage.x.reshape(shape), dtype), result=Result(stage.code),
                            iterations=int(iterations), residual=float(stage.residual), factor=factor, jacobian=jac,
                            factor_current=bool(current), shift=float(shift), free_dofs=problem.pattern.free_dofs,
                            load_steps=int(levels), message=stage.message, history=log.arrays())


def chord_newton(x_init, geometry, params, physics, previous: JacobianFactor, rtol: float,
                 max_iterations: int = 12) -> NewtonResult | None:
    """Warm-started Newton that reuses a nearby solution's factorised Jacobian.

    Each iteration costs one residual and one pair of triangular solves with
    ``previous.lu`` (no assembly, no LU): the chord (modified Newton)
    method. After a small change of parameters the old Jacobian is close to
    the new one, so the residual falls by about the relative change of J per
    iteration (two orders for a 1% pressure change). The returned factor is
    the old one (``factor_current`` False).

    Args:
        x_init: ``(n_span, n_contour, 3)`` start, usually the nearby solution's nodes.
        geometry, params, physics: the new problem.
        previous: the `JacobianFactor` of a nearby solution on the same grid
            and free dofs (`Solution.factor`).
        rtol: relative residual tolerance.
        max_iterations: cap; the method also stops as soon as an iteration
            fails to halve the residual.

    Returns:
        A converged `NewtonResult`, or None when the chord iteration does not
        converge (the caller then falls back on a full solve).
    """
    if previous is None:
        return None
    with float64_scope():
        physics = fk.static_physics(physics)
        free = free_dofs(geometry)
        if not np.array_equal(free, previous.free_dofs):
            return None
        dtype = geometry.contour_root.dtype
        shape = tuple(geometry.free.shape) + (3,)
        x = np.array(x_init, dtype=np.float64).reshape(-1)
        log = _Log()
        last = math.inf
        for iteration in range(max_iterations + 1):
            f, rel = static_state(jnp.asarray(x.reshape(shape), dtype), geometry, params, physics)
            r = f.total
            rel = float(rel)
            log.add(rel, 1.0, 0.0, float(params.pressure), chord=True)
            if not math.isfinite(rel) or rel > 0.5 * last:
                return None
            if rel <= rtol:
                return NewtonResult(
                    x=jnp.asarray(x.reshape(shape), dtype), result=Result.converged,
                    iterations=iteration, residual=rel, factor=previous.lu,
                    jacobian=previous.jacobian, factor_current=False, shift=previous.shift,
                    free_dofs=free, load_steps=0, message="converged (chord Newton, reused factor)",
                    history=log.arrays())
            last = rel
            x[free] += previous.lu.solve(-np.asarray(r, dtype=np.float64).reshape(-1)[free])
        return None
