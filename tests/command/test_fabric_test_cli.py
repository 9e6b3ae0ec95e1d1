"""The command with a fabric's biaxial test (``--fabric-test``, ``--warp``, ``--shear-stiffness``; a case
file's ``[fabric]`` table): refusals before any solve, one line each as docs/errors.md lists them, and
what the summary records (the law, its fit, the warp, the strains reached and the warning beyond the
tested range)."""

import json
import re
import shutil
from pathlib import Path

import pytest

from forward_solver.model.biaxial.synthetic import linear_law, synthetic_test
from inverse_design.app import cli
from inverse_design.app.case import Case
from inverse_design.app.case_file import EXAMPLE_FABRIC_TEST
from inverse_design.app.options import InputError
from support.cases import IN_PROCESS, SMALL, case_text

PAGE = Path(__file__).parents[2] / "docs" / "errors.md"
PREFIX = "optimise-pressure: error: "


def _page_messages() -> list[str]:
    """The messages of the page's section on the fabric's test."""
    section = PAGE.read_text(encoding="utf-8").split("## The fabric's biaxial test", 1)[1].split("\n## ", 1)[0]
    return [m.group(1) for m in re.finditer(r"^\|[^|]+\|[^|]*\| `([^`]+)` \|", section, flags=re.M)]


def _matches(message: str, documented: str) -> bool:
    """The page's message with its file name and its "…" parts as wildcards."""
    pattern = ".*".join(re.escape(part) for part in documented.split("…"))
    pattern = pattern.replace(re.escape("shop.csv"), ".*?").replace(re.escape("case.toml"), ".*?")
    return re.fullmatch(pattern, message, flags=re.DOTALL) is not None


def _linear_rows() -> list[str]:
    test = synthetic_test(linear_law(2e5, 2e5, 0.25), 8000.0)
    return [",".join([f"{float(v):.6g}" for v in (test.strain_warp[k], test.strain_weft[k], test.tension_warp[k],
                                                 test.tension_weft[k])] + [test.paths[k]]) for k in range(test.size)]


HEADER = "strain_warp,strain_weft,tension_warp,tension_weft,load_ratio"


def _scaled(rows, column, factor):
    out = []
    for row in rows:
        cells = row.split(",")
        cells[column] = repr(float(cells[column]) * factor)
        out.append(",".join(cells))
    return out


def _bad_files():
    rows = _linear_rows()
    falling = list(rows)
    cells = falling[4].split(",")
    cells[2] = repr(float(cells[2]) * 0.5)
    falling[4] = ",".join(cells)
    unloading = [r for r in rows if r.endswith(",2:1")]
    unloading = unloading + unloading[::-1][1:3] + [r for r in rows if not r.endswith(",2:1")]
    nan = list(rows)
    nan[5] = ",".join(c if i != 2 else "nan" for i, c in enumerate(nan[5].split(",")))
    return {
        "columns": ["strain_warp,strain_weft,tension_warp,t_weft", *rows],
        "few": [HEADER, *rows[:8]],
        "one-path": [HEADER, *[r for r in rows if r.endswith(",1:1")] * 2],
        "nan": [HEADER, *nan],
        "percent": [HEADER, *_scaled(_scaled(rows, 0, 100.0), 1, 100.0)],
        "negative": [HEADER, *[r.replace(",0,1:0", ",-500,1:0") for r in rows]],
        "falling": [HEADER, *falling],
        "unloading": [HEADER, *unloading],
    }


