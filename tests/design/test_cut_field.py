"""The cut as a designed field: basis, cut lengths, derivatives, design, input.

The B-spline basis is checked against its defining properties (partition of
unity, non-negative, end interpolation), the cut lengths against eq. (12)
with the field's local prestrain, a constant field against the uniform
prestrain it stands for (same equilibrium to solver tolerance), the
derivative of the equilibrium in the field's coefficients against central
differences in float64 (1e-6 relative: solves to rtol 1e-11 and a step of
1e-6 leave a truncation and round-off error of about 1e-9 of the
derivative), and a small design with ``cut_pattern`` against the uniform cut.
A wing's per-bay fields (one row per bay) are checked against each bay
solved alone with its row, their derivatives against central differences,
and a per-bay design against the shared field it starts from.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from forward_solver import Bay, Fabric, Parameters, Scene, solve_bays, solve_equilibrium
from forward_solver.model.cut_field import contour_parameter, field_values, spline_basis
from forward_solver import Wing
from inverse_design import DesignRequest, optimise_pressure, optimise_wing
from inverse_design.app.formats import write_cut_pattern
from inverse_design.rib_design import cut_lengths
from inverse_design.variables import DesignVariables
from inverse_design.settings import Layout, SolverSettings
from support.cases import IN_PROCESS, SMALL, case_text
from targets import naca

BASE = Parameters(pressure=2e4, prestrain_span=0.01, prestrain_chord=0.005)
FIELD = np.array([0.0, 0.004, -0.002, 0.006, 0.0, 0.003, -0.001, 0.002])  # K = 4 span, then 4 chord
OTHER = np.array([0.003, -0.001, 0.0, 0.002, -0.002, 0.0, 0.004, 0.001])  # a second bay's field
OPTIONS = dict(rtol=1e-11, method="relax+newton")


@pytest.fixture(scope="module")
def scene():
    return Scene(Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=5, n_contour=32), Fabric())


@pytest.fixture(scope="module")
def patterned(scene):
    return solve_equilibrium(scene, BASE.replace(cut_pattern=FIELD), **OPTIONS)


@pytest.fixture(scope="module")
def other():
    """A second, narrower bay on the same grid (a 2-bay wing with ``scene``)."""
    return Scene(Bay.from_airfoil(naca("2412"), chord=0.9, rib_spacing=0.25, n_span=5, n_contour=32), Fabric())


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


def test_a_wing_shares_the_field(scene, other, patterned):
    """solve_bays gives every bay the one field: a bay of the wing is the bay solved alone."""
    wing = solve_bays([scene, other], BASE.replace(cut_pattern=FIELD), rtol=1e-11, method="relax+newton")
    scale = np.abs(patterned.nodes - scene.bay.nominal_nodes()).max()
    np.testing.assert_allclose(np.asarray(wing.nodes[0]), patterned.nodes, atol=1e-8 * scale)
    alone = solve_equilibrium(other, BASE.replace(cut_pattern=FIELD), **OPTIONS)
    np.testing.assert_allclose(np.asarray(wing.nodes[1]), alone.nodes, atol=1e-8 * scale)


def test_per_bay_fields_cut_each_bay_by_its_own_row(scene, other, patterned):
    """``cut_patterns`` gives bay k row k: each bay equals the bay solved alone with its row (loop and
    batch strategies), and the derivative of bay 1's bulge in its row matches central differences
    while bay 0's row does not move it (rel 1e-6, as the shared field's test)."""
    rows = np.stack([FIELD, OTHER])
    wing = solve_bays([scene, other], BASE, cut_patterns=rows, **OPTIONS)
    scale = np.abs(patterned.nodes - scene.bay.nominal_nodes()).max()
    np.testing.assert_allclose(np.asarray(wing.nodes[0]), patterned.nodes, atol=1e-8 * scale)
    alone = solve_equilibrium(other, BASE.replace(cut_pattern=OTHER), **OPTIONS)
    np.testing.assert_allclose(np.asarray(wing.nodes[1]), alone.nodes, atol=1e-8 * scale)
    np.testing.assert_array_equal(wing.bay_parameters(1).cut_pattern, OTHER)
    assert wing.bay_parameters(0).cut_pattern.tolist() == FIELD.tolist()
    batch = solve_bays([scene, other], BASE, cut_patterns=rows, rtol=1e-11, strategy="batch")
    np.testing.assert_allclose(np.asarray(batch.nodes), np.asarray(wing.nodes), atol=1e-7 * scale)

    def bulge(r):
        return solve_bays([scene, other], BASE, cut_patterns=r, initial=wing, **OPTIONS).nodes[1, 2, 8, 2]

    with jax.enable_x64(True):
        grad = np.asarray(jax.grad(bulge)(jnp.asarray(rows)))
        assert np.all(grad[0] == 0.0) and np.abs(grad[1]).max() > 0
        for k in (2, 5):
            step = np.zeros_like(rows)
            step[1, k] = 1e-6
            fd = (bulge(rows + step) - bulge(rows - step)) / 2e-6
            assert grad[1, k] == pytest.approx(float(fd), rel=1e-6, abs=1e-9 * np.abs(grad).max())
    with pytest.raises(ValueError, match=r"cut_patterns must be an \(2, 2K\) array"):
        solve_bays([scene, other], BASE, cut_patterns=FIELD)
    with pytest.raises(ValueError, match="give the cut fields once"):
        solve_bays([scene, other], BASE.replace(cut_pattern=FIELD), cut_patterns=rows)


def test_per_bay_design_variables():
    """Layout "per_bay": one row per bay after the pressure, bounds on the local prestrain of each."""
    design = DesignVariables.build(("pressure", "cut_pattern"), BASE.replace(cut_pattern=OTHER),
                                   {"cut_pattern": (-0.02, 0.05)}, n_ribs=4, cut_pattern="per_bay")
    assert design.size == 1 + 3 * 8 and design.cut_patterns.shape == (3, 8)
    assert design.start.cut_pattern is None  # the shared parameters carry no field
    u = design.start_vector()
    u[1 + 8 + 3] = 0.5  # bay 1, span coefficient 3: 0.5 x 0.01
    moved = OTHER.copy()
    moved[3] = 0.005
    np.testing.assert_allclose(design.bay_parameters(u, 1).cut_pattern, moved)
    np.testing.assert_allclose(design.bay_parameters(u, 2).cut_pattern, OTHER)
    assert np.asarray(design.values(u)["cut_pattern"]).shape == (3, 8)
    np.testing.assert_allclose(design.from_values(design.values(u)), u)
    span, chord = 0.01, 0.005  # BASE's uniform prestrains, under each bay's span and chord halves
    np.testing.assert_allclose(design.lower[1:] * 0.01, np.tile(np.r_[np.full(4, -0.02 - span),
                                                                        np.full(4, -0.02 - chord)], 3))
    labels = [c[0] for c in design.components(design.start, cut_patterns=design.cut_patterns_at(u))]
    assert labels[1] == "cut_pattern[0][0]" and labels[-1] == "cut_pattern[2][7]"
    with pytest.raises(ValueError, match=r"cut_pattern start must be one row of 2K coefficients for every "
                                         r"bay or an \(3, 2K\) array"):
        DesignVariables.build(("pressure", "cut_pattern"), {"cut_pattern": np.zeros((4, 8))}, None, n_ribs=4,
                              cut_pattern="per_bay")
    with pytest.raises(ValueError, match="cut_pattern must be one of"):
        DesignVariables.build(("pressure", "cut_pattern"), None, None, cut_pattern="per_rib")


def test_a_per_bay_design_from_the_shared_field(scene):
    """A tapered 2-bay wing: per-bay fields started from the shared field's design keep or lower
    its error, inside the local bounds and the wrinkle floor."""
    target = naca("2412")
    wing = Wing(airfoils=(target,) * 3, chords=(1.0, 0.9, 0.6), stations=(0.0, 0.25, 0.5))
    start = {"pressure": 1e4, "prestrain_span": 0.02, "prestrain_chord": 0.0, "cut_pattern": np.zeros(8)}
    bounds = {"pressure": (1e3, 1e5), "cut_pattern": (-0.02, 0.05)}
    options = dict(variables=("pressure", "cut_pattern"), bounds=bounds, solver=SolverSettings(max_iterations=20))
    shared = optimise_wing(wing, Fabric(), request=DesignRequest(initial=start, layout=Layout(n_span=5, n_contour=32),
                                                                 **options))
    best = {**start, "pressure": shared.parameters.pressure, "cut_pattern": shared.parameters.cut_pattern}
    separate = optimise_wing(wing, Fabric(), request=DesignRequest(
        initial=best, layout=Layout(cut_pattern="per_bay", n_span=5, n_contour=32), **options))
    assert shared.success and separate.success, (shared.message, separate.message)
    assert shared.per_bay.cut_patterns is None and separate.per_bay.cut_patterns.shape == (2, 8)
    assert separate.rms_error <= shared.rms_error * (1 + 1e-9)
    rows = separate.per_bay.cut_patterns
    assert np.abs(rows[0] - rows[1]).max() > 1e-4  # the bays differ
    for k, row in enumerate(rows):
        local = field_values(np.linspace(0, 1, 201), 0.02, 0.0, row)
        assert min(v.min() for v in local) >= -0.02 - 1e-9 and max(v.max() for v in local) <= 0.05 + 1e-9
        assert separate.wing_solution.bay_parameters(k).cut_pattern.tolist() == row.tolist()


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
                                initial=start, objective="average", bounds=bounds,
                                solver=SolverSettings(max_iterations=30))
    best = uniform.parameters.replace(stiffness_span=None, stiffness_chord=None)
    field = optimise_pressure(scene, target, variables=("pressure", "cut_pattern"), initial=best,
                              objective="average", bounds={"pressure": (1e3, 1e5), "cut_pattern": (-0.02, 0.05)},
                              solver=SolverSettings(max_iterations=30))
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
    (["--cut-pattern-terms", "0"], "error: argument --cut-pattern-terms: must be 1 or more, got '0' (see optimise-pressure --help)"),
], ids=["bounds", "terms"])
def test_the_command_refuses_a_field_outside_its_bounds(tmp_path, capsys, args, message):
    from inverse_design.app import cli

    out = tmp_path / "out"
    code = cli.main(["--variables", "pressure,cut_pattern", *args, *SMALL, *IN_PROCESS, "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].endswith(message), err
    assert not out.exists()


def test_the_command_designs_a_field_per_bay(tmp_path, capsys):
    """A case file with ``cut-pattern-layout = "per_bay"``: summary.json has a row per bay, the console
    says so, each bay's cut_pattern.csv follows its own row, the folder holds the overview of every bay's
    field (cut_pattern_overview.png; its figure: tests/command/test_cut_field_report.py) and the console
    says the run's peak memory. (The wing, grid and terms of `test_a_per_bay_design_from_the_shared_field`,
    so the two share their compilations; one wing solve: this checks the plumbing, the design is checked there.)"""
    import json

    from inverse_design.app import cli

    case = tmp_path / "wing.toml"
    case.write_text(case_text(("naca2412", 1.0, 0.0), ("naca2412", 0.9, 0.25), ("naca2412", 0.6, 0.5),
                              variables=["pressure", "cut_pattern"], cut_pattern_terms=4, cut_pattern_layout="per_bay",
                              prestrain_chord=0.0, n_span=5, n_contour=32, max_iterations=1))
    out = tmp_path / "out"
    code = cli.main(["--config", str(case), "--out", str(out), "--no-compilation-cache", "--no-patterns"])
    captured = capsys.readouterr()
    assert code in (0, 1), captured.err
    summary = json.loads((out / "summary.json").read_text())
    rows = np.asarray(summary["results"]["cut_patterns"])
    assert rows.shape == (2, 8) and summary["results"]["values"]["cut_pattern"] is None
    local = summary["results"]["cut_pattern_local"]
    assert local["span"][0] <= local["span"][1] and local["chord"][0] <= local["chord"][1]
    assert "a cut field per bay (bay_K_cut_pattern.csv; local prestrain span" in captured.out
    assert {"cut_pattern_overview.png", "bay_0_cut_pattern.csv", "bay_1_cut_pattern.csv"} <= set(summary["files"])
    assert (out / "cut_pattern_overview.png").stat().st_size
    peak = summary["timings_s"]["peak_memory_mb"]
    assert 50 < peak < 1e5 and f"peak memory {peak:.0f} MB" in captured.out
    p = summary["results"]["values"]
    for k in range(2):
        table = np.genfromtxt(out / f"bay_{k}_cut_pattern.csv", delimiter=",", skip_header=2, names=True,
                              dtype=None, encoding="utf-8")
        assert table["span_prestrain"].min() >= min(rows[k, :4]) + p["prestrain_span"] - 1e-6
        assert table["span_prestrain"].max() <= max(rows[k, :4]) + p["prestrain_span"] + 1e-6
    with np.load(out / "wing.npz") as npz:
        np.testing.assert_allclose(npz["cut_patterns"], rows, rtol=1e-12)
