"""`solve_equilibrium`: the rest state of a pressurised bay, by a method value, differentiable by an adjoint value."""

from __future__ import annotations

import dataclasses
from functools import partial

from .derivatives.custom_jvp import as_adjoint, differentiable_solution
from .model.parameters import as_parameters
from .model.scene import Scene
from .precision import float32_floor, float64_scope
from .solution import Solution
from .solvers.chain import Auto
from .solvers.loop import check_stop
from .solvers.methods import Explicit, Newton, Relax, RelaxNewton
from .solvers.relax import has_abstract_values

__all__ = ["solve_equilibrium", "float32_residual_floor", "METHODS", "METHOD_KNOBS", "MOVED", "as_method",
           "refuse_moved"]

#: The equilibrium methods by shortcut name: the default value of each.
METHODS = {"relax": Relax(), "newton": Newton(), "relax+newton": RelaxNewton(), "explicit": Explicit(),
           "auto": Auto()}

#: The knobs of the methods, by name (what `as_method` may set).
METHOD_KNOBS = frozenset(field.name for value in METHODS.values() for field in dataclasses.fields(value))

#: Keywords that `solve_equilibrium` (and `solve_bays`, `solve_wing`) took once, and where they live now.
MOVED = {
    "stiffness": "give it in the Parameters: Parameters(pressure, prestrain_span, prestrain_chord, "
                 "stiffness_span=..., stiffness_chord=...)",
    "rib_thickness_scale": "give it in the Parameters: Parameters(pressure, ..., rib_thickness_scale=...)",
    "rib_chord_scale": "give it in the Parameters: Parameters(pressure, ..., rib_chord_scale=...)",
    "sequencing": "it is a knob of the relaxation: method=Relax(sequencing=...) (or RelaxNewton, Auto)",
    "symmetry": "it is a knob of the relaxation: method=Relax(symmetry=...) (or RelaxNewton, Auto)",
    "precision": "it is a knob of the relaxation and of the paper's scheme: method=Relax(precision=...) or "
                 "Explicit(precision=...); Newton's sparse LU, its quadratic convergence and the adjoint "
                 "need float64",
    "linear_solver": "it is a knob of the implicit derivative: adjoint=ImplicitAdjoint(linear_solver=...)",
}


def refuse_moved(function: str, keywords: dict, moved: dict = MOVED) -> None:
    """A TypeError for the first of ``keywords`` that ``function`` does not take, naming where it lives now."""
    for name in keywords:
        if name in moved:
            raise TypeError(f"{function}() takes no {name}= any more: {moved[name]}")
        raise TypeError(f"{function}() got an unexpected keyword argument {name!r}")


def as_method(method, **knobs):
    """The method value of ``method`` (a value, or a shortcut name of `METHODS`), with ``knobs`` set where
    it has them: a caller that lets the user pick the method may ask, say, for no grid sequencing
    (``sequencing=False``), which Newton, having none, leaves aside.

    Raises:
        ValueError: for an unknown name.
    """
    if isinstance(method, str):
        if method not in METHODS:
            raise ValueError(f"method must be one of {tuple(METHODS)}, got {method!r}")
        method = METHODS[method]
    names = {f.name for f in dataclasses.fields(method)}
    changes = {name: value for name, value in knobs.items() if name in names}
    return dataclasses.replace(method, **changes) if changes else method


