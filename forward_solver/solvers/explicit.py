"""The paper's scheme as written: physical mass, central differences, CFL step.

Paper eq. (14) advances the velocities with the force of eq. (10)-(15) over
the physical mass ``rho0 * area`` of each node, eq. (17) the positions; the
time step obeys the Courant-Friedrichs-Lewy condition (16)
``dt = alpha_k * min(h) / c`` with ``c = sqrt(E_max / ((1 - nu^2) rho0))``.
Pressure follows a ramp and, optionally, the aerodynamic damping of eq. (11);
the fabric's viscosity damps through eq. (10). The run stops at rest, on a
failure, or at the step cap, and records its history.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import forces as fk
from ..compilation import LOOP_OPTIONS
from ..stencils import safe_norm
from ..model.parameters import Parameters, as_parameters
from ..model.scene import Scene
from ..precision import check_precision, float64_scope, precision_extra
from ..solution import Result, Solution, initial_nodes, make_solution
from .loop import Stepper, check_stop, run_chunks

__all__ = ["PressureRamp", "simulate", "stable_time_step", "wave_speed", "plane_strain_modulus",
           "DEFAULT_COURANT", "DIVERGED_DETAIL"]

#: Courant coefficient alpha_k of eq. (16) used unless the caller picks one;
#: it keeps a margin of two below `MEASURED_COURANT_LIMIT` for distorted cells.
DEFAULT_COURANT = 0.5
#: Largest Courant coefficient at which the scheme came to rest on uniform
#: square cells (`benchmarks/stability_map.py`, 9x33 panel, 20 kPa, viscosity
#: 1-50 N*s/m): at 1.05 it already rings in its period-two mode (see
#: `_explicit_detail`), without viscosity it blows up. A cosine-spaced wing bay
#: (9x32 NACA 2412) still runs stably at 1.2: its smallest cell sets the step,
#: and every other cell runs far below its own limit.
MEASURED_COURANT_LIMIT = 1.0
#: `Solution.detail` of a run stopped at the divergence bound (this scheme's and the relaxation's).
DIVERGED_DETAIL = ("the skin kept inflating past the bound: the pressure is probably beyond what the fabric "
                   "can hold at this prestrain (lower the pressure, stiffen the fabric or raise the prestrain)")


@dataclass(frozen=True)
class PressureRamp:
    """Pressurisation history ``p_tilde(t)`` of eq. (11): a linear ramp to ``pressure``.

    Args:
        pressure: final overpressure, Pa.
        ramp_time: time to reach it, s (0 applies it at once).
    """

    pressure: float
    ramp_time: float = 0.0

    def __post_init__(self):
        Parameters(self.pressure).check()
        if not (math.isfinite(self.ramp_time) and self.ramp_time >= 0):
            raise ValueError(f"ramp_time must be zero or positive in s, got {self.ramp_time!r}")


class _State(NamedTuple):
    x: jnp.ndarray
    v: jnp.ndarray
    t: jnp.ndarray


def kinetic_rest_threshold(rtol, load, stiffness):
    """Largest kinetic energy (J) that still counts as "at rest".

    A mode of stiffness ``k`` oscillating with kinetic energy ``K`` reaches a
    force amplitude ``sqrt(2 k K)``; requiring it below ``rtol * load`` with
    ``k`` the fabric's plane-strain stiffness (N/m) gives this bound.
    """
    return 0.5 * (rtol * load) ** 2 / stiffness


def plane_strain_modulus(params, physics):
    """Stiffest plane-strain modulus of the kernel's `forces.KernelInputs` ``params`` under ``physics``'s
    law, N/m: ``max(E11, E22) / (1 - nu^2)`` for eq. (10), the largest diagonal tangent over the tested
    range for a fitted law (`model.fibre_law`)."""
    return physics.law.modulus(params)


def wave_speed(params, physics):
    """Speed of small in-plane disturbances ``c = sqrt(E_max / rho0)`` of eq. (16), m/s."""
    return jnp.sqrt(plane_strain_modulus(params, physics) / params.areal_density)


def stable_time_step(courant, h_min, wave_speed, params, physics):
    """Time step: eq. (16), shortened for the damping terms.

    Eq. (16) ``dt = alpha_k min(h) / c`` bounds the undamped scheme. The
    explicit (lagged) viscous term of eq. (10) adds a damper of ratio
    ``zeta = eta / (rho0 h c)`` to the highest grid mode, whose stable step
    is ``(sqrt(1 + zeta^2) - zeta)`` times the undamped one. The aerodynamic
    term of eq. (11) is a damper of rate ``2 p nu_n / rho0`` per node, stable
    below ``2 rho0 / (2 p nu_n)``; the Courant coefficient scales both.
    """
    dt = courant * h_min / wave_speed  # eq. (16)
    if physics.viscous:
        zeta = params.viscosity / (params.areal_density * h_min * wave_speed)
        dt = dt * (jnp.sqrt(1.0 + zeta * zeta) - zeta)
    if physics.aerodynamic:
        rate = 2.0 * params.pressure * params.aerodynamic_damping / params.areal_density
        dt = jnp.minimum(dt, courant * 2.0 / rate)
    return dt


@partial(jax.jit, static_argnames=("physics", "chunk", "max_chunks", "precision"), compiler_options=LOOP_OPTIONS)
def _simulate_jit(x_init, geometry, params, ramp_time, courant, rtol, divergence_bound,
                  physics, chunk, max_chunks, precision="float64"):
    """The run: loop output, float64 forces and nodes at its end, the time step, and
    the ratio of the next step's velocity to the last one (see `_explicit_detail`)."""
    static_physics = fk.static_physics(physics)
    ref64, params64 = fk.prepare(geometry, params, physics), params
    if precision != "float64":
        dtype = jnp.dtype(precision)
        geometry, params, x_init, ramp_time, courant, divergence_bound = jax.tree_util.tree_map(
            lambda a: jnp.asarray(a).astype(dtype),
            (geometry, params, x_init, ramp_time, courant, divergence_bound))
    ref = fk.prepare(geometry, params, physics)
    e_max = plane_strain_modulus(params, physics)
    h_min = jnp.minimum(jnp.min(ref.span_length), jnp.min(ref.contour_length))
    dt = stable_time_step(courant, h_min, wave_speed(params, physics), params, physics)
    mass = (params.areal_density * ref.node_area)[..., None]
    load = params.pressure * ref.skin_area
    ke_rest = kinetic_rest_threshold(rtol.astype(load.dtype), load, e_max)

    def ramp(t):
        frac = jnp.where(ramp_time > 0, jnp.clip(t / jnp.where(ramp_time > 0, ramp_time, 1.0), 0.0, 1.0), 1.0)
        return params.pressure * frac

    def step(s: _State) -> _State:
        f = fk.forces(s.x, ref, params, physics, pressure=ramp(s.t), v=s.v).total
        v = s.v + dt * f / mass  # eq. (14)
        x = s.x + dt * v  # eq. (17)
        return _State(x, v, s.t + dt)

    def relative_residual(x):  # always float64: "converged" holds for the returned shape
        return fk.relative_residual(x.astype(ref64.nodes.dtype), ref64, params64, physics)

    def kinetic(s):
        return 0.5 * jnp.sum(mass * s.v * s.v)

    def at_rest(s, _res):
        return (s.t >= ramp_time) & (kinetic(s) <= ke_rest)

    def effective_pressure(s):
        p_now = ramp(s.t)
        if not physics.aerodynamic:
            return p_now
        area = fk.node_area_vectors(s.x, physics.periodic)
        norm = safe_norm(area)
        normal = area / jnp.where(norm > 0, norm, 1.0)[..., None]
        factor = 1.0 - params.aerodynamic_damping * jnp.sum(s.v * normal, axis=-1)
        w = ref.free[..., 0] * norm
        return p_now * jnp.sum(w * factor * jnp.abs(factor)) / jnp.sum(w)

    def record(s):
        return {
            "time": s.t,
            "kinetic_energy": kinetic(s),
            "peak_displacement": jnp.max(safe_norm(s.x - ref.nodes) * ref.free[..., 0]),
            "pressure": effective_pressure(s),
        }

    state = _State(x_init, jnp.zeros_like(x_init), jnp.zeros((), x_init.dtype))
    out = run_chunks(state, Stepper(step, relative_residual, at_rest, record=record), ref.nodes, rtol,
                     divergence_bound, chunk, max_chunks)
    # One more step, not taken: the next velocity projected on the last one, over the last
    # one's square, is +1 for motion slow against the step and -1 (or below -1, growing)
    # for the period-two mode of a time step over the stability limit.
    v_now, v_next = out.state.v, step(out.state).v
    vv = jnp.sum(v_now * v_now)
    ratio = jnp.where(vv > 0, jnp.sum(v_now * v_next) / jnp.where(vv > 0, vv, 1.0), 0.0)
    x64 = out.state.x.astype(ref64.nodes.dtype)
    f = fk.forces(x64, ref64, params64, static_physics)
    return out, f, dt, ratio, x64


