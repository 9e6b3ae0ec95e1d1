"""``optimise-pressure --tolerance NAME=VALUE`` and a case file's ``[tolerances]`` table (docs/tolerances.md):
a run with the analysis and samples writes its section, figure and CSV; bad input is refused before any
solve with one line and nothing written. The command runs in this process (`cli.main`), on 5x32 bays."""

import csv
import json

import pytest

from inverse_design.app import cli
from inverse_design.app.case import parse_arguments
from inverse_design.app.options import InputError

CASE = """
variables = ["pressure"]
pressure = 5e3
n-span = 5
n-contour = 32
evaluate = true

[tolerances]
pressure = "2%"
stiffness_span = "uniform:10%"
cut_chord = 0.5
rib_station = 1.0

[[rib]]
section = "naca2412"
chord = 1.0
station = 0.0
[[rib]]
section = "naca2412"
chord = 0.9
station = 0.25
[[rib]]
section = "naca2412"
chord = 0.8
station = 0.5
"""


def test_a_wing_with_tolerances_and_samples_writes_its_analysis(tmp_path, capsys):
    case = tmp_path / "wing.toml"
    case.write_text(CASE)
    out = tmp_path / "out"
    code = cli.main(["--config", str(case), "--tolerance", "rib_profile=0.5", "--shape-spec", "20", "--samples", "3",
                     "--seed", "5", "--out", str(out), "--no-compilation-cache", "--no-patterns"])
    printed = capsys.readouterr().out
    assert code == 0, printed
    summary = json.loads((out / "summary.json").read_text())
    section = summary["tolerance"]
    assert set(section["inputs"]) == {"pressure", "stiffness_span", "cut_chord", "rib_station", "rib_profile"}
    assert section["inputs"]["stiffness_span"] == {"value": 10.0, "relative": True, "uniform": True,
                                                   "text": "uniform:10%", "unit": "%"}
    for key in ("linear", "sampled"):
        for measure in ("rms", "max", "min_tension"):
            assert set(section[key][measure]) >= {"mean", "std", "p95"}, (key, measure)
        assert len(section[key]["bays"]) == 2
    assert section["sampled"]["count"] == 3 and section["sampled"]["failed"] == 0
    assert set(section["shares"]["rms"]) == set(section["inputs"])
    assert section["budget"]["spec"] == 20.0 and set(section["budget"]["sources"]) == set(section["inputs"])
    assert {"tolerance", "samples"} <= set(summary["timings_s"])
    assert {"tolerance.png", "tolerance_samples.csv"} <= set(summary["files"])
    with open(out / "tolerance_samples.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [r["sample"] for r in rows] == ["0", "1", "2"]
    assert list(rows[0]) == ["sample", "pressure", "stiffness_span_bay_0", "stiffness_span_bay_1", "cut_chord_bay_0",
                             "cut_chord_bay_1", "rib_station_rib_0", "rib_station_rib_1", "rib_station_rib_2",
                             "rib_profile_rib_0", "rib_profile_rib_1", "rib_profile_rib_2", "rms", "max",
                             "min_tension", "converged"]
    assert abs(float(rows[0]["pressure"]) / 5e3 - 1) < 0.1 and abs(float(rows[0]["rib_station_rib_1"]) - 250) < 5
    assert sum(1 for line in printed.splitlines() if line.startswith("  tolerances:")
               or line.startswith("  budget")) == 2


@pytest.mark.parametrize("args, message", [
    (["--tolerance", "pressure=-2%"], "0 or more"),
    (["--tolerance", "bogus=1"], "no such source"),
    (["--tolerance", "stiffness_span=120%"], "100% or more"),
    (["--tolerance", "stiffness_chord=2e5"], "100% or more"),
    (["--tolerance", "pressure=2%", "--samples", "-1"], "--samples must be 0"),
    (["--tolerance", "pressure=2%", "--shape-spec", "0"], "must be a positive number (mm)"),
    (["--objective", "robust", "--tolerance", "pressure=0"], "every tolerance given is 0"),
    (["--objective", "robust", "--evaluate"], "designs nothing"),
    (["--objective", "robust", "--method", "slsqp"], "is minimised by gauss_newton"),
])
def test_bad_input_is_refused_before_any_solve(args, message, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code = cli.main([*args, "--n-span", "5", "--n-contour", "32", "--no-compilation-cache", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and message in err, err
    assert list(tmp_path.iterdir()) == []


def test_the_case_file_table_and_the_command_line_merge(tmp_path):
    case = tmp_path / "case.toml"
    case.write_text('tolerance = 1e-5\n[tolerances]\ndefaults = true\npressure = "1%"\n')
    args, _ = parse_arguments(["--config", str(case), "--tolerance", "pressure=3%", "--tolerance", "1e-6"])
    assert args.tolerance == 1e-6  # a number: still the optimiser's tolerance
    assert args.tolerances == ["defaults", "pressure=1%", "pressure=3%"]  # the command line's last
    case.write_text('tolerance = "pressure=2%"\n')
    with pytest.raises(InputError, match=r"\[tolerances\] table"):
        parse_arguments(["--config", str(case)])


@pytest.mark.parametrize("argv, writes, never", [
    ([], [], ["tolerance.png", "tolerance_samples.csv"]),
    (["--tolerance", "defaults"], ["tolerance.png"], ["tolerance_samples.csv"]),
    (["--tolerance", "defaults", "--samples", "4"], ["tolerance.png", "tolerance_samples.csv"], []),
    (["--objective", "robust"], ["tolerance.png"], ["tolerance_samples.csv"]),
], ids=["none", "first order", "samples", "robust: the defaults"])
def test_what_a_run_with_tolerances_may_write(argv, writes, never):
    from inverse_design.app import case as case_reader

    args, _ = case_reader.parse_arguments(argv)
    may = case_reader.report_may_write(args)
    assert all(may(name) for name in writes) and not any(may(name) for name in never)


def test_the_analysis_options_without_tolerances_are_said_to_be_ignored():
    from inverse_design.app import case as case_reader

    args, sources = case_reader.parse_arguments(["--samples", "10", "--shape-spec", "3"])
    lines = case_reader.ignored_options(args, sources)
    assert [line.split(" is ignored")[0] for line in lines] == ["--shape-spec", "--samples"]


def test_a_scheduler_without_tolerances_or_samples_is_said_to_be_ignored():
    from inverse_design.app import case as case_reader

    for argv, ignored in ((["--scheduler", "tcp://h:8786"], "without tolerances"),
                          (["--tolerance", "defaults", "--scheduler", "tcp://h:8786"], "without --samples")):
        args, sources = case_reader.parse_arguments(argv)
        lines = case_reader.ignored_options(args, sources)
        assert len(lines) == 1 and lines[0].startswith(f"--scheduler is ignored {ignored}"), lines
    args, sources = case_reader.parse_arguments(["--tolerance", "defaults", "--samples", "4", "--scheduler", "tcp://h:1"])
    assert case_reader.ignored_options(args, sources) == []


def test_a_design_that_does_not_solve_again_keeps_its_report_and_skips_the_analysis(tmp_path, capsys, monkeypatch):
    """The analysis linearises about the design's own equilibrium, solved again to the gradients' tolerance;
    where that solve fails (here: one Newton step allowed), the run still writes the design's report and
    says in a warning line, kept in the summary, that the analysis is skipped."""
    from forward_solver import solve_equilibrium
    from inverse_design.tolerance import model as tolerance_module

    monkeypatch.setattr(tolerance_module, "solve_equilibrium",
                        lambda *a, **k: solve_equilibrium(*a, **{**k, "max_steps": 1, "rtol": 1e-30}))
    out = tmp_path / "out"
    code = cli.main(["--evaluate", "--pressure", "5e3", "--n-span", "5", "--n-contour", "32", "--no-patterns",
                     "--tolerance", "pressure=2%", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert err.count("the tolerance analysis is skipped: the design did not solve again") == 1, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary.get("tolerance") is None and not (out / "tolerance.png").exists()
    assert any(w.startswith("the tolerance analysis is skipped") for w in summary["warnings"])


ROBUST_CASE = CASE.replace("evaluate = true\n", "objective = \"robust\"\n").replace(
    "[tolerances]\npressure = \"2%\"\nstiffness_span = \"uniform:10%\"\ncut_chord = 0.5\nrib_station = 1.0\n", "")


def test_a_robust_design_of_a_wing_reports_its_percentiles(tmp_path, capsys):
    """``objective = "robust"`` without tolerances: designed for the defaults, which the analysis then
    reports; the tension rows at their percentile are in the summary."""
    case = tmp_path / "wing.toml"
    case.write_text(ROBUST_CASE)
    out = tmp_path / "out"
    code = cli.main(["--config", str(case), "--out", str(out), "--no-compilation-cache", "--no-patterns", "--quiet"])
    assert code == 0, capsys.readouterr().err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["errors"]["objective"] == "robust"
    assert set(summary["tolerance"]["inputs"]) == {"pressure", "stiffness_span", "stiffness_chord", "cut_span",
                                                   "cut_chord", "rib_station", "rib_profile"}
    assert summary["constraints"]["values"]["min_tension_p5"] >= 0.0
    assert all(entry["robust_p95"] > 0 for entry in summary["history"])
