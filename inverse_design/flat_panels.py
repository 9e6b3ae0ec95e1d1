"""Flat patterns of the skin: each bay's panels developed in the plane from the cut lengths.

The fabric of a bay is cut flat and sewn (or bonded) to the two ribs. The
solver's reference state is the cut: every grid edge has a cut (reference)
length, paper eq. (12) ``h = mounted length / (1 + prestrain)``
(`rib_design.cut_lengths`, per edge, so a prestrain that varies from node to
node is followed with no change here). A panel is a strip of the grid's
quads: contour nodes ``j`` across, span stations ``i`` along (the span
fibres: the warp, unless the fabric's ``warp`` is "chord", when the contour
rows are; the drawing's WARP arrow says which, `Panel.warp`). `flat_layout.develop` lays it flat.

What is exact and what is a choice:

* exact: the length of every grid edge of the flat panel, the contour edges
  of every span row (the ribs' sewing edges included) and the span edges of
  every contour node's fibre, equals its cut length (solved by least
  squares to ``1e-9`` of the edge; `Panel.length_error` is the largest
  difference, measured). The sewing outline is the panel's boundary on the
  grid, so its edges are the cut lengths of the rib rows and of the panel's
  two boundary fibres.
* a choice: a grid of quads with given edge lengths is not rigid in the
  plane (the model's fabric has no shear stiffness, eq. 10; a quad's angle
  is free); among the exact layouts `develop` takes the one whose cells keep
  the angle between warp and weft of the mounted skin as closely as possible
  (least squares, then the edges made exact from there). The span fibres
  are therefore not straight in general (they are for an untapered bay with
  a prestrain uniform along the span).

Panels (`bay_panels`): an airfoil bay is split at its leading edge (the
contour node of least x) into an ``upper`` panel (trailing edge to leading
edge, Selig order) and a ``lower`` panel (leading edge round to the trailing
edge, the base edge of a blunt trailing edge included), so that both panels
are nearly flat strips and the seams are at the trailing and leading edges;
a flat test panel is one ``panel``. A panel is laid as its outside face is
seen (the face the pressure pushes out): the span (the warp, from the root
rib ``i = 0``) along ``+y`` and the contour (Selig order) along ``-x``, so
the upper panel has its leading edge on the left, as the wing is seen from
above with its root at the bottom, and the lower panel its leading edge on
the right, as seen from below. (`flat_layout.develop` lays the contour along
``+x``: that is the inside face seen, mirrored.) A shop lays the fabric
outside face up under the drawing.

`flat_layout.offset_outline` gives the cut line: the sewing outline offset outward by
the seam allowance (a miter offset of the closed polygon, sharp convex
corners rounded).

`rib_template` gives a rib's template: the outline of the rib itself, the
designed section (`forward_solver.model.rib_shape`: thickness scale about the
camber line, the rib shape's offset, the chord scale, at the rib's chord)
evaluated on the section's smooth contour, not the grid's polygon, at
points chosen so that no chord of the outline strays more than
`RIB_CHORDAL_ERROR` from the curve (adaptive bisection); and the skin's
attachment points, the grid's contour nodes on that rib (`mounted_skin`),
which lie on the outline.
"""

from __future__ import annotations

import weakref

import jax
import numpy as np

from forward_solver.model.rib_shape import bernstein_basis, class_function
from forward_solver.programs import mounted_compiled

from .flat_layout import Panel, develop, edge_lengths
from .rib_design import cut_lengths

__all__ = ["RIB_CHORDAL_ERROR", "bay_panels", "mounted_skin", "rib_outline", "rib_template"]

#: m: the largest distance of a rib template's outline (a polygon) from the designed section between its
#: points, its chordal error: far below a cutter's kerf, and below what a drawn line can show.
RIB_CHORDAL_ERROR = 5e-5
#: Fractions at which each interval of the outline is tested against its chord (the largest deviation of a
#: smooth arc from its chord lies near the middle).
_PROBES = np.array([0.25, 0.5, 0.75])
#: Cap on the halvings of an outline interval (2^-40 of the first spacing: far below float spacing).
_MAX_HALVINGS = 40


def _cell_cosines(nodes, columns) -> np.ndarray:
    """``(n - 1, m - 1)`` cosine of the angle between warp and weft in each mounted cell of a panel."""
    p = nodes[:, columns]
    s = 0.5 * (p[1:, :-1] - p[:-1, :-1] + p[1:, 1:] - p[:-1, 1:])
    c = 0.5 * (p[:-1, 1:] - p[:-1, :-1] + p[1:, 1:] - p[1:, :-1])
    return np.sum(s * c, axis=-1) / (np.linalg.norm(s, axis=-1) * np.linalg.norm(c, axis=-1))


