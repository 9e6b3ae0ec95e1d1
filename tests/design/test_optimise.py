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
from inverse_design import Constraints, Layout, Limits, RibLimits, SolverSettings, optimise_pressure, refine_design
from inverse_design.methods import SLSQP, GaussNewton, Optax, Root
from targets import Airfoil, naca

TRUE = {"pressure": 2e4, "prestrain_span": 0.004, "prestrain_chord": 0.006}
NAMES = ("pressure", "prestrain_span", "prestrain_chord")
#: The prestrains these tests start from where they give none (the library's start before it took the command's 2%).
PRESTRAINS = {"prestrain_span": 0.005, "prestrain_chord": 0.005}


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
    res = optimise_pressure(scene, generated, NAMES, initial=start, objective="mid_bay", method="least_squares",
                            solver=SolverSettings(max_iterations=40))
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
                            bounds={"pressure": (1e3, 1e5)}, objective="mid_bay")
    assert res.success, res.message
    assert abs(res.pressure / TRUE["pressure"] - 1.0) < 1e-4


def test_root_without_a_bracket_says_so(scene):
    # Ribs equal to the target: the bulge only adds thickness at any pressure.
    with pytest.raises(ValueError, match="no pressure in the bounds"):
        optimise_pressure(scene, naca("2412"), ("pressure",), initial={"pressure": 1e4, **PRESTRAINS},
                          bounds={"pressure": (5e3, 2e4)}, method="root", objective="mid_bay")


def test_ribs_equal_to_target_put_the_best_pressure_on_its_lower_bound(scene):
    res = optimise_pressure(scene, naca("2412"), ("pressure",), initial={"pressure": 1e4, **PRESTRAINS},
                            bounds={"pressure": (5e3, 2e4)}, method="least_squares", limits=Limits(tension=None),
                            solver=SolverSettings(max_iterations=20), objective="mid_bay")
    assert res.pressure == pytest.approx(5e3, rel=1e-6)
    assert "pressure>=lower" in res.limits.active
    assert res.rms_error < res.initial_rms_error


def test_slsqp_recovers_pressure_and_both_prestrains(scene, generated):
    start = {name: 1.5 * TRUE[name] for name in NAMES}  # 50% away
    # An inverse crime drives the objective to zero: ask SLSQP for a tight ftol.
    res = optimise_pressure(scene, generated, NAMES, initial=start, objective="mid_bay",
                            method=SLSQP(tolerance=1e-14))
    assert res.success, res.message
    for name in NAMES:
        assert abs(res.values[name] / TRUE[name] - 1.0) < 1e-4, (name, res.values[name])
    assert res.rms_error < 1e-6 < res.initial_rms_error
    assert res.limits.violated == {}
    assert all(len(h["constraints"]) == 1 for h in res.history)  # min_tension (no finite ceiling)
    assert res.solves <= 40


@pytest.fixture(scope="module")
def true_peak_tension(scene):
    sol = solve_equilibrium(scene, TRUE["pressure"], (TRUE["prestrain_span"], TRUE["prestrain_chord"]))
    return float(max(sol.tension_span.max(), sol.tension_chord.max()))


def test_allowable_tension_is_a_constraint_that_holds(scene, generated, true_peak_tension):
    # A ceiling below the tension the inverse crime needs: SLSQP stops on it, it is active and
    # not violated, and the design is a success.
    ceiling = 0.9 * true_peak_tension
    start = {"pressure": 1.5e4, "prestrain_span": TRUE["prestrain_span"],
             "prestrain_chord": TRUE["prestrain_chord"]}
    res = optimise_pressure(scene, generated, ("pressure",), initial=start, method="slsqp",
                            limits=Limits(tension=Constraints(max_tension=ceiling)), objective="mid_bay")
    assert res.success, res.message
    assert "max_tension" in res.limits.active and res.limits.violated == {}
    assert res.limits.values["max_tension"] <= ceiling * (1 + 1e-3)
    assert res.limits.values["max_tension"] >= ceiling * 0.99  # KS keeps it close, not far
    assert res.pressure < TRUE["pressure"]
    assert res.limits.violated_at_start == {}  # 1.5e4 Pa loads the skin below the ceiling


def test_a_start_that_breaks_a_limit_is_recorded_with_the_amount(scene, generated, true_peak_tension):
    # Started at 2.1e4 Pa, close to the inverse crime's exact answer but with its peak tension
    # above the ceiling: the design meets the ceiling with a larger error than the start's, and
    # the start's broken limit is kept with its amount (this says why the error rose).
    ceiling = 0.9 * true_peak_tension
    start = {"pressure": 2.1e4, "prestrain_span": TRUE["prestrain_span"],
             "prestrain_chord": TRUE["prestrain_chord"]}
    at_start = solve_equilibrium(scene, start["pressure"], (start["prestrain_span"], start["prestrain_chord"]))
    peak = float(max(at_start.tension_span.max(), at_start.tension_chord.max()))
    res = optimise_pressure(scene, generated, ("pressure",), initial=start, method="slsqp",
                            limits=Limits(tension=Constraints(max_tension=ceiling)), objective="mid_bay")
    assert res.success and res.limits.violated == {}, res.message
    assert set(res.limits.violated_at_start) == {"max_tension"}
    assert res.limits.violated_at_start["max_tension"] == pytest.approx(peak - ceiling, rel=1e-3)
    assert res.rms_error > res.initial_rms_error


