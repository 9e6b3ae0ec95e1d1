"""Flat patterns of the skin: each bay's panels developed in the plane from the cut lengths.

The fabric of a bay is cut flat and sewn (or bonded) to the two ribs. The
solver's reference state is the cut: every grid edge has a cut (reference)
length, paper eq. (12) ``h = mounted length / (1 + prestrain)``
(`rib_design.cut_lengths`, per edge, so a prestrain that varies from node to
node is followed with no change here). A panel is a strip of the grid's
quads: contour nodes ``j`` across (the weft), span stations ``i`` along (the
warp, the span fibres). `develop` lays it flat.

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
a flat test panel is one ``panel``. In the drawing a panel's contour runs
along ``+x`` and the span (the warp, from the root rib ``i = 0``) along
``+y``.

`offset_outline` gives the cut line: the sewing outline offset outward by
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

from dataclasses import dataclass

import numpy as np

__all__ = ["Panel", "RIB_CHORDAL_ERROR", "bay_panels", "develop", "mounted_skin", "offset_outline", "panel_outline",
           "rib_outline", "rib_template"]

#: Largest edge-length error accepted by `develop`, as a fraction of the edge's cut length.
LAYOUT_TOLERANCE = 1e-9
#: m: an exact layout whose largest edge error is below this has reached float64's rounding (edges of
#: centimetres to metres, sums of hundreds of them); a step that does not improve it ends the layout.
_ROUNDING_FLOOR = 1e-12


#: m: the largest distance of a rib template's outline (a polygon) from the designed section between its
#: points, its chordal error: far below a cutter's kerf, and below what a drawn line can show.
RIB_CHORDAL_ERROR = 5e-5
#: Fractions at which each interval of the outline is tested against its chord (the largest deviation of a
#: smooth arc from its chord lies near the middle).
_PROBES = np.array([0.25, 0.5, 0.75])
#: Cap on the halvings of an outline interval (2^-40 of the first spacing: far below float spacing).
_MAX_HALVINGS = 40


@dataclass(frozen=True)
class Panel:
    """One flat panel of a bay.

    Attributes:
        bay: the bay's index.
        name: "upper", "lower" or "panel".
        columns: ``(m,)`` contour node index ``j`` of each panel column (left to right).
        flat: ``(n_span, m, 2)`` the developed grid, metres (x across, y along the span).
        contour_cut: ``(n_span, m - 1)`` the cut length of each contour edge, m.
        span_cut: ``(n_span - 1, m)`` the cut length of each span edge, m.
        leading_edge: the panel column of the leading edge, or None.
        length_error: largest ``|flat edge length - cut length|`` over the panel's edges, m.
    """

    bay: int
    name: str
    columns: np.ndarray
    flat: np.ndarray
    contour_cut: np.ndarray
    span_cut: np.ndarray
    leading_edge: int | None
    length_error: float


def _edges(flat):
    """``(contour (n, m-1), span (n-1, m))`` edge lengths of a flat grid."""
    return (np.linalg.norm(flat[:, 1:] - flat[:, :-1], axis=-1),
            np.linalg.norm(flat[1:] - flat[:-1], axis=-1))


def develop(contour_cut, span_cut, cos_angle=None, *, shear_weight: float = 1e-2) -> np.ndarray:
    """Lay a strip of quads flat with every edge at its cut length (module docstring).

    Args:
        contour_cut: ``(n, m - 1)`` cut length of each contour edge (row ``i``, between columns).
        span_cut: ``(n - 1, m)`` cut length of each span edge (along column ``k``).
        cos_angle: ``(n - 1, m - 1)`` cosine of the angle between warp and weft in each
            cell to keep (the mounted skin's); None: right angles.
        shear_weight: weight of the angle terms in the first least-squares pass.

    Returns:
        ``(n, m, 2)`` the flat grid, x across the contour, y along the span, the
        first row's first node at the origin and the first row along +x.

    Raises:
        ValueError: if the edge lengths cannot be met in the plane (largest
            error above `LAYOUT_TOLERANCE` of its edge).
    """
    from scipy.sparse import coo_matrix

    contour_cut = np.asarray(contour_cut, np.float64)
    span_cut = np.asarray(span_cut, np.float64)
    n, m = span_cut.shape[0] + 1, contour_cut.shape[1] + 1
    cos_angle = np.zeros((n - 1, m - 1)) if cos_angle is None else np.asarray(cos_angle, np.float64)
    # Nodes numbered along the shorter grid direction first: the normal matrix of the least
    # squares is then banded with the least half-width (`_normal_step`).
    index = np.arange(n * m).reshape(n, m) if n >= m else np.arange(n * m).reshape(m, n).T
    # edges (a, b) of the grid and their cut lengths: contour edges, then span edges
    a = np.concatenate([index[:, :-1].ravel(), index[:-1].ravel()])
    b = np.concatenate([index[:, 1:].ravel(), index[1:].ravel()])
    h = np.concatenate([contour_cut.ravel(), span_cut.ravel()])
    # cells: corners (i, k), (i+1, k), (i+1, k+1), (i, k+1)
    c00, c10, c11, c01 = (index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(),
                          index[:-1, 1:].ravel())
    n_edges, n_cells = a.size, c00.size

    # first guess: each row laid straight along x, centred on the first row; rows stacked
    # along y by the mean span cut
    arc = np.concatenate([np.zeros((n, 1)), np.cumsum(contour_cut, axis=1)], axis=1)
    x0 = arc - 0.5 * (arc[:, -1:] - arc[:1, -1:])
    y0 = np.concatenate([np.zeros((1, m)), np.cumsum(span_cut, axis=0)]).mean(axis=1, keepdims=True)
    start = np.empty((n * m, 2))
    start[index] = np.stack([x0, np.broadcast_to(y0, (n, m))], axis=-1)
    start = start.ravel()

    def parts(z):
        p = z.reshape(-1, 2)
        d = p[b] - p[a]
        length = np.linalg.norm(d, axis=1)
        s = 0.5 * (p[c10] - p[c00] + p[c11] - p[c01])  # the cell's warp
        c = 0.5 * (p[c01] - p[c00] + p[c11] - p[c10])  # its weft
        ls, lc = np.linalg.norm(s, axis=1), np.linalg.norm(c, axis=1)
        return p, d, length, s, c, ls, lc

    def make(weight):
        def fun(z):
            _, _, length, s, c, ls, lc = parts(z)
            r = [(length - h) / h]
            if weight:
                r.append(weight * (np.sum(s * c, axis=1) / (ls * lc) - cos_angle.ravel()))
            return np.concatenate(r)

        def jac(z):
            _, d, length, s, c, ls, lc = parts(z)
            u = d / (length * h)[:, None]
            rows = [np.repeat(np.arange(n_edges), 4)]
            cols = [np.stack([2 * b, 2 * b + 1, 2 * a, 2 * a + 1], axis=1).ravel()]
            vals = [np.stack([u[:, 0], u[:, 1], -u[:, 0], -u[:, 1]], axis=1).ravel()]
            if weight:
                cos = np.sum(s * c, axis=1) / (ls * lc)
                ds = weight * ((c / lc[:, None]) - cos[:, None] * s / ls[:, None]) / ls[:, None]
                dc = weight * ((s / ls[:, None]) - cos[:, None] * c / lc[:, None]) / lc[:, None]
                # d s / d corner: c10, c11 +1/2; c00, c01 -1/2.  d c / d corner: c01, c11 +1/2; c00, c10 -1/2
                for corner, fs, fc in ((c00, -0.5, -0.5), (c10, 0.5, -0.5), (c11, 0.5, 0.5), (c01, -0.5, 0.5)):
                    g = fs * ds + fc * dc
                    rows.append(np.repeat(n_edges + np.arange(n_cells), 2))
                    cols.append(np.stack([2 * corner, 2 * corner + 1], axis=1).ravel())
                    vals.append(g.ravel())
            shape = (n_edges + (n_cells if weight else 0), 2 * n * m)
            return coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                              shape=shape).tocsr()

        return fun, jac

    z = start
    for weight in (shear_weight, 0.0):
        z = _levenberg_marquardt(*make(weight), z, exact=weight == 0.0)
    flat = z.reshape(-1, 2)[index]
    contour, span = _edges(flat)
    error = max(np.max(np.abs(contour - contour_cut) / contour_cut), np.max(np.abs(span - span_cut) / span_cut))
    if not error <= LAYOUT_TOLERANCE:
        raise ValueError(f"the cut lengths cannot be laid flat: an edge is off by {error:.3g} of its length "
                         f"(above {LAYOUT_TOLERANCE:g})")
    # place: first node at the origin, the first row's chord along +x, the span along +y
    flat = flat - flat[0, 0]
    direction = flat[0, -1] / np.linalg.norm(flat[0, -1])
    rotation = np.array([[direction[0], direction[1]], [-direction[1], direction[0]]])
    flat = flat @ rotation.T
    if np.mean(flat[-1, :, 1]) < 0:  # the span the other way: mirror
        flat[..., 1] *= -1
    return flat


def _levenberg_marquardt(fun, jac, z, exact: bool, max_iterations: int = 200) -> np.ndarray:
    """Minimise ``|fun(z)|^2`` by damped Gauss-Newton steps on the sparse normal equations.

    The damping also fixes the directions the residuals leave free (the
    panel's position and, without the angle terms, its shear): each step is
    the smallest that reduces the residual, so the layout stays near where it
    started. ``exact``: stop when every residual is below 1e-14 (the edges
    laid at their lengths), or below `_ROUNDING_FLOOR` when a step no longer
    improves it; otherwise when a step lowers the cost by less than 1e-10 of
    itself (the layout then moves by about 1e-14 m: bay 11 of
    ``wing_40_cells.toml``, against 1e-14 relative).
    """
    r = fun(z)
    cost = float(r @ r)
    damping = 1e-6
    for iteration in range(max_iterations):
        if exact and np.max(np.abs(r)) < 1e-14:
            break
        J = jac(z)
        step = _normal_step(J.T @ J, -(J.T @ r), damping)
        if step is None or not np.all(np.isfinite(step)):
            if exact and np.max(np.abs(r)) < _ROUNDING_FLOOR:
                break
            damping *= 8.0
            if damping > 1e12:
                break
            continue
        trial = z + step
        r_trial = fun(trial)
        cost_trial = float(r_trial @ r_trial)
        if cost_trial < cost:
            converged = not exact and cost - cost_trial <= 1e-10 * max(cost, 1e-30)
            z, r, cost = trial, r_trial, cost_trial
            damping = max(damping / 4.0, 1e-15)
            if converged:
                break
        else:
            if exact and np.max(np.abs(r)) < _ROUNDING_FLOOR:
                break
            damping *= 8.0
            if damping > 1e12:
                break
    return z


def _normal_step(normal, rhs, damping: float):
    """``(N + damping I)^-1 rhs`` for the symmetric banded normal matrix ``N`` (sparse), by a banded
    Cholesky factorisation (LAPACK ``pbsv``; a 17x33 panel: half-width 37, 0.3 ms against 2.4 ms
    of a general sparse LU); None where rounding leaves it not positive definite: the residuals
    leave the panel's position (and, without the angle terms, its shear) free, so a damping lost
    in rounding leaves it singular, and the step is rejected."""
    from scipy.linalg import LinAlgError, solveh_banded

    # Summed (none on a sparse product) as CSR, whose check of that is linear: COO's sorts, and took 12%
    # of a 40-bay wing's report.
    normal = normal.tocsr()
    normal.sum_duplicates()
    normal = normal.tocoo()
    upper = normal.col >= normal.row
    row, col, data = normal.row[upper], normal.col[upper], normal.data[upper]
    width = int(np.max(col - row, initial=0))
    banded = np.zeros((width + 1, rhs.size))
    banded[width + row - col, col] = data
    banded[width] += damping
    try:
        return solveh_banded(banded, rhs, check_finite=False)
    except LinAlgError:
        return None


def panel_outline(flat) -> tuple[np.ndarray, np.ndarray]:
    """The sewing outline of a flat panel: ``(points (p, 2), grid (p, 2) [i, k] of each point)``.

    Counter-clockwise from the root rib's first node: along the root rib row
    (``i = 0``), up the last column, back along the tip rib row, down the
    first column (the closing edge back to the start is implied).
    """
    n, m = flat.shape[:2]
    grid = ([(0, k) for k in range(m)] + [(i, m - 1) for i in range(1, n)]
            + [(n - 1, k) for k in range(m - 2, -1, -1)] + [(i, 0) for i in range(n - 2, 0, -1)])
    grid = np.asarray(grid)
    return flat[grid[:, 0], grid[:, 1]], grid


def offset_outline(points, distance: float) -> np.ndarray:
    """A closed polygon offset outward by ``distance``.

    Each edge moves out parallel to itself by ``distance``. At a corner the
    two moved edges meet (a miter); a convex corner that turns by more than
    90 degrees (a sharp trailing edge) is instead rounded by a polygon
    tangent to the circle of radius ``distance`` about the corner, in steps
    of at most 90 degrees, so that no point of the offset comes nearer the
    polygon than ``distance`` and none lies farther than ``sqrt(2) distance``
    from its corner.

    Args:
        points: ``(p, 2)`` the polygon's vertices, either orientation, not repeated at the end.
        distance: the offset (>= 0), in the points' unit.

    Returns:
        ``(q, 2)`` the offset polygon (``q >= p``).
    """
    p = np.asarray(points, np.float64)
    if distance == 0:
        return p.copy()
    area = 0.5 * np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])
    edge = np.roll(p, -1, axis=0) - p  # edge k from vertex k to k + 1
    edge /= np.linalg.norm(edge, axis=1, keepdims=True)
    sign = 1.0 if area > 0 else -1.0  # counter-clockwise: the outward normal is the edge turned clockwise
    normal = sign * np.stack([edge[:, 1], -edge[:, 0]], axis=1)
    out = []
    for k in range(len(p)):
        n1, n2 = normal[k - 1], normal[k]  # the edges before and after vertex k
        turn = float(np.arctan2(n1[0] * n2[1] - n1[1] * n2[0], np.dot(n1, n2)))  # from n1 to n2
        convex = turn * sign > 0
        steps = max(1, int(np.ceil(abs(turn) / (0.5 * np.pi) - 1e-12))) if convex else 1
        radius = distance / np.cos(0.5 * turn / steps)
        for i in range(steps):  # the tangent lines at n1, ..., n2 meet at these angles
            angle = (i + 0.5) * turn / steps
            c, s = np.cos(angle), np.sin(angle)
            out.append(p[k] + radius * np.array([c * n1[0] - s * n1[1], s * n1[0] + c * n1[1]]))
    return np.asarray(out)


def _cell_cosines(nodes, columns) -> np.ndarray:
    """``(n - 1, m - 1)`` cosine of the angle between warp and weft in each mounted cell of a panel."""
    p = nodes[:, columns]
    s = 0.5 * (p[1:, :-1] - p[:-1, :-1] + p[1:, 1:] - p[:-1, 1:])
    c = 0.5 * (p[:-1, 1:] - p[:-1, :-1] + p[1:, 1:] - p[1:, :-1])
    return np.sum(s * c, axis=-1) / (np.linalg.norm(s, axis=-1) * np.linalg.norm(c, axis=-1))


def mounted_skin(scene, parameters) -> np.ndarray:
    """``(n_span, n_contour, 3)`` the mounted skin of a bay (`forces.mounted_nodes`), m."""
    # (imported here, not at the top: the report's JAX-free workers import this module, app.cut_files)
    import jax

    from forward_solver.programs import mounted_compiled

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
    from .rib_design import cut_lengths  # (here: app.cut_files's JAX-free workers import this module)

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
        c, s = _edges(flat)
        error = float(max(np.max(np.abs(c - contour_cut)), np.max(np.abs(s - span_cut))))
        panels.append(Panel(bay=bay, name=name, columns=columns, flat=flat, contour_cut=contour_cut,
                            span_cut=span_cut, leading_edge=le, length_error=error))
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
    # (imported here: app.cut_files's JAX-free workers import this module)
    from forward_solver.model.rib_shape import bernstein_basis, class_function

    if not chordal_error > 0:
        raise ValueError(f"chordal_error must be a positive length in metres, got {chordal_error!r}")
    coefficients = None if shape is None else np.asarray(shape, np.float64).reshape(-1)
    t_le = section.leading_edge_parameter

    def mounted(t: np.ndarray) -> np.ndarray:
        x0, z0 = section.contour_points(t).T
        station = np.clip(x0, 0.0, 1.0)
        camber = np.asarray(section.camber(station))  # as `forward_solver.model.bay` takes it at the nodes
        z = camber + thickness_scale * (z0 - camber)
        if coefficients is not None and coefficients.size:
            k = coefficients.size // 2
            basis = np.asarray(class_function(station))[:, None] * np.asarray(bernstein_basis(station, k))
            upper = t <= t_le
            z = z + np.where(upper, basis @ coefficients[:k], -(basis @ coefficients[k:]))
        return np.column_stack([x0 * chord_scale, z]) * chord

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
