"""The equilibrium methods as values: what ``solve_equilibrium(method=...)`` takes.

Each method is a small frozen dataclass with its own knobs, and solves a
scene by a call: ``method.solve(scene, parameters, rtol=..., max_steps=...,
initial=...)`` returns the concrete `Solution`, its failure code included
(`solve_equilibrium` raises after it when asked); ``check_traceable``
refuses ``jax.jit`` / ``jax.vmap`` where the method cannot run traced (only
`Relax` can: `Relax.traced`). The shortcut strings name the default values
(`solve.METHODS`): `Relax` ("relax"), `Newton` ("newton"), `RelaxNewton`
("relax+newton"), `Explicit` ("explicit") and `chain.Auto` ("auto").
Newton's sparse LU, its quadratic convergence and the adjoint need float64:
only the relaxation and the paper's scheme have a ``precision``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from functools import partial
from typing import ClassVar, NamedTuple

import jax
import jax.numpy as jnp

from .. import forces as fk
from ..compilation import Ahead
from ..model.parameters import Parameters
from ..model.scene import Scene
from ..precision import check_precision, float64_scope, precision_extra
from ..programs import static_forces
from ..solution import Result, Solution, initial_nodes, make_solution
from .explicit import DEFAULT_COURANT, DIVERGED_DETAIL, simulate
from .newton import NewtonOptions, chord_newton, newton
from .relax import RELAX_CHUNK, traced_solution
from .sequencing import COARSE_RTOL, Relaxation, compile_ahead, sequenced_start, use_half

__all__ = ["Relax", "Newton", "RelaxNewton", "Explicit", "NEWTON_SWITCH_RTOL", "WARM_NEWTON_ITERATIONS", "HostOnly"]

#: Where "relax+newton" hands over from relaxation to Newton: loose enough that relaxation's slow
#: tail is skipped, tight enough that Newton starts in its quadratic basin (no line search or
#: continuation needed on the default bay). The 40-cell design takes 28.6 s with it (1e-3: 27.3 s;
#: 1e-5, the value until 2026-11-25: 37.4 s, its bays relaxed up to 2200 steps), the same 9 wing
#: solves and the same design to 1e-9 (the default case: the same 7).
NEWTON_SWITCH_RTOL = 1e-4


class HostOnly:
    """A method that runs on the host: it refuses ``jax.jit`` / ``jax.vmap`` of the parameters."""

    def check_traceable(self, where: str) -> None:
        """Refuse tracing, saying what to use instead."""
        raise TypeError(f"method={self.name!r} runs on the host and cannot be traced {where}; use method='relax' "
                        "(the pure-JAX relaxation), or call solve_equilibrium eagerly")


class _Host(NamedTuple):
    """What every host solve of a scene works on (made inside its float64 scope)."""

    bay: object
    geometry: fk.Geometry
    params: fk.KernelInputs
    physics: fk.Physics
    extra: dict  # the returned Solution's `extra`, filled as the solve goes


def _host(scene: Scene, parameters: Parameters, precision: str, rtol: float) -> _Host:
    physics = scene.physics(dynamic=False)
    params = scene.params(parameters, dtype=jnp.float64)  # the iteration runs in `precision`
    geometry = scene.bay.geometry()  # float64 within the scope (made once per bay)
    return _Host(scene.bay, geometry, params, physics, precision_extra(precision, rtol, geometry, params, physics))


def _relaxation_start(knobs: "Relax", host: _Host, scene, parameters, rtol, max_steps, initial, ahead,
                      relax_rtol: float, newton_next: bool):
    """A relaxation's `sequencing.Relaxation`, compiled-ahead handles, start time, start shape and the
    steps spent on coarse levels (a cold start descends the grid levels, a warm one re-mounts ``initial``)."""
    symmetric = knobs.symmetry and scene.symmetric(parameters)
    coarse_rtol = COARSE_RTOL
    if knobs.precision == "float32":
        coarse_rtol = max(COARSE_RTOL, rtol)  # coarser grids have lower floors
    relax = Relaxation(host.params, host.bay.divergence_bound, -(-max_steps // RELAX_CHUNK), host.physics,
                       symmetric, knobs.precision)
    prepared = {}
    if initial is None:
        prepared = compile_ahead(ahead, relax, host.geometry, knobs.sequencing, coarse_rtol, relax_rtol,
                                 newton_next)
    start = time.perf_counter()
    if initial is None:
        x_init, steps, levels = sequenced_start(host.geometry, relax, knobs.sequencing, coarse_rtol, prepared)
    else:
        x_init, steps, levels = initial_nodes(initial, host.geometry, host.params), 0, []
    host.extra.update(levels=levels, half_bay=use_half(host.geometry, symmetric))
    return relax, prepared, start, x_init, steps


def _relax_detail(code: int, extra: dict) -> str:
    """What to change after a failed relaxation (the `Solution.detail`)."""
    if code == Result.diverged:
        return DIVERGED_DETAIL
    if code == Result.max_steps_reached and extra.get("precision") == "float32":
        return ("if the residual has stopped falling, the float32 iteration has reached its "
                f"rounding floor (about {extra['float32_floor']:.1e} on this scene): use "
                "precision='float64'; otherwise raise max_steps")
    return ""


def _newton_solution(result, steps, *, method: str, start, parameters, host: _Host, extra) -> Solution:
    """A `Solution` from a `newton.NewtonResult` (steps count relaxation steps plus iterations)."""
    x = jnp.asarray(result.x, dtype=host.geometry.contour_root.dtype)
    f = static_forces(x, host.geometry, host.params, host.physics)
    extra = dict(extra, newton_iterations=result.iterations)
    detail = ""
    if int(result.result) != Result.converged:  # the real cause and the counts (not max_steps)
        relax = extra.get("relax_steps")
        detail = (f"Newton stopped after {result.iterations} iterations"
                  + (f" (following {relax} relaxation steps)" if relax else "") + f": {result.message}")
    return make_solution(result, f, x, steps + result.iterations, time.perf_counter() - start, method,
                         parameters, host.bay, extra=extra, detail=detail, factor=result.jacobian_factor())


@dataclass(frozen=True)
class Relax:
    """Dynamic relaxation (`relax`): the fast explicit path to the rest state.

    Args:
        sequencing: solve coarser grids first (cold starts only; `sequencing`).
        symmetry: solve half the bay when both ribs are identical and
            ``n_span`` is odd (the answer is the same, see tests).
        precision: "float64" (default) or "float32": the iteration runs in
            float32, the stop test and the returned `Solution` (float64
            arrays, residual evaluated at the returned nodes) in float64. An
            ``rtol`` below `solve.float32_residual_floor` of the scene is
            refused (`precision` for the rule and the measurements).
    """

    sequencing: bool = True
    symmetry: bool = True
    precision: str = "float64"
    name: ClassVar[str] = "relax"

    def __post_init__(self):
        check_precision(self.precision)

    def solve(self, scene: Scene, parameters: Parameters, *, rtol: float, max_steps: int, initial) -> Solution:
        """The relaxation's `Solution` at concrete ``parameters`` (from ``initial``, or cold)."""
        with float64_scope(), Ahead() as ahead:
            host = _host(scene, parameters, self.precision, rtol)
            relax, prepared, start, x_init, steps = _relaxation_start(
                self, host, scene, parameters, rtol, max_steps, initial, ahead, rtol, newton_next=False)
            ahead.ready(prepared.get(tuple(x_init.shape)))
            out, f, nodes = relax(x_init, host.geometry, rtol, with_forces=True)
            jax.block_until_ready(out)
            steps += int(out.chunks) * RELAX_CHUNK
            return make_solution(out, f, nodes, steps, time.perf_counter() - start, self.name, parameters,
                                 host.bay, extra=host.extra, detail=_relax_detail(int(out.result), host.extra))

    def check_traceable(self, where: str) -> None:
        """Refuse float32 under ``jax.jit`` / ``jax.vmap`` (the jit form runs in float64)."""
        if self.precision != "float64":
            raise TypeError(f"precision={self.precision!r} is available eagerly only; {where} use 'float64'")

    def traced(self, scene: Scene, parameters: Parameters, *, rtol: float, max_steps: int, initial,
               solver) -> Solution:
        """The relaxation as one pure-JAX program (`relax.traced_solution`), for abstract ``parameters``."""
        half = use_half(scene.bay.geometry(), self.symmetry and scene.symmetric(parameters))
        return traced_solution(scene, parameters, rtol=rtol, initial=initial, half=half,
                               max_chunks=-(-max_steps // RELAX_CHUNK), solver=solver)


@dataclass(frozen=True)
class Newton(NewtonOptions, HostOnly):
    """Sparse Newton (`newton`) from the start shape (the mounted one, or ``initial``), with load continuation.

    Its knobs are those of `newton.NewtonOptions` (``max_iterations``,
    ``continuation``, ``max_load_steps``, ``initial_load_fraction``,
    ``max_line_search``).
    """

    name: ClassVar[str] = "newton"

    def solve(self, scene: Scene, parameters: Parameters, *, rtol: float, max_steps: int, initial) -> Solution:
        """Newton's `Solution` at concrete ``parameters`` (``max_steps`` does not apply: `NewtonOptions`)."""
        del max_steps
        with float64_scope():
            host = _host(scene, parameters, "float64", rtol)
            start = time.perf_counter()
            x_init = initial_nodes(initial, host.geometry, host.params)
            host.extra.update(levels=[], half_bay=False)
            result = newton(x_init, host.geometry, host.params, host.physics, rtol, self,
                            divergence_bound=host.bay.divergence_bound)
            return _newton_solution(result, 0, method=self.name, start=start, parameters=parameters, host=host,
                                    extra=host.extra)


#: Newton iterations tried from a warm start whose chord iteration did not converge, before relaxing
#: (`RelaxNewton`): a nearby equilibrium converges in 2-5.
WARM_NEWTON_ITERATIONS = 8


@dataclass(frozen=True)
class RelaxNewton(HostOnly):
    """Relaxation to ``switch_rtol``, then Newton to ``rtol``: the fast, accurate host method.

    Its LU factor is kept in `Solution.factor` (the implicit derivative's
    adjoint solves reuse it). Warm-started from a `Solution` with a factor,
    it first tries chord Newton with that factor (`newton.chord_newton`):
    at the initial solution's own parameters, with no iteration needed, the
    factor is current and no fresh assembly and LU is made. Where that
    iteration does not converge, or the warm start has no factor (a
    `Solution` without one, or nodes), Newton proper runs from the start
    (`WARM_NEWTON_ITERATIONS`, no load continuation) before any relaxation.

    Args:
        switch_rtol: relative residual at which relaxation hands over.
        sequencing, symmetry: the relaxation's (`Relax`).
        newton: the Newton finish's knobs (`Newton`).
    """

    switch_rtol: float = NEWTON_SWITCH_RTOL
    sequencing: bool = True
    symmetry: bool = True
    newton: Newton = Newton()
    name: ClassVar[str] = "relax+newton"

    def solve(self, scene: Scene, parameters: Parameters, *, rtol: float, max_steps: int, initial) -> Solution:
        """The `Solution` at concrete ``parameters`` (chord Newton first from a factorised ``initial``)."""
        with float64_scope(), Ahead() as ahead:
            host = _host(scene, parameters, "float64", rtol)
            relax_rtol = max(rtol, self.switch_rtol)
            relax, prepared, start, x_init, steps = _relaxation_start(
                Relax(self.sequencing, self.symmetry), host, scene, parameters, rtol, max_steps, initial, ahead,
                relax_rtol, newton_next=True)
            finish = partial(_newton_solution, method=self.name, start=start, parameters=parameters, host=host)
            previous = initial.factor if isinstance(initial, Solution) else None
            if previous is not None:
                chord = chord_newton(x_init, host.geometry, host.params, host.physics, previous, rtol)
                if (chord is not None and chord.iterations == 0 and previous.current
                        and parameters.same_problem(initial.parameters)):
                    # At rest already, at the initial solution's own parameters: its factor is the Jacobian
                    # of this point (the same nodes, re-mounted to rounding), as an implicit derivative
                    # needs it; no fresh assembly and LU.
                    chord = chord._replace(factor_current=True)
                if chord is not None:
                    host.extra["warm_start"] = "chord Newton with the initial solution's factor"
                    return finish(chord, steps, extra=dict(host.extra, relax_steps=0))
            if initial is not None:
                # Beyond the chord iteration's reach (a design step's change of the Jacobian), or no factor (a
                # start of nodes: the bay before's shape, `bays.Loop`): Newton proper from the warm start,
                # without load continuation and with few iterations, before any relaxation (which from a
                # nearby shape still takes about as many steps as from the mounted one).
                near = newton(x_init, host.geometry, host.params, host.physics, rtol,
                              replace(self.newton, continuation=False, max_iterations=WARM_NEWTON_ITERATIONS),
                              divergence_bound=host.bay.divergence_bound)
                if near.result == Result.converged:
                    host.extra["warm_start"] = ("Newton from the initial solution" if previous is not None
                                                else "Newton from the initial nodes")
                    return finish(near, steps, extra=dict(host.extra, relax_steps=0))
            ahead.ready(prepared.get(tuple(x_init.shape)))
            out, _, nodes = relax(x_init, host.geometry, relax_rtol, with_forces=False)
            jax.block_until_ready(out)
            steps += int(out.chunks) * RELAX_CHUNK
            ahead.ready(prepared.get("newton"))
            if int(out.result) == Result.converged:
                host.extra["relax_steps"] = steps
                result = newton(nodes, host.geometry, host.params, host.physics, rtol, self.newton,
                                divergence_bound=host.bay.divergence_bound)
                return finish(result, steps, extra=host.extra)
            # Newton was to finish: the forces of where the relaxation stopped
            f = static_forces(nodes, host.geometry, host.params, host.physics)
            return make_solution(out, f, nodes, steps, time.perf_counter() - start, self.name, parameters,
                                 host.bay, extra=host.extra, detail=_relax_detail(int(out.result), host.extra))


@dataclass(frozen=True)
class Explicit(HostOnly):
    """The paper's scheme as written (`explicit.simulate`): physical mass, central differences, CFL step.

    It comes to rest only through the scene's damping (the fabric's viscosity,
    the aerodynamic damping); the pressure is applied at once.

    Args:
        courant: Courant coefficient ``alpha_k`` of eq. (16).
        record_every: steps between stop tests and history records.
        precision: "float64" or "float32" (as `Relax`'s).
    """

    courant: float = DEFAULT_COURANT
    record_every: int = 200
    precision: str = "float64"
    name: ClassVar[str] = "explicit"

    def __post_init__(self):
        check_precision(self.precision)

    def solve(self, scene: Scene, parameters: Parameters, *, rtol: float, max_steps: int, initial) -> Solution:
        """`explicit.simulate` to rest at concrete ``parameters``, not raising."""
        return simulate(scene, parameters, rtol=rtol, max_steps=max_steps, initial=initial, courant=self.courant,
                        record_every=self.record_every, precision=self.precision, throw=False)

