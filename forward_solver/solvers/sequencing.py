"""Grid sequencing of the relaxation: solve a coarse grid, interpolate its displacement, refine.

A bay's grid is nested (`Bay`): every other node along both directions is a
grid of its own, down to `COARSEST_SPAN` x `COARSEST_CONTOUR`. A cold
relaxation (`methods.Relax`, `methods.RelaxNewton`) starts from the coarsest
level, solved from the mounted shape to `COARSE_RTOL` (its discretisation
error is far above it), and carries each level's displacement to the next
finer one by linear interpolation (`prolong`): the fine grid starts close
to its rest state and needs a fraction of the steps. A coarse level that
fails is no better than the mounted shape, which the fine grid then starts
from.

`Relaxation` is one solve's call of `relax.relax_jit` on any level, and
`compile_ahead` hands what the cold solve compiles after its coarsest level
(the finer levels, Newton's programs) to the compile-ahead worker
(`compilation.Ahead`).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import forces as fk
from ..compilation import Ahead, compiling, signature
from ..derivatives.implicit import batched_rhs_task, default_linear_solver, expected_tangents
from ..programs import mounted_compiled
from ..solution import Result
from .newton import warm_up
from .relax import MASS_SAFETY, RELAX_CHUNK, RelaxOptions, relax_jit

__all__ = ["COARSEST_SPAN", "COARSEST_CONTOUR", "COARSE_RTOL", "Relaxation", "coarsenable", "coarsen",
           "prolong", "use_half", "sequenced_start", "compile_ahead"]

#: Coarsest grid that grid sequencing descends to.
COARSEST_SPAN = 5
COARSEST_CONTOUR = 24
#: Relative residual the coarse levels are solved to: their discretisation
#: error is far above it, so a tighter solve there buys nothing.
COARSE_RTOL = 1e-5


def use_half(geometry, symmetric: bool) -> bool:
    """Whether the relaxation solves half the bay: both ribs alike and an odd ``n_span >= 5``."""
    return symmetric and geometry.free.shape[0] % 2 == 1 and geometry.free.shape[0] >= 5


class Relaxation(NamedTuple):
    """`relax.relax_jit` with one solve's fixed arguments, on any grid level.

    Called on a start ``x`` and a level's ``geometry`` it relaxes; `compiling`
    gives the task that compiles its program for the same arguments
    (`compilation.compiling`): one place builds the arguments of both, so
    they meet.
    """

    params: fk.KernelInputs
    bound: float  # m, `Bay.divergence_bound`
    max_chunks: int
    physics: fk.Physics
    symmetric: bool  # both ribs alike (the half-bay rule of `use_half` decides per level)
    precision: str

    def _arguments(self, x, geometry, rtol, with_forces):
        # (NumPy scalars: the same float64 avals as JAX's, without an eager conversion compiled for them)
        options = RelaxOptions(self.max_chunks, use_half(geometry, self.symmetric), self.precision, with_forces)
        return (x, geometry, self.params, np.asarray(rtol, np.float64), np.asarray(self.bound, np.float64),
                MASS_SAFETY, self.physics, options)

    def __call__(self, x, geometry, rtol, with_forces=False):
        """``(loop output, forces or None, nodes)`` of the relaxation from ``x`` on ``geometry``'s grid."""
        return relax_jit(*self._arguments(x, geometry, rtol, with_forces))

    def compiling(self, x, geometry, rtol, with_forces=False):
        """The task that compiles the program a call with these arguments takes."""
        return compiling(relax_jit, *self._arguments(x, geometry, rtol, with_forces))


def coarsenable(shape, periodic: bool) -> bool:
    """Whether a grid of ``shape`` ``(n_span, n_contour)`` nests a coarser one no coarser than the coarsest."""
    ns, nc = shape
    contour_ok = (nc % 2 == 0) if periodic else (nc % 2 == 1)
    return ns % 2 == 1 and contour_ok and (ns + 1) // 2 >= COARSEST_SPAN and nc // 2 >= COARSEST_CONTOUR


