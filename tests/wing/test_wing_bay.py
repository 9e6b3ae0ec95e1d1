"""A tapered bay: the skin between two different ribs."""

import numpy as np

from forward_solver import Bay, Fabric, Scene, solve_equilibrium
from targets import naca


def test_tapered_bay_solves_between_different_ribs():
    root, tip = naca("2412"), naca("0012")
    bay = Bay.from_airfoil(root, chord=1.0, rib_spacing=0.25, n_span=9, n_contour=64,
                           tip_airfoil=tip, tip_chord=0.8)
    assert not bay.symmetric
    sol = solve_equilibrium(Scene(bay, Fabric()), 2e4, 0.005, rtol=1e-8)
    np.testing.assert_allclose(sol.nodes[0], np.asarray(bay.nominal_nodes())[0])
    np.testing.assert_allclose(sol.nodes[-1, :, 0].max(), 0.8)  # tip rib keeps its chord
    assert sol.section(0.0).shape == (64, 2)
