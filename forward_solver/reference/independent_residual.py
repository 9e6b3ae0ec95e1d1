"""An independent check of equilibrium: a plain numpy residual, cell by cell, from the paper.

Written from eq. (10), (12)-(15) with ``np.add.at``, sharing no code with
`forward_solver.forces`: every cell computes its own edge vectors, averaged
stretches, tensions, the forces its fibres carry along its four edges, and
the pressure on its four quarter-cells. If the JAX kernel and this disagree,
one of them is wrong. Slow (a Python loop over cells): for small grids, in
the tests (`tests/solver/test_independent_residual.py`) and the validation report
(`benchmarks/validation_report.py`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["numpy_relative_residual", "numpy_residual"]


def numpy_residual(bay, fabric, nodes, pressure, prestrain, tension_only=True):
    """Static nodal force (N) of fabric tension and pressure, zero on held nodes.

    Args:
        bay: a `forward_solver.Bay` (its mounted nodes and held nodes).
        fabric: a `forward_solver.Fabric` (stiffnesses and Poisson coupling).
        nodes: ``(n_span, n_contour, 3)`` positions, m.
        pressure: Pa.
        prestrain: ``(span, chord)``.
        tension_only: clamp negative fibre tensions to zero (wrinkling).

    Returns:
        ``(n_span, n_contour, 3)`` forces in N.
    """
    ps, pc = prestrain
    e1, e2, nu = fabric.stiffness_span, fabric.stiffness_chord, fabric.poisson
    x0 = np.asarray(bay.nominal_nodes(), dtype=np.float64)
    x = np.asarray(nodes, dtype=np.float64)
    ns, nc = bay.shape
    n_cells = nc if bay.periodic else nc - 1
    force = np.zeros_like(x)
    for i in range(ns - 1):
        for j in range(n_cells):
            jn = (j + 1) % nc
            corners = [(i, j), (i + 1, j), (i + 1, jn), (i, jn)]  # n00, n10, n11, n01
            p = [x[c] for c in corners]
            q = [x0[c] for c in corners]
            # Span edges of the cell: (n00 -> n10) and (n01 -> n11); contour: (n00 -> n01), (n10 -> n11).
            span_edges = [(0, 1), (3, 2)]
            contour_edges = [(0, 3), (1, 2)]
            cut1 = [np.linalg.norm(q[b] - q[a]) / (1 + ps) for a, b in span_edges]
            cut2 = [np.linalg.norm(q[b] - q[a]) / (1 + pc) for a, b in contour_edges]
            len1 = [np.linalg.norm(p[b] - p[a]) for a, b in span_edges]
            len2 = [np.linalg.norm(p[b] - p[a]) for a, b in contour_edges]
            lam1 = 0.5 * (len1[0] / cut1[0] + len1[1] / cut1[1])  # eq. (12)
            lam2 = 0.5 * (len2[0] / cut2[0] + len2[1] / cut2[1])
            t11 = (e1 * (lam1 - 1) + nu * e2 * (lam2 - 1)) / (1 - nu**2)  # eq. (10)
            t22 = (e2 * (lam2 - 1) + nu * e1 * (lam1 - 1)) / (1 - nu**2)
            if tension_only:
                t11, t22 = max(t11, 0.0), max(t22, 0.0)
            h1 = 0.5 * (cut1[0] + cut1[1])
            h2 = 0.5 * (cut2[0] + cut2[1])
            # {T11 lambda2} h2 across the cell, half along each span edge (eq. 14), on the
            # edge's current direction (eq. 13); likewise the contour fibres.
            for (a, b), length in zip(span_edges, len1):
                f = 0.5 * t11 * lam2 * h2 * (p[b] - p[a]) / length
                np.add.at(force, corners[a], f)
                np.add.at(force, corners[b], -f)
            for (a, b), length in zip(contour_edges, len2):
                f = 0.5 * t22 * lam1 * h1 * (p[b] - p[a]) / length
                np.add.at(force, corners[a], f)
                np.add.at(force, corners[b], -f)
            # Eq. (15): the two triangles (node, edge midpoint, cell centre) of each corner.
            centre = sum(p) / 4
            for k in range(4):
                node = p[k]
                after = 0.5 * (node + p[(k + 1) % 4])  # midpoint towards the next corner
                before = 0.5 * (node + p[(k - 1) % 4])
                area = 0.5 * np.cross(after - node, centre - node) + 0.5 * np.cross(centre - node, before - node)
                np.add.at(force, corners[k], pressure * area)
    force[bay.fixed] = 0.0
    return force


def numpy_relative_residual(bay, fabric, nodes, pressure, prestrain, tension_only=True) -> float:
    """``||R_free||_2 / (p A)`` of `numpy_residual`, A the bay's nominal skin area."""
    r = numpy_residual(bay, fabric, nodes, pressure, prestrain, tension_only)
    return float(np.linalg.norm(r) / (pressure * bay.skin_area()))
