"""The tolerance analysis (`inverse_design.tolerance`, docs/tolerances.md): its Jacobian against central
differences, its linear spread against Monte Carlo, a sample re-solved alone, the budget, bad input.

Small grids (5x32 per bay) at a fixed equilibrium (`evaluate_design`), one bay and a 2-bay wing."""

import math

import numpy as np
import pytest

import jax

from forward_solver import Fabric, Wing, solve_equilibrium
from forward_solver.solution import initial_nodes
from inverse_design import SolverSettings, evaluate_design
from inverse_design.tolerance import (DEFAULT_TOLERANCES, SOURCES, Sampling, ToleranceModel, parse_tolerance,
                                      parse_tolerances,
                                      tolerance_analysis)
from support.design import solve_sample, wing_outputs
from support.solver import counted_each
from targets import naca

START = {"pressure": 5e3, "prestrain_span": 0.02, "prestrain_chord": 0.02}


def _wing(n_bays):
    af = naca("2412")
    chords = (1.0, 0.9, 0.8)[:n_bays + 1]
    stations = (0.0, 0.25, 0.5)[:n_bays + 1]
    return Wing(airfoils=(af,) * (n_bays + 1), chords=chords, stations=stations)


@pytest.fixture(scope="module")
def one_bay():
    wing = _wing(1)
    return evaluate_design(wing.scenes(Fabric(), 5, 32), [naca("2412")] * 2, START, objective="average",
                           wing=wing, solver=SolverSettings(rtol=1e-11))


@pytest.fixture(scope="module")
def two_bays():
    wing = _wing(2)
    return evaluate_design(wing.scenes(Fabric(), 5, 32), [naca("2412")] * 3, START, objective="average",
                           wing=wing, solver=SolverSettings(rtol=1e-11))


def _tenth_of_defaults():
    return {name: parse_tolerance(name, DEFAULT_TOLERANCES[name]).scaled(0.1) for name in SOURCES}


def test_jacobian_agrees_with_central_differences(two_bays):
    """Every column of the distance and tension Jacobians of a 2-bay wing (each source, each bay or rib)
    against central differences of cold solves at rtol 1e-11; a step of 1e-3 of each column's spread
    leaves a truncation error of order 1e-6 relative and a solve error of order 1e-8 / 1e-3."""
    tolerances = parse_tolerances(["defaults"])
    analysis = tolerance_analysis(two_bays, tolerances, rtol=1e-11)
    assert analysis.columns == ["pressure", "stiffness_span_bay_0", "stiffness_span_bay_1", "stiffness_chord_bay_0",
                                "stiffness_chord_bay_1", "cut_span_bay_0", "cut_span_bay_1", "cut_chord_bay_0",
                                "cut_chord_bay_1", "rib_station_rib_0", "rib_station_rib_1", "rib_station_rib_2",
                                "rib_profile_rib_0", "rib_profile_rib_1", "rib_profile_rib_2"]
    jd, jt = np.vstack(analysis.distance_jacobians), np.vstack(analysis.tension_jacobians)
    # one column of each source, on either bay or an inner rib (the others are the same code per index)
    checked = ["pressure", "stiffness_span_bay_1", "stiffness_chord_bay_0", "cut_span_bay_0", "cut_chord_bay_1",
               "rib_station_rib_1", "rib_profile_rib_1"]
    for i in [analysis.columns.index(name) for name in checked]:
        step = 1e-3 * analysis.std[i]
        e = np.zeros(len(analysis.columns))
        e[i] = step
        plus, minus = wing_outputs(two_bays, tolerances, e, rtol=1e-11), wing_outputs(two_bays, tolerances, -e,
                                                                                      rtol=1e-11)
        fd_d = (np.concatenate(plus[0]) - np.concatenate(minus[0])) / (2 * step)
        fd_t = (np.concatenate(plus[1]) - np.concatenate(minus[1])) / (2 * step)
        for exact, fd in ((jd[:, i], fd_d), (jt[:, i], fd_t)):
            scale = np.max(np.abs(fd))
            assert scale > 0, analysis.columns[i]  # every column moves the skin
            assert np.max(np.abs(exact - fd)) <= 1e-4 * scale, (analysis.columns[i], np.max(np.abs(exact - fd)), scale)
    # a column touches only its bays: bay 0's Jacobian has no entry for bay 1's stiffness or rib 2
    first = analysis.distance_jacobians[0]
    for name in ("stiffness_span_bay_1", "cut_chord_bay_1", "rib_station_rib_2", "rib_profile_rib_2"):
        assert np.all(first[:, analysis.columns.index(name)] == 0.0)


