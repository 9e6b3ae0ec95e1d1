"""Equilibrium and dynamics of the bay against closed forms and invariances (docs/validation.md)."""

import jax
import numpy as np
import pytest

from forward_solver import (
    Bay,
    ConvergenceError,
    Fabric,
    PressureRamp,
    Relax,
    Result,
    Scene,
    simulate,
    solve_equilibrium,
)
from forward_solver.reference.closed_forms import strip_elongation, strip_sag
from forward_solver.solvers.relax import relax_jit

PRESSURE = 2e4
PRESTRAIN = (0.005, 0.005)


@pytest.fixture(scope="module")
def small_panel():
    return Bay.flat_panel(width=0.25, length=1.0, n_span=9, n_contour=33)


@pytest.fixture(scope="module")
def small_reference(small_panel):
    return solve_equilibrium(Scene(small_panel, Fabric()), PRESSURE, PRESTRAIN, rtol=1e-11)


def test_inflated_strip_matches_circular_arc():
    # Aspect ratio 8: the mid-section is far from the clamped ends, so plane strain holds.
    # Tolerance 1% of the sag (docs/validation.md); the grid gives ~0.1%.
    width, length = 0.25, 2.0
    bay = Bay.flat_panel(width=width, length=length, n_span=17, n_contour=129)
    fabric = Fabric()
    sol = solve_equilibrium(Scene(bay, fabric), PRESSURE, PRESTRAIN, rtol=1e-10)
    mid = sol.nodes[:, 64]
    sag = mid[:, 2].max()
    # The closed form takes the strain along the strip as given. With zero shear stiffness
    # T22 is uniform along each strip line, and the bulged ends lengthen the line, so at
    # mid-length it is 0.0062, not the 0.005 prestrain: measure it on the grid.
    strain_chord = strip_elongation(sol.nodes, length, PRESTRAIN[1])
    assert abs(strain_chord - PRESTRAIN[1]) < 2e-3
    expected = strip_sag(width, PRESSURE, fabric.stiffness_span, fabric.stiffness_chord, fabric.poisson,
                         PRESTRAIN[0], strain_chord)
    assert abs(sag - expected) < 0.01 * expected
    # Circular arc: every mid-section node lies at the same distance from the arc's centre.
    radius = (width**2 / 4 + expected**2) / (2 * expected)
    centre = np.array([width / 2, expected - radius])
    dist = np.hypot(mid[:, 1] - centre[0], mid[:, 2] - centre[1])
    assert np.ptp(dist) < 0.01 * expected


def test_equilibrium_does_not_depend_on_mass_or_damping(small_panel, small_reference):
    # The paper's scheme with two different masses and damping mixes reaches the relaxation
    # shape. Tolerance: rtol 1e-9 on the residual bounds the shape error at ~1e-8 m.
    # Both need viscosity: aerodynamic damping (eq. 11) acts on normal velocity only and leaves
    # the in-plane modes ringing.
    for density, viscosity, aero in [(0.3, 20.0, 0.02), (1.2, 5.0, 0.2)]:
        scene = Scene(small_panel, Fabric(areal_density=density, viscosity=viscosity),
                      aerodynamic_damping=aero)
        sol = simulate(scene, PressureRamp(PRESSURE, 0.005), PRESTRAIN, rtol=1e-9, max_steps=300_000)
        assert sol.converged
        assert np.abs(sol.nodes - small_reference.nodes).max() < 1e-7
        hist = sol.history
        assert hist["time"][-1] > 0.005 and np.all(np.diff(hist["time"]) > 0)
        assert np.isclose(hist["pressure"][-1], PRESSURE, rtol=1e-3)


@pytest.mark.parametrize("courant", [0.25, 0.9])
def test_equilibrium_does_not_depend_on_the_time_step(small_panel, small_reference, courant):
    # Invariance: the Courant coefficient (eq. 16) sets the time step, 3.6x apart
    # here, not the rest state. Same tolerance and reason as above.
    scene = Scene(small_panel, Fabric(viscosity=20.0), aerodynamic_damping=0.02)
    sol = simulate(scene, PressureRamp(PRESSURE, 0.005), PRESTRAIN, courant=courant, rtol=1e-9,
                   max_steps=300_000)
    assert sol.converged
    assert np.abs(sol.nodes - small_reference.nodes).max() < 1e-7


@pytest.mark.parametrize("courant", [1.5, 3.0])
def test_courant_over_the_limit_fails_loudly(small_panel, courant):
    scene = Scene(small_panel, Fabric())
    sol = simulate(scene, PRESSURE, PRESTRAIN, courant=courant, max_steps=20_000, throw=False)
    assert sol.result in (Result.nonfinite, Result.diverged)
    assert np.isfinite(sol.nodes).all()  # stopped by the step guard, before overflow
    with pytest.raises(ConvergenceError, match="lower the Courant coefficient"):
        simulate(scene, PRESSURE, PRESTRAIN, courant=courant, max_steps=20_000)


