"""Exact tests of closed polygons for the marker's checks: do two outlines cross, does one hold a point of
the other, how far apart are they. NumPy only (no shapely), vectorised over every pair of edges.

A polygon is ``(n, 2)`` points, closed from its last point to its first.
"""

from __future__ import annotations

import numpy as np


def _edges(polygon) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(polygon, np.float64)
    return p, np.roll(p, -1, axis=0)


def _orientation(a, b, c) -> np.ndarray:
    """The sign of the turn a -> b -> c (broadcast): +1 left, -1 right, 0 collinear."""
    return np.sign((b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0]))


def edges_cross(first, second) -> bool:
    """Whether an edge of ``first`` and an edge of ``second`` meet (a touch counts)."""
    a0, a1 = (e[:, None, :] for e in _edges(first))
    b0, b1 = (e[None, :, :] for e in _edges(second))
    d1, d2 = _orientation(b0, b1, a0), _orientation(b0, b1, a1)
    d3, d4 = _orientation(a0, a1, b0), _orientation(a0, a1, b1)
    proper = (d1 * d2 < 0) & (d3 * d4 < 0)
    # a touch: an end on the other edge (collinear and within its box)
    def on(p, s0, s1, d):
        inside = ((np.minimum(s0[..., 0], s1[..., 0]) <= p[..., 0]) & (p[..., 0] <= np.maximum(s0[..., 0], s1[..., 0]))
                  & (np.minimum(s0[..., 1], s1[..., 1]) <= p[..., 1]) & (p[..., 1] <= np.maximum(s0[..., 1], s1[..., 1])))
        return (d == 0) & inside
    touch = on(a0, b0, b1, d1) | on(a1, b0, b1, d2) | on(b0, a0, a1, d3) | on(b1, a0, a1, d4)
    return bool(np.any(proper | touch))


def inside(point, polygon) -> bool:
    """Whether ``point`` lies inside ``polygon`` (even-odd ray casting along +x)."""
    x, y = float(point[0]), float(point[1])
    p0, p1 = _edges(polygon)
    spans = (p0[:, 1] > y) != (p1[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        crossing = p0[:, 0] + (y - p0[:, 1]) * (p1[:, 0] - p0[:, 0]) / (p1[:, 1] - p0[:, 1])
    return bool(np.count_nonzero(spans & (x < crossing)) % 2)


def overlap(first, second) -> bool:
    """Whether two closed polygons share any point: their edges meet, or one lies inside the other."""
    return edges_cross(first, second) or inside(first[0], second) or inside(second[0], first)


def _point_segment(points, s0, s1) -> float:
    """The least distance from any of ``points`` to any segment ``s0 -> s1``."""
    p = np.asarray(points, np.float64)[:, None, :]
    d = (s1 - s0)[None]
    t = np.clip(np.sum((p - s0[None]) * d, axis=-1) / np.maximum(np.sum(d * d, axis=-1), 1e-300), 0.0, 1.0)
    return float(np.min(np.linalg.norm(p - (s0[None] + t[..., None] * d), axis=-1)))


def distance(first, second) -> float:
    """The least distance between the outlines of two polygons that do not overlap (`overlap`): between
    edges that do not cross it lies at an end of one of them."""
    a0, a1 = _edges(first)
    b0, b1 = _edges(second)
    return min(_point_segment(first, b0, b1), _point_segment(second, a0, a1))


def area(polygon) -> float:
    """A closed polygon's area (shoelace)."""
    p = np.asarray(polygon, np.float64)
    return 0.5 * abs(float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])))
