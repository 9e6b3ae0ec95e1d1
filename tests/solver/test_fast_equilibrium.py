"""The fast equilibrium paths agree with each other and with the paper's scheme."""

import numpy as np
import pytest

from forward_solver import Fabric, PressureRamp, Relax, Scene, simulate, solve_equilibrium
from forward_solver.solvers.methods import WARM_NEWTON_ITERATIONS
from support.solver import default_bay

PRESSURE = 2e4
PRESTRAIN = (0.005, 0.005)


@pytest.fixture(scope="module")
def wing_bay():
    return default_bay(9, 64)


@pytest.fixture(scope="module")
def wing_reference(wing_bay):
    return solve_equilibrium(Scene(wing_bay, Fabric()), PRESSURE, PRESTRAIN, rtol=1e-11)


def test_half_bay_equals_full_bay(wing_bay, wing_reference):
    # Tolerance: both solved to rtol 1e-11, i.e. shapes within ~1e-9 chord of each other.
    assert wing_reference.extra["half_bay"]
    full = solve_equilibrium(Scene(wing_bay, Fabric()), PRESSURE, PRESTRAIN, rtol=1e-11,
                             method=Relax(symmetry=False))
    assert not full.extra["half_bay"]
    assert np.abs(full.nodes - wing_reference.nodes).max() < 1e-8
    np.testing.assert_allclose(full.tension_span, wing_reference.tension_span, rtol=1e-6)
    # The reconstructed half really is the mirror image.
    nodes = wing_reference.nodes
    np.testing.assert_allclose(nodes[::-1, :, 1], 0.25 - nodes[:, :, 1], atol=1e-12)


def test_paper_scheme_reaches_the_same_wing_equilibrium():
    # The physical-mass scheme (eq. 14-17) run to rest lands on the relaxation equilibrium.
    # Tolerance 1e-6 chord (docs/validation.md). A coarse contour keeps its CFL step affordable: cosine
    # spacing makes the leading-edge cells tiny and the viscous term shortens the step there
    # further, so light viscosity (in-plane modes) plus aerodynamic damping (the bulge) it is.
    bay = default_bay(9, 32)
    relaxed = solve_equilibrium(Scene(bay, Fabric()), PRESSURE, PRESTRAIN, rtol=1e-11)
    scene = Scene(bay, Fabric(viscosity=5.0), aerodynamic_damping=0.05)
    sol = simulate(scene, PressureRamp(PRESSURE, 0.002), PRESTRAIN, rtol=1e-9, max_steps=600_000)
    assert np.abs(sol.nodes - relaxed.nodes).max() < 1e-6


@pytest.mark.parametrize("method", ["newton", "relax+newton"])
def test_every_method_reaches_the_same_shape(wing_bay, wing_reference, method):
    # Tolerance: all solved to rtol 1e-11, shapes within 1e-8 chord.
    sol = solve_equilibrium(Scene(wing_bay, Fabric()), PRESSURE, PRESTRAIN, rtol=1e-11, method=method)
    assert sol.method == method
    assert np.abs(sol.nodes - wing_reference.nodes).max() < 1e-8
    np.testing.assert_allclose(sol.tension_chord, wing_reference.tension_chord, rtol=1e-5, atol=1e-6)


def test_warm_start_after_one_percent_pressure_change(wing_bay):
    # A warm start takes at most a quarter of the steps of a cold start. With
    # relax+newton it reuses the previous factorised Jacobian (chord Newton): a handful of
    # residual evaluations and triangular solves instead of a relaxation.
    scene = Scene(wing_bay, Fabric())
    base = solve_equilibrium(scene, PRESSURE, PRESTRAIN, rtol=1e-9, method="relax+newton")
    cold = solve_equilibrium(scene, 1.01 * PRESSURE, PRESTRAIN, rtol=1e-9, method="relax+newton")
    warm = solve_equilibrium(scene, 1.01 * PRESSURE, PRESTRAIN, rtol=1e-9, method="relax+newton",
                             initial=base)
    assert "chord Newton" in warm.extra["warm_start"]
    assert warm.steps <= cold.steps / 4
    assert np.abs(warm.nodes - cold.nodes).max() < 1e-8
    # Relaxation alone warm-starts too, with fewer steps but not 4x fewer: its rate is linear
    # and a 1% load change still leaves 7 of the 9 orders of residual to remove.
    cold_relax = solve_equilibrium(scene, 1.01 * PRESSURE, PRESTRAIN, rtol=1e-9)
    relaxed = solve_equilibrium(scene, 1.01 * PRESSURE, PRESTRAIN, rtol=1e-9, initial=base)
    assert relaxed.steps < cold_relax.steps
    assert np.abs(relaxed.nodes - cold.nodes).max() < 1e-7


def test_a_warm_start_beyond_the_chord_iteration_takes_newton_not_relaxation(wing_bay):
    # A design step's change (pressure -40%, prestrain +1%): the old factor no longer halves the residual
    # each chord iteration, and Newton proper from the old shape converges without a relaxation step, to
    # the cold solve's shape (both at rtol 1e-9: within 1e-8 chord).
    scene = Scene(wing_bay, Fabric())
    base = solve_equilibrium(scene, PRESSURE, PRESTRAIN, rtol=1e-9, method="relax+newton")
    step = (0.6 * PRESSURE, (PRESTRAIN[0] + 0.01, PRESTRAIN[1]))
    cold = solve_equilibrium(scene, *step, rtol=1e-9, method="relax+newton")
    warm = solve_equilibrium(scene, *step, rtol=1e-9, method="relax+newton", initial=base)
    assert warm.extra["warm_start"] == "Newton from the initial solution" and warm.extra["relax_steps"] == 0
    assert warm.extra["newton_iterations"] <= WARM_NEWTON_ITERATIONS < cold.extra["relax_steps"]
    assert np.abs(warm.nodes - cold.nodes).max() < 1e-8


def test_equilibrium_does_not_depend_on_the_starting_shape(wing_bay, wing_reference):
    # A taut skin (no wrinkles here) has one equilibrium. Start from the mounted shape
    # pushed in and out by smooth bumps of up to 1 cm on every free node; tolerance: both solves
    # stop at rtol 1e-11, so shapes agree to ~1e-9 chord.
    assert not wing_reference.wrinkled.any()
    mounted = np.asarray(wing_bay.nominal_nodes())
    i = np.linspace(0, np.pi, wing_bay.n_span)[:, None]
    j = np.linspace(0, 2 * np.pi, wing_bay.n_contour, endpoint=False)[None, :]
    bump = 0.01 * np.sin(i)[..., None] * np.stack([np.sin(3 * j), 0 * j, np.cos(2 * j)], axis=-1)
    start = mounted + bump * (~wing_bay.fixed)[..., None]
    sol = solve_equilibrium(Scene(wing_bay, Fabric()), PRESSURE, PRESTRAIN, rtol=1e-11, initial=start)
    assert np.abs(sol.nodes - wing_reference.nodes).max() < 1e-8
