"""Derivatives of `solve_equilibrium`: implicit (adjoint) against finite differences and unrolled AD.

One 9 x 32 NACA 2412 bay is shared by every test (JAX compilation dominates).
Tolerances: the issue's 1e-5 relative agreement with central differences in
float64 (steps 1e-4 of each parameter, solves at rtol 1e-12, so truncation
error ~1e-8 and solve noise ~1e-12/1e-4 are both far below it).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from forward_solver import Parameters, Solution, solve_equilibrium
from forward_solver.model.parameters import PARAMETER_NAMES as DIFFERENTIABLE  # (every scalar field)
from forward_solver.derivatives.implicit import SparseLU, forward_only
from inverse_design.objectives import objective_residuals
from targets import naca
from support.solver import TIGHT_RTOL, default_scene, tight_solve

THETA = Parameters(pressure=2e4, prestrain_span=0.004, prestrain_chord=0.006, stiffness_span=2e5,
                   stiffness_chord=2e5, rib_thickness_scale=0.95, rib_chord_scale=1.0)
FD_RELATIVE_STEP = 1e-4
RTOL = TIGHT_RTOL


@pytest.fixture(scope="module")
def scene():
    return default_scene(9, 32)


@pytest.fixture(scope="module")
def weights():
    return np.random.default_rng(0).normal(size=(9, 32, 3))



@pytest.fixture(scope="module")
def reference(scene):
    return tight_solve(scene, THETA)


@pytest.fixture(scope="module")
def implicit_gradient(scene, weights, reference):
    def loss(q):
        sol = tight_solve(scene, q, initial=reference)
        return jnp.sum(weights * sol.nodes), sol

    with jax.enable_x64(True):
        (value, sol), grad = jax.value_and_grad(loss, has_aux=True)(THETA)
    return grad, sol


def _central_difference(scene, weights, reference, name):
    value = getattr(THETA, name)
    h = FD_RELATIVE_STEP * abs(value)
    plus = tight_solve(scene, THETA.replace(**{name: value + h}), reference).nodes
    minus = tight_solve(scene, THETA.replace(**{name: value - h}), reference).nodes
    return float(np.sum(weights * (plus - minus)) / (2 * h))


@pytest.mark.parametrize("name", DIFFERENTIABLE)
def test_implicit_gradient_matches_central_differences(scene, weights, reference, implicit_gradient, name):
    grad, _ = implicit_gradient
    fd = _central_difference(scene, weights, reference, name)
    assert isinstance(grad, Parameters)
    assert abs(float(getattr(grad, name)) - fd) <= 1e-5 * abs(fd)


def test_gradient_comes_with_the_concrete_solution(implicit_gradient, reference):
    _, sol = implicit_gradient
    assert isinstance(sol, Solution) and sol.converged
    assert sol.parameters == THETA  # recorded whole
    np.testing.assert_allclose(np.asarray(sol.nodes), reference.nodes, atol=1e-12)
    # Warm-started at its own parameters: chord Newton, zero iterations, the reference's LU kept.
    assert sol.factor is not None and sol.factor.lu is reference.factor.lu
    assert reference.factor.current  # Newton's LU at the returned nodes (the adjoint reuses it)


def test_loose_pressure_keyword_is_differentiable(scene, weights):
    """The documented form (README's API block): ``jax.grad(lambda p: f(solve_equilibrium(scene, pressure=p,
    prestrain=...).nodes))``, the derivative taken through a `Parameters` with the same values; the
    stiffnesses and rib scales travel in the `Parameters`, and the keywords they had once say so."""
    at = THETA.replace(stiffness_span=None, stiffness_chord=None, rib_thickness_scale=1.0)
    with jax.enable_x64(True):
        loose = jax.grad(lambda p: jnp.sum(weights * solve_equilibrium(
            scene, pressure=p, prestrain=THETA.prestrain, rtol=RTOL, method="relax+newton").nodes))(THETA.pressure)
        whole = jax.grad(lambda p: jnp.sum(weights * tight_solve(scene, at.replace(pressure=p)).nodes))(THETA.pressure)
    assert float(loose) == pytest.approx(float(whole), rel=1e-9)
    for name, value in (("stiffness", THETA.stiffness), ("rib_thickness_scale", 0.95), ("rib_chord_scale", 1.0)):
        with pytest.raises(TypeError, match=f"takes no {name}= any more: give it in the Parameters"):
            solve_equilibrium(scene, pressure=THETA.pressure, **{name: value})
    with pytest.raises(TypeError, match=r"adjoint=ImplicitAdjoint\(linear_solver=...\)"):
        solve_equilibrium(scene, THETA, linear_solver="lu")


def test_tensions_are_differentiable(scene, reference):
    """The returned tensions are functions of the traced nodes and parameters."""
    def largest(p):
        return jnp.max(tight_solve(scene, THETA.replace(pressure=p), reference).tension_chord)

    h = FD_RELATIVE_STEP * THETA.pressure
    with jax.enable_x64(True):
        grad = float(jax.grad(largest)(THETA.pressure))
        fd = float(largest(THETA.pressure + h) - largest(THETA.pressure - h)) / (2 * h)
    assert grad == pytest.approx(fd, rel=1e-5)


def test_forward_mode_matches_reverse_mode(scene, weights, reference, implicit_gradient):
    with jax.enable_x64(True):
        jac = jax.jacfwd(lambda q: jnp.sum(weights * tight_solve(scene, q, reference).nodes))(THETA)
    for name in DIFFERENTIABLE:
        # Same linear algebra, two directions of the same factor: rounding only.
        rev = float(getattr(implicit_gradient[0], name))
        assert abs(float(getattr(jac, name)) - rev) <= 1e-9 * abs(rev)


def test_forward_only_tangents_match_the_transposable_ones(scene, weights, reference, implicit_gradient):
    """`forward_only`: the batch of tangents back-solved on the host (``jax.jacfwd``) and one tangent
    by the traced callback solve (``jax.jvp``) against the reverse-mode gradient: rounding only."""
    def loss(q):
        return jnp.sum(weights * tight_solve(scene, q, reference).nodes)

    with jax.enable_x64(True), forward_only():
        jac = jax.jacfwd(loss)(THETA)
        direction = THETA.replace(pressure=1.0, prestrain_span=0.0, prestrain_chord=0.0, stiffness_span=0.0,
                                  stiffness_chord=0.0, rib_thickness_scale=0.0, rib_chord_scale=0.0)
        _, one = jax.jvp(loss, (THETA,), (direction,))
    for name in DIFFERENTIABLE:
        rev = float(getattr(implicit_gradient[0], name))
        assert abs(float(getattr(jac, name)) - rev) <= 1e-9 * abs(rev), name
    rev = float(implicit_gradient[0].pressure)
    assert abs(float(one) - rev) <= 1e-9 * abs(rev)


def test_reverse_mode_within_forward_only_is_refused(scene, weights, reference):
    with jax.enable_x64(True), forward_only(), pytest.raises(NotImplementedError, match="Transpose rule"):
        jax.grad(lambda q: jnp.sum(weights * tight_solve(scene, q, reference).nodes))(THETA)


def test_implicit_gradient_matches_unrolled_relaxation(scene, weights):
    q = THETA.replace(stiffness_span=None, stiffness_chord=None)

    def loss(p, rib, adjoint):
        sol = solve_equilibrium(scene, q.replace(pressure=p, rib_thickness_scale=rib), adjoint=adjoint,
                                rtol=1e-10, max_steps=2000, method="relax+newton")
        return jnp.sum(weights * sol.nodes), sol

    with jax.enable_x64(True):
        (_, exact), implicit = jax.value_and_grad(loss, argnums=(0, 1), has_aux=True)(2e4, 0.95, "implicit")
        (_, unrolled_sol), unrolled = jax.value_and_grad(loss, argnums=(0, 1), has_aux=True)(
            2e4, 0.95, "unrolled")
    # The unrolled loop has converged (state to 1e-10 m), so its exact
    # derivative must match the implicit one to the solve tolerance.
    assert unrolled_sol.method == "unrolled" and unrolled_sol.converged
    assert np.max(np.abs(np.asarray(unrolled_sol.nodes) - np.asarray(exact.nodes))) < 1e-10
    for a, b in zip(unrolled, implicit):
        assert abs(float(a) - float(b)) <= 1e-7 * abs(float(b))


def test_objective_gradient_matches_central_differences(scene, reference):
    target = naca("2412")

    def objective(p):
        nodes = tight_solve(scene, THETA.replace(pressure=p), reference).nodes
        r = objective_residuals(nodes, target, 1.0, "average")
        return jnp.sum(r * r)

    with jax.enable_x64(True):
        grad = jax.grad(objective)(2e4)
        h = FD_RELATIVE_STEP * 2e4
        fd = (objective(2e4 + h) - objective(2e4 - h)) / (2 * h)
    assert abs(float(grad) - float(fd)) <= 1e-5 * abs(float(fd))


def test_warm_start_reuses_the_factor(scene, reference):
    cold = solve_equilibrium(scene, THETA.replace(pressure=2.02e4), rtol=1e-10, method="relax+newton")
    warm = solve_equilibrium(scene, THETA.replace(pressure=2.02e4), rtol=1e-10, method="relax+newton",
                             initial=reference)
    assert warm.extra.get("warm_start", "").startswith("chord Newton")
    assert warm.steps < cold.steps  # no relaxation from the mounted shape
    np.testing.assert_allclose(warm.nodes, cold.nodes, atol=1e-9)


def test_parameters_and_loose_values_cannot_be_mixed(scene):
    with pytest.raises(ValueError, match="either a Parameters or loose values"):
        solve_equilibrium(scene, THETA, prestrain=0.01)
    with pytest.raises(ValueError, match="pressure must be a positive"):
        solve_equilibrium(scene, THETA.replace(pressure=-5.0))
    with pytest.raises(ValueError, match="stiffness_chord must be a positive"):
        solve_equilibrium(scene, THETA.replace(stiffness_chord=0.0))
    with pytest.raises(ValueError, match="adjoint must be one of"):
        solve_equilibrium(scene, THETA, adjoint="magic")
    with pytest.raises(TypeError, match="presure"):
        Parameters(2e4).replace(presure=2e4)
    assert "rib_thickness_scale" in DIFFERENTIABLE


def test_host_methods_under_jit_are_refused_with_a_clear_error(scene):
    # The pure-JAX path under jit / vmap is tested in tests/derivatives/test_transforms.py.
    with jax.enable_x64(True), pytest.raises(TypeError, match="method='relax'"):
        jax.jit(lambda p: solve_equilibrium(scene, pressure=p, method="newton", throw=False).nodes)(2e4)


def test_float32_caller_gets_a_clear_error(scene):
    if jax.config.jax_enable_x64:
        pytest.skip("the session runs with float64 on globally")
    with pytest.raises(RuntimeError, match="float64"):
        jax.grad(lambda p: jnp.sum(solve_equilibrium(scene, pressure=p).nodes))(2e4)


def test_host_solve_returns_float64_on_a_thread_without_float64(scene, reference):
    """XLA may run the LU callback on a worker thread outside the caller's float64 scope; JAX
    then canonicalises the returned array, which must stay float64 (else "Incorrect output
    dtype" aborts the gradient). Replays that on a fresh thread."""
    import threading

    with jax.enable_x64(True):
        geometry = jax.tree_util.tree_map(jnp.asarray, scene.bay.geometry())
        lin = SparseLU().bind(jnp.asarray(reference.nodes), geometry, scene.params(THETA),
                             scene.physics(dynamic=False))
    out = {}

    def worker():
        out["x64_before"] = bool(jax.config.jax_enable_x64)
        solved = lin.host_solve(np.ones(lin.factor.shape[0]), trans="N")
        out["dtype"] = jnp.asarray(solved).dtype  # canonicalised as the callback result is

    thread = threading.Thread(target=worker)
    thread.start()
    thread.join()
    assert out["x64_before"] is False  # the premise: a new thread starts without float64
    assert out["dtype"] == np.float64
    assert not jax.config.jax_enable_x64  # this (the caller's) thread is untouched


def test_host_solve_receives_float64_exactly_on_a_thread_without_float64(scene, reference):
    """JAX hands a callback its operands through ``device_put`` on the thread XLA runs it on; with
    float64 off there, a float64 right-hand side arrived rounded to float32 (forward-mode
    derivatives off by 6e-8 relative). Its uint32 words pass unchanged: replayed on a fresh thread."""
    import threading

    from forward_solver.derivatives.implicit import _bits, _host_solve

    with jax.enable_x64(True):
        geometry = jax.tree_util.tree_map(jnp.asarray, scene.bay.geometry())
        lin = SparseLU().bind(jnp.asarray(reference.nodes), geometry, scene.params(THETA),
                             scene.physics(dynamic=False))
        b = np.random.default_rng(1).normal(size=lin.factor.shape[0])
        words = np.asarray(_bits(jnp.asarray(b)))
    out = {}

    def worker():
        out["x64_before"] = bool(jax.config.jax_enable_x64)
        token, bits = jax.device_put((np.asarray(lin.token), words))  # as JAX passes operands
        out["plain"] = np.asarray(jax.device_put(b)).dtype
        out["solved"] = _host_solve(token, bits, "N")

    thread = threading.Thread(target=worker)
    thread.start()
    thread.join()
    assert out["x64_before"] is False and out["plain"] == np.float32  # the premise: float64 is lost
    np.testing.assert_array_equal(out["solved"], lin.factor.solve(b))


def test_a_pullback_finds_its_lu_factor_and_released_factors_stay_within_their_budget(
        scene, weights, reference, implicit_gradient, monkeypatch):
    """The compiled tangent reaches its LU by a registered token. A ``jax.vjp`` pullback called after
    everything else is gone still finds it (it holds copies of the nodes, not the nodes, so the
    factor outlives them among the released ones); the released factors keep to their budget."""
    import gc

    from forward_solver.derivatives import implicit

    with jax.enable_x64(True):
        _, pullback = jax.vjp(lambda q: jnp.sum(weights * tight_solve(scene, q, initial=reference).nodes), THETA)
    gc.collect()
    with jax.enable_x64(True):
        (grad,) = pullback(1.0)
    for name in DIFFERENTIABLE:
        want = float(getattr(implicit_gradient[0], name))
        assert abs(float(getattr(grad, name)) - want) <= 1e-12 * abs(want)
    del pullback
    gc.collect()
    # A budget of one factor (this scene's, the newest released: an older one may be another test's,
    # of another grid, in the same process): releasing more keeps only the newest.
    one = list(implicit._RELEASED.values())[-1]
    monkeypatch.setattr(implicit, "RELEASED_FACTOR_BYTES", implicit._factor_bytes(one))
    for _ in range(3):
        with jax.enable_x64(True):
            jax.grad(lambda q: jnp.sum(weights * tight_solve(scene, q, initial=reference).nodes))(THETA)
        gc.collect()
    assert len(implicit._RELEASED) == 1
    assert sum(implicit._factor_bytes(f) for f in implicit._RELEASED.values()) <= implicit.RELEASED_FACTOR_BYTES