@pytest.mark.parametrize("transform", [jax.jit, jax.grad])
def test_simulate_refuses_traced_values_before_it_compiles(small_panel, transform):
    # The explicit run is a host loop of top-level compiled chunks: inside a trace it says where to call it.
    scene = Scene(small_panel, Fabric())
    with pytest.raises(TypeError, match="outside jax.jit, jax.vmap and jax.grad"):
        transform(lambda p: simulate(scene, p, PRESTRAIN, max_steps=200).nodes.sum())(PRESSURE)


def test_over_the_limit_with_viscosity_rings_and_says_lower_the_courant(small_panel):
    # benchmarks/stability_map.py: at Courant 1.2 with viscosity the scheme neither blows up
    # nor comes to rest; it rings in its period-two mode at constant kinetic energy. The
    # message must point at the Courant coefficient, not at the step cap. At 0.9 the same
    # scene comes to rest (about 5000 steps).
    scene = Scene(small_panel, Fabric(viscosity=5.0), aerodynamic_damping=0.05)
    ring = simulate(scene, PressureRamp(PRESSURE, 0.002), PRESTRAIN, courant=1.2, max_steps=20_000,
                    throw=False)
    assert ring.result == Result.max_steps_reached and np.isfinite(ring.nodes).all()
    assert ring.extra["velocity_ratio"] < -0.9
    assert "lower the Courant coefficient" in ring.message
    calm = simulate(scene, PressureRamp(PRESSURE, 0.002), PRESTRAIN, courant=0.9, max_steps=20_000)
    assert calm.converged and calm.extra["velocity_ratio"] > 0


def test_no_viscosity_never_comes_to_rest_and_says_why(small_panel):
    # Aerodynamic damping (eq. 11) acts on the normal velocity only: without the fabric's
    # viscosity the in-plane modes ring on (a slow oscillation, velocity ratio near +1).
    scene = Scene(small_panel, Fabric(viscosity=0.0), aerodynamic_damping=0.05)
    sol = simulate(scene, PressureRamp(PRESSURE, 0.002), PRESTRAIN, courant=0.6, max_steps=20_000,
                   throw=False)
    assert sol.result == Result.max_steps_reached and sol.extra["velocity_ratio"] > 0.5
    assert "give it viscosity" in sol.message and "Courant" not in sol.message


def test_step_cap_returns_its_code(small_panel):
    sol = solve_equilibrium(Scene(small_panel, Fabric()), PRESSURE, PRESTRAIN, max_steps=100,
                            method=Relax(sequencing=False), throw=False)
    assert sol.result == Result.max_steps_reached and not sol.converged
    assert np.all(np.isfinite(sol.nodes)) and sol.residual > 1e-8
    with pytest.raises(ConvergenceError, match="max_steps"):
        solve_equilibrium(Scene(small_panel, Fabric()), PRESSURE, PRESTRAIN, max_steps=100,
                          method=Relax(sequencing=False))


def test_new_values_do_not_recompile(small_panel, small_reference):
    scene = Scene(small_panel, Fabric())
    solve_equilibrium(scene, PRESSURE, PRESTRAIN, method=Relax(sequencing=False))
    before = relax_jit._cache_size()
    sol = solve_equilibrium(scene, 1.3 * PRESSURE, (0.004, 0.007), method=Relax(sequencing=False))
    scene2 = Scene(small_panel, Fabric(stiffness_span=3e5, stiffness_chord=1e5, poisson=0.3))
    solve_equilibrium(scene2, PRESSURE, PRESTRAIN, method=Relax(sequencing=False))
    assert relax_jit._cache_size() == before
    assert sol.converged and np.abs(sol.nodes - small_reference.nodes).max() > 1e-4


def test_float64_without_touching_global_config(small_panel, small_reference):
    assert not jax.config.jax_enable_x64  # importing the package changed nothing
    assert small_reference.nodes.dtype == np.float64
    assert small_reference.extra["precision"] == "float64"
    assert not jax.config.jax_enable_x64  # and neither did solving
    # float32 has its own tests (tests/solver/test_precision.py).


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"pressure": -5.0}, "pressure must be a positive"),
        ({"pressure": float("nan")}, "pressure must be a positive"),
        ({"prestrain": (0.005, 2.0)}, "prestrain_chord"),
        ({"method": "magic"}, "method must be one of"),
        ({"rtol": 0.0}, "rtol"),
        ({"initial": np.zeros((3, 3, 3))}, "initial shape"),
    ],
)
def test_bad_input_says_what_to_change(small_panel, kwargs, message):
    args = {"pressure": PRESSURE, "prestrain": PRESTRAIN} | kwargs
    with pytest.raises(ValueError, match=message):
        solve_equilibrium(Scene(small_panel, Fabric()), **args)


@pytest.mark.parametrize(
    "build, message",
    [
        (lambda: Fabric(stiffness_span=-1.0), "stiffness_span must be a positive"),
        (lambda: Fabric(poisson=1.0), "poisson"),
        (lambda: Fabric(areal_density=0.0), "areal_density"),
        (lambda: Bay.flat_panel(n_span=2), "n_span"),
        (lambda: Bay.flat_panel(width=-1.0), "width"),
    ],
)
def test_non_physical_material_and_coarse_grid_are_rejected(build, message):
    with pytest.raises(ValueError, match=message):
        build()
