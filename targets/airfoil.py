"""Airfoil sections: a closed contour in Selig order and its smooth representation.

An :class:`Airfoil` holds the nodes of a section (``x``, ``z``, chord-normalised)
and a smooth representation of the same contour, a cubic spline of (x, z)
against the cumulative chord length of its points. Every geometric query
(thickness, camber, leading-edge radius, resampling, signed distance) is
answered on the spline, never on the polyline.

Conventions (docs/architecture.md, "Conventions"):

* Selig order: trailing edge -> upper surface -> leading edge -> lower
  surface -> trailing edge. With x to the right and z up this runs
  counter-clockwise, so the outward normal is the tangent turned clockwise,
  ``n = (dz/ds, -dx/ds) / |(dx/ds, dz/ds)|``.
* Chord-normalised: the trailing edge (mid-point of the first and last points)
  lies at x = 1 within :data:`CHORD_TOLERANCE`, and the leading edge (the
  minimum-x point) lies at x = 0 within :data:`LEADING_EDGE_BOUND`. The second
  bound is loose on purpose: a cambered section whose thickness is laid
  perpendicular to its camber line (every NACA section) bulges ahead of
  x = 0 by a few 1e-4 chord. Both checks catch coordinates given in percent,
  in metres or shifted; nothing is rescaled silently.
* Closed trailing edge: the first and last points are identical (exactly: a
  contour built from a formula, e.g. ``cos(2 pi)``, should copy its first
  point to its last). Otherwise the trailing edge is open (blunt) and the
  contour is closed, for distances, by the straight trailing-edge base from
  the last point to the first. A closed contour that is smooth through its
  trailing edge (a circle) gets a periodic spline; a sharp one (a NACA
  section) keeps its corner.
"""

from __future__ import annotations

import math
from functools import cached_property
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import CubicSpline, PPoly
from scipy.optimize import minimize_scalar
from scipy.spatial import cKDTree

from .monotone_spline import REVERSAL_TOLERANCE, limit_x_reversals

MIN_POINTS = 7
"""Fewest points of a contour: the trailing edge, two points per surface, the
leading edge and the closing trailing-edge point."""

CHORD_TOLERANCE = 1e-6
"""Tolerance (chord) on the trailing edge lying at x = 1 (six-decimal files)."""

LEADING_EDGE_BOUND = 0.1
"""Largest distance (chord) of the minimum-x node from x = 0."""

SURFACE_TOLERANCE = 1e-6
"""Largest distance (chord) of the nodes from an explicitly given surface."""

_DENSE_SAMPLES = 16384  # samples of the spline for the nearest-vertex start
_CANDIDATES = 4  # nearest samples refined per point (both sides of a corner)
_NEWTON_STEPS = 50  # cap on the projection iterations
_BISECTION_STEPS = 64  # halvings of a parameter interval: below float64 spacing
_STATION_TOLERANCE = 1e-6  # chord; stations this close outside the chord are clipped

TRAILING_EDGE_BLEND = 0.05
"""Chord fraction ahead of the trailing edge over which :meth:`Airfoil.with_trailing_edge`
blends a change of the trailing-edge gap (the section ahead of it is kept)."""

TRAILING_EDGE_MODES = ("close", "open", "as-given")
"""How :func:`common_trailing_edge` brings sections with open and closed trailing
edges to one form."""

ZERO_AREA = 1e-9
"""Enclosed area (chord^2) at or below which a contour has zero thickness: a 0.01%-thick
section encloses about 7e-5."""

ZERO_THICKNESS = 1e-9
"""Distance (chord) below which two parts of a contour that do not cross count as touching (zero
thickness): rounding-level, far below any section's thickness away from its trailing edge."""

TRAILING_EDGE_ZONE = 1e-5
"""Distance (chord) from the trailing edge (plus half its gap) within which a contour's surfaces may meet:
the thickness of a section vanishes there."""

ORDER_TOLERANCE = 0.02
"""Chord fraction by which x must turn back to count as a turn of the contour (see
:func:`x_turns`): far above the small reversals beside a rounded nose or trailing edge."""

_BLEND_NODES = 401  # nodes of the resampled contour that a trailing-edge blend is applied to


class Projection(NamedTuple):
    """Closest points of the contour to a set of query points.

    Attributes:
        distance: Signed normal distance from each point to the contour,
            positive outside, in chord units; shape ``(...)``.
        foot: Closest point of the contour to each point, chord units;
            shape ``(..., 2)`` as (x, z).
        normal: Unit gradient of ``distance`` with respect to the point,
            shape ``(..., 2)``. Where the closest point is a smooth point of
            the contour this is the outward normal there; at a trailing-edge
            corner it is the direction from the corner to the point.
    """

    distance: np.ndarray
    foot: np.ndarray
    normal: np.ndarray


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


def x_turns(x: np.ndarray, tolerance: float = ORDER_TOLERANCE) -> list[int]:
    """Indices of the points where x turns back by more than ``tolerance`` (a falling run becomes a rising one
    or the reverse).

    A section in contour order (Selig: trailing edge, upper surface, leading
    edge, lower surface, trailing edge) turns once, at the leading edge;
    shuffled or merged points turn many times.
    """
    turns: list[int] = []
    direction = 0  # +1 rising, -1 falling, 0 not known yet
    low = high = 0  # index of the lowest / highest x of the current run
    for i in range(1, len(x)):
        if x[i] < x[low]:
            low = i
        if x[i] > x[high]:
            high = i
        if direction >= 0 and x[i] < x[high] - tolerance:
            if direction > 0:
                turns.append(high)
            direction, low = -1, i
        elif direction <= 0 and x[i] > x[low] + tolerance:
            if direction < 0:
                turns.append(low)
            direction, high = 1, i
    return turns


def order_error(x: np.ndarray, where=None) -> str | None:
    """Why points are not in contour order (more than two turns of x, :func:`x_turns`), or None.

    ``where(i)`` names point ``i`` in the message (e.g. its line in a file).
    """
    turns = x_turns(np.asarray(x, dtype=np.float64))
    if len(turns) <= 2:  # one at the leading edge (two: a surface missing or reversed, said elsewhere)
        return None
    name = where or (lambda i: f"point {i}")
    shown = ", ".join(name(i) for i in turns[:4]) + (", ..." if len(turns) > 4 else "")
    return (f"the points are not in contour order: x turns back {len(turns)} times (at {shown}), where a "
            f"section turns once, at the leading edge; order them trailing edge, upper surface, leading "
            f"edge, lower surface, trailing edge (Selig), as the file's source lists them")