def mounted_skin(scene, parameters) -> np.ndarray:
    """``(n_span, n_contour, 3)`` the mounted skin of a bay (`forces.mounted_nodes`), m."""
    with jax.enable_x64(True):
        geometry = scene.bay.geometry()
        return np.asarray(mounted_compiled(geometry, scene.params(parameters.as_floats())))


def bay_panels(scene, parameters, bay: int = 0) -> list[Panel]:
    """The flat panels of one bay, from its cut lengths (`rib_design.cut_lengths`; module docstring).

    Args:
        scene: the bay's `forward_solver.Scene`.
        parameters: the design's `Parameters` for this bay (prestrain, rib scales and shapes).
        bay: the bay's index (the panels' label).

    Returns:
        ``[upper, lower]`` for an airfoil bay, ``[panel]`` for a flat panel.

    Raises:
        ValueError: if a panel cannot be laid flat at its cut lengths (`develop`).
    """
    cuts = cut_lengths(scene, parameters)
    contour, span = cuts["contour_edge_cut_m"], cuts["span_edge_cut_m"]
    nodes = mounted_skin(scene, parameters)
    n_contour = scene.bay.n_contour
    if scene.bay.periodic:
        j_le = int(np.argmin(np.asarray(scene.bay.contour_root)[:, 0]))
        pieces = [("upper", np.arange(0, j_le + 1), 0 + j_le),
                  ("lower", np.concatenate([np.arange(j_le, n_contour), [0]]), 0)]
    else:
        pieces = [("panel", np.arange(n_contour), None)]
    panels = []
    for name, columns, le in pieces:
        edges = columns[:-1]  # contour edge e joins nodes e and e + 1 (mod n_contour)
        contour_cut, span_cut = contour[:, edges], span[:, columns]
        flat = develop(contour_cut, span_cut, _cell_cosines(nodes, columns))
        flat[..., 0] = flat[0, -1, 0] - flat[..., 0]  # seen from outside: the contour along -x (docstring)
        c, s = edge_lengths(flat)
        error = float(max(np.max(np.abs(c - contour_cut)), np.max(np.abs(s - span_cut))))
        panels.append(Panel(bay=bay, name=name, columns=columns, flat=flat, contour_cut=contour_cut,
                            span_cut=span_cut, leading_edge=le, length_error=error, warp=scene.fabric.warp))
    return panels


def rib_outline(section, chord: float, thickness_scale: float = 1.0, chord_scale: float = 1.0, shape=None,
                chordal_error: float = RIB_CHORDAL_ERROR) -> np.ndarray:
    """The designed rib's outline, metres, sampled finely enough for ``chordal_error``.

    The rib is mounted as `forces.nominal_nodes` mounts the grid's nodes, but
    on the smooth contour of ``section`` (`targets.Airfoil.contour_points`):
    ``x = x0 c s_c``, ``z = (camber(x0) + s_t (z0 - camber(x0)) + dz(x0)) c``,
    with ``dz`` the rib shape's outward offset (`forward_solver.model.rib_shape`;
    upper surface before the leading edge, lower after). Points are added by
    halving every interval whose chord lies more than ``chordal_error`` from
    the curve at a quarter, half or three quarters of it, until none does.

    Args:
        section: the rib's starting section (`targets.Airfoil`, chord-normalised).
        chord: the rib's chord, m (> 0).
        thickness_scale: the rib thickness scale.
        chord_scale: the rib chord scale.
        shape: ``(2 K,)`` rib-shape coefficients, or None.
        chordal_error: m (> 0).

    Returns:
        ``(n, 2)`` x-z in metres, Selig order (trailing edge, upper surface,
        leading edge, lower surface, trailing edge; a closed trailing edge's
        point once).
    """
    if not chordal_error > 0:
        raise ValueError(f"chordal_error must be a positive length in metres, got {chordal_error!r}")
    coefficients = None if shape is None else np.asarray(shape, np.float64).reshape(-1)
    t_le = section.leading_edge_parameter

    def unit(t: np.ndarray) -> np.ndarray:
        x0, z0 = section.contour_points(t).T
        station = np.clip(x0, 0.0, 1.0)
        camber = np.asarray(section.camber(station))  # as `forward_solver.model.bay` takes it at the nodes
        z = camber + thickness_scale * (z0 - camber)
        if coefficients is not None and coefficients.size:
            k = coefficients.size // 2
            basis = np.asarray(class_function(station))[:, None] * np.asarray(bernstein_basis(station, k))
            upper = t <= t_le
            z = z + np.where(upper, basis @ coefficients[:k], -(basis @ coefficients[k:]))
        return np.column_stack([x0 * chord_scale, z])

    known = _known_points(section, thickness_scale, chord_scale, coefficients)

    def mounted(t: np.ndarray) -> np.ndarray:
        return known.points(t, unit) * chord

    t = np.unique(np.concatenate([np.linspace(0.0, 1.0, 65), [t_le]]))
    points = mounted(t)
    for _ in range(_MAX_HALVINGS):
        a, b = t[:-1], t[1:]
        probes = a[:, None] + (b - a)[:, None] * _PROBES
        at = mounted(probes.reshape(-1)).reshape(probes.shape + (2,))
        start, end = points[:-1, None, :], points[1:, None, :]
        along = end - start
        length = np.linalg.norm(along, axis=-1)
        offset = at - start
        deviation = np.abs(along[..., 0] * offset[..., 1] - along[..., 1] * offset[..., 0]) / np.where(
            length > 0, length, 1.0)
        split = np.max(deviation, axis=1) > chordal_error
        if not split.any():
            break
        middle = 0.5 * (a[split] + b[split])
        t = np.concatenate([t, middle])
        points = np.concatenate([points, mounted(middle)])
        order = np.argsort(t)
        t, points = t[order], points[order]
    if section.closed_te:
        points = points[:-1]  # the last point is the first
    return points


