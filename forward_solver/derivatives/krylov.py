"""The implicit tangent without a matrix: ``J dx = -dR/dtheta . dtheta`` by preconditioned BiCGStab in JAX.

`BiCGStab`, the "iterative" linear solver of `implicit`, solves the system of
the host LU (`implicit.SparseLU`) with JAX alone, so it runs under ``jax.jit``
and ``jax.vmap``, on any backend:

* the operator is matrix-free: ``J v`` is one ``jax.jvp`` of
  `forces.residual` (eq. 10-15) at the equilibrium ``x*``, on the full node
  array with the held degrees of freedom mapped to themselves (identity
  rows), so no index gathering is needed and the operator stays
  non-singular;
* ``J`` is not symmetric (follower pressure, eq. 15; tension clamping), so
  the Krylov method is BiCGStab (`jax.scipy.sparse.linalg.bicgstab`), not
  conjugate gradients. Restarted GMRES (restart 100) needed 1.2-1.9 times
  as many matrix-vector products and several times the run time (its
  orthogonalisation) on the grids below;
* the preconditioner is block Jacobi: the exact 3x3 diagonal block of
  ``J`` at every node, from 12 (at most 18) JVPs with the nodes coloured
  ``(i mod 2, j mod 2)`` (no two nodes of a colour are neighbours, so each
  JVP returns the diagonal blocks of its colour unmixed). It captures the
  anisotropy the scalar Gershgorin bound (`forces.node_stiffness`, the
  relaxation's masses) cannot: a membrane node is E/h stiff in its plane and
  only about T/h across it. Measured, the scalar Jacobi preconditioner
  needed 1.2-1.7 times as many products;
* the adjoint system ``J^T lambda = xbar`` (the transpose of the
  ``jax.lax.custom_linear_solve``) is solved by the same BiCGStab on ``J^T
  v`` (JAX's transpose of the linearised residual) with the transposed blocks.

Measured (NACA 2412 bay, 2e5 N/m, 0.5% prestrain, 20 kPa, equilibrium at
rtol 1e-12; x86_64, 2 cores; ``benchmarks/batched_equilibrium.py
--krylov``): matrix-vector products (two per BiCGStab iteration) to a
relative residual ``||J dx - b|| / ||b||`` of 1e-10, for the pressure
tangent's right-hand side: 242 on 9x32, 336 on 17x64, 666 on 17x128
(scalar Jacobi: 364, 744, 1106); for a random one 308, 466, 810 (scalar
376, 804, 1150). `KRYLOV_RTOL` = 1e-10 keeps the linear-solve error far
below the equilibrium's own (`custom_jvp.GRADIENT_RTOL`); the gradients agree
with the host LU's to about 1e-10 relative on 9x32.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.sparse.linalg import bicgstab

from .. import forces as fk
from .rhs import parameter_rhs

__all__ = ["KRYLOV_RTOL", "KRYLOV_MAX_ITERATIONS", "BiCGStab", "jacobian_operator"]

#: Relative residual ``||J dx - b|| / ||b||`` the BiCGStab solve stops at:
#: well below the equilibrium's own error (`custom_jvp.GRADIENT_RTOL`) in the tangent.
KRYLOV_RTOL = 1e-10
#: Cap on BiCGStab iterations (two matrix-vector products each); about ten
#: times what 17x128 needs.
KRYLOV_MAX_ITERATIONS = 4000


def _node_colours(shape, periodic: bool) -> np.ndarray:
    """``(n_span, n_contour)`` colours with no two neighbouring nodes alike (3x3 sense)."""
    ns, nc = shape
    j = np.arange(nc)
    contour = j % 2
    if periodic and nc % 2:
        contour = np.where(j == nc - 1, 2, contour)  # node nc-1 touches node 0 across the wrap
    return (np.arange(ns)[:, None] % 2) * 3 + contour[None, :]


def _diagonal_blocks(matvec, shape, periodic: bool) -> jnp.ndarray:
    """``(n_span, n_contour, 3, 3)`` diagonal blocks of the operator (row, column), by coloured JVPs."""
    colours = _node_colours(shape, periodic)
    used = np.unique(colours)
    node_mask = np.stack([colours == k for k in used]).astype(np.float64)  # (k, ns, nc)
    seeds = node_mask[:, None, :, :, None] * np.eye(3)[None, :, None, None, :]  # (k, c, ns, nc, 3)
    seeds = jnp.asarray(seeds.reshape((-1,) + tuple(shape) + (3,)))
    columns = jax.vmap(matvec)(seeds).reshape((len(used), 3) + tuple(shape) + (3,))
    return jnp.einsum("kcnmr,knm->nmrc", columns, jnp.asarray(node_mask, columns.dtype))


def jacobian_operator(x, geometry, params, physics):
    """``(matvec, preconditioner, transposed_preconditioner)`` of ``J = dR/dx`` at ``x``.

    ``matvec(v)`` is ``J v`` (N/m times m) on the free degrees of freedom and
    ``v`` itself on the held ones; ``preconditioner`` applies the inverse of
    its 3x3 diagonal blocks (block Jacobi), ``transposed_preconditioner`` that
    of ``J^T``'s. All act on ``(n_span, n_contour, 3)`` arrays.
    """
    physics = fk.static_physics(physics)
    ref = fk.prepare(geometry, params, physics)
    free = ref.free
    _, linear = jax.linearize(lambda y: fk.residual(y, ref, params, physics), x)

    def matvec(v):
        return linear(free * v) + (1.0 - free) * v

    inverse = jnp.linalg.inv(_diagonal_blocks(matvec, x.shape[:2], physics.periodic))

    def preconditioner(v):
        return jnp.einsum("nmrc,nmc->nmr", inverse, v)

    def transposed_preconditioner(v):
        return jnp.einsum("nmcr,nmc->nmr", inverse, v)

    return matvec, preconditioner, transposed_preconditioner


@dataclass(frozen=True)
class BiCGStab:
    """The implicit tangent's linear solver without a matrix: block-Jacobi BiCGStab in JAX (module docstring).

    The shortcut ``linear_solver="iterative"`` names the default value.

    Args:
        rtol: relative residual ``||J dx - b|| / ||b||`` to stop at.
        max_iterations: cap on iterations (two matrix-vector products each).
    """

    rtol: float = KRYLOV_RTOL
    max_iterations: int = KRYLOV_MAX_ITERATIONS
    name: ClassVar[str] = "iterative"

    def bind(self, x, geometry, params, physics, factor=None) -> "BiCGStab":
        """The solver at one equilibrium: itself (it keeps nothing per equilibrium; ``factor`` is the LU's)."""
        del x, geometry, params, physics, factor
        return self

    def check_traceable(self, where: str) -> None:
        """Nothing to refuse: it runs under ``jax.jit`` and ``jax.vmap`` (`implicit.SparseLU` cannot)."""

    def tangent(self, x, geometry, params, dparams, physics):
        """``dx*`` at the equilibrium ``x`` for a kernel-parameter tangent: the right-hand side
        (`rhs.parameter_rhs`), the transposable solve, the held nodes' motion."""
        b, dheld = parameter_rhs(x, geometry, params, dparams, physics)
        return _krylov_solve(x, geometry, params, b, dheld, fk.static_physics(physics), self)


@partial(jax.jit, static_argnames=("physics", "solver"))
def _krylov_solve(x, geometry, params, b, dheld, physics, solver: BiCGStab):
    """``J^-1 b + dheld`` by BiCGStab, transposable (the held nodes' motion added in the program: an
    eager addition was one more compilation in a fresh process)."""
    matvec, preconditioner, transposed_preconditioner = jacobian_operator(x, geometry, params, physics)

    def solve_with(precondition):
        def solve(operator, r):
            out, _ = bicgstab(operator, r, tol=solver.rtol, atol=0.0, maxiter=solver.max_iterations,
                              M=precondition)
            return out
        return solve

    return jax.lax.custom_linear_solve(matvec, b, solve=solve_with(preconditioner),
                                       transpose_solve=solve_with(transposed_preconditioner)) + dheld

