"""Forward-mode derivatives along a basis of tangents: the one per-bay (and per-wing) Jacobian of the design.

A function of a parameter vector whose outputs go through the equilibrium
(`forward_solver.solve_equilibrium`, `forward_solver.solve_bays`: the
implicit derivative of eq. 10-15 at rest) is pushed forward along every
tangent of a basis at once (``jax.vmap`` of ``jax.jvp``) within
`forward_solver.derivatives.implicit.forward_only`: the host LU back-solves the
whole batch of tangents as one array, and no transposable program is traced.
The design problem (its compressed seeds, `inverse_design.methods.blocks`) and
the tolerance model (one column per tolerance parameter touching a bay) both
take their Jacobian from `value_and_jacobian`.
"""

from __future__ import annotations

import jax
import numpy as np

from .implicit import forward_only

__all__ = ["value_and_jacobian"]


def value_and_jacobian(function, x, basis=None):
    """``function(x)``'s value, its derivatives along ``basis`` and its auxiliary output.

    ``jax.jacfwd`` less its bookkeeping: the basis is NumPy's and the Jacobian is transposed on the
    host (``jax.jacfwd`` built and unravelled them with a dozen eager operations, each compiled on
    its own in a fresh process).

    Args:
        function: ``x -> (y, aux)``, differentiable in ``x`` (eagerly: the implicit derivative of a
            solve calls back to the host); ``y`` a vector.
        x: ``(n,)`` the point (a JAX array).
        basis: ``(n_tangents, n)`` the tangents (None: the identity, the whole Jacobian).

    Returns:
        ``(y, jacobian, aux)``: the value (a JAX array), ``(y.size, n_tangents)`` derivatives along the
        tangents (NumPy) and the auxiliary output at ``x``.
    """
    basis = np.eye(x.size, dtype=np.float64) if basis is None else np.asarray(basis, np.float64)

    def push(t):
        return jax.jvp(function, (x,), (t,), has_aux=True)

    with forward_only(basis.shape[0]):
        y, dy, aux = jax.vmap(push, out_axes=(None, 0, None))(basis)
    return y, np.asarray(dy).T, aux
