"""`solve_equilibrium` under jax.jit and jax.vmap (the pure-JAX path, `forward_solver.solvers.relax.traced_solution`).

One 9 x 32 NACA 2412 bay and a few module-scoped compiled functions are
shared by every test (compilation dominates). Tolerances:

* nodes: 1e-8 m against the eager solve, both stopped at a relative residual
  of 1e-10 (the eager 9x32 solve relaxes from the same mounted shape, so the
  two agree far closer; 1e-8 m is what rtol 1e-10 guarantees on this bay);
* gradients: 1e-6 relative between the iterative (BiCGStab) and host-LU
  implicit derivatives, both at the same equilibrium (rtol 1e-12) with the
  Krylov solve at 1e-10; 1e-5 against central differences in float64, as
  in tests/derivatives/test_gradients.py (steps 1e-4 of the value, solves at 1e-12).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from forward_solver import (BiCGStab, ConvergenceError, ImplicitAdjoint, Parameters, Relax, Solution,
                            SparseLU, solve_equilibrium)
from forward_solver.derivatives.implicit import default_linear_solver
from forward_solver.solution import Result
from support.solver import default_scene

THETA = Parameters(pressure=2e4, prestrain_span=0.004, prestrain_chord=0.006, stiffness_span=2e5,
                   stiffness_chord=2e5, rib_thickness_scale=0.95, rib_chord_scale=1.0)
PRESSURES = np.linspace(5e3, 5e4, 8)
RTOL = 1e-10
GRADIENT_RTOL = 1e-12
FD_RELATIVE_STEP = 1e-4


@pytest.fixture(scope="module")
def scene():
    return default_scene(9, 32)


@pytest.fixture(scope="module")
def weights():
    return jnp.asarray(np.random.default_rng(0).normal(size=(9, 32, 3)))


@pytest.fixture(scope="module")
def x64():
    with jax.enable_x64(True):
        yield


@pytest.fixture(scope="module")
def compiled(scene, x64):
    """A jitted solve of the parameters that counts its traces."""
    traces = []

    @jax.jit
    def solve(parameters):
        traces.append(1)
        return solve_equilibrium(scene, parameters, rtol=RTOL, throw=False)

    return solve, traces


@pytest.fixture(scope="module")
def batch(scene, x64):
    """Eight pressures, one compiled call."""
    def one(pressure):
        return solve_equilibrium(scene, THETA.replace(pressure=pressure), rtol=RTOL, throw=False)

    return jax.jit(jax.vmap(one))(jnp.asarray(PRESSURES))


def _loss(scene, weights, **options):
    def loss(parameters):
        return jnp.sum(weights * solve_equilibrium(scene, parameters, rtol=GRADIENT_RTOL,
                                                   **options).nodes)
    return loss


@pytest.fixture(scope="module")
def lu_gradient(scene, weights, x64):
    return jax.grad(_loss(scene, weights, method="relax+newton"))(THETA)


@pytest.fixture(scope="module")
def jit_gradient(scene, weights, x64):
    return jax.jit(jax.grad(_loss(scene, weights, throw=False)))(THETA)


def _relative(a: Parameters, b: Parameters) -> dict:
    return {name: abs(float(getattr(a, name)) - float(getattr(b, name))) / abs(float(getattr(b, name)))
            for name, value in b.as_dict().items() if value is not None}  # unset rib shapes: no field


def test_jit_matches_the_eager_solve_and_does_not_retrace(scene, compiled):
    solve, traces = compiled
    for pressure in (2e4, 3.5e4):
        parameters = THETA.replace(pressure=pressure)
        sol = solve(parameters)
        eager = solve_equilibrium(scene, parameters, rtol=RTOL)
        assert isinstance(sol, Solution) and sol.converged and sol.result == Result.converged
        assert float(sol.residual) <= RTOL and int(sol.steps) == eager.steps
        np.testing.assert_allclose(np.asarray(sol.nodes), eager.nodes, rtol=0, atol=1e-8)
        np.testing.assert_allclose(np.asarray(sol.tension_chord), eager.tension_chord, rtol=1e-6)
        assert float(sol.parameters.pressure) == pressure
    assert len(traces) == 1  # new values, same program


def test_vmap_batch_matches_eager_solves(scene, batch):
    assert batch.nodes.shape == (len(PRESSURES), 9, 32, 3)
    assert np.all(batch.converged) and batch.raise_if_failed() is batch
    assert np.all(np.asarray(batch.residual) <= RTOL)
    for k, pressure in enumerate(PRESSURES[[0, 3, 7]]):
        index = [0, 3, 7][k]
        eager = solve_equilibrium(scene, THETA.replace(pressure=float(pressure)), rtol=RTOL)
        np.testing.assert_allclose(np.asarray(batch.nodes[index]), eager.nodes, rtol=0, atol=1e-8)
        member = jax.tree_util.tree_map(lambda a: a[index], batch)  # one member of the batch
        assert member.converged and float(member.pressure) == pressure
        assert member.message.startswith("converged")


def test_iterative_gradient_under_jit_matches_the_host_lu(lu_gradient, jit_gradient):
    assert isinstance(jit_gradient, Parameters)
    assert max(_relative(jit_gradient, lu_gradient).values()) <= 1e-6


@pytest.mark.parametrize("name", ["pressure", "prestrain_chord", "rib_thickness_scale"])
def test_gradient_under_jit_matches_central_differences(scene, weights, jit_gradient, name):
    value = getattr(THETA, name)
    h = FD_RELATIVE_STEP * abs(value)
    plus, minus = (solve_equilibrium(scene, THETA.replace(**{name: value + s}), rtol=GRADIENT_RTOL,
                                     method="relax+newton").nodes for s in (h, -h))
    fd = float(np.sum(np.asarray(weights) * (plus - minus)) / (2 * h))
    assert abs(float(getattr(jit_gradient, name)) - fd) <= 1e-5 * abs(fd)


def test_forward_mode_under_jit_and_vmap_of_gradients(scene, weights, jit_gradient):
    loss = _loss(scene, weights, throw=False)
    tangent = jax.jit(lambda p: jax.jvp(loss, (p,), (THETA.replace(
        pressure=1.0, prestrain_span=0.0, prestrain_chord=0.0, stiffness_span=0.0,
        stiffness_chord=0.0, rib_thickness_scale=0.0, rib_chord_scale=0.0),))[1])(THETA)
    assert abs(float(tangent) - float(jit_gradient.pressure)) <= 1e-6 * abs(float(tangent))
    pressures = jnp.asarray([THETA.pressure, 1.5 * THETA.pressure])
    grads = jax.vmap(lambda p: jax.grad(loss)(THETA.replace(pressure=p)))(pressures)
    assert abs(float(grads.pressure[0]) - float(jit_gradient.pressure)) <= 1e-8 * abs(float(tangent))
    assert np.all(np.isfinite(np.asarray(grads.pressure)))


def test_eager_iterative_gradient_is_the_gpu_fallback(scene, weights, lu_gradient, monkeypatch):
    """Where JAX's default backend is not the CPU, the eager derivative avoids the host callback."""
    assert default_linear_solver() == SparseLU()  # this machine
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert default_linear_solver() == BiCGStab()
    with jax.enable_x64(True):
        (_, sol), grad = jax.value_and_grad(
            lambda p: (lambda s: (jnp.sum(weights * s.nodes), s))(
                solve_equilibrium(scene, p, rtol=GRADIENT_RTOL, method="relax+newton")),
            has_aux=True)(THETA)
    assert sol.extra["linear_solver"] == "iterative"
    assert max(_relative(grad, lu_gradient).values()) <= 1e-6


