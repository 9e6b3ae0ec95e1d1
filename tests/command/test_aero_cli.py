"""The command's ``--aero`` (the comparison itself: tests/design/test_aero.py): a missing NeuralFoil and bad
angles are refused before any solve; a run writes each bay's figure and summary entry."""

import json
import subprocess
import sys

import pytest

from inverse_design.app import cli
from support.cases import SMALL
from support.command import environment, launch


def test_cli_without_neuralfoil_exits_before_solving(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "neuralfoil", None)
    code = cli.main(["--aero", "--evaluate", *SMALL, "--no-compilation-cache", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert err[0].startswith("optimise-pressure: error: --aero")
    assert 'pip install "inflatable-wing[aero]"' in err[0]
    assert not (tmp_path / "out").exists()


def test_cli_bad_alpha_range_in_case_file(tmp_path, capsys):
    case = tmp_path / "case.toml"
    case.write_text("aero = true\nalpha-range = [-4, 10]\n")
    assert cli.main(["--config", str(case), "--out", str(tmp_path / "out")]) == 2
    assert "alpha-range must be a list [start, stop, step]" in capsys.readouterr().err


def test_cli_writes_aero(tmp_path):
    pytest.importorskip("neuralfoil", reason="NeuralFoil is not installed (pip install -e '.[aero]')")
    done = subprocess.run(launch("--aero", "--evaluate", *SMALL, "--reynolds", "5e5", "--alpha-range", "-2", "6", "2",
                                 "--out", "out"), cwd=tmp_path,
                          env=environment(INFLATABLE_WING_CACHE=str(tmp_path / "cache")), capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    out = tmp_path / "out"
    summary = json.loads((out / "summary.json").read_text())
    assert (out / "bay_0_aero.png").stat().st_size > 10_000 and "bay_0_aero.png" in summary["files"]
    record = summary["bays"][0]["aero"]
    assert record["reynolds"] == 5e5 and record["alphas_deg"] == [-2.0, 0.0, 2.0, 4.0, 6.0]
    for section in ("target", "mid_bay", "bay_average"):
        assert len(record["sections"][section]["cd"]) == 5
    largest = record["max_abs_difference"]["mid_bay"]
    assert largest["cl"] > 0 and largest["cd"] > 0 and largest["cm"] > 0
    assert "aerodynamics at Re 5e+05" in done.stdout
