"""Inverse design over a covering subset of the case matrix.

`benchmarks/design_matrix.py` runs every combination of grid (7x64, 9x64,
17x128), objective (mid_bay, average, worst), design variables (pressure;
pressure and both prestrains; pressure and both rib scales) and target (NACA
2412, 0012, 4415, 23012) with the ``optimise-pressure`` defaults. These 12
cases cover every pair of levels of any two factors: each (target, grid),
(target, objective) and (target, variables) pair exactly once, each pair of
the three 3-level factors at least once (three mutually orthogonal 3x3 Latin
squares, one per target, and one more Latin square for the fourth target).

Every case runs the command's defaults (SLSQP, max_iterations 50, min_tension
0) and is expected to converge: in the full matrix every run that is not hit
by a known defect does. Each run must end with success True, or with success
False and a message that names the reason (a violated limit by name and
amount); stay below the evaluation cap; have finite parameters and errors;
and, when successful, respect every bound and not be worse than its start.
(The rib-scale cases failed until warm starts carried the displacement over
to new rib scales and the "worst" objective became a smooth maximum.)

A genuinely infeasible design (a tension ceiling below the prestress, which
no pressure in the bounds can meet) checks the failure path: success False,
the violated limit named with its amount.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from forward_solver import Bay, Fabric, Parameters, Scene
from inverse_design import Constraints, optimise_pressure
from inverse_design.app.case import parse_arguments
from inverse_design.methods import SLSQP_EVALUATIONS_PER_ITERATION
from targets import naca

VARIABLE_SETS = {
    "pressure": ("pressure",),
    "pressure+prestrains": ("pressure", "prestrain_span", "prestrain_chord"),
    "pressure+rib scales": ("pressure", "rib_thickness_scale", "rib_chord_scale"),
}

def _case(target, grid, objective, variables):
    return pytest.param(target, grid, objective, variables,
                        id=f"naca{target}-{grid[0]}x{grid[1]}-{objective}-{variables.replace(' ', '_')}")


# Ordered by grid, so each grid's functions compile once and its cases follow.
CASES = [
    _case("2412", (7, 64), "mid_bay", "pressure"),
    _case("23012", (7, 64), "average", "pressure+prestrains"),
    _case("4415", (7, 64), "worst", "pressure+rib scales"),
    _case("0012", (7, 64), "mid_bay", "pressure"),
    _case("2412", (9, 64), "average", "pressure+rib scales"),
    _case("23012", (9, 64), "worst", "pressure"),
    _case("4415", (9, 64), "mid_bay", "pressure+prestrains"),
    _case("0012", (9, 64), "worst", "pressure+rib scales"),
    _case("2412", (17, 128), "worst", "pressure+prestrains"),
    _case("23012", (17, 128), "mid_bay", "pressure+rib scales"),
    _case("4415", (17, 128), "average", "pressure"),
    _case("0012", (17, 128), "average", "pressure+prestrains"),
]


@pytest.fixture(scope="module")
def defaults():
    """The ``optimise-pressure`` defaults, from the command's own parser."""
    args, _ = parse_arguments([])
    return args


@pytest.fixture(scope="module")
def scenes(defaults):
    """Scenes built as `inverse_design.app.command.run` builds them (ribs = target), one per (target, grid)."""
    built = {}

    def scene(target, grid):
        if (target, grid) not in built:
            bay = Bay.from_airfoil(naca(target), chord=defaults.chord, rib_spacing=defaults.rib_spacing,
                                   n_span=grid[0], n_contour=grid[1])
            built[target, grid] = Scene(bay, Fabric(stiffness_span=defaults.stiffness_span,
                                                    stiffness_chord=defaults.stiffness_chord,
                                                    poisson=defaults.poisson))
        return built[target, grid]

    return scene


