"""Derivatives of an equilibrium with a fibre law fitted to a biaxial test and a shear stiffness.

The implicit gradient (the adjoint through the law's tensions and the shear
energy) against central differences in float64, in the pressure, both
prestrains and both stiffnesses, which scale the fitted law (a fabric lot's
scatter). One 5 x 32 NACA 2412 bay (the derivative's agreement does not depend on the grid; 5 x 32
is the suite's smallest); tolerances as in test_gradients.py: 1e-5
relative, steps 1e-4 of each parameter, solves at rtol 1e-12.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from forward_solver.model.biaxial import fit_law
from forward_solver.model.biaxial.synthetic import example_readings
from forward_solver import Fabric, Parameters
from support.solver import default_scene, tight_solve

LAW = fit_law(example_readings())
FABRIC = Fabric(law=LAW, warp="chord", shear_stiffness=3e3)
THETA = Parameters(pressure=2e4, prestrain_span=0.01, prestrain_chord=0.015, stiffness_span=1.05 * FABRIC.stiffness_span,
                   stiffness_chord=0.95 * FABRIC.stiffness_chord)
NAMES = ("pressure", "prestrain_span", "prestrain_chord", "stiffness_span", "stiffness_chord")


@pytest.fixture(scope="module")
def scene():
    return default_scene(5, 32, FABRIC)


@pytest.fixture(scope="module")
def weights():
    return np.random.default_rng(1).normal(size=(5, 32, 3))



@pytest.fixture(scope="module")
def reference(scene):
    return tight_solve(scene, THETA)


@pytest.fixture(scope="module")
def gradient(scene, weights, reference):
    with jax.enable_x64(True):
        return jax.grad(lambda q: jnp.sum(weights * tight_solve(scene, q, initial=reference).nodes))(THETA)


@pytest.mark.parametrize("name", NAMES)
def test_implicit_gradient_with_a_fitted_law_matches_central_differences(scene, weights, reference, gradient, name):
    value = getattr(THETA, name)
    h = 1e-4 * abs(value)
    plus = tight_solve(scene, THETA.replace(**{name: value + h}), reference).nodes
    minus = tight_solve(scene, THETA.replace(**{name: value - h}), reference).nodes
    fd = float(np.sum(weights * (plus - minus)) / (2 * h))
    assert abs(float(getattr(gradient, name)) - fd) <= 1e-5 * abs(fd), (name, float(getattr(gradient, name)), fd)
