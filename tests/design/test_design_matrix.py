"""The default method converges on every documented variable set of four cases (small grids).

`benchmarks/design_matrix.py` runs the matrix on the command's grid (17x64)
with slsqp and gauss_newton: every documented variable set (the pressure; the
prestrains; the rib thickness scale; a rib shape; a cut pattern, shared and
per bay; their combinations) on the default bay (NACA 2412), the built-in
wing (``inverse_design/cases/wing_taper.toml``), a NACA 0012 bay and a bay of
a real ``.dat`` section (E387). ``method="auto"`` must converge wherever some
method does; here it runs on the cells of that matrix on a 5x32 grid (one on
9x32: `GRIDS`), each
run the ``optimise-pressure`` command's own design of its case
(`inverse_design.app.case.Case`, `inverse_design.app.design.optimise`), with its
defaults for everything else. By default a covering subset of the cells runs
(`COVERING`); ``INFLATABLE_WING_FULL_DESIGN_MATRIX=1`` runs every cell.

The three bays share one grid, so their programs compile once per variable
set (the bay geometry is traced); the wing's compile once per variable set.

An infeasible design (a tension ceiling below the prestress, which no
pressure in the bounds can meet) checks the failure path: success False, the
violated limit named with its amount.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from inverse_design import Constraints
from inverse_design.app import design
from inverse_design.app.case import Case
from inverse_design.methods import AUTO, AUTO_FOR_WORST
from inverse_design.settings import Limits, SolverSettings

ROOT = Path(__file__).resolve().parents[2]
GRID = ("--n-span", "5", "--n-contour", "32")
CASES = {
    "default": (),
    "naca0012": ("--target", "naca0012"),
    "e387": ("--target", str(ROOT / "tests" / "data" / "uiuc" / "e387.dat")),
    "wing": ("--config", str(ROOT / "inverse_design" / "cases" / "wing_taper.toml")),
}
VARIABLE_SETS = {
    "pressure": ("--variables", "pressure"),
    "prestrains": ("--variables", "pressure,prestrain_span,prestrain_chord"),
    "rib_thickness": ("--variables", "pressure,rib_thickness_scale"),
    "rib_shape": ("--variables", "pressure,rib_shape"),
    "cut_pattern": ("--variables", "pressure,rib_thickness_scale,cut_pattern"),
    "cut_pattern_per_bay": ("--variables", "pressure,rib_thickness_scale,cut_pattern",
                            "--cut-pattern-layout", "per_bay"),
    "prestrains+rib_thickness": ("--variables", "pressure,prestrain_span,prestrain_chord,rib_thickness_scale"),
    "prestrains+rib_shape": ("--variables", "pressure,prestrain_span,prestrain_chord,rib_shape"),
}
#: Every cell of the matrix (29 designs; about 12 min on two busy cores, a design of each variable set
#: compiling its programs once for the bays and once for the wing) ...
MATRIX = [(case, name) for name in VARIABLE_SETS for case in CASES if name != "cut_pattern_per_bay" or case == "wing"]
#: ... and the cells run by default: each variable set once and each case at least once, among them every
#: set on which SLSQP stops at its iteration cap on 17x64 (a cut pattern, a rib shape on E387, the
#: prestrains with a rib shape; `benchmarks/results/design_matrix.json`).
COVERING = [("naca0012", "pressure"), ("wing", "prestrains"), ("default", "rib_thickness"), ("e387", "rib_shape"),
            ("default", "cut_pattern"), ("wing", "cut_pattern_per_bay"), ("naca0012", "prestrains+rib_thickness"),
            ("default", "prestrains+rib_shape")]
#: Cells on another grid than `GRID`: the README's cut-pattern example on 9x32, where SLSQP stops at its
#: iteration cap (55 solves, rms 3.42e-4 chord) as on 17x64 (on 5x32 and 7x32 it converges, in 40-49 solves).
GRIDS = {("default", "cut_pattern"): ("--n-span", "9", "--n-contour", "32")}
#: Set to 1 to run every cell of `MATRIX`.
FULL_MATRIX_VARIABLE = "INFLATABLE_WING_FULL_DESIGN_MATRIX"
CELLS = [pytest.param(case, name, id=f"{case}-{name}")
         for case, name in (MATRIX if os.environ.get(FULL_MATRIX_VARIABLE) == "1" else COVERING)]


def command_design(argv, **changes):
    """The design `inverse_design.app.run.run_case` runs for ``argv`` (no report), with ``changes`` to the
    keyword arguments of its `inverse_design.optimise_wing`; returns ``(result, case)``."""
    case = Case.from_arguments(list(argv))
    return design.optimise(case, **changes), case


@pytest.mark.parametrize("case, variables", CELLS)
def test_the_default_method_converges(case, variables):
    res, command_case = command_design([*CASES[case], *VARIABLE_SETS[variables], *GRIDS.get((case, variables), GRID)])
    assert command_case.options.method == "auto" and res.method == AUTO
    assert res.success, res.message
    assert not res.limits.violated
    assert np.isfinite([res.rms_error, res.max_error]).all()
    if not res.limits.violated_at_start:  # a start that met every limit is an iterate: never worse
        assert res.rms_error <= res.initial_rms_error * (1 + 1e-9)
    for name in set(res.variables) - {"rib_shape", "cut_pattern"}:  # (a shape's and a field's are not per value)
        lower, upper = command_case.bounds[name]
        slack = 1e-12 * (upper - lower)
        assert lower - slack <= getattr(res.parameters, name) <= upper + slack, name


def test_the_worst_objective_runs_slsqp():
    # Gauss-Newton needs a sum of squares: "auto" runs SLSQP for the smooth maximum (one iteration shows it).
    res, _ = command_design(["--objective", "worst", "--variables", "pressure", *GRID],
                            solver=SolverSettings(max_iterations=1))
    assert res.method == AUTO_FOR_WORST == "slsqp" and res.solves >= 1


# ------------------------------------------------------------ an infeasible design
# 2% prestrain of a 2e5 N/m fabric alone gives fibre tensions of several kN/m; a ceiling of
# 1 kN/m cannot be met by any pressure in the bounds: the design stops far below its cap.
INFEASIBLE_CEILING = 1000.0  # N/m


@pytest.mark.parametrize("method", ["auto", "slsqp"])
def test_an_infeasible_ceiling_fails_and_names_the_limit(method):
    limits = Limits(tension=Constraints(min_tension=None, max_tension=INFEASIBLE_CEILING))
    res, command_case = command_design(["--variables", "pressure", "--method", method, *GRID], limits=limits)
    assert not res.success
    assert set(res.limits.violated) == {"max_tension"}
    excess = res.limits.values["max_tension"] - INFEASIBLE_CEILING
    assert res.limits.violated["max_tension"] == pytest.approx(excess, rel=1e-12)
    assert excess > 1000.0  # N/m: far beyond the ceiling, not a tolerance effect
    assert "max_tension violated" in res.message and f"{INFEASIBLE_CEILING:.4g} N/m" in res.message
    assert np.isfinite([res.pressure, res.rms_error, res.max_error]).all() and math.isfinite(excess)
    lower, upper = command_case.bounds["pressure"]
    assert lower <= res.pressure <= upper
    assert res.solves <= 12
