"""The bay: the skin between two rigid ribs, as a structured grid (docs/architecture.md, "Conventions").

Index ``i`` runs along the span (alpha1, ``i = 0`` and ``n_span - 1`` on the
ribs), ``j`` along the contour (alpha2): periodic and in Selig order on a
closed contour (an airfoil), clamped at both ends on an open one (a flat
panel). With the span direction ``+y`` and this contour order, ``e1 x e2``
points out of the section, so a positive pressure pushes the skin outward.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from targets import common_trailing_edge

from ..precision import device_arrays, float64_scope
from ..forces import Geometry, nominal_nodes, surface_area

__all__ = ["Bay", "N_SPAN", "N_CONTOUR"]

#: Default grid of a bay, nodes along the span (ribs included) and around the contour: the
#: ``optimise-pressure`` command's, and every builder's (`Bay.from_airfoil`, `Wing.bays`, `solve_wing`).
N_SPAN = 17
N_CONTOUR = 64

_MIN_SPAN = 3
_MIN_CONTOUR_CLOSED = 12
_MIN_CONTOUR_OPEN = 3


def _check_length(name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive length in metres, got {value!r}")


def _contour_nodes(airfoil, n_contour: int) -> tuple[np.ndarray, np.ndarray, bool]:
    """Resample an airfoil to the grid's contour nodes.

    Returns chord-normalised ``(n_contour, 2)`` points, the camber line ``z``
    at each node's ``x``, and whether the trailing edge is closed.
    """
    resampled = airfoil.resample(n_contour + 1)
    points = np.stack([resampled.x, resampled.z], axis=-1)
    closed = bool(np.allclose(points[0], points[-1], rtol=0.0, atol=1e-12))
    if closed:
        points = points[:-1]  # the periodic grid closes the loop itself
    else:
        # A blunt trailing edge: keep both trailing-edge points, so the seam
        # edge between the last and the first node spans the base.
        points = np.concatenate([points[:-2], points[-1:]], axis=0)
    camber = np.asarray(airfoil.camber(np.clip(points[:, 0], 0.0, 1.0)), dtype=np.float64)
    return points.astype(np.float64), camber, closed


@dataclass(frozen=True, eq=False)
class Bay:
    """Geometry of one bay of skin and its grid.

    Build one with :meth:`from_airfoil` or :meth:`flat_panel`.

    Attributes:
        contour_root: ``(n_contour, 2)`` chord-normalised (x, z) rib contour at
            ``y = 0``, at the grid's contour nodes.
        contour_tip: the same at ``y = rib_spacing``.
        camber_root: ``(n_contour,)`` camber-line z under each root node (the
            rib thickness scale is applied about it).
        camber_tip: the same at the tip rib.
        chord_root: root rib chord, m.
        chord_tip: tip rib chord, m.
        rib_spacing: distance between the ribs, m.
        periodic: True for a closed contour.
        fixed: ``(n_span, n_contour)`` bool, nodes held by ribs and seams.
        name: a label for reports.
        trailing_edge_changes: the ribs whose trailing edge :meth:`from_airfoil`
            changed to the other's form (`targets.common_trailing_edge`'s notes,
            labels "root (name)" / "tip (name)"); empty when none was.
        airfoil: the root rib's section (`targets.Airfoil`) of a bay built
            with :meth:`from_airfoil`, else None (a flat panel).
        tip_airfoil: the tip rib's section as given to :meth:`from_airfoil`
            (None: the root's).
        fix_trailing_edge: whether :meth:`from_airfoil` held the trailing edge.
    """

    contour_root: np.ndarray
    contour_tip: np.ndarray
    camber_root: np.ndarray
    camber_tip: np.ndarray
    chord_root: float
    chord_tip: float
    rib_spacing: float
    periodic: bool
    fixed: np.ndarray
    name: str = "bay"
    trailing_edge_changes: tuple = ()
    airfoil: object = None
    tip_airfoil: object = None
    fix_trailing_edge: bool = True

    @property
    def n_span(self) -> int:
        return int(self.fixed.shape[0])

    @property
    def n_contour(self) -> int:
        return int(self.fixed.shape[1])

    @property
    def shape(self) -> tuple[int, int]:
        return (self.n_span, self.n_contour)

    @property
    def symmetric(self) -> bool:
        """True when both ribs are identical, so the bay is symmetric about mid-span."""
        return (
            self.chord_root == self.chord_tip
            and np.array_equal(self.contour_root, self.contour_tip)
            and np.array_equal(self.camber_root, self.camber_tip)
        )

    @property
    def chord(self) -> float:
        """Mean chord of the two ribs, m (the length that errors are reported against)."""
        return 0.5 * (self.chord_root + self.chord_tip)

    @property
    def divergence_bound(self) -> float:
        """Largest displacement (m) of a node from its mounted position before a solve stops as
        ``diverged`` (`Result.diverged`): the chord plus the rib spacing, far beyond any rest shape."""
        return self.chord + self.rib_spacing

    # ------------------------------------------------------------------ builders
    @classmethod
    def from_airfoil(cls, airfoil, chord: float = 1.0, rib_spacing: float = 0.25, n_span: int = N_SPAN,
                     n_contour: int = N_CONTOUR, fix_trailing_edge: bool = True, tip_airfoil=None,
                     tip_chord: float | None = None, trailing_edge: str = "close") -> "Bay":
        """A closed bay between two airfoil-shaped ribs.

        Args:
            airfoil: root rib section (a ``targets.Airfoil``).
            chord: root rib chord, m.
            rib_spacing: distance between the ribs, m.
            n_span: nodes along the span, ribs included (>= 3).
            n_contour: nodes around the contour (>= 12); they follow the
                airfoil's cosine spacing, so they cluster at both edges.
            fix_trailing_edge: hold the trailing-edge line (a seam). Free it
                for a smooth closed contour such as a circle.
            tip_airfoil: tip rib section for a tapered bay (default: the root's).
            tip_chord: tip rib chord, m (default: the root's).
            trailing_edge: for ribs of both trailing-edge forms (the grid has
                one seam form), "close", "open" or "as-given"
                (`targets.common_trailing_edge`); ``trailing_edge_changes``
                records a change.

        Raises:
            ValueError: for a non-positive length or a grid too coarse, or
                ribs of both trailing-edge forms with ``"as-given"``.
        """
        _check_length("chord", chord)
        _check_length("rib_spacing", rib_spacing)
        tip_chord = chord if tip_chord is None else tip_chord
        _check_length("tip_chord", tip_chord)
        _check_grid(n_span, n_contour, _MIN_CONTOUR_CLOSED, "closed contour")
        changes = []
        if tip_airfoil is not None:
            labels = [f"{end} ({getattr(a, 'name', 'airfoil')})"
                      for end, a in (("root", airfoil), ("tip", tip_airfoil))]
            (airfoil, tip_airfoil), changes = common_trailing_edge(
                (airfoil, tip_airfoil), trailing_edge, labels
            )
        root, camber_root, closed = _contour_nodes(airfoil, n_contour)
        if tip_airfoil is None:
            tip, camber_tip = root, camber_root
        else:
            tip, camber_tip, _ = _contour_nodes(tip_airfoil, n_contour)
        fixed = np.zeros((n_span, n_contour), dtype=bool)
        fixed[0, :] = fixed[-1, :] = True
        if fix_trailing_edge:
            fixed[:, 0] = True
            if not closed:
                fixed[:, -1] = True
        return cls(root, tip, camber_root, camber_tip, float(chord), float(tip_chord), float(rib_spacing),
                   periodic=True, fixed=fixed, name=str(getattr(airfoil, "name", "airfoil")),
                   trailing_edge_changes=tuple(changes), airfoil=airfoil, tip_airfoil=tip_airfoil,
                   fix_trailing_edge=bool(fix_trailing_edge))

    @classmethod
    def flat_panel(cls, width: float = 0.25, length: float = 1.0, n_span: int = 17, n_contour: int = 65) -> "Bay":
        """A flat rectangular panel clamped on its four edges.

        The panel lies in ``z = 0``; ``width`` runs along the span (y, between
        the "ribs") and ``length`` along x. The contour runs from ``x = length``
        to ``x = 0`` (like an upper surface), so positive pressure bulges it
        towards ``+z``. Nodes are uniformly spaced.

        Args:
            width: panel size along the span, m.
            length: panel size along the contour, m.
            n_span: nodes along the width (>= 3).
            n_contour: nodes along the length (>= 3).
        """
        _check_length("width", width)
        _check_length("length", length)
        _check_grid(n_span, n_contour, _MIN_CONTOUR_OPEN, "flat panel")
        x = np.linspace(1.0, 0.0, n_contour)
        contour = np.stack([x, np.zeros_like(x)], axis=-1)
        fixed = np.zeros((n_span, n_contour), dtype=bool)
        fixed[0, :] = fixed[-1, :] = True
        fixed[:, 0] = fixed[:, -1] = True
        zeros = np.zeros(n_contour)
        return cls(contour, contour, zeros, zeros, float(length), float(length), float(width), periodic=False,
                   fixed=fixed, name="flat panel")

    def __getstate__(self) -> dict:
        """Pickled without the `geometry` cache (device arrays, made again on first use): a pickled
        bay loads in a process that has not started JAX's backend (the report's figure workers,
        `inverse_design.app.workers.ReportWorkers`)."""
        state = dict(self.__dict__)
        state.pop("_geometry", None)
        return state

    # --------------------------------------------------------------- geometry
    def geometry(self) -> Geometry:
        """The bay as traced arrays for the force kernel.

        Made once per bay and float64 setting (a bay is immutable, JAX arrays too): a wing's
        design asks for each bay's geometry several times per solve (40 bays, 9 solves: 1680
        transfers of 0.6 ms).
        """
        x64 = bool(jax.config.jax_enable_x64)
        made = self.__dict__.setdefault("_geometry", {})  # a cache, not a field (frozen dataclass)
        if x64 in made:
            return made[x64]
        # numpy scalars, not Python floats: a weakly typed scalar is another jit signature than the
        # strongly typed one (a recompile of every kernel it reaches). One transfer for all.
        geometry = Geometry(*device_arrays([
            self.contour_root, self.contour_tip, self.camber_root, self.camber_tip,
            np.float64(self.chord_root), np.float64(self.chord_tip), np.float64(self.rib_spacing),
            (~np.asarray(self.fixed)).astype(np.float64)]))
        if not any(isinstance(a, jax.core.Tracer) for a in geometry):  # made inside a trace: its own
            made[x64] = geometry
        return geometry

    def nominal_nodes(self, rib_thickness_scale=1.0, rib_chord_scale=1.0, rib_shape=None,
                      rib_shape_tip=None) -> jnp.ndarray:
        """Mounted (nominal) shape of the skin, ``(n_span, n_contour, 3)`` in m: `forces.nominal_nodes`
        (``rib_shape_tip`` None: the tip rib takes ``rib_shape``). All may be traced JAX values."""
        tip = rib_shape if rib_shape_tip is None else rib_shape_tip
        with float64_scope(rib_thickness_scale, rib_chord_scale, rib_shape, tip):
            nodes = nominal_nodes(self.geometry(), rib_thickness_scale, rib_chord_scale, rib_shape, tip)
            if isinstance(nodes, jax.core.Tracer):
                return nodes
            return np.asarray(nodes)

    def skin_area(self) -> float:
        """Nominal area of the skin, m^2 (sum of the grid's quadrilaterals)."""
        with float64_scope():
            return float(surface_area(jnp.asarray(self.nominal_nodes()), self.periodic))


def _check_grid(n_span: int, n_contour: int, min_contour: int, what: str) -> None:
    if not isinstance(n_span, (int, np.integer)) or n_span < _MIN_SPAN:
        raise ValueError(f"n_span must be an integer >= {_MIN_SPAN} (the two ribs and at least one free row), "
                         f"got {n_span!r}; use a finer grid")
    if not isinstance(n_contour, (int, np.integer)) or n_contour < min_contour:
        raise ValueError(f"n_contour must be an integer >= {min_contour} for a {what}, got {n_contour!r}; "
                         "use a finer grid")
