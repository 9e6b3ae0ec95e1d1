"""The custom JVP of `solve_equilibrium`: its host solve made differentiable (`differentiable_solution`).

`solve_equilibrium` calls `differentiable_solution` when any of its
`Parameters` is a JAX tracer whose value is concrete (an eager ``jax.grad``,
``jax.jacfwd``, ``jax.jvp`` or ``jax.vjp``). It wraps the solve in a
``jax.custom_jvp`` over the whole `Parameters` pytree, whose primal is the
concrete host solve (relaxation, Newton, warm starts) and whose tangent and
cotangent come from the adjoint value (``adjoint=``): ``adjoint.primal``
solves, ``adjoint.jvp`` differentiates, `implicit.ImplicitAdjoint` by the
implicit rule at the solved state (the one rule of the package, `implicit`)
or `unrolled.UnrolledAdjoint` through the unrolled relaxation (the check).
Under ``jax.jit`` or ``jax.vmap`` the parameters are abstract and
`solve_equilibrium` takes the pure-JAX path of `relax.traced_solution`
instead; the two agree to 1e-10 relative on the 9x32 bay
(tests/derivatives/test_transforms.py).

Tolerance under differentiation. The derivative is exact only at an exact
equilibrium; at a state with residual ``r`` the tangent is wrong by about
``|J^-1| |dJ/dtheta| |J^-1 r|``, i.e. relative error of order the relative
residual. `GRADIENT_RTOL` = 1e-11 (``||R_free|| / (p A)``) keeps that error
several orders below the 1e-5 agreement with finite differences that the
tests demand; with ``method="relax+newton"`` Newton reaches it in one or two
extra iterations and leaves the factor the adjoint reuses.

Everything runs in float64; under the caller's own ``jax.grad`` float64 must
be on already (``with jax.enable_x64(True):``), else a RuntimeError says so.
"""

from __future__ import annotations

import contextlib
import contextvars
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

from ..model.parameters import Parameters
from ..model.scene import Scene
from ..precision import float64_scope
from ..programs import static_forces
from ..solution import Solution
from .implicit import ImplicitAdjoint, top_level
from .unrolled import UnrolledAdjoint

__all__ = ["ADJOINTS", "as_adjoint", "concrete_parameters", "GRADIENT_RTOL",
           "differentiable_solution", "nodes_only", "presolved"]

#: How `solve_equilibrium` is differentiated, by shortcut name.
ADJOINTS = {"implicit": ImplicitAdjoint(), "unrolled": UnrolledAdjoint()}

#: Whether a differentiated solve's tensions are traced too (`nodes_only` turns it off).
_TRACED_TENSIONS = contextvars.ContextVar("traced_tensions", default=True)


def as_adjoint(adjoint):
    """The adjoint value of ``adjoint``: a value as it is, or a shortcut name (`ADJOINTS`).

    Raises:
        ValueError: for an unknown name.
    """
    if isinstance(adjoint, str):
        if adjoint not in ADJOINTS:
            raise ValueError(f"adjoint must be one of {tuple(ADJOINTS)}, got {adjoint!r}")
        return ADJOINTS[adjoint]
    return adjoint


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


#: Host solves done already (`presolved`): ``id(scene) -> (scene, concrete Parameters, Solution)``.
_PRESOLVED = contextvars.ContextVar("presolved", default=None)


@contextlib.contextmanager
def presolved(solutions: dict):
    """Within: a differentiated solve of a scene in ``solutions`` (``id(scene) -> (scene, parameters,
    Solution)``, ``parameters`` concrete) at parameters that pose the same problem takes that
    `Solution` as its host solve instead of solving (`bays.Loop` solves a wing's bays before it
    differentiates them one by one, two at a time where the machine has a second core)."""
    token = _PRESOLVED.set(solutions)
    try:
        yield
    finally:
        _PRESOLVED.reset(token)


#: Relative residual ``||R_free||_2 / (p A)`` of solves whose derivative must
#: be accurate (see the module docstring for why).
GRADIENT_RTOL = 1e-11


def concrete_parameters(parameters: Parameters) -> Parameters:
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
                            adjoint, rtol: float, max_steps: int) -> Solution:
    """The `Solution` at traced ``parameters``, its nodes and tensions differentiable.

    Args:
        scene: the bay, fabric and switches.
        parameters: resolved `Parameters`, some leaves JAX tracers.
        solve: the concrete host solve, ``Parameters -> Solution``.
        adjoint: how the derivative is taken: `implicit.ImplicitAdjoint` (the
            host solve, implicit derivative) or `unrolled.UnrolledAdjoint`
            (``max_steps`` steps of the unrolled relaxation, plain AD).
        rtol: the solve's tolerance (the unrolled result is "converged" when
            its relative residual is below it).
        max_steps: the unrolled run's length.

    Returns:
        The concrete solve's `Solution` with ``nodes``, ``tension_span``,
        ``tension_chord`` replaced by traced values (and its concrete nodes
        in ``extra["primal_nodes"]``, for warm starts).
    """
    found = {}

    def primal_solution(p: Parameters) -> Solution:
        done = (_PRESOLVED.get() or {}).get(id(scene))
        if done is not None and done[0] is scene and p.same_problem(done[1]):
            return done[2]
        # The host solve runs at top level, as a plain call does: under the caller's transformation
        # (jax.jacfwd's batching, jax.grad's linearisation) each compiled program it calls was bound
        # to that trace and compiled again in a transformed (equivalent) form: relaxation, Newton
        # and its forces twice per grid in every design.
        with top_level():
            return adjoint.primal(scene, p, solve, rtol, max_steps)

    @jax.custom_jvp
    def nodes_of(p):
        found["solution"] = primal_solution(concrete_parameters(p))
        return jnp.asarray(found["solution"].nodes, jnp.float64)

    def nodes_jvp(primals, tangents):
        (p,), (dp,) = primals, tangents
        # A parameter nobody differentiates comes as a symbolic zero: NumPy's zero of its type here (JAX
        # would make each an eager operation, for the primal and again under a batch).
        dp = jax.tree_util.tree_map(lambda t: np.zeros(t.aval.shape, t.aval.dtype) if isinstance(t, SymbolicZero)
                                    else t, dp, is_leaf=lambda t: isinstance(t, SymbolicZero))
        concrete = concrete_parameters(p)
        sol = found["solution"] = primal_solution(concrete)
        return adjoint.jvp(scene, p, dp, concrete, sol, max_steps)

    nodes_of.defjvp(nodes_jvp, symbolic_zeros=True)

    with float64_scope(parameters):
        nodes = nodes_of(parameters)
        sol = found["solution"]
        if _TRACED_TENSIONS.get():
            geometry = scene.bay.geometry()
            f = static_forces(nodes, geometry, scene.params(parameters), scene.physics(dynamic=False))
        else:  # `nodes_only`: the concrete solve's
            f = sol
    return sol.replace(nodes=nodes, tension_span=f.tension_span, tension_chord=f.tension_chord,
                       extra={**sol.extra, "primal_nodes": sol.nodes, **adjoint.describe()})
