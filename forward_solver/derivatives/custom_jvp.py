"""Derivatives of the equilibrium shape: the custom JVP of `solve_equilibrium`.

Implicit differentiation. At equilibrium the static residual of eq. (10)-(15)
vanishes on the free degrees of freedom, ``R(x*(theta), theta) = 0``, so
(implicit function theorem)::

    dx*/dtheta = -J^-1 dR/dtheta,   J = dR/dx on the free dofs (N/m).

`solve_equilibrium` calls `differentiable_solution` when any of its
`Parameters` is a JAX tracer. That wraps the solve in a ``jax.custom_jvp``
over the whole `Parameters` pytree:

* primal: the concrete host solve (relaxation, Newton, warm starts) at the
  concrete parameter values;
* tangent (forward mode, ``jax.jvp`` / ``jax.jacfwd``) and cotangent
  (reverse mode, ``jax.grad`` / ``jax.vjp``): `implicit.ImplicitAdjoint` at
  the solved state, the one implicit rule of the package (its right-hand
  side ``-dR/dtheta . dtheta`` through `forces.prepare` and the mounted rib
  nodes; one ``jax.lax.custom_linear_solve``, whose transpose is the
  adjoint solve ``J^T lambda = xbar``) with the linear solver
  ``linear_solver``: "lu", the sparse LU of J on the host (the solution's
  own factor, `Solution.factor`, when it was factorised at the returned
  state), or "iterative", the matrix-free BiCGStab of `krylov`.
  `default_linear_solver` picks "lu" on a CPU backend and "iterative"
  elsewhere, since a host callback fails where JAX sees only a GPU
  (``JAX_PLATFORMS=cuda``). One adjoint solve per gradient, whatever the
  number of parameters; the two modes cannot disagree.

Tolerance under differentiation. The derivative is exact only at an exact
equilibrium; at a state with residual ``r`` the tangent is wrong by about
``|J^-1| |dJ/dtheta| |J^-1 r|``, i.e. relative error of order the relative
residual. `GRADIENT_RTOL` = 1e-11 (``||R_free|| / (p A)``) keeps that error
several orders below the 1e-5 agreement with finite differences that the
tests demand; with ``method="relax+newton"`` Newton reaches it in one or two
extra iterations and leaves the factor the adjoint reuses.

Precision: everything runs in float64; under the caller's own ``jax.grad``
float64 must be on already (wrap the call in ``with jax.enable_x64(True):``),
else a RuntimeError says so.

Two paths. This module's primal is host code (scipy, Python control flow),
so it serves eager ``jax.grad``, ``jax.jacfwd``, ``jax.jvp`` and
``jax.vjp``, where the parameters are traced but concrete. Under ``jax.jit``
or ``jax.vmap`` of the parameters they are abstract and `solve_equilibrium`
takes the pure-JAX path of `jit_equilibrium` instead: the relaxation alone, under
``stop_gradient``, its fixed point differentiated by `implicit.implicit_nodes`
(the same implicit rule with the iterative solver). The two agree to 1e-10
relative on the 9x32 bay (tests/derivatives/test_transforms.py). The host methods
(newton, relax+newton, explicit) refuse jit and vmap with a TypeError that
names "relax".

Unrolled differentiation (``adjoint="unrolled"``). `unrolled_equilibrium_nodes`
is a pure JAX dynamic relaxation (the loop of `relax`, kinetic damping,
Gershgorin masses) for a fixed number of steps, as a `lax.scan` of
checkpointed chunks, so plain AD runs through it in memory proportional to
the number of chunks. Its derivative converges to the implicit one as the
iterates converge; it is slow and is meant for checking the implicit rule on
small grids.
"""

from __future__ import annotations

import contextlib
import contextvars
import math
import time
from functools import partial
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from .. import forces as fk
from ..precision import float64_scope
from .implicit import LINEAR_SOLVERS, ImplicitAdjoint, default_linear_solver
from ..solvers.loop import LoopOutput
from ..model.parameters import PARAMETER_NAMES, Parameters
from ..solvers.relax import MASS_SAFETY, kinetic_damping_step
from ..model.scene import Scene
from ..solution import Result, Solution, make_solution, static_forces

#: Runs concrete host work at top level, outside a caller's transformation (see
#: `differentiable_solution`); a JAX without ``jax.core.eval_context`` runs it under the caller's
#: trace: the same result, with the programs compiled twice.
_top_level = getattr(jax.core, "eval_context", contextlib.nullcontext)

__all__ = [
    "ADJOINTS",
    "LINEAR_SOLVERS",
    "default_linear_solver",
    "DIFFERENTIABLE",
    "GRADIENT_RTOL",
    "differentiable_solution",
    "nodes_only",
    "unrolled_equilibrium_nodes",
]

