"""Checks of a section's contour: order, self-crossings and pinches, orientation, chord normalisation.

A contour is accepted only if it is one section in Selig order (trailing edge,
upper surface, leading edge, lower surface, trailing edge), chord-normalised
(see :mod:`targets.airfoil`), running counter-clockwise and enclosing area
without crossing or pinching itself inside the chord. :func:`validated_contour`
applies every check and raises a ValueError with a one-line sentence naming
what to change; :func:`order_error` and :func:`crossing_error` give the
sentences alone, for callers that number the points their own way (the lines
of a ``.dat`` file, :mod:`targets.dat`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

MIN_POINTS = 7
"""Fewest points of a contour: the trailing edge, two points per surface, the
leading edge and the closing trailing-edge point."""

CHORD_TOLERANCE = 1e-6
"""Tolerance (chord) on the trailing edge lying at x = 1 (six-decimal files)."""

LEADING_EDGE_BOUND = 0.1
"""Largest distance (chord) of the minimum-x node from x = 0."""

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


def validated_contour(x: ArrayLike, z: ArrayLike, what: str, crossing: bool = True) -> tuple[np.ndarray, np.ndarray]:
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
        raise ValueError(f"{what}: x and z must be 1-D arrays of equal length, got shapes {x.shape} and "
                         f"{z.shape}")
    n = x.size
    if n < MIN_POINTS:
        raise ValueError(f"{what} has {n} points; at least {MIN_POINTS} are needed (trailing edge, two points "
                         f"on each surface, leading edge, trailing edge): pass more points")
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
        raise ValueError(f"{what}: points {i} and {i + 1} coincide at ({x[i]}, {z[i]}); remove the duplicate")
    i_le = int(np.argmin(x))
    if i_le in (0, n - 1):
        end = "first" if i_le == 0 else "last"
        raise ValueError(f"{what}: the {end} point is the leading edge (minimum x); Selig order starts and ends "
                         f"at the trailing edge (trailing edge, upper surface, leading edge, lower surface, "
                         f"trailing edge): reorder the points or add the missing surface")
    x_te = 0.5 * (x[0] + x[-1])
    if abs(x_te - 1.0) > CHORD_TOLERANCE:
        raise ValueError(f"{what} is not chord-normalised: its trailing edge (mid-point of the first and last "
                         f"points) is at x = {x_te:.9g}, expected 1 within {CHORD_TOLERANCE:g}; divide the "
                         f"coordinates by the chord and put the leading edge at x = 0")
    if abs(x[i_le]) > LEADING_EDGE_BOUND:
        raise ValueError(f"{what} is not chord-normalised: its leading edge is at x = {x[i_le]:.6g}, expected 0 "
                         f"within {LEADING_EDGE_BOUND:g}; shift the coordinates so the leading edge is at x = 0")
    crossed = crossing_error(x, z) if crossing else None
    if crossed is not None:
        raise ValueError(f"{what}: {crossed}")
    # Shoelace area of the polygon closed by the trailing-edge base.
    area = 0.5 * float(np.sum(x * np.roll(z, -1) - np.roll(x, -1) * z))
    if abs(area) <= ZERO_AREA:
        raise ValueError(f"{what} has zero thickness: its contour encloses no area (signed area {area:.3g}), as a flat "
                         f"plate or a camber line alone does; a bay's rib needs a section with thickness: give both "
                         f"surfaces")
    if area < 0.0:
        raise ValueError(f"{what} runs clockwise (signed area {area:.3g}); Selig order runs counter-clockwise "
                         f"(trailing edge, upper surface, leading edge, lower surface): reverse the points")
    return x, z

def checked_n_points(n_points: int) -> int:
    """Validates a node count (an integer, at least MIN_POINTS)."""
    if isinstance(n_points, bool) or not isinstance(n_points, (int, np.integer)):
        raise ValueError(f"n_points must be an integer, got {n_points!r}")
    if n_points < MIN_POINTS:
        raise ValueError(f"n_points must be at least {MIN_POINTS}, got {n_points}")
    return int(n_points)
