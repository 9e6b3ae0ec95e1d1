"""A fabric's fibre law as a strain-energy surface ``W(e_warp, e_weft)``, evaluated on NumPy or JAX arrays.

The tensions are the surface's gradient, ``T_warp = dW/de_warp`` and
``T_weft = dW/de_weft`` (N/m), and its Hessian is the tangent stiffness
(N/m), symmetric: the law is reciprocal (the warp's response to the weft's
strain is the weft's to the warp's), so it has an energy and Newton's
material tangent is symmetric. ``W`` is a polynomial without constant or
linear terms (no tension at zero strain: the cut state is unstressed)::

    W = sum_{2 <= a + b <= degree} c_ab e_warp^a e_weft^b      (N/m)

which is a response surface fitted directly to biaxial readings, after
Bridgens & Gosling (2004, "Direct stress-strain representation for coated
woven fabrics", Computers & Structures 82:1913), written as an energy so
that it stays reciprocal. Its quadratic terms are the reciprocal linear law
``T = K e``; degree 2 is exactly that law (eq. 10 of the paper with equal
stiffnesses both ways is one), degree 4 gives cubic tensions, enough for the
soft start and later stiffening of crimp interchange.

Outside the tested strain range (`EnergySurface.warp_range`, ``weft_range``:
the readings' least and largest strain in each direction) the polynomial is
not trusted: the tensions continue along the tangent at the range's edge,
``T(e) = T(c) + K(c) (e - c)`` with ``c`` the strain clamped into the range.
That is continuous with a continuous tangent, and grows linearly (a
polynomial's cubic terms would turn over or run away). Beyond the range the
tangent is exactly ``K(c)`` where both strains are outside; where one is, it
gains the change of ``K`` along the range's edge times the excess strain
(so the continuation is reciprocal only in the range and its corners).

Every function takes the array module ``xp`` (``numpy`` by default,
``jax.numpy`` in the solver's force kernel): the coefficients are Python
floats and the arithmetic is the same on both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["EnergySurface", "monomials"]

#: Points per direction of the grid over the tested range on which the tangent's bounds are taken.
BOUND_GRID = 33


def monomials(degree: int) -> tuple:
    """The exponents ``(a, b)`` of ``e_warp^a e_weft^b`` in ``W`` of that degree, quadratic terms first."""
    return tuple((n - b, b) for n in range(2, degree + 1) for b in range(n + 1))


def _powers(e, highest: int, xp):
    """``[1, e, e^2, ..., e^highest]`` (by products: the same rounding on NumPy and JAX)."""
    out = [xp.ones_like(e), e]
    for _ in range(highest - 1):
        out.append(out[-1] * e)
    return out


@dataclass(frozen=True)
class EnergySurface:
    """``W(e_warp, e_weft)``, its gradient (the tensions) and Hessian (the tangent) (module docstring).

    Attributes:
        degree: the polynomial's degree, 2 (a linear law) or more.
        coefficients: ``c_ab`` in the order of `monomials` (``degree``), N/m.
        warp_range: ``(least, largest)`` tested warp strain (fractions).
        weft_range: the same for the weft.
    """

    degree: int
    coefficients: tuple
    warp_range: tuple
    weft_range: tuple

    def __post_init__(self) -> None:
        terms = monomials(self.degree)
        if len(self.coefficients) != len(terms):
            raise ValueError(f"a surface of degree {self.degree} has {len(terms)} coefficients, "
                             f"got {len(self.coefficients)}")
        for name in ("warp_range", "weft_range"):
            low, high = getattr(self, name)
            if not (math.isfinite(low) and math.isfinite(high) and low < high):
                raise ValueError(f"{name} must be (least, largest) finite strains, got {getattr(self, name)!r}")

    # ------------------------------------------------------------------ the polynomial
    def polynomial_tensions(self, e_warp, e_weft, xp=np):
        """``(T_warp, T_weft)``, N/m, of the polynomial itself (no continuation outside the range)."""
        pw, pf = _powers(e_warp, self.degree - 1, xp), _powers(e_weft, self.degree - 1, xp)
        t_warp = t_weft = 0.0
        for (a, b), c in zip(monomials(self.degree), self.coefficients):
            if a:
                t_warp = t_warp + (a * c) * pw[a - 1] * pf[b]
            if b:
                t_weft = t_weft + (b * c) * pw[a] * pf[b - 1]
        return t_warp, t_weft

    def tangent(self, e_warp, e_weft, xp=np):
        """``(k_warp_warp, k_warp_weft, k_weft_weft)``, N/m: the polynomial's Hessian (``dT_warp/de_warp``,
        ``dT_warp/de_weft = dT_weft/de_warp``, ``dT_weft/de_weft``)."""
        pw, pf = _powers(e_warp, self.degree - 1, xp), _powers(e_weft, self.degree - 1, xp)
        kww = kwf = kff = 0.0
        for (a, b), c in zip(monomials(self.degree), self.coefficients):
            if a >= 2:
                kww = kww + (a * (a - 1) * c) * pw[a - 2] * pf[b]
            if a and b:
                kwf = kwf + (a * b * c) * pw[a - 1] * pf[b - 1]
            if b >= 2:
                kff = kff + (b * (b - 1) * c) * pw[a] * pf[b - 2]
        return kww, kwf, kff

    def energy(self, e_warp, e_weft, xp=np):
        """``W``, N/m (J/m^2), of the polynomial."""
        pw, pf = _powers(e_warp, self.degree, xp), _powers(e_weft, self.degree, xp)
        total = 0.0
        for (a, b), c in zip(monomials(self.degree), self.coefficients):
            total = total + c * pw[a] * pf[b]
        return total

    # ------------------------------------------------------------------ the law
    def tensions(self, e_warp, e_weft, xp=np):
        """``(T_warp, T_weft)``, N/m: the polynomial's gradient in the tested range, continued along its
        tangent at the range's edge outside it (module docstring)."""
        c_warp = xp.clip(e_warp, *self.warp_range)
        c_weft = xp.clip(e_weft, *self.weft_range)
        t_warp, t_weft = self.polynomial_tensions(c_warp, c_weft, xp)
        kww, kwf, kff = self.tangent(c_warp, c_weft, xp)
        d_warp, d_weft = e_warp - c_warp, e_weft - c_weft
        return t_warp + kww * d_warp + kwf * d_weft, t_weft + kwf * d_warp + kff * d_weft

    def inside(self, e_warp, e_weft):
        """Whether each strain pair lies in the tested range (NumPy)."""
        return ((self.warp_range[0] <= e_warp) & (e_warp <= self.warp_range[1])
                & (self.weft_range[0] <= e_weft) & (e_weft <= self.weft_range[1]))

    def grid(self, n: int = BOUND_GRID):
        """``(e_warp, e_weft)``: an ``n x n`` grid over the tested range (NumPy)."""
        return np.meshgrid(np.linspace(*self.warp_range, n), np.linspace(*self.weft_range, n), indexing="ij")

    def tangent_bounds(self) -> dict:
        """The tangent's largest values over the tested range (a `BOUND_GRID` grid), N/m: ``row_warp``
        and ``row_weft`` the largest row sums ``|k_ww| + |k_wf|`` and ``|k_wf| + |k_ff|`` (a Gershgorin
        bound of each direction's stiffness), ``diagonal_warp`` and ``diagonal_weft`` the largest
        ``|k_ww|`` and ``|k_ff|``. Outside the range the tangent is that of its edge (module docstring),
        so these bound it there too, up to the change along an edge times the excess strain."""
        kww, kwf, kff = self.tangent(*self.grid())
        return {"row_warp": float(np.max(np.abs(kww) + np.abs(kwf))),
                "row_weft": float(np.max(np.abs(kwf) + np.abs(kff))),
                "diagonal_warp": float(np.max(np.abs(kww))), "diagonal_weft": float(np.max(np.abs(kff)))}

    def not_positive_definite(self, e_warp, e_weft):
        """The first strain pair among ``e_warp``, ``e_weft`` (NumPy arrays) where the tangent is not
        positive-definite, as ``(e_warp, e_weft)``, or None where it is at every one."""
        kww, kwf, kff = self.tangent(np.asarray(e_warp, np.float64), np.asarray(e_weft, np.float64))
        bad = ~((kww > 0) & (kff > 0) & (kww * kff - kwf * kwf > 0))
        if not np.any(bad):
            return None
        k = int(np.argmax(bad))
        return float(np.ravel(e_warp)[k]), float(np.ravel(e_weft)[k])

    def strains_at(self, t_warp: float, t_weft: float, tol: float = 1e-12, max_steps: int = 100):
        """The strains ``(e_warp, e_weft)`` at which the law carries the tensions ``(t_warp, t_weft)`` (N/m):
        its inverse, by Newton's method from zero strain (NumPy).

        Raises:
            ValueError: when Newton's method does not reach ``tol`` (relative to the tensions) in
                ``max_steps`` steps (a tangent that is not positive-definite on the way).
        """
        target = np.array([t_warp, t_weft], np.float64)
        e = np.zeros(2)
        scale = max(float(np.max(np.abs(target))), 1.0)
        for _ in range(max_steps):
            residual = np.array(self.tensions(e[0], e[1])) - target
            if np.max(np.abs(residual)) <= tol * scale:
                return float(e[0]), float(e[1])
            kww, kwf, kff = self.tangent(*np.clip(e, [self.warp_range[0], self.weft_range[0]],
                                                  [self.warp_range[1], self.weft_range[1]]))
            e = e - np.linalg.solve(np.array([[kww, kwf], [kwf, kff]], np.float64), residual)
        raise ValueError(f"no strain found for the tensions ({t_warp:g}, {t_weft:g}) N/m within {max_steps} "
                         "Newton steps: the law's tangent is not positive-definite on the way")
