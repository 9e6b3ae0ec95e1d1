"""A `Scene`: everything that defines one simulation, and its traced parameters."""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax.numpy as jnp

from .bay import Bay
from .fabric import Fabric
from ..precision import device_arrays
from ..forces import KernelInputs, Physics
from .parameters import Parameters

__all__ = ["Scene"]


@dataclass(frozen=True, eq=False)
class Scene:
    """One simulation: a bay, its fabric, and which physical terms are on.

    The switches are static: a term that is off is removed when the solver is
    traced, not multiplied by zero at run time. Viscosity is on when
    ``fabric.viscosity > 0``.

    Args:
        bay: the skin's geometry and grid.
        fabric: the skin's material.
        tension_only: fabric carries no compression; a negative fibre tension
            is clamped to zero and the cell is reported as wrinkled.
        gravity: apply the skin's weight (mass force ``q`` of eq. 1) along -z.
        gravity_acceleration: m/s^2.
        aerodynamic_damping: coefficient ``nu_n`` of eq. (11), s/m; 0 is off.
            Dynamic only: it does not change the equilibrium.
    """

    bay: Bay
    fabric: Fabric = Fabric()
    tension_only: bool = True
    gravity: bool = False
    gravity_acceleration: float = 9.81
    aerodynamic_damping: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.bay, Bay):
            raise TypeError(f"bay must be a forward_solver.Bay, got {type(self.bay).__name__}")
        if not isinstance(self.fabric, Fabric):
            raise TypeError(f"fabric must be a forward_solver.Fabric, got {type(self.fabric).__name__}")
        if not (math.isfinite(self.aerodynamic_damping) and self.aerodynamic_damping >= 0):
            raise ValueError(f"aerodynamic_damping must be zero or positive in s/m, got {self.aerodynamic_damping!r}")
        if not (math.isfinite(self.gravity_acceleration) and self.gravity_acceleration >= 0):
            raise ValueError(
                f"gravity_acceleration must be zero or positive in m/s^2, got {self.gravity_acceleration!r}"
            )

    def physics(self, dynamic: bool) -> Physics:
        """Static switches and the fabric's law and shear stiffness; the equilibrium (``dynamic=False``)
        drops the velocity terms."""
        return Physics(periodic=self.bay.periodic, tension_only=self.tension_only,
                       viscous=dynamic and self.fabric.viscosity > 0,
                       aerodynamic=dynamic and self.aerodynamic_damping > 0, gravity=self.gravity,
                       law=self.fabric.fibre_law, shear_stiffness=self.fabric.shear_stiffness)

    def params(self, parameters: Parameters, dtype=jnp.float64) -> KernelInputs:
        """The force kernel's traced parameters: ``parameters`` merged with the fabric's constants.

        Args:
            parameters: the design `Parameters` (unset stiffnesses take the
                fabric's).
            dtype: floating dtype of the arrays.
        """
        p = parameters.resolved(self.fabric)
        fab = self.fabric
        values = KernelInputs(
            pressure=p.pressure,
            prestrain_span=p.prestrain_span,
            prestrain_chord=p.prestrain_chord,
            stiffness_span=p.stiffness_span,
            stiffness_chord=p.stiffness_chord,
            poisson=fab.poisson,
            areal_density=fab.areal_density,
            viscosity=fab.viscosity,
            aerodynamic_damping=self.aerodynamic_damping,
            gravity=self.gravity_acceleration,
            rib_thickness_scale=p.rib_thickness_scale,
            rib_chord_scale=p.rib_chord_scale,
            rib_shape_root=_no_shape if p.rib_shapes[0] is None else p.rib_shapes[0],
            rib_shape_tip=_no_shape if p.rib_shapes[1] is None else p.rib_shapes[1],
            cut_pattern=_no_shape if p.cut_pattern is None else p.cut_pattern,
        )
        return KernelInputs(*device_arrays(values, dtype))

    def check_parameters(self, parameters: Parameters) -> Parameters:
        """``parameters.check()``, and a rib shape only on a closed (airfoil) contour.

        Raises:
            ValueError: saying what to change.
        """
        parameters.check()
        if parameters.rib_shape is not None and not self.bay.periodic:
            raise ValueError("rib_shape offsets an airfoil rib's upper and lower surfaces; this bay is a "
                             "flat panel: leave rib_shape None or build the bay with Bay.from_airfoil")
        return parameters

    def symmetric(self, parameters: Parameters) -> bool:
        """Whether the bay with these ``parameters`` is symmetric about mid-span (both ribs alike)."""
        return self.bay.symmetric and parameters.rib_shape_tip is None


#: Kernel value of an unset rib shape: no coefficients, no offset (`rib_shape.rib_offsets`).
_no_shape = ()
