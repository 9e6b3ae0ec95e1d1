"""The design Jacobian bay by bay (`inverse_design.methods.blocks`) and the sparse step QP
(`inverse_design.methods.step_qp`) of the Gauss-Newton method.

A 3-bay tapered NACA 2412 wing on 5x32 grids, designed with a cut field per
bay and a shape per rib: the compressed forward pass against one tangent per
variable through the whole wing (`support.design.dense_linearised`); one
bay's block alone, by the implicit derivative of its own solve
(`forward_solver.solve_equilibrium` warm from the wing's, pushed along its
columns by `forward_solver.derivatives.forward.value_and_jacobian`), against
the same columns; the step QP by Clarabel against SLSQP on the dense QP
(`support.design.dense_step`). Then a wing whose three bays are equal: a
field per bay ends where one shared field does.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from forward_solver import Fabric, Wing, solve_equilibrium
from forward_solver.derivatives.forward import value_and_jacobian
from inverse_design import Constraints, DesignRequest, Layout, RibLimits, SolverSettings, optimise_wing
from inverse_design.constraints import cell_tensions
from inverse_design.methods.blocks import compressed_seeds
from inverse_design.methods.gauss_newton import GN_PENALTY, GN_QP_PENALTY, trust_region_step
from inverse_design.methods.step_qp import BINDING_TOLERANCE
from inverse_design.objectives import WingTargets, distance_residuals
from inverse_design.problem import DesignProblem
from inverse_design.rib_design import RibGeometry
from inverse_design.variables import DesignVariables
from support.design import bay_columns, dense_linearised, dense_step
from targets import naca

GRID = dict(n_span=5, n_contour=32)
START = {"pressure": 1e4, "prestrain_span": 0.02, "prestrain_chord": 0.02}


@pytest.fixture(scope="module")
def linearised():
    """The problem, the point, its compressed (sparse) and dense linearisations."""
    af = naca("2412")
    wing = Wing(airfoils=(af,) * 4, chords=(1.0, 0.9, 0.8, 0.7), stations=(0.0, 0.25, 0.5, 0.75))
    with jax.enable_x64(True):
        variables = DesignVariables.build(("pressure", "rib_thickness_scale", "cut_pattern", "rib_shape"), START,
                                          None, n_ribs=4, rib_shape="per_rib", cut_pattern="per_bay")
        scenes = wing.scenes(Fabric(), **GRID)
        problem = DesignProblem(scenes, WingTargets([s.bay for s in scenes], wing.airfoils, "average"), variables,
                                tension=Constraints(), solver=SolverSettings(rtol=1e-12))
        u = variables.start_vector() + 0.01 * np.sin(np.arange(variables.size))
        sparse = problem.linearised(u)
        block = _bay_block(problem, u, sparse[-1], 1)  # (with the solve's factors, before another solve)
        dense = dense_linearised(problem, u)
    return problem, u, sparse, dense, block


def _bay_block(problem, u, sol, k):
    """Bay ``k``'s shape rows in its own columns, by the implicit derivative of the bay alone: its solve
    warm from the wing's (with that solve's factor), pushed along its own columns."""
    scene, targets = problem.scenes[k], problem.targets
    base = jnp.asarray(u, jnp.float64)
    columns = bay_columns(problem.variables, len(problem.scenes))[k]

    def outputs(w):
        parameters = problem.variables.bay_parameters(base.at[columns].set(w), k)
        nodes = solve_equilibrium(scene, parameters, rtol=1e-12, method="newton", initial=sol.solutions[k]).nodes
        d = targets.distances(k, nodes)
        return np.sqrt(targets.weights[k]) * distance_residuals(d, targets.objective), cell_tensions(scene, nodes,
                                                                                                     parameters)

    return value_and_jacobian(outputs, base[columns])[1]


def test_compressed_seeds_move_each_bay_by_one_variable_each(linearised):
    problem = linearised[0]
    seeds, columns = compressed_seeds(problem.variables, 3)
    # 2 shared + 12 per bay + 2 x 8 per rib tangents, not 2 + 36 + 32 variables
    assert seeds.shape == (30, 70)
    for k, own in enumerate(bay_columns(problem.variables, 3)):
        assert sorted(columns[k]) == list(own)  # each bay sees every variable that moves it, once
        assert np.all(seeds[:, own].sum(axis=1) == 1.0)


def test_block_jacobian_equals_the_dense_one(linearised):
    _, _, (r, jr, g, jg, _), (r_dense, jr_dense, g_dense, jg_dense), _ = linearised
    assert jr.format == "csr" and jr.nnz < 0.5 * jr_dense.size  # stored sparse: a bay's rows, its columns
    np.testing.assert_allclose(r, r_dense, rtol=0, atol=1e-14 * np.max(np.abs(r_dense)))
    np.testing.assert_allclose(g, g_dense, rtol=0, atol=1e-14 * np.max(np.abs(g_dense)))
    np.testing.assert_allclose(jr.toarray(), jr_dense, rtol=0, atol=1e-10 * np.max(np.abs(jr_dense)))
    np.testing.assert_allclose(jg.toarray(), jg_dense, rtol=0, atol=1e-10 * np.max(np.abs(jg_dense)))
    assert np.max(np.abs(jr_dense)) > 0 and np.max(np.abs(jg_dense)) > 0


def test_one_bays_block_alone_equals_its_rows_of_the_wing_jacobian(linearised):
    problem, u, (_, jr, _, _, _), (_, jr_dense, _, _), block = linearised
    k = 1
    own = bay_columns(problem.variables, 3)[k]
    n = problem.targets.residual_size // 3
    rows = jr[k * n:(k + 1) * n].toarray()  # the same solve's (the dense one is at a second solve of u)
    np.testing.assert_allclose(block, rows[:, own], rtol=0, atol=1e-10 * np.max(np.abs(rows)))
    rows = jr_dense[k * n:(k + 1) * n]
    others = np.setdiff1d(np.arange(u.size), own)
    assert np.all(rows[:, others] == 0.0)  # no other variable moves this bay


def test_sparse_qp_step_equals_the_dense_qp_step(linearised):
    problem, u, (r, jr, g, jg, _), _, _ = linearised
    # A floor just above the least cell tension's row: some rows start broken, others bind in the step.
    g = g - np.quantile(g, 0.02)
    lo = np.maximum(problem.variables.lower - u, -1.0)
    hi = np.minimum(problem.variables.upper - u, 1.0)
    scale = 1.0 / np.sqrt(r @ r)
    sparse = trust_region_step(r * scale, jr * scale, g, jg, lo, hi, GN_PENALTY, GN_QP_PENALTY)
    dense = dense_step(r * scale, jr.toarray() * scale, g, jg.toarray(), lo, hi, GN_PENALTY, GN_QP_PENALTY)
    assert sparse[2] == dense[2] > 0  # the same rows kept
    assert sparse[1] == pytest.approx(dense[1], rel=1e-6)  # the model's predicted fall
    np.testing.assert_allclose(sparse[0], dense[0], rtol=0, atol=1e-4 * np.max(np.abs(dense[0])))


def test_the_rib_rows_along_the_bays_seeds_are_their_dense_jacobian(linearised):
    """The rib limits' rows of a shape per rib, pushed along the bays' compressed seeds and decompressed
    (`blocks.rib_columns`), against forward mode in every variable of the same rows (`RibGeometry.functions`):
    the wing's four ribs, a per-bay cut field and the rib thickness scale beside them."""
    problem, u, _, _, _ = linearised
    af = naca("2412")
    variables = problem.variables
    with jax.enable_x64(True):
        ribbed = DesignProblem(problem.scenes, problem.targets, variables, tension=problem.tension,
                               ribs=[(k, RibGeometry(af, RibLimits())) for k in range(4)],
                               solver=problem.solver)
        ribbed.remember(problem.previous, u)
        *_, g, jg, _ = ribbed.linearised(u)

        def rows(w):
            parameters, shapes = variables.parameters(w), variables.rib_shapes_at(w)
            return jnp.concatenate([geometry.functions(parameters.replace(rib_shape=shapes[k]))
                                    for k, geometry in ribbed.ribs])

        w = jnp.asarray(u, jnp.float64)
        expected_g, expected = np.asarray(rows(w)), np.asarray(jax.jacfwd(rows)(w))
    n = expected_g.size
    np.testing.assert_allclose(g[-n:], expected_g, rtol=0, atol=1e-14 * np.max(np.abs(expected_g)))
    np.testing.assert_allclose(jg[-n:].toarray(), expected, rtol=0, atol=1e-12 * np.max(np.abs(expected)))
    assert np.count_nonzero(expected[:, variables.slices()["rib_shape"]]) > 0  # the shapes move them


