"""The wing design loop: one pressure for every bay of a tapered wing.

One 3-bay wing on 9x32 grids is shared by the gradient, optimum and limit
tests (its bays' solves compile once): chords 1.0 -> 0.8 -> 0.7 -> 0.6 m, stations 0.25 m apart, NACA
2412 ribs except a NACA 4415 tip rib, so the last bay compares its rows with
sections blended between two different airfoils. A one-bay wing is checked
against `optimise_pressure` on the same bay.
"""

import jax
import numpy as np
import pytest

from forward_solver import Bay, Fabric, Scene
from forward_solver import Wing
from inverse_design import Constraints, DesignRequest, optimise_pressure, optimise_wing
from inverse_design.constraints import VIOLATION_TOLERANCE
from inverse_design.objectives import WingTargets, bay_distances, bay_weights, row_targets
from inverse_design.problem import DesignProblem
from forward_solver.solution import BaysConvergenceError
from inverse_design.rib_design import RibGeometry, RibLimits
from inverse_design.variables import DesignVariables
from inverse_design.settings import Layout, Limits, SolverSettings
from targets import naca

GRID = dict(n_span=9, n_contour=32)
LAYOUT = Layout(**GRID)
START = {"pressure": 3e4, "prestrain_span": 0.02, "prestrain_chord": 0.02}
BOUNDS = {"pressure": (1e3, 1e5)}


@pytest.fixture(scope="module")
def wing():
    root, tip = naca("2412"), naca("4415")
    return Wing(airfoils=(root, root, root, tip), chords=(1.0, 0.8, 0.7, 0.6), stations=(0.0, 0.25, 0.5, 0.75))


@pytest.fixture(scope="module")
def design(wing):
    return optimise_wing(wing, Fabric(), request=DesignRequest(initial=START, bounds=BOUNDS, layout=LAYOUT,
                                                               solver=SolverSettings(max_iterations=30)))


def _problem(wing, variables, rtol, **options):
    """The design problem of ``wing`` on the test grid, objective "average", tension limits the defaults."""
    scenes = wing.scenes(Fabric(), **GRID)
    return DesignProblem(scenes, WingTargets([s.bay for s in scenes], wing.airfoils, "average"), variables,
                         tension=Constraints(), solver=SolverSettings(rtol=rtol, **options.pop("solver", {})),
                         **options)


def test_objective_and_constraint_gradients_match_central_differences(wing):
    # Solves to rtol 1e-12 (node error ~1e-12 m) against a step of 1e-4 of the pressure: the
    # difference quotient's truncation (~1e-8 relative) and round-off stay far below 1e-5.
    with jax.enable_x64(True):
        variables = DesignVariables.build(("pressure",), START, BOUNDS, n_ribs=4, rib_shape="per_rib")
        problem = _problem(wing, variables, 1e-12)
        u = np.array([1.0])
        f, grad, g, dg, _ = problem.evaluate(u)
        h = 1e-4
        fp, _, gp, _, _ = problem.evaluate(u + h)
        fm, _, gm, _, _ = problem.evaluate(u - h)
    assert grad[0] == pytest.approx((fp - fm) / (2 * h), rel=1e-5)
    assert dg[0, 0] == pytest.approx((gp[0] - gm[0]) / (2 * h), rel=1e-5)
    assert abs(grad[0]) > 1e-3 * f  # the objective does depend on the pressure


def test_measure_reads_what_the_evaluation_computed(wing):
    """`DesignProblem.measure` at an evaluated iterate takes the distances and tensions the
    evaluation computed (no second program of either), the same values as computing them again;
    for another solve at the same vector (other nodes) it computes them."""
    import dataclasses

    with jax.enable_x64(True):
        variables = DesignVariables.build(("pressure",), START, BOUNDS, n_ribs=4, rib_shape="per_rib")
        problem = _problem(wing, variables, 1e-12)
        u = np.array([1.0])
        sol = problem.evaluate(u)[-1]
        calls = []
        computed = problem.distances
        problem.distances = lambda nodes: calls.append(1) or computed(nodes)
        kept = problem.measure(sol, u)
        assert not calls
        other = problem.measure(dataclasses.replace(sol, nodes=np.array(sol.nodes)), u)
        assert len(calls) == 1
    for name in ("rms", "max", "min_tension", "max_tension"):
        np.testing.assert_allclose(kept[name], other[name], rtol=1e-12, atol=0)
    assert kept["wing_rms"] == pytest.approx(other["wing_rms"], rel=1e-12)


