"""Derivatives of the equilibrium shape (DESIGN section 5).

Implicit differentiation. At equilibrium the static residual vanishes on the
free degrees of freedom, ``R(x*(theta), theta) = 0``, so (implicit function
theorem)::

    dx*/dtheta = -J^-1 dR/dtheta,   J = dR/dx on the free dofs (N/m).

`Equilibrium` wraps `solve_equilibrium` in a `jax.custom_jvp`:

* primal: the concrete host solve (``method="relax+newton"``, tolerance
  `GRADIENT_RTOL`), warm-started from the previous call's equilibrium;
* tangent (forward mode, ``jax.jvp`` / ``jax.jacfwd``): ``dR/dtheta . dtheta``
  is one ``jax.jvp`` of `forces.residual` (through `forces.prepare`, so the
  cut lengths see the prestrain, and through the mounted rib nodes, which
  move with the rib geometry parameters), then ``dx = -J^-1 (...)`` with the
  sparse LU of J: Newton's own factor when it was factorised at the returned
  state (``NewtonResult.factor_current``), else a fresh one from
  `newton.assemble_jacobian`;
* cotangent (reverse mode, ``jax.grad`` / ``jax.vjp``): JAX transposes the
  tangent rule. The linear solve is a `jax.lax.custom_linear_solve` whose
  transpose solves the adjoint system ``J^T lambda = xbar`` with the same
  factor (``factor.solve(b, trans="T")``), and the transpose of the
  ``jax.jvp`` above is ``thetabar = -(dR/dtheta)^T lambda``. This is the
  custom VJP of the issue, derived from the JVP rule instead of written
  twice, so the two modes cannot disagree.

Tolerance under differentiation. The derivative is exact only at an exact
equilibrium; at a state with residual ``r`` the tangent is wrong by about
``|J^-1| |dJ/dtheta| |J^-1 r|``, i.e. relative error of order the relative
residual. `GRADIENT_RTOL` = 1e-11 (``||R_free|| / (p A)``, the residual force
over the total pressure load) keeps that error several orders below the
1e-5 agreement with finite differences that the tests demand; Newton reaches
it in one or two extra iterations, so it costs little.

Precision: everything runs in float64. A concrete call enters
``jax.enable_x64`` itself (`scene.float64_scope`); under the caller's own
``jax.grad`` / ``jax.jacfwd`` float64 must be on already (wrap the call in
``with jax.enable_x64(True):``), else a RuntimeError says so.

Limits: the primal is host code (scipy, Python control flow), so the
parameters must be concrete when the solve runs: use ``jax.grad``,
``jax.jacfwd``, ``jax.jvp`` and ``jax.vjp`` eagerly, not under ``jax.jit``
or ``jax.vmap`` of the parameters (a clear TypeError says so).

Unrolled differentiation. `unrolled_equilibrium_nodes` is a pure JAX
dynamic relaxation (the loop of `relax`, kinetic damping, Gershgorin masses)
for a fixed number of steps, as a `lax.scan` of checkpointed chunks, so plain
reverse-mode AD runs through it in memory proportional to the number of
chunks. Its derivative converges to the implicit one as the iterates
converge; it is slow and is meant for checking `Equilibrium` on small grids.
"""

from __future__ import annotations

import math
from functools import partial
from typing import Mapping

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse.linalg as spla

from . import forces as fk
from .newton import PERMC_SPEC, assemble_jacobian, free_dofs
from .relax import MASS_SAFETY, kinetic_damping_step
from .scene import Scene, float64_scope
from .solution import Solution
from .solve import solve_equilibrium

__all__ = [
    "DIFFERENTIABLE",
    "GRADIENT_RTOL",
    "Equilibrium",
    "equilibrium_nodes",
    "unrolled_equilibrium_nodes",
]

#: Parameters the equilibrium can be differentiated in (names of `forces.Params` fields).
DIFFERENTIABLE = (
    "pressure",
    "prestrain_span",
    "prestrain_chord",
    "stiffness_span",
    "stiffness_chord",
    "rib_thickness_scale",
    "rib_chord_scale",
)

#: Relative residual ``||R_free||_2 / (p A)`` of the solves under
#: differentiation (see the module docstring for why).
GRADIENT_RTOL = 1e-11


def _defaults(scene: Scene) -> dict:
    fab = scene.fabric
    return {
        "prestrain_span": 0.0,
        "prestrain_chord": 0.0,
        "stiffness_span": fab.stiffness_span,
        "stiffness_chord": fab.stiffness_chord,
        "rib_thickness_scale": 1.0,
        "rib_chord_scale": 1.0,
    }


def _check_names(names) -> None:
    for name in names:
        if name not in DIFFERENTIABLE:
            raise ValueError(
                f"unknown parameter {name!r}: the equilibrium is differentiable in {DIFFERENTIABLE}"
            )


