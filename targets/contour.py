"""The smooth representation of a section's contour: a cubic spline, closest points and signed distance.

:class:`SmoothContour` is a cubic spline of (x, z) against the cumulative
chord length of a contour's points (periodic for a closed contour that is
smooth through its trailing edge, :func:`is_smooth_join`), with the queries
:class:`~targets.airfoil.Airfoil` answers on it: points, tangents, normals,
curvature, the parameter where x takes a value on one surface, and the
closest points of the contour to query points (:class:`Projection`, whose
``distance`` is the signed normal distance, positive outside). An open
trailing edge is closed, for distances, by its straight base.
"""

from __future__ import annotations

import math
from functools import cached_property
from typing import NamedTuple

import numpy as np
from scipy.interpolate import CubicSpline, PPoly
from scipy.spatial import cKDTree

from .monotone_spline import REVERSAL_TOLERANCE, limit_x_reversals

_DENSE_SAMPLES = 16384  # samples of the spline for the nearest-vertex start
_CANDIDATES = 4  # nearest samples refined per point (both sides of a corner)
_NEWTON_STEPS = 50  # cap on the projection iterations
_BISECTION_STEPS = 64  # halvings of a parameter interval: below float64 spacing
STATION_TOLERANCE = 1e-6
"""Distance (chord) outside the section within which a station is clipped onto it."""


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


def _unit(vectors: np.ndarray, fallback=0.0) -> np.ndarray:
    """``vectors`` over their lengths; ``fallback`` where a length is zero (two opposite normals summed at
    a cusp of an open trailing edge: NumPy's 0/0 warned "invalid value" on the command's console)."""
    length = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return np.where(length > 0.0, vectors / np.where(length > 0.0, length, 1.0), fallback)


def is_smooth_join(x: np.ndarray, z: np.ndarray) -> bool:
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


