"""The implicit tangent without a matrix: ``J dx = -dR/dtheta . dtheta`` by preconditioned BiCGStab in JAX.

The host path of `adjoint` factorises the sparse Jacobian with scipy and
reaches it through ``jax.pure_callback``: it needs concrete values and a CPU
backend. This module solves the same linear system with JAX alone, so it
runs under ``jax.jit`` and ``jax.vmap``, on any backend:

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
* the solve is a ``jax.lax.custom_linear_solve``, so reverse mode transposes
  it into the adjoint system ``J^T lambda = xbar``, solved by the same
  BiCGStab on ``J^T v`` (JAX's transpose of the linearised residual) with the
  transposed blocks: one adjoint solve per gradient, as with the LU.

Measured (NACA 2412 bay, 2e5 N/m, 0.5% prestrain, 20 kPa, equilibrium at
rtol 1e-12; x86_64, 2 cores; ``benchmarks/batched_equilibrium.py
--krylov``): matrix-vector products (two per BiCGStab iteration) to a
relative residual ``||J dx - b|| / ||b||`` of 1e-10, for the pressure
tangent's right-hand side: 242 on 9x32, 336 on 17x64, 666 on 17x128
(scalar Jacobi: 364, 744, 1106); for a random one 308, 466, 810 (scalar
376, 804, 1150). `KRYLOV_RTOL` = 1e-10 keeps the linear-solve error far
below the equilibrium's own (`adjoint.GRADIENT_RTOL`); the gradients agree
with the host LU's to about 1e-10 relative on 9x32.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.sparse.linalg import bicgstab

from . import forces as fk

__all__ = ["KRYLOV_RTOL", "KRYLOV_MAX_ITERATIONS", "implicit_tangent", "implicit_nodes",
           "jacobian_operator"]

#: Relative residual ``||J dx - b|| / ||b||`` the BiCGStab solve stops at:
#: well below the equilibrium's own error (`adjoint.GRADIENT_RTOL`) in the tangent.
KRYLOV_RTOL = 1e-10
#: Cap on BiCGStab iterations (two matrix-vector products each); about ten
#: times what 17x128 needs.
KRYLOV_MAX_ITERATIONS = 4000


def _mounted_nodes(x, geometry, params):
    """``x`` on the free nodes, held nodes at the mounted (rib) position of ``params``."""
    mounted = fk.mounted_nodes(geometry, params)
    free = geometry.free[..., None]
    return free * x + (1.0 - free) * mounted


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


@partial(jax.jit, static_argnames=("physics",))
def implicit_tangent(x, geometry: fk.Geometry, params: fk.Params, dparams: fk.Params,
                     physics: fk.Physics) -> jnp.ndarray:
    """``dx*`` for a kernel-parameter tangent ``dparams`` at the equilibrium ``x``.

    ``-J^-1 dR/dtheta . dtheta`` on the free nodes (BiCGStab, see the module
    docstring) plus the motion of the held (rib) nodes, which follow the rib
    scales. ``dR/dtheta`` goes through `forces.prepare` (cut lengths see the
    prestrain) and through the mounted rib nodes.

    Args:
        x: ``(n_span, n_contour, 3)`` equilibrium nodes, m.
        geometry: the bay's `forces.Geometry`.
        params: kernel parameters of the equilibrium.
        dparams: their tangent (same structure).
        physics: static switches.

    Returns:
        ``(n_span, n_contour, 3)`` node tangent, m per unit parameter tangent.
    """
    physics = fk.static_physics(physics)

    def response(p):
        nodes = _mounted_nodes(x, geometry, p)
        return fk.residual(nodes, fk.prepare(geometry, p, physics), p, physics), nodes

    _, (dr, dnodes) = jax.jvp(response, (params,), (dparams,))
    held = 1.0 - geometry.free[..., None]
    matvec, preconditioner, transposed_preconditioner = jacobian_operator(x, geometry, params, physics)

    def solver(precondition):
        def solve(operator, b):
            out, _ = bicgstab(operator, b, tol=KRYLOV_RTOL, atol=0.0, maxiter=KRYLOV_MAX_ITERATIONS,
                              M=precondition)
            return out
        return solve

    dx = jax.lax.custom_linear_solve(matvec, -dr, solve=solver(preconditioner),
                                     transpose_solve=solver(transposed_preconditioner))
    return dx + held * dnodes


@partial(jax.custom_jvp, nondiff_argnums=(0,))
def implicit_nodes(physics: fk.Physics, x, geometry: fk.Geometry, params: fk.Params, converged):
    """The equilibrium ``x`` (returned as is), differentiable in ``params`` by `implicit_tangent`.

    ``x`` must be the equilibrium at ``params`` computed without derivatives
    (under ``jax.lax.stop_gradient``); its own tangent and the geometry's are
    ignored (the geometry is the bay's, a constant). Where ``converged`` is
    False there is no equilibrium and the tangent is NaN (the solve's result
    code says why).
    """
    return x


@implicit_nodes.defjvp
def _implicit_nodes_jvp(physics, primals, tangents):
    x, geometry, params, converged = primals
    dparams = tangents[2]
    dx = implicit_tangent(x, geometry, params, dparams, physics)
    return x, jnp.where(converged, dx, jnp.nan)
