"""A whole wing: N bays between N + 1 rigid ribs, solved together (`solve_bays`, `solve_wing`).

Given rigid ribs, the bays of a wing are independent: each is a `Bay`
between its two ribs (with their sections and chords: taper), and all share
one inflation pressure and one fabric, so their equilibrium is
differentiable in the shared `Parameters` bay by bay (`implicit`). Per-rib
shapes (``rib_shapes``, one row per rib: bay ``k`` is mounted between rows
``k`` and ``k + 1``) and per-bay cut fields (``cut_patterns``, one row per
bay, `model.cut_field`) are mapped over the bays and differentiated like the
parameters. A warm start (``initial``: an earlier `BaysSolution`) starts
every bay from its earlier displacement added to this solve's mounted shape
(as `solution.initial_nodes` does for one bay), so a design loop re-solves a
nearby design in fewer steps.

Two strategies, as values: `Loop` ("loop", `solve_equilibrium` on each bay
in turn: the faster way on a CPU, ``benchmarks/wing_batch.py``) and `Batch`
("batch", one ``jax.jit(jax.vmap(...))`` relaxation of the stacked bays'
`forces.Geometry` with the matrix-free Krylov adjoint: for accelerators);
"auto" picks by the backend (`default_strategy`). Both give the same nodes
within the solver tolerance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from .. import forces as fk
from ..derivatives.custom_jvp import as_adjoint, nodes_only, presolved
from ..model.bay import N_CONTOUR, N_SPAN
from ..model.fabric import Fabric
from ..model.parameters import as_parameters, bay_parameters
from ..model.scene import Scene
from ..model.wing import Wing
from ..precision import float64_scope
from ..programs import rounding_floors_compiled
from ..solution import BaysSolution, ConvergenceError, Result, Solution
from ..solve import METHOD_KNOBS, MOVED, as_method, refuse_moved, solve_equilibrium
from .bay_starts import chains, from_the_bay_before, mounted_shape, presolve
from .loop import check_stop
from .methods import Relax
from .relax import RELAX_CHUNK, relaxed_nodes

__all__ = ["check_rib_gaps", "solve_wing", "solve_bays", "Loop", "Batch", "STRATEGIES", "as_strategy",
           "default_strategy"]

#: A bay is refused when rounding its node positions to float64 can leave a relative residual
#: (`forces.rounding_residual_floor`) above this many times ``rtol``. Measured on 5x32 NACA 2412
#: bays at 1e4 Pa: the relaxation stalls at 0.005-0.006 times that estimate, so ribs 1e-6 m and
#: 3e-5 m apart (estimates 7.5e3 and 830 times rtol = 1e-8) ran their 200,000 and 50,000 steps
#: without converging, while 1e-4 m (75 times) converged in 600 steps.
ROUNDING_MARGIN = 100.0


def stack_trees(trees):
    return jax.tree_util.tree_map(lambda *leaves: jnp.stack([jnp.asarray(x) for x in leaves]), *trees)


def _bay_equilibrium(geometry, bound, displacement, shape_root, shape_tip, field, params, rtol, physics,
                     max_chunks):
    if shape_root is not None:  # per-rib shapes: this bay's two ribs
        params = params._replace(rib_shape_root=shape_root, rib_shape_tip=shape_tip)
    if field is not None:  # per-bay cut fields: this bay's
        params = params._replace(cut_pattern=field)
    mounted = fk.mounted_nodes(geometry, params)
    # Held nodes (ribs, seams) start mounted; free nodes keep the warm start's displacement.
    x_init = mounted + jax.lax.stop_gradient(displacement) * geometry.free[..., None]
    nodes, out = relaxed_nodes(x_init, geometry, params, rtol, bound, physics, max_chunks, half=False)
    return nodes, out.result, out.residual, out.chunks * RELAX_CHUNK, jax.lax.stop_gradient(mounted)


@partial(jax.jit, static_argnames=("physics", "max_chunks"))
def batched_equilibrium(geometries, bounds, displacements, shapes_root, shapes_tip, fields, params, rtol, physics,
                      max_chunks):
    solve = partial(_bay_equilibrium, physics=physics, max_chunks=max_chunks)
    return jax.vmap(solve, in_axes=(0, 0, 0, 0, 0, 0, None, None))(geometries, bounds, displacements, shapes_root,
                                                                    shapes_tip, fields, params, rtol)


def check_rib_gaps(wing: Wing, fabric: Fabric, parameters, *, n_span: int = N_SPAN, n_contour: int = N_CONTOUR,
                   rtol: float = 1e-8) -> None:
    """Refuse ribs too close for the grid: a bay whose float64 rounding floor is above `ROUNDING_MARGIN`
    times ``rtol`` at these (concrete) parameters. `solve_wing` checks every concrete solve; a design
    loop, whose solves are traced, checks its start with this.

    Raises:
        ValueError: naming the two ribs, their gap and the least gap that works.
    """
    parameters = as_parameters(parameters).resolved(fabric).check()
    bays = wing.bays(n_span, n_contour)
    scene = Scene(bays[0], fabric)
    physics = fk.static_physics(scene.physics(dynamic=False))
    with float64_scope():
        params = scene.params(parameters)
        eps = float(np.finfo(np.float64).eps)
        geometries = fk.Geometry(*(np.stack(parts) for parts in zip(*(map(np.asarray, b.geometry()) for b in bays))))
        floors = np.asarray(rounding_floors_compiled(geometries, params, physics, eps)).tolist()
    for k, (bay, floor) in enumerate(zip(bays, floors)):
        if floor > ROUNDING_MARGIN * rtol:
            gap = bay.rib_spacing
            needed = gap * math.sqrt(floor / (ROUNDING_MARGIN * rtol))  # the floor falls as 1/gap^2
            raise ValueError(
                f"ribs {k} and {k + 1} (stations {wing.stations[k]:g} and {wing.stations[k + 1]:g} m) are "
                f"only {gap:.3g} m apart: on the {bay.n_span}x{bay.n_contour} grid (rows {gap / (bay.n_span - 1):.3g} "
                f"m apart) rounding the node positions alone leaves bay {k} a relative residual of about "
                f"{floor:.2g} (estimate), far above rtol={rtol:g}, so it cannot converge; place the ribs at "
                f"least {needed:.2g} m apart, or merge them")


def solve_wing(wing: Wing, fabric: Fabric, parameters=None, prestrain=None, *, n_span: int = N_SPAN,
               n_contour: int = N_CONTOUR, rtol: float = 1e-8, tension_only: bool = True, **options) -> BaysSolution:
    """Every bay of ``wing`` at one pressure: `solve_bays` of ``wing.scenes(...)``.

    Args:
        wing: the ribs.
        fabric: the skin's material (one for the whole wing).
        parameters: a `Parameters` (or the pressure in Pa with ``prestrain``),
            shared by all bays; JAX values allowed (``jax.grad`` of a function
            of the nodes differentiates every bay implicitly).
        n_span, n_contour: the grid of every bay.
        rtol: relative residual each bay is solved to.
        tension_only: the scene switch (no compression, wrinkles).
        **options: `solve_bays`'s other keywords (``max_steps``, ``method``,
            ``initial``, ``rib_shapes``, ``cut_patterns``, ``strategy``,
            ``throw``, method knobs).

    Returns:
        A `BaysSolution`. A failed bay is reported by its result code, not
        raised; its nodes are NaN (the implicit fixed point is undefined).

    Raises:
        ValueError: as `solve_bays`, or for ribs too close for the grid to
            reach ``rtol`` (`ROUNDING_MARGIN`; the message names the ribs,
            their gap and the least gap that works).
    """
    given = as_parameters(parameters, prestrain)
    if not given.is_traced():  # (a design loop, whose solves are traced, checks its start itself)
        check_rib_gaps(wing, fabric, given, n_span=n_span, n_contour=n_contour, rtol=rtol)
    return solve_bays(wing.scenes(fabric, n_span, n_contour, tension_only=tension_only), given, rtol=rtol,
                      **options)


def default_strategy() -> str:
    """"loop" when JAX's default backend is the CPU, else "batch": the name of the strategy "auto" takes."""
    return "loop" if jax.default_backend() == "cpu" else "batch"


