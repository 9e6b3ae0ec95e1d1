"""Equilibrium by dynamic relaxation: the fast explicit path.

Equilibrium does not depend on mass, viscosity or aerodynamic damping, so
this path drops them and runs the explicit update of eq. (14)/(17) with

* fictitious nodal masses ``m_i = safety * S_i / 2`` for a unit time step,
  where ``S_i`` bounds the node's stiffness (`forces.node_stiffness`): by
  Gershgorin's theorem every node then runs at the same stable step, so the
  tiny leading-edge cells no longer set the pace for the whole bay; the
  masses are re-estimated at the start of every chunk as tensions grow;
* kinetic damping: whenever the total kinetic energy falls, the motion has
  passed an energy peak; velocities are zeroed and the run restarts from
  there, with the masses refreshed against the current shape, growing only
  (zero velocities keep the kinetic energy consistent). Measured need: a
  soft fabric under high pressure (NACA 4415 bay, 1e4 N/m, 1e5 Pa, no
  prestrain) stretches fivefold within the first chunk and blew up to NaN
  in ~40 steps on the chunk's masses; with the refresh it converges (to a
  balloon 0.79 m out);
* a stagnation guard: if the residual stops falling (non-smooth wrinkling
  can lock kinetic damping into a limit cycle), the masses grow by half;
  and a hopeless run ends early: over every `WINDOW_CHUNKS` chunks without
  such growth, the best residual's rate of fall is extrapolated, and if it
  would need more than `GIVE_UP_CHUNKS` further chunks to reach ``rtol``
  the run ends ``stalled`` (the caller then hands over to Newton,
  `chain.Auto`). Measured need, 17x64: slack fabric (NACA 2412, 1e4 Pa,
  prestrain -5%) cycles at a residual of 1e-4 to 4e-3 up to the
  200,000-step cap (now stalled after 10,500 steps; Newton from there
  converges in 8 iterations); and kinetic damping, which stops at the
  kinetic-energy peaks (the minima of a potential energy), can cycle for
  ever where the force is not the gradient of one: eq. (1)-(2) with ``nu12 =
  nu21`` is not reciprocal when the stiffnesses differ (NACA 0006, 323 Pa,
  2e4/3e5 N/m, poisson 0.25, prestrain 4%/3%, ribs 0.5 m apart: residual
  0.2-4 for 200,000 steps, now stalled after 11,000; poisson 0.1 converges
  in 7800 steps; Newton in 30 iterations either way);
* half-bay symmetry: a bay whose two ribs are identical (odd ``n_span``) is
  symmetric about mid-span, so only rows ``0..m`` are solved, on a grid
  extended by one ghost row that mirrors row ``m - 1``; the mid row keeps
  ``y = rib_spacing / 2``. A step then costs about half as much;
* grid sequencing (`sequencing`);
* precision: the iteration runs in ``float32`` or ``float64``; the stop test
  (`loop.run_chunks`) always evaluates the residual in float64 at the
  current nodes, so "converged" means the returned shape meets ``rtol``.

Its jit form (`traced_solution`). When the `Parameters` reach
`solve_equilibrium` as abstract tracers (inside ``jax.jit``, or batched by
``jax.vmap``), their values cannot steer host code, so the solve is this
relaxation alone: from the mounted shape (or the ``initial`` nodes), full
or half grid as the eager path chooses it (static), no grid sequencing (its
fallback when a coarse level fails is a host decision), at most
``max_steps`` steps. The result code, steps and residual come back as
arrays in the `Solution` (leaves of its pytree), so a failure is reported,
never raised (the caller passes ``throw=False``; after the compiled call
`Solution.raise_if_failed` raises for the batch). Derivatives come from the
implicit function theorem with a pure-JAX linear solver
(`implicit.implicit_nodes`, BiCGStab): the relaxation runs under
``stop_gradient`` and only its fixed point carries a tangent, so
``jax.grad``, ``jax.jacfwd`` and ``jax.vmap`` of either compose with
``jax.jit``. Under ``jax.vmap`` the ``while_loop`` runs until every member
of the batch has stopped, so a batch costs its slowest member's step count.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .. import forces as fk
from ..compilation import stored_jit
from ..derivatives.implicit import implicit_nodes
from ..derivatives.krylov import BiCGStab
from ..model.parameters import Parameters
from ..model.scene import Scene
from ..precision import float64_scope
from ..programs import static_forces
from ..solution import Result, Solution, initial_nodes, make_solution
from .loop import Stepper, run_chunks

try:  # public home of the check since JAX 0.4.36; jax.core's copy is deprecated
    from jax.extend.core import concrete_or_error
except ImportError:  # pragma: no cover - older JAX
    from jax.core import concrete_or_error

__all__ = ["relax_jit", "RelaxOptions", "MASS_SAFETY", "RELAX_CHUNK", "LIGHT_RELAX_NODES", "kinetic_damping_step",
           "mirror_rows", "has_abstract_values", "relaxed_nodes", "traced_solution"]

#: Factor over the Gershgorin mass bound: 1.0 is the bound itself; 1.5
#: leaves room for the couplings the bound leaves out (cell averaging).
MASS_SAFETY = 1.5
#: Steps per chunk of the relaxation loop (stop test and mass update between chunks).
RELAX_CHUNK = 100
#: Grids of at most this many nodes compile their relaxation light (`compilation.stored_jit`): at
#: 17x64 (1,088 nodes) a relaxation runs 0.1 s longer and compiles 0.65 s shorter, which a process
#: relaxing a grid fewer than about six times gains; at 33x128 it would run 0.52 s longer
#: (docs/compilation.md).
LIGHT_RELAX_NODES = 2_000


def _light_relaxation(x_init, **_) -> bool:
    return x_init.shape[0] * x_init.shape[1] <= LIGHT_RELAX_NODES


class _State(NamedTuple):
    x: jnp.ndarray
    v: jnp.ndarray
    kinetic: jnp.ndarray
    mass: jnp.ndarray
    safety: jnp.ndarray  # current factor over the Gershgorin bound
    best: jnp.ndarray  # lowest relative residual seen
    stalled: jnp.ndarray  # chunks since the residual last improved by STALL_GAIN
    window_best: jnp.ndarray  # best relative residual when the current window began
    window_chunks: jnp.ndarray  # chunks begun in the current window


#: Stagnation guard: when the residual has not fallen below ``STALL_GAIN``
#: times its best value for ``STALL_CHUNKS`` chunks, the mass safety factor
#: grows by ``SAFETY_GROWTH`` (up to ``MAX_SAFETY``) and the run restarts
#: from rest. Measured need: on the 65x512 default bay the wrinkled cells at
#: the trailing edge lock kinetic damping into a limit cycle at safety 1.5
#: (residual stuck at 8e-2); at 2.5 it converges in 9100 steps.
STALL_CHUNKS = 10
STALL_GAIN = 0.9
SAFETY_GROWTH = 1.5
MAX_SAFETY = 20.0
#: Early end of a hopeless run: the best residual's fall over `WINDOW_CHUNKS` chunks (a window
#: restarts at every growth of the masses) is extrapolated geometrically; a run that would
#: need more than `GIVE_UP_CHUNKS` further chunks ends ``stalled``. Converging relaxations
#: fall by orders of magnitude per window (default bay, 17x64: 1e-8 in 1900 steps).
WINDOW_CHUNKS = 2 * STALL_CHUNKS
GIVE_UP_CHUNKS = 300


def kinetic_damping_step(x, v, kinetic, mass, force):
    """One explicit step of unit length with kinetic damping.

    Eq. (14)/(17) with fictitious masses: ``v += F / m``, ``x += v``; when the
    kinetic energy falls below its previous value the motion has passed an
    energy peak, so the velocities are zeroed (and the position held).

    Returns:
        ``(x, v, kinetic)`` after the step.
    """
    v = v + force / mass
    new_kinetic = 0.5 * jnp.sum(mass * v * v)
    peaked = new_kinetic < kinetic
    v = jnp.where(peaked, 0.0, v)
    return x + v, v, jnp.where(peaked, 0.0, new_kinetic)


def mirror_rows(rows: jnp.ndarray, mid_y) -> jnp.ndarray:
    """Reflect grid rows through the plane ``y = mid_y``."""
    return rows.at[..., 1].set(2.0 * mid_y - rows[..., 1])


class _Grid(NamedTuple):
    """The residual, stiffness and norm of the grid actually solved."""

    residual: callable
    stiffness: callable
    relative_residual: callable
    full: callable  # solved rows -> full grid
    x0: jnp.ndarray


def _full_grid(ref, params, physics) -> _Grid:
    return _Grid(lambda x: fk.residual(x, ref, params, physics), lambda x: fk.node_stiffness(x, ref, params, physics),
                 lambda x: fk.relative_residual(x, ref, params, physics), lambda x: x, ref.nodes)


def _half_grid(ref, params, physics) -> _Grid:
    ns = ref.nodes.shape[0]
    m = (ns - 1) // 2  # the mid row: rows 0 .. m are solved
    mid_y = ref.nodes[m, 0, 1]
    free = jnp.broadcast_to(ref.free[: m + 2], (m + 2,) + ref.free.shape[1:-1] + (3,))
    free = free.at[m + 1].set(0.0).at[m, :, 1].set(0.0)
    half = fk.Reference(ref.nodes[: m + 2], ref.span_length[: m + 1], ref.contour_length[: m + 2],
                        ref.node_area[: m + 2], free, ref.skin_area)

    def extend(x):
        return jnp.concatenate([x, mirror_rows(x[m - 1 : m], mid_y)], axis=0)

    # Rows below the mid row stand for themselves and their mirror images.
    weight = jnp.full((m + 1, 1, 1), 2.0).at[m].set(1.0)

    def relative_residual(x):
        r = fk.residual(extend(x), half, params, physics)[: m + 1]
        return jnp.sqrt(jnp.sum(weight * r * r)) / (params.pressure * ref.skin_area)

    return _Grid(lambda x: fk.residual(extend(x), half, params, physics)[: m + 1],
                 lambda x: fk.node_stiffness(extend(x), half, params, physics)[: m + 1], relative_residual,
                 lambda x: jnp.concatenate([x, mirror_rows(x[:m][::-1], mid_y)], axis=0), ref.nodes[: m + 1])


def _cast(tree, dtype):
    return jax.tree_util.tree_map(lambda a: jnp.asarray(a).astype(dtype), tree)


class RelaxOptions(NamedTuple):
    """The static choices of one `relax_jit` program (a change compiles another).

    Attributes:
        max_chunks: chunk cap.
        half: solve half the bay (rows ``0 .. m`` and a ghost row, module docstring).
        precision: "float64" or "float32", the iteration's type.
        with_forces: return the float64 forces at the end.
        chunk: steps per chunk.
    """

    max_chunks: int
    half: bool = False
    precision: str = "float64"
    with_forces: bool = True
    chunk: int = RELAX_CHUNK


@stored_jit(static_argnames=("physics", "options"), light=_light_relaxation, loop=True)
def relax_jit(x_init, geometry, params, rtol, divergence_bound, mass_safety, physics, options: RelaxOptions):
    """Dynamic relaxation from the full-grid shape ``x_init``.

    ``x_init``, ``geometry`` and ``params`` are float64; the iteration runs
    in ``options.precision`` ("float64" or "float32") and the stop test in float64.

    Returns the loop output (its state on the solved rows, in ``precision``)
    and the float64 forces (None without ``with_forces``) and nodes on the
    full grid. A caller that does not use the forces (a coarse grid level, a
    relaxation that Newton finishes) leaves them out: one copy of the force
    kernel less to compile (0.15 s of 1.2 s at 17x64) and to run.
    """
    max_chunks, half, precision, with_forces, chunk = options
    physics = fk.static_physics(physics)
    ref64 = fk.prepare(geometry, params, physics)
    make_grid = _half_grid if half else _full_grid
    grid64 = make_grid(ref64, params, physics)
    if precision == "float64":
        grid = grid64
    else:  # the same grid in the iteration's type
        dtype = jnp.dtype(precision)
        geometry_c, params_c = _cast(geometry, dtype), _cast(params, dtype)
        grid = make_grid(fk.prepare(geometry_c, params_c, physics), params_c, physics)
        x_init = x_init.astype(dtype)
        divergence_bound = divergence_bound.astype(dtype)
    x_start = x_init[: grid.x0.shape[0]]

    def relative_residual(x):
        return grid64.relative_residual(x.astype(ref64.nodes.dtype))

    def masses(x, safety):
        return (0.5 * safety * grid.stiffness(x))[..., None]

    def begin_chunk(s: _State, residual) -> _State:
        improved = residual < STALL_GAIN * s.best
        stalled = jnp.where(improved, 0, s.stalled + 1)
        grow = (stalled >= STALL_CHUNKS) & (s.safety * SAFETY_GROWTH <= MAX_SAFETY)
        safety = jnp.where(grow, s.safety * SAFETY_GROWTH, s.safety)
        v = jnp.where(grow, 0.0, s.v)
        mass = masses(s.x, safety)
        best = jnp.minimum(s.best, residual)
        window = s.window_chunks + 1
        restart = grow | (window >= WINDOW_CHUNKS)
        return _State(s.x, v, 0.5 * jnp.sum(mass * v * v), mass, safety, best,
                      jnp.where(grow, 0, stalled), jnp.where(restart, best, s.window_best),
                      jnp.where(restart, 0, window))

    def step(s: _State) -> _State:
        x, v, kinetic = kinetic_damping_step(s.x, s.v, s.kinetic, s.mass, grid.residual(s.x))
        # Zero kinetic energy: the velocities were just zeroed at an energy peak (or the
        # state is exactly at rest, where a refresh is harmless). Refresh the masses there.
        mass = jax.lax.cond(kinetic == 0.0, lambda: jnp.maximum(s.mass, masses(x, s.safety)),
                            lambda: s.mass)
        return s._replace(x=x, v=v, kinetic=kinetic, mass=mass)

    def give_up(s: _State, residual):
        # At the end of a window: extrapolate the best residual's geometric fall to rtol.
        best = jnp.minimum(s.best, residual)
        gain = best / s.window_best  # 0 in the first window (window_best inf)
        falls = gain < 1.0
        needed = WINDOW_CHUNKS * jnp.log(best / rtol) / jnp.log(jnp.where(falls, 1.0 / gain, 2.0))
        return (s.window_chunks + 1 >= WINDOW_CHUNKS) & (~falls | (needed > GIVE_UP_CHUNKS))

    dtype = x_start.dtype
    safety0 = jnp.asarray(mass_safety, dtype)
    state = _State(x_start, jnp.zeros_like(x_start), jnp.zeros((), dtype), masses(x_start, safety0),
                   safety0, jnp.asarray(jnp.inf, rtol.dtype), jnp.zeros((), jnp.int32),
                   jnp.asarray(jnp.inf, rtol.dtype), jnp.zeros((), jnp.int32))
    stepper = Stepper(step, relative_residual, lambda s, r: True, begin_chunk=begin_chunk, give_up=give_up)
    out = run_chunks(state, stepper, grid.x0, rtol, divergence_bound, chunk, max_chunks)
    x_full = grid64.full(out.state.x.astype(ref64.nodes.dtype))
    return out, (fk.forces(x_full, ref64, params, physics) if with_forces else None), x_full


# ---------------------------------------------------------------- the jit form
def _is_abstract(value) -> bool:
    if not isinstance(value, jax.core.Tracer):
        return False
    try:
        concrete_or_error(None, value)
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


def relaxed_nodes(x_init, geometry, params, rtol, bound, physics, max_chunks: int, *, half: bool,
                  solver: BiCGStab = BiCGStab()):
    """The relaxation from ``x_init`` as pure JAX, its fixed point differentiable in ``params``.

    The loop runs on ``stop_gradient`` values; only its fixed point carries a
    tangent, by the implicit function theorem with the pure-JAX ``solver``
    (`implicit.implicit_nodes`; NaN where the loop did not converge).
    Vmappable over ``geometry`` and ``bound`` too (`bays.Batch`).

    Returns:
        ``(nodes, out)``: the nodes and the loop's `loop.LoopOutput`.
    """
    fixed = jax.lax.stop_gradient(params)
    out, _, x_star = relax_jit(jax.lax.stop_gradient(x_init), geometry, fixed, rtol, bound, MASS_SAFETY,
                               physics, RelaxOptions(max_chunks, half=half, with_forces=False))
    return implicit_nodes(solver, physics, x_star, geometry, params, out.result == Result.converged), out


def traced_solution(scene: Scene, parameters: Parameters, *, rtol: float, initial, half: bool, max_chunks: int,
                    solver: BiCGStab) -> Solution:
    """The relaxation's `Solution` at abstract ``parameters`` (see the module docstring).

    Args:
        scene: the bay, fabric and switches.
        parameters: resolved `Parameters` (abstract tracers allowed).
        rtol: relative residual ``||R_free|| / (p A)`` to stop at.
        initial: None, a `Solution` or nodes on this grid (a warm start; not
            differentiated).
        half: solve half the bay (static; see the module docstring).
        max_chunks: chunk cap (``max_steps`` rounded up to chunks of `RELAX_CHUNK`).
        solver: the implicit derivative's pure-JAX linear solver.

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
        bound = jnp.asarray(bay.divergence_bound, jnp.float64)
        nodes, out = relaxed_nodes(x_init, geometry, params, jnp.asarray(rtol, jnp.float64), bound, physics,
                                   max_chunks, half=half, solver=solver)
        f = static_forces(nodes, geometry, params, physics)
    return make_solution(out, f, nodes, out.chunks * RELAX_CHUNK, None, "relax", parameters, bay,
                         extra={"precision": "float64", "half_bay": half, "levels": [], "traced": True,
                                "linear_solver": solver.name})

