"""`solve_equilibrium` under ``jax.jit`` and ``jax.vmap``: the relaxation as one pure-JAX program.

When the `Parameters` reach `solve_equilibrium` as abstract tracers (inside
``jax.jit``, or batched by ``jax.vmap``), their values cannot steer host
code, so the solve is the relaxation loop of `relax` alone, with nothing
decided in Python from values:

* from the mounted shape (or the ``initial`` nodes), full or half grid as
  the eager path chooses it (static), no grid sequencing (its fallback when
  a coarse level fails is a host decision), at most ``max_steps`` steps;
* the result code, steps and residual come back as arrays in the `Solution`
  (leaves of its pytree), so a failure is reported, never raised: the caller
  passes ``throw=False`` and checks ``solution.result`` / ``converged``
  (after the compiled call, `Solution.raise_if_failed` raises for the batch);
* derivatives by the implicit function theorem with the matrix-free
  BiCGStab of `krylov` (`implicit.implicit_nodes`): the relaxation runs under
  ``stop_gradient`` and only its fixed point carries a tangent, so
  ``jax.grad``, ``jax.jacfwd`` and ``jax.vmap`` of either compose with
  ``jax.jit``.

Under ``jax.vmap`` the relaxation's ``while_loop`` runs until every member
of the batch has stopped (members that stopped are frozen by JAX's batching
rule), so a batch costs its slowest member's step count.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .. import forces as fk
from ..precision import float64_scope
from ..derivatives.implicit import implicit_nodes
from ..model.parameters import Parameters
from .relax import MASS_SAFETY, relax_jit
from ..model.scene import Scene
from ..solution import Result, Solution, initial_nodes, static_forces

__all__ = ["has_abstract_values", "relaxed_nodes", "traced_solution"]

try:  # public home of the check since JAX 0.4.36; jax.core's copy is deprecated
    from jax.extend.core import concrete_or_error as _concrete_or_error
except ImportError:  # pragma: no cover - older JAX
    from jax.core import concrete_or_error as _concrete_or_error


def _is_abstract(value) -> bool:
    if not isinstance(value, jax.core.Tracer):
        return False
    try:
        _concrete_or_error(None, value)
    except jax.errors.ConcretizationTypeError:
        return True
    return False


def has_abstract_values(parameters: Parameters) -> bool:
    """Whether some value is an abstract tracer (``jax.jit``, ``jax.vmap``), not merely traced.

    An eager ``jax.grad`` or ``jax.jvp`` traces its inputs but keeps their
    values concrete; the host solve can run there. Under ``jax.jit`` or
    ``jax.vmap`` it cannot.
    """
    return any(_is_abstract(v) for v in jax.tree_util.tree_leaves(parameters))


def relaxed_nodes(x_init, geometry, params, rtol, bound, physics, chunk: int, max_chunks: int,
                  half: bool):
    """The relaxation from ``x_init`` as pure JAX, its fixed point differentiable in ``params``.

    The loop runs on ``stop_gradient`` values; only its fixed point carries a
    tangent, by the implicit function theorem (`implicit.implicit_nodes`; NaN
    where the loop did not converge). Vmappable over ``geometry`` and
    ``bound`` too (`wing.solve_wing`).

    Returns:
        ``(nodes, out)``: the nodes and the loop's `loop.LoopOutput`.
    """
    fixed = jax.lax.stop_gradient(params)
    out, _, x_star = relax_jit(jax.lax.stop_gradient(x_init), geometry, fixed, rtol, bound, MASS_SAFETY,
                               physics, chunk, max_chunks, half=half, with_forces=False)
    return implicit_nodes(physics, x_star, geometry, params, out.result == Result.converged), out


def traced_solution(scene: Scene, parameters: Parameters, *, rtol: float, initial, half: bool,
                    chunk: int, max_chunks: int) -> Solution:
    """The relaxation's `Solution` at abstract ``parameters`` (see the module docstring).

    Args:
        scene: the bay, fabric and switches.
        parameters: resolved `Parameters` (abstract tracers allowed).
        rtol: relative residual ``||R_free|| / (p A)`` to stop at.
        initial: None, a `Solution` or nodes on this grid (a warm start; not
            differentiated).
        half: solve half the bay (static; see `relax`).
        chunk: steps per chunk of the loop.
        max_chunks: chunk cap (``max_steps`` rounded up to chunks).

    Returns:
        A `Solution` whose ``result``, ``steps``, ``residual`` and
        ``parameters`` are arrays; ``nodes`` and the tensions differentiable
        in ``parameters``.
    """
    bay = scene.bay
    physics = fk.static_physics(scene.physics(dynamic=False))
    with float64_scope(parameters):
        params = scene.params(parameters)
        geometry = bay.geometry()
        x_init = initial_nodes(initial, geometry, jax.lax.stop_gradient(params))
        bound = jnp.asarray(bay.chord + bay.rib_spacing, jnp.float64)
        nodes, out = relaxed_nodes(x_init, geometry, params, jnp.asarray(rtol, jnp.float64), bound,
                                   physics, chunk, max_chunks, half)
        f = static_forces(nodes, geometry, params, physics)
    return Solution(nodes=nodes, tension_span=f.tension_span, tension_chord=f.tension_chord,
                    wrinkled=f.wrinkled, result=out.result, steps=out.chunks * chunk,
                    residual=out.residual, wall_time=None, method="relax", parameters=parameters,
                    rib_spacing=bay.rib_spacing, history=None,
                    extra={"precision": "float64", "half_bay": half, "levels": [], "traced": True,
                           "linear_solver": "iterative"})