def test_a_qp_started_from_the_last_steps_binding_rows_takes_the_same_step(linearised):
    """A working set started with more rows (`step_qp.solve_working_set`'s ``start``: Gauss-Newton passes
    the rows that bound at the last step) solves the same QP: a row of the set that does not bind changes
    nothing. The rows said to bind are at their limit at the step."""
    problem, u, (r, jr, g, jg, _), _, _ = linearised
    g = g - np.quantile(g, 0.02)  # some rows broken at the start, others binding in the step (as above)
    lo = np.maximum(problem.variables.lower - u, -1.0)
    hi = np.minimum(problem.variables.upper - u, 1.0)
    scale = 1.0 / np.sqrt(r @ r)
    cold = trust_region_step(r * scale, jr * scale, g, jg, lo, hi, GN_PENALTY, GN_QP_PENALTY)
    binding = cold[4]
    assert binding.shape == g.shape and binding.any()
    assert np.all(g[binding] + jg[binding] @ cold[0] <= BINDING_TOLERANCE)
    # The binding rows and the 40 least rows still above their limit, most of which do not bind.
    start = binding | (g <= np.sort(g[g > 0.0])[39]) & (g > 0.0)
    warm = trust_region_step(r * scale, jr * scale, g, jg, lo, hi, GN_PENALTY, GN_QP_PENALTY, rows=start)
    assert warm[3] >= cold[3] + 40 - binding.sum()  # the set held them
    assert warm[1] == pytest.approx(cold[1], rel=1e-6)
    np.testing.assert_allclose(warm[0], cold[0], rtol=0, atol=1e-4 * np.max(np.abs(cold[0])))
    np.testing.assert_array_equal(warm[4], binding)


