"""NACA 4- and 5-digit sections from the NACA Report 824 formulas.

Both series share the thickness distribution (chord units, x in [0, 1])::

    y_t = 5 t (0.2969 sqrt(x) - 0.1260 x - 0.3516 x^2 + 0.2843 x^3 + a4 x^4)

with ``a4 = -0.1015`` (the report's open, blunt trailing edge, 2 y_t(1) =
0.021 t) or ``a4 = -0.1036`` (the usual modification that closes it), chosen
by ``closed_te``. The thickness is laid perpendicular to the mean line:
``(x -/+ y_t sin(theta), y_c +/- y_t cos(theta))`` with ``theta =
atan(dy_c/dx)``, upper/lower.

4-digit ``MPTT``: maximum camber ``m = M/100`` at ``p = P/10``, thickness ``t =
TT/100``; the mean line is two parabolas meeting at x = p.

5-digit ``LPSTT``: design lift coefficient ``c_l = 0.15 L``, maximum camber at
``p = 0.05 P``, ``S`` = 0 standard or 1 reflexed mean line, thickness ``t =
TT/100``. The mean lines use the tabulated constants ``r``, ``k1`` (and ``k2/k1``
for reflexed lines), given for ``c_l = 0.3``; the ordinates scale linearly
with ``c_l``.

Points are placed at cosine-spaced stations of the camber-line abscissa ``x``
(the standard practice): node k of n sits at ``x = (1 + cos(2 pi k/(n-1)))/2``
of the mean line, on the upper surface for k < (n-1)/2 and the lower surface
after, and node (n-1)/2 is the leading edge (0, 0) when n is odd. On a
cambered section the surface points are displaced from those stations by
``-/+ y_t sin(theta)``; use :meth:`targets.Airfoil.resample` for nodes at exact
chordwise stations.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .airfoil import Airfoil
from .checks import checked_n_points

THICKNESS_COEFFICIENTS = (0.2969, -0.1260, -0.3516, 0.2843)
"""Coefficients of sqrt(x), x, x^2, x^3 in y_t / (5 t) (Report 824)."""

TE_COEFFICIENT_OPEN = -0.1015
"""Coefficient of x^4 in y_t / (5 t) for the report's open trailing edge."""

TE_COEFFICIENT_CLOSED = -0.1036
"""Coefficient of x^4 in y_t / (5 t) that closes the trailing edge."""

LEADING_EDGE_RADIUS_FACTOR = 1.1019
"""Leading-edge radius over t^2 (Report 824), = 25 * 0.2969^2 / 2."""

FIVE_DIGIT_TABLE_LIFT = 0.3
"""Design lift coefficient for which the 5-digit constants are tabulated."""

SURFACE_POINTS = 4097
"""Analytic samples from which the smooth representation of a NACA section is built."""


@dataclass(frozen=True)
class FiveDigitConstants:
    """Tabulated constants of one 5-digit mean line (for c_l = 0.3).

    Attributes:
        position: Chordwise station of maximum camber p (chord units).
        r: Station where the cubic front part joins the rear part (chord units).
        k1: Scale of the ordinates (dimensionless).
        k2_over_k1: Reflex term ratio; 0 for a standard mean line.
    """

    position: float
    r: float
    k1: float
    k2_over_k1: float = 0.0


FIVE_DIGIT_MEAN_LINES: dict[str, FiveDigitConstants] = {
    "210": FiveDigitConstants(0.05, 0.0580, 361.400),
    "220": FiveDigitConstants(0.10, 0.1260, 51.640),
    "230": FiveDigitConstants(0.15, 0.2025, 15.957),
    "240": FiveDigitConstants(0.20, 0.2900, 6.643),
    "250": FiveDigitConstants(0.25, 0.3910, 3.230),
    "221": FiveDigitConstants(0.10, 0.1300, 51.990, 0.000764),
    "231": FiveDigitConstants(0.15, 0.2170, 15.793, 0.00677),
    "241": FiveDigitConstants(0.20, 0.3180, 6.520, 0.0303),
    "251": FiveDigitConstants(0.25, 0.4410, 3.191, 0.1355),
}
"""Report 824 / Abbott and von Doenhoff constants, keyed by the digits 2PS."""


def _stations(x: ArrayLike) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if not np.all((x >= 0.0) & (x <= 1.0)):
        raise ValueError("chordwise stations of a NACA section must lie in [0, 1] (chord units)")
    return x


