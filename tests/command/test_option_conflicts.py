"""Options that contradict each other are refused (exit 2, one line naming both); options given that the
run ignores are named in a warning line; ``--help`` names the cache variables.

Every refusal here comes before any solve (`case.Case.from_arguments` checks the combinations as the
options are read), so the command runs in this process (`cli.main`).
"""

import pytest

from inverse_design.app import cli, design
from inverse_design.app.case import Case
from inverse_design.app.options import InputError
from support.cases import IN_PROCESS, SMALL, TAPERED_BAY


@pytest.mark.parametrize("argv, message", [
    (["--no-tension-constraints", "--min-tension", "100"],
     "--min-tension 100 N/m contradicts --no-tension-constraints, which drops both tension limits: give one or "
     "the other"),
    (["--max-tension", "5000", "--no-tension-constraints"],
     "--max-tension 5000 N/m contradicts --no-tension-constraints"),
    (["--evaluate", "--refine"],
     "--refine polishes a design on a finer grid, and --evaluate solves one equilibrium and designs nothing: give "
     "one or the other"),
    (["--evaluate", "--variables", "pressure,rib_shape"],
     "--evaluate solves at the given values, and rib_shape of --variables has no value to give (it would solve "
     "the unshaped rib and the uniform cut): drop --evaluate to design it, or drop it from --variables"),
    (["--evaluate", "--variables", "cut_pattern"], "and cut_pattern of --variables has no value to give"),
    (["--method", "root", "--variables", "pressure,prestrain_span"],
     "--method root solves for the pressure alone (brentq on one scalar condition at mid-bay, --root-condition), "
     "got --variables pressure,prestrain_span: give --variables pressure, or another --method"),
    (["--method", "root"], "got --variables pressure,rib_thickness_scale"),  # the default variables
], ids=["min tension", "max tension", "evaluate refine", "evaluate rib shape", "evaluate cut pattern",
        "root two variables", "root default variables"])
def test_contradicting_options_exit_2_with_one_line(tmp_path, capsys, argv, message):
    out = tmp_path / "out"
    code = cli.main([*argv, *SMALL, *IN_PROCESS, "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith("optimise-pressure: error: ") and message in err
    assert not out.exists()


def test_a_case_file_contradiction_names_the_case_file(tmp_path):
    (tmp_path / "case.toml").write_text("no-tension-constraints = true\nmin-tension = 50\n")
    with pytest.raises(InputError) as info:
        Case.from_arguments(["--config", str(tmp_path / "case.toml")])
    assert str(info.value).startswith("min-tension (case file) 50 N/m contradicts no-tension-constraints (case file)")


@pytest.mark.parametrize("argv", [["--no-tension-constraints"], ["--evaluate"], ["--refine"],
                                  ["--method", "root", "--variables", "pressure"],
                                  ["--evaluate", "--variables", "pressure"], ["--min-tension", "100"]])
def test_options_that_agree_still_parse(argv):
    Case.from_arguments(argv)


def test_variables_ignored_by_evaluate_are_named_in_a_warning():
    assert Case.from_arguments(["--evaluate", "--variables", "pressure,prestrain_span"]).ignored_options() == [
        "--variables pressure,prestrain_span is ignored with --evaluate, which solves the equilibrium at the "
        "given values (--pressure, --prestrain-span, ...) and optimises nothing"]
    for argv in (["--evaluate"], ["--variables", "pressure"]):
        assert Case.from_arguments(argv).ignored_options() == []


def test_a_wing_with_method_root_keeps_its_own_message(tmp_path):
    (tmp_path / "wing.toml").write_text('method = "root"\n' + TAPERED_BAY)
    Case.from_arguments(["--config", str(tmp_path / "wing.toml")])  # (a wing: its own check, which two ribs pass)


def test_equilibrium_methods_that_the_batch_cannot_run_are_refused_there_only():
    case = Case.from_arguments(["--equilibrium-method", "newton"])
    with pytest.raises(InputError, match="--equilibrium-method newton: on this machine's accelerator "
                                         "the design relaxes its bays together in one batch"):
        design.check_equilibrium_method(case, "batch")
    design.check_equilibrium_method(case, "loop")  # the CPU runs every method
    for argv in (["--equilibrium-method", "relax"], ["--equilibrium-method", "auto"],
                 ["--equilibrium-method", "newton", "--evaluate"]):
        design.check_equilibrium_method(Case.from_arguments(argv), "batch")


def test_newton_on_a_wing_is_honoured_on_the_cpu(tmp_path, capsys, monkeypatch):
    from forward_solver.solvers.bays import default_strategy
    from inverse_design import problem

    if default_strategy() != "loop":
        pytest.skip("a batch backend: newton is refused there (test above)")
    asked = []

    def record(*args, method, **kwargs):
        asked.append(method)
        raise KeyboardInterrupt  # stop before any solve

    monkeypatch.setattr(problem, "solve_bays", record)
    (tmp_path / "wing.toml").write_text(TAPERED_BAY)
    code = cli.main(["--config", str(tmp_path / "wing.toml"), "--equilibrium-method", "newton", "--out",
                     str(tmp_path / "out"), *IN_PROCESS])
    assert code == cli.EXIT_INTERRUPTED and asked == ["newton"], capsys.readouterr().err


def test_help_names_the_cache_variables_and_the_refusals_page(capsys):
    with pytest.raises(SystemExit):
        Case.from_arguments(["--help"])
    text = capsys.readouterr().out
    for name in ("INFLATABLE_WING_CACHE", "JAX_COMPILATION_CACHE_DIR", "XDG_CACHE_HOME", "docs/errors.md"):
        assert name in text
