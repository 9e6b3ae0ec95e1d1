"""The cut as a designed field (issue 21, items 1 and 5): basis, cut lengths, derivatives, design, input.

The B-spline basis is checked against its defining properties (partition of
unity, non-negative, end interpolation), the cut lengths against eq. (12)
with the field's local prestrain, a constant field against the uniform
prestrain it stands for (same equilibrium to solver tolerance), the
derivative of the equilibrium in the field's coefficients against central
differences in float64 (1e-6 relative: solves to rtol 1e-11 and a step of
1e-6 leave a truncation and round-off error of about 1e-9 of the
derivative), and a small design with ``cut_pattern`` against the uniform cut.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from forward_solver import Bay, Fabric, Parameters, Scene, solve_bays, solve_equilibrium
from forward_solver.cut_field import contour_parameter, field_values, spline_basis
from inverse_design import optimise_pressure
from inverse_design.rib_design import cut_lengths
from inverse_design.variables import DesignVariables
from targets import naca

BASE = Parameters(pressure=2e4, prestrain_span=0.01, prestrain_chord=0.005)
FIELD = np.array([0.0, 0.004, -0.002, 0.006, 0.0, 0.003, -0.001, 0.002])  # K = 4 span, then 4 chord
OPTIONS = dict(rtol=1e-11, method="relax+newton")


@pytest.fixture(scope="module")
def scene():
    return Scene(Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=9, n_contour=32), Fabric())


@pytest.fixture(scope="module")
def patterned(scene):
    return solve_equilibrium(scene, BASE.replace(cut_pattern=FIELD), **OPTIONS)


def test_basis_is_a_partition_of_unity():
    s = np.linspace(0.0, 1.0, 101)
    with jax.enable_x64(True):
        for k in (1, 2, 3, 6, 12):
            basis = np.asarray(spline_basis(jnp.asarray(s), k))
            assert basis.shape == (101, k)
            np.testing.assert_allclose(basis.sum(axis=1), 1.0, atol=1e-14)
            assert basis.min() >= 0.0
            assert basis[0, 0] == pytest.approx(1.0) and basis[-1, -1] == pytest.approx(1.0)  # clamped ends
    span, chord = field_values(s, 0.01, 0.0, np.r_[np.full(6, 0.02), np.linspace(0.0, 0.03, 6)])
    np.testing.assert_allclose(span, 0.03, atol=1e-15)  # a constant field adds its constant
    assert 0.0 <= chord.min() and chord.max() <= 0.03  # the convex hull of the coefficients


def test_cut_lengths_follow_the_field(scene):
    """Eq. (12) with the local prestrain: cut length x (1 + local prestrain) = mounted length."""
    cuts = cut_lengths(scene, BASE.replace(cut_pattern=FIELD))
    plain = cut_lengths(scene, BASE)
    geometry = scene.bay
    s_nodes, s_edges = (np.asarray(v) for v in contour_parameter(geometry.contour_root, geometry.contour_tip, True))
    span, chord = field_values(s_nodes, 0.01, 0.005, FIELD)
    _, chord_edges = field_values(s_edges, 0.01, 0.005, FIELD)
    np.testing.assert_allclose(cuts["span_prestrain"], span, atol=1e-15)
    np.testing.assert_allclose(cuts["contour_prestrain"], chord_edges, atol=1e-15)
    np.testing.assert_allclose(cuts["span_cut_m"] * (1 + span), plain["span_cut_m"] * 1.01, rtol=1e-13)
    np.testing.assert_allclose(cuts["contour_edge_cut_m"] * (1 + chord_edges),
                               plain["contour_edge_cut_m"] * 1.005, rtol=1e-13)
    np.testing.assert_allclose(cuts["span_mounted_m"], plain["span_mounted_m"], rtol=1e-13)
    assert np.ptp(cuts["span_prestrain"]) > 1e-3  # the field varies along the contour


def test_a_constant_field_is_the_uniform_prestrain(scene, patterned):
    uniform = solve_equilibrium(scene, BASE.replace(prestrain_span=0.013, prestrain_chord=0.002), **OPTIONS)
    constant = solve_equilibrium(scene, BASE.replace(cut_pattern=np.r_[np.full(4, 0.003), np.full(4, -0.003)]),
                                 **OPTIONS)
    scale = np.abs(uniform.nodes - scene.bay.nominal_nodes()).max()
    np.testing.assert_allclose(constant.nodes, uniform.nodes, atol=1e-9 * scale)
    zero = solve_equilibrium(scene, BASE.replace(cut_pattern=np.zeros(8)), **OPTIONS)
    np.testing.assert_allclose(zero.nodes, solve_equilibrium(scene, BASE, **OPTIONS).nodes, atol=1e-9 * scale)
    assert np.abs(patterned.nodes - zero.nodes).max() > 1e-4  # a varying field moves the skin
    assert patterned.extra["half_bay"]  # the field varies along the contour: the bay stays symmetric


def test_field_gradient_matches_central_differences(scene, patterned):
    def bulge(q):
        return solve_equilibrium(scene, q, initial=patterned, **OPTIONS).nodes[4, 8, 2]

    q = BASE.replace(cut_pattern=FIELD)
    with jax.enable_x64(True):
        grad = np.asarray(jax.grad(bulge)(q).cut_pattern)
        for k in (1, 3, 6):
            step = np.zeros_like(FIELD)
            step[k] = 1e-6
            fd = (bulge(q.replace(cut_pattern=FIELD + step)) - bulge(q.replace(cut_pattern=FIELD - step))) / 2e-6
            assert grad[k] == pytest.approx(float(fd), rel=1e-6, abs=1e-9 * np.abs(grad).max())
    assert np.abs(grad).max() > 0


def test_field_gradient_through_two_bays():
    """A wing's bays share one field; the derivative through solve_bays agrees with central differences."""
    scenes = [Scene(Bay.from_airfoil(naca("2412"), chord=c, rib_spacing=0.25, n_span=5, n_contour=32), Fabric())
              for c in (1.0, 0.9)]

    def bulge(c):
        wing = solve_bays(scenes, BASE.replace(cut_pattern=c), rtol=1e-11, method="relax+newton")
        return wing.nodes[1, 2, 8, 2] + wing.nodes[0, 2, 20, 2]

    with jax.enable_x64(True):
        grad = np.asarray(jax.grad(bulge)(jnp.asarray(FIELD)))
        k, step = 5, np.eye(FIELD.size)[5] * 1e-6
        fd = (bulge(FIELD + step) - bulge(FIELD - step)) / 2e-6
    assert grad[k] == pytest.approx(float(fd), rel=1e-6, abs=1e-9 * np.abs(grad).max())