class _KnownPoints:
    """A rib outline's points in chord units (`rib_outline`'s ``unit``), by contour parameter, as computed
    so far for one section, scales and shape: a wing's ribs share a section and differ in chord, and an
    outline's parameters are halvings of one grid, so a smaller rib's are mostly a larger one's (the 40-cell
    wing's 41 ribs: every point once instead of once per rib)."""

    def __init__(self):
        self.t = np.zeros(0)
        self.values = np.zeros((0, 2))

    def points(self, t: np.ndarray, unit) -> np.ndarray:
        """``unit(t)``: the known values, and the others computed (in one call) and kept."""
        at = np.minimum(np.searchsorted(self.t, t), max(self.t.size - 1, 0))
        hit = (self.t[at] == t) if self.t.size else np.zeros(t.shape, bool)
        out = np.empty((t.size, 2))
        out[hit] = self.values[at[hit]]
        if not hit.all():
            new_t = t[~hit]
            out[~hit] = new = unit(new_t)
            order = np.argsort(np.concatenate([self.t, new_t]), kind="stable")
            self.t = np.concatenate([self.t, new_t])[order]
            self.values = np.concatenate([self.values, new])[order]
        return out


#: The `_KnownPoints` of the last outlines' sections, scales and shapes (a few: a report's ribs in turn).
_KNOWN: dict = {}
_MAX_KNOWN = 4


def _known_points(section, thickness_scale: float, chord_scale: float, coefficients) -> _KnownPoints:
    """The `_KnownPoints` of ``section`` (by identity) at these scales and shape coefficients."""
    key = (id(section), float(thickness_scale), float(chord_scale),
           None if coefficients is None else coefficients.tobytes())
    entry = _KNOWN.pop(key, None)
    if entry is None or entry[0]() is not section:  # (a section collected since, its id reused)
        entry = (weakref.ref(section), _KnownPoints())
    while len(_KNOWN) >= _MAX_KNOWN:
        _KNOWN.pop(next(iter(_KNOWN)))
    _KNOWN[key] = entry  # (the most recently used last)
    return entry[1]


def rib_template(scene, parameters, row: int) -> tuple[np.ndarray, np.ndarray]:
    """A rib's template: its outline (`rib_outline`) and the skin's attachment nodes on it.

    Args:
        scene: the bay's `forward_solver.Scene` (a bay built with `Bay.from_airfoil`).
        parameters: the bay's design `Parameters` (rib scales and shapes).
        row: 0 for the root rib, -1 for the tip rib.

    Returns:
        ``(outline, nodes)``: ``(n, 2)`` and ``(n_contour, 2)`` x-z, metres.
    """
    bay = scene.bay
    tip = row != 0
    section = (bay.tip_airfoil or bay.airfoil) if tip else bay.airfoil
    chord = bay.chord_tip if tip else bay.chord_root
    shape = parameters.rib_shapes[1 if tip else 0]
    outline = rib_outline(section, chord, float(parameters.rib_thickness_scale), float(parameters.rib_chord_scale),
                          None if shape is None else np.asarray(shape, np.float64))
    nodes = np.asarray(mounted_skin(scene, parameters)[row][:, [0, 2]])
    return outline, nodes
