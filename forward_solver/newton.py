"""Equilibrium by Newton's method on a coloured sparse Jacobian (DESIGN section 5).

The static force residual ``R(x)`` of `forces.residual` is solved on the free
degrees of freedom with Newton's method. Its Jacobian ``J = dR/dx`` (N/m) is
assembled from a handful of Jacobian-vector products:

* Locality. On the structured grid the force on node ``(i, j)`` depends only
  on the nodes ``(i', j')`` with ``|i' - i| <= 1`` and ``|j' - j| <= 1``
  (``j`` taken modulo ``n_contour`` on a closed contour), checked against
  `forces`: the span-edge force of edge ``(i+1/2, j)`` sums the tensions of
  cells ``(i+1/2, j-1/2)`` and ``(i+1/2, j+1/2)``, each a function of its four
  corners only (stretches of eq. 12 of its two span and two contour edges,
  tensions of eq. 10); the contour-edge force of ``(i, j+1/2)`` likewise
  sums cells ``(i-1/2, j+1/2)`` and ``(i+1/2, j+1/2)``; edge directions
  (eq. 13) depend on the edge's two nodes; the pressure area vector of a
  node (eq. 15) sums quarter-cell contributions of its (up to four) adjacent
  cells, each a function of that cell's corners; gravity is constant. Every
  one of these lies in the 3x3 block of nodes around ``(i, j)``, so each row
  of ``J`` has at most 27 non-zeros.
* Colouring. Two columns may share one seed vector when no row sees both.
  Column ``(i, j, c)`` gets colour ``(i mod 3, j mod 3, c)``: same-coloured
  nodes are at least 3 apart in each index, so no 3x3 block holds two of
  them. 27 colours on an open grid. On a closed contour ``j mod 3`` wraps
  correctly only if ``n_contour % 3 == 0``; otherwise the last
  ``n_contour % 3`` contour columns get colours of their own (36 or 45).
* One ``jax.vmap`` of ``jax.jvp`` over the colour seeds gives every column
  of ``J`` compressed; the known sparsity pattern decompresses it into a
  `scipy.sparse.csc_matrix`.

``J`` is not symmetric (measured on a 5x7 panel: ``max|J - J^T| / max|J|``
of 0.02 with ``nu = 0``, 0.08 with ``nu = 0.25``): the fibre forces act on
the current widths ``lambda h`` of eq. (14), eq. (10) couples the two fibre
directions, and the pressure is a follower load (eq. 15). The linear solves
therefore use SuperLU (`scipy.sparse.linalg.splu`), whose factor a caller
may reuse for adjoint solves (``J^T y = b`` is
``factor.solve(b, trans="T")``).

Robustness: a backtracking line search on ``||R_free||``; a Levenberg-style
diagonal shift ``J - mu D`` (``D`` the nodal mean of ``|diag J|``, which
stiffens the tangent stiffness ``K = -J``) when the factorisation fails or
no step descends, since zero shear stiffness and wrinkled cells
(``tension_only``) can make ``J`` singular; and load continuation
(pressure steps from a fraction of ``p`` up to ``p``, each warm-started from
the last) when Newton from the initial shape fails.

Known limit: an exactly flat panel with no prestrain is slack, and its
out-of-plane Jacobian block vanishes (zero tension, and the out-of-plane
motion changes the stretches only to second order); no Newton step leaves
it, so `newton` returns ``max_steps_reached`` ("stalled"). Start such a case
from a slightly bulged shape or from dynamic relaxation.
"""

from __future__ import annotations

import functools
import math
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import forces as fk
from .scene import float64_scope
from .solution import Result

__all__ = [
    "Sparsity",
    "NewtonResult",
    "jacobian_sparsity",
    "free_dofs",
    "assemble_jacobian",
    "newton",
]

