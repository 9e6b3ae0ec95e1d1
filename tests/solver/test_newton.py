"""Newton equilibrium solver: coloured Jacobian, convergence, agreement with relaxation, failure codes.

Grids are small and shared through module-level fixtures: JAX compilation
(one Jacobian kernel per grid shape and physics) dominates these tests.
"""

from __future__ import annotations

from functools import partial

import jax
import numpy as np
import pytest

from forward_solver import Bay, Result, Scene, solve_equilibrium
from forward_solver import forces as fk
from forward_solver.solvers.jacobian import OrderedLU, assemble_jacobian, factorise, free_dofs, jacobian_sparsity
from forward_solver.solvers.newton import NewtonOptions, newton
from forward_solver.model.parameters import as_parameters

DESIGN_PRESSURE = 2e4  # Pa
PRESTRAIN = 0.005


# Compiled once per grid shape (eager JAX compiles every primitive per shape).
prepare = jax.jit(fk.prepare, static_argnames="physics")
relative_residual = jax.jit(fk.relative_residual, static_argnames="physics")


@partial(jax.jit, static_argnames="physics")
def dense_jacobian(x, ref, params, physics):
    """Dense ``dR/dx`` by forward-mode AD, and the wrinkled-cell mask at ``x``."""
    jac = jax.jacfwd(lambda y: fk.residual(y, ref, params, physics).reshape(-1))(x)
    return jac.reshape(x.size, x.size), fk.forces(x, ref, params, physics).wrinkled


def circle_bay(n_span: int, n_contour: int, rib_spacing: float = 0.25, chord: float = 1.0) -> Bay:
    """A closed periodic bay between two circular ribs of diameter ``chord`` (no airfoil needed)."""
    phi = 2.0 * np.pi * np.arange(n_contour) / n_contour
    contour = np.stack([(1.0 + np.cos(phi)) / 2.0, np.sin(phi) / 2.0], axis=-1)  # Selig order
    fixed = np.zeros((n_span, n_contour), dtype=bool)
    fixed[0] = fixed[-1] = True
    zeros = np.zeros(n_contour)
    return Bay(contour_root=contour, contour_tip=contour, camber_root=zeros, camber_tip=zeros,
               chord_root=chord, chord_tip=chord, rib_spacing=rib_spacing, periodic=True,
               fixed=fixed, name="circle")


def problem(bay: Bay, pressure=DESIGN_PRESSURE, prestrain=PRESTRAIN, tension_only=True):
    """Scene, float64 geometry and parameters, and static physics of one case."""
    scene = Scene(bay=bay, tension_only=tension_only)
    with jax.enable_x64(True):
        params = scene.params(as_parameters(pressure, prestrain))
        geometry = bay.geometry()
    return scene, geometry, params, scene.physics(dynamic=False)


# ------------------------------------------------------------------ colouring
@pytest.mark.parametrize(
    "shape, periodic, n_colours",
    [((5, 7), False, 27), ((4, 12), True, 27), ((5, 13), True, 36), ((5, 14), True, 45), ((3, 4), True, 36)],
)
def test_colouring_separates_columns_that_share_a_row(shape, periodic, n_colours):
    sparsity = jacobian_sparsity(shape, periodic)
    assert sparsity.n_colours == n_colours
    n_dof = shape[0] * shape[1] * 3
    row_colours = sparsity.colours[sparsity.cols]
    # A row that sees two columns of one colour would mix them in one JVP.
    pairs = np.unique(np.stack([sparsity.rows, row_colours]), axis=1)
    assert pairs.shape[1] == sparsity.rows.size
    assert np.bincount(sparsity.rows, minlength=n_dof).max() <= 27  # 3x3 nodes x 3 components