@pytest.mark.parametrize("kind", list(_bad_files()))
def test_each_bad_test_file_is_refused_with_its_line_and_exit_2(tmp_path, monkeypatch, capsys, kind):
    monkeypatch.chdir(tmp_path)
    Path("shop.csv").write_text("\n".join(_bad_files()[kind]) + "\n")
    code = cli.main(["--fabric-test", "shop.csv", *SMALL, *IN_PROCESS, "--out", "out"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and err.startswith(PREFIX + "shop.csv: "), err
    message = err[len(PREFIX):].rstrip("\n")
    assert any(_matches(message, documented) for documented in _page_messages()), message  # (docs/errors.md)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shop.csv"]  # nothing written


def test_the_test_is_read_and_fitted_as_the_case_is_read(tmp_path):
    # A case file's [fabric] table: the test file relative to the case file's folder, the warp and the
    # shear stiffness; the command line overrides it. No solve, no JAX needed.
    folder = tmp_path / "cases"
    folder.mkdir()
    shutil.copy(EXAMPLE_FABRIC_TEST, folder / "shop.csv")
    (folder / "case.toml").write_text(case_text(tables={"fabric": {"test": "shop.csv", "warp": "chord",
                                                                    "shear-stiffness": 4000.0}}))
    case = Case.from_arguments(["--config", str(folder / "case.toml"), "--out", "unused"])
    assert case.law is not None and case.law.readings == 50 and case.options.fabric_test == str(folder / "shop.csv")
    assert (case.options.warp, case.options.shear_stiffness) == ("chord", 4000.0)
    fabric = case.fabric
    assert fabric.law == case.law and fabric.warp == "chord" and fabric.shear_stiffness == 4000.0
    assert fabric.stiffness_span == case.law.stiffness_weft  # (the weft runs along the span)
    over = Case.from_arguments(["--config", str(folder / "case.toml"), "--warp", "span", "--out", "unused"])
    assert over.fabric.warp == "span" and over.fabric.stiffness_span == case.law.stiffness_warp
    (folder / "twice.toml").write_text(case_text(fabric_test="shop.csv", tables={"fabric": {"test": "shop.csv"}}))
    with pytest.raises(InputError, match="fabric-test is given twice"):
        Case.from_arguments(["--config", str(folder / "twice.toml"), "--out", "unused"])
    (folder / "bad.toml").write_text(case_text(tables={"fabric": {"stiffness": 1.0}}))
    with pytest.raises(InputError) as caught:
        Case.from_arguments(["--config", str(folder / "bad.toml"), "--out", "unused"])
    assert any(_matches(str(caught.value), documented) for documented in _page_messages()), str(caught.value)


def test_eq_10_is_the_default_and_takes_the_warp_and_shear(tmp_path):
    case = Case.from_arguments(["--shear-stiffness", "3000", "--warp", "chord", "--out", "unused"])
    assert case.law is None and case.fabric.law is None
    assert (case.fabric.stiffness_span, case.fabric.warp, case.fabric.shear_stiffness) == (2e5, "chord", 3000.0)


def test_the_summary_records_the_law_and_warns_beyond_the_tested_range(tmp_path, capsys):
    # One equilibrium at 60 kPa with the example test's law: the strains go past the tested 4.3% (the
    # warning, once, in the summary too); the summary records the law, its fit and the strains reached.
    out = tmp_path / "out"
    code = cli.main(["--fabric-test", str(EXAMPLE_FABRIC_TEST), "--evaluate", "--pressure", "6e4", *SMALL,
                     "--no-figures", "--no-compilation-cache", "--out", str(out)])
    printed = capsys.readouterr()
    err = printed.err
    assert code == 0, err
    assert "  fabric: law fitted to fabric_test_example.csv (degree 4, warp along the span" in printed.out + err
    summary = json.loads((out / "summary.json").read_text())
    law = summary["case"]["fabric"]["law"]
    assert law["kind"] == "strain-energy surface" and law["degree"] == 4 and len(law["coefficients"]) == 12
    assert law["readings"] == 50 and law["paths"] == ["1:1", "2:1", "1:2", "1:0", "0:1"] and len(law["sha256"]) == 16
    assert 0 < law["fit_error_n_per_m"]["rms"]["warp"] < 50 and law["warp"] == "span"
    assert law["tested_strain"]["warp"] == pytest.approx([-0.007925, 0.043278])
    assert summary["case"]["fabric"]["warp"] == "span" and summary["case"]["fabric"]["shear_stiffness_n_per_m"] == 0
    reached = summary["results"]["fibre_strains"]
    assert max(reached["span"][1], reached["chord"][1]) > 0.043278
    beyond = [w for w in summary["warnings"] if "leave the range" in w]
    assert len(beyond) == 1 and beyond[0].startswith("the fibre strains of the equilibrium leave the range")
    assert f"optimise-pressure: warning: {beyond[0]}" in err.splitlines()


def test_a_design_with_the_default_law_records_eq_10(tmp_path):
    out = tmp_path / "out"
    assert cli.main(["--evaluate", *SMALL, "--no-figures", *IN_PROCESS, "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["case"]["fabric"]["law"] == {"kind": "linear, eq. 10", "stiffness_span_n_per_m": 2e5,
                                                "stiffness_chord_n_per_m": 2e5, "poisson": 0.25}
    assert summary["results"]["fibre_strains"] is None
    assert not [w for w in summary["warnings"] if "leave the range" in w]