#: Armijo constant of the line search: accept a step of length ``alpha`` when
#: ``||R(x + alpha dx)|| <= (1 - ARMIJO alpha) ||R(x)||``.
ARMIJO = 1e-4
#: Levenberg shifts tried in turn (multiples of ``|diag J|``) when the plain
#: Newton step fails; the first is small enough to keep quadratic convergence.
SHIFTS = (0.0, 1e-6, 1e-4, 1e-2, 1.0, 1e2)
#: Column ordering of SuperLU. The pattern is structurally symmetric, so a
#: minimum-degree ordering of ``J^T + J`` fits it; measured on a 33x257 closed
#: grid (one core): 0.17 s and 4.0e6 factor non-zeros against 0.58 s and
#: 1.0e7 for the default COLAMD.
PERMC_SPEC = "MMD_AT_PLUS_A"
#: Relative residual to which intermediate load steps are solved: they only
#: need to land in the next step's basin of attraction.
STAGE_RTOL = 1e-4
#: Iterations over which the residual must halve before a stage that has a
#: fallback (continuation, a smaller load step) gives up on it.
STAGNATION_WINDOW = 10
#: Smallest load increment (fraction of p) before continuation gives up.
MIN_LOAD_INCREMENT = 1.0 / 1024.0


class Sparsity(NamedTuple):
    """Sparsity pattern and column colouring of ``dR/dx`` on a full grid.

    Degrees of freedom are numbered as ``x.reshape(-1)`` of an
    ``(n_span, n_contour, 3)`` array: ``dof = (i * n_contour + j) * 3 + c``.

    Attributes:
        rows: ``(nnz,)`` row dof of every structural non-zero.
        cols: ``(nnz,)`` column dof of every structural non-zero.
        colours: ``(n_dof,)`` colour of every column.
        n_colours: number of colours (27, 36 or 45).
    """

    rows: np.ndarray
    cols: np.ndarray
    colours: np.ndarray
    n_colours: int


class _FreePattern(NamedTuple):
    """The pattern restricted to free dofs, in CSC order, with its gather indices."""

    free_dofs: np.ndarray  # (nf,) full dof index of each free dof
    indices: np.ndarray  # CSC row indices (reduced numbering)
    indptr: np.ndarray  # CSC column pointers
    gather_colour: np.ndarray  # (nnz_free,) colour of each non-zero's column
    gather_row: np.ndarray  # (nnz_free,) full row dof of each non-zero
    colours: np.ndarray  # (n_dof,) int32 column colours
    n_colours: int


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
        factor: `scipy.sparse.linalg.SuperLU` of the last factorised matrix
            (None if none was factorised).
        jacobian: that matrix's unshifted Jacobian ``dR/dx`` on the free dofs,
            N/m, `scipy.sparse.csc_matrix` (None if none was assembled).
        factor_current: True when ``factor`` is the LU of the unshifted
            ``jacobian`` assembled at the returned ``x`` (so it serves adjoint
            solves at the equilibrium as it is).
        shift: Levenberg shift ``mu`` of ``factor`` (it factorises
            ``jacobian - mu D``, D the mean ``|diag|`` of each node); 0.0
            when unshifted.
        free_dofs: ``(n_free,)`` index of each Jacobian row/column into
            ``x.reshape(-1)``.
        load_steps: pressure levels solved by continuation (0 if plain Newton
            from ``x_init`` converged or continuation was off).
        message: why it stopped, in words.
        history: per iteration (numpy arrays of equal length):
            ``residual`` (relative residual after the step at that step's
            pressure), ``step_length`` (line-search fraction of the Newton
            step), ``shift`` (Levenberg ``mu``), ``pressure`` (Pa),
            ``wall_time`` (s since the start).
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


# ------------------------------------------------------------------ sparsity
def _contour_colours(n_contour: int, periodic: bool) -> tuple[np.ndarray, int]:
    """Colour of each contour index ``j`` and the number of contour colours."""
    j = np.arange(n_contour)
    colour = j % 3
    extra = n_contour % 3 if periodic else 0
    if extra:
        # The wrap joins j = n_contour-1 to j = 0: the last `extra` columns
        # would sit closer than 3 to a same-coloured one, so they get their own.
        last = np.arange(n_contour - extra, n_contour)
        colour[last] = 3 + (last - (n_contour - extra))
    return colour, 3 + extra


