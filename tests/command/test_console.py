"""What the console says at the end of a run, read from the summary: labelled, grouped and short on a
large case (the 40-cell wing's "wrote" line was 12,000 characters, its active bounds 20 entries)."""

from inverse_design.app import console


def test_the_components_of_a_vector_variable_at_one_bound_are_one_entry():
    active = ["pressure>=lower", *[f"cut_pattern[{i}][{j}]<=upper" for i in range(4) for j in range(5)],
              "rib_shape[1][3]<=upper", "min_tension"]
    assert console.grouped_names(active) == ["pressure>=lower", "cut_pattern<=upper (20 coefficients)",
                                             "rib_shape[1][3]<=upper", "min_tension"]


def test_a_report_of_many_files_says_how_many_and_where_they_are_listed():
    many = {"out": "/tmp/wing40", "files": [f"pattern_bay_{k}_upper.dxf" for k in range(240)]}
    line = console.wrote_line(many)
    assert line == 'wrote /tmp/wing40 (240 files; summary.json lists them under "files")' and len(line) < 100
    few = {"out": "out", "files": ["summary.json", "wing.npz"]}
    assert console.wrote_line(few) == "wrote out (summary.json, wing.npz)"


def test_a_value_at_a_bound_of_zero_reads_zero():
    assert console.number_text(6.27851e-13) == "0"  # (a prestrain at its lower bound 0, as a design returned it)
    assert console.number_text(1e-6) == "1e-06" and console.number_text(1000.0) == "1000"


def _summary(mode: str, objective: str) -> dict:
    return {"mode": mode, "case": {"ribs": [{"target": "NACA 2412", "chord_m": 1.0, "station_m": 0.0},
                                            {"target": "NACA 2412", "chord_m": 1.0, "station_m": 0.25}],
                                   "n_bays": 1, "grid": [5, 32]},
            "errors": {"objective": objective}}


def test_the_first_line_says_what_the_errors_are_over():
    assert console._case_line(_summary("optimise", "worst")).endswith("5x32 grid, worst objective")
    evaluated = console._case_line(_summary("evaluate", "average"))
    assert evaluated.endswith("errors over every row from rib to rib") and "objective" not in evaluated


def _tolerance(count: int) -> dict:
    stats = {"mean": 2.5, "std": 0.1, "p95": 2.7, "p5": 40.0}
    return {"linear": {"rms": stats, "min_tension": stats}, "sampled": {"rms": stats, "count": count, "failed": 0},
            "budget": None, "shares": {"rms": {"pressure": 1.0}}}


def test_a_95th_percentile_of_few_samples_says_so():
    few, many = console.tolerance_lines(_tolerance(4))[0], console.tolerance_lines(_tolerance(400))[0]
    assert "(4 samples; too few to place a 95th percentile" in few and "too few" not in many
    assert "the wing's least tension, 5th percentile 40 N/m" in many  # (the whole wing's, not a cell's)