def _is_traced(value) -> bool:
    return isinstance(value, jax.core.Tracer)


# ------------------------------------------------------------ linearisation
def _full_nodes(x_free_full, geometry, params):
    """Free nodes from ``x_free_full``, held nodes at the mounted (rib) position of ``params``."""
    mounted = fk.nominal_nodes(geometry, params.rib_thickness_scale, params.rib_chord_scale)
    free = geometry.free[..., None]
    return free * x_free_full + (1.0 - free) * mounted


@partial(jax.jit, static_argnames=("physics",))
def _parameter_tangent(x, geometry, params, dparams, free, physics):
    """``(-dR_free/dtheta . dtheta, dx_held)`` at fixed free nodes.

    ``dR/dtheta`` includes the change of the cut lengths and areas
    (`forces.prepare`) and the pull of the held rib nodes, which move with
    the rib geometry parameters; ``dx_held`` is that motion (full grid, zero
    on free nodes).
    """

    def response(p):
        nodes = _full_nodes(x, geometry, p)
        ref = fk.prepare(geometry, p, physics)
        return fk.residual(nodes, ref, p, physics), nodes

    _, (dr, dnodes) = jax.jvp(response, (params,), (dparams,))
    held = 1.0 - geometry.free[..., None]
    return -dr.reshape(-1)[free], held * dnodes


@partial(jax.jit, static_argnames=("physics",))
def _state_tangent(x, geometry, params, dx_free, free, physics):
    """``J dx`` on the free dofs: the matvec of the linear solve (used for its transpose)."""
    ref = fk.prepare(geometry, params, physics)
    dx = _scatter(dx_free, free, x.shape)
    return jax.jvp(lambda y: fk.residual(y, ref, params, physics), (x,), (dx,))[1].reshape(-1)[free]


def _scatter(v_free, free, shape):
    full = jnp.zeros(math.prod(shape), v_free.dtype).at[free].set(v_free, unique_indices=True)
    return full.reshape(shape)


@partial(jax.jit, static_argnames=("shape",))
def _assemble_tangent(dx_free, dheld, free, shape):
    return _scatter(dx_free, free, shape) + dheld


_prepare = jax.jit(fk.prepare, static_argnames=("physics",))


def _float64_on_this_thread() -> None:
    """Let a host callback return float64 when XLA runs it on one of its own threads.

    `float64_scope` turns float64 on for the calling thread only. XLA may run a
    ``jax.pure_callback`` on a worker thread of its own, where JAX then
    canonicalises the callback's float64 result to float32 and rejects it
    ("Incorrect output dtype"). On such a thread (float64 off) this turns
    float64 on for that thread, for good: it runs nothing but callbacks. The
    caller's thread is inside its float64 scope already and is left alone.
    """
    if not jax.config.jax_enable_x64:
        jax.enable_x64(True).__enter__()


class _Linearisation:
    """What the tangent rule needs at one equilibrium: state, parameters and the LU of J."""

    def __init__(self, scene: Scene, solution: Solution, params: fk.Params):
        physics = fk.static_physics(scene.physics(dynamic=False))
        geometry = jax.tree_util.tree_map(jnp.asarray, scene.bay.geometry())
        x = jnp.asarray(solution.nodes)
        newton_result = solution.extra.get("newton")
        if newton_result is not None and newton_result.factor_current and newton_result.factor is not None:
            factor, free = newton_result.factor, np.asarray(newton_result.free_dofs)
            self.reused_factor = True
        else:
            ref = _prepare(geometry, params, physics)
            factor = spla.splu(assemble_jacobian(x, ref, params, physics), permc_spec=PERMC_SPEC)
            free = free_dofs(ref)
            self.reused_factor = False
        self.factor = factor
        self.free = jnp.asarray(free)
        self.x = x
        self.geometry = geometry
        self.params = params
        self.physics = physics

    # Host solves with the LU; ``b`` may carry leading batch axes (jax.vmap, jacfwd).
    def _host_solve(self, b, trans):
        _float64_on_this_thread()
        b = np.asarray(b, dtype=np.float64)
        flat = b.reshape(-1, b.shape[-1]).T
        out = self.factor.solve(np.ascontiguousarray(flat), trans=trans)
        return out.T.reshape(b.shape)

    def _solve(self, b, transpose: bool):
        trans = "T" if transpose else "N"
        shape = jax.ShapeDtypeStruct(b.shape, jnp.float64)
        return jax.pure_callback(partial(self._host_solve, trans=trans), shape, b,
                                 vmap_method="expand_dims")

    def tangent(self, dparams: fk.Params):
        """``dx*`` for a parameter tangent: ``-J^-1 dR/dtheta . dtheta`` plus the held nodes' motion."""
        rhs, dheld = _parameter_tangent(self.x, self.geometry, self.params, dparams, self.free,
                                        self.physics)

        def matvec(v):
            return _state_tangent(self.x, self.geometry, self.params, v, self.free, self.physics)

        dx_free = jax.lax.custom_linear_solve(
            matvec, rhs,
            solve=lambda _, b: self._solve(b, transpose=False),
            transpose_solve=lambda _, b: self._solve(b, transpose=True),
        )
        return _assemble_tangent(dx_free, dheld, self.free, tuple(self.x.shape))


