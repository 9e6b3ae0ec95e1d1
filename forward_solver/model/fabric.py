"""The fabric: its fibre law (paper eq. 10, or one fitted to a biaxial test), shear stiffness and mass."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

from .biaxial import FittedLaw, fit_law, read_test
from .fibre_law import LinearLaw, SurfaceLaw

__all__ = ["DEFAULT_STIFFNESS", "DEFAULT_POISSON", "WARP_DIRECTIONS", "Fabric"]

#: Eq. (10)'s stiffness both ways, N/m, and its Poisson coupling, when a fabric gives none.
DEFAULT_STIFFNESS = 2e5
DEFAULT_POISSON = 0.25
#: Where a fabric's warp (the roll's length) runs on the wing.
WARP_DIRECTIONS = ("span", "chord")


def _check_positive(name: str, value: float, unit: str) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number in {unit}, got {value!r}")


@dataclass(frozen=True)
class Fabric:
    """Material of the skin, per unit width (soft-shell convention).

    The fibre law, by default paper eq. (10) with zero shear stiffness::

        T11 = (E11 e11 + nu E22 e22) / (1 - nu^2) + eta de11/dt
        T22 = (E22 e22 + nu E11 e11) / (1 - nu^2) + eta de22/dt

    with ``e = lambda - 1`` the engineering elongation of a fibre direction
    against its cut (reference) length and ``nu12 = nu21 = poisson``. With
    ``law``, a law fitted to the fabric's biaxial test (`model.biaxial.fit_law`;
    `from_test` reads and fits a file), the elastic part is the law's
    strain-energy surface instead (docs/fabric_test.md), its warp along
    ``warp``; each wing direction's tensions are then scaled by its
    stiffness over the law's nominal one (a fabric lot's scatter), so
    ``stiffness_span`` and ``stiffness_chord`` default to the nominal
    stiffnesses of the law. A shear stiffness gives the ``T12`` terms of
    eq. (1) and (6) (`forward_solver.shear`).

    Args:
        stiffness_span: tensile stiffness E11 of the span (alpha1) fibres, N/m (default 2e5; with a
            ``law``, its nominal stiffness along the span).
        stiffness_chord: tensile stiffness E22 of the contour (alpha2) fibres, N/m (likewise).
        poisson: the Poisson-like coupling nu12 = nu21 of eq. (10), dimensionless, in [0, 1) (default
            0.25; with a ``law``, the law's own coupling, recorded: give none).
        areal_density: mass per unit undeformed area rho0, kg/m^2. Used only by
            the paper's dynamic scheme (`simulate`); equilibrium does not depend
            on it.
        viscosity: viscous friction eta of eq. (10), N*s/m. Dynamic only.
        allowable_tension: largest fibre tension the fabric may carry, N/m
            (a design constraint; ``inf`` means none).
        law: None (eq. 10), or the `model.biaxial.FittedLaw` of the fabric's biaxial test.
        warp: where the warp (the roll's length, the test's warp) runs on the wing: "span" (the
            default) or "chord". With eq. (10) it only says which way the patterns' warp arrow points.
        shear_stiffness: ``G`` of ``T12 = G gamma``, N/m, 0 or more (default 0, as the paper takes it;
            textiles have about 2% of their tensile stiffness, it says).

    Raises:
        ValueError: if a value is non-physical, or ``poisson`` is given with a ``law``.
    """

    stiffness_span: float | None = None
    stiffness_chord: float | None = None
    poisson: float | None = None
    areal_density: float = 0.3
    viscosity: float = 0.0
    allowable_tension: float = math.inf
    law: FittedLaw | None = None
    warp: str = "span"
    shear_stiffness: float = 0.0

    def __post_init__(self) -> None:
        if self.law is not None and not isinstance(self.law, FittedLaw):
            raise TypeError(f"law must be a forward_solver.FittedLaw (forward_solver.fit_law) or None, got {type(self.law).__name__}")
        if self.warp not in WARP_DIRECTIONS:
            raise ValueError(f"warp must be 'span' or 'chord' (where the warp runs on the wing), got {self.warp!r}")
        if self.law is not None and self.poisson is not None:
            raise ValueError("poisson is eq. (10)'s coupling; a fitted law has its own (law.poisson): leave "
                             "poisson unset with a law")
        nominal = self._nominal()
        for name, default in (("stiffness_span", nominal[0]), ("stiffness_chord", nominal[1]), ("poisson", nominal[2])):
            if getattr(self, name) is None:
                object.__setattr__(self, name, default)
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
        if not (isinstance(self.shear_stiffness, (int, float)) and math.isfinite(self.shear_stiffness)
                and self.shear_stiffness >= 0.0):
            raise ValueError(f"shear_stiffness must be zero or a positive number in N/m, got {self.shear_stiffness!r}")
        object.__setattr__(self, "shear_stiffness", float(self.shear_stiffness))

    @classmethod
    def from_test(cls, path, *, warp: str = "span", shear_stiffness: float = 0.0, degree: int | None = None,
                  **fields) -> "Fabric":
        """The fabric whose law is fitted to the biaxial test file ``path`` (`model.biaxial.read_test`,
        `model.biaxial.fit_law`; docs/fabric_test.md), its warp along ``warp``.

        Args:
            path: the test file (CSV).
            warp: "span" or "chord".
            shear_stiffness: N/m.
            degree: the fitted surface's degree (None: the highest whose tangent is positive-definite
                where the fabric was tested).
            **fields: other `Fabric` fields (``areal_density``, ``allowable_tension``, ...).

        Raises:
            model.biaxial.TestFileError: one line, for a file that cannot be fitted.
        """
        return cls(law=fit_law(read_test(path), degree), warp=warp, shear_stiffness=shear_stiffness, **fields)

    def _nominal(self) -> tuple:
        """``(stiffness_span, stiffness_chord, poisson)`` a fabric takes when it gives none."""
        if self.law is None:
            return DEFAULT_STIFFNESS, DEFAULT_STIFFNESS, DEFAULT_POISSON
        warp, weft = self.law.stiffness_warp, self.law.stiffness_weft
        span, chord = (warp, weft) if self.warp == "span" else (weft, warp)
        return span, chord, self.law.poisson

    @cached_property
    def fibre_law(self):
        """The law as the force kernel reads it (`fibre_law.LinearLaw` or `fibre_law.SurfaceLaw`)."""
        if self.law is None:
            return LinearLaw()
        return SurfaceLaw.of(self.law.surface, self.warp == "span", self.law.stiffness_warp, self.law.stiffness_weft)

    @property
    def wave_speed(self) -> float:
        """Speed of small in-plane disturbances ``c = sqrt(E_max / rho0)`` of eq. (16), m/s: ``E_max`` the
        law's stiffest plane-strain modulus (eq. 10's ``max(E11, E22) / (1 - nu^2)``; a fitted law's largest
        tangent over its tested range)."""
        return math.sqrt(float(self.fibre_law.modulus(self)) / self.areal_density)

    @property
    def strain_range(self) -> dict | None:
        """``{"span": (least, largest), "chord": (...)}``: the strains the law's test covered in the wing's
        directions, or None for eq. (10)."""
        if self.law is None:
            return None
        tested = self.law.strain_range
        span, chord = ("warp", "weft") if self.warp == "span" else ("weft", "warp")
        return {"span": tested[span], "chord": tested[chord]}
