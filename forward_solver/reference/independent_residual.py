"""An independent check of equilibrium: a plain numpy residual, cell by cell, from the paper.

Written from eq. (10), (12)-(15) with ``np.add.at``, sharing no code with
`forward_solver.forces`: every cell computes its own edge vectors, averaged
stretches, tensions, the forces its fibres carry along its four edges, and
the pressure on its four quarter-cells. A fabric with a fitted law takes its
tensions from the law's surface (`model.biaxial`, in NumPy) in the wing's
directions, scaled by the stiffnesses; a shear stiffness adds each cell's
``T12`` forces from the derivative of its angle, written out by hand (the
kernel differentiates the shear energy with JAX). If the JAX kernel and this
disagree, one of them is wrong. Slow (a Python loop over cells): for small grids, in
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
        fabric: a `forward_solver.Fabric` (its law, stiffnesses, Poisson coupling and shear stiffness).
        nodes: ``(n_span, n_contour, 3)`` positions, m.
        pressure: Pa.
        prestrain: ``(span, chord)``.
        tension_only: clamp negative fibre tensions to zero (wrinkling).

    Returns:
        ``(n_span, n_contour, 3)`` forces in N.
    """
    ps, pc = prestrain
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
            t11, t22 = _tensions(fabric, lam1 - 1, lam2 - 1)
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
            if fabric.shear_stiffness:
                for k, f in enumerate(_shear_forces(p, q, fabric.shear_stiffness, h1 * h2)):
                    np.add.at(force, corners[k], f)
    force[bay.fixed] = 0.0
    return force


def _tensions(fabric, e1: float, e2: float) -> tuple:
    """``(T11, T22)`` of a cell's span and chord strains: eq. (10), or the fabric's fitted law."""
    if fabric.law is None:
        e_span, e_chord, nu = fabric.stiffness_span, fabric.stiffness_chord, fabric.poisson
        return ((e_span * e1 + nu * e_chord * e2) / (1 - nu**2),  # eq. (10)
                (e_chord * e2 + nu * e_span * e1) / (1 - nu**2))
    warp_along_span = fabric.warp == "span"
    t_warp, t_weft = fabric.law.tensions(*((e1, e2) if warp_along_span else (e2, e1)))
    t_span, t_chord = (t_warp, t_weft) if warp_along_span else (t_weft, t_warp)
    nominal = fabric.law.stiffness_warp, fabric.law.stiffness_weft
    n_span, n_chord = nominal if warp_along_span else nominal[::-1]
    return float(t_span) * fabric.stiffness_span / n_span, float(t_chord) * fabric.stiffness_chord / n_chord


def _angle(a, b) -> float:
    return float(np.arctan2(np.linalg.norm(np.cross(a, b)), np.dot(a, b)))


def _shear_forces(p: list, q: list, stiffness: float, area: float) -> list:
    """The forces on a cell's corners (n00, n10, n11, n01) of its shear energy ``G gamma^2 A / 2``:
    ``gamma = phi0 - phi``, ``phi`` the angle between the mean span edge ``a`` and the mean contour edge
    ``b``; ``dphi/da = -(b^ - cos(phi) a^) / (|a| sin(phi))`` and likewise for ``b``, and each corner moves
    ``a`` and ``b`` by half its displacement, with the signs of ``a = (n10 - n00 + n11 - n01) / 2`` and
    ``b = (n01 - n00 + n11 - n10) / 2``."""
    a = 0.5 * (p[1] - p[0] + p[2] - p[3])
    b = 0.5 * (p[3] - p[0] + p[2] - p[1])
    phi = _angle(a, b)
    gamma = _angle(0.5 * (q[1] - q[0] + q[2] - q[3]), 0.5 * (q[3] - q[0] + q[2] - q[1])) - phi
    ua, ub = a / np.linalg.norm(a), b / np.linalg.norm(b)
    dphi_da = -(ub - np.cos(phi) * ua) / (np.linalg.norm(a) * np.sin(phi))
    dphi_db = -(ua - np.cos(phi) * ub) / (np.linalg.norm(b) * np.sin(phi))
    t12 = stiffness * gamma  # T12 = G gamma; F = -dE/dx = G gamma A dphi/dx
    signs_a, signs_b = (-0.5, 0.5, 0.5, -0.5), (-0.5, -0.5, 0.5, 0.5)
    return [t12 * area * (sa * dphi_da + sb * dphi_db) for sa, sb in zip(signs_a, signs_b)]


def numpy_relative_residual(bay, fabric, nodes, pressure, prestrain, tension_only=True) -> float:
    """``||R_free||_2 / (p A)`` of `numpy_residual`, A the bay's nominal skin area."""
    r = numpy_residual(bay, fabric, nodes, pressure, prestrain, tension_only)
    return float(np.linalg.norm(r) / (pressure * bay.skin_area()))