# ------------------------------------------------------------------- jacobian
@pytest.mark.parametrize(
    "bay, prestrain, tension_only",
    [
        # Cut longer than mounted (negative prestrain): with the random motion
        # below, some cells are clamped (wrinkled) and some taut.
        (Bay.flat_panel(0.25, 1.0, 5, 7), -0.01, True),
        (circle_bay(5, 14), -0.01, True),  # n_contour % 3 == 2: 45 colours, the wrap
    ],
    ids=["panel-wrinkled", "circle14-wrinkled"],
)
def test_jacobian_matches_jacfwd(bay, prestrain, tension_only):
    """Coloured assembly equals dense forward-mode AD; both are exact, so 1e-12 is roundoff."""
    _, geometry, params, physics = problem(bay, prestrain=prestrain, tension_only=tension_only)
    with jax.enable_x64(True):
        ref = prepare(geometry, params, physics)
        rng = np.random.default_rng(0)
        # A generic shape: random motion of the free nodes, 2% of the rib spacing.
        x = ref.nodes + 0.005 * rng.standard_normal(ref.nodes.shape) * ref.free
        jac = assemble_jacobian(x, ref, params, physics).toarray()
        dense, wrinkled = dense_jacobian(x, ref, params, physics)
    dofs = free_dofs(ref)
    dense = np.asarray(dense)[np.ix_(dofs, dofs)]
    wrinkled = np.asarray(wrinkled)
    assert np.max(np.abs(jac - dense)) <= 1e-12 * np.max(np.abs(dense))
    assert 0.0 < wrinkled.mean() < 1.0  # both clamped and taut cells are exercised
    # The follower pressure and eq. (10) make J non-symmetric: LU, not Cholesky.
    assert np.max(np.abs(jac - jac.T)) > 1e-3 * np.max(np.abs(jac))


# --------------------------------------------------------------------- newton
@pytest.fixture(scope="module")
def panel():
    """The 9x33 flat panel at the design pressure and its Newton solve from the mounted shape."""
    bay = Bay.flat_panel(0.25, 1.0, 9, 33)
    scene, geometry, params, physics = problem(bay)
    with jax.enable_x64(True):
        out = newton(bay.nominal_nodes(), geometry, params, physics, rtol=1e-10,
                     divergence_bound=bay.divergence_bound)
    return bay, scene, geometry, params, physics, out


@pytest.fixture(scope="module")
def plain_newton(panel):
    """The panel's solve by Newton proper: a fresh assembly and LU every iteration, no chord step."""
    bay, _, geometry, params, physics, _ = panel
    with jax.enable_x64(True):
        return newton(bay.nominal_nodes(), geometry, params, physics, rtol=1e-10,
                      options=NewtonOptions(chord_steps=False), divergence_bound=bay.divergence_bound)


def test_newton_converges_quadratically(panel, plain_newton):
    bay, _, geometry, params, physics, _ = panel
    out = plain_newton
    assert out.result == Result.converged, out.message
    assert out.residual <= 1e-10
    assert out.load_steps == 0  # plain Newton suffices at the design pressure
    with jax.enable_x64(True):
        ref = prepare(geometry, params, physics)
        assert float(relative_residual(out.x, ref, params, physics)) == pytest.approx(out.residual)
    assert not out.history["chord"].any()
    r, step = out.history["residual"], out.history["step_length"]
    assert r.size == out.iterations
    # Quadratic convergence: every full step taken from r_k < 1e-2 that lands
    # above the roundoff floor (1e-13) satisfies r_{k+1} <= 10 r_k^2; a linear
    # rate would miss this by orders of magnitude at r_k ~ 1e-5. At least two
    # such steps must appear.
    pairs = [(a, b) for a, b, s in zip(r[:-1], r[1:], step[1:]) if s == 1.0 and a < 1e-2 and b > 1e-13]
    assert len(pairs) >= 2, r
    assert all(b <= 10.0 * a * a for a, b in pairs), r


