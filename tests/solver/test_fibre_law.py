"""The fibre law in the force kernel (`forward_solver.model.fibre_law`): eq. (10) and a fitted surface.

A surface fitted to eq. (10)'s own readings is eq. (10) in the kernel; a
fitted law's cell tensions are the law's at the cells' strains, the warp
along the span or the chord, scaled by the stiffnesses; its stiffness bound
holds the relaxation's masses; the returned equilibrium satisfies the
independent residual.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from forward_solver.model.biaxial import fit_law
from forward_solver.model.biaxial.synthetic import example_readings, linear_law, synthetic_test
from forward_solver import Bay, Fabric, Scene, simulate, solve_equilibrium
from forward_solver import forces as fk
from forward_solver.model.fibre_law import LinearLaw, SurfaceLaw
from forward_solver.model.parameters import Parameters
from forward_solver.reference.independent_residual import numpy_residual
from support.solver import default_bay


@pytest.fixture(scope="module")
def example():
    return fit_law(example_readings())


@pytest.fixture(scope="module")
def eq10():
    """The surface fitted to readings of eq. (10), 2e5 N/m both ways, Poisson 0.25, on the five paths."""
    return fit_law(synthetic_test(linear_law(2e5, 2e5, 0.25), 8000.0))


def _state(fabric, parameters=Parameters(2e4, 0.01, 0.02), seed=0, amplitude=0.004):
    bay = default_bay(5, 32)
    scene = Scene(bay, fabric)
    physics = scene.physics(dynamic=False)
    params = scene.params(parameters)
    ref = fk.prepare(bay.geometry(), params, physics)
    x = ref.nodes + jnp.asarray(amplitude * np.random.default_rng(seed).standard_normal(ref.nodes.shape))
    return physics, params, ref, x


def test_the_default_law_is_eq_10():
    assert Fabric().fibre_law == LinearLaw() and Fabric().law is None
    assert (Fabric().stiffness_span, Fabric().stiffness_chord, Fabric().poisson) == (2e5, 2e5, 0.25)
    assert Fabric(stiffness_span=3e5).stiffness_span == 3e5


@pytest.mark.parametrize("warp", ["span", "chord"])
def test_a_surface_fitted_to_eq_10_is_eq_10_in_the_kernel(x64, eq10, warp):
    # The fit reproduces eq. (10)'s readings to rounding (it is a reciprocal linear law), its nominal
    # stiffness is eq. (10)'s E and its coupling nu, so the kernel's forces agree to 1e-12.
    assert max(eq10.rms_error) < 1e-9 and eq10.surface.degree == 4
    assert eq10.stiffness_warp == pytest.approx(2e5, rel=1e-12) and eq10.poisson == pytest.approx(0.25, rel=1e-12)
    fitted = Fabric(law=eq10, warp=warp)
    assert isinstance(fitted.fibre_law, SurfaceLaw)
    physics, params, ref, x = _state(Fabric())
    f_linear = fk.forces(x, ref, params, physics)
    physics, params, ref, x = _state(fitted)
    f_fitted = fk.forces(x, ref, params, physics)
    scale = float(jnp.max(jnp.abs(f_linear.total)))
    np.testing.assert_allclose(np.asarray(f_fitted.total), np.asarray(f_linear.total), atol=1e-12 * scale)
    np.testing.assert_allclose(np.asarray(f_fitted.tension_span), np.asarray(f_linear.tension_span),
                               rtol=1e-11, atol=1e-9)


@pytest.mark.parametrize("warp", ["span", "chord"])
def test_a_fitted_law_gives_each_cell_the_laws_tensions(x64, example, warp):
    # Unclamped tensions at a perturbed state (strains inside and outside the tested range) against the
    # law evaluated in NumPy at the cells' strains, warp along the span or the chord; a stiffness
    # twice the nominal doubles that direction's tensions alone (a lot's scale).
    fabric = Fabric(law=example, warp=warp)
    physics, params, ref, x = _state(fabric, amplitude=0.01)
    physics = dataclasses.replace(physics, tension_only=False)
    fib = fk.fibres(x, ref, params, physics)
    e_span, e_chord = np.asarray(fib.strain_span), np.asarray(fib.strain_chord)
    assert not example.surface.inside(e_span, e_chord).all()  # (the continuation is checked too)
    pairs = (e_span, e_chord) if warp == "span" else (e_chord, e_span)
    t_warp, t_weft = example.tensions(*pairs)
    t_span, t_chord = (t_warp, t_weft) if warp == "span" else (t_weft, t_warp)
    np.testing.assert_allclose(np.asarray(fib.tension_span), t_span, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(np.asarray(fib.tension_chord), t_chord, rtol=1e-12, atol=1e-9)
    doubled = fk.fibres(x, ref, params._replace(stiffness_span=2.0 * params.stiffness_span), physics)
    np.testing.assert_allclose(np.asarray(doubled.tension_span), 2.0 * t_span, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(np.asarray(doubled.tension_chord), t_chord, rtol=1e-12, atol=1e-9)
    assert fabric.stiffness_span == (example.stiffness_warp if warp == "span" else example.stiffness_weft)


def test_a_fitted_laws_bound_holds_its_tangent(x64, example):
    # The stiffness bound is at least every cell's tangent row sum (at the current strains, by forward
    # derivatives) and the tested range's; the masses of a fitted law bound the assembled Jacobian as
    # eq. (10)'s do theirs: rows at most 1.8 times the node's bound (measured 0.9-0.94 here, eq. (10) 1.4-1.7).
    fabric = Fabric(law=example)
    physics, params, ref, x = _state(fabric, amplitude=0.004)
    fib = fk.fibres(x, ref, params, physics)
    law = physics.law
    bound = float(law.stiffness_bound(params, fib.strain_span, fib.strain_chord))
    kww, kwf, kff = example.surface.tangent(*example.surface.grid())
    assert bound >= max(np.max(np.abs(kww) + np.abs(kwf)), np.max(np.abs(kwf) + np.abs(kff))) * (1 - 1e-12)
    jac = jax.jacfwd(lambda e: jnp.stack(law.tensions(e[0], e[1], params)))(
        jnp.stack([fib.strain_span, fib.strain_chord]))  # (2, ...cells, 2, ...cells): diagonal in the cells
    rows = np.abs(np.einsum("aijbij->aijb", np.asarray(jac))).sum(axis=-1)
    assert bound >= np.max(rows) * (1 - 1e-12)
    jacobian = jax.jacfwd(lambda y: fk.residual(y, ref, params, physics).reshape(-1))(x)
    rows = np.abs(np.asarray(jacobian.reshape(ref.nodes.size, -1))).sum(axis=1).reshape(ref.nodes.shape).max(-1)
    stiffness = np.asarray(fk.node_stiffness(x, ref, params, physics))
    free = np.asarray(ref.free[..., 0]) > 0
    assert np.max(rows[free] / stiffness[free]) < 1.8


def test_the_equilibrium_of_a_fitted_law_satisfies_an_independent_residual(example):
    bay = default_bay(7, 32)
    for fabric in (Fabric(law=example, warp="chord", stiffness_span=1.1 * example.stiffness_weft),
                   Fabric(law=example, shear_stiffness=4e3)):
        sol = solve_equilibrium(Scene(bay, fabric), 2e4, (0.005, 0.01), rtol=1e-10)
        r = numpy_residual(bay, fabric, sol.nodes, 2e4, (0.005, 0.01))
        assert np.linalg.norm(r) / (2e4 * bay.skin_area()) < 1e-10 + 1e-12


def test_relaxation_and_newton_agree_with_a_fitted_law(example):
    scene = Scene(default_bay(9, 32), Fabric(law=example))
    relaxed = solve_equilibrium(scene, 2e4, (0.005, 0.005), rtol=1e-10, method="relax")
    newton = solve_equilibrium(scene, 2e4, (0.005, 0.005), rtol=1e-10, method="newton")
    assert relaxed.converged and newton.converged
    assert np.max(np.abs(relaxed.nodes - newton.nodes)) < 1e-7


def test_the_papers_scheme_takes_the_laws_stiffest_tangent(example):
    # Eq. (16): c = sqrt(E_max / rho0) with E_max the law's largest diagonal tangent over the tested
    # range (above its nominal stiffness: the law stiffens), so the step is shorter than eq. (10)'s
    # at the nominal stiffness; the run stays stable (no divergence, finite).
    bay = Bay.flat_panel(width=0.25, length=0.5, n_span=5, n_contour=9)
    runs = [simulate(Scene(bay, fabric), 2e3, (0.01, 0.01), max_steps=400, throw=False)
            for fabric in (Fabric(stiffness_span=example.stiffness_warp, stiffness_chord=example.stiffness_weft),
                           Fabric(law=example))]
    dt = [run.extra["dt"] for run in runs]
    bounds = example.surface.tangent_bounds()
    assert bounds["diagonal_warp"] > example.stiffness_warp
    assert dt[1] < dt[0]
    assert np.isfinite(runs[1].nodes).all() and runs[1].result.name != "diverged"