def coarsen(geometry: fk.Geometry) -> fk.Geometry:
    """Every other node along both directions (nested grids, see `Bay`)."""
    return geometry._replace(contour_root=geometry.contour_root[::2], contour_tip=geometry.contour_tip[::2],
                             camber_root=geometry.camber_root[::2], camber_tip=geometry.camber_tip[::2],
                             free=geometry.free[::2, ::2])


def prolong(u: jnp.ndarray, periodic: bool) -> jnp.ndarray:
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


@partial(jax.jit, static_argnames=("periodic",))
def _prolonged(x0, xc, xc0, free, periodic: bool):
    """The fine grid's start: its mounted shape ``x0`` plus the coarse solution's displacement
    ``xc - xc0`` interpolated (`prolong`) on the free nodes (one program: twenty eager
    operations before, each compiled on its own and, while a level compiled ahead, waiting for it)."""
    return x0 + prolong(xc - xc0, periodic) * free[..., None]


def sequenced_start(geometry, relax: Relaxation, sequencing: bool, coarse_rtol: float = COARSE_RTOL,
                    prepared=None):
    """Starting shape: the mounted shape, or the interpolated coarse-grid solution.

    Args:
        geometry: the grid's `forces.Geometry`.
        relax: the solve's `Relaxation`.
        sequencing: descend to coarser grids at all.
        coarse_rtol: relative residual of the coarse levels.
        prepared: `compile_ahead`'s handles, or None.

    Returns:
        ``(x, steps, levels)``: the start, the steps spent on coarse levels and
        a record per level (``shape``, ``steps``).
    """
    params, physics = relax.params, relax.physics
    x0 = mounted_compiled(geometry, params)
    if not (sequencing and coarsenable(geometry.free.shape, physics.periodic)):
        return x0, 0, []
    coarse = coarsen(geometry)
    xc, steps, levels = sequenced_start(coarse, relax, sequencing, coarse_rtol, prepared)
    Ahead.ready((prepared or {}).get(tuple(xc.shape)))
    out, _, xc_full = relax(xc, coarse, coarse_rtol)
    if int(out.result) != Result.converged:
        return x0, steps, levels  # a failed coarse level is no better than the mounted shape
    xc0 = mounted_compiled(coarse, params)
    Ahead.ready((prepared or {}).get(("prolong", tuple(x0.shape))))
    chunks = int(out.chunks)
    levels = levels + [{"shape": tuple(coarse.free.shape), "steps": chunks * RELAX_CHUNK}]
    return _prolonged(x0, xc_full, xc0, geometry.free, physics.periodic), steps + chunks * RELAX_CHUNK, levels


def compile_ahead(ahead: Ahead, relax: Relaxation, geometry, sequencing: bool, coarse_rtol: float,
                  relax_rtol: float, newton_next: bool) -> dict:
    """Submit to ``ahead`` what a cold solve compiles after its coarsest relaxation: the relaxation of
    every finer grid-sequencing level, coarse to fine, then (``newton_next``) Newton's programs on
    the full grid (`newton.warm_up`). Returns the handles by level shape ``(ns, nc, 3)`` and
    ``"newton"``."""
    params, physics = relax.params, relax.physics
    grids = [geometry]
    while sequencing and coarsenable(grids[-1].free.shape, physics.periodic):
        grids.append(coarsen(grids[-1]))
    options = (relax.max_chunks, relax.symmetric, relax.precision)
    prepared, prolongations = {}, []
    for k in range(len(grids) - 2, -1, -1):  # the coarsest (last) is the solve's own first program
        shape = tuple(grids[k].free.shape) + (3,)
        x = np.zeros(shape)  # (NumPy: no eager program to compile for a placeholder)
        key = ("relax", signature(x, grids[k], params), physics, options)
        rtol, with_forces = (relax_rtol, not newton_next) if k == 0 else (coarse_rtol, False)
        prepared[shape] = ahead.submit(key + (with_forces,), relax.compiling(x, grids[k], rtol, with_forces))
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
    if n_tangents and default_linear_solver().name == "lu":  # the design's forward-mode derivative next
        ahead.submit(*batched_rhs_task(geometry, params, physics, n_tangents))
    return prepared
