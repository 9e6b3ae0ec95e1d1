"""`solve_equilibrium`: the rest state of a pressurised bay."""

from __future__ import annotations

import time
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from . import forces as fk
from .precision import float32_floor, precision_extra
from .compilation import Ahead, compiling, signature
from .derivatives.custom_jvp import ADJOINTS, LINEAR_SOLVERS, default_linear_solver, differentiable_solution
from .solvers.explicit import simulate
from .solvers.chain import run_chain
from .derivatives.implicit import batched_rhs_task, expected_tangents
from .solvers.loop import LoopOutput
from .solvers.newton import chord_newton, newton, warm_up
from .model.parameters import Parameters, as_parameters
from .solvers.relax import MASS_SAFETY, relax_jit
from .model.scene import PRECISIONS, Scene, float64_scope
from .solution import Result, Solution, initial_nodes, make_solution, mounted_compiled, static_forces
from .solvers.traced import has_abstract_values, traced_solution

__all__ = ["solve_equilibrium", "float32_residual_floor", "METHODS", "FLOAT32_METHODS"]

METHODS = ("relax", "newton", "relax+newton", "explicit", "auto")
#: Methods that may iterate in float32 (Newton's LU and the adjoint need float64).
FLOAT32_METHODS = ("relax", "explicit")

#: Where "relax+newton" hands over from relaxation to Newton: loose enough that
#: relaxation's slow tail is skipped, tight enough that Newton starts in its
#: quadratic basin (no line search or continuation needed on the default bay).
#: 1e-5 until 2026-11-25: the 40-cell design's bays relaxed up to 2200 steps to
#: reach it, and its design took 37.4 s; with 1e-4 it takes 28.6 s (1e-3: 27.3 s),
#: the same 9 wing solves and the same design to 1e-9 (the default case: the same 7).
NEWTON_SWITCH_RTOL = 1e-4

#: Steps per chunk of the relaxation loop (stop test and mass update between chunks).
RELAX_CHUNK = 100
#: Coarsest grid that grid sequencing descends to.
_COARSEST_SPAN = 5
_COARSEST_CONTOUR = 24
#: Relative residual the coarse levels are solved to: their discretisation
#: error is far above it, so a tighter solve there buys nothing.
_COARSE_RTOL = 1e-5


