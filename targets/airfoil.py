"""Airfoil sections: a closed contour in Selig order and its smooth representation.

An :class:`Airfoil` holds the nodes of a section (``x``, ``z``, chord-normalised)
and answers every geometric query (thickness, camber, leading-edge radius,
resampling, signed distance) on their smooth representation
(:class:`~targets.contour.SmoothContour`), never on the polyline.

Conventions (docs/architecture.md, "Conventions"):

* Selig order: trailing edge -> upper surface -> leading edge -> lower
  surface -> trailing edge. With x to the right and z up this runs
  counter-clockwise, so the outward normal is the tangent turned clockwise,
  ``n = (dz/ds, -dx/ds) / |(dx/ds, dz/ds)|``.
* Chord-normalised: the trailing edge (mid-point of the first and last points)
  lies at x = 1 within :data:`~targets.checks.CHORD_TOLERANCE`, and the leading edge (the
  minimum-x point) lies at x = 0 within :data:`~targets.checks.LEADING_EDGE_BOUND`. The second
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

The checks that refuse a contour live in :mod:`targets.checks`, the spline and
its projection in :mod:`targets.contour`, the common trailing-edge form of
several sections in :mod:`targets.trailing_edge`; the methods of
:class:`Airfoil` delegate to them.
"""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import minimize_scalar

from .checks import checked_n_points, validated_contour
from .contour import Projection, SmoothContour
from .trailing_edge import BLEND_NODES, TRAILING_EDGE_BLEND

SURFACE_TOLERANCE = 1e-6
"""Largest distance (chord) of the nodes from an explicitly given surface."""


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
        ValueError: If the contour has fewer than :data:`~targets.checks.MIN_POINTS` points,
            non-finite or repeated consecutive points, is not chord-normalised
            (see the module docstring), runs clockwise, or does not start and
            end at the trailing edge.

    Attributes:
        x: Read-only node x-coordinates (chord units), shape ``(n_points,)``.
        z: Read-only node z-coordinates (chord units), shape ``(n_points,)``.
        name: The section's label.
    """

    def __init__(self, x: ArrayLike, z: ArrayLike, name: str = "airfoil", *,
                 surface: tuple[ArrayLike, ArrayLike] | None = None):
        if not isinstance(name, str):
            raise ValueError(f"name must be a string, got {type(name).__name__}")
        x, z = validated_contour(x, z, f"airfoil {name!r}")
        if surface is None:
            contour = SmoothContour(x, z)
        else:
            sx, sz = validated_contour(surface[0], surface[1], f"surface of airfoil {name!r}")
            contour = SmoothContour(sx, sz)
            ends = np.array([[x[0], z[0]], [x[-1], z[-1]]])
            if not np.array_equal(ends, np.array([contour.start, contour.end])):
                raise ValueError(f"airfoil {name!r}: the surface must start and end at the same trailing-edge "
                                 f"points as the nodes, got {contour.start} and {contour.end} for {ends[0]} and "
                                 f"{ends[1]}")
            off = np.abs(contour.project(np.column_stack([x, z])).distance)
            if off.max() > SURFACE_TOLERANCE:
                i = int(np.argmax(off))
                raise ValueError(f"airfoil {name!r}: node {i} lies {off[i]:.3g} chord off the given surface "
                                 f"(tolerance {SURFACE_TOLERANCE:g}); pass nodes sampled from that surface")
        self._set(x, z, name, contour)

    @classmethod
    def _on_contour(cls, x: np.ndarray, z: np.ndarray, name: str, contour: SmoothContour) -> Airfoil:
        """An airfoil whose nodes were sampled from an existing smooth contour."""
        airfoil = cls.__new__(cls)
        x, z = validated_contour(x, z, f"airfoil {name!r}", crossing=False)
        airfoil._set(x, z, name, contour)
        return airfoil

    def _set(self, x: np.ndarray, z: np.ndarray, name: str, contour: SmoothContour) -> None:
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
        return self._contour.spline(np.array(self._contour.le_parameter))

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
        return self._contour.spline(t * self._contour.length)

    @cached_property
    def leading_edge_radius(self) -> float:
        """Radius of curvature (chord units) of the smooth contour at the leading edge.

        The leading edge is the minimum-x point. For a symmetric NACA section
        this is 1.1019 t^2; for a cambered one the minimum-x point is not the
        end of the camber line and the radius differs by a few percent.
        """
        return float(1.0 / self._contour.curvature(np.array(self._contour.le_parameter)))

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
        upper, lower = self._contour.surfaces_at(x, f"airfoil {self.name!r}")
        return (upper - lower)[()]

    def camber(self, x: ArrayLike) -> np.ndarray:
        """Camber distribution: the mean of upper and lower surface z (chord units) at the stations ``x``
        of :meth:`thickness` (same shape and refusals).

        For a NACA section this differs slightly from its mean line, whose
        thickness is laid perpendicular to it rather than vertically.
        """
        upper, lower = self._contour.surfaces_at(x, f"airfoil {self.name!r}")
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

    @property
    def surface_error(self) -> str | None:
        """Why the section has no single-valued surfaces (x turns back along one: its thickness, camber
        and resampling, which a bay needs, are then undefined), or None."""
        return self._contour.monotonic_error

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
                even or odd, at least :data:`~targets.checks.MIN_POINTS`.

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
        side = upper | lower  # (both surfaces in one bisection)
        end = np.where(upper, contour.start[0], contour.end[0])
        s[side] = contour.parameter_at_x((x_le + (end - x_le) * station)[side], upper[side])
        points = contour.spline(s)
        points[0], points[-1] = contour.start, contour.end
        return Airfoil._on_contour(points[:, 0], points[:, 1], self.name, contour)

    def with_trailing_edge(self, gap: float, blend: float = TRAILING_EDGE_BLEND) -> Airfoil:
        """The section with its trailing-edge gap changed to ``gap``, blended over the last ``blend``.

        The contour is resampled at :data:`BLEND_NODES` cosine-spaced nodes
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
        dense = self.resample(BLEND_NODES)
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
        x, z = validated_contour(x, z, f"airfoil {self.name!r}", crossing=False)
        return Airfoil._on_contour(x, z, self.name, SmoothContour(x, z))

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
        return self._contour.project(points)

    def distance(self, points: ArrayLike) -> np.ndarray:
        """Signed normal distance (chord units, shape ``(...)``) from the points of :meth:`project` to the
        contour, positive outside."""
        return self.project(points).distance

