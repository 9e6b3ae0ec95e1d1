"""Designs and tolerances with a fibre law fitted to a biaxial test (docs/fabric_test.md).

A test file made from eq. (10) gives the design eq. (10) gives; the tolerance
analysis scales the fitted law by the stiffness columns (its Jacobian against
central differences); Monte Carlo samples record the strains they reach and
warn beyond the tested range. 5x32 bays.
"""

import warnings

import numpy as np
import pytest

from forward_solver.model.biaxial import fit_law
from forward_solver.model.biaxial.synthetic import example_readings, linear_law, synthetic_test
from forward_solver import Fabric, Scene, Wing
from inverse_design import SolverSettings, evaluate_design, optimise_pressure
from inverse_design.fabric_range import FabricRangeWarning, strain_range
from inverse_design.tolerance import Sampling, parse_tolerances, tolerance_analysis
from support.design import wing_outputs
from support.solver import default_bay
from targets import naca

VARIABLES = ("pressure", "prestrain_span", "prestrain_chord")
START = {"pressure": 5e3, "prestrain_span": 0.02, "prestrain_chord": 0.02}


def _design(fabric):
    return optimise_pressure(Scene(default_bay(5, 32), fabric), target=naca("2412"), variables=VARIABLES,
                             initial={"pressure": 5e3, "prestrain_span": 0.01, "prestrain_chord": 0.01},
                             bounds={"pressure": (1e3, 1e5), "prestrain_span": (0.0, 0.05),
                                     "prestrain_chord": (-0.02, 0.05)})


@pytest.fixture(scope="module")
def linear_design():
    return _design(Fabric())


@pytest.mark.parametrize("warp", ["span", "chord"])
def test_a_test_made_from_eq_10_gives_the_design_of_eq_10(linear_design, warp):
    # E 2e5 N/m both ways, Poisson 0.25, readings along the five standard paths: the fitted surface is
    # eq. (10) to rounding, so the design is the same to 1e-8 relative (measured 1e-12; a variable
    # near zero against its bounds' width).
    law = fit_law(synthetic_test(linear_law(2e5, 2e5, 0.25), 8000.0))
    with pytest.warns(FabricRangeWarning, match="leave the range synthetic tested"):  # (to 5%: continued exactly)
        fitted = _design(Fabric(law=law, warp=warp))
    assert linear_design.success and fitted.success
    widths = {"pressure": 1e5 - 1e3, "prestrain_span": 0.05, "prestrain_chord": 0.07}
    for name, width in widths.items():
        a, b = linear_design.values[name], fitted.values[name]
        assert abs(b - a) <= 1e-8 * max(abs(a), 1e-3 * width), (name, a, b)
    assert abs(fitted.rms_error - linear_design.rms_error) <= 1e-8 * linear_design.rms_error
    scale = np.max(np.abs(linear_design.solution.nodes))
    assert np.max(np.abs(fitted.solution.nodes - linear_design.solution.nodes)) <= 1e-8 * scale


@pytest.fixture(scope="module")
def example_bay():
    wing = Wing(airfoils=(naca("2412"),) * 2, chords=(1.0, 1.0), stations=(0.0, 0.25))
    law = fit_law(example_readings())
    return evaluate_design(wing.scenes(Fabric(law=law, shear_stiffness=3e3), 5, 32), [naca("2412")] * 2, START,
                           objective="average", wing=wing, solver=SolverSettings(rtol=1e-11))


def test_the_law_scale_columns_agree_with_central_differences(example_bay):
    # A fabric lot's stiffness scatter scales the fitted law (its stiffness over the nominal): the tolerance
    # Jacobian's stiffness and pressure columns against central differences of cold solves at rtol 1e-11
    # (a step of 1e-3 of each column's spread; truncation ~1e-6 relative, solve noise ~1e-8 / 1e-3).
    tolerances = parse_tolerances(["pressure=2%", "stiffness_span=10%", "stiffness_chord=5000"])
    analysis = tolerance_analysis(example_bay, tolerances, rtol=1e-11)
    assert analysis.columns == ["pressure", "stiffness_span", "stiffness_chord"]
    law = example_bay.per_bay.scenes[0].fabric.law
    assert analysis.nominal[1] == law.stiffness_warp and analysis.nominal[2] == law.stiffness_weft
    jd, jt = np.vstack(analysis.distance_jacobians), np.vstack(analysis.tension_jacobians)
    for i in range(3):
        step = 1e-3 * analysis.std[i]
        e = np.zeros(3)
        e[i] = step
        plus, minus = (wing_outputs(example_bay, tolerances, e, rtol=1e-11),
                       wing_outputs(example_bay, tolerances, -e, rtol=1e-11))
        for exact, fd in ((jd[:, i], (np.concatenate(plus[0]) - np.concatenate(minus[0])) / (2 * step)),
                          (jt[:, i], (np.concatenate(plus[1]) - np.concatenate(minus[1])) / (2 * step))):
            scale = np.max(np.abs(fd))
            assert scale > 0 and np.max(np.abs(exact - fd)) <= 1e-4 * scale, (analysis.columns[i], scale)


def test_monte_carlo_samples_record_their_strains_and_warn_beyond_the_test(example_bay):
    reached = strain_range(example_bay)
    law = example_bay.per_bay.scenes[0].fabric.law
    assert law.surface.warp_range[0] <= reached["span"][0] and reached["span"][1] <= law.surface.warp_range[1]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        inside = tolerance_analysis(example_bay, parse_tolerances(["pressure=1%"]), sampling=Sampling(samples=2))
        outside = tolerance_analysis(example_bay, parse_tolerances(["cut_span=uniform:15"]),  # (prestrain +-6%)
                                     sampling=Sampling(samples=3, seed=1))
    for analysis in (inside, outside):
        strains = analysis.sampled["fibre_strains"]
        assert strains["span"][0] <= strains["span"][1] and strains["chord"][0] <= strains["chord"][1]
    lines = [str(w.message) for w in caught if issubclass(w.category, FabricRangeWarning)]
    assert outside.sampled["fibre_strains"]["span"][1] > law.surface.warp_range[1]  # (the warp along the span)
    assert len(lines) == 1 and lines[0].startswith("the fibre strains of the Monte Carlo samples leave the range")