#: How `solve_equilibrium` is differentiated.
ADJOINTS = ("implicit", "unrolled")

#: Parameters the equilibrium can be differentiated in (the `Parameters` fields).
DIFFERENTIABLE = PARAMETER_NAMES

#: Whether a differentiated solve's tensions are traced too (`nodes_only` turns it off).
_TRACED_TENSIONS = contextvars.ContextVar("traced_tensions", default=True)


@contextlib.contextmanager
def nodes_only():
    """Within: a differentiated `solve_equilibrium` traces its nodes alone; its `Solution`'s
    tensions are the concrete solve's (not differentiable).

    For callers that read only the nodes under ``jax.vjp`` / ``jax.jacfwd`` (`wing.solve_bays`, whose
    design loop computes the tensions it constrains from the nodes): the traced tensions cost an
    extra compiled program of the force kernel under each transformation (its JVP, its transpose),
    about a second of XLA compilation on a 2-core machine, for values nobody differentiates.
    """
    token = _TRACED_TENSIONS.set(False)
    try:
        yield
    finally:
        _TRACED_TENSIONS.reset(token)


#: Relative residual ``||R_free||_2 / (p A)`` of solves whose derivative must
#: be accurate (see the module docstring for why).
GRADIENT_RTOL = 1e-11


# ---------------------------------------------------------------- the rule
def _kernel_tangent(dparameters: Parameters, like: fk.KernelInputs) -> fk.KernelInputs:
    """The kernel-parameter tangent of a `Parameters` tangent (fabric constants do not move).

    An unset tip rib shape follows the root's, so it takes the root's tangent too.
    """
    tangents = {name: getattr(dparameters, name) for name in PARAMETER_NAMES}
    tangents["rib_shape_root"], tangents["rib_shape_tip"] = dparameters.rib_shapes
    tangents["cut_pattern"] = dparameters.cut_pattern
    # Cast to the primal's dtype: a weakly typed tangent (a Python zero) would be another jit
    # signature of the kernels it reaches than a strongly typed one, and recompile them. Zeros
    # are NumPy's and a tangent already of that type is kept: an eager JAX operation is a program
    # compiled (or fetched from the cache) in every process.
    def tangent(name):
        primal, value = getattr(like, name), tangents.get(name)
        if value is None:
            return np.zeros(np.shape(primal), primal.dtype)
        if isinstance(value, jax.Array) and jax.typeof(value) == jax.typeof(primal).update(weak_type=False):
            return value
        return jnp.asarray(value, dtype=primal.dtype)

    return fk.KernelInputs(*(tangent(name) for name in fk.KernelInputs._fields))


def _concrete(parameters: Parameters) -> Parameters:
    """Float values of the primal parameters; a clear TypeError under jit or vmap."""
    try:
        return parameters.as_floats()
    except (jax.errors.ConcretizationTypeError, jax.errors.TracerArrayConversionError, TypeError):
        raise TypeError(
            "solve_equilibrium solves on the host, so its parameters must be concrete: "
            "differentiate it with jax.grad / jax.jacfwd / jax.jvp / jax.vjp outside jax.jit and "
            "jax.vmap, or use method='relax', which runs as pure JAX under jit and vmap"
        ) from None