def as_strategy(strategy):
    """The strategy value of ``strategy``: a value as it is, or a shortcut name (`STRATEGIES`, or "auto":
    `default_strategy`'s).

    Raises:
        ValueError: for an unknown name.
    """
    if isinstance(strategy, str):
        if strategy not in ("auto", *STRATEGIES):
            raise ValueError(f"strategy must be one of {('auto', *STRATEGIES)}, got {strategy!r}")
        return STRATEGIES[default_strategy() if strategy == "auto" else strategy]
    return strategy


#: Keywords `solve_bays` took once, and where they live now.
_MOVED = {**MOVED, "linear_solver": "it is a knob of the loop's implicit derivative: "
                                    "strategy=Loop(adjoint=ImplicitAdjoint(linear_solver=...))"}


def solve_bays(scenes, parameters=None, *, rtol: float = 1e-8, max_steps: int = 200_000, method="relax",
               initial: BaysSolution | None = None, rib_shapes=None, cut_patterns=None, strategy="auto",
               throw: bool = False, **knobs) -> BaysSolution:
    """The equilibrium of N >= 1 bays sharing one `Parameters`; differentiable like `solve_equilibrium`.

    Args:
        scenes: one `Scene` per bay, root to tip: one fabric, the same physics
            switches and the same grid shape.
        parameters: a `Parameters`, or the pressure in Pa; JAX values allowed
            (``jax.grad``, ``jax.vjp``, ``jax.jvp``).
        rtol: relative residual ``||R_free|| / (p A)`` each bay is solved to.
        max_steps: step cap (per bay and grid level on the loop; for the
            whole batch, which runs until its slowest bay stops).
        method: as `solve_equilibrium`'s (the loop); the batch runs
            `methods.Relax`.
        initial: None, or an earlier `BaysSolution` of these bays on this
            grid (not differentiated). The loop passes each bay its earlier
            `Solution` where it has one (so "relax+newton" first tries chord
            Newton with its factor), else the earlier displacement added to
            this solve's mounted shape, as the batch does.
        rib_shapes: None, or ``(n_bays + 1, 2 K)`` rib-shape coefficients, one
            row per rib: bay ``k`` lies between rows ``k`` and ``k + 1`` (its
            ``rib_shape`` and ``rib_shape_tip``). JAX values allowed.
        cut_patterns: None, or ``(n_bays, 2 K)`` cut-field coefficients, one
            row per bay (its ``cut_pattern``, `forward_solver.model.cut_field`).
            JAX values allowed.
        strategy: `Loop` ("loop"), `Batch` ("batch") or "auto"
            (`default_strategy`); module docstring.
        throw: raise `ConvergenceError` (naming the first failed bay) instead
            of returning the failure codes.
        **knobs: set on the method where it has them (`solve.as_method`), e.g.
            ``sequencing=False`` (small grids compile faster without).

    Returns:
        A `BaysSolution`; ``solutions`` holds the loop's per-bay `Solution`s.
        A failed bay's nodes are NaN there (its result code says why).

    Raises:
        ValueError: for scenes that differ in fabric, switches or grid, bad
            ``rtol``, ``max_steps``, ``method``, ``strategy``, ``initial``,
            ``rib_shapes`` or ``cut_patterns``.
        TypeError: for a knob no method has (one that moved names its place).
        ConvergenceError: if ``throw`` and a bay failed.
    """
    refuse_moved("solve_bays", {k: v for k, v in knobs.items() if k not in METHOD_KNOBS}, _MOVED)
    scenes = list(scenes) if not isinstance(scenes, Scene) else [scenes]
    _check_scenes(scenes)
    first = scenes[0]
    parameters = as_parameters(parameters).resolved(first.fabric)
    first.check_parameters(parameters)
    check_stop(rtol, max_steps=max_steps)
    method = as_method(method, **knobs)
    strategy = as_strategy(strategy)
    strategy.check_method(method)
    n_bays = len(scenes)
    if parameters.rib_shape_tip is not None and n_bays > 1:
        raise ValueError("rib_shape_tip has no meaning for a whole wing: give every rib's shape as "
                         "rib_shapes (n_ribs x 2K), or one rib_shape for all ribs")
    if rib_shapes is not None:
        _check_rows(rib_shapes, "rib_shapes", parameters.rib_shape, n_bays + 1, "rib", "rib shapes")
        if not first.bay.periodic:
            raise ValueError("rib_shapes offset airfoil ribs; these bays are flat panels: leave rib_shapes None")
    if cut_patterns is not None:
        _check_rows(cut_patterns, "cut_patterns", parameters.cut_pattern, n_bays, "bay", "cut fields")
    shape = (n_bays,) + first.bay.shape + (3,)
    if initial is not None:
        if not isinstance(initial, BaysSolution) or tuple(np.shape(initial.nodes)) != shape:
            raise ValueError(f"initial must be a BaysSolution of these bays on their {shape[1]}x{shape[2]} "
                             f"grid ({n_bays} bays), got {type(initial).__name__}"
                             + (f" of shape {tuple(np.shape(initial.nodes))}" if hasattr(initial, "nodes") else ""))
        if not np.all(np.isfinite(np.asarray(initial.displacements()))):
            raise ValueError("initial holds a bay that did not converge (NaN nodes); start that "
                             "solve from the mounted shape (initial=None)")
    with float64_scope(parameters, rib_shapes, cut_patterns):
        shapes = None if rib_shapes is None else jnp.asarray(rib_shapes, jnp.float64)
        fields = None if cut_patterns is None else jnp.asarray(cut_patterns, jnp.float64)
        sol = strategy.solve(scenes, parameters, shapes, fields, rtol=rtol, max_steps=max_steps, method=method,
                             initial=initial)
    if throw and not isinstance(sol.result, jax.core.Tracer):
        failed = sol.failed_bays()
        if failed:
            raise ConvergenceError(sol.bay_solution(failed[0]), (failed[0], len(failed), n_bays))
    return sol


