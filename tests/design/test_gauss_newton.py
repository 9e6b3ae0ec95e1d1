"""method="gauss_newton": few wing solves, the same optimum as SLSQP, limits kept.

One 2-bay tapered wing on 5x32 grids (chords 1.0 -> 0.8 -> 0.6 m, ribs 0.25 m
apart, NACA 2412) is shared by every test, so its solves compile once.
"""

import jax
import numpy as np
import pytest

from forward_solver import Fabric
from forward_solver import Wing
from inverse_design import Constraints, DesignRequest, optimise_wing
from inverse_design.constraints import VIOLATION_TOLERANCE
from inverse_design.objectives import WingTargets
from inverse_design.problem import DesignProblem
from inverse_design.variables import DesignVariables
from inverse_design.settings import Layout, Limits, SolverSettings
from targets import naca

GRID = dict(n_span=5, n_contour=32)
LAYOUT = Layout(**GRID)
START = {"pressure": 1e4, "prestrain_span": 0.02, "prestrain_chord": 0.02}
BOUNDS = {"pressure": (1e3, 1e5), "prestrain_span": (0.0, 0.05)}
VARIABLES = ("pressure", "prestrain_span")


@pytest.fixture(scope="module")
def wing():
    af = naca("2412")
    return Wing(airfoils=(af, af, af), chords=(1.0, 0.8, 0.6), stations=(0.0, 0.25, 0.5))


@pytest.fixture(scope="module")
def designs(wing):
    return {m: optimise_wing(wing, Fabric(), request=DesignRequest(VARIABLES, START, BOUNDS, method=m, layout=LAYOUT,
                                                                   solver=SolverSettings(max_iterations=40)))
            for m in ("gauss_newton", "slsqp")}


def test_forward_mode_jacobian_matches_central_differences(wing):
    # Solves to rtol 1e-12 against steps of 1e-4 in the scaled variables: truncation (~1e-8
    # relative) and the solve's error stay far below the 1e-5 asked of the columns.
    with jax.enable_x64(True):
        variables = DesignVariables.build(VARIABLES, START, BOUNDS, n_ribs=3)
        scenes = wing.scenes(Fabric(), **GRID)
        problem = DesignProblem(scenes, WingTargets([s.bay for s in scenes], wing.airfoils, "average"), variables,
                                tension=Constraints(), solver=SolverSettings(rtol=1e-12))
        u = np.array([1.0, 2.0])
        r, jr, g, jg, _ = problem.linearised(u)
        jr, jg = jr.toarray(), jg.toarray()  # scipy.sparse
        h = 1e-4
        for i in range(u.size):
            e = np.zeros_like(u)
            e[i] = h
            rp, _, gp, _, _ = problem.linearised(u + e)
            rm, _, gm, _, _ = problem.linearised(u - e)
            np.testing.assert_allclose(jr[:, i], (rp - rm) / (2 * h), rtol=0,
                                       atol=1e-5 * np.max(np.abs(jr[:, i])))
            np.testing.assert_allclose(jg[:, i], (gp - gm) / (2 * h), rtol=0,
                                       atol=1e-5 * np.max(np.abs(jg[:, i])))
        objective = problem.targets.objective_value(problem.distances(problem.solve(u).nodes))
    assert np.all(np.max(np.abs(jr), axis=0) > 1e-3 * np.max(np.abs(r)))  # both variables move the fit
    assert r @ r == pytest.approx(float(objective), rel=1e-12)