def command_options(args, variables, **changes):
    """Start, bounds, constraints and optimiser options of `inverse_design.app.command.run`."""
    all_bounds = {"pressure": args.pressure_bounds, "prestrain_span": args.prestrain_bounds,
                  "prestrain_chord": args.prestrain_bounds, "rib_thickness_scale": args.rib_thickness_bounds,
                  "rib_chord_scale": args.rib_chord_bounds}
    options = dict(
        initial=Parameters(pressure=args.pressure, prestrain_span=args.prestrain_span,
                           prestrain_chord=args.prestrain_chord, rib_thickness_scale=args.rib_thickness_scale,
                           rib_chord_scale=args.rib_chord_scale),
        bounds={n: tuple(all_bounds[n]) for n in variables},
        constraints=Constraints(min_tension=args.min_tension, max_tension=args.max_tension),
        method=args.method, max_iterations=args.max_iterations, tolerance=args.tolerance)
    return {**options, **changes}


def check_clear_outcome(res, options):
    """The contract every design meets, converged or not."""
    cap = SLSQP_EVALUATIONS_PER_ITERATION * options["max_iterations"]
    assert res.solves < cap, f"{res.solves} forward solves, the cap is {cap}: {res.message}"
    values = [getattr(res.parameters, n) for n in res.variables]
    assert np.isfinite(values).all(), values
    assert np.isfinite([res.rms_error, res.max_error, res.initial_rms_error, res.initial_max_error]).all()
    if res.success:
        # Not worse than the start: the start is an iterate, so SLSQP cannot return worse.
        assert res.rms_error <= res.initial_rms_error * (1 + 1e-9)
        for name, value in zip(res.variables, values):
            # Rounding only: the optimiser clips its scaled variables (value / scale) to the bounds.
            lower, upper = options["bounds"][name]
            slack = 1e-12 * (upper - lower)
            assert lower - slack <= value <= upper + slack, f"{name} = {value!r} outside {(lower, upper)}"
        assert not res.violated_constraints
    else:
        assert res.message.strip(), "a failed design must say why"
        for name, amount in res.violated_constraints.items():
            assert name in res.message and amount > 0 and math.isfinite(amount), res.violated_constraints


@pytest.mark.parametrize("target, grid, objective, variables", CASES)
def test_design_ends_converged_or_says_why(scenes, defaults, target, grid, objective, variables):
    names = VARIABLE_SETS[variables]
    options = command_options(defaults, names)
    res = optimise_pressure(scenes(target, grid), naca(target), names, objective=objective, **options)
    check_clear_outcome(res, options)
    # Every case of the full matrix converges on the defaults (benchmarks/design_matrix.py),
    # so a failure here is a regression.
    assert res.success, res.message


# ------------------------------------------------------------ an infeasible design
# 2% prestrain of a 2e5 N/m fabric alone gives fibre tensions of several kN/m; a ceiling of
# 1 kN/m cannot be met by any pressure in the bounds. SLSQP either stops at once ("Positive
# directional derivative for linesearch") or its line search keeps returning to the lower
# pressure bound, which ends the run as stalled after a few returns: either way far below
# the evaluation cap.
INFEASIBLE_CEILING = 1000.0  # N/m


def test_an_infeasible_ceiling_fails_and_names_the_limit(scenes, defaults):
    options = command_options(defaults, ("pressure",),
                              constraints=Constraints(min_tension=None, max_tension=INFEASIBLE_CEILING))
    res = optimise_pressure(scenes("2412", (7, 64)), naca("2412"), ("pressure",), objective="average",
                            **options)
    assert not res.success
    assert set(res.violated_constraints) == {"max_tension"}
    excess = res.constraint_values["max_tension"] - INFEASIBLE_CEILING
    assert res.violated_constraints["max_tension"] == pytest.approx(excess, rel=1e-12)
    assert excess > 1000.0  # N/m: far beyond the ceiling, not a tolerance effect
    assert "max_tension violated" in res.message and f"{INFEASIBLE_CEILING:.4g} N/m" in res.message
    assert np.isfinite([res.pressure, res.rms_error, res.max_error]).all()
    lower, upper = options["bounds"]["pressure"]
    assert lower <= res.pressure <= upper
    assert res.solves <= 12
