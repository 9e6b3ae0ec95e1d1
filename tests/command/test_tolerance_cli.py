"""``optimise-pressure --tolerance NAME=VALUE`` and a case file's ``[tolerances]`` table (docs/tolerances.md):
a run with the analysis and samples writes its section, figure and CSV; bad input is refused before any
solve with one line and nothing written. The command runs in this process (`cli.main`), on 5x32 bays."""

import csv
import json

import pytest

from inverse_design.app import cli
from inverse_design.app.case import Case
from inverse_design.app.options import InputError
from support.cases import IN_PROCESS, SMALL, case_text

RIBS = (("naca2412", 1.0, 0.0), ("naca2412", 0.9, 0.25), ("naca2412", 0.8, 0.5))
TOLERANCES = {"pressure": "2%", "stiffness_span": "uniform:10%", "cut_chord": 0.5, "rib_station": 1.0}
CASE = case_text(*RIBS, tables={"tolerances": TOLERANCES}, variables=["pressure"], pressure=5e3, n_span=5,
                 n_contour=32, evaluate=True)


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
    (["--tolerance", "pressure=2%", "--samples", "-1"], "argument --samples: must be 0 or more"),
    (["--tolerance", "pressure=2%", "--shape-spec", "0"], "must be a positive number (mm)"),
    (["--objective", "robust", "--tolerance", "pressure=0"], "every tolerance given is 0"),
    (["--objective", "robust", "--evaluate"], "designs nothing"),
    (["--objective", "robust", "--method", "slsqp"], "is minimised by gauss_newton"),
])
def test_bad_input_is_refused_before_any_solve(args, message, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code = cli.main([*args, *SMALL, *IN_PROCESS])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and message in err, err
    assert list(tmp_path.iterdir()) == []


def test_the_case_file_table_and_the_command_line_merge(tmp_path):
    case = tmp_path / "case.toml"
    case.write_text('tolerance = 1e-5\n[tolerances]\ndefaults = true\npressure = "1%"\n')
    options = Case.from_arguments(["--config", str(case), "--tolerance", "pressure=3%", "--tolerance", "1e-6"]).options
    assert options.tolerance == 1e-6  # a number: still the optimiser's tolerance
    assert options.tolerances == ["defaults", "pressure=1%", "pressure=3%"]  # the command line's last
    case.write_text('tolerance = "pressure=2%"\n')
    with pytest.raises(InputError, match=r"\[tolerances\] table"):
        Case.from_arguments(["--config", str(case)])


@pytest.mark.parametrize("argv, writes, never", [
    ([], [], ["tolerance.png", "tolerance_samples.csv"]),
    (["--tolerance", "defaults"], ["tolerance.png"], ["tolerance_samples.csv"]),
    (["--tolerance", "defaults", "--samples", "4"], ["tolerance.png", "tolerance_samples.csv"], []),
    (["--objective", "robust"], ["tolerance.png"], ["tolerance_samples.csv"]),
], ids=["none", "first order", "samples", "robust: the defaults"])
def test_what_a_run_with_tolerances_may_write(argv, writes, never):
    may = Case.from_arguments(argv).may_write
    assert all(may(name) for name in writes) and not any(may(name) for name in never)


def test_the_analysis_options_without_tolerances_are_said_to_be_ignored():
    lines = Case.from_arguments(["--samples", "10", "--shape-spec", "3"]).ignored_options()
    assert [line.split(" is ignored")[0] for line in lines] == ["--shape-spec", "--samples"]


def test_a_scheduler_without_tolerances_or_samples_is_said_to_be_ignored():
    for argv, ignored in ((["--scheduler", "tcp://h:8786"], "without tolerances"),
                          (["--tolerance", "defaults", "--scheduler", "tcp://h:8786"], "without --samples")):
        lines = Case.from_arguments(argv).ignored_options()
        assert len(lines) == 1 and lines[0].startswith(f"--scheduler is ignored {ignored}"), lines
    assert Case.from_arguments(["--tolerance", "defaults", "--samples", "4", "--scheduler", "tcp://h:1"]
                               ).ignored_options() == []


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


ROBUST_CASE = case_text(*RIBS, variables=["pressure"], pressure=5e3, n_span=5, n_contour=32, objective="robust")


def test_a_robust_design_of_a_wing_reports_its_percentiles(tmp_path, capsys):
    """``objective = "robust"`` without tolerances: designed for the defaults, which the analysis then
    reports; the tension rows at their percentile are in the summary."""
    case = tmp_path / "wing.toml"
    case.write_text(ROBUST_CASE)
    out = tmp_path / "out"
    code = cli.main(["--config", str(case), "--out", str(out), "--no-patterns", "--no-figures", *IN_PROCESS])
    assert code == 0, capsys.readouterr().err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["errors"]["objective"] == "robust"
    assert set(summary["tolerance"]["inputs"]) == {"pressure", "stiffness_span", "stiffness_chord", "cut_span",
                                                   "cut_chord", "rib_station", "rib_profile"}
    assert summary["constraints"]["values"]["min_tension_p5"] >= 0.0
    assert all(entry["robust_p95"] > 0 for entry in summary["history"])
