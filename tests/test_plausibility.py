"""Plausibility warnings: inputs outside the ranges the model and its validation cover.

`check_plausibility` is pure Python (no solve); the command's use of it is
checked in tests/test_cli.py (one bay) and tests/test_wing_cli.py (a wing).
"""

import warnings

import pytest

from forward_solver import Fabric, Parameters
from inverse_design.plausibility import RANGES, PlausibilityWarning, check_plausibility

DEFAULT = Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.02)
DEFAULT_BOUNDS = {"pressure": (1e3, 1e5), "rib_thickness_scale": (0.7, 1.0)}
BAY = [(0.25, 1.0)]


def test_the_default_case_gives_no_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any warning fails the test
        assert check_plausibility(Fabric(), DEFAULT, BAY, DEFAULT_BOUNDS) == []
        assert check_plausibility(Fabric(), DEFAULT, BAY, {"prestrain_span": (0.0, 0.05),
                                                           "prestrain_chord": (0.0, 0.05)}) == []
        # The built-in wing's bays: 0.25 m apart, mean chords 0.925 to 0.65 m.
        assert check_plausibility(Fabric(), DEFAULT, [(0.25, 0.925), (0.25, 0.775), (0.25, 0.65)]) == []


@pytest.mark.parametrize("fabric, parameters, bays, bounds, expected", [
    (Fabric(), DEFAULT.replace(prestrain_span=0.8), BAY, None,
     "prestrain span 0.8 (80%) lies outside the range the model is validated for (-2% to 5%)"),
    (Fabric(), DEFAULT.replace(prestrain_chord=-0.05), BAY, None, "prestrain chord -0.05 (-5%) lies outside"),
    (Fabric(), DEFAULT, [(100.0, 250.0)], None,
     "rib spacing 100 m lies outside the range the model is validated for (0.05 to 0.5 m)"),
    (Fabric(), DEFAULT, [(0.3, 0.2)], None,
     "rib spacing / chord 1.5 lies outside the range the model is validated for (0.05 to 0.5)"),
    (Fabric(), DEFAULT.replace(pressure=5e5), BAY, None, "pressure 5e+05 Pa lies outside"),
    (Fabric(), DEFAULT.replace(pressure=50.0), BAY, None, "pressure 50 Pa lies outside"),
    (Fabric(stiffness_span=5e6, stiffness_chord=1e6), DEFAULT, BAY, None, "stiffness span 5e+06 N/m lies outside"),
    (Fabric(), DEFAULT.replace(stiffness_chord=1e3), BAY, None, "stiffness chord 1000 N/m lies outside"),
    (Fabric(stiffness_span=1e6, stiffness_chord=2e4), DEFAULT, BAY, None,
     "stiffness ratio span/chord 50 lies outside the range the model is validated for (0.1 to 10)"),
    (Fabric(), DEFAULT, BAY, {"pressure": (1e3, 1e6)},
     "pressure bounds 1000 Pa to 1e+06 Pa reach outside the range the model is validated for"),
    (Fabric(), DEFAULT, BAY, {"prestrain_span": (0.0, 0.2)}, "prestrain span bounds 0 (0%) to 0.2 (20%) reach"),
    (Fabric(), DEFAULT, [(0.25, 1.0), (2.0, 1.0)], None, "bay 1: rib spacing 2 m lies outside"),
], ids=["prestrain 80%", "prestrain -5%", "rib spacing 100 m", "spacing over chord", "pressure high",
        "pressure low", "stiffness high", "stiffness low (parameters)", "stiffness ratio", "pressure bounds",
        "prestrain bounds", "a wing's bay"])
def test_each_input_outside_its_range_gives_one_warning(fabric, parameters, bays, bounds, expected):
    with pytest.warns(PlausibilityWarning) as caught:
        lines = check_plausibility(fabric, parameters, bays, bounds)
    ours = [line for line in lines if expected in line]
    assert len(ours) == 1, lines
    assert all("\n" not in line for line in lines)
    assert [str(w.message) for w in caught] == lines  # one warning per line, the same text


def test_the_issue_inputs_warn_and_warn_false_only_returns_the_lines():
    parameters = {"pressure": 1e4, "prestrain_span": 0.8, "prestrain_chord": 0.02}  # a mapping works too
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lines = check_plausibility(Fabric(), parameters, [(100.0, 1.0)], warn=False)
    assert len(lines) == 3  # the prestrain, the rib spacing and the spacing over the chord
    assert issubclass(PlausibilityWarning, UserWarning)
    assert set(RANGES) == {"pressure", "stiffness", "stiffness_ratio", "prestrain", "rib_spacing",
                           "rib_spacing_over_chord"}
