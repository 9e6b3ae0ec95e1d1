"""Derivatives of the equilibrium: implicit (adjoint) against finite differences and unrolled AD.

One 9 x 32 NACA 2412 bay is shared by every test (JAX compilation dominates).
Tolerances: the issue's 1e-5 relative agreement with central differences in
float64 (steps 1e-4 of each parameter, solves at rtol 1e-12, so truncation
error ~1e-8 and solve noise ~1e-12/1e-4 are both far below it).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from forward_solver import Bay, Scene
from forward_solver.adjoint import DIFFERENTIABLE, Equilibrium, equilibrium_nodes, unrolled_equilibrium_nodes
from inverse_design.objectives import objective_residuals
from targets import naca

THETA = {"pressure": 2e4, "prestrain_span": 0.004, "prestrain_chord": 0.006, "stiffness_span": 2e5,
         "rib_thickness_scale": 0.95}
FD_RELATIVE_STEP = 1e-4


@pytest.fixture(scope="module")
def scene():
    return Scene(Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=9, n_contour=32))


@pytest.fixture(scope="module")
def weights():
    return np.random.default_rng(0).normal(size=(9, 32, 3))


@pytest.fixture(scope="module")
def equilibrium(scene):
    return Equilibrium(scene, rtol=1e-12)


@pytest.fixture(scope="module")
def implicit_gradient(equilibrium, weights):
    with jax.enable_x64(True):
        return jax.grad(lambda th: jnp.sum(weights * equilibrium(th)))(THETA)


def _central_difference(equilibrium, weights, name):
    h = FD_RELATIVE_STEP * abs(THETA[name])
    plus = equilibrium.solve({**THETA, name: THETA[name] + h}).nodes
    minus = equilibrium.solve({**THETA, name: THETA[name] - h}).nodes
    return float(np.sum(weights * (plus - minus)) / (2 * h))


@pytest.mark.parametrize("name", sorted(THETA))
def test_implicit_gradient_matches_central_differences(equilibrium, weights, implicit_gradient, name):
    fd = _central_difference(equilibrium, weights, name)
    assert abs(float(implicit_gradient[name]) - fd) <= 1e-5 * abs(fd)


def test_forward_mode_matches_reverse_mode(equilibrium, weights, implicit_gradient):
    with jax.enable_x64(True):
        jac = {}
        for name in THETA:  # one jvp per parameter (jacfwd would compile vmapped kernels)
            tangent = {k: 1.0 if k == name else 0.0 for k in THETA}
            jac[name] = jax.jvp(lambda th: jnp.sum(weights * equilibrium(th)), (THETA,), (tangent,))[1]
    for name in THETA:
        # Same linear algebra, two directions of the same factor: rounding only.
        assert abs(float(jac[name]) - float(implicit_gradient[name])) <= 1e-9 * abs(float(jac[name]))


def test_implicit_gradient_matches_unrolled_relaxation(scene, weights, equilibrium):
    theta = {"pressure": 2e4, "rib_thickness_scale": 0.95}
    fixed = {"prestrain_span": 0.004, "prestrain_chord": 0.006}
    eq = Equilibrium(scene, fixed)
    with jax.enable_x64(True):
        implicit = jax.grad(lambda th: jnp.sum(weights * eq(th)))(theta)
        x_unrolled, pullback = jax.vjp(
            lambda th: unrolled_equilibrium_nodes(scene, th, fixed, n_steps=2000), theta)
        (unrolled,) = pullback(jnp.asarray(weights))
    # The unrolled loop has converged (state to 1e-12 m), so its exact
    # derivative must match the implicit one to the solve tolerance.
    assert np.max(np.abs(np.asarray(x_unrolled) - eq.solution.nodes)) < 1e-10
    for name in theta:
        assert abs(float(unrolled[name]) - float(implicit[name])) <= 1e-7 * abs(float(implicit[name]))


def test_objective_gradient_matches_central_differences(scene, equilibrium):
    target = naca("2412")

    def objective(th):
        r = objective_residuals(equilibrium(th), target, 1.0, "average")
        return jnp.sum(r * r)

    with jax.enable_x64(True):
        grad = jax.grad(objective)({"pressure": 2e4})["pressure"]
        h = FD_RELATIVE_STEP * 2e4
        fd = (objective({"pressure": 2e4 + h}) - objective({"pressure": 2e4 - h})) / (2 * h)
    assert abs(float(grad) - float(fd)) <= 1e-5 * abs(float(fd))


def test_warm_start_counts_solves_and_steps(scene):
    eq = Equilibrium(scene, {"prestrain_span": 0.005, "prestrain_chord": 0.005})
    eq.solve({"pressure": 2e4})
    eq.solve({"pressure": 2.02e4})
    assert eq.solves == 2 and len(eq.steps) == 2
    assert eq.steps[1] < eq.steps[0]  # the warm start skips the relaxation from the mounted shape


def test_unknown_parameter_is_refused(scene):
    with pytest.raises(ValueError, match="differentiable in"):
        equilibrium_nodes(scene, {"presure": 2e4})
    with pytest.raises(ValueError, match="pressure must be given"):
        Equilibrium(scene).solve({"prestrain_span": 0.01})
    assert "rib_thickness_scale" in DIFFERENTIABLE


def test_jit_is_refused_with_a_clear_error(scene):
    eq = Equilibrium(scene)
    with jax.enable_x64(True), pytest.raises(TypeError, match="outside jax.jit"):
        jax.jit(lambda p: eq({"pressure": p}))(2e4)


def test_float32_caller_gets_a_clear_error(scene):
    eq = Equilibrium(scene)
    if jax.config.jax_enable_x64:
        pytest.skip("the session runs with float64 on globally")
    with pytest.raises(RuntimeError, match="float64"):
        jax.grad(lambda p: jnp.sum(eq({"pressure": p})))(2e4)


def test_host_solve_returns_float64_on_a_thread_without_float64(equilibrium):
    """XLA may run the LU callback on a worker thread outside the caller's float64 scope; JAX
    then canonicalises the returned array, which must stay float64 (else "Incorrect output
    dtype" aborts the gradient). Replays that on a fresh thread."""
    import threading

    with jax.enable_x64(True):
        lin = equilibrium._linearised(equilibrium.values(THETA))
    out = {}

    def worker():
        out["x64_before"] = bool(jax.config.jax_enable_x64)
        solved = lin._host_solve(np.ones(lin.factor.shape[0]), trans="N")
        out["dtype"] = jnp.asarray(solved).dtype  # canonicalised as the callback result is

    thread = threading.Thread(target=worker)
    thread.start()
    thread.join()
    assert out["x64_before"] is False  # the premise: a new thread starts without float64
    assert out["dtype"] == np.float64
    assert not jax.config.jax_enable_x64  # this (the caller's) thread is untouched
