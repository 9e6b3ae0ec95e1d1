"""float32: an opt-in precision of the explicit solvers, used only where it meets the tolerance.

The rule (`forward_solver.precision`): the iteration runs in float32, the
stop test and the returned `Solution` in float64; an ``rtol`` below the
scene's float32 rounding floor is refused with a ValueError; Newton stays
float64. One 9x33 panel is shared by every test (JAX compilation dominates).
"""

import jax
import numpy as np
import pytest

from forward_solver import (
    Bay,
    Fabric,
    PressureRamp,
    Relax,
    Result,
    Scene,
    forces,
    simulate,
    solve_equilibrium,
)
from forward_solver.solve import float32_residual_floor
from forward_solver.model.parameters import as_parameters

PRESSURE = 2e4
PRESTRAIN = (0.005, 0.005)
FLOAT32 = Relax(precision="float32")


@pytest.fixture(scope="module")
def scene():
    return Scene(Bay.flat_panel(width=0.25, length=1.0, n_span=9, n_contour=33), Fabric())


@pytest.fixture(scope="module")
def reference(scene):
    return solve_equilibrium(scene, PRESSURE, PRESTRAIN, rtol=1e-11)


@pytest.fixture(scope="module")
def floor(scene):
    return float32_residual_floor(scene, PRESSURE, PRESTRAIN)


def _float64_residual(scene, nodes):
    """||R_free|| / (p A) of ``nodes``, evaluated here in float64, outside the solver."""
    with jax.enable_x64(True):
        params = scene.params(as_parameters(PRESSURE, PRESTRAIN))
        physics = scene.physics(dynamic=False)
        ref = forces.prepare(scene.bay.geometry(), params, physics)
        return float(forces.relative_residual(jax.numpy.asarray(nodes), ref, params, physics))


def test_floor_scales_with_the_load_and_the_grid(scene, floor):
    # The estimate of forces.rounding_residual_floor: 1.1e-4 on this panel at 20 kPa; it
    # is inversely proportional to the pressure and grows on a finer grid.
    assert 5e-5 < floor < 5e-4
    assert float32_residual_floor(scene, PRESSURE / 10, PRESTRAIN) == pytest.approx(10 * floor, rel=1e-6)
    finer = Scene(Bay.flat_panel(width=0.25, length=1.0, n_span=17, n_contour=65), Fabric())
    assert float32_residual_floor(finer, PRESSURE, PRESTRAIN) > 1.5 * floor


def test_float32_meets_the_tolerance_it_accepts(scene, reference, floor):
    single = solve_equilibrium(scene, PRESSURE, PRESTRAIN, rtol=floor, method=FLOAT32)
    double = solve_equilibrium(scene, PRESSURE, PRESTRAIN, rtol=floor)
    assert single.converged and single.extra["precision"] == "float32"
    assert single.extra["float32_floor"] == pytest.approx(floor)
    # The Solution is float64 and its residual is the float64 residual of its own nodes.
    assert single.nodes.dtype == np.float64 and single.tension_chord.dtype == np.float64
    assert single.residual <= floor
    assert _float64_residual(scene, single.nodes) == pytest.approx(single.residual, rel=1e-9)
    # At a tolerance it accepts, float32 is as close to the equilibrium as float64 at that
    # tolerance (measured: 2.6e-6 m against 2.5e-6 m); the bound allows twice plus 1e-6 m.
    error32 = np.abs(single.nodes - reference.nodes).max()
    error64 = np.abs(double.nodes - reference.nodes).max()
    assert error32 <= 2 * error64 + 1e-6


def test_float32_refuses_a_tolerance_below_its_floor(scene, floor):
    with pytest.raises(ValueError, match="use precision='float64', or rtol >="):
        solve_equilibrium(scene, PRESSURE, PRESTRAIN, rtol=floor / 2, method=FLOAT32)
    with pytest.raises(ValueError, match="use precision='float64', or rtol >="):
        simulate(Scene(scene.bay, Fabric(viscosity=20.0)), PRESSURE, PRESTRAIN, rtol=floor / 2,
                 precision="float32")
    with pytest.raises(TypeError, match="need float64"):  # Newton has no precision; the keyword says where it is
        solve_equilibrium(scene, PRESSURE, PRESTRAIN, rtol=1e-3, method="newton", precision="float32")
    with pytest.raises(ValueError, match="precision must be one of"):
        Relax(precision="float16")


def test_float32_that_stops_short_says_so(scene, floor):
    # The step cap hits before the tolerance: the failure code, finite float64 nodes, and a
    # message that names float32's floor as one possible reason.
    sol = solve_equilibrium(scene, PRESSURE, PRESTRAIN, rtol=floor, max_steps=100, throw=False,
                            method=Relax(sequencing=False, precision="float32"))
    assert sol.result == Result.max_steps_reached
    assert np.isfinite(sol.nodes).all() and sol.residual > floor
    assert "float32" in sol.message and "precision='float64'" in sol.message


def test_float32_does_not_depend_on_the_callers_x64_setting(scene, floor):
    before = jax.config.jax_enable_x64
    with jax.enable_x64(False):
        off = solve_equilibrium(scene, PRESSURE, PRESTRAIN, rtol=floor, method=FLOAT32)
    with jax.enable_x64(True):
        on = solve_equilibrium(scene, PRESSURE, PRESTRAIN, rtol=floor, method=FLOAT32)
    np.testing.assert_array_equal(off.nodes, on.nodes)
    assert off.residual == on.residual
    assert jax.config.jax_enable_x64 == before


def test_paper_scheme_in_float32_reaches_the_equilibrium(scene, reference, floor):
    # The physical-mass scheme (eq. 14-17) in float32, stop test in float64. At rtol 2 x floor
    # its shape is 5.0e-6 m from the equilibrium, as float64's at that rtol; bound 2e-5 m.
    dynamic = Scene(scene.bay, Fabric(viscosity=20.0), aerodynamic_damping=0.02)
    sol = simulate(dynamic, PressureRamp(PRESSURE, 0.005), PRESTRAIN, rtol=2 * floor,
                   precision="float32", max_steps=100_000)
    assert sol.converged and sol.extra["precision"] == "float32"
    assert sol.residual <= 2 * floor and sol.nodes.dtype == np.float64
    assert np.abs(sol.nodes - reference.nodes).max() < 2e-5