def test_per_rib_shape_gradients_match_central_differences(wing):
    # The design vector: pressure, then 4 ribs x 4 coefficients (K = 2). Coefficient 1 of rib 1
    # moves bays 0 and 1 (its tip and root); the objective's and the wrinkle row's derivatives
    # in it and in the pressure must match central differences (steps of 2e-4 in the scaled
    # variables: rel 1e-5). The wrinkle row's derivative in the coefficient is small (1.5e-5 per
    # unit), so the solves go to rtol 1e-13: at 1e-12 their noise alone moved the difference
    # quotient by 3e-5 relative (measured; at 1e-13 it agrees to 1e-6 for steps 1e-4 to 4e-4).
    # The rib-limit rows follow the tension row.
    shapes = 0.01 * np.array([[0.0, 0.5, 0.0, -0.5], [-0.5, 0.5, 0.5, -0.5], [0.5, -0.5, 0.0, 0.5],
                              [0.5, 0.5, -0.5, 0.0]])
    with jax.enable_x64(True):
        variables = DesignVariables.build(("pressure", "rib_shape"), {**START, "rib_shape": shapes}, BOUNDS,
                                          n_ribs=4, rib_shape="per_rib")
        problem = _problem(wing, variables, 1e-13, solver={"max_steps": 400_000},
                           ribs=[(k, RibGeometry(af, RibLimits())) for k, af in enumerate(wing.airfoils)])
        u = variables.start_vector()
        assert u.size == 1 + 16
        f, grad, g, dg, _ = problem.evaluate(u)
        assert g.size == 1 + 4 * problem.ribs[0][1].functions(
            variables.bay_parameters(u, 0)).size  # wrinkle row, then every rib's limit rows
        h = 2e-4
        for index in (0, 1 + 4 + 1):  # the pressure; rib 1's coefficient 1
            step = np.zeros_like(u)
            step[index] = h
            fp, _, gp, _, _ = problem.evaluate(u + step)
            fm, _, gm, _, _ = problem.evaluate(u - step)
            assert grad[index] == pytest.approx((fp - fm) / (2 * h), rel=1e-5), index
            assert dg[0, index] == pytest.approx((gp[0] - gm[0]) / (2 * h), rel=1e-5), index
            np.testing.assert_allclose(dg[1:, index], (gp[1:] - gm[1:]) / (2 * h), rtol=1e-5, atol=1e-7)
        assert abs(grad[1 + 4 + 1]) > 1e-3 * f  # the rib shape does move the skin


def test_the_mounted_skin_of_a_mixed_bay_lies_on_its_row_targets():
    # Ribs equal to their targets: the mounted (ruled) skin between a NACA 2412 rib of 0.7 m and a
    # NACA 4415 rib of 0.6 m is the blended target surface, so every row is within the blend's
    # resampling error (401 points: 2.3e-7 chord measured; bound 1e-6), where comparing the rows
    # with the root section alone would report up to 3.4e-2 chord.
    root, tip = naca("2412"), naca("4415")
    bay = Bay.from_airfoil(root, chord=0.7, rib_spacing=0.25, tip_airfoil=tip, tip_chord=0.6, **GRID)
    etas = np.linspace(0.0, 1.0, GRID["n_span"])
    chords = [(1 - e) * 0.7 + e * 0.6 for e in etas]
    with jax.enable_x64(True):
        nodes = np.asarray(bay.nominal_nodes())
        blended = np.asarray(bay_distances(nodes, row_targets(root, tip, 0.7, 0.6, etas), etas, chords))
        naive = np.asarray(bay_distances(nodes, [root] * len(etas), etas, chords))
    assert np.max(np.abs(blended)) < 1e-6
    assert np.max(np.abs(naive[-1])) > 1e-2


def test_blended_rows_run_from_the_root_to_the_tip_section():
    root, tip = naca("2412"), naca("4415")
    rows = row_targets(root, tip, 1.0, 0.6, np.linspace(0.0, 1.0, 5))
    assert rows[0] is root and rows[-1] is tip
    thickness = [r.max_thickness for r in rows]
    assert np.all(np.diff(thickness) > 0)  # 12% -> 15%, monotone along the span
    # Same section both sides (another instance of it too): the airfoil itself, whatever the taper.
    assert all(r is root for r in row_targets(root, naca("2412"), 1.0, 0.6, [0.0, 0.5, 1.0]))
    np.testing.assert_allclose(bay_weights(Wing((root,) * 3, (1.0, 0.8, 0.6), (0.0, 0.3, 0.4))),
                               np.array([0.27, 0.07]) / 0.34)


