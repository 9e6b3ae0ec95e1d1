"""The fabric's shear stiffness: the ``T12`` terms of eq. (1) and (6) from the shear angle of eq. (8)-(9).

The paper keeps ``T12`` in its equations of motion (eq. 1, 6) and sets it to
zero, textiles having "a low shear stiffness, about 2% of the tensile". With
a shear stiffness ``G`` (N/m, `forces.Physics.shear_stiffness`; 0, the
default, removes this term from the compiled program):

* the shear angle of a cell is the change of the angle between its fibres,
  ``gamma = phi0 - phi``, with ``phi`` the angle between the cell's span
  fibre (the mean of its two span edges) and its contour fibre (the mean of
  its two contour edges), and ``phi0`` the same in the mounted shape. With
  fibres at right angles in the reference (a flat panel, an untapered bay)
  this is eq. (9)'s ``theta``: ``sin theta = 2 e12 / (lambda1 lambda2)``
  with eq. (8)'s ``e12 = g12 / (2 sqrt(g11^0 g22^0))`` gives
  ``sin theta = cos phi``, ``theta = pi/2 - phi``. Measured from the mounted
  angle, a bay whose mounted fibres do not cross at right angles (a tapered
  bay) carries no shear where it is mounted, and a flat prestressed panel
  stays flat;
* ``T12 = T21 = G gamma`` (`shear_tension`);
* the nodal forces are those of the shear energy ``sum_cells 1/2 G gamma^2
  A`` (``A = h1 h2``, the cell's cut area, as the kernel lumps areas),
  ``F = -dE/dx`` by ``jax.grad`` (`shear_forces`). Its work on a change of
  the angle is ``T12 A dgamma``, what eq. (1)'s ``T12 tau2 sqrt(g22)`` and
  ``T21 tau1 sqrt(g11)`` terms do to first order in the shear on a net at
  right angles; from the energy, the forces are reciprocal, vanish under a
  rigid motion, and their tangent (Newton's) is symmetric.

The shear acts whatever the fibres' tensions (a wrinkled cell keeps it).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .stencils import cell_corners, next_j, safe_norm, this_j

__all__ = ["cell_angles", "shear_angles", "shear_forces", "shear_tension"]


def cell_angles(x: jnp.ndarray, periodic: bool) -> jnp.ndarray:
    """``(n_span - 1, n_cells)`` the angle between each cell's span and contour fibres, rad."""
    n00, n10, n11, n01 = cell_corners(x, periodic)
    span = 0.5 * ((n10 - n00) + (n11 - n01))
    contour = 0.5 * ((n01 - n00) + (n11 - n10))
    return jnp.arctan2(safe_norm(jnp.cross(span, contour)), jnp.sum(span * contour, axis=-1))


def shear_angles(x: jnp.ndarray, ref, periodic: bool) -> jnp.ndarray:
    """``(n_span - 1, n_cells)`` each cell's shear angle ``gamma = phi0 - phi`` (module docstring), rad;
    ``ref`` is the solve's `forces.Reference` (its mounted nodes)."""
    return cell_angles(ref.nodes, periodic) - cell_angles(x, periodic)


def shear_tension(x: jnp.ndarray, ref, physics) -> jnp.ndarray:
    """``(n_span - 1, n_cells)`` ``T12 = G gamma``, N/m (``G``: ``physics.shear_stiffness``)."""
    return physics.shear_stiffness * shear_angles(x, ref, physics.periodic)


def _cell_areas(ref, periodic: bool) -> jnp.ndarray:
    """The cells' cut areas ``h1 h2``, m^2 (the kernel's lumped areas are quarters of them)."""
    h1 = 0.5 * (this_j(ref.span_length, periodic) + next_j(ref.span_length, periodic))
    h2 = 0.5 * (ref.contour_length[:-1] + ref.contour_length[1:])
    return h1 * h2


def shear_forces(x: jnp.ndarray, ref, physics) -> jnp.ndarray:
    """``(n_span, n_contour, 3)`` the nodal forces of the shear energy (module docstring), N (held nodes
    included: the kernel zeroes them)."""
    periodic = physics.periodic
    area = _cell_areas(ref, periodic)
    reference = cell_angles(ref.nodes, periodic)

    def energy(y):
        gamma = reference - cell_angles(y, periodic)
        return 0.5 * physics.shear_stiffness * jnp.sum(area * gamma * gamma)

    return -jax.grad(energy)(x)
