"""The cut as a field: prestrain varying along the contour (docs/design_problem.md).

A uniform prestrain cuts every fibre of one direction the same fraction
shorter than its mounted length (eq. 12: reference length = mounted length /
(1 + prestrain)). A cut pattern lets that fraction vary along the contour::

    eps_span(s)  = prestrain_span  + sum_k a_k N_k(s),
    eps_chord(s) = prestrain_chord + sum_k b_k N_k(s),

with ``s`` in [0, 1] the normalised arc parameter of the contour (0 at the
trailing edge's upper node, about 0.5 at the leading edge, 1 back at the
trailing edge after the lower surface; Selig order), ``N_k`` the K clamped
B-splines of degree ``min(3, K - 1)`` on uniform knots, and the
coefficients ``[a_0..a_{K-1}, b_0..b_{K-1}]`` (`Parameters.cut_pattern`).
Span fibres take the field at their contour node ``s_j``, contour fibres at
their edge's midpoint ``s_{j+1/2}``; the reference lengths of eq. (12) are
then ``h1 = |x0_{i+1,j} - x0_{i,j}| / (1 + eps_span(s_j))`` and ``h2 =
|x0_{i,j+1} - x0_{i,j}| / (1 + eps_chord(s_{j+1/2}))``.

The B-splines are a partition of unity and non-negative, so a constant
field (every ``a_k = a``) is the uniform prestrain ``prestrain_span + a``
exactly, and the field lies between its smallest and largest coefficient
(the convex-hull property): bounding each ``prestrain + coefficient``
bounds the local prestrain everywhere, which is how a design keeps the cut
within its bounds (`inverse_design.variables`). No coefficients (None) is
today's uniform cut, at no cost.

``s`` comes from the chord-normalised section contours (the mean of the
root's and the tip's), not from the mounted rib, so it does not depend on
the design: the derivatives of the equilibrium in the coefficients enter
only through the cut lengths (the implicit adjoint's right-hand side,
`forward_solver.derivatives.implicit`). The field varies along the contour, not the
span, so a symmetric bay stays symmetric about mid-span; a wing's bays share
one field, or each has its own (`solve_bays`'s ``cut_patterns``, one row per
bay).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["spline_basis", "contour_parameter", "local_prestrain", "field_values"]


def _knots(n_terms: int) -> tuple[np.ndarray, int]:
    degree = min(3, n_terms - 1)
    interior = np.linspace(0.0, 1.0, n_terms - degree + 1)[1:-1]
    return np.concatenate([np.zeros(degree + 1), interior, np.ones(degree + 1)]), degree


def spline_basis(s, n_terms: int):
    """``(len(s), n_terms)`` clamped uniform B-splines of degree ``min(3, K - 1)`` at ``s`` in [0, 1].

    Cox-de Boor recursion on static knots (``s`` may be traced); the basis
    sums to 1 at every ``s`` (``s`` is clipped to [0, 1]).
    """
    if n_terms < 1:
        raise ValueError(f"a cut pattern needs at least 1 term, got {n_terms}")
    knots, degree = _knots(n_terms)
    s = jnp.clip(jnp.asarray(s), 0.0, 1.0)
    last = max(i for i in range(len(knots) - 1) if knots[i] < knots[i + 1])
    basis = []
    for i in range(len(knots) - 1):
        if knots[i] == knots[i + 1]:
            basis.append(jnp.zeros_like(s))
        elif i == last:
            basis.append(jnp.where((s >= knots[i]) & (s <= knots[i + 1]), 1.0, 0.0))
        else:
            basis.append(jnp.where((s >= knots[i]) & (s < knots[i + 1]), 1.0, 0.0))
    for d in range(1, degree + 1):
        nxt = []
        for i in range(len(knots) - 1 - d):
            term = jnp.zeros_like(s)
            if knots[i + d] > knots[i]:
                term = term + (s - knots[i]) / (knots[i + d] - knots[i]) * basis[i]
            if knots[i + d + 1] > knots[i + 1]:
                term = term + (knots[i + d + 1] - s) / (knots[i + d + 1] - knots[i + 1]) * basis[i + 1]
            nxt.append(term)
        basis = nxt
    return jnp.stack(basis, axis=-1)


def contour_parameter(contour_root, contour_tip, periodic: bool):
    """``(s_nodes (nc,), s_edges (ne,))``: normalised arc parameter of each contour node and edge midpoint.

    Measured along the mean of the root and tip chord-normalised contours;
    a closed (periodic) contour includes its closing edge, so the last edge's
    midpoint lies just short of 1.
    """
    points = 0.5 * (jnp.asarray(contour_root) + jnp.asarray(contour_tip))
    following = jnp.roll(points, -1, axis=0) if periodic else points[1:]
    edges = jnp.sqrt(jnp.sum((following - points[: following.shape[0]]) ** 2, axis=-1))
    before = jnp.concatenate([jnp.zeros(1, edges.dtype), jnp.cumsum(edges)])
    total = before[-1]
    return before[: points.shape[0]] / total, (before[:-1] + 0.5 * edges) / total


def local_prestrain(geometry, params, periodic: bool):
    """``(span, chord)`` prestrain of the kernel ``params``: scalars, or with a cut pattern the fields.

    ``span`` is ``(nc,)`` (one per contour node, its span fibres), ``chord``
    ``(ne,)`` (one per contour edge); both broadcast against the
    ``(ns - 1, nc)`` span and ``(ns, ne)`` contour edges.
    """
    coefficients = params.cut_pattern
    if jnp.shape(coefficients)[-1] == 0:
        return params.prestrain_span, params.prestrain_chord
    n_terms = jnp.shape(coefficients)[-1] // 2
    s_nodes, s_edges = contour_parameter(geometry.contour_root, geometry.contour_tip, periodic)
    span = params.prestrain_span + spline_basis(s_nodes, n_terms) @ coefficients[:n_terms]
    chord = params.prestrain_chord + spline_basis(s_edges, n_terms) @ coefficients[n_terms:]
    return span, chord


def field_values(s, prestrain_span, prestrain_chord, cut_pattern):
    """``(span, chord)`` local prestrain at the arc parameters ``s`` (numpy, for reports and plots)."""
    s = np.asarray(s, np.float64)
    if cut_pattern is None or np.size(cut_pattern) == 0:
        return np.full(s.shape, float(prestrain_span)), np.full(s.shape, float(prestrain_chord))
    c = np.asarray(cut_pattern, np.float64)
    with jax.enable_x64(True):
        basis = np.asarray(spline_basis(jnp.asarray(s), c.size // 2))
    return float(prestrain_span) + basis @ c[: c.size // 2], float(prestrain_chord) + basis @ c[c.size // 2:]