def test_the_tapered_wing_optimum_is_no_worse_than_its_start_and_feasible(design):
    # From 30 kPa the skin bulges too much; lowering the pressure reduces the error until the
    # wrinkle floor (min fibre tension >= 0) stops it.
    assert design.success, design.message
    assert design.method == "gauss_newton"  # "auto" on a wing of 3 bays
    assert design.rms_error < design.initial_rms_error
    assert design.pressure < START["pressure"]
    assert design.bay_results == ("converged",) * 3
    scale = 0.5 * START["pressure"] * 0.9  # the tension scale: p_start times the widest bay's chord / 2
    assert np.all(design.per_bay.min_tension >= -VIOLATION_TOLERANCE * scale)
    assert "min_tension" in design.limits.active and not design.limits.violated
    assert design.limits.violated_at_start == {}  # 30 kPa: a taut skin everywhere
    assert design.solves == len(design.history) and design.solves < 20
    assert design.per_bay.rms_error.shape == (3,) and np.all(design.per_bay.rms_error > 0)
    w = design.per_bay.weights
    assert design.rms_error == pytest.approx(float(np.sqrt(np.sum(w * design.per_bay.rms_error**2))), rel=1e-12)


def test_unmeetable_limits_are_named_with_their_bay(wing):
    # A ceiling of 50 N/m: at the lowest pressure, 1 kPa, the hoop tension is ~400 N/m.
    res = optimise_wing(wing, Fabric(), request=DesignRequest(
        initial=START, bounds=BOUNDS, solver=SolverSettings(max_iterations=3), layout=LAYOUT,
        limits=Limits(tension=Constraints(min_tension=None, max_tension=50.0))))
    assert not res.success
    assert set(res.limits.violated) == {"max_tension"}
    assert set(res.limits.violated_where["max_tension"]) == {0, 1, 2}
    assert res.limits.violated["max_tension"] == max(res.limits.violated_where["max_tension"].values())
    assert "max_tension violated in bay 0" in res.message and "above the ceiling 50 N/m" in res.message
    # The start (30 kPa) breaks the ceiling in every bay too, by more than the design does.
    assert set(res.limits.violated_at_start) == {"max_tension"}
    start = res.limits.violated_at_start_where["max_tension"]
    assert set(start) == {0, 1, 2}
    assert all(start[k] > res.limits.violated_where["max_tension"][k] > 0 for k in start)


def test_a_one_bay_wing_agrees_with_optimise_pressure():
    af = naca("2412")
    wing = Wing(airfoils=(af, af), chords=(1.0, 1.0), stations=(0.0, 0.25))
    res = optimise_wing(wing, Fabric(), request=DesignRequest(initial=START, bounds=BOUNDS, layout=LAYOUT,
                                                              solver=SolverSettings(max_iterations=30)))
    scene = Scene(Bay.from_airfoil(af, chord=1.0, rib_spacing=0.25, **GRID))
    single = optimise_pressure(scene, af, ("pressure",), initial=START, bounds=BOUNDS, objective="average",
                               solver=SolverSettings(max_iterations=30))
    assert res.success and single.success, (res.message, single.message)
    assert res.method == single.method == "gauss_newton"  # "auto"
    # Both stop on the same design of the same problem; the solves differ at rtol 1e-11.
    assert res.pressure == pytest.approx(single.pressure, rel=1e-6)
    assert res.per_bay.rms_error[0] == pytest.approx(single.rms_error, rel=1e-6)


def test_a_failed_bay_is_reported_not_returned_as_nan(wing):
    # 100 relaxation steps cannot converge any bay: the problem raises, naming the first bay and
    # its result code (its NaN nodes never reach the optimiser). Through `DesignProblem.solve`, the
    # path of every final solve, so the test compiles only the forward loop at its new step cap.
    with jax.enable_x64(True):
        variables = DesignVariables.build(("pressure",), START, BOUNDS, n_ribs=4, rib_shape="per_rib")
        problem = _problem(wing, variables, 1e-11, solver={"equilibrium_method": "relax", "max_steps": 100})
        with pytest.raises(BaysConvergenceError, match=r"bay 0 \(ribs 0 and 1.*max_steps_reached") as failure:
            problem.solve(np.array([1.0]))
    assert failure.value.bay == 0 and failure.value.failed == [0, 1, 2]
    assert failure.value.solution.result.name == "max_steps_reached"