def test_linear_spread_agrees_with_monte_carlo_at_a_tenth_of_the_defaults(one_bay):
    """At a tenth of the default tolerances the linearised distances predict the sampled spread: the
    std of the rms and of the least tension within 10% of Monte Carlo's, both on the samples' own draws
    (the linear model at the drawn values: no sampling noise between the two) and as reported (the
    linear model's own 4000 draws against 64 solves: sampling noise of about 9%, so 25%)."""
    tolerances = _tenth_of_defaults()
    rows = []
    analysis = tolerance_analysis(one_bay, tolerances, sampling=Sampling(samples=64, seed=0, on_sample=rows.append))
    assert analysis.sampled["count"] == 64 and analysis.sampled["failed"] == 0 and len(rows) == 64
    assert all(row["converged"] for row in rows)
    e = np.array([[row[c] - v for c, v in zip(analysis.columns, analysis.nominal)] for row in rows])
    d = analysis.distances[0][None, :] + e @ analysis.distance_jacobians[0].T
    t = analysis.tensions[0][None, :] + e @ analysis.tension_jacobians[0].T
    linear_rms, linear_min = np.sqrt(np.mean(d**2, axis=1)), t.min(axis=1)
    sampled_rms = np.array([row["rms"] for row in rows])
    sampled_min = np.array([row["min_tension"] for row in rows])
    assert np.std(sampled_rms) > 0 and np.std(sampled_min) > 0
    assert abs(np.std(linear_rms) / np.std(sampled_rms) - 1) < 0.1
    assert abs(np.std(linear_min) / np.std(sampled_min) - 1) < 0.1
    for key in ("rms", "min_tension"):
        assert abs(analysis.linear[key]["std"] / analysis.sampled[key]["std"] - 1) < 0.25, key
    # the exact mean square of the linear model against its draws' (4000 draws: within 2%)
    assert analysis.rms_squared_mean == pytest.approx(np.mean(analysis.linear_rms**2), rel=0.02)


def test_the_bays_jacobians_are_the_same_on_one_thread_or_two(two_bays, monkeypatch):
    """The bays' Jacobians are taken two at a time where there is a second core (`threads.each`): each bay
    whole on one thread, so the analysis is the same to the bit as one bay after the other."""
    from inverse_design.tolerance import first_order

    tolerances = {"pressure": "2%", "stiffness_span": "10%", "cut_chord": "uniform:1", "rib_station": 1.0}
    counts = counted_each(monkeypatch, first_order)
    shared = tolerance_analysis(two_bays, tolerances)
    monkeypatch.setattr(first_order, "each", lambda function, count: [function(k) for k in range(count)])
    alone = tolerance_analysis(two_bays, tolerances)
    assert counts[0] == 2
    for a, b in zip(shared.distance_jacobians + shared.tension_jacobians + shared.distances,
                    alone.distance_jacobians + alone.tension_jacobians + alone.distances):
        assert np.array_equal(a, b)
    assert np.any(shared.distance_jacobians[1] != 0)