# ---------------------------------------------------------------- the map
class Equilibrium:
    """Differentiable map from design parameters to the equilibrium nodes of one scene.

    Calling it solves the equilibrium on the host (``solve_equilibrium`` with
    ``method="relax+newton"``) and returns the nodes as a JAX array whose
    derivatives in the parameters of ``names`` follow from the implicit
    function theorem (module docstring). Each solve warm-starts from the
    previous call's equilibrium (``initial=previous_solution``).

    Args:
        scene: the bay, fabric and physics switches.
        fixed: values of parameters that are not passed at call time
            (``pressure`` in Pa, prestrains, stiffnesses in N/m, rib scales);
            unspecified ones take the fabric's stiffnesses, zero prestrain and
            unit rib scales.
        rtol: relative residual of every solve (`GRADIENT_RTOL` by default).
        warm_start: start each solve from the previous equilibrium.
        max_steps: step cap of each solve.
        sequencing: let the first (cold) solve use grid sequencing; off, it
            compiles one relaxation loop fewer, which on small grids saves
            more time than sequencing gains.

    Attributes:
        solution: the last `Solution`.
        solves: forward solves so far.
        steps: forward-solve steps (relaxation steps plus Newton iterations)
            of each solve, in order.

    Raises:
        ValueError: for an unknown parameter name or a non-physical value.
    """

    def __init__(self, scene: Scene, fixed: Mapping | None = None, *, rtol: float = GRADIENT_RTOL,
                 warm_start: bool = True, max_steps: int = 200_000, sequencing: bool = True):
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a forward_solver.Scene, got {type(scene).__name__}")
        fixed = dict(fixed or {})
        _check_names(fixed)
        self.scene = scene
        self.fixed = fixed
        self.sequencing = sequencing
        self.rtol = rtol
        self.warm_start = warm_start
        self.max_steps = max_steps
        self.solution: Solution | None = None
        self.solves = 0
        self.steps: list[int] = []
        self._linearisation: _Linearisation | None = None
        self._key = None

    def values(self, theta: Mapping) -> dict:
        """All seven parameter values (concrete floats) for ``theta`` over ``fixed``."""
        merged = {**_defaults(self.scene), **self.fixed, **theta}
        if "pressure" not in merged:
            raise ValueError("pressure must be given, in theta or in fixed (Pa)")
        return merged

    def solve(self, theta: Mapping) -> Solution:
        """The equilibrium `Solution` at concrete ``theta`` (no derivatives); cached per value."""
        _check_names(theta)
        values = {k: float(np.asarray(v)) for k, v in self.values(theta).items()}
        key = tuple(sorted(values.items()))
        if key == self._key and self.solution is not None:
            return self.solution
        initial = self._initial(values)
        sol = solve_equilibrium(
            self.scene,
            values["pressure"],
            (values["prestrain_span"], values["prestrain_chord"]),
            rtol=self.rtol,
            max_steps=self.max_steps,
            method="relax+newton",
            initial=initial,
            stiffness=(values["stiffness_span"], values["stiffness_chord"]),
            rib_thickness_scale=values["rib_thickness_scale"],
            rib_chord_scale=values["rib_chord_scale"],
            sequencing=self.sequencing,
            throw=True,
        )
        self.solution, self._key, self._linearisation = sol, key, None
        self.solves += 1
        self.steps.append(int(sol.steps))
        return sol

    def _initial(self, values: dict):
        """Warm start: the previous equilibrium (`solve_equilibrium` re-mounts its held
        nodes on the new ribs, and with ``relax+newton`` reuses its factor)."""
        return self.solution if self.warm_start else None

    def _linearised(self, values: dict) -> _Linearisation:
        self.solve(values)
        if self._linearisation is None:
            params = self.scene.params(
                values["pressure"], (values["prestrain_span"], values["prestrain_chord"]),
                (values["stiffness_span"], values["stiffness_chord"]),
                values["rib_thickness_scale"], values["rib_chord_scale"])
            self._linearisation = _Linearisation(self.scene, self.solution, params)
        return self._linearisation

    def __call__(self, theta: Mapping) -> jnp.ndarray:
        """Equilibrium nodes ``(n_span, n_contour, 3)`` in m, differentiable in ``theta``.

        Args:
            theta: ``{name: scalar}`` for names in `DIFFERENTIABLE`; values may
                be JAX tracers of ``jax.grad`` / ``jax.jacfwd`` (not of
                ``jax.jit``).
        """
        _check_names(theta)
        names = tuple(sorted(theta))
        with float64_scope(*(theta[n] for n in names)):
            leaves = tuple(jnp.asarray(theta[n], jnp.float64) for n in names)
            for name, leaf in zip(names, leaves):
                if leaf.shape != ():
                    raise ValueError(f"{name} must be a scalar, got shape {leaf.shape}")
            return self._nodes(names, leaves)

    def _nodes(self, names, leaves):
        @jax.custom_jvp
        def nodes(*values):
            concrete = self._concrete(names, values)
            return jnp.asarray(self.solve(concrete).nodes, jnp.float64)

        @nodes.defjvp
        def nodes_jvp(primals, tangents):
            concrete = self._concrete(names, primals)
            lin = self._linearised(self.values(concrete))
            zero = fk.Params(*(np.zeros((), np.float64) for _ in fk.Params._fields))
            dparams = zero._replace(**dict(zip(names, tangents)))
            return lin.x, lin.tangent(dparams)

        return nodes(*leaves)

    @staticmethod
    def _concrete(names, values) -> dict:
        if any(_is_traced(v) for v in values):
            raise TypeError(
                "the equilibrium is solved on the host, so its parameters must be concrete: "
                "differentiate with jax.grad / jax.jacfwd / jax.jvp outside jax.jit and jax.vmap"
            )
        return {n: float(np.asarray(v)) for n, v in zip(names, values)}