def test_same_optimum_as_slsqp_in_fewer_solves(designs):
    gn, sq = designs["gauss_newton"], designs["slsqp"]
    assert gn.success and sq.success, (gn.message, sq.message)
    # SLSQP keeps a smooth (KS) minimum of the tensions above the floor, which lies below the true
    # minimum (`constraints.KS_SHARPNESS`), so its optimum stops a little short of the true limit that
    # gauss_newton keeps cell by cell: the same optimum, gauss_newton's error at most SLSQP's and
    # within 1% of it (measured: 3.0785e-3 against 3.0874e-3, 0.29% lower).
    assert sq.rms_error * (1 - 1e-2) <= gn.rms_error <= sq.rms_error * (1 + 1e-6), (gn.rms_error, sq.rms_error)
    assert gn.pressure == pytest.approx(sq.pressure, rel=5e-2), (gn.pressure, sq.pressure)
    assert gn.solves < sq.solves, (gn.solves, sq.solves)
    # the wrinkle floor binds at this optimum and is kept (true cell extremes)
    assert "min_tension" in gn.limits.active
    assert gn.limits.values["min_tension"] >= -VIOLATION_TOLERANCE * 0.5 * gn.pressure * 1.0


def test_a_limit_no_design_meets_is_a_failure_with_the_amount(wing):
    # A ceiling of 100 N/m: the hoop tension p c / 2 alone is 500 N/m at the lowest pressure, 1 kPa.
    res = optimise_wing(wing, Fabric(), request=DesignRequest(
        VARIABLES, START, BOUNDS, method="gauss_newton", limits=Limits(tension=Constraints(max_tension=100.0)),
        solver=SolverSettings(max_iterations=15), layout=LAYOUT))
    assert not res.success
    assert "max_tension violated" in res.message
    amount = res.limits.violated["max_tension"]
    assert amount == pytest.approx(res.limits.values["max_tension"] - 100.0, rel=1e-9)
    assert amount > 100.0
    from inverse_design.result import FORMER_LIMIT_FIELDS

    for former, field in FORMER_LIMIT_FIELDS.items():  # the former field names read the record, for one release
        assert getattr(res, former) is getattr(res.limits, field)


def test_the_worst_objective_is_refused(wing):
    with pytest.raises(ValueError, match="gauss_newton.*'worst'"):
        optimise_wing(wing, Fabric(), request=DesignRequest(VARIABLES, START, objective="worst",
                                                            method="gauss_newton", layout=LAYOUT))
    # The default ("auto") picks slsqp for it instead of refusing (one SLSQP iteration suffices to see).
    res = optimise_wing(wing, Fabric(), request=DesignRequest(VARIABLES, START, BOUNDS, objective="worst",
                                                              solver=SolverSettings(max_iterations=1), layout=LAYOUT))
    assert res.method == "slsqp" and res.solves >= 1


class _CurvedLimit:
    """A one-variable fit of ``u`` to 2 under the curved limit ``g = 1 - u^2 >= 0`` (the shape of a
    tension floor along which the linearised limit misses its curvature), started just past it."""

    variables = type("Bounds", (), {"lower": np.array([0.0]), "upper": np.array([3.0])})

    def linearised(self, u):
        import scipy.sparse

        u = float(u[0])
        return (np.array([u - 2.0]), np.array([[1.0]]), np.array([1.0 - u * u]),
                scipy.sparse.csr_matrix([[-2.0 * u]]), None)

    history = type("History", (), {"at": staticmethod(lambda u: None)})

    def reweight(self, u):
        return False


def test_a_stop_inside_the_slack_but_past_the_floor_margin_restores_the_limit_first():
    """Past the wrinkle-free floor's margin (`constraints.FLOOR_MARGIN`) but inside the merit's slack
    (`methods.gauss_newton.GN_SLACK`) the model sees no gain in restoring the limit, so the design stopped
    there and was reported wrinkled; now the QP's restoring step comes first."""
    from inverse_design.constraints import FLOOR_MARGIN
    from inverse_design.methods import GaussNewton
    from inverse_design.methods.gauss_newton import GN_SLACK

    start = np.array([1.0 + 3e-5])  # g = -6e-5: inside the slack, past the margin
    assert GN_SLACK > -(1.0 - start[0] ** 2) > FLOOR_MARGIN
    u, success, message = GaussNewton(tolerance=1e-3).run(_CurvedLimit(), start, max_iterations=10)
    assert success, message
    assert 1.0 - u[0] ** 2 >= -FLOOR_MARGIN  # the limit holds to the margin
    assert u[0] == pytest.approx(1.0, abs=1e-6)  # and the fit is the best the limit allows