@pytest.mark.parametrize("method", ["slsqp", "least_squares"])
def test_a_ceiling_no_design_can_meet_is_a_failure_with_the_amount(scene, generated, true_peak_tension,
                                                                   method):
    # Pressure held in [1.5e4, 3e4] Pa: the skin's peak tension cannot fall to 30% of the
    # tension at 2e4 Pa anywhere inside the bounds.
    ceiling = 0.3 * true_peak_tension
    start = {"pressure": 2e4, "prestrain_span": TRUE["prestrain_span"],
             "prestrain_chord": TRUE["prestrain_chord"]}
    res = optimise_pressure(scene, generated, ("pressure",), initial=start, bounds={"pressure": (1.5e4, 3e4)},
                            method=method,
                            limits=Limits(tension=Constraints(max_tension=ceiling, min_tension=None)),
                            solver=SolverSettings(max_iterations=20), objective="mid_bay")
    assert not res.success
    over = res.limits.values["max_tension"] - ceiling
    assert res.limits.violated["max_tension"] == pytest.approx(over) and over > 0
    assert "max_tension violated" in res.message and f"{over:.4g} N/m above" in res.message


def test_contradictory_tension_limits_are_bad_input(scene, generated):
    with pytest.raises(ValueError, match="inconsistent tension limits"):
        optimise_pressure(scene, generated, ("pressure",),
                          limits=Limits(tension=Constraints(min_tension=5000.0, max_tension=100.0)))


def test_optax_reduces_the_error(scene, generated):
    start = {"pressure": 1.5e4, "prestrain_span": TRUE["prestrain_span"],
             "prestrain_chord": TRUE["prestrain_chord"]}
    res = optimise_pressure(scene, generated, ("pressure",), initial=start, method=Optax(optimiser=optax.adam(0.05)),
                            solver=SolverSettings(max_iterations=6), limits=Limits(tension=None), objective="mid_bay")
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


@pytest.mark.parametrize(
    "build, match",
    [
        (lambda: GaussNewton(tolerance=0.0), "tolerance must lie in"),
        (lambda: SolverSettings(max_iterations=0), "max_iterations must be a positive integer"),
        (lambda: Root(condition="area"), "root condition must be one of"),
        (lambda: SolverSettings(rtol=2.0), "rtol .* must lie in"),
        (lambda: Layout(cut_pattern="per_rib"), "cut_pattern layout must be one of"),
        (lambda: Layout(n_span=1), "n_span must be an integer >= 2"),
        (lambda: Limits(tension=0.0), "Limits.tension must be an inverse_design.Constraints"),
        (lambda: Limits(ribs=RibLimits(min_thickness=1.5)), "min_thickness is a fraction"),
    ],
)
def test_bad_options_are_refused_when_built(build, match):
    with pytest.raises(ValueError, match=match):
        build()


def test_an_old_keyword_names_the_object_that_holds_it_now(scene):
    with pytest.raises(TypeError, match=r"max_iterations -> solver=SolverSettings\(max_iterations=\.\.\.\)"):
        optimise_pressure(scene, naca("2412"), max_iterations=3)
    with pytest.raises(TypeError, match=r"tolerance -> method=GaussNewton\(tolerance=\.\.\.\)"):
        SolverSettings(tolerance=1e-3)
    with pytest.raises(TypeError, match=r"root_condition -> method=Root\(condition=\.\.\.\)"):
        SolverSettings(root_condition="thickness")


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
        rms, largest = design_errors(nodes * (1 + offset), generated, 1.0, "mid_bay")
        rms0, _ = design_errors(nodes, generated, 1.0, "mid_bay")
    assert rms0 < 1e-12
    assert 0.1 * offset < rms < 10 * offset and largest < 10 * offset


def test_refine_design_reports_the_move_between_grids(scene):
    # Target generated on the finer 17 x 32 grid: the 9 x 32 design is off by the coarse
    # grid's discretisation error, the refined one recovers the true pressure.
    fine = Scene(Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=17, n_contour=32))
    sol = solve_equilibrium(fine, TRUE["pressure"], (TRUE["prestrain_span"], TRUE["prestrain_chord"]),
                            method="relax+newton", rtol=1e-12)
    section = sol.section(0.5)
    target = Airfoil(*np.concatenate([section, section[:1]]).T, name="generated on 17x32")
    start = {"pressure": 1.5e4, "prestrain_span": TRUE["prestrain_span"],
             "prestrain_chord": TRUE["prestrain_chord"]}
    coarse = optimise_pressure(scene, target, ("pressure",), initial=start, limits=Limits(tension=None),
                               method=GaussNewton(tolerance=1e-14), objective="mid_bay")
    refined = refine_design(coarse, Layout(n_span=17, n_contour=32))  # (fine's grid: the bay rebuilt on it)
    assert coarse.success and refined.success, (coarse.message, refined.message)
    change = refined.grid_change
    assert change["grids"] == [[9, 32], [17, 32]]
    assert change["values"]["pressure"] == [coarse.pressure, refined.pressure]
    assert refined.pressure == pytest.approx(TRUE["pressure"], rel=1e-4)
    assert change["change"]["pressure"] == pytest.approx(refined.pressure / coarse.pressure - 1.0)
    assert abs(change["change"]["pressure"]) > 1e-4  # the coarse grid really is off
    assert refined.solves > coarse.solves  # both grids counted
    assert refined.rms_error < 1e-6