#: Ratio of successive velocities (see `_simulate_jit`) below which the motion
#: counts as the period-two oscillation of an over-limit time step. Measured
#: on the 9x33 panel: -1.000 at Courant 1.2-1.5 with viscosity 5-50 N*s/m,
#: where the run rings at constant kinetic energy without blowing up; +0.91
#: to +0.95 for the undamped in-plane ringing of a fabric without viscosity
#: at Courant 0.6-1.0; below -1 (-1.13) for the blow-up at Courant 1.5
#: without viscosity, stopped by the divergence guard.
RINGING_RATIO = -0.5


def _explicit_detail(code: int, ratio: float, courant: float, viscous: bool,
                     precision: str, floor: float | None) -> str:
    """What to change after a failed run of the paper's scheme (the `Solution.detail`)."""
    if code == Result.converged:
        return ""
    limit = (f"lower the Courant coefficient (now {courant:g}; the scheme's measured limit is "
             f"{MEASURED_COURANT_LIMIT:.1f}, see benchmarks/stability_map.py)")
    if ratio < RINGING_RATIO:
        return (f"the velocity reverses at every step (ratio {ratio:.2f} of successive "
                "velocities), the signature of a time step over the stability limit of "
                f"eq. (16): {limit} rather than raising max_steps")
    if code == Result.nonfinite:
        return (f"the run overflowed between two guard checks: the time step is probably over "
                f"the stability limit of eq. (16), so {limit}; else check the input")
    if code == Result.diverged:
        return DIVERGED_DETAIL
    if not viscous:
        return ("the fabric has no viscosity (eq. 10), so its in-plane modes ring undamped and "
                "never come to rest: give it viscosity (e.g. 5-20 N*s/m), or use "
                "solve_equilibrium, which needs no damping")
    if precision == "float32":
        return ("if the residual has stopped falling, the float32 run has reached its rounding "
                f"floor (about {floor:.1e} on this scene): use precision='float64'; otherwise "
                "raise max_steps")
    return ""