class Crossing(NamedTuple):
    """Where a contour crosses or touches itself (see :func:`self_crossings`).

    Attributes:
        x, z: The meeting point, chord units.
        first, second: The segments that meet, each by the index of its
            first point (segment ``i`` joins points ``i`` and ``i + 1``;
            ``n - 1`` is an open trailing edge's base, from the last point to
            the first); ``first < second``.
        touching: True when the two only touch (the section's thickness
            drops to zero there), False when they cross.
    """

    x: float
    z: float
    first: int
    second: int
    touching: bool


def _point_segment(q: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance from points ``q`` to segments ``a b`` (rows), and the closest points."""
    ab = b - a
    length2 = np.sum(ab * ab, axis=1)
    t = np.clip(np.sum((q - a) * ab, axis=1) / np.where(length2 > 0.0, length2, 1.0), 0.0, 1.0)
    foot = a + t[:, None] * ab
    return np.linalg.norm(q - foot, axis=1), foot


def self_crossings(x: ArrayLike, z: ArrayLike) -> list[Crossing]:
    """Every point inside the chord where the polygon through the nodes (closed by its trailing-edge base)
    crosses or touches itself, ordered by x.

    Two segments cross when each one's end points lie strictly on opposite
    sides of the other's line (exact orientation products); they touch when
    they come closer than :data:`ZERO_THICKNESS` without crossing (a pinch
    to zero thickness). Segments that share a node (neighbours along the
    contour) meet there by construction and are not counted, nor are the two
    trailing-edge segments (they share the trailing edge, or its base joins
    them) or a meeting within :data:`TRAILING_EDGE_ZONE` of the trailing
    edge: a section's thickness may vanish there. Candidate pairs are the
    segments whose x- and z-extents overlap (a sweep over x), so a section's
    few thousand nodes cost a few milliseconds.

    Args:
        x, z: Node coordinates, chord units, shape ``(n,)``, contour order
            (first and last point at the trailing edge).

    Returns:
        The :class:`Crossing` points, empty for a section that neither
        crosses nor pinches itself.
    """
    p = np.column_stack([np.asarray(x, np.float64), np.asarray(z, np.float64)])
    n = p.shape[0]
    end = np.roll(p, -1, axis=0)
    index = np.flatnonzero(np.any(p != end, axis=1))  # without a closed trailing edge's zero-length base
    a, b = p[index], end[index]
    m = index.size
    lo = np.minimum(a, b) - 0.5 * ZERO_THICKNESS
    hi = np.maximum(a, b) + 0.5 * ZERO_THICKNESS
    order = np.argsort(lo[:, 0], kind="stable")
    reach = np.searchsorted(lo[order, 0], hi[order, 0], side="right")
    count = np.maximum(reach - np.arange(m) - 1, 0)
    first = np.repeat(np.arange(m), count)
    second = first + 1 + np.arange(first.size) - np.repeat(np.cumsum(count) - count, count)
    i, j = order[first], order[second]
    gap = np.abs(i - j)
    ends = {0, n - 2}
    near = (gap == 1) | (gap == m - 1) | np.isin(index[i], list(ends)) & np.isin(index[j], list(ends))
    keep = (lo[i, 1] <= hi[j, 1]) & (lo[j, 1] <= hi[i, 1]) & ~near
    i, j = i[keep], j[keep]

    def orientation(o, u, v):
        return (u[:, 0] - o[:, 0]) * (v[:, 1] - o[:, 1]) - (u[:, 1] - o[:, 1]) * (v[:, 0] - o[:, 0])

    o1, o2 = orientation(a[i], b[i], a[j]), orientation(a[i], b[i], b[j])
    o3, o4 = orientation(a[j], b[j], a[i]), orientation(a[j], b[j], b[i])
    cross = (o1 * o2 < 0.0) & (o3 * o4 < 0.0)
    t = o1 / np.where(cross, o1 - o2, 1.0)  # where along segment j the lines meet
    at = a[j] + t[:, None] * (b[j] - a[j])
    # Otherwise the closest approach: at an end point of one of the two segments.
    candidates = [_point_segment(a[i], a[j], b[j]), _point_segment(b[i], a[j], b[j]),
                  _point_segment(a[j], a[i], b[i]), _point_segment(b[j], a[i], b[i])]
    distance = np.stack([c[0] for c in candidates])
    nearest = np.argmin(distance, axis=0)
    ends_at = np.stack([a[i], b[i], a[j], b[j]])
    feet = np.stack([c[1] for c in candidates])
    rows = np.arange(i.size)
    closest = 0.5 * (ends_at[nearest, rows] + feet[nearest, rows])
    touch = ~cross & (distance[nearest, rows] <= ZERO_THICKNESS)
    point = np.where(cross[:, None], at, closest)
    trailing_edge = 0.5 * (p[0] + p[-1])
    inside = np.linalg.norm(point - trailing_edge, axis=1) > TRAILING_EDGE_ZONE + 0.5 * np.linalg.norm(p[0] - p[-1])
    meet = (cross | touch) & inside
    crossings = [Crossing(float(point[k, 0]), float(point[k, 1]), int(min(index[i[k]], index[j[k]])),
                          int(max(index[i[k]], index[j[k]])), bool(touch[k])) for k in np.flatnonzero(meet)]
    distinct: list[Crossing] = []  # one entry per place (a shared node meets four segments)
    for c in sorted(crossings, key=lambda c: (c.x, c.first)):
        if not any(math.hypot(c.x - d.x, c.z - d.z) <= 1e3 * ZERO_THICKNESS for d in distinct):
            distinct.append(c)
    return distinct


def crossing_error(x: np.ndarray, z: np.ndarray, where=None, noun: str = "points") -> str | None:
    """Why a contour is not a section because it crosses or pinches itself (:func:`self_crossings`), or None.

    ``where(i)`` numbers point ``i`` in the message, as ``noun`` (e.g. its line in a file: ``"lines"``).
    """
    crossings = self_crossings(x, z)
    if not crossings:
        return None
    name = where or str
    n = len(x)
    i_le = int(np.argmin(x))

    def surface(segment: int) -> str:
        if segment == n - 1:
            return "trailing-edge base"
        return "upper surface" if segment < i_le else "lower surface"

    first = crossings[0]
    parts = {surface(first.first), surface(first.second)}
    if parts == {"upper surface", "lower surface"}:
        what = f"its upper and lower surfaces {'meet' if first.touching else 'cross'}"
    elif len(parts) == 2:
        what = f"its {' and '.join(sorted(parts))} {'meet' if first.touching else 'cross'}"
    else:
        what = f"its {parts.pop()} {'touches' if first.touching else 'crosses'} itself"
    points = f"{noun} " + " and ".join(f"{name(s)}-{name((s + 1) % n)}" for s in (first.first, first.second))
    more = f" ({len(crossings)} places in all, from x/c = {crossings[0].x:.4g} to {crossings[-1].x:.4g})" \
        if len(crossings) > 1 else ""
    return (f"{what} at x/c = {first.x:.4g}, z/c = {first.z:.4g} (between {points}){more}: the section has "
            f"{'zero' if first.touching else 'negative'} thickness inside the chord, which no rib or skin can "
            f"take; correct the coordinates there (a lost minus sign, or surfaces swapped) so the upper surface "
            f"lies above the lower one everywhere ahead of the trailing edge")


def _validated_contour(x: ArrayLike, z: ArrayLike, what: str, crossing: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Checks a Selig-ordered, chord-normalised contour and returns float64 copies.

    ``crossing``: also refuse a contour that crosses or pinches itself (:func:`crossing_error`); off for
    the nodes derived from a section already accepted (a resampling, a trailing-edge blend), whose
    polygon may pinch where the section's own thickness is below their spacing (a thin tail on a
    coarse grid, the blend of a closed trailing edge).

    Raises:
        ValueError: With a sentence naming what to change.
    """
    try:
        x = np.array(x, dtype=np.float64)
        z = np.array(z, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{what}: x and z must be arrays of numbers ({err})") from err
    if x.ndim != 1 or z.ndim != 1 or x.shape != z.shape:
        raise ValueError(
            f"{what}: x and z must be 1-D arrays of equal length, got shapes {x.shape} and "
            f"{z.shape}"
        )
    n = x.size
    if n < MIN_POINTS:
        raise ValueError(
            f"{what} has {n} points; at least {MIN_POINTS} are needed (trailing edge, two points "
            f"on each surface, leading edge, trailing edge): pass more points"
        )
    not_finite = ~(np.isfinite(x) & np.isfinite(z))
    if not_finite.any():
        i = int(np.argmax(not_finite))
        raise ValueError(f"{what}: point {i} is not finite (x={x[i]}, z={z[i]}); fix or remove it")
    disorder = order_error(x)
    if disorder is not None:
        raise ValueError(f"{what}: {disorder}")
    segment = np.hypot(np.diff(x), np.diff(z))
    if (segment == 0.0).any():
        i = int(np.argmax(segment == 0.0))
        raise ValueError(
            f"{what}: points {i} and {i + 1} coincide at ({x[i]}, {z[i]}); remove the duplicate"
        )
    i_le = int(np.argmin(x))
    if i_le in (0, n - 1):
        end = "first" if i_le == 0 else "last"
        raise ValueError(
            f"{what}: the {end} point is the leading edge (minimum x); Selig order starts and ends "
            f"at the trailing edge (trailing edge, upper surface, leading edge, lower surface, "
            f"trailing edge): reorder the points or add the missing surface"
        )
    x_te = 0.5 * (x[0] + x[-1])
    if abs(x_te - 1.0) > CHORD_TOLERANCE:
        raise ValueError(
            f"{what} is not chord-normalised: its trailing edge (mid-point of the first and last "
            f"points) is at x = {x_te:.9g}, expected 1 within {CHORD_TOLERANCE:g}; divide the "
            f"coordinates by the chord and put the leading edge at x = 0"
        )
    if abs(x[i_le]) > LEADING_EDGE_BOUND:
        raise ValueError(
            f"{what} is not chord-normalised: its leading edge is at x = {x[i_le]:.6g}, expected 0 "
            f"within {LEADING_EDGE_BOUND:g}; shift the coordinates so the leading edge is at x = 0"
        )
    crossed = crossing_error(x, z) if crossing else None
    if crossed is not None:
        raise ValueError(f"{what}: {crossed}")
    # Shoelace area of the polygon closed by the trailing-edge base.
    area = 0.5 * float(np.sum(x * np.roll(z, -1) - np.roll(x, -1) * z))
    if abs(area) <= ZERO_AREA:
        raise ValueError(
            f"{what} has zero thickness: its contour encloses no area (signed area {area:.3g}), as a flat "
            f"plate or a camber line alone does; a bay's rib needs a section with thickness: give both "
            f"surfaces"
        )
    if area < 0.0:
        raise ValueError(
            f"{what} runs clockwise (signed area {area:.3g}); Selig order runs counter-clockwise "
            f"(trailing edge, upper surface, leading edge, lower surface): reverse the points"
        )
    return x, z


def _is_smooth_join(x: np.ndarray, z: np.ndarray) -> bool:
    """Whether a closed contour turns through its trailing edge like a smooth curve.

    The polygon's turning angle at the trailing-edge node is compared with the
    turn a smooth curve would make there, the smaller curvature estimated at
    its two neighbours (turn / mean adjacent segment length) times the mean
    length of the two trailing-edge segments. A sharp trailing edge (a NACA
    section) turns through almost pi whatever the spacing; a smooth closed
    curve (a circle, an ellipse) turns no more than about that estimate, so
    the threshold is three times it. The smaller curvature, because a smooth
    join looks smooth from both sides: a kink in the points next to a sharp
    trailing edge (UIUC ``fx73170a``, 0.6 rad at the node before it) must not
    make the corner pass for a curve.
    """
    step = np.column_stack([np.diff(x), np.diff(z)])
    length = np.linalg.norm(step, axis=1)
    direction = step / length[:, None]

    def turn(a: np.ndarray, b: np.ndarray) -> float:
        return math.atan2(abs(a[0] * b[1] - a[1] * b[0]), float(a @ b))

    at_te = turn(direction[-1], direction[0])
    curvature = min(
        turn(direction[0], direction[1]) / (0.5 * (length[0] + length[1])),
        turn(direction[-2], direction[-1]) / (0.5 * (length[-2] + length[-1])),
    )
    return at_te <= 3.0 * curvature * 0.5 * (length[0] + length[-1])


class _SmoothContour:
    """Cubic spline of (x, z) against cumulative chord length, with its queries.

    The spline is periodic when the contour is closed and smooth through its
    trailing edge, otherwise it has not-a-knot ends (the trailing edge is a
    corner, or open). Where its x(s) turns back between nodes whose x is
    monotonic (beside a sharp nose, or beside the trailing-edge node of a
    periodic contour), the x part is repaired by
    :func:`~targets.monotone_spline.limit_x_reversals` and is C1 there.
    """

    def __init__(self, x: np.ndarray, z: np.ndarray):
        self.closed = bool(x[0] == x[-1] and z[0] == z[-1])
        self.periodic = self.closed and _is_smooth_join(x, z)
        points = np.column_stack([x, z])
        knots = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(z)))])
        self.length = float(knots[-1])
        spline = CubicSpline(
            knots, points, axis=0, bc_type="periodic" if self.periodic else "not-a-knot"
        )
        self.spline = limit_x_reversals(spline, x, self.periodic)
        self._tangent = self.spline.derivative(1)
        self._second = self.spline.derivative(2)
        self._x_poly = PPoly(self.spline.c[..., 0], knots, extrapolate=False)
        self.start = points[0].copy()
        self.end = points[-1].copy()

        dxds = self._x_poly.derivative()
        roots = dxds.roots(extrapolate=False)
        roots = roots[np.isfinite(roots) & (roots > 0.0) & (roots < self.length)]
        candidates = np.concatenate([roots, [knots[int(np.argmin(x))]]])
        self.le_parameter = float(candidates[np.argmin(self._x_poly(candidates))])
        self.x_le = float(self._x_poly(self.le_parameter))

        per_segment = max(4, math.ceil(_DENSE_SAMPLES / (knots.size - 1)))
        fraction = np.arange(per_segment) / per_segment
        dense = (knots[:-1, None] + np.diff(knots)[:, None] * fraction).ravel()
        if not self.periodic:
            dense = np.append(dense, self.length)
        self._dense_parameter = dense
        self._tree = cKDTree(self.spline(dense))
        self._max_step = 2.0 * float(np.max(np.diff(dense)))

    def points(self, s: np.ndarray) -> np.ndarray:
        return self.spline(s)

    def tangent(self, s: np.ndarray) -> np.ndarray:
        return self._tangent(s)

    def outward_normal(self, s: np.ndarray) -> np.ndarray:
        t = self._tangent(s)
        return _unit(np.stack([t[..., 1], -t[..., 0]], axis=-1))

    def curvature(self, s: np.ndarray) -> np.ndarray:
        """Signed curvature (1/chord), positive where the contour turns counter-clockwise."""
        t, k = self._tangent(s), self._second(s)
        cross = t[..., 0] * k[..., 1] - t[..., 1] * k[..., 0]
        return cross / np.hypot(t[..., 0], t[..., 1]) ** 3

    @cached_property
    def monotonic_error(self) -> str | None:
        """Why x is not single-valued along a surface, or None when it is."""
        s = self._dense_parameter
        slope = self._tangent(s)
        speed = np.hypot(slope[:, 0], slope[:, 1])
        for surface, part, wrong_sign in (
            ("upper", s < self.le_parameter, slope[:, 0] > REVERSAL_TOLERANCE * speed),
            ("lower", s > self.le_parameter, slope[:, 0] < -REVERSAL_TOLERANCE * speed),
        ):
            bad = part & wrong_sign
            if bad.any():
                x_bad = float(self._x_poly(s[np.argmax(bad)]))
                return (
                    f"x turns back along the {surface} surface near x = {x_bad:.4f}; thickness, "
                    f"camber and resampling need each surface to run monotonically in x from the "
                    f"leading edge to the trailing edge"
                )
        return None

    def parameter_at_x(self, stations: np.ndarray, upper: bool) -> np.ndarray:
        """Contour parameter where x equals each station, on one surface.

        Args:
            stations: Chordwise stations (chord units) inside the x-range of
                the surface, shape ``(m,)``.
            upper: True for the upper surface (parameter 0 to the leading
                edge), False for the lower one (leading edge to the end).

        Returns:
            Parameters, shape ``(m,)``, found by bisection to float64
            resolution (x is monotonic along each surface).
        """
        low, high = (0.0, self.le_parameter) if upper else (self.le_parameter, self.length)
        a = np.full(stations.shape, low)
        b = np.full(stations.shape, high)
        for _ in range(_BISECTION_STEPS):
            middle = 0.5 * (a + b)
            above = self._x_poly(middle) > stations
            root_after_middle = above if upper else ~above
            a = np.where(root_after_middle, middle, a)
            b = np.where(root_after_middle, b, middle)
        return 0.5 * (a + b)

    def project(self, points: np.ndarray) -> Projection:
        """Closest contour points to ``points`` of shape ``(m, 2)``."""
        _, index = self._tree.query(points, k=_CANDIDATES)
        s = self._dense_parameter[index]
        target = points[:, None, :]
        for _ in range(_NEWTON_STEPS):
            offset = self.spline(s) - target
            tangent = self._tangent(s)
            slope = np.sum(offset * tangent, axis=-1)  # half the derivative of the squared distance
            speed2 = np.sum(tangent * tangent, axis=-1)
            hessian = speed2 + np.sum(offset * self._second(s), axis=-1)
            # Gauss-Newton where the squared distance is not locally convex.
            hessian = np.where(hessian > 0.1 * speed2, hessian, speed2)
            step = np.clip(-slope / hessian, -self._max_step, self._max_step)
            s_next = s + step
            if not self.periodic:
                s_next = np.clip(s_next, 0.0, self.length)
            change = float(np.max(np.abs(s_next - s)))
            s = s_next
            if change <= 1e-13 * self.length:
                break
        gap = np.linalg.norm(self.spline(s) - target, axis=-1)
        best = np.argmin(gap, axis=1)
        rows = np.arange(points.shape[0])
        s = s[rows, best]
        if self.periodic:
            s = np.mod(s, self.length)
        foot = self.spline(s)
        gap = gap[rows, best]
        normal = self.outward_normal(s)

        if not self.periodic:
            n_start, n_end = self.outward_normal(np.array([0.0, self.length]))
            if self.closed:
                corner = _unit(n_start + n_end)
                normal[(s <= 0.0) | (s >= self.length)] = corner
            else:
                base = self.start - self.end  # trailing-edge base, last point -> first point
                n_base = _unit(np.array([base[1], -base[0]]))
                corner_start = _unit(n_start + n_base)
                corner_end = _unit(n_end + n_base)
                normal[s <= 0.0] = corner_start
                normal[s >= self.length] = corner_end
                fraction = np.clip((points - self.end) @ base / (base @ base), 0.0, 1.0)
                foot_base = self.end + fraction[:, None] * base
                gap_base = np.linalg.norm(points - foot_base, axis=-1)
                on_base = gap_base < gap
                normal_base = np.where(
                    (fraction <= 0.0)[:, None],
                    corner_end,
                    np.where((fraction >= 1.0)[:, None], corner_start, n_base),
                )
                foot = np.where(on_base[:, None], foot_base, foot)
                gap = np.where(on_base, gap_base, gap)
                normal = np.where(on_base[:, None], normal_base, normal)

        away = points - foot
        sign = np.where(np.sum(away * normal, axis=-1) < 0.0, -1.0, 1.0)
        resolved = gap > 1e-12
        direction = np.where(
            resolved[:, None], away / np.where(resolved, gap, 1.0)[:, None] * sign[:, None], normal
        )
        return Projection(distance=sign * gap, foot=foot, normal=direction)