def test_a_cut_pattern_design_beats_the_uniform_cut():
    scene = Scene(Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=5, n_contour=32), Fabric())
    target = naca("2412")
    start = Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.0)
    common = dict(objective="average", max_iterations=30, bounds={"pressure": (1e3, 1e5)})
    uniform = optimise_pressure(scene, target, variables=("pressure", "prestrain_span", "prestrain_chord"),
                                initial=start, **common)
    bounds = {"pressure": (1e3, 1e5), "cut_pattern": (-0.02, 0.05)}
    field = optimise_pressure(scene, target, variables=("pressure", "cut_pattern"),
                              initial=start.replace(cut_pattern=np.zeros(8)), **{**common, "bounds": bounds})
    assert uniform.success and field.success
    assert field.rms_error < 0.9 * uniform.rms_error
    local = field_values(np.linspace(0, 1, 201), 0.02, 0.0, field.parameters.cut_pattern)
    assert min(v.min() for v in local) >= -0.02 - 1e-9 and max(v.max() for v in local) <= 0.05 + 1e-9
    assert min(np.min(field.solution.tension_span), np.min(field.solution.tension_chord)) >= -1e-6


def test_bad_fields_are_refused(scene):
    with pytest.raises(ValueError, match="2 K coefficients"):
        solve_equilibrium(scene, BASE.replace(cut_pattern=np.zeros(3)))
    with pytest.raises(ValueError, match="finite"):
        solve_equilibrium(scene, BASE.replace(cut_pattern=np.array([0.0, np.nan])))
    with pytest.raises(ValueError, match=r"local prestrain_span .* must lie in \(-0.5, 1.0\)"):
        solve_equilibrium(scene, BASE.replace(cut_pattern=np.array([0.0, -0.6, 0.0, 0.0])))
    start = BASE.replace(cut_pattern=np.array([0.0, 0.05, 0.0, 0.0]))  # local span prestrain up to 0.06
    with pytest.raises(ValueError, match=r"starting cut pattern's local prestrain reaches 0.005..0.06"):
        DesignVariables.build(("pressure", "cut_pattern"), start, {"cut_pattern": (-0.02, 0.05)})
    with pytest.raises(ValueError, match="optimise cut_pattern or prestrain_span, not both"):
        DesignVariables.build(("pressure", "prestrain_span", "cut_pattern"), BASE, None)
    with pytest.raises(ValueError, match=r"bounds of cut_pattern must lie in \(-0.5, 1.0\)"):
        DesignVariables.build(("pressure", "cut_pattern"), BASE, {"cut_pattern": (-0.7, 0.05)})
    design = DesignVariables.build(("pressure", "cut_pattern"), BASE, {"cut_pattern": (-0.02, 0.05)})
    assert design.size == 13  # pressure and 2 x 6 coefficients (the default terms)
    np.testing.assert_allclose(design.lower[1:7] * 0.01, -0.03)  # local bound less the uniform span prestrain
    np.testing.assert_allclose(design.upper[7:] * 0.01, 0.045)