def test_failure_is_returned_not_raised_under_jit(scene, x64):
    def solve(pressure):
        return solve_equilibrium(scene, THETA.replace(pressure=pressure), rtol=RTOL, max_steps=100,
                                 throw=False)

    sols = jax.jit(jax.vmap(solve))(jnp.asarray([2e4, 3e4]))
    assert np.all(np.asarray(sols.result) == Result.max_steps_reached)
    assert not np.any(sols.converged) and np.all(np.isfinite(np.asarray(sols.nodes)))
    with pytest.raises(ConvergenceError, match="2 of 2 solves of the batch failed; the first, at index"):
        sols.raise_if_failed()
    one = jax.jit(solve)(2e4)
    assert one.message.startswith("max_steps_reached")
    with pytest.raises(ConvergenceError, match="max_steps_reached"):
        one.raise_if_failed()


def test_options_the_traced_path_cannot_honour_are_refused(scene, x64):
    def run(**options):
        return jax.jit(lambda p: solve_equilibrium(scene, pressure=p, **options).nodes)(2e4)

    with pytest.raises(TypeError, match="throw=False"):
        run()
    for method in ("newton", "relax+newton", "explicit"):
        with pytest.raises(TypeError, match="method='relax'"):
            run(method=method, throw=False)
    with pytest.raises(TypeError, match="linear_solver='iterative'"):
        run(adjoint=ImplicitAdjoint(linear_solver="lu"), throw=False)
    with pytest.raises(TypeError, match="float64"):
        run(method=Relax(precision="float32"), throw=False)


def test_concrete_solutions_keep_their_python_fields(scene, compiled):
    sol = solve_equilibrium(scene, THETA, rtol=1e-6)
    leaves = jax.tree_util.tree_leaves(sol)
    assert len(leaves) == 4  # nodes, tensions, wrinkle mask; the rest static
    copy = jax.tree_util.tree_map(np.asarray, sol)
    assert isinstance(copy.result, Result) and isinstance(copy.steps, int)
    assert copy.converged is True and copy.parameters == sol.parameters