def _check_rows(rows, name: str, shared, count: int, what: str, things: str) -> None:
    """Refuse per-rib or per-bay coefficient ``rows`` (argument ``name``, one row per ``what``) that
    are also given once in the `Parameters` (``shared``), are not ``(count, 2 K)`` or not finite."""
    if shared is not None:
        raise ValueError(f"give the {things} once: per {what} as {name}, or one parameters.{name[:-1]} "
                         f"for every {what}, not both")
    size = np.shape(rows)
    if len(size) != 2 or size[0] != count or size[1] < 2 or size[1] % 2:
        raise ValueError(f"{name} must be an ({count}, 2K) array, one row of 2K >= 2 coefficients per {what}, "
                         f"got shape {size}")
    if not isinstance(rows, jax.core.Tracer) and not np.all(np.isfinite(np.asarray(rows))):
        raise ValueError(f"{name} must be finite")


def _check_scenes(scenes) -> None:
    """One clear line for scenes that cannot share one solve."""
    if not scenes:
        raise ValueError("solve_bays needs at least one Scene (one per bay)")
    for k, scene in enumerate(scenes):
        if not isinstance(scene, Scene):
            raise TypeError(f"scenes must be forward_solver.Scene objects; item {k} is {type(scene).__name__}")
    first = scenes[0]
    for k, scene in enumerate(scenes[1:], start=1):
        differs = [name for name in ("tension_only", "gravity", "gravity_acceleration", "aerodynamic_damping")
                   if getattr(scene, name) != getattr(first, name)]
        if scene.fabric != first.fabric:
            differs.insert(0, "fabric")
        if scene.bay.shape != first.bay.shape:
            differs.append(f"grid {scene.bay.shape[0]}x{scene.bay.shape[1]} (bay 0: "
                           f"{first.bay.shape[0]}x{first.bay.shape[1]})")
        if scene.bay.periodic != first.bay.periodic:
            differs.append("contour (closed airfoil against flat panel)")
        if differs:
            raise ValueError(f"the bays of one solve share one fabric, physics switches and grid; scene {k} "
                             f"differs from scene 0 in: {', '.join(differs)}")


