"""The force kernel's programs that the solvers share, each compiled whole (`forces` eagerly is many small programs).

* `prepare_compiled`: the reference state of a bay at its parameters
  (`forces.prepare`);
* `mounted_compiled`: the mounted (nominal) shape (`forces.mounted_nodes`);
* `static_state`, `static_forces`: the forces of the static residual and
  ``||R_free|| / (p A)`` at a state, for Newton, chord Newton and every
  returned `Solution`'s tensions;
* `cell_strains`: each cell's fibre strains at a state (what a fitted law's
  tested range is checked against);
* `rounding_floors_compiled`: the relative residual that rounding each bay's
  coordinates alone leaves (`precision.residual_rounding_floor`), which a
  wing's rib gaps are checked against before any solve.

They are `compilation.stored_jit` programs: kept between processes while a
program store is in use.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from . import forces as fk
from .precision import residual_rounding_floor
from .stencils import safe_norm
from .compilation import stored_jit

__all__ = ["prepare_compiled", "mounted_compiled", "static_state", "static_forces", "cell_strains",
           "rounding_floors_compiled"]


#: `forces.prepare` as one compiled program (eagerly, each of its operations compiles on its own).
prepare_compiled = stored_jit(fk.prepare, static_argnames=("physics",))

#: `forces.mounted_nodes` as one compiled program (eagerly, a dozen operations compiled and
#: dispatched one by one, on every cold start and on every bay of every wing solve).
mounted_compiled = stored_jit(fk.mounted_nodes)

def _rounding_floors(geometries, params, physics, eps):
    return jax.vmap(lambda geometry: residual_rounding_floor(geometry, params, physics, eps))(geometries)


#: `precision.residual_rounding_floor` of every bay of a wing at once (``geometries``: a `forces.Geometry`
#: of the bays' arrays stacked), a stored program: the rib-gap check runs it before the first solve of
#: every run (traced and lowered, it took a tenth of a second; bay by bay, 0.18 s for 40 bays).
rounding_floors_compiled = stored_jit(_rounding_floors, static_argnames=("physics",), light=True)


@stored_jit(static_argnames=("physics",))
def static_state(x, geometry: fk.Geometry, params: fk.KernelInputs, physics: fk.Physics):
    """``(forces, relative)`` at nodes ``x``: the `forces.Forces` of the static residual (velocity
    terms dropped) and ``||R_free||_2 / (p A)`` (`forces.relative_residual`; NaN when a coordinate
    is not finite).

    One compiled program serves Newton's residuals and line search, chord Newton and the
    returned solution's tensions (`static_forces`): every extra program of the force kernel is
    another XLA compilation of it (about a second on a 2-core machine).
    """
    physics = fk.static_physics(physics)
    ref = fk.prepare(geometry, params, physics)
    f = fk.forces(x, ref, params, physics)
    rel = safe_norm(f.total.reshape(-1)) / (params.pressure * ref.skin_area)
    return f, jnp.where(jnp.all(jnp.isfinite(x)), rel, jnp.nan)


def static_forces(x, geometry: fk.Geometry, params: fk.KernelInputs, physics: fk.Physics) -> fk.Forces:
    """`forces.Forces` of the static residual at nodes ``x`` (velocity terms dropped); `static_state`."""
    return static_state(x, geometry, params, physics)[0]


@stored_jit(static_argnames=("physics",))
def cell_strains(x, geometry: fk.Geometry, params: fk.KernelInputs, physics: fk.Physics):
    """``(strain_span, strain_chord)``, each ``(n_span - 1, n_cells)``: the cells' fibre strains
    ``lambda - 1`` (eq. 12) at nodes ``x``."""
    physics = fk.static_physics(physics)
    fib = fk.fibres(x, fk.prepare(geometry, params, physics), params, physics)
    return fib.strain_span, fib.strain_chord
