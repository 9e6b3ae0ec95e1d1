"""A `Scene`: everything that defines one simulation, and its traced parameters."""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from .bay import Bay
from .fabric import Fabric
from ._precision import float64_scope
from .forces import Params, Physics

__all__ = ["Scene", "float64_scope", "check_pressure", "check_prestrain"]

#: dtype of each precision mode.
PRECISIONS = {"float64": jnp.float64, "float32": jnp.float32}


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
            raise ValueError(
                f"aerodynamic_damping must be zero or positive in s/m, got {self.aerodynamic_damping!r}"
            )
        if not (math.isfinite(self.gravity_acceleration) and self.gravity_acceleration >= 0):
            raise ValueError(
                f"gravity_acceleration must be zero or positive in m/s^2, got {self.gravity_acceleration!r}"
            )

    def physics(self, dynamic: bool) -> Physics:
        """Static switches; the equilibrium (``dynamic=False``) drops the velocity terms."""
        return Physics(
            periodic=self.bay.periodic,
            tension_only=self.tension_only,
            viscous=dynamic and self.fabric.viscosity > 0,
            aerodynamic=dynamic and self.aerodynamic_damping > 0,
            gravity=self.gravity,
        )

    def params(
        self,
        pressure,
        prestrain=(0.0, 0.0),
        stiffness=None,
        rib_thickness_scale=1.0,
        rib_chord_scale=1.0,
        dtype=jnp.float64,
    ) -> Params:
        """Traced parameters of one solve.

        Args:
            pressure: internal overpressure, Pa.
            prestrain: ``(span, chord)`` prestrain, or one number for both.
            stiffness: ``(span, chord)`` tensile stiffness in N/m overriding the
                fabric's (to differentiate or sweep it), or None.
            rib_thickness_scale: multiplies the rib thickness about the camber line.
            rib_chord_scale: multiplies the rib chord.
            dtype: floating dtype of the arrays.
        """
        ps, pc = _pair(prestrain)
        fab = self.fabric
        es, ec = (fab.stiffness_span, fab.stiffness_chord) if stiffness is None else _pair(stiffness)
        values = Params(
            pressure=pressure,
            prestrain_span=ps,
            prestrain_chord=pc,
            stiffness_span=es,
            stiffness_chord=ec,
            poisson=fab.poisson,
            areal_density=fab.areal_density,
            viscosity=fab.viscosity,
            aerodynamic_damping=self.aerodynamic_damping,
            gravity=self.gravity_acceleration,
            rib_thickness_scale=rib_thickness_scale,
            rib_chord_scale=rib_chord_scale,
        )
        return Params(*(jnp.asarray(v, dtype=dtype) for v in values))


def _pair(value):
    if isinstance(value, (tuple, list)):
        if len(value) != 2:
            raise ValueError(f"expected a (span, chord) pair, got {value!r}")
        return value[0], value[1]
    if isinstance(value, (np.ndarray, jax.Array)) and np.ndim(value) == 1:
        if np.shape(value)[0] != 2:
            raise ValueError(f"expected a (span, chord) pair, got shape {np.shape(value)}")
        return value[0], value[1]
    return value, value


def _concrete(value) -> float | None:
    """The float value of a concrete number, None for a JAX tracer."""
    if isinstance(value, jax.core.Tracer):
        return None
    return float(np.asarray(value))


def check_pressure(pressure) -> None:
    """Raise a clear error for a non-physical pressure (tracers pass)."""
    value = _concrete(pressure)
    if value is not None and not (math.isfinite(value) and value > 0):
        raise ValueError(
            f"pressure must be a positive internal overpressure in Pa, got {value!r}"
        )


def check_prestrain(prestrain) -> None:
    """Raise a clear error for a prestrain that cuts the fabric to nothing."""
    for name, v in zip(("span", "chord"), _pair(prestrain)):
        value = _concrete(v)
        if value is not None and not (math.isfinite(value) and -0.5 < value < 1.0):
            raise ValueError(
                f"prestrain_{name} must lie in (-0.5, 1.0) (a fraction, 0.005 is 0.5%), got {value!r}"
            )