def _concrete_solution(solution: Solution) -> Solution:
    """A `Solution` returned under eager ``jax.grad`` with its primal (concrete) nodes and tensions."""
    if not isinstance(solution.nodes, jax.core.Tracer) or "primal_nodes" not in solution.extra:
        return solution
    # Solved under `custom_jvp.nodes_only`: the tensions are the concrete solve's already.
    nodes = jnp.asarray(solution.extra["primal_nodes"], jnp.float64)
    extra = {k: v for k, v in solution.extra.items() if k != "primal_nodes"}
    return solution.replace(nodes=np.asarray(nodes), tension_span=np.asarray(solution.tension_span),
                            tension_chord=np.asarray(solution.tension_chord), wrinkled=np.asarray(solution.wrinkled),
                            extra=extra)


@dataclass(frozen=True)
class Loop:
    """The "loop" strategy: `solve_equilibrium` on each bay in turn (float64 scope on).

    Every method, grid sequencing, half-bay symmetry, Newton and the factor
    reuse of a warm start: the faster way on a CPU. From cold, each bay after
    the first of its half of the wing (`chains`) starts from the bay before's
    shape (`from_the_bay_before`); with a host method, the bays' host solves
    are made first, two at a time where there is a second core (`presolve`,
    `threads.each`: warm, bay by bay; cold, the two halves), and each bay's
    `solve_equilibrium` then takes its own (the same `Solution` it would have
    solved).

    Args:
        adjoint: each bay's derivative (`solve_equilibrium`'s ``adjoint``:
            "implicit", or an `implicit.ImplicitAdjoint` with its linear solver).
    """

    adjoint: object = "implicit"
    name: ClassVar[str] = "loop"

    def check_method(self, method) -> None:
        """Every method runs on the loop."""

    def solve(self, scenes, parameters, shapes, fields, *, rtol, max_steps, method, initial) -> BaysSolution:
        """The bays' `BaysSolution` (``shapes``, ``fields``: float64 per-rib shapes and per-bay cut fields, or None)."""
        solutions, nodes, mounted = [], [], []
        moved = None if initial is None or initial.solutions is not None else initial.displacements()
        done = presolve(scenes, parameters, shapes, fields, rtol, max_steps, method, initial,
                        as_adjoint(self.adjoint))
        for k, scene in enumerate(scenes):
            p = bay_parameters(parameters, shapes, k, fields)
            rest = done[id(scene)][3] if id(scene) in done else mounted_shape(scene, p)
            if initial is None:
                first = any(k == run.start for run in chains(len(scenes)))
                start = None if first else from_the_bay_before(method, rest, solutions[-1], mounted[-1])
            elif initial.solutions is not None:
                start = initial.solutions[k]
            else:  # a batch's solution: its displacement on this solve's mounted shape
                start = rest + jnp.asarray(moved[k], jnp.float64)
            if id(scene) in done and not p.is_traced():  # (concrete parameters: the presolve's is the solve)
                sol = done[id(scene)][2]
            else:
                with nodes_only(), presolved(done):  # the tensions returned are the primal's (`_concrete_solution`)
                    sol = solve_equilibrium(scene, p, rtol=rtol, max_steps=max_steps, method=method,
                                            initial=start, throw=False, adjoint=self.adjoint)
            traced = bool(sol.extra.get("traced"))
            if traced:  # under jax.jit / vmap: result codes are arrays
                x = jnp.where(sol.result == Result.converged, sol.nodes, jnp.nan)
            elif sol.converged:
                x = sol.nodes
            else:
                x = np.full(np.shape(sol.nodes), np.nan)
            nodes.append(x)
            mounted.append(rest)
            solutions.append(sol if traced else _concrete_solution(sol))
        if any(isinstance(x, jax.core.Tracer) for x in nodes):
            stacked = _stack_nodes(nodes)
        else:
            stacked = np.stack([np.asarray(x, np.float64) for x in nodes])
        if any(isinstance(s.result, jax.core.Tracer) for s in solutions):
            result = jnp.stack([jnp.asarray(s.result) for s in solutions])
            residual = jnp.stack([jnp.asarray(s.residual) for s in solutions])
            steps = jnp.stack([jnp.asarray(s.steps) for s in solutions])
            rest = jnp.stack(mounted)
        else:
            result = np.asarray([int(s.result) for s in solutions], np.int32)
            residual = np.asarray([float(s.residual) for s in solutions])
            steps = np.asarray([int(s.steps) for s in solutions])
            rest = np.stack([np.asarray(m) for m in mounted])
        first = scenes[0]
        return BaysSolution(nodes=stacked, result=result, residual=residual, steps=steps,
                            bays=[s.bay for s in scenes], parameters=parameters, fabric=first.fabric,
                            tension_only=first.tension_only, mounted=rest, rib_shapes=shapes,
                            solutions=solutions, scenes=list(scenes), cut_patterns=fields)