def test_bad_wing_designs_are_refused(wing):
    with pytest.raises(ValueError, match=r"rib_shape start must be one row of 2K coefficients for every rib "
                                         r"or an \(4, 2K\) array"):
        optimise_wing(wing, Fabric(), request=DesignRequest(("pressure", "rib_shape"), layout=LAYOUT,
                                                            initial={**START, "rib_shape": np.zeros((3, 8))}))
    with pytest.raises(ValueError, match="one target section per rib: the wing has 4 ribs, got 2"):
        optimise_wing(wing, Fabric(), targets=[naca("2412")] * 2, request=DesignRequest(layout=LAYOUT))
    with pytest.raises(ValueError, match="objective must be one of"):
        optimise_wing(wing, Fabric(), request=DesignRequest(objective="tip", layout=LAYOUT))
    with pytest.raises(ValueError, match="unknown design variable"):
        optimise_wing(wing, Fabric(), request=DesignRequest(("stiffness_span",), layout=LAYOUT))
    with pytest.raises(TypeError, match=r"layout -> request=DesignRequest\(layout=\.\.\.\)"):
        optimise_wing(wing, Fabric(), layout=LAYOUT)


def test_every_method_designs_a_wing_or_says_why_not(wing):
    # least_squares and optax run on the wing as on a bay (the bays' residuals weighted by the square
    # root of their area); brentq's mid-bay condition has no meaning over several bays: refused.
    res = optimise_wing(wing, Fabric(), request=DesignRequest(
        initial=START, bounds=BOUNDS, method="least_squares", solver=SolverSettings(max_iterations=4),
        limits=Limits(tension=None), layout=LAYOUT))
    assert res.rms_error < res.initial_rms_error and res.per_bay.rms_error.shape == (3,)
    assert res.pressure < START["pressure"] and res.solves == len(res.history)
    steps = optimise_wing(wing, Fabric(), request=DesignRequest(
        initial=START, bounds=BOUNDS, method="optax", solver=SolverSettings(max_iterations=2),
        limits=Limits(tension=None), layout=LAYOUT))
    assert len(steps.history) == 2 and steps.pressure != START["pressure"]
    with pytest.raises(ValueError, match="method='root' solves one scalar condition at one bay's mid-bay"):
        optimise_wing(wing, Fabric(), request=DesignRequest(initial=START, bounds=BOUNDS, method="root",
                                                            layout=LAYOUT))


def test_a_one_bay_result_keeps_the_single_bay_attributes_and_a_wing_its_bays(design):
    # One result class: a wing's solution is its BaysSolution (per-bay Solutions inside), its
    # violations one format (the largest per name, and per bay in violated_where) whether one bay or three.
    assert design.n_bays == 3 and design.solution is design.wing_solution
    assert design.solution.bay_solution(2).converged
    assert design.max_error == pytest.approx(float(np.max(design.per_bay.max_error)))


def test_refine_design_confirms_a_wing_on_a_finer_grid(design):
    # The 9x32 wing design re-run on 17x32 from its optimum: refine_design records both grids and
    # the move, keeps the coarse start's errors and counts both grids' solves. The pressure moves
    # with the span resolution (9 span nodes: docs' grid study), but stays inside its bounds and the
    # fine design is itself a success.
    from inverse_design import refine_design

    fine = refine_design(design, Layout(n_span=17, n_contour=32))  # (the design's bounds, limits and settings)
    change = fine.grid_change
    assert change["grids"] == [[9, 32], [17, 32]]
    assert change["values"]["pressure"][0] == pytest.approx(design.pressure, rel=1e-12)
    assert change["values"]["pressure"][1] == pytest.approx(fine.pressure, rel=1e-12)
    assert change["change"]["pressure"] == pytest.approx((fine.pressure - design.pressure) / design.pressure)
    assert fine.success and fine.n_bays == 3 and np.shape(fine.wing_solution.nodes)[1:3] == (17, 32)
    assert fine.solves > design.solves and fine.initial_rms_error == design.initial_rms_error
    assert BOUNDS["pressure"][0] <= fine.pressure <= BOUNDS["pressure"][1]
    # The command's wing summary and console keep the record (they dropped it before).
    from inverse_design.app.console import refined_line
    from inverse_design.app.summary import summarise

    results = summarise(fine)["results"]
    assert results["grid_change"]["grids"] == [[9, 32], [17, 32]]
    assert results["grid_change"]["rms_error"] == [design.rms_error, fine.rms_error]
    assert refined_line(results).startswith("  refined 9x32 -> 17x32: pressure ")
