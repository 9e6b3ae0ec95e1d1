"""Unrolled differentiation, the check of the implicit rule: `UnrolledAdjoint` (``adjoint="unrolled"``).

`unrolled_equilibrium_nodes` is a pure JAX dynamic relaxation (the loop of
`relax`: kinetic damping, Gershgorin masses) for a fixed number of steps, as
a `lax.scan` of checkpointed chunks, so plain AD runs through it in memory
proportional to the number of chunks. Its derivative converges to the
implicit one (`implicit.ImplicitAdjoint`) as the iterates converge; it is slow
and is meant for checking the implicit rule on small grids.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from functools import partial
from typing import ClassVar

import jax
import jax.numpy as jnp

from .. import forces as fk
from ..model.parameters import Parameters
from ..model.scene import Scene
from ..precision import float64_scope
from ..programs import static_forces
from ..solution import Result, Solution, Stop, make_solution
from ..solvers.relax import MASS_SAFETY, kinetic_damping_step

__all__ = ["UnrolledAdjoint", "unrolled_equilibrium_nodes"]


@dataclass(frozen=True)
class UnrolledAdjoint:
    """Derivatives by plain AD through ``max_steps`` steps of `unrolled_equilibrium_nodes`.

    The primal solve is that same unrolled relaxation (its `Solution`'s
    method is "unrolled"; "converged" when its relative residual is below
    ``rtol``). Eager only: it refuses ``jax.jit`` and ``jax.vmap``.

    Args:
        chunk: steps per checkpointed chunk (reverse mode stores one state per chunk).
    """

    chunk: int = 100
    name: ClassVar[str] = "unrolled"

    def prepared(self, scene: Scene, parameters: Parameters, solution: Solution) -> Solution:
        """``solution`` as it is (the unrolled derivative takes nothing from a host solve)."""
        del scene, parameters
        return solution

    def primal(self, scene: Scene, parameters: Parameters, solve, rtol: float, max_steps: int) -> Solution:
        """The unrolled relaxation's `Solution` (``solve``, the host solve, is not used)."""
        del solve
        start = time.perf_counter()
        with float64_scope():
            params = scene.params(parameters)
            geometry = scene.bay.geometry()
            physics = scene.physics(dynamic=False)
            nodes = unrolled_equilibrium_nodes(scene, parameters, n_steps=max_steps, chunk=self.chunk)
            f = static_forces(nodes, geometry, params, physics)
            ref = fk.prepare(geometry, params, fk.static_physics(physics))
            rel = float(fk.relative_residual(nodes, ref, params, fk.static_physics(physics)))
        code = Result.converged if rel <= rtol else (Result.nonfinite if not math.isfinite(rel)
                                                     else Result.max_steps_reached)
        return make_solution(Stop(int(code), rel), f, nodes, max_steps, time.perf_counter() - start, "unrolled",
                             parameters, scene.bay, extra={"precision": "float64"})

    def jvp(self, scene: Scene, parameters, dparameters, concrete, solution, max_steps: int):
        """``(nodes, tangent)`` by ``jax.jvp`` through the unrolled relaxation."""
        del concrete, solution
        return jax.jvp(partial(unrolled_equilibrium_nodes, scene, n_steps=max_steps, chunk=self.chunk),
                       (parameters,), (dparameters,))

    def traced_solver(self, where: str):
        """Refuse ``jax.jit`` / ``jax.vmap``: this is an eager check."""
        raise TypeError(f"adjoint='unrolled' is for eager checks; {where} use adjoint='implicit'")

    def describe(self) -> dict:
        """The `Solution.extra` entries of a derivative taken this way."""
        return {"adjoint": self.name}


def unrolled_equilibrium_nodes(scene: Scene, parameters: Parameters, *, n_steps: int = 20_000,
                               chunk: int = 100) -> jnp.ndarray:
    """Equilibrium nodes by ``n_steps`` of dynamic relaxation, differentiable by plain JAX AD.

    From the mounted shape, on the full grid: a ``lax.scan`` over chunks,
    each a ``jax.checkpoint``-ed ``lax.scan`` of ``chunk`` steps (module
    docstring). The masses, re-estimated every chunk, are a preconditioner
    (they do not change the fixed point) and are held constant under
    differentiation (``stop_gradient``). Traceable: use it under ``jax.grad``
    or ``jax.jit`` (in float64). Its derivative is exact for the iterate it
    returns.

    Args:
        scene: the bay, fabric and physics switches.
        parameters: resolved `Parameters` (JAX values allowed).
        n_steps: relaxation steps (rounded up to whole chunks).
        chunk: steps per checkpointed chunk.

    Returns:
        ``(n_span, n_contour, 3)`` nodes in m.
    """
    with float64_scope(parameters):
        params = scene.params(parameters.resolved(scene.fabric))
        geometry = scene.bay.geometry()
        physics = fk.static_physics(scene.physics(dynamic=False))
        n_chunks = max(1, -(-int(n_steps) // int(chunk)))
        return _unrolled(geometry, params, physics, n_chunks, int(chunk))


@partial(jax.jit, static_argnames=("physics", "n_chunks", "chunk"))
def _unrolled(geometry, params, physics, n_chunks, chunk):
    ref = fk.prepare(geometry, params, physics)

    def step(state, _):
        x, v, kinetic, mass = state
        force = fk.residual(x, ref, params, physics)
        return (*kinetic_damping_step(x, v, kinetic, mass, force), mass), None

    @jax.checkpoint
    def run_chunk(state, _):
        x, v, _, _ = state
        mass = jax.lax.stop_gradient(0.5 * MASS_SAFETY * fk.node_stiffness(x, ref, params, physics))[..., None]
        kinetic = jax.lax.stop_gradient(0.5 * jnp.sum(mass * v * v))
        state, _ = jax.lax.scan(step, (x, v, kinetic, mass), None, length=chunk)
        return state, None

    x0 = ref.nodes
    zero = jnp.zeros((), x0.dtype)
    state = (x0, jnp.zeros_like(x0), zero, jnp.ones(x0.shape[:2] + (1,), x0.dtype))
    state, _ = jax.lax.scan(run_chunk, state, None, length=n_chunks)
    return state[0]