class SmoothContour:
    """Cubic spline of (x, z) against cumulative chord length, with its queries (module docstring).

    Not periodic, it has not-a-knot ends (the trailing edge is a corner, or
    open). Where its x(s) turns back between nodes whose x is
    monotonic (beside a sharp nose, or beside the trailing-edge node of a
    periodic contour), the x part is repaired by
    :func:`~targets.monotone_spline.limit_x_reversals` and is C1 there.
    """

    def __init__(self, x: np.ndarray, z: np.ndarray):
        self.closed = bool(x[0] == x[-1] and z[0] == z[-1])
        self.periodic = self.closed and is_smooth_join(x, z)
        points = np.column_stack([x, z])
        knots = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(z)))])
        self.length = float(knots[-1])
        spline = CubicSpline(
            knots, points, axis=0, bc_type="periodic" if self.periodic else "not-a-knot"
        )
        self.spline = limit_x_reversals(spline, x, self.periodic)
        self.tangent = self.spline.derivative(1)  # and `spline(s)`: the points
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

    def outward_normal(self, s: np.ndarray) -> np.ndarray:
        t = self.tangent(s)
        return _unit(np.stack([t[..., 1], -t[..., 0]], axis=-1))

    def curvature(self, s: np.ndarray) -> np.ndarray:
        """Signed curvature (1/chord), positive where the contour turns counter-clockwise."""
        t, k = self.tangent(s), self._second(s)
        cross = t[..., 0] * k[..., 1] - t[..., 1] * k[..., 0]
        return cross / np.hypot(t[..., 0], t[..., 1]) ** 3

    @cached_property
    def monotonic_error(self) -> str | None:
        """Why x is not single-valued along a surface, or None when it is."""
        s = self._dense_parameter
        slope = self.tangent(s)
        speed = np.hypot(slope[:, 0], slope[:, 1])
        for surface, part, wrong_sign in (
            ("upper", s < self.le_parameter, slope[:, 0] > REVERSAL_TOLERANCE * speed),
            ("lower", s > self.le_parameter, slope[:, 0] < -REVERSAL_TOLERANCE * speed),
        ):
            bad = part & wrong_sign
            if bad.any():
                x_bad = float(self._x_poly(s[np.argmax(bad)]))
                return (f"x turns back along the {surface} surface near x = {x_bad:.4f}; thickness, "
                        f"camber and resampling need each surface to run monotonically in x from the "
                        f"leading edge to the trailing edge")
        return None

    def parameter_at_x(self, stations: np.ndarray, upper) -> np.ndarray:
        """Contour parameter where x equals each station, on one surface.

        Args:
            stations: Chordwise stations (chord units) inside the x-range of
                the surface, shape ``(m,)``.
            upper: True for the upper surface (parameter 0 to the leading
                edge), False for the lower one (leading edge to the end); or
                ``(m,)`` booleans, a surface per station (both surfaces in one
                bisection: each station's steps are its own).

        Returns:
            Parameters, shape ``(m,)``, found by bisection to float64
            resolution (x is monotonic along each surface).
        """
        upper = np.broadcast_to(np.asarray(upper, dtype=bool), np.shape(stations))
        a = np.where(upper, 0.0, self.le_parameter)
        b = np.where(upper, self.le_parameter, self.length)
        for _ in range(_BISECTION_STEPS):
            middle = 0.5 * (a + b)
            above = self._x_poly(middle) > stations
            root_after_middle = above == upper  # (above on the upper surface, below on the lower)
            a = np.where(root_after_middle, middle, a)
            b = np.where(root_after_middle, b, middle)
        return 0.5 * (a + b)

    def surface_z(self, stations: np.ndarray, upper) -> np.ndarray:
        """z of one surface at chordwise ``stations`` (inside its x-range, or beyond its trailing-edge end);
        ``upper`` as `parameter_at_x` takes it (a surface, or one per station)."""
        upper = np.broadcast_to(np.asarray(upper, dtype=bool), np.shape(stations))
        end = np.where(upper, self.start[0], self.end[0])
        inside = np.clip(stations, self.x_le, end)
        z = self.spline(self.parameter_at_x(inside, upper))[:, 1]
        beyond = stations > end
        if beyond.any():
            # An open, cambered trailing edge ends its surfaces a little before or after
            # x = 1; continue the shorter one along its end tangent.
            tangent = np.where(upper[:, None], self.tangent(np.array(0.0)), self.tangent(np.array(self.length)))
            z = z + np.where(beyond, tangent[:, 1] / tangent[:, 0] * (stations - end), 0.0)
        return z

    def surfaces_at(self, x, what: str) -> tuple[np.ndarray, np.ndarray]:
        """``(upper, lower)`` surface z at chordwise stations ``x`` (any shape), chord units.

        Raises:
            ValueError: naming ``what`` (e.g. ``"airfoil 'naca2412'"``), if x is not monotonic
                along a surface or a station lies outside the section.
        """
        if self.monotonic_error is not None:
            raise ValueError(f"{what}: {self.monotonic_error}")
        stations = np.asarray(x, dtype=np.float64)
        flat = stations.reshape(-1)
        x_te = max(self.start[0], self.end[0])
        low, high = self.x_le - STATION_TOLERANCE, x_te + STATION_TOLERANCE
        outside = ~((flat >= low) & (flat <= high))
        if outside.any():
            raise ValueError(f"{what}: station x = {flat[np.argmax(outside)]!r} lies outside the "
                             f"section, which runs from x = {self.x_le:.6g} to x = {x_te:.6g}")
        flat = np.clip(flat, self.x_le, x_te)
        both = self.surface_z(np.concatenate([flat, flat]), np.arange(2 * flat.size) < flat.size)
        return both[:flat.size].reshape(stations.shape), both[flat.size:].reshape(stations.shape)

    def project(self, points) -> Projection:
        """Closest points of the contour to query points (x, z) of shape ``(..., 2)``, chord units.

        Raises:
            ValueError: If points does not end in an axis of length 2 or is not finite.
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
        result = self.closest(flat)
        shape = query.shape[:-1]
        return Projection(
            distance=result.distance.reshape(shape),
            foot=result.foot.reshape(shape + (2,)),
            normal=result.normal.reshape(shape + (2,)),
        )

    def closest(self, points: np.ndarray) -> Projection:
        """Closest contour points to ``points`` of shape ``(m, 2)``."""
        _, index = self._tree.query(points, k=_CANDIDATES)
        s = self._dense_parameter[index]
        target = points[:, None, :]
        for _ in range(_NEWTON_STEPS):
            offset = self.spline(s) - target
            tangent = self.tangent(s)
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
                corner = _unit(n_start + n_end, fallback=n_start)
                normal[(s <= 0.0) | (s >= self.length)] = corner
            else:
                base = self.start - self.end  # trailing-edge base, last point -> first point
                n_base = _unit(np.array([base[1], -base[0]]))
                corner_start = _unit(n_start + n_base, fallback=n_base)
                corner_end = _unit(n_end + n_base, fallback=n_base)
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
