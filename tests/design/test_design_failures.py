"""Inverse design when a forward solve fails mid-way: a DesignResult that says so, no NaN."""

import numpy as np
import pytest

from forward_solver import Bay, ConvergenceError, Fabric, Scene
from inverse_design import optimise_pressure
from inverse_design.methods import Root
from inverse_design.settings import Limits
from targets import naca

START = {"pressure": 1e4, "prestrain_span": 0.005, "prestrain_chord": 0.005}


@pytest.fixture(scope="module")
def soft_scene():
    # 1e4 N/m fabric on the 9x32 NACA 2412 bay: equilibria up to 1.6e5 Pa, none inside the
    # divergence bound at 3.2e5 Pa (the relaxation stops there as diverged).
    bay = Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=9, n_contour=32)
    return Scene(bay, Fabric(stiffness_span=1e4, stiffness_chord=1e4))


def test_a_failed_forward_solve_stops_the_design_and_says_so(soft_scene):
    # Ribs equal to the target: the mean offset stays positive at every pressure, so the
    # bracketing of method="root" doubles the pressure towards its 1e6 Pa bound and meets a
    # pressure the fabric cannot hold. The result is the best iterate that solved.
    res = optimise_pressure(soft_scene, naca("2412"), ("pressure",), initial=START,
                            bounds={"pressure": (1e4, 1e6)}, method=Root(condition="mean_offset"),
                            limits=Limits(tension=None), objective="mid_bay")
    assert not res.success
    assert "forward solve at pressure" in res.message and "diverged" in res.message
    assert res.solution.converged and np.isfinite(res.solution.nodes).all()
    assert np.isfinite([res.pressure, res.rms_error, res.max_error]).all()
    assert res.pressure == pytest.approx(1e4)  # the smallest offset of the solved iterates
    assert all(h["values"]["pressure"] < 3.2e5 for h in res.history)


def test_a_failed_start_raises(soft_scene):
    # Nothing to return when the starting point itself has no equilibrium.
    with pytest.raises(ConvergenceError, match="diverged"):
        optimise_pressure(soft_scene, naca("2412"), ("pressure",), initial={**START, "pressure": 5e5},
                          bounds={"pressure": (1e4, 1e6)}, method="least_squares", limits=Limits(tension=None),
                          objective="mid_bay")