@functools.lru_cache(maxsize=16)
def jacobian_sparsity(shape: tuple[int, int], periodic: bool) -> Sparsity:
    """Structural non-zeros and column colours of ``dR/dx`` on an ``(n_span, n_contour)`` grid.

    Each node's force depends only on its 3x3 node neighbourhood (see the
    module docstring for the check against `forces`), so row ``(i, j, c)``
    has non-zeros in columns ``(i', j', c')`` with ``|i' - i| <= 1``,
    ``|j' - j| <= 1`` (``j`` modulo ``n_contour`` when ``periodic``) and any
    ``c'``. Columns are coloured ``(i mod 3, j mod 3, c)``; on a periodic
    contour with ``n_contour % 3 != 0`` the last ``n_contour % 3`` contour
    indices get extra colours. Cached per ``(shape, periodic)``; the returned
    arrays are read-only.

    Args:
        shape: ``(n_span, n_contour)`` grid shape.
        periodic: True for a closed contour.

    Returns:
        The `Sparsity`.
    """
    ns, nc = (int(s) for s in shape)
    node = np.arange(ns * nc).reshape(ns, nc)
    row_nodes, col_nodes = [], []
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            i = np.arange(ns)[:, None]
            j = np.arange(nc)[None, :]
            i2 = i + di
            j2 = j + dj
            if periodic:
                j2 = j2 % nc
            ok = (i2 >= 0) & (i2 < ns) & (j2 >= 0) & (j2 < nc)
            ok = np.broadcast_to(ok, (ns, nc))
            i2 = np.broadcast_to(np.clip(i2, 0, ns - 1), (ns, nc))
            j2 = np.broadcast_to(np.clip(j2, 0, nc - 1), (ns, nc))
            row_nodes.append(node[ok])
            col_nodes.append(node[i2[ok], j2[ok]])
    pairs = np.unique(np.stack([np.concatenate(row_nodes), np.concatenate(col_nodes)]), axis=1)
    c = np.arange(3)
    rows = (3 * pairs[0][:, None, None] + c[:, None]).repeat(3, axis=2).reshape(-1)
    cols = (3 * pairs[1][:, None, None] + c[None, :]).repeat(3, axis=1).reshape(-1)

    contour_colour, n_contour_colours = _contour_colours(nc, periodic)
    node_colour = (np.arange(ns)[:, None] % 3) * n_contour_colours + contour_colour[None, :]
    colours = (3 * node_colour[..., None] + c).reshape(-1)
    sparsity = Sparsity(rows.astype(np.int64), cols.astype(np.int64), colours.astype(np.int64),
                        9 * n_contour_colours)
    for a in sparsity[:3]:
        a.setflags(write=False)  # shared through the cache
    return sparsity


@functools.lru_cache(maxsize=16)
def _free_pattern(shape: tuple[int, int], periodic: bool, free_key: bytes) -> _FreePattern:
    """The pattern of `jacobian_sparsity` on the free dofs, in CSC order."""
    sparsity = jacobian_sparsity(shape, periodic)
    free_node = np.frombuffer(free_key, dtype=bool).reshape(shape)
    free_dof = np.repeat(free_node.reshape(-1), 3)
    reduced = np.cumsum(free_dof) - 1
    keep = free_dof[sparsity.rows] & free_dof[sparsity.cols]
    rows, cols = sparsity.rows[keep], sparsity.cols[keep]
    order = np.lexsort((rows, cols))  # column-major: CSC order
    rows, cols = rows[order], cols[order]
    n_free = int(free_dof.sum())
    indptr = np.concatenate([[0], np.cumsum(np.bincount(reduced[cols], minlength=n_free))])
    pattern = _FreePattern(
        free_dofs=np.flatnonzero(free_dof),
        indices=reduced[rows].astype(np.int32),
        indptr=indptr.astype(np.int32),
        gather_colour=sparsity.colours[cols].astype(np.int32),
        gather_row=rows.astype(np.int32),
        colours=sparsity.colours.astype(np.int32),
        n_colours=sparsity.n_colours,
    )
    for a in pattern[:6]:
        a.setflags(write=False)  # shared through the cache
    return pattern


