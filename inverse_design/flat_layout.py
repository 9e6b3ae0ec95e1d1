"""A bay's panels laid flat from their cut lengths, and their outlines: geometry alone, no solver.

`develop` lays a grid of quads flat so that every edge has its cut length
(paper eq. 12's reference lengths; the exact and the chosen parts are in
`flat_panels`' docstring); `panel_outline` is the sewing outline of a laid
panel and `offset_outline` its cut line, the outline offset outward by the
seam allowance. A `Panel` holds one laid panel. NumPy and SciPy only: the
report's workers, which draw the panels (`inverse_design.app.cut_files`),
import this module without JAX.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

__all__ = ["LAYOUT_TOLERANCE", "Panel", "develop", "edge_lengths", "layout_faults", "offset_outline", "panel_outline"]

#: Largest edge-length error accepted by `develop`, as a fraction of the edge's cut length.
LAYOUT_TOLERANCE = 1e-9
#: m: an exact layout whose largest edge error is below this has reached float64's rounding (edges of
#: centimetres to metres, sums of hundreds of them); a step that does not improve it ends the layout.
_ROUNDING_FLOOR = 1e-12


@dataclass(frozen=True)
class Panel:
    """One flat panel of a bay.

    Attributes:
        bay: the bay's index.
        name: "upper", "lower" or "panel".
        columns: ``(m,)`` contour node index ``j`` of each panel column (left to right).
        flat: ``(n_span, m, 2)`` the developed grid, metres (x across, y along the span from the root
            rib), as its outside face is seen (`flat_panels.bay_panels`: the contour along -x). A
            wing's bay ``k`` lies between ribs ``k`` (root, row 0) and ``k + 1`` (tip, the last row).
        contour_cut: ``(n_span, m - 1)`` the cut length of each contour edge, m.
        span_cut: ``(n_span - 1, m)`` the cut length of each span edge, m.
        leading_edge: the panel column of the leading edge, or None.
        length_error: largest ``|flat edge length - cut length|`` over the panel's edges, m.
        warp: where the fabric's warp (the roll's length) runs: "span" (along y, the span fibres) or
            "chord" (along the contour rows); the drawing's WARP arrow follows it.
    """

    bay: int
    name: str
    columns: np.ndarray
    flat: np.ndarray
    contour_cut: np.ndarray
    span_cut: np.ndarray
    leading_edge: int | None
    length_error: float
    warp: str = "span"


def edge_lengths(flat):
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
            error above `LAYOUT_TOLERANCE` of its edge), or only by a layout
            that lies over itself (`layout_faults`: a mirrored cell, a crossing
            of the outline), which no fabric can be cut to.
    """
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
    n_cells = c00.size

    # first guess: each row laid straight along x, centred on the first row; rows stacked
    # along y by the mean span cut
    arc = np.concatenate([np.zeros((n, 1)), np.cumsum(contour_cut, axis=1)], axis=1)
    x0 = arc - 0.5 * (arc[:, -1:] - arc[:1, -1:])
    y0 = np.concatenate([np.zeros((1, m)), np.cumsum(span_cut, axis=0)]).mean(axis=1, keepdims=True)
    start = np.empty((n * m, 2))
    start[index] = np.stack([x0, np.broadcast_to(y0, (n, m))], axis=-1)
    start = start.ravel()

    cells = (c00, c10, c11, c01)
    edge_columns = np.stack([2 * b, 2 * b + 1, 2 * a, 2 * a + 1], axis=1)
    cell_columns = np.concatenate([np.stack([2 * c, 2 * c + 1], axis=1) for c in cells], axis=1)

    def evaluate(z, weight):
        """The residuals at ``z`` and the Jacobian's non-zeros of each row (in ``edge_columns``,
        ``cell_columns``)."""
        p = z.reshape(-1, 2)
        d = p[b] - p[a]
        length = np.linalg.norm(d, axis=1)
        r = [(length - h) / h]
        u = d / (length * h)[:, None]
        values = [np.concatenate([u, -u], axis=1)]
        if weight:
            s = 0.5 * (p[c10] - p[c00] + p[c11] - p[c01])  # the cell's warp
            c = 0.5 * (p[c01] - p[c00] + p[c11] - p[c10])  # its weft
            ls, lc = np.linalg.norm(s, axis=1), np.linalg.norm(c, axis=1)
            cos = np.sum(s * c, axis=1) / (ls * lc)
            r.append(weight * (cos - cos_angle.ravel()))
            ds = weight * ((c / lc[:, None]) - cos[:, None] * s / ls[:, None]) / ls[:, None]
            dc = weight * ((s / ls[:, None]) - cos[:, None] * c / lc[:, None]) / lc[:, None]
            # d s / d corner: c10, c11 +1/2; c00, c01 -1/2.  d c / d corner: c01, c11 +1/2; c00, c10 -1/2
            values.append(np.concatenate([fs * ds + fc * dc for fs, fc in
                                          ((-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5))], axis=1))
        return np.concatenate(r), values

    z = start
    for weight in (shear_weight, 0.0):
        normal = _NormalEquations([edge_columns, cell_columns] if weight else [edge_columns], 2 * n * m)
        z = _levenberg_marquardt(partial(evaluate, weight=weight), normal, z, exact=weight == 0.0)
    flat = z.reshape(-1, 2)[index]
    contour, span = edge_lengths(flat)
    error = max(np.max(np.abs(contour - contour_cut) / contour_cut), np.max(np.abs(span - span_cut) / span_cut))
    if not error <= LAYOUT_TOLERANCE:
        raise ValueError(f"the cut lengths cannot be laid flat: an edge is off by {error:.3g} of its length "
                         f"(above {LAYOUT_TOLERANCE:g})")
    folded, crossings = layout_faults(flat)
    if folded or crossings:
        raise ValueError("the cut lengths cannot be laid flat without the panel lying over itself: the layout "
                         f"that meets every edge length has {folded} of {n_cells} cells mirrored and {crossings} "
                         "crossings of its outline")
    # place: first node at the origin, the first row's chord along +x, the span along +y
    flat = flat - flat[0, 0]
    direction = flat[0, -1] / np.linalg.norm(flat[0, -1])
    rotation = np.array([[direction[0], direction[1]], [-direction[1], direction[0]]])
    flat = flat @ rotation.T
    if np.mean(flat[-1, :, 1]) < 0:  # the span the other way: mirror
        flat[..., 1] *= -1
    return flat