def test_a_sample_resolved_alone_reproduces_its_row(two_bays):
    """A Monte Carlo wing (solved warm from the nominal equilibrium) solved again alone and cold from
    its CSV row's drawn values gives the same rms, max and least tension (both to rtol 1e-11)."""
    tolerances = {"pressure": "2%", "stiffness_span": "10%", "cut_chord": "uniform:1", "rib_station": 1.0,
                  "rib_profile": 0.5}
    rows = []
    tolerance_analysis(two_bays, tolerances, sampling=Sampling(samples=2, seed=7, rtol=1e-11, on_sample=rows.append))
    row = rows[1]
    assert set(row) >= {"sample", "pressure", "stiffness_span_bay_1", "cut_chord_bay_0", "rib_station_rib_2",
                        "rib_profile_rib_1", "rms", "max", "min_tension", "converged"}
    again = solve_sample(two_bays, tolerances, row, rtol=1e-11)
    assert again["converged"] and row["converged"]
    for key in ("rms", "max", "min_tension"):
        assert again[key] == pytest.approx(row[key], rel=1e-7, abs=1e-9), key


def test_a_bays_parameters_are_one_program_for_every_bay_and_numpys_for_a_sample(two_bays):
    """`ToleranceModel.bay_parameters` at traced deviations is one jitted call whose
    program is the same for both bays (``k`` an operand), and gives the concrete (NumPy) values of a
    sample; at no deviation the nominal parameters to the bit (their kept factor then serves)."""
    model = ToleranceModel.of(two_bays, parse_tolerances(["defaults"]))
    e = np.random.default_rng(3).standard_normal(model.size) * model.spread
    fields = ("pressure", "stiffness_span", "stiffness_chord", "prestrain_span", "prestrain_chord", "rib_shape",
              "rib_shape_tip")
    programs = []
    with jax.enable_x64(True):
        for k in range(2):
            def changed(v, k=k):
                p = model.bay_parameters(k, v)
                return {f: getattr(p, f) for f in fields}

            calls = [q for q in jax.make_jaxpr(changed)(e).eqns if q.primitive.name in ("pjit", "jit")]
            assert [q.params["name"] for q in calls] == ["bay_changes"]
            programs.append(str(calls[0].params["jaxpr"]))
            concrete, traced = model.bay_parameters(k, e), jax.jit(changed)(e)
            for f in fields:
                np.testing.assert_allclose(np.asarray(traced[f]), np.asarray(getattr(concrete, f)), rtol=1e-14,
                                           err_msg=f)
            assert float(concrete.prestrain_span) != float(model.nominal[k].prestrain_span)
            at_zero = jax.jit(changed)(np.zeros(model.size))
            for f in fields:
                nominal = getattr(model.nominal[k], f)
                np.testing.assert_array_equal(np.asarray(at_zero[f]), np.zeros(model.shape_terms) if nominal is None
                                              else np.asarray(nominal), err_msg=f)
    assert programs[0] == programs[1]


def test_a_samples_warm_start_is_the_nominal_moved_to_first_order(two_bays):
    """A Monte Carlo sample starts from the nominal nodes moved by their tangents (`predicted_start`): for
    each source that scatters bay 1, drawn at its spread alone (its rib profiles move its mounted shape),
    the start is far closer to the sample's equilibrium than the nominal is (measured 8 times for a rib
    station, 50-500 times for the others), and its error is second order: a half draw leaves about a
    quarter of it (measured 0.23-0.27)."""
    model = ToleranceModel.of(two_bays, parse_tolerances(["defaults"]))
    with jax.enable_x64(True):
        nominal = model.nominal_solutions(1e-11)
        model.bay_jacobian(1, nominal[1], 1e-11)
        scene = model.scenes[1]
        geometry = scene.bay.geometry()
        for c in model.touching[1]:
            errors = []
            for fraction in (1.0, 0.5):
                e = np.zeros(model.size)
                e[c] = fraction * model.spread[c]
                p = model.bay_parameters(1, e)
                exact = np.asarray(solve_equilibrium(scene, p, rtol=1e-11).nodes)
                start = initial_nodes(model.predicted_start(1, e, nominal[1]), geometry, scene.params(p))
                plain = initial_nodes(nominal[1], geometry, scene.params(p))
                errors.append((np.abs(np.asarray(start) - exact).max(), np.abs(np.asarray(plain) - exact).max()))
            (moved, plain), (half, _) = errors
            assert moved < 0.2 * plain, (model.columns[c].name, errors)
            assert 0.15 < half / moved < 0.35, (model.columns[c].name, errors)


