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
from inverse_design.app.export import write_cut_pattern
from inverse_design.rib_design import cut_lengths
from inverse_design.variables import DesignVariables
from targets import naca

BASE = Parameters(pressure=2e4, prestrain_span=0.01, prestrain_chord=0.005)
FIELD = np.array([0.0, 0.004, -0.002, 0.006, 0.0, 0.003, -0.001, 0.002])  # K = 4 span, then 4 chord
OPTIONS = dict(rtol=1e-11, method="relax+newton")


@pytest.fixture(scope="module")
def scene():
    return Scene(Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=5, n_contour=32), Fabric())


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


def test_cut_lengths_follow_the_field(scene, tmp_path):
    """Eq. (12) with the local prestrain: cut length x (1 + local prestrain) = mounted length."""
    cuts = cut_lengths(scene, BASE.replace(cut_pattern=FIELD))
    plain = cut_lengths(scene, BASE)
    geometry = scene.bay
    with jax.enable_x64(True):
        s_nodes, s_edges = (np.asarray(v) for v in contour_parameter(
            jnp.asarray(geometry.contour_root), jnp.asarray(geometry.contour_tip), True))
    span, chord = field_values(s_nodes, 0.01, 0.005, FIELD)
    _, chord_edges = field_values(s_edges, 0.01, 0.005, FIELD)
    np.testing.assert_allclose(cuts["span_prestrain"], span, atol=1e-15)
    np.testing.assert_allclose(cuts["contour_prestrain"], chord_edges, atol=1e-15)
    np.testing.assert_allclose(cuts["span_cut_m"] * (1 + span), plain["span_cut_m"] * 1.01, rtol=1e-13)
    np.testing.assert_allclose(cuts["contour_edge_cut_m"] * (1 + chord_edges),
                               plain["contour_edge_cut_m"] * 1.005, rtol=1e-13)
    np.testing.assert_allclose(cuts["span_mounted_m"], plain["span_mounted_m"], rtol=1e-13)
    assert np.ptp(cuts["span_prestrain"]) > 1e-3  # the field varies along the contour
    write_cut_pattern(tmp_path / "cut_pattern.csv", scene, BASE.replace(cut_pattern=FIELD))
    rows = np.genfromtxt(tmp_path / "cut_pattern.csv", delimiter=",", skip_header=2, names=True, dtype=None,
                         encoding="utf-8")
    np.testing.assert_allclose(rows["span_prestrain"], span, rtol=1e-5)  # 6 significant digits in the file
    np.testing.assert_allclose(rows["contour_prestrain"], chord_edges, rtol=1e-5)
    np.testing.assert_allclose(rows["span_cut_m"], cuts["span_cut_m"], atol=1e-6)


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
        return solve_equilibrium(scene, q, initial=patterned, **OPTIONS).nodes[2, 8, 2]

    q = BASE.replace(cut_pattern=FIELD)
    with jax.enable_x64(True):
        grad = np.asarray(jax.grad(bulge)(q).cut_pattern)
        for k in (1, 6):
            step = np.zeros_like(FIELD)
            step[k] = 1e-6
            fd = (bulge(q.replace(cut_pattern=FIELD + step)) - bulge(q.replace(cut_pattern=FIELD - step))) / 2e-6
            assert grad[k] == pytest.approx(float(fd), rel=1e-6, abs=1e-9 * np.abs(grad).max())
    assert np.abs(grad).max() > 0


def test_a_wing_shares_the_field(scene, patterned):
    """solve_bays gives every bay the one field: a bay of the wing is the bay solved alone."""
    other = Scene(Bay.from_airfoil(naca("2412"), chord=0.9, rib_spacing=0.25, n_span=5, n_contour=32), Fabric())
    wing = solve_bays([scene, other], BASE.replace(cut_pattern=FIELD), rtol=1e-11, method="relax+newton")
    scale = np.abs(patterned.nodes - scene.bay.nominal_nodes()).max()
    np.testing.assert_allclose(np.asarray(wing.nodes[0]), patterned.nodes, atol=1e-8 * scale)
    alone = solve_equilibrium(other, BASE.replace(cut_pattern=FIELD), **OPTIONS)
    np.testing.assert_allclose(np.asarray(wing.nodes[1]), alone.nodes, atol=1e-8 * scale)


def test_a_cut_pattern_design_from_the_best_uniform_cut(scene):
    """The field, started from the best uniform cut within the same bounds, keeps or lowers its error,
    inside the local prestrain bounds and the wrinkle floor.

    Both designs carry a cut pattern (zero and fixed in the uniform one), so they share compilations.
    Measured on this grid: 4.35e-4 -> 4.31e-4 (-1%); on 17x64 see benchmarks/cut_field.py.
    """
    target = naca("2412")
    start = Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.0, cut_pattern=np.zeros(4))
    bounds = {"pressure": (1e3, 1e5), "prestrain_span": (-0.02, 0.05), "prestrain_chord": (-0.02, 0.05)}
    uniform = optimise_pressure(scene, target, variables=("pressure", "prestrain_span", "prestrain_chord"),
                                initial=start, objective="average", max_iterations=30, bounds=bounds)
    best = uniform.parameters.replace(stiffness_span=None, stiffness_chord=None)
    field = optimise_pressure(scene, target, variables=("pressure", "cut_pattern"), initial=best,
                              objective="average", max_iterations=30,
                              bounds={"pressure": (1e3, 1e5), "cut_pattern": (-0.02, 0.05)})
    assert uniform.success and field.success
    assert uniform.parameters.prestrain_chord < -0.005  # the best uniform cut has the contour fabric cut long
    assert field.rms_error <= uniform.rms_error * (1 + 1e-9)
    local = field_values(np.linspace(0, 1, 201), *best.prestrain, field.parameters.cut_pattern)
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


@pytest.mark.parametrize("args, message", [
    (["--cut-pattern-bounds", "0.03", "0.05"],
     "error: the starting cut pattern's local prestrain reaches 0.02..0.02 (uniform prestrain plus each "
     "coefficient), outside its bounds (0.03, 0.05): change the bounds or the starting prestrains"),
    (["--cut-pattern-terms", "0"], "error: --cut-pattern-terms must be at least 1, got 0"),
], ids=["bounds", "terms"])
def test_the_command_refuses_a_field_outside_its_bounds(tmp_path, capsys, args, message):
    from inverse_design.app import cli

    out = tmp_path / "out"
    code = cli.main(["--variables", "pressure,cut_pattern", *args, "--n-span", "5", "--n-contour", "32",
                     "--no-compilation-cache", "--quiet", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].endswith(message), err
    assert not out.exists()