def layout_faults(flat) -> tuple[int, int]:
    """``(folded, crossings)`` of a laid grid ``(n, m, 2)``: the cells mirrored against the most (their signed
    area of the other sign), and the pairs of its outline's edges (`panel_outline`) that cross. A panel
    that can be cut has neither: edge lengths alone are also met by a layout folded over itself (a bay
    whose ribs are a millimetre apart and whose chords differ: its panel turns through hundreds of radians)."""
    a, b, c, d = flat[:-1, :-1], flat[1:, :-1], flat[1:, 1:], flat[:-1, 1:]
    area = (c - a)[..., 0] * (d - b)[..., 1] - (c - a)[..., 1] * (d - b)[..., 0]
    folded = int(min(np.sum(area > 0), np.sum(area < 0)))
    p, _ = panel_outline(flat)
    q = np.roll(p, -1, axis=0)  # edge k from p[k] to q[k]

    def side(o, u, v):  # the sign of the turn o -> u -> v, for every pair of edges
        return np.sign((u[..., 0] - o[..., 0]) * (v[..., 1] - o[..., 1])
                       - (u[..., 1] - o[..., 1]) * (v[..., 0] - o[..., 0]))

    i, j = np.triu_indices(len(p), k=2)
    keep = ~((i == 0) & (j == len(p) - 1))  # (the last edge meets the first)
    i, j = i[keep], j[keep]
    cross = ((side(p[i], q[i], p[j]) * side(p[i], q[i], q[j]) < 0)
             & (side(p[j], q[j], p[i]) * side(p[j], q[j], q[i]) < 0))
    return folded, int(np.sum(cross))