def _pattern(ref: fk.Reference, periodic: bool) -> _FreePattern:
    free_node = np.asarray(ref.free[..., 0]) > 0.5
    return _free_pattern(free_node.shape, bool(periodic), free_node.tobytes())


def free_dofs(ref: fk.Reference) -> np.ndarray:
    """Index of each free degree of freedom into ``x.reshape(-1)`` (the Jacobian's numbering)."""
    free_node = np.asarray(ref.free[..., 0]) > 0.5
    return np.flatnonzero(np.repeat(free_node.reshape(-1), 3))


# ------------------------------------------------------------------ jacobian
@functools.partial(jax.jit, static_argnames=("physics", "n_colours"))
def _jacobian_values(x, ref, params, colours, gather_colour, gather_row, physics, n_colours):
    """Residual and the Jacobian's structural non-zeros from one vmap of jvp over the colours."""
    physics = fk.static_physics(physics)
    free = jnp.broadcast_to(ref.free, x.shape).reshape(-1)
    seeds = (colours[None, :] == jnp.arange(n_colours, dtype=colours.dtype)[:, None]).astype(x.dtype)
    seeds = seeds * free

    def flat_residual(flat):
        return fk.residual(flat.reshape(x.shape), ref, params, physics).reshape(-1)

    def column_group(seed):
        return jax.jvp(flat_residual, (x.reshape(-1),), (seed,))

    r, compressed = jax.vmap(column_group, out_axes=(None, 0))(seeds)
    return r, compressed[gather_colour, gather_row]


def _linearise(x, ref, params, physics, pattern: _FreePattern):
    """``(J, R_free)`` at ``x``: the free-dof Jacobian (csc, N/m) and residual (N)."""
    r, data = _jacobian_values(jnp.asarray(x), ref, params, pattern.colours, pattern.gather_colour,
                               pattern.gather_row, physics, pattern.n_colours)
    n = pattern.free_dofs.size
    # Copies: scipy may sort or prune index arrays in place, and these are cached.
    jac = sp.csc_matrix((np.asarray(data, dtype=np.float64), pattern.indices.copy(),
                         pattern.indptr.copy()), shape=(n, n))
    return jac, np.asarray(r, dtype=np.float64)[pattern.free_dofs]


def assemble_jacobian(x, ref: fk.Reference, params: fk.Params, physics: fk.Physics) -> sp.csc_matrix:
    """Sparse Jacobian ``dR/dx`` of `forces.residual` on the free degrees of freedom.

    One ``jax.vmap`` of ``jax.jvp`` over the colour seeds of
    `jacobian_sparsity` (27 to 45 products, compiled once per grid shape and
    physics), decompressed along the sparsity pattern. Rows and columns are
    the free dofs of ``ref.free`` in the order of `free_dofs`. The velocity
    terms of ``physics`` are ignored (static residual).

    Args:
        x: ``(n_span, n_contour, 3)`` node positions, m.
        ref: cut lengths and free mask from `forces.prepare`.
        params: traced parameters (pressure in Pa, ...).
        physics: static switches.

    Returns:
        ``(n_free, n_free)`` `scipy.sparse.csc_matrix` in N/m.
    """
    with float64_scope(x, ref, params):
        return _linearise(x, ref, params, physics, _pattern(ref, physics.periodic))[0]


# -------------------------------------------------------------------- newton
@functools.partial(jax.jit, static_argnames=("physics",))
def _relative_residual(x, ref, params, physics):
    """`forces.relative_residual`, NaN unless the state and the residual are finite.

    `forces.safe_norm` maps a NaN vector to 0 (its ``sq > 0`` test is False
    for NaN), so the relative residual alone would call a NaN state
    converged; the explicit check keeps the stop test honest.
    """
    rel = fk.relative_residual(x, ref, params, physics)
    finite = jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(fk.residual(x, ref, params, physics)))
    return jnp.where(finite, rel, jnp.nan)


_prepare = jax.jit(fk.prepare, static_argnames=("physics",))


