"""An independent check of equilibrium: a plain numpy residual evaluated on returned shapes.

The reference below is written from the paper (eq. 10, 12-15) cell by cell with
``np.add.at``, sharing no code with `forward_solver.forces`: every cell computes
its own edge vectors, averaged stretches, tensions, the forces its fibres carry
along its four edges, and the pressure on its four quarter-cells. If the JAX
kernel and this disagree, one of them is wrong.
"""

import numpy as np
import pytest

from forward_solver import Bay, Fabric, Scene, solve_equilibrium
from targets import naca


def numpy_residual(bay: Bay, fabric: Fabric, nodes, pressure, prestrain, tension_only=True):
    """Static nodal force (N) of fabric tension and pressure, zero on held nodes."""
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


@pytest.mark.parametrize(
    "make_bay, pressure, prestrain",
    [
        (lambda: Bay.flat_panel(width=0.25, length=1.0, n_span=7, n_contour=21), 2e4, (0.005, 0.005)),
        (lambda: Bay.from_airfoil(naca("2412"), 1.0, 0.25, n_span=7, n_contour=32), 2e4, (0.005, 0.005)),
        (lambda: Bay.from_airfoil(naca("4415"), 0.8, 0.3, n_span=7, n_contour=32), 5e3, (0.01, -0.002)),
    ],
)
def test_returned_equilibrium_satisfies_an_independent_residual(make_bay, pressure, prestrain):
    # Tolerance: the JAX solve stops at ||R|| / (p A) <= 1e-10; the numpy residual of the
    # same law on the returned shape must agree to that level (plus round-off, 1e-12).
    bay = make_bay()
    fabric = Fabric(stiffness_span=2e5, stiffness_chord=1.5e5, poisson=0.3)
    sol = solve_equilibrium(Scene(bay, fabric), pressure, prestrain, rtol=1e-10)
    r = numpy_residual(bay, fabric, sol.nodes, pressure, prestrain)
    relative = np.linalg.norm(r) / (pressure * bay.skin_area())
    assert relative < 1e-10 + 1e-12
    # And it is a real check: the mounted shape is far from equilibrium for both codes.
    mounted = numpy_residual(bay, fabric, bay.nominal_nodes(), pressure, prestrain)
    assert np.linalg.norm(mounted) / (pressure * bay.skin_area()) > 1e-3
