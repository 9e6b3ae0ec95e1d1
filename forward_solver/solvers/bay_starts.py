"""Where each bay of a wing solve starts, and its host solves made ahead (`bays.Loop`; docs/architecture.md).

A cold wing solve takes each bay after the first of its half of the wing from
the bay before's shape (`from_the_bay_before`, `chains`): a wing's
neighbouring bays differ by a step of its taper, and Newton from there
converges in 2-5 iterations where the cold start relaxes for hundreds of
steps. `presolve` makes the bays' host solves before they are
differentiated, two at a time where the machine has a second core
(`threads.each`): warm, bay by bay from each one's own warm start; cold, the
two halves. Each is the `Solution` that `solve_equilibrium` would make where
the bay is differentiated, which then takes it (`custom_jvp.presolved`).
"""

from __future__ import annotations

import jax
import numpy as np

from ..derivatives.custom_jvp import concrete_parameters
from ..derivatives.implicit import top_level
from ..model.parameters import Parameters, as_parameters, bay_parameters
from ..model.scene import Scene
from ..precision import float64_scope
from ..programs import mounted_compiled
from ..solution import Solution
from .methods import HostOnly, RelaxNewton
from .relax import has_abstract_values
from .threads import each, helpers

__all__ = ["chains", "from_the_bay_before", "mounted_shape", "presolve"]


def presolve(scenes, parameters, shapes, fields, rtol, max_steps, method, initial, adjoint) -> dict:
    """The host solves of a wing solve, two at a time where the machine has a second core
    (`threads.each`): ``id(scene) -> (scene, parameters, Solution, mounted)`` for `custom_jvp.presolved`
    (``parameters`` concrete, those the bay's solve poses; ``mounted`` the bay's `mounted_shape` at
    them). Warm (``initial`` a loop's `BaysSolution`), every bay from its own warm start; cold, each of
    the `chains` from its first bay, every later bay from the bay before (`from_the_bay_before`). Each
    is the solve `solve_equilibrium` makes where the bay is differentiated, made before the bays are
    differentiated one after the other, and a bay to be differentiated is `prepared` by ``adjoint``
    (its value) on the thread that solved it. Empty where there is nothing to share (one chain of a
    cold solve, one core, ``jax.jit`` or ``jax.vmap``, a method that is not host-only)."""
    warm = initial is not None and initial.solutions is not None
    cold = initial is None and isinstance(method, RelaxNewton) and len(chains(len(scenes))) > 1
    if not (warm or cold) or len(scenes) < 2 or helpers() == 0 or not isinstance(method, HostOnly):
        return {}
    posed, differentiated = [], []
    for k, scene in enumerate(scenes):
        p = as_parameters(bay_parameters(parameters, shapes, k, fields)).resolved(scene.fabric)
        if has_abstract_values(p):
            return {}
        scene.check_parameters(p)
        # (an eager transformation's primal values: `stop_gradient` is the identity on them, and no tracer)
        posed.append(concrete_parameters(jax.lax.stop_gradient(p)) if p.is_traced() else p)
        differentiated.append(p.is_traced())

    def solve(k, start):
        with top_level():  # (the caller's share runs inside its transformation, as `custom_jvp` solves)
            sol = method.solve(scenes[k], posed[k], rtol=rtol, max_steps=max_steps, initial=start)
            return adjoint.prepared(scenes[k], posed[k], sol) if differentiated[k] else sol

    def rest(k):
        with top_level(), float64_scope():  # (float64 is a thread's own setting: the helper's too)
            return mounted_shape(scenes[k], posed[k])

    if warm:
        solved = each(lambda k: (solve(k, initial.solutions[k]), rest(k)), len(scenes))
    else:
        def chain(bays):
            out, before, before_rest = [], None, None
            with top_level(), float64_scope():  # (float64 is a thread's own setting: the helper's too)
                for k in bays:
                    here = rest(k)
                    out.append((solve(k, from_the_bay_before(method, here, before, before_rest)), here))
                    before, before_rest = out[-1][0], here
            return out

        runs = chains(len(scenes))
        solved = [pair for part in each(lambda c: chain(runs[c]), len(runs)) for pair in part]
    return {id(scene): (scene, posed[k], sol, here) for k, (scene, (sol, here)) in enumerate(zip(scenes, solved))}


def chains(n_bays: int) -> list[range]:
    """The runs of bays a cold wing solve takes one from another (`from_the_bay_before`): two halves from
    four bays on, so that two threads can take one each (`presolve`), on any machine (the starts, and so
    the equilibria to the last bit, do not depend on its cores)."""
    if n_bays < 4:
        return [range(n_bays)]
    half = (n_bays + 1) // 2
    return [range(half), range(half, n_bays)]


def from_the_bay_before(method, rest, before: Solution | None, before_rest):
    """A cold bay's start after the first: the displacement of the bay before (``before``, solved on its
    mounted shape ``before_rest``) on this bay's mounted shape ``rest``, for a method that tries Newton
    from such a start (`methods.RelaxNewton`); None (the method's cold start) for the first bay of each
    of the `chains`, after a bay that failed, under ``jax.jit`` or ``jax.vmap``, or for another method.
    A wing's neighbouring bays differ by a step of its taper: Newton from there converges in 2-5
    iterations where the cold start relaxes for hundreds of steps first (docs/architecture.md)."""
    if before is None or not isinstance(method, RelaxNewton):
        return None
    arrays = (before.nodes, before_rest, rest)
    if any(isinstance(a, jax.core.Tracer) for a in arrays):
        return None
    x, x_rest, here = (np.asarray(a, np.float64) for a in arrays)
    if not np.all(np.isfinite(x)):
        return None
    return here + (x - x_rest)


def mounted_shape(scene: Scene, parameters: Parameters):
    """Bay's mounted shape at ``parameters``, not differentiated (concrete eagerly).

    The gradient is stopped on ``parameters`` before their arrays are made: under an eager
    ``jax.jvp`` (the design's forward mode) they are then the concrete primal values, moved in one
    transfer, not a converted tracer each (an eager operation compiled or fetched apiece)."""
    geometry = scene.bay.geometry()
    params = scene.params(jax.lax.stop_gradient(parameters))
    return jax.lax.stop_gradient(mounted_compiled(geometry, params))
