"""What held a design where it is (`inverse_design.sensitivity`): its shadow prices against designs with the
bound moved, its windows against direct evaluations.

One 5 x 32 NACA 2412 bay with the command's default design (pressure and rib thickness scale, bounds 1 to
100 kPa and 0.7 to 1.0, from 10 kPa), which sits on both bounds: the pressure at its floor, the rib at
full thickness. The designs with a moved bound reuse the first one's compilations.
"""

import json

import pytest

from forward_solver import Bay, Scene
from inverse_design import evaluate_design, optimise_pressure
from targets import naca

VARIABLES = ("pressure", "rib_thickness_scale")


@pytest.fixture(scope="module")
def bay():
    target = naca("2412")
    return Scene(Bay.from_airfoil(target, chord=1.0, rib_spacing=0.25, n_span=5, n_contour=32)), target


def _design(bay, floor=1e3, rib_top=1.0, method="auto"):
    scene, target = bay
    return optimise_pressure(scene, target, VARIABLES, initial={"pressure": 1e4}, method=method,
                             bounds={"pressure": (floor, 1e5), "rib_thickness_scale": (0.7, rib_top)})


@pytest.fixture(scope="module")
def designs(bay):
    return {"default": _design(bay), "floor 0.95 kPa": _design(bay, floor=950.0),
            "rib 1.005": _design(bay, rib_top=1.005)}


def _price(result, name):
    (price,) = [p for p in result.sensitivity["prices"] if p["name"] == name]
    return price


def test_the_default_design_sits_on_both_bounds_and_says_the_bounds_decided_it(designs):
    result = designs["default"]
    assert result.success and result.sensitivity["solves"] == 0  # Gauss-Newton's own last linearisation
    assert [p["name"] for p in result.sensitivity["prices"]] == ["pressure>=lower", "rib_thickness_scale<=upper"]
    assert result.sensitivity["stationarity"] < 1e-6  # two variables, two active bounds: balanced exactly
    pressure, rib = result.sensitivity["windows"]
    assert pressure["at_bound"] == "lower" and pressure["low_end"] == "lower bound" and pressure["high_end"] == "rms"
    assert rib["at_bound"] == "upper" and rib["high_end"] == "upper bound" and rib["low_end"] == "rms"
    # Freed from its floor the pressure would gain less than 1% of the rms (0.015% on this grid):
    # the bound, not the physics, chose 1 kPa.
    assert pressure["decided_by_bound"] and pressure["free_gain"] < 1e-2 and pressure["wide"]
    json.dumps(result.sensitivity, allow_nan=False)  # JSON as it is


def test_the_pressure_floors_price_is_the_slope_of_the_rms_between_two_designs(designs):
    # Floors 1 and 0.95 kPa, not 0.9: on this grid the free optimum lies at 943 Pa, so below it the design
    # leaves the floor and the price falls to zero within the step. The rms curves steeply there (the
    # price is 1.34e-5 per kPa at 1 kPa and 2.0e-6 at 0.95), so the difference quotient is compared with
    # the mean of the two ends' prices (the trapezoid rule, exact for a quadratic): 1% holds it (measured
    # 7.714e-6 against 7.711e-6, 3e-4); both designs sit exactly on their floors, solved to 1e-10.
    a, b = designs["default"], designs["floor 0.95 kPa"]
    assert a.pressure == pytest.approx(1e3, rel=1e-6) and b.pressure == pytest.approx(950.0, rel=1e-6)
    slope = (b.rms_error - a.rms_error) / (0.95 - 1.0)  # per kPa of the floor
    prices = [_price(r, "pressure>=lower") for r in (a, b)]
    assert all(p["d_rms"] > 0 and p["per"] == "1 kPa" for p in prices)  # raising a floor costs accuracy
    assert 0.5 * (prices[0]["d_rms"] + prices[1]["d_rms"]) == pytest.approx(slope, rel=1e-2)
    assert prices[0]["relaxed_gain"] == prices[0]["d_rms"]


def test_the_rib_scales_upper_bound_price_is_the_slope_of_the_rms_between_two_designs(designs):
    # As above, the rib thickness scale's ceiling at 1.0 and 1.005 (measured -2.7199e-5 against the
    # prices' mean -2.7165e-5 per 0.01, 1.3e-3): raising a ceiling lowers the rms, a negative price.
    a, b = designs["default"], designs["rib 1.005"]
    assert b.parameters.rib_thickness_scale == pytest.approx(1.005, rel=1e-9)
    slope = (b.rms_error - a.rms_error) / 0.5  # per 0.01 of the bound
    prices = [_price(r, "rib_thickness_scale<=upper")["d_rms"] for r in (a, b)]
    assert all(p < 0 for p in prices)
    assert 0.5 * sum(prices) == pytest.approx(slope, rel=1e-2)


def test_the_windows_end_where_a_direct_evaluation_finds_the_rms_one_percent_up(designs, bay):
    # Each end the rms ends (not a bound) evaluated by one equilibrium with the other variable as
    # designed: the Gauss-Newton model's 1% is the solve's 1% to 0.1% of the rms, a tenth of the window's
    # growth (measured 1.00992 at 1.42 kPa, 1.0099998 at a rib thickness scale of 0.9953).
    result = designs["default"]
    scene, target = bay
    ends = 0
    for window in result.sensitivity["windows"]:
        for end in ("low", "high"):
            if window[f"{end}_end"] != "rms":
                continue
            values = {"pressure": result.pressure, "prestrain_span": 0.02, "prestrain_chord": 0.02,
                      "rib_thickness_scale": result.parameters.rib_thickness_scale, window["name"]: window[end]}
            rms = evaluate_design(scene, target, values).rms_error
            assert rms / result.rms_error == pytest.approx(1.01, abs=1e-3), (window["name"], end, window[end])
            ends += 1
    assert ends == 2


def test_other_methods_pay_one_linearisation_and_find_the_same_prices(designs, bay):
    # SLSQP ends on the same vertex of bounds; its record costs one wing solve and its Jacobian, which
    # are not among the design's solves (one per iterate in the history).
    gn, sq = designs["default"], _design(bay, method="slsqp")
    assert sq.success and sq.sensitivity["solves"] == 1 and sq.solves == len(sq.history)
    for name in ("pressure>=lower", "rib_thickness_scale<=upper"):
        assert _price(sq, name)["d_rms"] == pytest.approx(_price(gn, name)["d_rms"], rel=1e-3)


def test_a_single_equilibrium_has_no_sensitivity(bay):
    scene, target = bay
    assert evaluate_design(scene, target, {"pressure": 1e4}).sensitivity is None
