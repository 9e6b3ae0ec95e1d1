"""A whole wing: tapered bays solved as one batch.

Three bays of a NACA 2412 wing tapering from 1.0 m to 0.6 m on 9x32 grids.
Each bay of the batched solve must be the equilibrium that the eager
`solve_equilibrium` finds for that bay alone (both relaxed to rtol 1e-10, so
their nodes agree far below 1e-8 m), and the batch must be differentiable in
the shared pressure (central differences, float64, 1e-5 relative: the
issue's gradient tolerance).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from forward_solver import Fabric, Parameters, Scene, solve_equilibrium
from forward_solver import Wing
from forward_solver.solvers.bays import solve_wing
from targets import naca

GRID = dict(n_span=9, n_contour=32)
PARAMETERS = Parameters(pressure=2e4, prestrain_span=0.005, prestrain_chord=0.005)


@pytest.fixture(scope="module")
def wing():
    af = naca("2412")
    return Wing(airfoils=(af, af, af, af), chords=(1.0, 0.8, 0.7, 0.6), stations=(0.0, 0.25, 0.5, 0.75))


@pytest.fixture(scope="module")
def batched(wing):
    return solve_wing(wing, Fabric(), PARAMETERS, rtol=1e-10, **GRID)


def test_each_bay_matches_its_own_solve(wing, batched):
    assert batched.converged and batched.nodes.shape == (3, 9, 32, 3)
    for k, bay in enumerate(batched.bays):
        alone = solve_equilibrium(Scene(bay, Fabric()), PARAMETERS, rtol=1e-10)
        assert np.max(np.abs(np.asarray(batched.nodes[k]) - alone.nodes)) < 1e-8
    # Tapered: the tip rib of bay k is the root rib of bay k + 1.
    np.testing.assert_allclose(np.asarray(batched.nodes[0, -1, :, 0]).max(), 0.8)
    np.testing.assert_allclose(np.asarray(batched.nodes[1, 0, :, 0]).max(), 0.8)


def test_the_batch_is_differentiable_in_the_shared_pressure(wing):
    def bulge(p):
        nodes = solve_wing(wing, Fabric(), PARAMETERS.replace(pressure=p), rtol=1e-11, **GRID).nodes
        return jnp.sum(nodes[:, 4, :, 2] ** 2)

    h = 1e-4 * PARAMETERS.pressure
    with jax.enable_x64(True):
        grad = float(jax.grad(bulge)(PARAMETERS.pressure))
        fd = float(bulge(PARAMETERS.pressure + h) - bulge(PARAMETERS.pressure - h)) / (2 * h)
    assert grad == pytest.approx(fd, rel=1e-5)


def test_bad_wings_are_refused():
    af = naca("2412")
    with pytest.raises(ValueError, match="at least two ribs"):
        Wing(airfoils=(af,), chords=(1.0,), stations=(0.0,))
    with pytest.raises(ValueError, match="increase strictly"):
        Wing(airfoils=(af, af), chords=(1.0, 0.8), stations=(0.0, 0.0))
    with pytest.raises(ValueError, match="positive lengths"):
        Wing(airfoils=(af, af), chords=(1.0, -0.8), stations=(0.0, 0.3))
    with pytest.raises(ValueError, match="one chord and one station per rib"):
        Wing(airfoils=(af, af), chords=(1.0,), stations=(0.0, 0.3))


def test_per_rib_shapes_mount_each_bay_between_its_own_ribs(wing):
    # Rib k's coefficients: bay k's root and bay k - 1's tip. Each bay must equal its own
    # solve_equilibrium with rib_shape = rib k's row and rib_shape_tip = rib k + 1's (rtol 1e-10,
    # nodes < 1e-8 m), and d/d(one coefficient of rib 1, shared by bays 0 and 1) must match
    # central differences (solves at 1e-11 against a step of 1e-4 of the offset: rel 1e-5).
    shapes = 0.01 * np.array([[0.0, 0.0, 0.0, 0.0], [-1.0, 0.5, 1.0, -0.5], [0.5, -1.0, 0.0, 1.0],
                              [1.0, 1.0, -1.0, 0.0]])
    sol = solve_wing(wing, Fabric(), PARAMETERS, rtol=1e-10, rib_shapes=shapes, **GRID)
    assert sol.converged
    for k, bay in enumerate(sol.bays):
        alone = solve_equilibrium(Scene(bay, Fabric()),
                                  PARAMETERS.replace(rib_shape=shapes[k], rib_shape_tip=shapes[k + 1]), rtol=1e-10)
        assert np.max(np.abs(np.asarray(sol.nodes[k]) - alone.nodes)) < 1e-8
    # The shared rib really is one rib: bay 0's tip row is bay 1's root row.
    np.testing.assert_allclose(np.asarray(sol.nodes[0, -1, :, [0, 2]]), np.asarray(sol.nodes[1, 0, :, [0, 2]]),
                               atol=1e-14)

    def bulge(c):
        s = jnp.asarray(shapes).at[1, 1].set(c)
        nodes = solve_wing(wing, Fabric(), PARAMETERS, rtol=1e-11, rib_shapes=s, **GRID).nodes
        return jnp.sum(nodes[:2, 4, :, 2] ** 2)

    c0, h = shapes[1, 1], 1e-4
    with jax.enable_x64(True):
        grad = float(jax.grad(bulge)(c0))
        fd = float(bulge(c0 + h) - bulge(c0 - h)) / (2 * h)
    assert grad == pytest.approx(fd, rel=1e-5)
    with pytest.raises(ValueError, match=r"rib_shapes must be an \(4, 2K\) array"):
        solve_wing(wing, Fabric(), PARAMETERS, rib_shapes=shapes[:3], **GRID)
