"""Returned equilibria satisfy an independent residual (`forward_solver.reference.independent_residual`).

The reference is a plain numpy residual written from the paper (eq. 10, 12-15)
cell by cell, sharing no code with `forward_solver.forces`; the validation
report (`benchmarks/validation_report.py`) uses the same function.
"""

import numpy as np
import pytest

from forward_solver import Bay, Fabric, Scene, solve_equilibrium
from forward_solver.reference.independent_residual import numpy_residual
from targets import naca


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
