"""Rib shape as design variables: a smooth outward offset of the rib contour.

The ribs fix the skin at their sections (paper, "Statement of the problem":
the rib and the skin meet along the rib contour, the boundary of eq. 1's
subregions). To let the design move that boundary, each rib contour gets an
offset along z, in fractions of chord, of the class-shape (CST) form of
Kulfan's parametrisation::

    dz_upper(x) = + C(x) sum_k a_k B_k(x),    dz_lower(x) = - C(x) sum_k b_k B_k(x),
    C(x) = sqrt(x) (1 - x),   B_k(x) = binom(K-1, k) x^k (1 - x)^(K-1-k),

with K Bernstein terms per surface and the coefficients ``[a_0..a_{K-1},
b_0..b_{K-1}]`` (`Parameters.rib_shape`). A positive coefficient moves its
surface outward (thickens the rib). The class function keeps the trailing
edge where it is (``C(1) = 0``) and lets the leading-edge radius change
(``dz ~ sqrt(x)`` near the nose, the way a round nose grows), so the offset
is smooth along the whole contour for any coefficients; a few terms (K = 3
to 8) span the useful shapes.

Upper and lower surfaces are told apart at the contour's leading-edge node
(the node of least x; Selig order: trailing edge, upper surface, leading
edge, lower surface). The offset is added after the rib thickness scale
(``z = camber + s (z0 - camber) + dz``) and before the chord scale, so all
three rib variables compose.

Everything here is a pure function of arrays: the coefficients may be JAX
tracers (``jax.grad`` flows to them through the mounted rib nodes, the cut
lengths of eq. 12 and the held-node pull of the implicit derivative).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from targets import Airfoil

__all__ = ["bernstein_basis", "class_function", "rib_offsets", "rib_section", "offset_basis"]


def _array_module(x):
    """NumPy for host values (a rib template's outline: no JAX program per outline length), else
    ``jax.numpy`` (JAX arrays and tracers)."""
    return np if isinstance(x, (np.ndarray, np.generic, float, int)) else jnp


def class_function(x):
    """``sqrt(x) (1 - x)`` on chord-normalised ``x`` (clipped to [0, 1]), with a finite derivative at 0."""
    xp = _array_module(x)
    x = xp.clip(x, 0.0, 1.0)
    positive = x > 0
    return xp.where(positive, xp.sqrt(xp.where(positive, x, 1.0)), 0.0) * (1.0 - x)


def bernstein_basis(x, n_terms: int):
    """``(len(x), n_terms)`` Bernstein polynomials of degree ``n_terms - 1`` at ``x`` in [0, 1]."""
    xp = _array_module(x)
    x = xp.clip(xp.asarray(x), 0.0, 1.0)[..., None]
    degree = n_terms - 1
    k = np.arange(n_terms)
    binomial = np.array([math.comb(degree, int(i)) for i in k], dtype=np.float64)
    return binomial * x ** k * (1.0 - x) ** (degree - k)


def offset_basis(contour_x, n_terms: int):
    """``(n_points, 2 K)``: the outward z offset of each contour point per unit coefficient.

    Column k < K moves the upper surface (points up to the leading-edge
    node, the one of least x), column K + k the lower surface, with the sign
    that makes a positive coefficient outward.

    Args:
        contour_x: ``(n_points,)`` chord-normalised x along the contour in
            Selig order.
        n_terms: K, Bernstein terms per surface.
    """
    contour_x = jnp.asarray(contour_x)
    index = jnp.arange(contour_x.shape[0])
    upper = (index <= jnp.argmin(contour_x))[:, None]
    shape = class_function(contour_x)[:, None] * bernstein_basis(contour_x, n_terms)
    zero = jnp.zeros_like(shape)
    return jnp.concatenate([jnp.where(upper, shape, zero), jnp.where(upper, zero, -shape)], axis=1)


def rib_offsets(contour_x, coefficients):
    """Outward z offset of the rib contour, chord-normalised, ``(n_points,)``.

    Args:
        contour_x: ``(n_points,)`` chord-normalised x in Selig order.
        coefficients: None or ``(0,)`` (no offset), or ``(2 K,)`` (upper
            surface, then lower).
    """
    contour_x = jnp.asarray(contour_x)
    if coefficients is None or jnp.shape(coefficients)[-1] == 0:
        return jnp.zeros_like(contour_x)
    coefficients = jnp.asarray(coefficients)
    return offset_basis(contour_x, coefficients.shape[-1] // 2) @ coefficients


def rib_section(airfoil, coefficients=None, thickness_scale: float = 1.0, n_points: int = 161,
                name: str | None = None):
    """The designed rib section as a chord-normalised `targets.Airfoil` (e.g. to write a ``.dat``).

    The rib of ``airfoil`` with its thickness scaled about the camber line
    and the offset of ``coefficients`` added, exactly as the solver mounts it
    (`forces.nominal_nodes`), on ``n_points`` points of the airfoil's own
    (cosine) spacing. The chord scale only changes the physical chord, so it
    does not enter a chord-normalised section.

    Args:
        airfoil: the rib's starting section (`targets.Airfoil`).
        coefficients: ``(2 K,)`` rib-shape coefficients, or None.
        thickness_scale: the rib thickness multiplier.
        n_points: points of the returned contour (Selig order).
        name: the section's name (default: the airfoil's with " rib").
    """
    resampled = airfoil.resample(n_points)
    x = np.asarray(resampled.x, np.float64)
    camber = np.asarray(airfoil.camber(np.clip(x, 0.0, 1.0)), np.float64)
    z = camber + thickness_scale * (np.asarray(resampled.z, np.float64) - camber)
    offsets = np.asarray(rib_offsets(x, None if coefficients is None else np.asarray(coefficients, np.float64)))
    return Airfoil(x, z + offsets, name=name or f"{airfoil.name} rib")
