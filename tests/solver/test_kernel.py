"""The force kernel (eq. 10-15) against exact identities and closed forms."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from forward_solver import Bay, Fabric, Scene
from forward_solver import forces as fk
from forward_solver.stencils import safe_norm
from forward_solver.reference.closed_forms import circle_contour, fabric_tensions, flat_panel_pressure_force
from forward_solver.model.parameters import as_parameters


def _setup(bay, pressure=2e4, prestrain=(0.005, 0.005), fabric=Fabric()):
    scene = Scene(bay, fabric)
    physics = scene.physics(dynamic=False)
    params = scene.params(as_parameters(pressure, prestrain))
    ref = fk.prepare(bay.geometry(), params, physics)
    return scene, physics, params, ref


def _perturbed(bay, ref, seed=0, amplitude=0.01):
    rng = np.random.default_rng(seed)
    noise = amplitude * rng.standard_normal(ref.nodes.shape)
    return ref.nodes + jnp.asarray(noise) * (~bay.fixed)[..., None]


def _circle_bay(n_span=5, n_contour=20, spacing=0.3):
    """A periodic tube built directly from a circle contour (no airfoil package needed)."""
    contour = np.stack(circle_contour(n_contour, repeat_first=False), axis=-1)
    fixed = np.zeros((n_span, n_contour), bool)
    fixed[0] = fixed[-1] = True
    zeros = np.zeros(n_contour)
    return Bay(contour, contour, zeros, zeros, 0.2, 0.2, spacing, True, fixed, "tube")


def test_pressure_force_on_flat_panel_is_p_times_area(x64):
    # Exact: the area vectors of the eight triangles tile the panel (eq. 15).
    bay = Bay.flat_panel(width=0.3, length=0.7, n_span=6, n_contour=9)
    _, physics, params, ref = _setup(bay)
    total = jnp.sum(fk.node_area_vectors(ref.nodes, physics.periodic), axis=(0, 1))
    # Area vectors are p A / p: the unit-pressure force.
    np.testing.assert_allclose(np.asarray(total), [0.0, 0.0, flat_panel_pressure_force(1.0, 0.3, 0.7)],
                               rtol=1e-13, atol=1e-15)


def test_net_pressure_force_on_closed_tube_vanishes(x64):
    # The tube's two open ends are the same contour, so its area vector closes: sum = 0 to
    # round-off for any deformation of the interior nodes.
    bay = _circle_bay()
    _, physics, params, ref = _setup(bay)
    x = _perturbed(bay, ref, amplitude=0.02)
    total = jnp.sum(fk.node_area_vectors(x, physics.periodic), axis=(0, 1))
    scale = float(jnp.sum(safe_norm(fk.node_area_vectors(x, physics.periodic))))
    assert float(safe_norm(total)) < 1e-14 * scale


@pytest.mark.parametrize("make_bay", [lambda: Bay.flat_panel(0.3, 0.7, 6, 9), _circle_bay])
def test_forces_are_invariant_under_rigid_motion(x64, make_bay):
    # Internal and follower forces rotate with the body and ignore translation.
    bay = make_bay()
    _, physics, params, ref = _setup(bay)
    x = _perturbed(bay, ref, seed=1)
    angle = 0.7
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rot = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    moved = x @ jnp.asarray(rot).T + jnp.asarray([0.3, -1.2, 2.0])
    fixed_physics = fk.Physics(physics.periodic, tension_only=True)
    f = fk.forces(x, ref, params, fixed_physics)
    g = fk.forces(moved, ref, params, fixed_physics)
    np.testing.assert_allclose(np.asarray(g.total), np.asarray(f.total) @ rot.T, atol=1e-10 * float(jnp.max(jnp.abs(f.total))))
    np.testing.assert_allclose(np.asarray(g.tension_span), np.asarray(f.tension_span), rtol=1e-11)


def test_prestressed_flat_panel_is_in_equilibrium_with_closed_form_tensions(x64):
    # Without pressure the mounted flat panel is at rest: uniform stretches 1 + prestrain give
    # T11 = (E11 e1 + nu E22 e2) / (1 - nu^2) (eq. 10) and zero net force on every node.
    fabric = Fabric(stiffness_span=3e5, stiffness_chord=1e5, poisson=0.3)
    bay = Bay.flat_panel(width=0.3, length=0.7, n_span=6, n_contour=9)
    _, physics, params, ref = _setup(bay, pressure=0.0, prestrain=(0.01, 0.004), fabric=fabric)
    f = fk.forces(ref.nodes, ref, params, physics)
    t11, t22 = fabric_tensions(3e5, 1e5, 0.3, 0.01, 0.004)
    assert t11 == pytest.approx((3e5 * 0.01 + 0.3 * 1e5 * 0.004) / (1 - 0.09), rel=1e-15)
    np.testing.assert_allclose(np.asarray(f.tension_span), t11, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(f.tension_chord), t22, rtol=1e-12)
    # Round-off scale: an edge force is about T * h ~ 1e3 * 0.1 N.
    assert float(jnp.max(jnp.abs(f.total))) < 1e-10
    assert not bool(jnp.any(f.wrinkled))


def test_slack_fabric_wrinkles_and_carries_no_compression(x64):
    bay = Bay.flat_panel(width=0.3, length=0.7, n_span=6, n_contour=9)
    # Span fibres cut 1% long: compressive -> clamped to zero and reported as wrinkled; the
    # chord fibres still carry (E e2 + nu E e1) / (1 - nu^2) = 320 N/m.
    _, physics, params, ref = _setup(bay, pressure=0.0, prestrain=(-0.01, 0.004))
    f = fk.forces(ref.nodes, ref, params, physics)
    assert bool(jnp.all(f.wrinkled))
    assert float(jnp.max(f.tension_span)) == 0.0
    expected = (2e5 * 0.004 + 0.25 * 2e5 * -0.01) / (1 - 0.0625)
    np.testing.assert_allclose(np.asarray(f.tension_chord), expected, rtol=1e-12)


def test_nan_state_never_passes_the_residual_test(x64):
    bay = Bay.flat_panel(width=0.3, length=0.7, n_span=6, n_contour=9)
    _, physics, params, ref = _setup(bay)
    x = ref.nodes.at[2, 3, 2].set(jnp.nan)
    assert bool(jnp.isnan(fk.relative_residual(x, ref, params, physics)))
    assert float(safe_norm(jnp.zeros(3))) == 0.0
    assert np.isfinite(np.asarray(jax.grad(lambda v: safe_norm(v))(jnp.zeros(3)))).all()


def test_gravity_adds_the_skin_weight(x64):
    # Mass force q of eq. (1): each free node carries rho0 g times its lumped undeformed area;
    # all nodes together carry the weight of the cut fabric, rho0 g L W / ((1+ps)(1+pc)).
    bay = Bay.flat_panel(width=0.3, length=0.7, n_span=6, n_contour=9)
    fabric = Fabric(areal_density=0.4)
    scene = Scene(bay, fabric, gravity=True, gravity_acceleration=9.81)
    params = scene.params(as_parameters(2e4, (0.01, 0.02)))
    on = scene.physics(dynamic=False)
    off = fk.Physics(on.periodic, on.tension_only, gravity=False)
    ref = fk.prepare(bay.geometry(), params, on)
    x = _perturbed(bay, ref, seed=2, amplitude=0.005)
    weight = fk.forces(x, ref, params, on).total - fk.forces(x, ref, params, off).total
    np.testing.assert_allclose(np.asarray(weight[..., :2]), 0.0, atol=1e-12)
    expected = -0.4 * 9.81 * np.asarray(ref.node_area) * (~bay.fixed)
    np.testing.assert_allclose(np.asarray(weight[..., 2]), expected, rtol=1e-12, atol=1e-15)
    total = float(jnp.sum(ref.node_area))
    np.testing.assert_allclose(total, 0.3 * 0.7 / (1.01 * 1.02), rtol=1e-12)
