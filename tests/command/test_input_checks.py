"""Every option checked as the case is read, before any solve, with one line that names it (or the
case file and its key) and says what to change; the library's defaults are the command's."""

import pytest

from inverse_design.app.case import Case
from inverse_design.app.options import InputError


@pytest.mark.parametrize("argv, message", [
    (["--seed", "-1"], "argument --seed: must be 0 or more, got '-1' (see optimise-pressure --help)"),
    (["--max-iterations", "0"], "argument --max-iterations: must be 1 or more, got '0' (see optimise-pressure --help)"),
    (["--n-span", "2"], "argument --n-span: must be 3 or more (the two ribs and at least one row between), got '2'"),
    (["--n-contour", "8"], "argument --n-contour: must be 12 or more (nodes around an airfoil), got '8'"),
    (["--variables", "presure"], "--variables: unknown design variable 'presure'; choose among pressure, "),
    (["--target", ""], "--target: the section is an empty name (an unset shell variable?); give a NACA code"),
    (["--seam-allowance", "1e9"], "--seam-allowance 1e+09 mm puts the cut line more than 1 m outside the sewing "
                                  "line: give the allowance in millimetres"),
    (["--rib-spacing", "1000"], "--rib-spacing 1000: the ribs lie 1000 m apart on a 1 m chord, more than 5 chords"),
    (["--prestrain-bounds", "0.05", "0"], "--prestrain-bounds 0.05 0: the lower bound must lie below the upper"),
], ids=["seed", "iterations", "n-span", "n-contour", "variable", "empty-target", "seam", "far-ribs", "bounds"])
def test_a_bad_option_is_refused_as_the_case_is_read(argv, message):
    with pytest.raises(InputError) as info:
        Case.from_arguments([*argv, "--out", "unused"])
    assert str(info.value).startswith(message), str(info.value)


@pytest.mark.parametrize("text, message", [
    ('n-span = "17"\n', 'case.toml: n-span must be a number, got the string "17": write it without quotes, '
                        'e.g. n-span = 17'),
    ('pressure = true\n', "case.toml: pressure must be a number, got true: give a number, e.g. pressure = 10000"),
    ('n-span = -17\n', "case.toml: n-span: must be 3 or more (the two ribs and at least one row between), got '-17'"),
    ('variables = ["presure"]\n', "case.toml: variables: unknown design variable 'presure'"),
    ('[rib]\nsection = "naca2412"\nchord = 1.0\nstation = 0.0\n',
     "case.toml: [rib] is one table; list each rib as a [[rib]] table (two brackets), root to tip, at least two"),
    ('[[rib]]\nsection = "naca2412"\nchord = "1.0"\nstation = 0.0\n[[rib]]\nsection = "naca2412"\nchord = 1.0\n'
     'station = 0.25\n', 'case.toml: rib 0: chord must be a finite number in m, got the string "1.0": write it '
                         'without quotes'),
    ('[[rib]]\nsection = "naca2412"\nchord = 1.0\nstation = 0.0\n[[rib]]\nsection = "naca2412"\nchord = 1.0\n'
     'station = 1000.0\n', "case.toml: ribs 0 and 1: the ribs lie 1000 m apart on a 1 m chord, more than 5 chords"),
], ids=["string", "boolean", "negative", "variable", "one-rib-table", "rib-chord-string", "far-ribs"])
def test_a_bad_case_file_is_refused_naming_the_file_and_key(tmp_path, monkeypatch, text, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "case.toml").write_text(text)
    with pytest.raises(InputError) as info:
        Case.from_arguments(["--config", "case.toml", "--out", "unused"])
    assert str(info.value).startswith(message), str(info.value)


def test_a_case_file_with_a_byte_order_mark_is_read(tmp_path):
    case = tmp_path / "case.toml"
    case.write_bytes("\ufeffn-span = 9\n".encode("utf-8"))  # (as some editors save UTF-8)
    assert Case.from_arguments(["--config", str(case), "--out", "unused"]).options.n_span == 9


def test_the_library_defaults_are_the_commands():
    from forward_solver.model.bay import N_CONTOUR, N_SPAN
    from inverse_design import defaults
    from inverse_design.objectives import DEFAULT_OBJECTIVE
    from inverse_design.settings import Layout
    from inverse_design.variables import DEFAULT_START, VARIABLES

    o = Case.from_arguments(["--out", "unused"]).options
    assert (o.objective, o.n_span, o.n_contour) == (DEFAULT_OBJECTIVE, Layout().n_span, Layout().n_contour)
    assert (o.pressure, o.prestrain_span, o.prestrain_chord) == (
        DEFAULT_START.pressure, DEFAULT_START.prestrain_span, DEFAULT_START.prestrain_chord)
    assert (N_SPAN, N_CONTOUR) == (defaults.N_SPAN, defaults.N_CONTOUR)  # (the solver's own bay grid)
    assert tuple(o.variables.split(",")) == defaults.DESIGN_VARIABLES and VARIABLES == defaults.VARIABLES


def test_a_negative_tension_floor_warns_that_the_skin_may_wrinkle():
    from inverse_design.app import design

    lines = design.warning_lines(Case.from_arguments(["--min-tension", "-10", "--n-span", "5", "--n-contour", "32",
                                                      "--out", "unused"]))
    assert any(line.startswith("--min-tension -10 N/m lets the skin wrinkle") for line in lines), lines
