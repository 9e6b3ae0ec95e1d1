"""The fabric: an orthotropic membrane with zero shear stiffness (paper eq. 10)."""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Fabric"]


def _check_positive(name: str, value: float, unit: str) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number in {unit}, got {value!r}")


@dataclass(frozen=True)
class Fabric:
    """Material of the skin, per unit width (soft-shell convention).

    The tensions follow paper eq. (10) with zero shear stiffness::

        T11 = (E11 e11 + nu E22 e22) / (1 - nu^2) + eta de11/dt
        T22 = (E22 e22 + nu E11 e11) / (1 - nu^2) + eta de22/dt

    with ``e = lambda - 1`` the engineering elongation of a fibre direction
    against its cut (reference) length and ``nu12 = nu21 = poisson``.

    Args:
        stiffness_span: tensile stiffness E11 of the span (alpha1) fibres, N/m.
        stiffness_chord: tensile stiffness E22 of the contour (alpha2) fibres, N/m.
        poisson: the Poisson-like coupling nu12 = nu21, dimensionless, in [0, 1).
        areal_density: mass per unit undeformed area rho0, kg/m^2. Used only by
            the paper's dynamic scheme (`simulate`); equilibrium does not depend
            on it.
        viscosity: viscous friction eta of eq. (10), N*s/m. Dynamic only.
        allowable_tension: largest fibre tension the fabric may carry, N/m
            (a design constraint; ``inf`` means none).

    Raises:
        ValueError: if a value is non-physical.
    """

    stiffness_span: float = 2e5
    stiffness_chord: float = 2e5
    poisson: float = 0.25
    areal_density: float = 0.3
    viscosity: float = 0.0
    allowable_tension: float = math.inf

    def __post_init__(self) -> None:
        _check_positive("stiffness_span", self.stiffness_span, "N/m")
        _check_positive("stiffness_chord", self.stiffness_chord, "N/m")
        _check_positive("areal_density", self.areal_density, "kg/m^2")
        if not (0.0 <= self.poisson < 1.0):
            raise ValueError(f"poisson must lie in [0, 1) so that 1 - nu^2 > 0, got {self.poisson!r}")
        if not (math.isfinite(self.viscosity) and self.viscosity >= 0.0):
            raise ValueError(f"viscosity must be zero or positive in N*s/m, got {self.viscosity!r}")
        if not (self.allowable_tension > 0.0):
            raise ValueError(
                f"allowable_tension must be positive in N/m (inf for none), got {self.allowable_tension!r}"
            )