@dataclass(frozen=True)
class FourDigitMeanLine:
    """Mean line of a 4-digit section: two parabolas meeting at x = p.

    Attributes:
        max_camber: m, maximum camber (chord units).
        position: p, station of maximum camber (chord units); 0 when m = 0.
    """

    max_camber: float
    position: float

    def __call__(self, x: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Ordinate y_c (chord units) and slope dy_c/dx at stations x in [0, 1]."""
        x = _stations(x)
        m, p = self.max_camber, self.position
        if m == 0.0:
            return np.zeros_like(x), np.zeros_like(x)
        front = x < p
        scale = np.where(front, m / p**2, m / (1.0 - p) ** 2)
        ordinate = scale * np.where(front, 2.0 * p * x - x**2, (1.0 - 2.0 * p) + 2.0 * p * x - x**2)
        slope = 2.0 * scale * (p - x)
        return ordinate, slope


@dataclass(frozen=True)
class FiveDigitMeanLine:
    """Mean line of a 5-digit section (standard or reflexed).

    Attributes:
        designation: The digits 2PS of the tabulated line, e.g. "230".
        design_lift: Design lift coefficient c_l = 0.15 L (dimensionless).
        constants: The tabulated r, k1, k2/k1 for c_l = 0.3.
    """

    designation: str
    design_lift: float
    constants: FiveDigitConstants

    @property
    def position(self) -> float:
        """Station of maximum camber p (chord units)."""
        return self.constants.position

    def __call__(self, x: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Ordinate y_c (chord units) and slope dy_c/dx at stations x in [0, 1]."""
        x = _stations(x)
        r, k1, ratio = self.constants.r, self.constants.k1, self.constants.k2_over_k1
        k1 = k1 * self.design_lift / FIVE_DIGIT_TABLE_LIFT
        front = x < r
        if ratio == 0.0:
            ordinate = np.where(
                front,
                k1 / 6.0 * (x**3 - 3.0 * r * x**2 + r**2 * (3.0 - r) * x),
                k1 * r**3 / 6.0 * (1.0 - x),
            )
            slope = np.where(
                front, k1 / 6.0 * (3.0 * x**2 - 6.0 * r * x + r**2 * (3.0 - r)), -k1 * r**3 / 6.0
            )
            return ordinate, slope
        cube = np.where(front, 1.0, ratio) * (x - r) ** 3
        ordinate = k1 / 6.0 * (cube - ratio * (1.0 - r) ** 3 * x - r**3 * x + r**3)
        slope = k1 / 6.0 * (
            3.0 * np.where(front, 1.0, ratio) * (x - r) ** 2 - ratio * (1.0 - r) ** 3 - r**3
        )
        return ordinate, slope


@dataclass(frozen=True)
class NacaSection:
    """A parsed NACA section: thickness, mean line and trailing-edge choice.

    Attributes:
        designation: The digits, e.g. "2412" or "23012".
        thickness: t, maximum thickness (chord units).
        mean_line: The camber line.
        closed_te: True for the closed trailing edge (x^4 coefficient
            -0.1036), False for the report's open one (-0.1015).
    """

    designation: str
    thickness: float
    mean_line: FourDigitMeanLine | FiveDigitMeanLine
    closed_te: bool = True

    @property
    def name(self) -> str:
        """Label, e.g. "NACA 2412"."""
        return f"NACA {self.designation}"

    def half_thickness(self, x: ArrayLike) -> np.ndarray:
        """Half thickness y_t (chord units) at stations x in [0, 1]."""
        x = _stations(x)
        a0, a1, a2, a3 = THICKNESS_COEFFICIENTS
        a4 = TE_COEFFICIENT_CLOSED if self.closed_te else TE_COEFFICIENT_OPEN
        y = 5.0 * self.thickness * (a0 * np.sqrt(x) + x * (a1 + x * (a2 + x * (a3 + x * a4))))
        if self.closed_te:
            # The closed polynomial vanishes at x = 1; remove its rounding residue there.
            y = np.where(x == 1.0, 0.0, y)
        return y

    def _surface_points(self, x: np.ndarray, side: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Surface at camber-line stations x; side +1 upper, -1 lower."""
        half = self.half_thickness(x)
        ordinate, slope = self.mean_line(x)
        angle = np.arctan(slope)
        return x - side * half * np.sin(angle), ordinate + side * half * np.cos(angle)

    def surface(self, phi: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Analytic contour at angle parameters phi in [0, 2 pi].

        Args:
            phi: Angle parameter: camber-line station x = (1 + cos(phi)) / 2,
                upper surface for phi < pi, lower surface for phi > pi.

        Returns:
            ``(x, z)`` of the surface points (chord units), each shaped like phi.
        """
        phi = np.asarray(phi, dtype=np.float64)
        x = np.clip(np.cos(0.5 * phi) ** 2, 0.0, 1.0)
        return self._surface_points(x, np.where(phi < np.pi, 1.0, -1.0))

    def _contour(self, n_points: int) -> tuple[np.ndarray, np.ndarray]:
        k = np.arange(n_points)
        station = np.cos(np.pi * k / (n_points - 1)) ** 2  # (1 + cos(2 pi k/(n-1))) / 2
        station[0] = station[-1] = 1.0
        leading_edge = 2 * k == n_points - 1
        station[leading_edge] = 0.0
        x, z = self._surface_points(station, np.where(2 * k < n_points - 1, 1.0, -1.0))
        if self.closed_te:
            x[-1], z[-1] = x[0], z[0]
        return x, z

    def airfoil(self, n_points: int = 257) -> Airfoil:
        """The section sampled at cosine-spaced camber-line stations (see the module docstring).

        Args:
            n_points: Number of points, both trailing-edge points included.

        Returns:
            An :class:`~targets.Airfoil` whose smooth representation is built
            from max(4097, n_points) analytic samples.
        """
        n = checked_n_points(n_points)
        x, z = self._contour(n)
        surface = self._contour(max(SURFACE_POINTS, n))
        return Airfoil(x, z, name=self.name, surface=surface)


_CODE = re.compile(r"\s*(?:naca)?[\s_-]*(.*?)\s*", re.IGNORECASE | re.DOTALL)


def parse_naca(code: str, closed_te: bool = True) -> NacaSection:
    """Parses a NACA 4- or 5-digit designation.

    Args:
        code: The designation, e.g. "2412", "NACA2412", "naca 2412", "23012",
            "23112" (reflexed).
        closed_te: Close the trailing edge (x^4 coefficient -0.1036) or keep
            the report's open one (-0.1015).

    Returns:
        The parsed :class:`NacaSection`.

    Raises:
        TypeError: If code is not a string.
        ValueError: If the designation is not a valid 4- or 5-digit code; the
            message says which digit is wrong.
    """
    if not isinstance(code, str):
        raise TypeError(f"NACA code must be a string such as '0012', got {type(code).__name__}")
    if not isinstance(closed_te, (bool, np.bool_)):
        raise ValueError(f"closed_te must be True or False, got {closed_te!r}")

    def invalid(reason: str) -> ValueError:
        return ValueError(f"NACA code {code!r} is not a valid 4- or 5-digit code: {reason}")

    digits = _CODE.fullmatch(code).group(1)
    if not digits.isascii() or not digits.isdigit():
        raise invalid("expected 4 or 5 digits, optionally after 'NACA' (e.g. '2412', 'NACA 23012')")
    if len(digits) not in (4, 5):
        raise invalid(f"it has {len(digits)} digits; use 4 (e.g. '2412') or 5 (e.g. '23012')")
    thickness = int(digits[-2:]) / 100.0
    if thickness == 0.0:
        raise invalid("the last two digits give the thickness in percent of chord and must not be 00")
    if len(digits) == 4:
        m, p = int(digits[0]) / 100.0, int(digits[1]) / 10.0
        if m > 0.0 and p == 0.0:
            raise invalid("a cambered section needs a camber-position digit 1-9 (e.g. '2412')")
        if m == 0.0 and p > 0.0:
            raise invalid(f"a symmetric section has camber-position digit 0; use '00{digits[2:]}'")
        mean_line: FourDigitMeanLine | FiveDigitMeanLine = FourDigitMeanLine(m, p)
    else:
        lift_digit, line = int(digits[0]), "2" + digits[1:3]
        if lift_digit == 0:
            raise invalid(f"the first digit sets the design lift coefficient 0.15 L and must be 1-9; "
                          f"for a symmetric section use the 4-digit code '00{digits[3:]}'")
        if digits[2] not in "01":
            raise invalid("the third digit must be 0 (standard mean line) or 1 (reflexed mean line)")
        if line not in FIVE_DIGIT_MEAN_LINES:
            raise invalid(f"mean line digits {digits[1:3]!r} (position {digits[1]}, reflex {digits[2]}) are "
                          f"not tabulated; use position digit 1-5 for a standard line (210-250) or 2-5 "
                          f"for a reflexed one (221-251)")
        mean_line = FiveDigitMeanLine(line, 0.15 * lift_digit, FIVE_DIGIT_MEAN_LINES[line])
    return NacaSection(digits, thickness, mean_line, bool(closed_te))


def naca(code: str, n_points: int = 257, closed_te: bool = True) -> Airfoil:
    """A NACA 4- or 5-digit section as an :class:`~targets.Airfoil`.

    Args:
        code, closed_te: as :func:`parse_naca`'s.
        n_points: Number of points, both trailing-edge points included (for a
            closed trailing edge the first and last coincide exactly); at
            least 7. Points sit at cosine-spaced camber-line stations, see
            the module docstring.

    Returns:
        The section in Selig order, chord-normalised, named "NACA <digits>".

    Raises:
        ValueError: If the code or n_points is invalid, or the section folds
            over itself (x turns back along a surface, as NACA 9999's does
            near its trailing edge): no rib or bay can be built on it.
    """
    section = parse_naca(code, closed_te).airfoil(n_points)
    if section.surface_error is not None:
        raise ValueError(f"{section.name}: {section.surface_error}; a section this thick or this cambered folds "
                         "over itself: choose a thinner or less cambered code")
    return section