def solve_equilibrium(
    scene: Scene,
    parameters=None,
    prestrain=None,
    *,
    pressure=None,
    stiffness=None,
    rib_thickness_scale=None,
    rib_chord_scale=None,
    rtol: float = 1e-8,
    max_steps: int = 200_000,
    method: str = "relax",
    initial=None,
    throw: bool = True,
    sequencing: bool = True,
    symmetry: bool = True,
    precision: str = "float64",
    adjoint: str = "implicit",
    linear_solver: str | None = None,
) -> Solution:
    """Rest shape of the pressurised bay; differentiable in its `Parameters`.

    Equilibrium is where the static force residual ``R(x)`` of eq. (10)-(15)
    vanishes on the free nodes; it does not depend on the fabric's mass,
    viscosity or the aerodynamic damping.

    Derivatives. Under ``jax.grad``, ``jax.jacfwd``, ``jax.jvp`` or
    ``jax.vjp`` of the parameters, the returned `Solution`'s nodes and
    tensions are differentiable: ``jax.grad(lambda q: f(solve_equilibrium(
    scene, q).nodes))(parameters)`` returns a `Parameters` of derivatives.
    ``adjoint="implicit"`` (default) differentiates the equilibrium by the
    implicit function theorem (eq. 10-15 residual, `adjoint`): one linear
    solve with the Jacobian ``J`` per tangent or gradient, whatever the
    number of parameters, by one of two solvers (``linear_solver``):
    "lu", the sparse LU of ``J`` on the host (scipy, through
    ``jax.pure_callback``; the factor of a Newton solve is reused), or
    "iterative", a matrix-free block-Jacobi BiCGStab in JAX (`krylov`; no
    host callback, so it runs on any backend). None picks "lu" when JAX's
    default backend is the CPU and "iterative" otherwise (a host callback
    fails where JAX sees only a GPU). Either way the derivative's error is
    of the order of the relative residual, so solve to a tight ``rtol``
    (`adjoint.GRADIENT_RTOL`) where it must be accurate.
    ``adjoint="unrolled"`` differentiates through ``max_steps`` steps of a
    pure-JAX dynamic relaxation instead (slow; for checks on small grids).

    Under ``jax.jit`` and ``jax.vmap``. When the parameters are abstract
    (traced by ``jax.jit``, or batched by ``jax.vmap``), the solve cannot
    run on the host: method "relax" then runs as one pure-JAX program
    (`jit_equilibrium`): the relaxation from the mounted shape or ``initial``, no
    grid sequencing, at most ``max_steps`` steps, the result code, steps and
    residual returned as arrays in the `Solution`; derivatives by the
    implicit function theorem with the iterative solver. A failure cannot
    raise inside a compiled call, so ``throw=False`` is required there:
    check ``solution.converged`` (or call ``raise_if_failed()`` on the
    result outside the transformation). The other methods (Newton's sparse
    LU, the paper's scheme with its history) are host code and raise a
    TypeError naming "relax". A `jax.vmap` batch runs until its slowest
    member stops. Both ways need float64 on (``jax.enable_x64``).

    Args:
        scene: the bay, fabric and physics switches.
        parameters: a `Parameters`, or the internal overpressure in Pa (> 0)
            with the loose values below.
        prestrain: ``(span, chord)`` prestrain (0.005 is 0.5%), or one number.
        pressure: Pa, when not given as ``parameters``.
        stiffness: ``(span, chord)`` N/m overriding the fabric's.
        rib_thickness_scale: rib thickness multiplier (about the camber line).
        rib_chord_scale: rib chord multiplier.
        rtol: stop when ``||R_free||_2 / (p A) <= rtol`` (A the nominal skin
            area): the residual force as a fraction of the total pressure load.
        max_steps: cap on explicit steps (per grid level).
        method: "relax" (dynamic relaxation, default); "newton" (sparse
            Newton from the start shape, with load continuation);
            "relax+newton" (relaxation to `NEWTON_SWITCH_RTOL`, then Newton;
            its factorised Jacobian is kept in `Solution.factor` for
            adjoint solves; warm-started from such a solution it first tries
            chord Newton with that factor, see `newton.chord_newton`); or
            "explicit" (the paper's physical-mass scheme via `simulate`; it
            needs the scene's viscosity or aerodynamic damping to come to rest);
            or "auto": "relax+newton", then Newton from where it stopped,
            then Newton with load continuation from the mounted shape, until
            one converges (`fallback`; a failure's message names every try).
        initial: warm start, a `Solution` (or nodes array) on the same grid.
        throw: raise `ConvergenceError` if the solve fails; else return the
            `Solution` with its failure code.
        sequencing: solve coarser grids first (relax, cold starts only).
        symmetry: solve half the bay when both ribs are identical and
            ``n_span`` is odd (relax; the answer is the same, see tests).
        precision: "float64" (default) or "float32" (methods "relax" and
            "explicit" only): the iteration runs in float32, the stop test
            and the returned `Solution` (float64 arrays, residual evaluated
            at the returned nodes) in float64. An ``rtol`` below
            `float32_residual_floor` of the scene is refused (see
            `_precision` for the rule and the measurements).
        adjoint: "implicit" or "unrolled": how derivatives are taken (above).
        linear_solver: "lu", "iterative" or None (the backend's default):
            the implicit derivative's linear solver (above). Under
            ``jax.jit`` / ``jax.vmap`` only "iterative" (or None) applies.

    Returns:
        The `Solution`; ``extra["precision"]`` records the iteration's type.

    Raises:
        ValueError: for non-physical input, or float32 asked of Newton or
            for an ``rtol`` below its floor.
        TypeError: parameters traced by ``jax.jit`` or ``jax.vmap`` with a
            method other than "relax", ``throw=True``, ``adjoint="unrolled"``,
            ``linear_solver="lu"`` or ``precision="float32"``.
        ConvergenceError: if ``throw`` and the solve failed.
    """
    parameters = as_parameters(parameters, prestrain, pressure=pressure, stiffness=stiffness,
                               rib_thickness_scale=rib_thickness_scale,
                               rib_chord_scale=rib_chord_scale).resolved(scene.fabric)
    scene.check_parameters(parameters)
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if not (isinstance(rtol, float | int) and 0 < rtol < 1):
        raise ValueError(f"rtol must lie in (0, 1), got {rtol!r}")
    if not (isinstance(max_steps, int) and max_steps >= 1):
        raise ValueError(f"max_steps must be a positive integer, got {max_steps!r}")
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {sorted(PRECISIONS)}, got {precision!r}")
    if precision == "float32" and method not in FLOAT32_METHODS:
        raise ValueError(
            f"precision='float32' is available for methods {FLOAT32_METHODS}, not {method!r}: "
            "Newton's sparse LU, its quadratic convergence and the adjoint need float64; use "
            "precision='float64' or method='relax'"
        )
    if adjoint not in ADJOINTS:
        raise ValueError(f"adjoint must be one of {ADJOINTS}, got {adjoint!r}")
    if linear_solver is not None and linear_solver not in LINEAR_SOLVERS:
        raise ValueError(f"linear_solver must be one of {LINEAR_SOLVERS} or None, got {linear_solver!r}")
    if has_abstract_values(parameters):
        _check_transformable(method, throw, adjoint, linear_solver, precision)
        return traced_solution(scene, parameters, rtol=rtol, initial=initial,
                               half=_use_half_bay(scene, parameters, symmetry), chunk=RELAX_CHUNK,
                               max_chunks=-(-max_steps // RELAX_CHUNK))
    linear_solver = linear_solver or default_linear_solver()

    def solve(concrete: Parameters) -> Solution:
        if method == "explicit":
            return simulate(scene, concrete, rtol=rtol, max_steps=max_steps, initial=initial,
                            precision=precision, throw=False)
        if method == "auto":
            return run_chain(lambda m, start: _solve(scene, concrete, rtol, max_steps, m, start, sequencing,
                                                     symmetry, precision), initial)
        return _solve(scene, concrete, rtol, max_steps, method, initial, sequencing, symmetry, precision)

    if parameters.is_traced():
        sol = differentiable_solution(scene, parameters, solve, adjoint, rtol, max_steps,
                                      linear_solver=linear_solver)
    else:
        sol = solve(parameters)
    if throw:
        sol.raise_if_failed()
    return sol


def _check_transformable(method, throw, adjoint, linear_solver, precision) -> None:
    """Refuse, with what to change, the options the pure-JAX (jit / vmap) path cannot honour."""
    where = "under jax.jit or jax.vmap of the parameters"
    if method != "relax":
        raise TypeError(
            f"method={method!r} runs on the host and cannot be traced {where}; use method='relax' "
            "(the pure-JAX relaxation), or call solve_equilibrium eagerly")
    if throw:
        raise TypeError(
            f"a solve {where} cannot raise on failure: pass throw=False and check "
            "solution.converged (or call solution.raise_if_failed() outside the transformation)")
    if adjoint != "implicit":
        raise TypeError(f"adjoint={adjoint!r} is for eager checks; {where} use adjoint='implicit'")
    if linear_solver == "lu":
        raise TypeError(
            f"linear_solver='lu' needs concrete values (a host sparse LU); {where} use "
            "linear_solver='iterative' or None")
    if precision != "float64":
        raise TypeError(f"precision={precision!r} is available eagerly only; {where} use 'float64'")


def _use_half_bay(scene, parameters, symmetry: bool) -> bool:
    """Whether the relaxation solves half the bay (both ribs alike, odd ``n_span``)."""
    return _use_half(scene.bay.geometry(), symmetry and scene.symmetric(parameters))


def _solve(scene, parameters, rtol, max_steps, method, initial, sequencing, symmetry,
           precision) -> Solution:
    """The concrete host solve of `solve_equilibrium` (methods relax, newton, relax+newton)."""
    bay = scene.bay
    bound = bay.chord + bay.rib_spacing
    physics = scene.physics(dynamic=False)
    symmetric = symmetry and scene.symmetric(parameters)
    max_chunks = -(-max_steps // RELAX_CHUNK)
    with float64_scope(), Ahead() as ahead:
        dtype = jnp.float64  # inputs, stop test and results; the iteration runs in `precision`
        params = scene.params(parameters, dtype=dtype)
        geometry = bay.geometry()  # float64 within the scope (made once per bay)
        extra = precision_extra(precision, rtol, geometry, params, physics)
        coarse_rtol = _COARSE_RTOL
        if precision == "float32":
            coarse_rtol = max(_COARSE_RTOL, rtol)  # coarser grids have lower floors
        relax_rtol = max(rtol, NEWTON_SWITCH_RTOL) if method == "relax+newton" else rtol
        relax = partial(_relax, params=params, bound=bound, max_chunks=max_chunks, physics=physics,
                        symmetric=symmetric, precision=precision)
        prepared = {}
        if initial is None and method != "newton":
            prepared = _compile_ahead(ahead, relax, geometry, params, physics, sequencing, coarse_rtol,
                                      relax_rtol, newton_next=method == "relax+newton")
        start = time.perf_counter()
        steps = 0
        levels = []
        if initial is None and method == "newton":
            x_init = mounted_compiled(geometry, params)
        elif initial is None:
            x_init, steps, levels = _sequenced_start(geometry, params, physics, relax, sequencing, coarse_rtol,
                                                     prepared)
        else:
            x_init = initial_nodes(initial, geometry, params)
        half = _use_half(geometry, symmetric)
        extra.update(levels=levels, half_bay=half)
        previous = initial.factor if isinstance(initial, Solution) else None
        chord = None
        if method == "relax+newton" and previous is not None:
            chord = chord_newton(x_init, geometry, params, physics, previous, rtol)
            if (chord is not None and chord.iterations == 0 and previous.current
                    and parameters.same_problem(initial.parameters)):
                # At rest already, at the initial solution's own parameters: its factor is the Jacobian
                # of this point (the same nodes, re-mounted to rounding), as an implicit derivative
                # needs it; no fresh assembly and LU.
                chord = chord._replace(factor_current=True)
        newton_solution = partial(_newton_solution, start=start, parameters=parameters, bay=bay,
                                  params=params, geometry=geometry, physics=physics)
        if chord is not None:
            extra["warm_start"] = "chord Newton with the initial solution's factor"
            return newton_solution(chord, steps, extra=dict(extra, relax_steps=0))
        if method == "newton":
            result = newton(x_init, geometry, params, physics, rtol, divergence_bound=bound)
            return newton_solution(result, steps, extra=extra)
        ahead.ready(prepared.get(tuple(x_init.shape)))
        out, f, nodes = relax(x_init, geometry, relax_rtol, with_forces=method != "relax+newton")
        jax.block_until_ready(out)
        steps += int(out.chunks) * RELAX_CHUNK
        if method == "relax+newton" and int(out.result) == Result.converged:
            extra["relax_steps"] = steps
            ahead.ready(prepared.get("newton"))
            result = newton(nodes, geometry, params, physics, rtol, divergence_bound=bound)
            return newton_solution(result, steps, extra=extra)
        if f is None:  # Newton was to finish: the forces of where the relaxation stopped
            ahead.ready(prepared.get("newton"))
            f = static_forces(nodes, geometry, params, physics)
        return make_solution(out, f, steps, time.perf_counter() - start, method, parameters, bay,
                             extra=extra, nodes=nodes, detail=_relax_detail(int(out.result), extra))


def _relax(x, geometry, rtol, with_forces=False, *, params, bound, max_chunks, physics, symmetric, precision,
           compile_only=False):
    """`relax.relax_jit` from ``x`` on ``geometry``'s grid, or (``compile_only``) the task that compiles
    its program for those arguments (`ahead.compiling`): one function builds the arguments of both,
    so they meet."""
    # (NumPy scalars: the same float64 avals as JAX's, without an eager conversion compiled for them)
    args = (x, geometry, params, np.asarray(rtol, np.float64), np.asarray(bound, np.float64), MASS_SAFETY, physics,
            RELAX_CHUNK, max_chunks)
    options = dict(half=_use_half(geometry, symmetric), precision=precision, with_forces=with_forces)
    if compile_only:
        return compiling(relax_jit, *args, **options)
    return relax_jit(*args, **options)


def _compile_ahead(ahead: Ahead, relax, geometry, params, physics, sequencing: bool, coarse_rtol: float,
                   relax_rtol: float, newton_next: bool) -> dict:
    """Submit to ``ahead`` what a cold solve compiles after its coarsest relaxation: the relaxation of
    every finer grid-sequencing level, coarse to fine, then (``newton_next``) Newton's programs on
    the full grid (`newton.warm_up`). Returns the handles by level shape ``(ns, nc, 3)`` and
    ``"newton"``."""
    grids = [geometry]
    while sequencing and coarsenable(grids[-1].free.shape, physics.periodic):
        grids.append(_coarsen(grids[-1]))
    options = tuple(relax.keywords[k] for k in ("max_chunks", "symmetric", "precision"))
    prepared, prolongations = {}, []
    for k in range(len(grids) - 2, -1, -1):  # the coarsest (last) is the solve's own first program
        shape = tuple(grids[k].free.shape) + (3,)
        x = np.zeros(shape)  # (NumPy: no eager program to compile for a placeholder)
        key = ("relax", signature(x, grids[k], params), physics, options)
        rtol, with_forces = (relax_rtol, not newton_next) if k == 0 else (coarse_rtol, False)
        prepared[shape] = ahead.submit(key + (with_forces,), relax(x, grids[k], rtol, with_forces, compile_only=True))
        xc = np.zeros(tuple(grids[k + 1].free.shape) + (3,))
        prolongations.append((("prolong", shape), ("prolong", signature(x, xc, grids[k].free), physics.periodic),
                              compiling(_prolonged, x, xc, xc, grids[k].free, physics.periodic)))
    # The small programs that carry a level's solution to the next after the long ones: if the
    # solve reaches one first it compiles it itself, beside the worker's longer compilation.
    for name, key, task in prolongations:
        prepared[name] = ahead.submit(key, task)
    if newton_next:
        x = np.zeros(tuple(geometry.free.shape) + (3,))
        prepared["newton"] = ahead.submit(("newton", signature(x, geometry, params), physics),
                                          partial(warm_up, x, geometry, params, physics))
    n_tangents = expected_tangents()
    if n_tangents and default_linear_solver() == "lu":  # the design's forward-mode derivative next
        ahead.submit(*batched_rhs_task(geometry, params, physics, n_tangents))
    return prepared


def float32_residual_floor(scene: Scene, parameters=None, prestrain=None, *, pressure=None,
                           stiffness=None, rib_thickness_scale=None, rib_chord_scale=None) -> float:
    """Smallest ``rtol`` that a ``precision="float32"`` solve of this scene accepts.

    `forces.rounding_residual_floor` with float32's machine epsilon: the
    relative residual that rounding the coordinates to float32 can leave.

    Args:
        scene: the bay, fabric and physics switches.
        parameters, prestrain, pressure, stiffness, rib_thickness_scale,
            rib_chord_scale: as for `solve_equilibrium`.

    Returns:
        The floor, dimensionless (``||R_free|| / (p A)``).
    """
    parameters = as_parameters(parameters, prestrain, pressure=pressure, stiffness=stiffness,
                               rib_thickness_scale=rib_thickness_scale,
                               rib_chord_scale=rib_chord_scale).resolved(scene.fabric).check()
    with float64_scope():
        params = scene.params(parameters)
        geometry = scene.bay.geometry()
        return float32_floor(geometry, params, scene.physics(dynamic=False))


def _relax_detail(code: int, extra: dict) -> str:
    """What to change after a failed relaxation (the `Solution.detail`)."""
    if code == Result.diverged:
        return ("the skin kept inflating past the bound: the pressure is probably beyond what "
                "the fabric can hold at this prestrain (lower the pressure, stiffen the fabric "
                "or raise the prestrain)")
    if code == Result.max_steps_reached and extra.get("precision") == "float32":
        return ("if the residual has stopped falling, the float32 iteration has reached its "
                f"rounding floor (about {extra['float32_floor']:.1e} on this scene): use "
                "precision='float64'; otherwise raise max_steps")
    return ""


def _newton_solution(result, steps, *, start, parameters, bay, params, geometry, physics, extra):
    """A `Solution` from a `newton.NewtonResult` (steps count relaxation steps plus iterations)."""
    x = jnp.asarray(result.x, dtype=geometry.contour_root.dtype)
    f = static_forces(x, geometry, params, physics)
    out = LoopOutput(None, int(result.result), 0, result.residual, None)
    extra = dict(extra, newton_iterations=result.iterations)
    method = "relax+newton" if "relax_steps" in extra else "newton"
    detail = ""
    if int(result.result) != Result.converged:  # the real cause and the counts (not max_steps)
        relax = extra.get("relax_steps")
        detail = (f"Newton stopped after {result.iterations} iterations"
                  + (f" (following {relax} relaxation steps)" if relax else "") + f": {result.message}")
    return make_solution(out, f, steps + result.iterations, time.perf_counter() - start, method,
                         parameters, bay, extra=extra, nodes=x, detail=detail,
                         factor=result.jacobian_factor())


def coarsenable(shape, periodic: bool) -> bool:
    ns, nc = shape
    contour_ok = (nc % 2 == 0) if periodic else (nc % 2 == 1)
    return ns % 2 == 1 and contour_ok and (ns + 1) // 2 >= _COARSEST_SPAN and nc // 2 >= _COARSEST_CONTOUR


def _coarsen(geometry: fk.Geometry) -> fk.Geometry:
    """Every other node along both directions (nested grids, see `Bay`)."""
    return geometry._replace(
        contour_root=geometry.contour_root[::2],
        contour_tip=geometry.contour_tip[::2],
        camber_root=geometry.camber_root[::2],
        camber_tip=geometry.camber_tip[::2],
        free=geometry.free[::2, ::2],
    )


def _prolong(u: jnp.ndarray, periodic: bool) -> jnp.ndarray:
    """Linear interpolation of a coarse nodal field to the nested fine grid."""
    ns, nc = u.shape[:2]
    if periodic:
        mid = 0.5 * (u + jnp.roll(u, -1, axis=1))
        rows = jnp.stack([u, mid], axis=2).reshape(ns, 2 * nc, 3)
    else:
        mid = 0.5 * (u[:, :-1] + u[:, 1:])
        rows = jnp.concatenate(
            [jnp.stack([u[:, :-1], mid], axis=2).reshape(ns, 2 * (nc - 1), 3), u[:, -1:]], axis=1
        )
    mid_rows = 0.5 * (rows[:-1] + rows[1:])
    out = jnp.stack([rows[:-1], mid_rows], axis=1).reshape(2 * (ns - 1), rows.shape[1], 3)
    return jnp.concatenate([out, rows[-1:]], axis=0)


def _use_half(geometry, symmetric: bool) -> bool:
    return symmetric and geometry.free.shape[0] % 2 == 1 and geometry.free.shape[0] >= 5


def _sequenced_start(geometry, params, physics, relax, sequencing, coarse_rtol=_COARSE_RTOL, prepared=None):
    """Starting shape: the mounted shape, or the interpolated coarse-grid solution (``relax``: `_relax`
    with the solve's options; ``prepared``: `_compile_ahead`'s handles)."""
    x0 = mounted_compiled(geometry, params)
    if not (sequencing and coarsenable(geometry.free.shape, physics.periodic)):
        return x0, 0, []
    coarse = _coarsen(geometry)
    xc, steps, levels = _sequenced_start(coarse, params, physics, relax, sequencing, coarse_rtol, prepared)
    Ahead.ready((prepared or {}).get(tuple(xc.shape)))
    out, _, xc_full = relax(xc, coarse, coarse_rtol)
    if int(out.result) != Result.converged:
        return x0, steps, levels  # a failed coarse level is no better than the mounted shape
    xc0 = mounted_compiled(coarse, params)
    Ahead.ready((prepared or {}).get(("prolong", tuple(x0.shape))))
    chunks = int(out.chunks)
    levels = levels + [{"shape": tuple(coarse.free.shape), "steps": chunks * RELAX_CHUNK}]
    return _prolonged(x0, xc_full, xc0, geometry.free, physics.periodic), steps + chunks * RELAX_CHUNK, levels


@partial(jax.jit, static_argnames=("periodic",))
def _prolonged(x0, xc, xc0, free, periodic: bool):
    """The fine grid's start: its mounted shape ``x0`` plus the coarse solution's displacement
    ``xc - xc0`` interpolated (`_prolong`) on the free nodes (one program: twenty eager
    operations before, each compiled on its own and, while a level compiled ahead, waiting for it)."""
    return x0 + _prolong(xc - xc0, periodic) * free[..., None]