def test_budget_meets_the_spec(one_bay):
    """The common scale of the budget puts the linear p95 of the rms on the spec (the same draws), and
    each source's budget alone does the same with the others exact."""
    tolerances = parse_tolerances({"pressure": "2%", "cut_span": 0.5, "rib_station": 1.0})
    spec = 1.1e3 * one_bay.rms_error  # mm: 10% above the rms on the largest chord (1 m)
    analysis = tolerance_analysis(one_bay, tolerances, spec=spec)
    budget = analysis.budget
    nominal = np.sqrt(np.mean(analysis.distances[0] ** 2))
    assert budget["nominal_rms"] == pytest.approx(nominal, rel=1e-9) and budget["met_at_nominal"]
    assert 0 < budget["common_scale"] < budget["sources"]["cut_span"]["scale"]
    scaled = {n: t.scaled(budget["common_scale"]) for n, t in tolerances.items()}
    assert tolerance_analysis(one_bay, scaled).linear["rms"]["p95"] == pytest.approx(spec, rel=1e-6)
    alone = budget["sources"]["cut_span"]
    only = {"cut_span": tolerances["cut_span"].scaled(alone["scale"])}
    assert tolerance_analysis(one_bay, only).linear["rms"]["p95"] == pytest.approx(spec, rel=0.02)
    shares = analysis.shares["rms"]
    assert set(shares) == set(tolerances) and sum(shares.values()) == pytest.approx(1.0)


@pytest.mark.parametrize("name, value, message", [
    ("pressure", "-1", "0 or more"),
    ("thickness", "1", "no such source"),
    ("stiffness_span", "100%", "100% or more"),
    ("stiffness_chord", "uniform:100%", "100% or more"),
    ("rib_station", "2%", "in mm"),
    ("cut_span", "abc", "expected a standard deviation"),
])
def test_bad_tolerances_are_refused(name, value, message):
    with pytest.raises(ValueError, match=message):
        parse_tolerance(name, value)


def test_bad_samples_and_spec_are_refused(one_bay):
    with pytest.raises(ValueError, match="0 or more"):
        tolerance_analysis(one_bay, {"pressure": "2%"}, sampling=Sampling(samples=-1))
    with pytest.raises(ValueError, match="must be positive"):
        tolerance_analysis(one_bay, {"pressure": "2%"}, spec=0.0)


def test_parsing_forms():
    t = parse_tolerances(["pressure=uniform:3%", "defaults", "cut_span=0"])
    assert t["pressure"].uniform and t["pressure"].relative and t["pressure"].value == 3.0  # defaults first
    assert t["pressure"].std(1e4) == pytest.approx(300 / math.sqrt(3))
    assert t["cut_span"].value == 0.0 and t["stiffness_chord"].text == "10%"
    assert parse_tolerance("rib_profile", "default").value == 0.5


def test_a_failed_sample_is_counted_named_and_kept(one_bay):
    """A pressure scatter of uniform:150% draws negative pressures (a third of the wings): their solves
    are refused, and each such sample is counted, named with its bay and why, and kept as a row."""
    rows = []
    analysis = tolerance_analysis(one_bay, {"pressure": "uniform:150%"},
                                  sampling=Sampling(samples=6, seed=0, on_sample=rows.append))
    failed = [row for row in rows if not row["converged"]]
    assert len(rows) == 6 and failed and analysis.sampled["failed"] == len(failed)
    assert all(row["pressure"] <= 0 and math.isnan(row["rms"]) for row in failed)
    assert [f["sample"] for f in analysis.failures] == [row["sample"] for row in failed]
    assert all(f["bay"] == 0 and "pressure must be a positive" in f["message"] for f in analysis.failures)
    assert analysis.sampled["rms"]["mean"] == pytest.approx(np.mean([r["rms"] for r in rows if r["converged"]]))
