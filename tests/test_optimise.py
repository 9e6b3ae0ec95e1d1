"""Inverse design: inverse crimes, bound-limited optima, constraint reports and bad input.

One 9 x 32 NACA 2412 bay is shared by every test (JAX compilation dominates).
The inverse-crime target is the mid-bay section of an equilibrium computed
at known parameters, as an `Airfoil` through its nodes, so the exact answer
has zero error and must be recovered (1e-4 relative, the issue's tolerance).
"""

import numpy as np
import optax
import pytest

from forward_solver import Bay, Scene, solve_equilibrium
from inverse_design import Constraints, optimise_pressure
from targets import Airfoil, naca

TRUE = {"pressure": 2e4, "prestrain_span": 0.004, "prestrain_chord": 0.006}
NAMES = ("pressure", "prestrain_span", "prestrain_chord")


@pytest.fixture(scope="module")
def scene():
    return Scene(Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=9, n_contour=32))


@pytest.fixture(scope="module")
def generated(scene):
    sol = solve_equilibrium(scene, TRUE["pressure"], (TRUE["prestrain_span"], TRUE["prestrain_chord"]),
                            method="relax+newton", rtol=1e-12)
    section = sol.section(0.5)
    closed = np.concatenate([section, section[:1]])
    return Airfoil(closed[:, 0], closed[:, 1], name="generated")


def test_least_squares_recovers_pressure_and_both_prestrains(scene, generated):
    start = {name: 1.5 * TRUE[name] for name in NAMES}  # 50% away
    res = optimise_pressure(scene, generated, NAMES, initial=start, objective="mid_bay",
                            method="least_squares", max_iterations=40)
    assert res.success, res.message
    for name in NAMES:
        assert abs(res.values[name] / TRUE[name] - 1.0) < 1e-4, (name, res.values[name])
    assert res.rms_error < 1e-7 < res.initial_rms_error
    assert res.prestrain == (res.values["prestrain_span"], res.values["prestrain_chord"])
    assert len(res.history) >= 2
    assert res.history[0]["objective"] > res.history[-1]["objective"]
    assert res.history[0]["steps"] > 0 and all(h["steps"] >= 0 for h in res.history)


def test_root_recovers_the_pressure(scene, generated):
    start = {"pressure": 3e4, "prestrain_span": TRUE["prestrain_span"],
             "prestrain_chord": TRUE["prestrain_chord"]}
    res = optimise_pressure(scene, generated, ("pressure",), initial=start, method="root",
                            bounds={"pressure": (1e3, 1e5)})
    assert res.success, res.message
    assert abs(res.pressure / TRUE["pressure"] - 1.0) < 1e-4


def test_root_without_a_bracket_says_so(scene):
    # Ribs equal to the target: the bulge only adds thickness at any pressure.
    with pytest.raises(ValueError, match="no pressure in the bounds"):
        optimise_pressure(scene, naca("2412"), ("pressure",), initial={"pressure": 1e4},
                          bounds={"pressure": (5e3, 2e4)}, method="root")


def test_ribs_equal_to_target_put_the_best_pressure_on_its_lower_bound(scene):
    res = optimise_pressure(scene, naca("2412"), ("pressure",), initial={"pressure": 1e4},
                            bounds={"pressure": (5e3, 2e4)}, method="least_squares",
                            constraints=None, max_iterations=20)
    assert res.pressure == pytest.approx(5e3, rel=1e-6)
    assert "pressure>=lower" in res.active_constraints
    assert res.rms_error < res.initial_rms_error


def test_allowable_tension_is_reported_active(scene, generated):
    # A ceiling below the tension the inverse crime needs: the penalty holds
    # the maximum tension near it and the result reports it.
    sol = solve_equilibrium(scene, TRUE["pressure"], (TRUE["prestrain_span"], TRUE["prestrain_chord"]))
    ceiling = 0.9 * float(max(sol.tension_span.max(), sol.tension_chord.max()))
    start = {"pressure": 1.5e4, "prestrain_span": TRUE["prestrain_span"],
             "prestrain_chord": TRUE["prestrain_chord"]}
    res = optimise_pressure(scene, generated, ("pressure",), initial=start,
                            constraints=Constraints(max_tension=ceiling, penalty=1e4),
                            method="least_squares", max_iterations=30)
    assert "max_tension" in res.active_constraints
    assert res.constraint_values["max_tension"] < 1.02 * ceiling
    assert res.pressure < TRUE["pressure"]


def test_optax_reduces_the_error(scene, generated):
    start = {"pressure": 1.5e4, "prestrain_span": TRUE["prestrain_span"],
             "prestrain_chord": TRUE["prestrain_chord"]}
    res = optimise_pressure(scene, generated, ("pressure",), initial=start, method="optax",
                            optimiser=optax.adam(0.05), constraints=None, max_iterations=6)
    # Six Adam steps of 0.05 (in units of the starting pressure) move 1.5e4 Pa
    # most of the way to 2e4 Pa.
    assert res.rms_error < 0.5 * res.initial_rms_error
    assert all(np.isfinite(h["gradient_norm"]) for h in res.history)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(variables=("presure",)), "unknown design variable"),
        (dict(variables=("pressure",), method="bfgs"), "method must be one of"),
        (dict(variables=("pressure",), objective="tip"), "objective must be one of"),
        (dict(variables=("pressure",), bounds={"pressure": (2e4, 1e4)}), "lower < upper"),
        (dict(variables=("pressure",), bounds={"pressure": (2e4, 3e4)}), "outside its bounds"),
        (dict(variables=("pressure",), bounds={"prestrain_span": (0, 0.1)}), "not among the variables"),
        (dict(variables=("pressure", "prestrain_span"), method="root"), "pressure alone"),
    ],
)
def test_bad_input_raises_a_clear_error(scene, kwargs, match):
    with pytest.raises(ValueError, match=match):
        optimise_pressure(scene, naca("2412"), initial={"pressure": 1e4}, **kwargs)


def test_design_errors_are_float64_whatever_the_callers_jax_setting(scene, generated):
    """A target a tiny offset away: float32 distances would round it to noise (or zero)."""
    import warnings

    import jax

    from inverse_design import design_errors

    nodes = np.asarray(Bay.from_airfoil(generated, chord=1.0, rib_spacing=0.25, n_span=9,
                                        n_contour=32).nominal_nodes())
    assert not jax.config.jax_enable_x64
    offset = 1e-9  # m, chord 1 m: below float32's resolution of 1 m coordinates (6e-8)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "explicitly requested dtype float64" truncation
        rms, largest = design_errors(nodes * (1 + offset), generated, 1.0)
        rms0, _ = design_errors(nodes, generated, 1.0)
    assert rms0 < 1e-12
    assert 0.1 * offset < rms < 10 * offset and largest < 10 * offset
