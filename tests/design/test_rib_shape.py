"""Rib shape as design variables: the offset, the mounted rib, its derivatives.

The offset is checked against its closed form (Bernstein polynomials sum to
one, so equal coefficients give ``a C(x)``), the mounted rib against the
designed section, and the derivative of the equilibrium in the coefficients
against central differences in float64 (1e-6 relative: solves to rtol 1e-11
and a step of 1e-6 chord leave a truncation and round-off error of about
1e-9 of the derivative) on both the host (sparse LU) and the pure-JAX
(jit, BiCGStab) paths.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from forward_solver import Bay, Fabric, Parameters, Scene, rib_section, solve_equilibrium
from forward_solver.model.rib_shape import bernstein_basis, class_function, offset_basis, rib_offsets
from targets import naca

COEFFICIENTS = np.array([0.01, -0.005, 0.0, 0.002, 0.0, -0.003])
BASE = Parameters(pressure=2e4, prestrain_span=0.005, prestrain_chord=0.005)
OPTIONS = dict(rtol=1e-11, method="relax+newton")


@pytest.fixture(scope="module")
def scene():
    return Scene(Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=9, n_contour=32), Fabric())


@pytest.fixture(scope="module")
def shaped(scene):
    return solve_equilibrium(scene, BASE.replace(rib_shape=COEFFICIENTS), **OPTIONS)


def test_offset_closed_form():
    x = np.linspace(0.0, 1.0, 41)
    contour = np.concatenate([x[::-1], x[1:]])  # trailing edge, upper, nose, lower, trailing edge
    with jax.enable_x64(True):
        np.testing.assert_allclose(np.sum(bernstein_basis(x, 5), axis=1), 1.0, atol=1e-14)
        dz = np.asarray(rib_offsets(contour, np.array([0.02] * 4 + [0.01] * 4)))
        cls = np.asarray(class_function(contour))
        basis = np.asarray(offset_basis(contour, 4))
    upper = np.arange(contour.size) <= 40
    np.testing.assert_allclose(dz[upper], 0.02 * cls[upper], atol=1e-15)  # outward = up
    np.testing.assert_allclose(dz[~upper], -0.01 * cls[~upper], atol=1e-15)  # outward = down
    assert dz[0] == dz[40] == dz[-1] == 0.0  # trailing edge and nose stay where they are
    assert basis.shape == (contour.size, 8)
    np.testing.assert_allclose(cls, np.sqrt(contour) * (1.0 - contour), atol=1e-15)


def test_the_mounted_rib_is_the_designed_section(scene, shaped):
    """The solver's rib nodes lie on `rib_section` (same offset, same thickness scale)."""
    section = rib_section(naca("2412"), COEFFICIENTS, n_points=2001)
    rib = shaped.nodes[0]
    z_rib = rib[:, 2]
    x_rib = rib[:, 0]
    # Compare surface by surface at the rib's x (the section is dense: interpolation error < 1e-7).
    nose = np.argmin(section.x)
    upper_x, upper_z = section.x[: nose + 1][::-1], section.z[: nose + 1][::-1]
    lower_x, lower_z = section.x[nose:], section.z[nose:]
    j_nose = np.argmin(x_rib)
    np.testing.assert_allclose(z_rib[1:j_nose], np.interp(x_rib[1:j_nose], upper_x, upper_z), atol=2e-6)
    np.testing.assert_allclose(z_rib[j_nose + 1:], np.interp(x_rib[j_nose + 1:], lower_x, lower_z), atol=2e-6)
    plain = scene.bay.nominal_nodes()
    moved = np.abs(z_rib - plain[0, :, 2]).max()
    assert 1e-3 < moved < 1e-2  # the offset of these coefficients is millimetres on a 1 m chord
    assert shaped.extra["half_bay"]  # one shape on both ribs keeps the bay symmetric


def test_rib_shape_gradient_matches_central_differences(scene, shaped):
    def bulge(q):
        return solve_equilibrium(scene, q, initial=shaped, **OPTIONS).nodes[4, 10, 2]

    q = BASE.replace(rib_shape=COEFFICIENTS)
    with jax.enable_x64(True):
        grad = np.asarray(jax.grad(bulge)(q).rib_shape)
        for k in (0, 3, 5):
            step = np.zeros_like(COEFFICIENTS)
            step[k] = 1e-6
            fd = (bulge(q.replace(rib_shape=COEFFICIENTS + step))
                  - bulge(q.replace(rib_shape=COEFFICIENTS - step))) / 2e-6
            assert grad[k] == pytest.approx(float(fd), rel=1e-6, abs=1e-9 * np.abs(grad).max())
        # The pure-JAX path (jit; matrix-free BiCGStab adjoint) gives the same derivative.
        traced = jax.jit(jax.grad(lambda c: solve_equilibrium(
            scene, BASE.replace(rib_shape=c), rtol=1e-11, throw=False).nodes[4, 10, 2]))(
                jnp.asarray(COEFFICIENTS))
    np.testing.assert_allclose(np.asarray(traced), grad, rtol=1e-7, atol=1e-9 * np.abs(grad).max())


def test_a_tip_shape_breaks_the_symmetry(scene, shaped):
    tip_plain = solve_equilibrium(scene, BASE.replace(rib_shape=COEFFICIENTS,
                                                      rib_shape_tip=np.zeros(6)), rtol=1e-10)
    assert not tip_plain.extra["half_bay"]
    plain = scene.bay.nominal_nodes()
    np.testing.assert_allclose(tip_plain.nodes[-1], plain[-1], atol=1e-15)  # the tip rib unchanged
    np.testing.assert_allclose(tip_plain.nodes[0], shaped.nodes[0], atol=1e-15)  # the root rib shaped


def test_bad_rib_shapes_are_refused(scene):
    with pytest.raises(ValueError, match="2 K coefficients"):
        solve_equilibrium(scene, BASE.replace(rib_shape=np.zeros(3)))
    with pytest.raises(ValueError, match="finite"):
        solve_equilibrium(scene, BASE.replace(rib_shape=np.array([0.0, np.nan])))
    with pytest.raises(ValueError, match="same number of coefficients"):
        solve_equilibrium(scene, BASE.replace(rib_shape=np.zeros(4), rib_shape_tip=np.zeros(6)))
    with pytest.raises(ValueError, match="needs rib_shape"):
        solve_equilibrium(scene, BASE.replace(rib_shape_tip=np.zeros(4)))
    panel = Scene(Bay.flat_panel(n_span=5, n_contour=9), Fabric())
    with pytest.raises(ValueError, match="flat panel"):
        solve_equilibrium(panel, BASE.replace(rib_shape=np.zeros(4)))


def test_parameters_with_shapes_compare_and_record(shaped):
    q = BASE.replace(rib_shape=COEFFICIENTS)
    assert q == BASE.replace(rib_shape=COEFFICIENTS.copy()) and q != BASE
    recorded = shaped.parameters
    assert isinstance(recorded.rib_shape, np.ndarray) and recorded.rib_shape_tip is None
    np.testing.assert_array_equal(recorded.rib_shape, COEFFICIENTS)