@jax.jit
def _stack_nodes(nodes):
    """``(n_bays, ...)`` float64 stack of the bays' nodes: one program under an eager transformation
    (the design's forward mode), not an eager conversion and stack of the primal and tangent apiece."""
    return jnp.stack([jnp.asarray(x, jnp.float64) for x in nodes])


@dataclass(frozen=True)
class Batch:
    """The "batch" strategy: one ``jax.jit(jax.vmap(...))`` relaxation of every bay (float64 scope on).

    `methods.Relax` only (no grid sequencing, the full grid), derivatives by
    the matrix-free Krylov adjoint (`krylov.BiCGStab`): for accelerators.
    """

    name: ClassVar[str] = "batch"

    def check_method(self, method) -> None:
        """Refuse a method other than the relaxation."""
        if not isinstance(method, Relax):
            raise ValueError(f"the batch strategy runs method='relax' only, got {method.name!r}: use strategy='loop'")

    def solve(self, scenes, parameters, shapes, fields, *, rtol, max_steps, method, initial) -> BaysSolution:
        """The bays' `BaysSolution` (as `Loop.solve`; ``method`` is a `methods.Relax`)."""
        del method  # relax, and the matrix-free adjoint of `krylov`
        first = scenes[0]
        bays = [scene.bay for scene in scenes]
        physics = fk.static_physics(first.physics(dynamic=False))
        params = first.params(parameters)  # the fabric's constants: the same for every bay
        geometries = stack_trees([bay.geometry() for bay in bays])
        bounds = jnp.asarray([bay.divergence_bound for bay in bays], jnp.float64)
        if initial is None:
            displacements = jnp.zeros((len(bays),) + first.bay.shape + (3,), jnp.float64)
        else:
            displacements = jnp.asarray(initial.displacements(), jnp.float64)
        nodes, result, residual, steps, mounted = batched_equilibrium(
            geometries, bounds, displacements, None if shapes is None else shapes[:-1],
            None if shapes is None else shapes[1:], fields, params, jnp.asarray(rtol, jnp.float64), physics,
            -(-max_steps // RELAX_CHUNK))
        return BaysSolution(nodes=nodes, result=result, residual=residual, steps=steps, bays=bays,
                            parameters=parameters, fabric=first.fabric, tension_only=first.tension_only,
                            mounted=mounted, rib_shapes=shapes, solutions=None, scenes=list(scenes),
                            cut_patterns=fields)


#: The strategies of `solve_bays` by shortcut name ("auto" takes `default_strategy`'s).
STRATEGIES = {"loop": Loop(), "batch": Batch()}