@pytest.fixture(scope="module")
def equal_bays():
    af = naca("2412")
    wing = Wing(airfoils=(af,) * 4, chords=(0.8,) * 4, stations=(0.0, 0.25, 0.5, 0.75))
    options = dict(variables=("pressure", "cut_pattern"), initial=START, method="gauss_newton",
                   solver=SolverSettings(max_iterations=30))
    return {layout: optimise_wing(wing, Fabric(), request=DesignRequest(layout=Layout(cut_pattern=layout, **GRID),
                                                                        **options))
            for layout in ("shared", "per_bay")}


def test_a_field_per_bay_on_equal_bays_ends_at_the_shared_field(equal_bays):
    shared, per_bay = equal_bays["shared"], equal_bays["per_bay"]
    assert shared.success and per_bay.success, (shared.message, per_bay.message)
    assert per_bay.rms_error == pytest.approx(shared.rms_error, rel=1e-3), (per_bay.rms_error, shared.rms_error)
    assert float(per_bay.parameters.pressure) == pytest.approx(float(shared.parameters.pressure), rel=1e-3)
    # Every bay's field is the same: the three rows agree to 1e-4 of the local prestrain (they end where the
    # shared field does but along its flat directions: measured, the first span coefficient 0.0077 against
    # 0.0092 shared, with rms and pressure equal to 1e-3).
    fields = np.asarray(per_bay.per_bay.cut_patterns)
    np.testing.assert_allclose(fields, np.tile(fields.mean(axis=0), (3, 1)), rtol=0, atol=1e-4)
    shared_field = np.asarray(shared.parameters.cut_pattern)
    assert np.median(np.abs(fields - shared_field)) < 1e-4
    assert np.max(np.abs(shared_field)) > 1e-3  # the field moved: a real design


