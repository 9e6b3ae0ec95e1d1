"""The robust design (`inverse_design.tolerance.robust`, docs/tolerances.md): the gradient of its objective and the
Jacobian of its percentile tension rows against central differences in float64, on one bay and on a
2-bay wing (per-bay and per-rib tolerance columns), 5x32; a robust design of the wing; bad input."""

import math

import jax
import numpy as np
import pytest

from forward_solver import Fabric, Wing
from inverse_design import Constraints, Layout, optimise_wing
from inverse_design.objectives import WingTargets
from inverse_design.problem import DesignProblem
from inverse_design.settings import DesignRequest
from inverse_design.tolerance.robust import QUANTILE_Z, check_robust_tolerances
from inverse_design.variables import DesignVariables
from targets import naca

START = {"pressure": 5e3, "prestrain_span": 0.02, "prestrain_chord": 0.02}


def _wing(n_bays):
    chords = (1.0, 0.9, 0.8)[:n_bays + 1]
    return Wing(airfoils=(naca("2412"),) * (n_bays + 1), chords=chords, stations=(0.0, 0.25, 0.5)[:n_bays + 1])


def _problem(n_bays, variables):
    wing = _wing(n_bays)
    design = DesignVariables.build(variables, START, None, n_ribs=n_bays + 1, rib_shape="per_rib",
                                   cut_pattern="shared")
    scenes = wing.scenes(Fabric(), 5, 32)
    return DesignProblem(scenes, WingTargets([s.bay for s in scenes], [naca("2412")] * (n_bays + 1), "robust"),
                         design, tension=Constraints())


def _check_against_central_differences(problem, u, step):
    """The robust objective ``q = E[ms] + 1.645 sqrt(Var[ms])`` and the percentile tension rows at ``u``:
    the gradient the Gauss-Newton loop sees (``2 dR/du^T R`` with the majoriser tight at ``u``) and the
    rows' Jacobian against central differences of ``q`` and of the rows (each side solved and its
    tolerance Jacobian taken afresh)."""
    stacked, jstacked, g, jg, _ = problem.linearised(u)
    problem.reweight(u)
    stacked, jstacked, g, jg, _ = problem.linearised(u)
    gradient = 2.0 * (jstacked.T @ stacked)

    def measured(v):
        r, _, rows, _, sol = problem.nominal_linearised(v)
        at = problem.robust.at(v, r, rows, sol)
        return at["quantile"], at["g"]

    q, rows = measured(u)
    assert q == pytest.approx(stacked @ stacked + 0.5 * QUANTILE_Z * problem.robust.scale, rel=1e-12)
    assert np.allclose(rows, g, rtol=0, atol=1e-14)
    jg = jg.toarray()
    for j in range(u.size):
        e = np.zeros(u.size)
        e[j] = step
        (q_plus, rows_plus), (q_minus, rows_minus) = measured(u + e), measured(u - e)
        fd = (q_plus - q_minus) / (2 * step)
        assert gradient[j] == pytest.approx(fd, rel=1e-5), (j, gradient[j], fd)
        fd_rows = (rows_plus - rows_minus) / (2 * step)
        assert np.max(np.abs(jg[:, j] - fd_rows)) <= 1e-5 * np.max(np.abs(fd_rows)), j


def test_the_robust_gradient_agrees_with_central_differences_on_one_bay():
    """Pressure and rib thickness on one bay: a step of 1e-3 in the scaled variables leaves a truncation
    error of order 1e-6 of q (its third derivative) and, at the solves' residual 1e-11 and the
    tolerance Jacobian's own step of 1e-4, a rounding error of order 1e-7 (measured 1e-7)."""
    with jax.enable_x64(True):
        problem = _problem(1, ("pressure", "rib_thickness_scale"))
        _check_against_central_differences(problem, problem.variables.start_vector(), 1e-3)


def test_the_robust_gradient_agrees_with_central_differences_on_a_wing_and_its_design_holds_the_limits():
    """A 2-bay wing, the pressure alone: each bay has its own stiffness and cut columns and shares
    its ribs' (15 columns). Then its robust design (the default tolerances): a success, every cell's
    tension at its own 5th percentile on or above the floor, each iterate's percentile recorded."""
    with jax.enable_x64(True):
        problem = _problem(2, ("pressure",))
        _check_against_central_differences(problem, problem.variables.start_vector(), 1e-3)
        assert problem.robust.size == 15
    wing = _wing(2)
    result = optimise_wing(wing, Fabric(), None, DesignRequest(("pressure",), START, objective="robust",
                                                               layout=Layout(n_span=5, n_contour=32)))
    assert result.success, result.message
    assert result.limits.values["min_tension_p5"] >= 0.0  # (a wrinkle-free floor: no negative tension)
    assert all(math.isfinite(h["robust_p95"]) and h["robust_p95"] > 0 for h in result.history)
    assert result.request.tolerances is None  # the defaults, as asked


def test_bad_robust_requests_are_refused():
    with pytest.raises(ValueError, match="every tolerance given is 0"):
        check_robust_tolerances({"pressure": 0})
    with pytest.raises(ValueError, match="method='gauss_newton'"):
        DesignRequest(objective="robust", method="slsqp")
    with pytest.raises(ValueError, match="objective='robust'"):
        DesignRequest(objective="average", tolerances={"pressure": "2%"})
    assert set(check_robust_tolerances(None)) == {"pressure", "stiffness_span", "stiffness_chord", "cut_span",
                                                  "cut_chord", "rib_station", "rib_profile"}
    assert math.isclose(QUANTILE_Z, 1.6448536269514722)