def _levenberg_marquardt(evaluate, normal, z, exact: bool, max_iterations: int = 200) -> np.ndarray:
    """Minimise ``|r(z)|^2`` by damped Gauss-Newton steps on the banded normal equations.

    ``evaluate(z)`` gives the residuals ``r`` and the Jacobian's non-zeros of
    each row, ``normal`` (a `_NormalEquations`) assembles ``J^T J`` and
    ``-J^T r`` from them. The damping also fixes the directions the residuals
    leave free (the panel's position and, without the angle terms, its
    shear): each step is the smallest that reduces the residual, so the
    layout stays near where it started. ``exact``: stop when every residual
    is below 1e-14 (the edges laid at their lengths), or below
    `_ROUNDING_FLOOR` when a step no longer improves it; otherwise when every
    residual is below `_ROUNDING_FLOOR` (a mounted skin's own cell angles are
    met to rounding too: the pass took some sixty more steps shuffling it
    below 2e-14, nine tenths of a 40-cell wing's panels' time, and the
    layout moved by 1e-14 m) or a step lowers the cost by less than 1e-10 of
    itself (the layout then moves by about 1e-14 m: bay 11 of
    ``wing_40_cells.toml``, against 1e-14 relative).
    """
    r, values = evaluate(z)
    cost = float(r @ r)
    damping = 1e-6
    system = None
    for iteration in range(max_iterations):
        if np.max(np.abs(r)) < (1e-14 if exact else _ROUNDING_FLOOR):
            break
        if system is None:  # (at a new iterate; a rejected step keeps it and changes the damping alone)
            system = normal(values, r)
        step = _normal_step(*system, damping)
        if step is None or not np.all(np.isfinite(step)):
            if exact and np.max(np.abs(r)) < _ROUNDING_FLOOR:
                break
            damping *= 8.0
            if damping > 1e12:
                break
            continue
        trial = z + step
        r_trial, values_trial = evaluate(trial)
        cost_trial = float(r_trial @ r_trial)
        if cost_trial < cost:
            converged = not exact and cost - cost_trial <= 1e-10 * max(cost, 1e-30)
            z, r, values, cost, system = trial, r_trial, values_trial, cost_trial, None
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


class _NormalEquations:
    """``J^T J`` in LAPACK's upper banded storage and ``-J^T r``, summed straight from the Jacobian's
    non-zeros: each residual row's entries lie in fixed columns (a block of rows per kind: an edge's
    4, a cell's 8), so every product ``J_ri J_rj`` has a fixed place in the band, found once per
    layout; no sparse matrix is built, multiplied or converted at each iteration (which took most of
    a panel's layout: 1.6 ms an iteration on a 17x33 panel)."""

    def __init__(self, columns, size: int):
        self.size = size
        self.columns = [np.asarray(c) for c in columns]
        self.pairs = [np.triu_indices(c.shape[1]) for c in self.columns]  # (s <= t) within a row's entries
        lo, hi = [], []
        for c, (s, t) in zip(self.columns, self.pairs):
            lo.append(np.minimum(c[:, s], c[:, t]).ravel())
            hi.append(np.maximum(c[:, s], c[:, t]).ravel())
        lo, hi = np.concatenate(lo), np.concatenate(hi)
        self.width = int(np.max(hi - lo, initial=0))
        self.place = (self.width + lo - hi) * size + hi  # (row, col) -> banded[width + row - col, col]
        self.flat_columns = np.concatenate([c.ravel() for c in self.columns])

    def __call__(self, values, r):
        """``(banded J^T J, -J^T r)`` for the rows' non-zeros ``values`` (one array per block) and residuals."""
        products = np.concatenate([(v[:, s] * v[:, t]).ravel() for v, (s, t) in zip(values, self.pairs)])
        banded = np.bincount(self.place, weights=products, minlength=(self.width + 1) * self.size)
        rows = np.split(r, np.cumsum([v.shape[0] for v in values])[:-1])
        rhs = np.bincount(self.flat_columns, weights=-np.concatenate([(v * q[:, None]).ravel()
                                                                      for v, q in zip(values, rows)]),
                          minlength=self.size)
        return banded.reshape(self.width + 1, self.size), rhs


def _normal_step(banded, rhs, damping: float):
    """``(N + damping I)^-1 rhs`` for the symmetric banded normal matrix ``N`` (LAPACK's upper banded
    storage, `_NormalEquations`), by a banded Cholesky factorisation (LAPACK ``pbsv``; a 17x33 panel:
    half-width 37, 0.3 ms against 2.4 ms of a general sparse LU); None where rounding leaves it not
    positive definite: the residuals leave the panel's position (and, without the angle terms, its
    shear) free, so a damping lost in rounding leaves it singular, and the step is rejected."""
    from scipy.linalg import LinAlgError, solveh_banded

    damped = banded.copy()
    damped[-1] += damping
    try:
        return solveh_banded(damped, rhs, overwrite_ab=True, check_finite=False)
    except LinAlgError:
        return None


def panel_outline(flat) -> tuple[np.ndarray, np.ndarray]:
    """The sewing outline of a flat panel: ``(points (p, 2), grid (p, 2) [i, k] of each point)``.

    From the root rib's first node: along the root rib row (``i = 0``), up
    the last column, back along the tip rib row, down the first column (the
    closing edge back to the start is implied); clockwise on a panel seen
    from outside (`Panel.flat`), counter-clockwise on one laid by `develop`.
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