def _factorise(matrix: sp.csc_matrix):
    """SuperLU of ``matrix``; raises RuntimeError when it is exactly singular."""
    return spla.splu(matrix, permc_spec=PERMC_SPEC)


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

    def add(self, residual, step_length, shift, pressure):
        self.rows.append((residual, step_length, shift, pressure, time.perf_counter() - self.start))

    def arrays(self) -> dict:
        keys = ("residual", "step_length", "shift", "pressure", "wall_time")
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
    ref: fk.Reference
    physics: fk.Physics
    pattern: _FreePattern
    shape: tuple
    dtype: object
    x_mounted: np.ndarray  # flat
    bound: float


def _rel(problem: _Problem, params, x_flat) -> float:
    x = jnp.asarray(x_flat.reshape(problem.shape), problem.dtype)
    return float(_relative_residual(x, problem.ref, params, problem.physics))


def _newton_stage(problem: _Problem, params, x, rtol, max_iterations, max_line_search, log,
                  give_up_when_slow: bool) -> _Stage:
    """Newton iterations at one pressure from ``x`` (flattened, float64).

    With ``give_up_when_slow`` (there is a fallback: continuation or a
    smaller load step) the stage also stops when the residual has not halved
    over the last `STAGNATION_WINDOW` iterations.
    """
    pattern = problem.pattern
    free = pattern.free_dofs
    pressure = float(params.pressure)
    rel = _rel(problem, params, x)
    factor = jac = factor_x = None
    shift = 0.0
    if not math.isfinite(rel):
        return _Stage(x, Result.nonfinite, 0, rel, None, None, None, 0.0,
                      "the residual at the starting shape is not finite")
    first_shift = 0  # index into SHIFTS: after a shifted step, retry one level lower
    past = [rel]
    for k in range(max_iterations):
        if rel <= rtol:
            return _Stage(x, Result.converged, k, rel, factor, jac, factor_x, shift, "converged")
        if give_up_when_slow and k >= STAGNATION_WINDOW and rel > 0.5 * past[k - STAGNATION_WINDOW]:
            return _Stage(x, Result.max_steps_reached, k, rel, factor, jac, factor_x, shift,
                          f"slow progress: the residual did not halve in {STAGNATION_WINDOW} iterations")
        x_j = jnp.asarray(x.reshape(problem.shape), problem.dtype)
        jac, r_free = _linearise(x_j, problem.ref, params, problem.physics, pattern)
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
            for _ in range(max_line_search):
                trial = x.copy()
                trial[free] += alpha * dx
                rel_trial = _rel(problem, params, trial)
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
        x, rel = trial, rel_trial
        past.append(rel)
        log.add(rel, alpha, mu, pressure)
        if np.max(np.abs(x - problem.x_mounted)) > problem.bound:
            return _Stage(x, Result.diverged, k + 1, rel, factor, jac, factor_x, shift,
                          "diverged: a node moved further than the divergence bound")
    code = Result.converged if rel <= rtol else Result.max_steps_reached
    message = "converged" if code == Result.converged else "the iteration cap was hit"
    return _Stage(x, code, max_iterations, rel, factor, jac, factor_x, shift, message)


def _continuation(problem, params, x_start, rtol, max_iterations, max_line_search, max_load_steps,
                  initial_fraction, log):
    """Load steps ``p_k = lambda_k p`` up to ``p``, each warm-started; adaptive increments."""
    p = params.pressure
    done, increment = 0.0, initial_fraction
    x = x_start
    iterations = levels = 0
    last = None
    for _ in range(max_load_steps):
        target = min(1.0, done + increment)
        at_full = target >= 1.0
        stage_params = params._replace(pressure=p * target)
        stage_rtol = rtol if at_full else max(rtol, STAGE_RTOL)
        stage = _newton_stage(problem, stage_params, x, stage_rtol, max_iterations, max_line_search, log,
                              give_up_when_slow=True)
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


