"""Keeps the x-coordinate of a contour spline monotonic where its points are.

A cubic spline of x against chord length is not shape preserving: where the
spacing or the curvature changes abruptly, x(s) overshoots between nodes. At
a sharp nose (x rising like s^4 away from the nose node, e.g. UIUC ``k1``,
``e193gu``, ``rc0864c``) it dips below the nose on both sides, so x runs
back and forth (a "W") although the points are monotonic; thickness and
camber then refuse the section. Near a rounded, asymmetric trailing edge a
periodic spline puts its largest x beside the trailing-edge node
(``dbln526``).

:func:`limit_x_reversals` repairs the spline where, and only where, it
reverses against its points: it keeps the C2 spline's slopes dx/ds at the
nodes, except at the two nodes of an interval where x(s) turns back, whose
slopes it limits with Hyman's filter (J. M. Hyman, "Accurate
monotonicity-preserving cubic interpolation", SIAM J. Sci. Stat. Comput. 4,
1983): a slope keeps the sign of the adjacent secants and at most three times
the smaller of them, and is zero at a local extremum of the points (Fritsch
and Carlson's sufficient condition for a monotonic cubic Hermite interval).
The repaired x(s) is a C1 cubic Hermite interpolant of the same points; z(s)
is untouched, so the contour stays C1 and keeps C2 wherever nothing reversed.

The two intervals beside the minimum-x node are special: the leading edge is
the minimum of the smooth contour, which may lie between nodes (any round
nose not sampled at its tip), so they may hold one turn from decreasing to
increasing x, but not more.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PPoly

REVERSAL_TOLERANCE = 1e-9
"""Largest dx/ds of the wrong sign taken as monotonic. The parameter is chord
length, so |d(x, z)/ds| is about 1 and this is a relative slope."""


def _hermite_coefficients(knots: np.ndarray, values: np.ndarray, slopes: np.ndarray) -> np.ndarray:
    """PPoly coefficients, shape (4, m), of the cubic Hermite interpolant of values and slopes."""
    step = np.diff(knots)
    secant = np.diff(values) / step
    left, right = slopes[:-1], slopes[1:]
    return np.stack(
        [
            (left + right - 2.0 * secant) / step**2,
            (3.0 * secant - 2.0 * left - right) / step,
            left,
            values[:-1],
        ]
    )


def _slope_range(coefficients: np.ndarray, step: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Smallest and largest derivative of each cubic piece over its interval (exact)."""
    cubic, quadratic, linear = coefficients[0], coefficients[1], coefficients[2]
    at_end = 3.0 * cubic * step**2 + 2.0 * quadratic * step + linear
    low, high = np.minimum(linear, at_end), np.maximum(linear, at_end)
    curved = cubic != 0.0
    vertex = np.where(curved, -quadratic / np.where(curved, 3.0 * cubic, 1.0), -1.0)
    inside = curved & (vertex > 0.0) & (vertex < step)
    at_vertex = np.where(inside, linear + quadratic * vertex, linear)  # 3c t^2 + 2q t + l at t*
    return np.minimum(low, at_vertex), np.maximum(high, at_vertex)


def _rises_then_falls(coefficients: np.ndarray, knots: np.ndarray) -> bool:
    """Whether x(s) on consecutive pieces goes from increasing to decreasing anywhere."""
    derivative = PPoly(
        coefficients[:-1] * np.array([3.0, 2.0, 1.0])[:, None], knots, extrapolate=False
    )
    roots = derivative.roots(discontinuity=False, extrapolate=False)
    breaks = np.unique(np.concatenate([knots, roots[np.isfinite(roots)]]))
    slope = derivative(0.5 * (breaks[:-1] + breaks[1:]))
    signs = np.sign(slope[np.abs(slope) > REVERSAL_TOLERANCE])
    rising = np.flatnonzero(signs > 0)
    return bool(rising.size and (signs[rising[0] :] < 0).any())


def _reversing_nodes(coefficients: np.ndarray, knots: np.ndarray, secant: np.ndarray, nose: int) -> np.ndarray:
    """Nodes bounding the pieces whose x(s) turns back against the points."""
    low, high = _slope_range(coefficients, np.diff(knots))
    moves = np.maximum(-low, high) > REVERSAL_TOLERANCE  # where the nodes' x are equal
    reverses = np.where(
        secant > 0.0,
        low < -REVERSAL_TOLERANCE,
        np.where(secant < 0.0, high > REVERSAL_TOLERANCE, moves),
    )
    reverses[nose - 1 : nose + 1] = False
    nodes = np.union1d(np.flatnonzero(reverses), np.flatnonzero(reverses) + 1)
    if _rises_then_falls(coefficients[:, nose - 1 : nose + 1], knots[nose - 1 : nose + 2]):
        nodes = np.union1d(nodes, [nose - 1, nose, nose + 1])
    return nodes


def _hyman_slopes(slopes: np.ndarray, secant: np.ndarray, periodic: bool) -> np.ndarray:
    """Slopes limited to Fritsch and Carlson's monotonic region (Hyman's filter)."""
    if periodic:
        before = np.concatenate([secant[-1:], secant])
        after = np.concatenate([secant, secant[:1]])
    else:
        before = np.concatenate([secant[:1], secant])  # an open end has one secant
        after = np.concatenate([secant, secant[-1:]])
    direction = np.where(before * after > 0.0, np.sign(after), 0.0)  # zero at an extremum
    bound = 3.0 * np.minimum(np.abs(before), np.abs(after))
    return direction * np.clip(direction * slopes, 0.0, bound)


def limit_x_reversals(spline: PPoly, x: np.ndarray, periodic: bool) -> PPoly:
    """The contour spline with x(s) monotonic wherever its nodes are.

    Args:
        spline: Cubic spline of the points (x, z) against chord length,
            coefficients of shape ``(4, m, 2)`` over ``m + 1`` knots.
        x: The nodes' x (chord units), shape ``(m + 1,)``; the minimum-x
            node is neither the first nor the last.
        periodic: Whether the spline is periodic (node m is node 0).

    Returns:
        ``spline`` itself when x(s) nowhere turns back against the nodes,
        otherwise a :class:`~scipy.interpolate.PPoly` through the same nodes
        whose x part has Hyman-limited slopes at the nodes of the reversing
        pieces (see the module docstring) and whose z part is unchanged.
    """
    knots = spline.x
    coefficients = spline.c[..., 0]
    secant = np.diff(x) / np.diff(knots)
    nose = int(np.argmin(x))
    slopes = spline(knots, 1)[:, 0]
    limited = _hyman_slopes(slopes, secant, periodic)
    changed = False
    # Each pass limits the nodes of the pieces still reversing; a limited node keeps its
    # slope, so the loop ends after at most one pass per node.
    for _ in range(knots.size):
        nodes = _reversing_nodes(coefficients, knots, secant, nose)
        if periodic and (0 in nodes or knots.size - 1 in nodes):
            nodes = np.union1d(nodes, [0, knots.size - 1])  # one node, two indices
        if nodes.size == 0 or np.array_equal(slopes[nodes], limited[nodes]):
            break
        slopes[nodes] = limited[nodes]
        coefficients = _hermite_coefficients(knots, x, slopes)
        changed = True
    if not changed:
        return spline
    both = spline.c.copy()
    both[..., 0] = coefficients
    return PPoly(both, knots, extrapolate=spline.extrapolate)
