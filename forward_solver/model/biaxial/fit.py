"""The fibre law fitted to a biaxial test (`fit_law`): a strain-energy surface and how well it fits.

The surface (`surface.EnergySurface`) is linear in its coefficients, and so
are its tensions: both tensions of every reading are fitted together by
linear least squares (N/m, each direction's errors weighted alike), the
strains scaled by their largest value so that the columns are of one size.
Data that come from a reciprocal linear law (eq. 10 with equal stiffnesses
both ways among them) are reproduced exactly, to rounding, at every degree:
the quadratic terms hold the law and the higher ones come out zero.

The degree is the highest of `DEGREES` whose surface has a positive-definite
tangent along every tested path (at each reading, between consecutive
readings and from zero load to a path's first reading): a higher degree
follows the curves more closely, and a fit that bends the tangent negative
where the fabric was tested would make a law with no stable equilibrium
there. The choice is recorded (`FittedLaw.notes`). A test for which even the
linear surface is not positive-definite is refused.

The fabric's nominal stiffness is the linear surface's, as the
plane-stress moduli of EN 17117-1 are fitted to all paths by least
squares: with ``K`` its constant tangent, ``E_warp = k_ww - k_wf^2 / k_ff``
(the warp's stiffness with the weft unloaded), ``E_weft`` likewise, and the
coupling ``nu = k_wf / sqrt(k_ww k_ff)``; for eq. 10 with ``E11 = E22 = E``
they are ``E`` and ``nu``. A fabric lot's stiffness scatter scales each
direction's tensions by its stiffness over this nominal one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .readings import BiaxialTest, TestFileError
from .surface import EnergySurface, monomials

__all__ = ["DEGREES", "FIT_WARNING", "FittedLaw", "fit_law", "points_on_paths"]

#: The degrees of the surface tried, highest first (4: cubic tensions).
DEGREES = (4, 3, 2)
#: The fit's largest error, as a fraction of the largest tension tested, beyond which a design warns.
FIT_WARNING = 0.05
#: Points put between consecutive readings of a path where the tangent must be positive-definite.
_BETWEEN = 3


@dataclass(frozen=True)
class FittedLaw:
    """A fibre law fitted to a biaxial test (module docstring). Values only (tuples, floats): it compares
    and pickles as a value.

    Attributes:
        surface: the strain-energy surface (`surface.EnergySurface`), warp and weft.
        stiffness_warp, stiffness_weft: the nominal stiffnesses, N/m (the linear fit's, module docstring).
        poisson: the linear fit's coupling ``k_wf / sqrt(k_ww k_ff)``.
        rms_error, max_error: ``(warp, weft)`` the fit's rms and largest error over the readings, N/m.
        readings: the number of readings.
        paths: the load-ratio paths' labels.
        source: the test file's name.
        digest: the first 16 hex digits of the file's SHA-256.
        notes: what the fit chose (the degree, and why where it is not the highest).
        largest_tension: ``(warp, weft)`` the largest tension read, N/m.
    """

    surface: EnergySurface
    stiffness_warp: float
    stiffness_weft: float
    poisson: float
    rms_error: tuple
    max_error: tuple
    readings: int
    paths: tuple
    source: str
    digest: str
    notes: tuple = ()
    largest_tension: tuple = (math.nan, math.nan)

    def tensions(self, e_warp, e_weft, xp=np):
        """``(T_warp, T_weft)``, N/m (`surface.EnergySurface.tensions`)."""
        return self.surface.tensions(e_warp, e_weft, xp)

    @property
    def strain_range(self) -> dict:
        """``{"warp": (least, largest), "weft": (least, largest)}``: the tested strains."""
        return {"warp": tuple(self.surface.warp_range), "weft": tuple(self.surface.weft_range)}

    def as_dict(self) -> dict:
        """The law as a summary records it (plain JSON types)."""
        return {"kind": "strain-energy surface", "degree": self.surface.degree,
                "coefficients": {f"e_warp^{a} e_weft^{b}": c
                                 for (a, b), c in zip(monomials(self.surface.degree), self.surface.coefficients)},
                "coefficient_unit": "N/m", "source": self.source, "sha256": self.digest, "readings": self.readings,
                "paths": list(self.paths),
                "tested_strain": {k: list(v) for k, v in self.strain_range.items()},
                "fit_error_n_per_m": {"rms": {"warp": self.rms_error[0], "weft": self.rms_error[1]},
                                      "max": {"warp": self.max_error[0], "weft": self.max_error[1]}},
                "largest_tension_n_per_m": {"warp": self.largest_tension[0], "weft": self.largest_tension[1]},
                "nominal": {"stiffness_warp_n_per_m": self.stiffness_warp,
                            "stiffness_weft_n_per_m": self.stiffness_weft, "poisson": self.poisson},
                "notes": list(self.notes)}

    def fit_warning(self) -> str | None:
        """One line when the fit misses a reading by more than `FIT_WARNING` of the largest tension tested
        (the law does not follow the test there), else None."""
        full = max(self.largest_tension)
        worst = max(self.max_error)
        if not worst > FIT_WARNING * full:
            return None
        return (f"the fibre law fitted to {self.source} misses a reading by {worst:.4g} N/m, "
                f"{100 * worst / full:.3g}% of the largest tension tested ({full:.4g} N/m; surface of degree "
                f"{self.surface.degree}): check the readings, or read the design as that uncertain "
                "(docs/fabric_test.md)")

    def describe(self) -> str:
        """One paragraph: the law, its fit and its tested range, in words."""
        w, f = self.strain_range["warp"], self.strain_range["weft"]
        return (f"fibre law fitted to {self.source} ({self.readings} readings on {len(self.paths)} paths: "
                f"{', '.join(self.paths)}): a strain-energy surface of degree {self.surface.degree}; fit error warp "
                f"rms {self.rms_error[0]:.3g} N/m, max {self.max_error[0]:.3g} N/m, weft rms {self.rms_error[1]:.3g} "
                f"N/m, max {self.max_error[1]:.3g} N/m; tested strains warp {100 * w[0]:.3g}% to {100 * w[1]:.3g}%, "
                f"weft {100 * f[0]:.3g}% to {100 * f[1]:.3g}%; nominal stiffness warp {self.stiffness_warp:.4g} N/m, "
                f"weft {self.stiffness_weft:.4g} N/m, coupling {self.poisson:.3g}")


def points_on_paths(test: BiaxialTest) -> tuple:
    """``(e_warp, e_weft)``: the strains along every tested path, where the fitted tangent must be
    positive-definite (each reading, `_BETWEEN` points between consecutive readings of a path, and as
    many from zero strain to a path's first reading)."""
    warp, weft = [test.strain_warp], [test.strain_weft]
    t = np.linspace(0.0, 1.0, _BETWEEN + 2)[1:-1]
    for label in test.path_labels:
        k = test.path(label)
        a = np.concatenate([[0.0], test.strain_warp[k]]), np.concatenate([[0.0], test.strain_weft[k]])
        for values, out in zip(a, (warp, weft)):
            out.append((values[:-1, None] + t[None, :] * np.diff(values)[:, None]).ravel())
    return np.concatenate(warp), np.concatenate(weft)


def _least_squares(test: BiaxialTest, degree: int) -> EnergySurface:
    """The surface of ``degree`` whose tensions fit both tensions of every reading (module docstring)."""
    sw = max(float(np.max(np.abs(test.strain_warp))), 1e-12)
    sf = max(float(np.max(np.abs(test.strain_weft))), 1e-12)
    u, v = test.strain_warp / sw, test.strain_weft / sf
    columns = []
    for a, b in monomials(degree):  # d/de_warp and d/de_weft of (e_warp / sw)^a (e_weft / sf)^b
        warp = a * u ** max(a - 1, 0) * v ** b / sw if a else np.zeros_like(u)
        weft = b * u ** a * v ** max(b - 1, 0) / sf if b else np.zeros_like(u)
        columns.append(np.concatenate([warp, weft]))
    matrix = np.stack(columns, axis=1)
    norms = np.linalg.norm(matrix, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    rhs = np.concatenate([test.tension_warp, test.tension_weft])
    q = np.linalg.lstsq(matrix / norms, rhs, rcond=None)[0] / norms
    coefficients = tuple(float(c / (sw ** a * sf ** b)) for c, (a, b) in zip(q, monomials(degree)))
    return EnergySurface(degree, coefficients, test.warp_range, test.weft_range)


def fit_law(test: BiaxialTest, degree: int | None = None) -> FittedLaw:
    """The fibre law fitted to ``test`` (module docstring).

    Args:
        test: the readings (`readings.read_test`).
        degree: the surface's degree (2: linear; 4: cubic tensions); None takes the highest of
            `DEGREES` whose tangent is positive-definite along the tested paths.

    Returns:
        The `FittedLaw`.

    Raises:
        TestFileError: when no surface (or not the one of ``degree``) has a positive-definite
            tangent along the tested paths, naming the strains where it fails.
    """
    points = points_on_paths(test)
    linear = _least_squares(test, 2)
    kww, kwf, kff = linear.tangent(0.0, 0.0)
    if not (kww > 0 and kff > 0 and kww * kff > kwf * kwf):
        raise TestFileError(f"{test.source}: no stable linear law fits the readings (the least-squares stiffness "
                            f"warp {kww:.4g}, weft {kff:.4g}, coupling {kwf:.4g} N/m is not positive-definite): check "
                            "the columns (warp and weft swapped, a sign) and the paths")
    notes, chosen = [], None
    for d in (DEGREES if degree is None else (degree,)):
        surface = linear if d == 2 else _least_squares(test, d)
        where = surface.not_positive_definite(*points)
        if where is None:
            chosen = surface
            break
        notes.append(f"a surface of degree {d} was not taken: its tangent is not positive-definite at warp "
                     f"{100 * where[0]:.3g}%, weft {100 * where[1]:.3g}%, on a tested path")
    if chosen is None:
        raise TestFileError(f"{test.source}: {notes[-1].replace('was not taken: its', 'fits the readings, but its')}; "
                            "check the readings there, or give fewer, smoother ones")
    notes.append(f"degree {chosen.degree}")
    t_warp, t_weft = chosen.polynomial_tensions(test.strain_warp, test.strain_weft)
    errors = (t_warp - test.tension_warp, t_weft - test.tension_weft)
    return FittedLaw(surface=chosen, stiffness_warp=float(kww - kwf * kwf / kff),
                     stiffness_weft=float(kff - kwf * kwf / kww), poisson=float(kwf / math.sqrt(kww * kff)),
                     rms_error=tuple(float(np.sqrt(np.mean(e * e))) for e in errors),
                     max_error=tuple(float(np.max(np.abs(e))) for e in errors), readings=test.size,
                     paths=test.path_labels, source=test.source, digest=test.digest, notes=tuple(notes),
                     largest_tension=(float(np.max(test.tension_warp)), float(np.max(test.tension_weft))))