def equilibrium_nodes(scene: Scene, theta: Mapping, fixed: Mapping | None = None, *,
                      rtol: float = GRADIENT_RTOL, initial: Solution | None = None) -> jnp.ndarray:
    """Equilibrium nodes, differentiable in ``theta`` (a one-off `Equilibrium`).

    Args:
        scene: the bay, fabric and physics switches.
        theta: ``{name: scalar}`` for names in `DIFFERENTIABLE` (Pa, N/m or
            dimensionless).
        fixed: other parameters (see `Equilibrium`).
        rtol: relative residual of the solve.
        initial: a nearby `Solution` to warm-start from.

    Returns:
        ``(n_span, n_contour, 3)`` nodes in m (float64).
    """
    eq = Equilibrium(scene, fixed, rtol=rtol)
    eq.solution = initial
    return eq(theta)


# ----------------------------------------------------------------- unrolled
def unrolled_equilibrium_nodes(scene: Scene, theta: Mapping, fixed: Mapping | None = None, *,
                               n_steps: int = 20_000, chunk: int = 100) -> jnp.ndarray:
    """Equilibrium nodes by ``n_steps`` of dynamic relaxation, differentiable by plain JAX AD.

    The loop of `relax` (fictitious Gershgorin masses re-estimated every
    chunk, kinetic damping) from the mounted shape, on the full grid, for a
    fixed number of steps: a ``lax.scan`` over chunks, each chunk a
    ``jax.checkpoint``-ed ``lax.scan`` of ``chunk`` steps, so reverse mode
    stores one state per chunk. The masses are a preconditioner (they do not
    change the fixed point) and are held constant under differentiation
    (``stop_gradient``). Traceable: use it under ``jax.grad`` or ``jax.jit``
    (in float64).

    Meant for checking the implicit derivative on small grids: it is exact
    for the iterate it returns, so it agrees with `Equilibrium` once the
    iterates (and their tangents) have converged.

    Args:
        scene: the bay, fabric and physics switches.
        theta: ``{name: scalar}`` (JAX values allowed).
        fixed: other parameters (as for `Equilibrium`).
        n_steps: relaxation steps (rounded up to whole chunks).
        chunk: steps per checkpointed chunk.

    Returns:
        ``(n_span, n_contour, 3)`` nodes in m.
    """
    _check_names(theta)
    fixed = dict(fixed or {})
    _check_names(fixed)
    merged = {**_defaults(scene), **fixed, **theta}
    if "pressure" not in merged:
        raise ValueError("pressure must be given, in theta or in fixed (Pa)")
    with float64_scope(*theta.values()):
        params = scene.params(merged["pressure"], (merged["prestrain_span"], merged["prestrain_chord"]),
                              (merged["stiffness_span"], merged["stiffness_chord"]),
                              merged["rib_thickness_scale"], merged["rib_chord_scale"])
        geometry = jax.tree_util.tree_map(jnp.asarray, scene.bay.geometry())
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
