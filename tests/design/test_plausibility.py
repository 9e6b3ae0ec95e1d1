"""Plausibility warnings: inputs outside the ranges the model and its validation cover, and numerical
and drawing choices outside their limits (a coarse design grid, a seam allowance, field terms, the
Reynolds number of the aerodynamic comparison).

`check_plausibility` is pure Python (no solve); the command's use of it is
checked in tests/command/test_cli.py (one bay) and tests/command/test_wing_cli.py (a wing).
"""

import warnings

import pytest

from forward_solver import Fabric, Parameters
from inverse_design.plausibility import LIMITS, RANGES, PlausibilityWarning, check_plausibility

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


@pytest.mark.parametrize("keywords, expected", [
    (dict(grid=(9, 32)), "the design grid has 9 span nodes, fewer than the 17 that the grid study found enough "
                         "(on 9 the default design lands at 6.4 kPa and rib scale 0.945 against 1 kPa and 1.0 on "
                         "17 or more"),
    (dict(seam_allowance_mm=60.0), "seam allowance 60 mm is more than 50 mm: the value is in millimetres"),
    (dict(grid=(17, 32), terms={"cut_pattern": 9}),
     "cut pattern of 9 terms on 32 contour nodes: more than a quarter of the nodes (8)"),
    (dict(grid=(17, 64), terms={"rib_shape": 17}), "give rib_shape terms 16 or fewer, or more contour nodes (n_contour)"),
    (dict(reynolds=1e9), "Reynolds number 1e+09 lies outside NeuralFoil's training data (3e+02 to 3e+08)"),
    (dict(reynolds=100.0), "Reynolds number 100 lies outside NeuralFoil's training data"),
], ids=["coarse grid", "seam allowance", "cut pattern terms", "rib shape terms", "reynolds high", "reynolds low"])
def test_numerical_and_drawing_choices_outside_their_limits_give_one_line(keywords, expected):
    with pytest.warns(PlausibilityWarning):
        lines = check_plausibility(Fabric(), DEFAULT, BAY, DEFAULT_BOUNDS, **keywords)
    assert len(lines) == 1 and expected in lines[0], lines


def test_the_limits_themselves_give_no_line():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert check_plausibility(Fabric(), DEFAULT, BAY, DEFAULT_BOUNDS, grid=(17, 64), seam_allowance_mm=50.0,
                                  terms={"cut_pattern": 16, "rib_shape": 4}, reynolds=1e6) == []
        # one equilibrium on a coarse grid is not a design: its optimum is not in question
        assert check_plausibility(Fabric(), DEFAULT, BAY, grid=(5, 32), design=False) == []
    low, high = LIMITS["reynolds"]
    assert low == pytest.approx(316.2, rel=1e-3) and high == pytest.approx(3.162e8, rel=1e-3)


def test_the_command_shows_and_records_the_new_lines(tmp_path, capsys):
    from inverse_design.app import run
    from inverse_design.app.case import Case

    case = Case.from_arguments(
        ["--n-span", "9", "--n-contour", "32", "--seam-allowance", "80", "--variables", "pressure,cut_pattern",
         "--cut-pattern-terms", "12", "--aero", "--reynolds", "5e9", "--out", str(tmp_path / "out")])
    lines = run.warn(case)
    err = capsys.readouterr().err.splitlines()
    assert err == [f"optimise-pressure: warning: {line}" for line in lines]  # what the summary records
    assert [line.split(" ")[:2] for line in lines] == [["the", "design"], ["seam", "allowance"], ["cut", "pattern"],
                                                      ["Reynolds", "number"]]
    # The command's own lines name its options.
    assert lines[0].endswith("give --n-span 17 or more, or --refine")
    assert lines[2].endswith("give --cut-pattern-terms 8 or fewer, or more --n-contour")
    # --refine reaches 17 span nodes from 9: the grid is then not in question; --no-patterns draws no seam.
    case = Case.from_arguments(["--n-span", "9", "--refine", "--seam-allowance", "80", "--no-patterns", "--quiet"])
    assert run.warn(case) == []
    assert capsys.readouterr().err == ""