def simulate(scene: Scene, pressure_history, prestrain=None, *, courant: float = DEFAULT_COURANT, rtol: float = 1e-6,
             max_steps: int = 200_000, record_every: int = 200, initial=None, precision: str = "float64",
             throw: bool = True) -> Solution:
    """Pressurise the bay with the paper's explicit scheme until it comes to rest.

    Args:
        scene: the bay, fabric and physics switches (viscosity from the fabric,
            aerodynamic damping from the scene).
        pressure_history: a `PressureRamp`, or a final pressure in Pa applied
            at once, or a `Parameters` (its pressure applied at once; then
            give no ``prestrain``). Stiffnesses and rib scales travel in a
            `Parameters` (``Parameters.replace``).
        prestrain: ``(span, chord)`` prestrain or one number for both.
        courant: Courant coefficient ``alpha_k`` of eq. (16).
        rtol: stop when ``||R_free|| / (p A) <= rtol``, the ramp is over and
            the kinetic energy is below `kinetic_rest_threshold`.
        max_steps: step cap (rounded up to whole chunks of ``record_every``).
        record_every: steps between stop tests and history records.
        initial: starting shape, a `Solution` or ``(n_span, n_contour, 3)``
            array (default: the mounted shape).
        precision: "float64" (default) or "float32" (the rule of
            `forward_solver.precision`).
        throw: raise `ConvergenceError` unless the run converged (a node
            further than `Bay.divergence_bound` from its mounted position
            stops it as ``diverged``).

    Returns:
        A `Solution` whose ``history`` holds time (s), kinetic_energy (J),
        peak_displacement (m) and pressure (Pa, the effective pressure of
        eq. 11 averaged over the skin) after each chunk; ``extra`` holds the
        time step ``dt`` (s) and ``velocity_ratio``, the next step's
        velocity projected on the last one over its square: near +1 for
        motion slow against the step, near -1 when the run ended in the
        period-two oscillation of a time step over the stability limit (then
        `Solution.detail` says to lower the Courant coefficient).

    Raises:
        ValueError: for non-physical input or a float32 ``rtol`` below its floor.
        TypeError: for traced values (inside ``jax.jit``, ``jax.vmap`` or ``jax.grad``): the run is a
            host loop of compiled chunks, its program compiled at top level (`compilation.LOOP_OPTIONS`).
        ConvergenceError: if ``throw`` and the run did not converge.
    """
    if isinstance(pressure_history, PressureRamp):
        ramp, parameters = pressure_history, as_parameters(pressure_history.pressure, prestrain)
    else:
        parameters = as_parameters(pressure_history, prestrain)
        ramp = PressureRamp(parameters.pressure)
    if parameters.is_traced() or isinstance(ramp.ramp_time, jax.core.Tracer):
        raise TypeError("simulate runs the explicit scheme on the host, chunk by chunk, with concrete values: "
                        "call it outside jax.jit, jax.vmap and jax.grad (derivatives of the equilibrium: "
                        "solve_equilibrium, whose implicit derivative is eq. 10-15 at rest)")
    parameters = scene.check_parameters(parameters.resolved(scene.fabric))
    if not (math.isfinite(courant) and courant > 0):
        raise ValueError(f"courant must be a positive number (eq. 16), got {courant!r}")
    check_stop(record_every=record_every, max_steps=max_steps)
    check_precision(precision)
    bay = scene.bay
    bound = bay.divergence_bound
    max_chunks = -(-max_steps // record_every)
    physics = scene.physics(dynamic=True)
    with float64_scope():
        dtype = jnp.float64  # inputs, stop test and results; the iteration runs in `precision`
        params = scene.params(parameters, dtype=dtype)
        geometry = bay.geometry()  # float64 within the scope (made once per bay)
        extra = precision_extra(precision, rtol, geometry, params, physics)
        floor = extra.get("float32_floor")
        x_init = initial_nodes(initial, geometry, params)
        start = time.perf_counter()
        out, f, dt, ratio, nodes = _simulate_jit(
            x_init, geometry, params, jnp.asarray(ramp.ramp_time, dtype), jnp.asarray(courant, dtype),
            jnp.asarray(rtol, dtype), jnp.asarray(bound, dtype), physics, record_every, max_chunks,
            precision=precision,
        )
        jax.block_until_ready(out)
        wall = time.perf_counter() - start
        n = int(out.chunks)
        history = {k: np.asarray(v, dtype=np.float64)[:n] for k, v in out.history.items()}
        extra.update(dt=float(dt), velocity_ratio=float(ratio))
        detail = _explicit_detail(int(out.result), float(ratio), courant, physics.viscous,
                                  precision, floor)
        sol = make_solution(out, f, nodes, int(out.chunks) * record_every, wall, "explicit", parameters, bay,
                            history=history, extra=extra, detail=detail)
    if throw:
        sol.raise_if_failed()
    return sol