def test_a_field_per_bay_on_one_bay_is_the_shared_field_said_once():
    with pytest.warns(UserWarning, match="one bay is the shared field") as caught:
        variables = DesignVariables.build(("pressure", "cut_pattern"), START, None, n_ribs=2, cut_pattern="per_bay")
    assert len(caught) == 1
    assert variables.cut_patterns is None and variables.sizes["cut_pattern"] == 12


def test_more_field_terms_than_contour_nodes_is_refused_before_a_solve():
    af = naca("2412")
    wing = Wing(airfoils=(af, af), chords=(1.0, 1.0), stations=(0.0, 0.25))
    variables = DesignVariables.build(("pressure", "cut_pattern"), {**START, "cut_pattern": np.zeros(2 * 33)}, None)
    scenes = wing.scenes(Fabric(), **GRID)
    with pytest.raises(ValueError, match="33 terms per fibre direction on 32 contour nodes"):
        DesignProblem(scenes, WingTargets([s.bay for s in scenes], wing.airfoils), variables)


def test_memory_estimate_counts_the_seeds_and_refuses_beyond_half_the_memory():
    from inverse_design.app.resources import check_design_memory
    from inverse_design.memory import design_memory, design_tangents

    names = ("pressure", "cut_pattern", "rib_shape")
    variables = DesignVariables.build(names, START, None, n_ribs=41, rib_shape="per_rib", cut_pattern="per_bay")
    assert variables.size == 809  # 1 + 40 x 12 + 41 x 8
    tangents = design_tangents(names, 40, cut_pattern_terms=6, rib_shape_terms=4, cut_pattern="per_bay")
    assert tangents == compressed_seeds(variables, 40)[0].shape[0] == 29
    estimate = design_memory(40, 17, 64, tangents)
    assert design_memory(40, 33, 64, tangents) > estimate > design_memory(20, 17, 64, tangents)
    with pytest.raises(ValueError, match="40 bays on 17 x 64 with 29 Jacobian tangents"):
        check_design_memory(40, 17, 64, tangents, available=(estimate, "test"))
    assert check_design_memory(40, 17, 64, tangents, available=(2.5 * estimate, "test")) == estimate
    assert check_design_memory(40, 17, 64, tangents, allow_large=True, available=(estimate, "test")) == estimate


def test_the_next_solve_starts_from_the_first_order_prediction(linearised):
    # The linearisation's tangents of every bay's displacement (a cut field per bay, a shape per rib: each
    # bay's columns decompressed) move the last solution to the next point: the predicted displacement
    # is within the step's second order of the solve there, far closer than the last one (measured
    # 1e-3 of it here for a step of 1e-3 of each scaled variable). Runs last: it moves the problem on.
    problem, u, *_ = linearised
    step = 1e-3 * np.cos(np.arange(u.size))
    old = problem.previous
    with jax.enable_x64(True):
        predicted = problem.predicted_start(u + step)
        after = problem.solve(u + step)
    for k, sol in enumerate(predicted.solutions):
        actual = np.asarray(after.nodes[k]) - np.asarray(after.mounted[k])
        first = np.abs(np.asarray(sol.nodes) - np.asarray(old.mounted[k]) - actual).max()
        zeroth = np.abs(np.asarray(old.nodes[k]) - np.asarray(old.mounted[k]) - actual).max()
        assert first < 0.05 * zeroth, (k, first, zeroth)