def newton(
    x_init,
    geometry: fk.Geometry,
    params: fk.Params,
    physics: fk.Physics,
    rtol: float,
    max_iterations: int = 50,
    *,
    continuation: bool = True,
    max_load_steps: int = 24,
    initial_load_fraction: float = 0.25,
    max_line_search: int = 12,
    factor_at_solution: bool = True,
    divergence_bound: float | None = None,
) -> NewtonResult:
    """Static equilibrium ``R(x) = 0`` on the free nodes by Newton's method.

    Each iteration assembles ``J = dR/dx`` (`assemble_jacobian`), solves
    ``J dx = -R`` with SuperLU and backtracks (halving, at most
    ``max_line_search`` times) until ``||R_free||`` falls by the Armijo
    factor. If the factorisation fails or no step descends, it retries with
    the Levenberg shifts ``J - mu D`` of `SHIFTS` (``D`` the mean
    ``|diag J|`` of each node). If Newton from ``x_init`` does not converge
    (iteration cap, stall, or, when continuation is on, a residual that has
    not halved in `STAGNATION_WINDOW` iterations) and ``continuation`` is on,
    it restarts from ``x_init`` with load continuation: pressure levels ``lambda p`` with
    ``lambda`` starting at ``initial_load_fraction``, doubling the increment
    after a converged level and halving it after a failed one (intermediate
    levels are solved to `STAGE_RTOL`).

    Stop test (as the rest of the package): ``forces.relative_residual`` ``=
    ||R_free||_2 / (p A) <= rtol``, the residual force over the total
    pressure load, with a non-finite state or residual counted as not
    converged. Meant to be called inside `scene.float64_scope` (it enters
    that scope itself too, which nests harmlessly); the residual is computed
    in the dtype of ``geometry`` and the linear algebra in float64.

    Args:
        x_init: ``(n_span, n_contour, 3)`` starting node positions, m (held
            nodes should sit at their mounted positions).
        geometry: bay geometry (`forces.Geometry`).
        params: traced parameters; ``params.pressure`` > 0, Pa.
        physics: static switches (velocity terms are ignored).
        rtol: relative residual tolerance, in (0, 1).
        max_iterations: cap on Newton iterations per pressure level; a solve
            runs at most ``max_iterations * (1 + max_load_steps)`` in all.
        continuation: fall back on load continuation when plain Newton fails.
        max_load_steps: cap on continuation levels tried (converged or not).
        initial_load_fraction: first continuation level, a fraction of p.
        max_line_search: cap on step halvings per shift.
        factor_at_solution: after convergence, assemble and factorise the
            unshifted Jacobian at the returned ``x`` (one more assembly and
            LU), so ``factor`` serves adjoint solves at the equilibrium.
        divergence_bound: largest displacement from the mounted shape, m,
            before the solve stops as ``diverged`` (default: chord + rib
            spacing, as `solve_equilibrium`).

    Returns:
        A `NewtonResult`; never raises for a failed solve, and never returns
        a non-finite ``x`` (a non-finite trial is rejected by the line
        search).

    Raises:
        ValueError: for an ``rtol``, cap or fraction out of range, or an
            ``x_init`` of the wrong shape.
    """
    if not (isinstance(rtol, float | int) and 0 < rtol < 1):
        raise ValueError(f"rtol must lie in (0, 1), got {rtol!r}")
    for name, value in (("max_iterations", max_iterations), ("max_load_steps", max_load_steps),
                        ("max_line_search", max_line_search)):
        if not (isinstance(value, int) and value >= 1):
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if not 0.0 < initial_load_fraction <= 1.0:
        raise ValueError(
            f"initial_load_fraction must lie in (0, 1] (a fraction of the pressure), "
            f"got {initial_load_fraction!r}"
        )
    with float64_scope():
        physics = fk.static_physics(physics)
        shape = tuple(geometry.free.shape) + (3,)
        if tuple(np.shape(x_init)) != shape:
            raise ValueError(f"x_init has shape {np.shape(x_init)} but this bay's grid needs {shape}")
        dtype = geometry.contour_root.dtype
        ref = _prepare(geometry, params, physics)
        if divergence_bound is None:
            chord = 0.5 * float(geometry.chord_root + geometry.chord_tip)
            divergence_bound = chord + float(geometry.rib_spacing)
        problem = _Problem(ref, physics, _pattern(ref, physics.periodic), shape, dtype,
                           np.asarray(ref.nodes, dtype=np.float64).reshape(-1), float(divergence_bound))
        log = _Log()
        x0 = np.array(x_init, dtype=np.float64).reshape(-1)
        stage = _newton_stage(problem, params, x0, rtol, max_iterations, max_line_search, log,
                              give_up_when_slow=continuation)
        iterations, levels = stage.iterations, 0
        if stage.code != Result.converged and continuation and stage.code != Result.nonfinite:
            cont, cont_iterations, levels, reached = _continuation(
                problem, params, x0, rtol, max_iterations, max_line_search, max_load_steps,
                initial_load_fraction, log)
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
        if stage.code == Result.converged and factor_at_solution:
            x_j = jnp.asarray(stage.x.reshape(shape), dtype)
            jac_new, _ = _linearise(x_j, ref, params, physics, problem.pattern)
            try:
                factor, jac, factor_x, shift = _factorise(jac_new), jac_new, stage.x, 0.0
            except RuntimeError:  # singular at the solution: keep the last factor
                pass
        current = (factor is not None and shift == 0.0 and factor_x is not None
                   and np.array_equal(factor_x, stage.x))
        return NewtonResult(
            x=jnp.asarray(stage.x.reshape(shape), dtype),
            result=Result(stage.code),
            iterations=int(iterations),
            residual=float(stage.residual),
            factor=factor,
            jacobian=jac,
            factor_current=bool(current),
            shift=float(shift),
            free_dofs=problem.pattern.free_dofs,
            load_steps=int(levels),
            message=stage.message,
            history=log.arrays(),
        )


