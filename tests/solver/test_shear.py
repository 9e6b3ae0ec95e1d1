"""The shear stiffness: the T12 terms of eq. (1) and (6) from the shear angle of eq. (8)-(9) (`forward_solver.shear`).

A flat prestressed panel stays flat, a rigid motion leaves the internal forces
as they were (rotated), a sheared panel carries ``T12 = G theta`` with eq.
(9)'s ``theta``, the forces agree with an independent residual that writes
their derivative out by hand, and at zero shear stiffness the term is not in
the compiled program at all.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from forward_solver import Bay, Fabric, Scene, solve_equilibrium
from forward_solver import forces as fk
from forward_solver.model.parameters import as_parameters
from forward_solver.reference.independent_residual import numpy_residual
from forward_solver.shear import shear_forces, shear_tension
from support.solver import default_bay

#: 2% of the default 2e5 N/m, as the paper says of textiles.
SHEAR = 4e3


def _kernel(bay, fabric, pressure=2e4, prestrain=(0.005, 0.005)):
    scene = Scene(bay, fabric)
    physics = scene.physics(dynamic=False)
    params = scene.params(as_parameters(pressure, prestrain))
    return physics, params, fk.prepare(bay.geometry(), params, physics)


def _panel():
    return Bay.flat_panel(width=0.3, length=0.7, n_span=6, n_contour=9)


def test_a_flat_prestressed_panel_with_shear_stiffness_stays_flat(x64):
    # The mounted panel is the shear's reference: no angle has changed, so no T12 and, as without
    # shear, no net force on any node (round-off: an edge force is about T h ~ 1e3 * 0.1 N).
    physics, params, ref = _kernel(_panel(), Fabric(shear_stiffness=SHEAR), pressure=0.0, prestrain=(0.01, 0.004))
    assert physics.shear_stiffness == SHEAR
    assert float(jnp.max(jnp.abs(shear_tension(ref.nodes, ref, physics)))) < 1e-12
    assert float(jnp.max(jnp.abs(fk.forces(ref.nodes, ref, params, physics).total))) < 1e-10


@pytest.mark.parametrize("make_bay", [_panel, lambda: default_bay(5, 32)])
def test_a_rigid_motion_leaves_the_internal_forces_as_they_were(x64, make_bay):
    bay = make_bay()
    physics, params, ref = _kernel(bay, Fabric(shear_stiffness=SHEAR), pressure=0.0)
    rng = np.random.default_rng(3)
    x = ref.nodes + jnp.asarray(0.01 * rng.standard_normal(ref.nodes.shape)) * (~bay.fixed)[..., None]
    angle, axis = 0.9, np.array([0.3, -1.0, 2.0]) / np.linalg.norm([0.3, -1.0, 2.0])
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rot = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    moved = x @ jnp.asarray(rot).T + jnp.asarray([1.0, 0.5, -2.0])
    physics = dataclasses.replace(physics, tension_only=False)  # (no clamp: every term acts)
    f, g = fk.forces(x, ref, params, physics).total, fk.forces(moved, ref, params, physics).total
    shear = fk.forces(x, ref, params, physics).total - fk.forces(x, ref, params, dataclasses.replace(
        physics, shear_stiffness=0.0)).total
    assert float(jnp.max(jnp.abs(shear))) > 1e-3 * float(jnp.max(jnp.abs(f)))  # (the shear takes part)
    np.testing.assert_allclose(np.asarray(g), np.asarray(f) @ rot.T, atol=1e-10 * float(jnp.max(jnp.abs(f))))
    np.testing.assert_allclose(np.asarray(shear_tension(moved, ref, physics)),
                               np.asarray(shear_tension(x, ref, physics)), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("slope", [1e-3, 0.2])
def test_a_sheared_panel_carries_t12_as_eq_8_and_9_say(x64, slope):
    # Simple shear x += s y of the whole mounted panel: every cell's span fibre leans by atan(s).
    # Eq. (8): e12 = (g12 - g12^0) / (2 sqrt(g11^0 g22^0)), eq. (9): sin(theta) = 2 e12 / (lambda1
    # lambda2), from the grid's own metric; T12 = G theta in every cell (round-off).
    bay = _panel()
    physics, params, ref = _kernel(bay, Fabric(shear_stiffness=SHEAR), pressure=0.0, prestrain=(0.0, 0.0))
    x = ref.nodes.at[..., 0].add(slope * ref.nodes[..., 1])
    r1 = np.asarray(x[1:, :-1] - x[:-1, :-1])  # along alpha1 (span), per cell
    r2 = np.asarray(x[:-1, 1:] - x[:-1, :-1])  # along alpha2 (contour)
    r1_0 = np.asarray(ref.nodes[1:, :-1] - ref.nodes[:-1, :-1])
    r2_0 = np.asarray(ref.nodes[:-1, 1:] - ref.nodes[:-1, :-1])
    g11_0, g22_0 = np.sum(r1_0 * r1_0, -1), np.sum(r2_0 * r2_0, -1)
    e12 = (np.sum(r1 * r2, -1) - np.sum(r1_0 * r2_0, -1)) / (2 * np.sqrt(g11_0 * g22_0))
    lambda1, lambda2 = np.sqrt(np.sum(r1 * r1, -1) / g11_0), np.sqrt(np.sum(r2 * r2, -1) / g22_0)
    theta = np.arcsin(2 * e12 / (lambda1 * lambda2))
    t12 = np.asarray(shear_tension(x, ref, physics))
    np.testing.assert_allclose(t12, SHEAR * theta, rtol=1e-12, atol=1e-12 * SHEAR)
    assert abs(abs(t12.mean()) - SHEAR * np.arctan(slope)) < 1e-12 * SHEAR
    # The shear forces on the tip rib's row add up to the section's shear force: the shear energy
    # G theta^2 A / 2 of the panel (A = L W) with that row moved by dx along x changes theta by
    # cos^2(theta) dx / W, so the row carries G theta L cos^2(theta) along x (held, the rib takes it):
    # T12 L to first order in the shear, as eq. (1) and (6) have it.
    row = np.asarray(jnp.sum(shear_forces(x, ref, physics)[-1], axis=0))
    length, mean = 0.7, float(np.mean(theta))
    expected = SHEAR * abs(mean) * length * np.cos(mean) ** 2
    assert abs(abs(row[0]) - expected) < 1e-9 * expected
    assert abs(abs(row[0]) - abs(t12.mean()) * length) <= 1.01 * slope ** 2 * expected
    # It acts across the leaning span fibre (s, 1, 0), in the plane: along tau2 = -x to first order.
    assert abs(row[0] * slope + row[1]) < 1e-9 * expected and abs(row[2]) < 1e-9 * expected


def test_shear_forces_agree_with_an_independent_residual():
    # The returned equilibrium of a bay with shear stiffness (and a fitted-law-free fabric) satisfies the
    # plain numpy residual, which writes the shear forces' derivative out by hand: to the solve's 1e-10.
    bay = default_bay(7, 32)
    fabric = Fabric(stiffness_span=2e5, stiffness_chord=1.5e5, poisson=0.3, shear_stiffness=SHEAR)
    sol = solve_equilibrium(Scene(bay, fabric), 2e4, (0.005, 0.005), rtol=1e-10)
    r = numpy_residual(bay, fabric, sol.nodes, 2e4, (0.005, 0.005))
    assert np.linalg.norm(r) / (2e4 * bay.skin_area()) < 1e-10 + 1e-12
    without = numpy_residual(bay, dataclasses.replace(fabric, shear_stiffness=0.0), sol.nodes, 2e4, (0.005, 0.005))
    assert np.linalg.norm(without) / (2e4 * bay.skin_area()) > 1e-6  # (the shear is in the balance)


def test_relaxation_and_newton_reach_the_same_equilibrium_with_shear():
    scene = Scene(default_bay(9, 32), Fabric(shear_stiffness=SHEAR))
    relaxed = solve_equilibrium(scene, 2e4, (0.005, 0.005), rtol=1e-10, method="relax")
    newton = solve_equilibrium(scene, 2e4, (0.005, 0.005), rtol=1e-10, method="newton")
    assert relaxed.converged and newton.converged
    assert np.max(np.abs(relaxed.nodes - newton.nodes)) < 1e-7
    plain = solve_equilibrium(Scene(default_bay(9, 32), Fabric()), 2e4, (0.005, 0.005), rtol=1e-10, method="newton")
    assert np.max(np.abs(plain.nodes - newton.nodes)) > 1e-6  # (the shear moves the skin)


def test_the_masses_bound_the_shear_stiffness(x64):
    # Gershgorin: the rows of the shear forces' Jacobian against the share node_stiffness gives them
    # (SHEAR_BOUND G): at most 1.1 near the mounted shape (measured 1.05 here), within the fibres' own
    # 0.8-1.7 (the relaxation's mass safety covers both).
    bay = default_bay(5, 32)
    physics, params, ref = _kernel(bay, Fabric(shear_stiffness=SHEAR))
    physics = fk.static_physics(physics)
    x = ref.nodes + 1e-5 * jnp.asarray(np.random.default_rng(1).standard_normal(ref.nodes.shape))
    jacobian = jax.jacfwd(lambda y: shear_forces(y, ref, physics).reshape(-1))(x).reshape(ref.nodes.size, -1)
    rows = np.abs(np.asarray(jacobian)).sum(axis=1).reshape(ref.nodes.shape).max(axis=-1)
    share = (np.asarray(fk.node_stiffness(x, ref, params, physics))
             - np.asarray(fk.node_stiffness(x, ref, params, dataclasses.replace(physics, shear_stiffness=0.0))))
    free = ~bay.fixed
    assert np.max(rows[free] / share[free]) < 1.1


def test_zero_shear_stiffness_is_not_in_the_program(x64):
    # G = 0 (the default) is the code path without shear: the same program as a Physics that never
    # heard of it; any G > 0 traces the shear term.
    bay = _panel()
    physics, params, ref = _kernel(bay, Fabric())
    bare = fk.Physics(physics.periodic, physics.tension_only)
    assert physics == bare and Fabric(shear_stiffness=0.0).shear_stiffness == 0.0

    def program(p):
        return str(jax.make_jaxpr(lambda x: fk.forces(x, ref, params, p).total)(ref.nodes))

    assert program(physics) == program(bare)
    assert program(dataclasses.replace(physics, shear_stiffness=1.0)) != program(bare)
