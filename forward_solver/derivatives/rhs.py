"""The right-hand side and the operator of the implicit rule (`implicit`), built here only.

At an equilibrium ``x*`` the implicit function theorem gives the tangent
``dx* = -J^-1 dR/dtheta . dtheta`` (eq. 10-15 residual ``R``, ``J = dR/dx`` on
the free dofs):

* `kernel_tangent`: the kernel parameters' tangent ``dtheta`` of a `Parameters`
  tangent;
* `parameter_rhs`: ``-dR/dtheta . dtheta``, one ``jax.jvp`` of
  `forces.residual` in the kernel parameters, through `forces.prepare` (the
  cut lengths see the prestrain) and through the held (rib) nodes, which move
  with the rib scales and shapes; that motion is the held nodes' tangent,
  returned beside it; `batched_rhs` is it for a batch of tangents, one
  program;
* `jacobian_matvec`: ``J v`` on the full node array with the held dofs mapped
  to themselves (the residual is zero there, so the held part of a solution is
  zero and the held nodes' motion is added after).

Both linear solvers use them: the host LU (`implicit.SparseLU`) and the
matrix-free BiCGStab (`krylov.BiCGStab`).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .. import forces as fk
from ..compilation import stored_jit
from ..model.parameters import PARAMETER_NAMES, Parameters

__all__ = ["kernel_tangent", "parameter_rhs", "batched_rhs", "jacobian_matvec"]


def kernel_tangent(dparameters: Parameters, like: fk.KernelInputs) -> fk.KernelInputs:
    """The kernel-parameter tangent of a `Parameters` tangent (fabric constants do not move).

    An unset tip rib shape follows the root's, so it takes the root's tangent too.
    """
    tangents = {name: getattr(dparameters, name) for name in PARAMETER_NAMES}
    tangents["rib_shape_root"], tangents["rib_shape_tip"] = dparameters.rib_shapes
    tangents["cut_pattern"] = dparameters.cut_pattern
    # Cast to the primal's dtype: a weakly typed tangent (a Python zero) would be another jit
    # signature of the kernels it reaches than a strongly typed one, and recompile them. Zeros
    # are NumPy's, a concrete tangent is cast by NumPy and a tangent already of that type is kept:
    # an eager JAX operation is a program compiled (or fetched from the cache) in every process.
    def tangent(name):
        primal, value = getattr(like, name), tangents.get(name)
        if value is None:
            return np.zeros(np.shape(primal), primal.dtype)
        if isinstance(value, jax.Array) and jax.typeof(value) == jax.typeof(primal).update(weak_type=False):
            return value
        if not isinstance(value, jax.core.Tracer):  # (a concrete tangent, e.g. a zero: cast on the host)
            return np.asarray(value, dtype=primal.dtype)
        return jnp.asarray(value, dtype=primal.dtype)

    return fk.KernelInputs(*(tangent(name) for name in fk.KernelInputs._fields))


@partial(jax.jit, static_argnames=("physics",))
def parameter_rhs(x, geometry: fk.Geometry, params: fk.KernelInputs, dparams: fk.KernelInputs, physics: fk.Physics):
    """``(-dR/dtheta . dtheta, dx_held)`` at the equilibrium ``x``, both ``(n_span, n_contour, 3)``.

    The first is zero on held nodes (the residual is); the second, the
    motion of the held nodes with the rib parameters, is zero on free ones.
    """
    physics = fk.static_physics(physics)
    free = geometry.free[..., None]

    def response(p):  # x on the free nodes, the held ones at the mounted (rib) position of p
        nodes = free * x + (1.0 - free) * fk.mounted_nodes(geometry, p)
        return fk.residual(nodes, fk.prepare(geometry, p, physics), p, physics), nodes

    _, (dr, dnodes) = jax.jvp(response, (params,), (dparams,))
    return -dr, (1.0 - geometry.free[..., None]) * dnodes


@stored_jit(static_argnames=("physics",))
def batched_rhs(x, geometry: fk.Geometry, params: fk.KernelInputs, dparams: fk.KernelInputs, physics: fk.Physics):
    """`parameter_rhs` of a batch of tangents (a leading axis on every leaf of ``dparams``): one
    program, ``jax.vmap(parameter_rhs)``, that a caller holding the batch as arrays calls at top
    level, so that it compiles ahead (`implicit.batched_rhs_task`) and is found in the persistent cache
    without batching a traced program in every process."""
    return jax.vmap(partial(parameter_rhs, physics=physics), in_axes=(None, None, None, 0))(
        x, geometry, params, dparams)


@partial(jax.jit, static_argnames=("physics",))
def jacobian_matvec(x, geometry: fk.Geometry, params: fk.KernelInputs, v, physics: fk.Physics):
    """``J v`` on the free dofs and ``v`` on the held ones (the operator of the linear solve)."""
    physics = fk.static_physics(physics)
    ref = fk.prepare(geometry, params, physics)
    free = ref.free
    return jax.jvp(lambda y: fk.residual(y, ref, params, physics), (x,), (free * v,))[1] + (1.0 - free) * v