@functools.partial(jax.jit, static_argnames=("physics",))
def _residual_and_relative(x, ref, params, physics):
    r = fk.residual(x, ref, params, physics)
    return r, _relative_residual(x, ref, params, physics)


def chord_newton(x_init, geometry, params, physics, previous: NewtonResult, rtol: float,
                 max_iterations: int = 12) -> NewtonResult | None:
    """Warm-started Newton that reuses a nearby solution's factorised Jacobian.

    Each iteration costs one residual and one pair of triangular solves with
    ``previous.factor`` (no assembly, no LU): the chord (modified Newton)
    method. After a small change of parameters the old Jacobian is close to
    the new one, so the residual falls by about the relative change of J per
    iteration (two orders for a 1% pressure change). The returned factor is
    the old one (``factor_current`` False).

    Args:
        x_init: ``(n_span, n_contour, 3)`` start, usually ``previous.x``.
        geometry, params, physics: the new problem.
        previous: a converged `NewtonResult` on the same grid and free dofs.
        rtol: relative residual tolerance.
        max_iterations: cap; the method also stops as soon as an iteration
            fails to halve the residual.

    Returns:
        A converged `NewtonResult`, or None when the chord iteration does not
        converge (the caller then falls back on a full solve).
    """
    if previous is None or previous.factor is None:
        return None
    with float64_scope():
        physics = fk.static_physics(physics)
        ref = _prepare(geometry, params, physics)
        free = free_dofs(ref)
        if not np.array_equal(free, previous.free_dofs):
            return None
        dtype = geometry.contour_root.dtype
        shape = tuple(geometry.free.shape) + (3,)
        x = np.array(x_init, dtype=np.float64).reshape(-1)
        log = _Log()
        last = math.inf
        for iteration in range(max_iterations + 1):
            r, rel = _residual_and_relative(jnp.asarray(x.reshape(shape), dtype), ref, params, physics)
            rel = float(rel)
            log.add(rel, 1.0, 0.0, float(params.pressure))
            if not math.isfinite(rel) or rel > 0.5 * last:
                return None
            if rel <= rtol:
                return NewtonResult(
                    x=jnp.asarray(x.reshape(shape), dtype), result=Result.converged,
                    iterations=iteration, residual=rel, factor=previous.factor,
                    jacobian=previous.jacobian, factor_current=False, shift=previous.shift,
                    free_dofs=free, load_steps=0, message="converged (chord Newton, reused factor)",
                    history=log.arrays())
            last = rel
            x[free] += previous.factor.solve(-np.asarray(r, dtype=np.float64).reshape(-1)[free])
        return None