class Airfoil:
    """A section given by a closed contour in Selig order, chord-normalised.

    Args:
        x: Chordwise coordinates of the nodes (chord units), shape ``(n,)``,
            Selig order, first and last point at the trailing edge.
        z: Vertical coordinates of the nodes (chord units), shape ``(n,)``.
        name: Label used in messages and plots.
        surface: Optional denser sampling ``(x, z)`` of the same contour, in
            Selig order with the same trailing-edge points, from which the
            smooth representation is built instead of from the nodes.
            :func:`targets.naca` passes its analytic surface at 4097 points,
            so its distances are accurate whatever ``n_points`` is. The nodes
            must lie on it within :data:`SURFACE_TOLERANCE`.

    Raises:
        ValueError: If the contour has fewer than :data:`MIN_POINTS` points,
            non-finite or repeated consecutive points, is not chord-normalised
            (see the module docstring), runs clockwise, or does not start and
            end at the trailing edge.

    Attributes:
        x: Read-only node x-coordinates (chord units), shape ``(n_points,)``.
        z: Read-only node z-coordinates (chord units), shape ``(n_points,)``.
        name: The section's label.
    """

    def __init__(
        self,
        x: ArrayLike,
        z: ArrayLike,
        name: str = "airfoil",
        *,
        surface: tuple[ArrayLike, ArrayLike] | None = None,
    ):
        if not isinstance(name, str):
            raise ValueError(f"name must be a string, got {type(name).__name__}")
        x, z = _validated_contour(x, z, f"airfoil {name!r}")
        if surface is None:
            contour = _SmoothContour(x, z)
        else:
            sx, sz = _validated_contour(surface[0], surface[1], f"surface of airfoil {name!r}")
            contour = _SmoothContour(sx, sz)
            ends = np.array([[x[0], z[0]], [x[-1], z[-1]]])
            if not np.array_equal(ends, np.array([contour.start, contour.end])):
                raise ValueError(
                    f"airfoil {name!r}: the surface must start and end at the same trailing-edge "
                    f"points as the nodes, got {contour.start} and {contour.end} for {ends[0]} and "
                    f"{ends[1]}"
                )
            off = np.abs(contour.project(np.column_stack([x, z])).distance)
            if off.max() > SURFACE_TOLERANCE:
                i = int(np.argmax(off))
                raise ValueError(
                    f"airfoil {name!r}: node {i} lies {off[i]:.3g} chord off the given surface "
                    f"(tolerance {SURFACE_TOLERANCE:g}); pass nodes sampled from that surface"
                )
        self._set(x, z, name, contour)

    @classmethod
    def _on_contour(
        cls, x: np.ndarray, z: np.ndarray, name: str, contour: _SmoothContour
    ) -> Airfoil:
        """An airfoil whose nodes were sampled from an existing smooth contour."""
        airfoil = cls.__new__(cls)
        x, z = _validated_contour(x, z, f"airfoil {name!r}", crossing=False)
        airfoil._set(x, z, name, contour)
        return airfoil

    def _set(self, x: np.ndarray, z: np.ndarray, name: str, contour: _SmoothContour) -> None:
        x.setflags(write=False)
        z.setflags(write=False)
        self.x = x
        self.z = z
        self.name = name
        self._contour = contour

    def __repr__(self) -> str:
        return f"Airfoil(name={self.name!r}, n_points={self.n_points}, closed_te={self.closed_te})"

    @property
    def n_points(self) -> int:
        """Number of nodes, both trailing-edge points included."""
        return int(self.x.size)

    @property
    def closed_te(self) -> bool:
        """True when the first and last nodes coincide (sharp trailing edge)."""
        return bool(self.x[0] == self.x[-1] and self.z[0] == self.z[-1])

    @property
    def trailing_edge_gap(self) -> float:
        """Distance between the first and last nodes (chord units): 0 for a closed trailing edge."""
        return float(np.hypot(self.x[0] - self.x[-1], self.z[0] - self.z[-1]))

    @property
    def points(self) -> np.ndarray:
        """Nodes as an array of shape ``(n_points, 2)`` of (x, z), chord units."""
        return np.column_stack([self.x, self.z])

    @property
    def leading_edge(self) -> np.ndarray:
        """The leading edge, the minimum-x point of the smooth contour, as (x, z)."""
        return self._contour.points(np.array(self._contour.le_parameter))

    @property
    def leading_edge_parameter(self) -> float:
        """Where the leading edge (minimum x) lies along the smooth contour, as a fraction of its length
        (the parameter of :meth:`contour_points`): the upper surface runs before it, the lower after."""
        return self._contour.le_parameter / self._contour.length

    def contour_points(self, t: ArrayLike) -> np.ndarray:
        """Points of the smooth contour at fractions ``t`` of its length from the first node.

        Args:
            t: Fractions in [0, 1] (0: the first node, the upper trailing
                edge; 1: the last node), any shape; the cumulative chord
                length of the nodes parametrises the spline, so ``t`` is
                close to the arc-length fraction.

        Returns:
            ``(..., 2)`` points (x, z), chord units.

        Raises:
            ValueError: If a fraction lies outside [0, 1] or is not finite.
        """
        t = np.asarray(t, dtype=np.float64)
        if not np.all(np.isfinite(t) & (t >= 0.0) & (t <= 1.0)):
            raise ValueError("contour fractions t must lie in [0, 1]")
        return self._contour.points(t * self._contour.length)

    @cached_property
    def leading_edge_radius(self) -> float:
        """Radius of curvature (chord units) of the smooth contour at the leading edge.

        The leading edge is the minimum-x point. For a symmetric NACA section
        this is 1.1019 t^2; for a cambered one the minimum-x point is not the
        end of the camber line and the radius differs by a few percent.
        """
        return float(1.0 / self._contour.curvature(np.array(self._contour.le_parameter)))

    def _surface_z(self, stations: np.ndarray, upper: bool) -> np.ndarray:
        contour = self._contour
        end = contour.start if upper else contour.end
        inside = np.clip(stations, contour.x_le, end[0])
        z = contour.points(contour.parameter_at_x(inside, upper))[:, 1]
        beyond = stations > end[0]
        if beyond.any():
            # An open, cambered trailing edge ends its surfaces a little before or after
            # x = 1; continue the shorter one along its end tangent.
            tangent = contour.tangent(np.array(0.0 if upper else contour.length))
            z = z + np.where(beyond, tangent[1] / tangent[0] * (stations - end[0]), 0.0)
        return z

    def _surfaces_at(self, x: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        contour = self._contour
        if contour.monotonic_error is not None:
            raise ValueError(f"airfoil {self.name!r}: {contour.monotonic_error}")
        stations = np.asarray(x, dtype=np.float64)
        flat = stations.reshape(-1)
        x_te = max(contour.start[0], contour.end[0])
        low, high = contour.x_le - _STATION_TOLERANCE, x_te + _STATION_TOLERANCE
        outside = ~((flat >= low) & (flat <= high))
        if outside.any():
            raise ValueError(
                f"airfoil {self.name!r}: station x = {flat[np.argmax(outside)]!r} lies outside the "
                f"section, which runs from x = {contour.x_le:.6g} to x = {x_te:.6g}"
            )
        flat = np.clip(flat, contour.x_le, x_te)
        upper = self._surface_z(flat, upper=True).reshape(stations.shape)
        lower = self._surface_z(flat, upper=False).reshape(stations.shape)
        return upper, lower

    def thickness(self, x: ArrayLike) -> np.ndarray:
        """Thickness distribution: upper minus lower surface at chordwise stations.

        Args:
            x: Stations (chord units), any shape, between the leading edge and
                the trailing edge.

        Returns:
            Vertical distance between the surfaces (chord units), same shape as ``x``.

        Raises:
            ValueError: If a station lies outside the section, or x is not
                monotonic along a surface.
        """
        upper, lower = self._surfaces_at(x)
        return (upper - lower)[()]

    def camber(self, x: ArrayLike) -> np.ndarray:
        """Camber distribution: mid-point of the surfaces at chordwise stations.

        For a NACA section this differs slightly from its mean line, whose
        thickness is laid perpendicular to it rather than vertically.

        Args:
            x: Stations (chord units), any shape, between the leading edge and
                the trailing edge.

        Returns:
            Mean of upper and lower surface z (chord units), same shape as ``x``.

        Raises:
            ValueError: As for :meth:`thickness`.
        """
        upper, lower = self._surfaces_at(x)
        return (0.5 * (upper + lower))[()]

    def _extremum(self, function, sign: float) -> tuple[float, float]:
        """Location and value maximising ``sign * function`` over the chord."""
        contour = self._contour
        x_te = min(contour.start[0], contour.end[0])
        cosine = 0.5 * (1.0 - np.cos(np.linspace(0.0, np.pi, 801)))
        stations = contour.x_le + (x_te - contour.x_le) * cosine
        values = sign * function(stations)
        i = int(np.argmax(values))
        bounds = (stations[max(i - 1, 0)], stations[min(i + 1, stations.size - 1)])
        result = minimize_scalar(
            lambda v: -sign * float(function(v)),
            bounds=bounds,
            method="bounded",
            options={"xatol": 1e-12},
        )
        if -result.fun < values[i]:
            return float(stations[i]), float(function(stations[i]))
        return float(result.x), float(function(result.x))

    @cached_property
    def _max_thickness(self) -> tuple[float, float]:
        return self._extremum(self.thickness, 1.0)

    @property
    def max_thickness(self) -> float:
        """Largest value of :meth:`thickness` (chord units)."""
        return self._max_thickness[1]

    @property
    def max_thickness_location(self) -> float:
        """Station of the largest thickness (chord units)."""
        return self._max_thickness[0]

    @cached_property
    def _max_camber(self) -> tuple[float, float]:
        contour = self._contour
        x_te = min(contour.start[0], contour.end[0])
        probe = self.camber(np.linspace(contour.x_le, x_te, 401))
        sign = 1.0 if probe.max() >= -probe.min() else -1.0
        return self._extremum(self.camber, sign)

    @property
    def max_camber(self) -> float:
        """Camber of largest magnitude (chord units, signed, positive above the chord line)."""
        return self._max_camber[1]

    @property
    def max_camber_location(self) -> float:
        """Station of the camber of largest magnitude (chord units)."""
        return self._max_camber[0]

    def resample(self, n_points: int) -> Airfoil:
        """Nodes at cosine-spaced chordwise stations on the smooth contour.

        Node k (k = 0 .. n_points-1) sits where x equals
        ``x_le + (x_end - x_le) * (1 + cos(2 pi k / (n_points - 1))) / 2`` on
        the upper surface for k < (n_points-1)/2 and on the lower surface for
        k > (n_points-1)/2; ``x_end`` is the x of that surface's trailing-edge
        point and ``x_le`` that of the leading edge (minimum x). For a contour
        with its leading edge at x = 0 and trailing edge at x = 1 this is
        exactly ``x = (1 + cos(2 pi k / (n_points - 1))) / 2``. When n_points
        is odd node (n_points-1)/2 is the leading edge itself. The end nodes
        are copied, so a closed trailing edge stays exactly closed. The
        returned airfoil keeps this airfoil's smooth representation.

        Args:
            n_points: Number of nodes, both trailing-edge points included,
                even or odd, at least :data:`MIN_POINTS`.

        Returns:
            The resampled airfoil, same name.

        Raises:
            ValueError: If n_points is too small, or x is not monotonic along
                a surface.
        """
        n = checked_n_points(n_points)
        contour = self._contour
        if contour.monotonic_error is not None:
            raise ValueError(f"airfoil {self.name!r}: {contour.monotonic_error}")
        k = np.arange(n)
        station = 0.5 * (1.0 + np.cos(2.0 * np.pi * k / (n - 1)))
        upper, lower = 2 * k < n - 1, 2 * k > n - 1
        s = np.full(n, contour.le_parameter)
        x_le = contour.x_le
        s[upper] = contour.parameter_at_x(x_le + (contour.start[0] - x_le) * station[upper], True)
        s[lower] = contour.parameter_at_x(x_le + (contour.end[0] - x_le) * station[lower], False)
        points = contour.points(s)
        points[0], points[-1] = contour.start, contour.end
        return Airfoil._on_contour(points[:, 0], points[:, 1], self.name, contour)

    def with_trailing_edge(self, gap: float, blend: float = TRAILING_EDGE_BLEND) -> Airfoil:
        """The section with its trailing-edge gap changed to ``gap``, blended over the last ``blend``.

        The contour is resampled at :data:`_BLEND_NODES` cosine-spaced nodes
        (:meth:`resample`); each surface's node at chordwise distance ``d``
        ahead of that surface's trailing-edge point moves by ``w(d) (e' - e)``,
        where ``e`` is its trailing-edge point, ``e'`` the new one and
        ``w = 1 - S(d / blend)`` with ``S(t) = 10 t^3 - 15 t^4 + 6 t^5`` for
        ``t < 1`` (0 beyond): the blend is C2 where it starts and moves
        nothing ahead of ``1 - blend``, where the section is the original's to
        the resampling error (below 1e-5 chord on the UIUC test files, 1e-4 over
        the whole database). The new trailing-edge points
        lie ``gap / 2`` either side of the old mid-point, along the old base
        (vertically for a closed trailing edge), so the chord stays unit.

        Narrowing the gap from ``g`` to ``g'`` lowers the thickness by
        ``w (g - g') min(1, t(x) / (g - g'))``: the gap change itself where the
        section is thicker than that (nearly everywhere), and never more than
        ``w t(x)``, so the surfaces cannot cross where a section thickens
        towards its trailing edge (35 of the 895 open sections of the UIUC
        database do, within the last 1%). No point moves further than half
        the gap change.

        Args:
            gap: the new gap, chord units, >= 0 (0 closes the trailing edge).
            blend: chord fraction over which the change is blended, in (0, 0.5].

        Returns:
            A new :class:`Airfoil` of the same name (``self`` when the gap is
            already ``gap``).

        Raises:
            ValueError: for a bad ``gap`` or ``blend``.
        """
        if isinstance(gap, bool) or not isinstance(gap, (int, float, np.floating)) or not (
            math.isfinite(gap) and 0.0 <= gap < 0.1
        ):
            raise ValueError(f"trailing-edge gap must be a number in [0, 0.1) chord, got {gap!r}")
        if isinstance(blend, bool) or not isinstance(blend, (int, float, np.floating)) or not (
            0.0 < blend <= 0.5
        ):
            raise ValueError(f"trailing-edge blend must be a chord fraction in (0, 0.5], got {blend!r}")
        old_gap = self.trailing_edge_gap
        if old_gap == gap:
            return self
        dense = self.resample(_BLEND_NODES)
        x, z = dense.x.copy(), dense.z.copy()
        first, last = np.array([x[0], z[0]]), np.array([x[-1], z[-1]])
        middle = 0.5 * (first + last)
        base = (first - last) / old_gap if old_gap > 0.0 else np.array([0.0, 1.0])
        new_first, new_last = middle + 0.5 * gap * base, middle - 0.5 * gap * base
        if gap == 0.0:
            new_first = new_last = middle
        i_le = int(np.argmin(x))
        narrowing = old_gap - gap
        for nodes, end, moved in ((slice(0, i_le), first, new_first),
                                  (slice(i_le + 1, x.size), last, new_last)):
            t = np.clip((end[0] - x[nodes]) / blend, 0.0, 1.0)
            weight = 1.0 - t**3 * (10.0 - 15.0 * t + 6.0 * t**2)
            if narrowing > 0.0:  # never take more thickness than there is (see the docstring)
                inside = weight > 0.0
                local = self.thickness(np.clip(x[nodes][inside], self._contour.x_le, 1.0))
                weight[inside] *= np.clip(local / narrowing, 0.0, 1.0)
            x[nodes] += weight * (moved[0] - end[0])
            z[nodes] += weight * (moved[1] - end[1])
        (x[0], z[0]), (x[-1], z[-1]) = new_first, new_last
        # (the blend may pinch the polygon to zero thickness where the section is thinner than the gap
        # change, within the blend: the accepted section's own trailing edge, closed)
        x, z = _validated_contour(x, z, f"airfoil {self.name!r}", crossing=False)
        return Airfoil._on_contour(x, z, self.name, _SmoothContour(x, z))

    def with_closed_trailing_edge(self, blend: float = TRAILING_EDGE_BLEND) -> Airfoil:
        """The section with its trailing edge closed (see :meth:`with_trailing_edge`, gap 0)."""
        return self.with_trailing_edge(0.0, blend)

    def scaled(self, chord: float) -> tuple[np.ndarray, np.ndarray]:
        """Node coordinates scaled to a physical chord.

        Args:
            chord: Chord length (m), positive.

        Returns:
            ``(x, z)`` in metres, leading edge at the origin as for the
            chord-normalised nodes.

        Raises:
            ValueError: If chord is not a positive finite number.
        """
        if not (np.isfinite(chord) and chord > 0):
            raise ValueError(f"chord must be a positive length in metres, got {chord!r}")
        return self.x * chord, self.z * chord

    def project(self, points: ArrayLike) -> Projection:
        """Closest points of the smooth contour to query points.

        The closest point is found by a bounded Newton iteration on the
        spline, started from the nearest of ~16k samples of it; an open
        trailing edge is closed by its straight base.

        Args:
            points: Query points (x, z), chord units, shape ``(..., 2)``.

        Returns:
            :class:`Projection` with arrays of shape ``(...)`` and ``(..., 2)``.

        Raises:
            ValueError: If points does not end in an axis of length 2 or is
                not finite.
        """
        query = np.asarray(points, dtype=np.float64)
        if query.ndim == 0 or query.shape[-1] != 2:
            raise ValueError(f"points must have shape (..., 2) of (x, z), got shape {query.shape}")
        flat = query.reshape(-1, 2)
        if not np.isfinite(flat).all():
            raise ValueError("points must be finite; got NaN or infinity")
        if flat.shape[0] == 0:
            empty = np.zeros(query.shape[:-1])
            return Projection(empty, np.zeros(query.shape), np.zeros(query.shape))
        result = self._contour.project(flat)
        shape = query.shape[:-1]
        return Projection(
            distance=result.distance.reshape(shape),
            foot=result.foot.reshape(shape + (2,)),
            normal=result.normal.reshape(shape + (2,)),
        )

    def distance(self, points: ArrayLike) -> np.ndarray:
        """Signed normal distance from points to the contour, positive outside.

        Args:
            points: Query points (x, z), chord units, shape ``(..., 2)``.

        Returns:
            Distances (chord units), shape ``(...)``.

        Raises:
            ValueError: As for :meth:`project`.
        """
        return self.project(points).distance


def checked_n_points(n_points: int) -> int:
    """Validates a node count (an integer, at least MIN_POINTS)."""
    if isinstance(n_points, bool) or not isinstance(n_points, (int, np.integer)):
        raise ValueError(f"n_points must be an integer, got {n_points!r}")
    if n_points < MIN_POINTS:
        raise ValueError(f"n_points must be at least {MIN_POINTS}, got {n_points}")
    return int(n_points)


def common_trailing_edge(
    airfoils, mode: str = "close", labels=None, blend: float = TRAILING_EDGE_BLEND
) -> tuple[list, list[dict]]:
    """Sections brought to one trailing-edge form, open or closed, and what was changed.

    A skin between two ribs, and a wing of bays, runs one grid whose
    trailing-edge seam is either one line (closed) or two with a base
    between them (open), so its sections must share the form. NACA codes are
    closed; most real ``.dat`` files are open by 0.1-0.5% of chord.

    Modes:

    * ``"close"`` (the default): close every open trailing edge
      (:meth:`Airfoil.with_closed_trailing_edge`). A fabric wing's trailing
      edge is a seam where the upper and lower skins meet, so a shop builds
      it closed whatever the section's file says; closing moves the section
      by at most half the gap, only over the last ``blend`` of chord.
    * ``"open"``: open every closed trailing edge to the largest gap among
      the open ones (:meth:`Airfoil.with_trailing_edge`), for a wing whose
      trailing edge is a rigid (blunt) spar.
    * ``"as-given"``: change nothing; a mix raises ValueError naming a closed
      and an open section and the modes that fix it.

    Sections that already share a form are returned unchanged in every mode.

    Args:
        airfoils: the sections (:class:`Airfoil`).
        mode: one of :data:`TRAILING_EDGE_MODES`.
        labels: a name per section for the notes and messages (default: the
            airfoil names).
        blend: chord fraction of the blend.

    Returns:
        ``(sections, changes)``: the sections, and per changed one a dict with
        ``index``, ``label``, ``gap_before``, ``gap_after`` (chord units) and
        ``blend``.

    Raises:
        ValueError: for an unknown mode, or a mix with ``"as-given"``.
    """
    if mode not in TRAILING_EDGE_MODES:
        raise ValueError(f"trailing_edge must be one of {', '.join(TRAILING_EDGE_MODES)}, got {mode!r}")
    airfoils = list(airfoils)
    labels = [a.name for a in airfoils] if labels is None else list(labels)
    closed = [a.closed_te for a in airfoils]
    if all(closed) or not any(closed):
        return airfoils, []
    if mode == "as-given":
        i, j = closed.index(True), closed.index(False)
        raise ValueError(
            f"{labels[i]} has a closed trailing edge and {labels[j]} an open one (gap "
            f"{airfoils[j].trailing_edge_gap:.3g} chord), and one skin cannot join the two: set "
            f"trailing_edge (--trailing-edge) to close (close the open ones, the default) or open "
            f"(open the closed ones to the largest gap)"
        )
    gap = 0.0 if mode == "close" else max(a.trailing_edge_gap for a in airfoils)
    sections, changes = [], []
    for k, airfoil in enumerate(airfoils):
        if airfoil.closed_te == (mode == "close"):
            sections.append(airfoil)
            continue
        sections.append(airfoil.with_trailing_edge(gap, blend))
        changes.append({"index": k, "label": labels[k], "gap_before": airfoil.trailing_edge_gap,
                        "gap_after": gap, "blend": blend})
    return sections, changes