def test_chord_steps_reach_the_same_equilibrium_with_fewer_factorisations(panel, plain_newton):
    """A chord step with the last factor replaces a fresh assembly and LU where it cuts the residual
    tenfold: the same nodes (both within rtol = 1e-10), fewer factorised iterations."""
    bay, _, _, _, _, out = panel
    assert out.result == Result.converged and out.residual <= 1e-10, out.message
    chord = out.history["chord"] > 0
    assert chord.any()
    assert np.count_nonzero(~chord) < plain_newton.iterations
    # every chord step kept cut the residual at least tenfold
    r = out.history["residual"]
    assert all(r[k] <= 0.1 * r[k - 1] for k in np.flatnonzero(chord) if k > 0)
    scale = np.max(np.abs(np.asarray(out.x) - bay.nominal_nodes()))
    assert np.max(np.abs(np.asarray(out.x) - np.asarray(plain_newton.x))) <= 1e-9 * scale


def test_factor_is_the_lu_of_the_jacobian_at_the_solution(panel):
    """The factor a later adjoint solve reuses: J x = b and J^T x = b both solve."""
    _, _, geometry, params, physics, out = panel
    assert out.factor_current and out.shift == 0.0
    with jax.enable_x64(True):
        ref = prepare(geometry, params, physics)
        jac = assemble_jacobian(out.x, ref, params, physics)
    assert abs(jac - out.jacobian).max() == 0.0
    b = np.random.default_rng(1).standard_normal(jac.shape[0])
    scale = np.linalg.norm(b)
    assert np.linalg.norm(jac @ out.factor.solve(b) - b) <= 1e-10 * scale
    assert np.linalg.norm(jac.T @ out.factor.solve(b, trans="T") - b) <= 1e-10 * scale