def solve_equilibrium(scene: Scene, parameters=None, prestrain=None, *, pressure=None, rtol: float = 1e-8,
                      max_steps: int = 200_000, method="relax", initial=None, throw: bool = True,
                      adjoint="implicit", **moved) -> Solution:
    """Rest shape of the pressurised bay; differentiable in its `Parameters`.

    Equilibrium is where the static force residual ``R(x)`` of eq. (10)-(15)
    vanishes on the free nodes; it does not depend on the fabric's mass,
    viscosity or the aerodynamic damping.

    ``method`` and ``adjoint`` are values with their own knobs, or the
    shortcut names of their defaults: the methods `Relax` ("relax"), `Newton`,
    `RelaxNewton` ("relax+newton"), `Explicit` and `Auto` (`METHODS`,
    `solvers.methods`); the adjoints `ImplicitAdjoint` ("implicit": the
    implicit function theorem, one linear solve per tangent or gradient
    whatever the number of parameters, by its ``linear_solver``;
    `derivatives.implicit`) and `UnrolledAdjoint` ("unrolled": AD through
    ``max_steps`` relaxation steps, a slow check for small grids). Under
    ``jax.grad``, ``jax.jacfwd``, ``jax.jvp`` or ``jax.vjp`` of the
    parameters the nodes and tensions are differentiable: ``jax.grad(lambda
    q: f(solve_equilibrium(scene, q).nodes))(parameters)`` returns a
    `Parameters` of derivatives, whose error is of the order of the relative
    residual (solve to `custom_jvp.GRADIENT_RTOL` where it must be accurate).

    Under ``jax.jit`` or ``jax.vmap`` of the parameters `Relax` runs as one
    pure-JAX program (`relax.traced_solution`; what it does and does not do:
    `relax`'s module docstring), its result code, steps and residual arrays
    in the `Solution`: pass ``throw=False`` and check ``solution.converged``.
    The host methods raise a TypeError naming "relax". Both ways need float64
    on (``jax.enable_x64``).

    Args:
        scene: the bay, fabric and physics switches.
        parameters: a `Parameters` (stiffnesses and rib scales travel there),
            or the internal overpressure in Pa (> 0) with ``prestrain``.
        prestrain: ``(span, chord)`` prestrain (0.005 is 0.5%), or one number.
        pressure: Pa, when not given as ``parameters``.
        rtol: stop when ``||R_free||_2 / (p A) <= rtol`` (A the nominal skin
            area): the residual force as a fraction of the total pressure load.
        max_steps: cap on explicit steps (per grid level).
        method: the method value or its shortcut name (above).
        initial: warm start, a `Solution` (or nodes array) on the same grid.
        throw: raise `ConvergenceError` if the solve fails; else return the
            `Solution` with its failure code.
        adjoint: the adjoint value or its shortcut name (above).
        **moved: keywords taken once (``stiffness``, the rib scales,
            ``sequencing``, ``symmetry``, ``precision``, ``linear_solver``):
            a TypeError names where each lives now (`MOVED`).

    Returns:
        The `Solution`; ``extra["precision"]`` records the iteration's type.

    Raises:
        ValueError: for non-physical input, an unknown shortcut, or a
            float32 ``rtol`` below its floor.
        TypeError: parameters traced by ``jax.jit`` or ``jax.vmap`` with a
            method other than `methods.Relax` (or a float32 one),
            ``throw=True``, the unrolled adjoint or the "lu" linear solver;
            a keyword in ``moved``.
        ConvergenceError: if ``throw`` and the solve failed.
    """
    refuse_moved("solve_equilibrium", moved)
    parameters = as_parameters(parameters, prestrain, pressure=pressure).resolved(scene.fabric)
    scene.check_parameters(parameters)
    method, adjoint = as_method(method), as_adjoint(adjoint)
    check_stop(rtol, max_steps=max_steps)
    if has_abstract_values(parameters):
        where = "under jax.jit or jax.vmap of the parameters"
        method.check_traceable(where)
        if throw:
            raise TypeError(
                f"a solve {where} cannot raise on failure: pass throw=False and check "
                "solution.converged (or call solution.raise_if_failed() outside the transformation)")
        return method.traced(scene, parameters, rtol=rtol, max_steps=max_steps, initial=initial,
                             solver=adjoint.traced_solver(where))
    solve = partial(method.solve, scene, rtol=rtol, max_steps=max_steps, initial=initial)
    if parameters.is_traced():
        sol = differentiable_solution(scene, parameters, solve, adjoint, rtol, max_steps)
    else:
        sol = solve(parameters)
    if throw:
        sol.raise_if_failed()
    return sol


def float32_residual_floor(scene: Scene, parameters=None, prestrain=None, *, pressure=None) -> float:
    """Smallest ``rtol`` that a float32 relaxation (``method=Relax(precision="float32")``) of this scene accepts.

    `forces.rounding_residual_floor` with float32's machine epsilon: the
    relative residual that rounding the coordinates to float32 can leave.

    Args:
        scene: the bay, fabric and physics switches.
        parameters, prestrain, pressure: as for `solve_equilibrium`.

    Returns:
        The floor, dimensionless (``||R_free|| / (p A)``).
    """
    parameters = as_parameters(parameters, prestrain, pressure=pressure).resolved(scene.fabric).check()
    with float64_scope():
        params = scene.params(parameters)
        geometry = scene.bay.geometry()
        return float32_floor(geometry, params, scene.physics(dynamic=False))
