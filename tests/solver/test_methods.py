"""Choices are values: the methods, adjoints and strategies are frozen dataclasses, the strings name defaults.

A 5x32 default bay (the grid of the command's tests, compiled once per run).
"""

import pickle

import numpy as np
import pytest

from forward_solver import (Auto, Batch, Bay, Explicit, ImplicitAdjoint, Loop, Newton, Parameters, Relax, RelaxNewton,
                            UnrolledAdjoint, solve_bays, solve_equilibrium)
from forward_solver.derivatives.custom_jvp import as_adjoint
from forward_solver.model.bay import N_CONTOUR
from forward_solver.solve import METHODS, as_method
from forward_solver.solvers.bays import as_strategy
from support.solver import default_scene
from targets import naca

THETA = Parameters(2e4, 0.005, 0.005)


@pytest.fixture(scope="module")
def scene():
    return default_scene(5, 32)


def test_a_shortcut_is_its_default_value(scene):
    assert METHODS == {"relax": Relax(), "newton": Newton(), "relax+newton": RelaxNewton(),
                       "explicit": Explicit(), "auto": Auto()}
    by_name = solve_equilibrium(scene, THETA, method="relax+newton")
    by_value = solve_equilibrium(scene, THETA, method=RelaxNewton())
    np.testing.assert_array_equal(by_name.nodes, by_value.nodes)
    assert by_value.method == "relax+newton" and by_value.steps == by_name.steps
    assert as_adjoint("implicit") == ImplicitAdjoint() and as_adjoint("unrolled") == UnrolledAdjoint()
    assert as_strategy("loop") == Loop() and as_strategy("batch") == Batch()
    with pytest.raises(ValueError, match="method must be one of"):
        as_method("fast")


def test_knobs_are_set_where_the_method_has_them():
    assert as_method("auto", sequencing=False) == Auto(sequencing=False)
    assert as_method("relax", sequencing=False) == Relax(sequencing=False)
    assert as_method("newton", sequencing=False) == Newton()  # no grid sequencing to turn off
    assert as_method(Relax(symmetry=False)) == Relax(symmetry=False)
    with pytest.raises(ValueError, match="max_iterations must be a positive integer"):
        Newton(max_iterations=0)


def test_the_keywords_that_moved_name_their_new_place(scene):
    for name, value, place in (("sequencing", False, r"method=Relax\(sequencing=...\)"),
                               ("symmetry", False, r"method=Relax\(symmetry=...\)"),
                               ("precision", "float32", r"method=Relax\(precision=...\)"),
                               ("linear_solver", "lu", r"adjoint=ImplicitAdjoint\(linear_solver=...\)"),
                               ("stiffness", (2e5, 2e5), "give it in the Parameters")):
        with pytest.raises(TypeError, match=place):
            solve_equilibrium(scene, THETA, **{name: value})
    with pytest.raises(TypeError, match="unexpected keyword argument 'sequence'"):
        solve_equilibrium(scene, THETA, sequence=False)
    with pytest.raises(TypeError, match="give it in the Parameters"):
        solve_bays([scene], THETA, rib_chord_scale=0.9)


def test_the_lu_factor_stays_in_this_process(scene):
    sol = solve_equilibrium(scene, THETA, method="relax+newton")
    assert sol.factor is not None
    assert sol.without_factor().factor is None and sol.without_factor().nodes is sol.nodes
    copy = pickle.loads(pickle.dumps(sol))
    assert copy.factor is None and sol.factor is not None
    np.testing.assert_array_equal(copy.nodes, sol.nodes)
    wing = solve_bays([scene, scene], THETA, method="relax+newton")
    assert all(s.factor is None for s in wing.without_factors().solutions)
    assert all(s.factor is not None for s in wing.solutions)


def test_one_default_grid_and_one_divergence_bound():
    bay = Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.3, n_span=5, tip_chord=0.8)
    assert bay.n_contour == N_CONTOUR == 64  # the command's
    assert bay.divergence_bound == pytest.approx(0.9 + 0.3)