def differentiable_solution(scene: Scene, parameters: Parameters, solve: Callable[[Parameters], Solution],
                            adjoint: str, rtol: float, max_steps: int,
                            linear_solver: str = "lu") -> Solution:
    """The `Solution` at traced ``parameters``, its nodes and tensions differentiable.

    Args:
        scene: the bay, fabric and switches.
        parameters: resolved `Parameters`, some leaves JAX tracers.
        solve: the concrete host solve, ``Parameters -> Solution``.
        adjoint: "implicit" (the host solve, implicit derivative) or
            "unrolled" (``max_steps`` steps of `unrolled_equilibrium_nodes`,
            derivative by plain AD through them).
        rtol: the solve's tolerance (the unrolled result is "converged" when
            its relative residual is below it).
        max_steps: the unrolled run's length.
        linear_solver: "lu" (host sparse LU) or "iterative" (`krylov`): the
            implicit tangent's linear solve.

    Returns:
        The concrete solve's `Solution` with ``nodes``, ``tension_span``,
        ``tension_chord`` replaced by traced values (and its concrete nodes
        in ``extra["primal_nodes"]``, for warm starts).
    """
    found = {}

    def primal_solution(p: Parameters) -> Solution:
        # The host solve runs at top level, as a plain call does: under the caller's transformation
        # (jax.jacfwd's batching, jax.grad's linearisation) each compiled program it calls was bound
        # to that trace and compiled again in a transformed (equivalent) form: relaxation, Newton
        # and its forces twice per grid in every design.
        with _top_level():
            if adjoint == "unrolled":
                return _unrolled_solution(scene, p, rtol, max_steps)
            return solve(p)

    @jax.custom_jvp
    def nodes_of(p):
        found["solution"] = primal_solution(_concrete(p))
        return jnp.asarray(found["solution"].nodes, jnp.float64)

    @nodes_of.defjvp
    def nodes_jvp(primals, tangents):
        (p,), (dp,) = primals, tangents
        concrete = _concrete(p)
        sol = found["solution"] = primal_solution(concrete)
        if adjoint == "unrolled":
            return jax.jvp(partial(unrolled_equilibrium_nodes, scene, n_steps=max_steps), (p,), (dp,))
        if not sol.converged:
            # No equilibrium, no implicit derivative: the caller sees the failure (throw) or
            # gets the failed solution, whose tangent is undefined.
            nan = jnp.full(sol.nodes.shape, jnp.nan)
            return jnp.asarray(sol.nodes), nan
        with _top_level():  # concrete: the LU (a fresh one after chord Newton) as a plain call
            params = scene.params(concrete)
            x = jnp.asarray(sol.nodes)
            geometry = scene.bay.geometry()
            implicit = ImplicitAdjoint(x, geometry, params, scene.physics(dynamic=False), linear_solver,
                                       factor=sol.factor)
        return x, implicit.tangent(_kernel_tangent(dp, params))

    with float64_scope(parameters):
        nodes = nodes_of(parameters)
        sol = found["solution"]
        if _TRACED_TENSIONS.get():
            geometry = scene.bay.geometry()
            f = static_forces(nodes, geometry, scene.params(parameters), scene.physics(dynamic=False))
        else:  # `nodes_only`: the concrete solve's
            f = sol
    return Solution(nodes=nodes, tension_span=f.tension_span, tension_chord=f.tension_chord,
                    wrinkled=sol.wrinkled, result=sol.result, steps=sol.steps, residual=sol.residual,
                    wall_time=sol.wall_time, method=sol.method, parameters=sol.parameters,
                    rib_spacing=sol.rib_spacing, history=sol.history,
                    extra={**sol.extra, "primal_nodes": sol.nodes, "adjoint": adjoint,
                           "linear_solver": linear_solver},
                    detail=sol.detail, factor=sol.factor)


def _unrolled_solution(scene: Scene, parameters: Parameters, rtol: float, steps: int) -> Solution:
    """A `Solution` from ``steps`` steps of `unrolled_equilibrium_nodes` (concrete parameters)."""
    start = time.perf_counter()
    with float64_scope():
        params = scene.params(parameters)
        geometry = scene.bay.geometry()
        physics = scene.physics(dynamic=False)
        nodes = unrolled_equilibrium_nodes(scene, parameters, n_steps=steps)
        f = static_forces(nodes, geometry, params, physics)
        ref = fk.prepare(geometry, params, fk.static_physics(physics))
        rel = float(fk.relative_residual(nodes, ref, params, fk.static_physics(physics)))
    code = Result.converged if rel <= rtol else (Result.nonfinite if not math.isfinite(rel)
                                                 else Result.max_steps_reached)
    out = LoopOutput(None, int(code), 0, rel, None)
    return make_solution(out, f, steps, time.perf_counter() - start, "unrolled", parameters, scene.bay,
                         nodes=nodes, extra={"precision": "float64"})


# ----------------------------------------------------------------- unrolled
def unrolled_equilibrium_nodes(scene: Scene, parameters: Parameters, *, n_steps: int = 20_000,
                               chunk: int = 100) -> jnp.ndarray:
    """Equilibrium nodes by ``n_steps`` of dynamic relaxation, differentiable by plain JAX AD.

    The loop of `relax` (fictitious Gershgorin masses re-estimated every
    chunk, kinetic damping) from the mounted shape, on the full grid, for a
    fixed number of steps: a ``lax.scan`` over chunks, each chunk a
    ``jax.checkpoint``-ed ``lax.scan`` of ``chunk`` steps, so reverse mode
    stores one state per chunk. The masses are a preconditioner (they do not
    change the fixed point) and are held constant under differentiation
    (``stop_gradient``). Traceable: use it under ``jax.grad`` or ``jax.jit``
    (in float64).

    Meant for checking the implicit derivative on small grids (it is what
    ``solve_equilibrium(..., adjoint="unrolled")`` runs): it is exact for the
    iterate it returns, so it agrees with the implicit derivative once the
    iterates (and their tangents) have converged.

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