def test_a_structure_is_factorised_in_superlus_order_and_the_same_every_time(panel):
    """`factorise`: every matrix of a structure reordered by the permutation SuperLU chose for it (an
    `OrderedLU`, with SuperLU's fill), the first as every later one (the same factor to the bit); each
    solves J x = b and J^T x = b, and so does the LU of a Levenberg-shifted matrix."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from forward_solver.solvers.jacobian import PERMC_SPEC

    _, _, _, _, _, out = panel
    jac = out.jacobian[:-1, :-1].tocsc()  # (a structure no solve has met)
    first, again = factorise(jac), factorise(jac)
    assert isinstance(first, OrderedLU) and isinstance(again, OrderedLU)
    assert first.nnz <= 1.05 * spla.splu(jac, permc_spec=PERMC_SPEC).nnz
    b = np.random.default_rng(2).standard_normal((jac.shape[0], 3))
    np.testing.assert_array_equal(first.solve(b), again.solve(b))
    shifted = (jac - sp.diags(1e-2 * np.abs(jac.diagonal()), format="csc")).tocsc()
    scale = np.linalg.norm(b)
    for matrix, lu in ((jac, first), (shifted, factorise(shifted))):
        assert np.linalg.norm(matrix @ lu.solve(b) - b) <= 1e-10 * scale
        assert np.linalg.norm(matrix.T @ lu.solve(b, trans="T") - b) <= 1e-10 * scale
        assert np.linalg.norm(matrix @ lu.solve(b[:, 0]) - b[:, 0]) <= 1e-10 * scale


def test_newton_and_relaxation_reach_the_same_shape(panel):
    """Two independent solvers of one residual; at rtol 1e-10 each is within ~1e-11 m of R = 0."""
    _, scene, _, _, _, out = panel
    sol = solve_equilibrium(scene, DESIGN_PRESSURE, PRESTRAIN, rtol=1e-10)
    assert np.max(np.abs(sol.nodes - np.asarray(out.x))) <= 1e-8


def test_continuation_converges_where_plain_newton_fails():
    """At 1 MPa the flat start's out-of-plane stiffness is only the prestress's T/h, so
    the first Newton steps overshoot and plain Newton crawls on damped steps into its
    50-iteration cap; pressure steps from p/4, each warm-started, converge."""
    bay = Bay.flat_panel(0.25, 1.0, 9, 33)
    _, geometry, params, physics = problem(bay, pressure=1e6)
    with jax.enable_x64(True):
        x0 = bay.nominal_nodes()
        plain = newton(x0, geometry, params, physics, 1e-10, NewtonOptions(continuation=False),
                       divergence_bound=bay.divergence_bound)
        stepped = newton(x0, geometry, params, physics, rtol=1e-10, divergence_bound=bay.divergence_bound)
    assert plain.result == Result.max_steps_reached
    assert plain.iterations == 50 and np.all(np.isfinite(np.asarray(plain.x)))
    assert stepped.result == Result.converged, stepped.message
    assert stepped.residual <= 1e-10 and stepped.load_steps >= 2
    pressure = stepped.history["pressure"]
    assert pressure.min() < 1e6 and pressure[-1] == 1e6


def test_newton_on_a_closed_periodic_bay():
    bay = circle_bay(5, 14)  # n_contour % 3 == 2: the extra colours of the wrap
    _, geometry, params, physics = problem(bay)
    with jax.enable_x64(True):
        out = newton(bay.nominal_nodes(), geometry, params, physics, rtol=1e-10,
                     divergence_bound=bay.divergence_bound)
    assert out.result == Result.converged, out.message
    assert out.residual <= 1e-10


def test_iteration_cap_returns_max_steps_reached(panel):
    bay, _, geometry, params, physics, _ = panel
    with jax.enable_x64(True):
        out = newton(bay.nominal_nodes(), geometry, params, physics, 1e-10, NewtonOptions(max_iterations=1),
                     divergence_bound=bay.divergence_bound)
    assert out.result == Result.max_steps_reached
    assert np.isfinite(out.residual) and out.residual > 1e-10
    assert np.all(np.isfinite(np.asarray(out.x)))


def test_slack_flat_panel_stalls_with_a_code():
    """No prestrain: the flat start has no out-of-plane stiffness (documented limit)."""
    bay = Bay.flat_panel(0.25, 1.0, 9, 33)
    _, geometry, params, physics = problem(bay, prestrain=0.0)
    with jax.enable_x64(True):
        out = newton(bay.nominal_nodes(), geometry, params, physics, rtol=1e-10,
                     divergence_bound=bay.divergence_bound)
    assert out.result == Result.max_steps_reached
    assert "stalled" in out.message
    assert np.all(np.isfinite(np.asarray(out.x))) and np.isfinite(out.residual)


def test_nonfinite_start_returns_nonfinite(panel):
    bay, _, geometry, params, physics, _ = panel
    with jax.enable_x64(True):
        x0 = np.array(bay.nominal_nodes())
        x0[4, 16, 2] = np.nan
        out = newton(x0, geometry, params, physics, rtol=1e-10, divergence_bound=bay.divergence_bound)
    assert out.result == Result.nonfinite
    assert out.iterations == 0


@pytest.mark.parametrize(
    "kwargs, match",
    [({"rtol": 0.0}, "rtol"), ({"max_iterations": 0}, "max_iterations"),
     ({"initial_load_fraction": 0.0}, "initial_load_fraction")],
)
def test_bad_arguments_raise(panel, kwargs, match):
    bay, _, geometry, params, physics, _ = panel
    rtol = kwargs.pop("rtol", 1e-8)
    with pytest.raises(ValueError, match=match):  # (the knobs are refused when the options are made)
        newton(np.zeros(bay.shape + (3,)), geometry, params, physics, rtol, NewtonOptions(**kwargs),
               divergence_bound=bay.divergence_bound)


def test_wrong_initial_shape_raises(panel):
    _, _, geometry, params, physics, _ = panel
    with pytest.raises(ValueError, match="x_init"):
        newton(np.zeros((3, 3, 3)), geometry, params, physics, rtol=1e-8, divergence_bound=1.25)
