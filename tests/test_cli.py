"""The optimise-pressure command: exit codes, messages and the summary it writes."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(*args, cwd):
    # The repository's sources first, so the test runs the code under test whether or not
    # (and however) the package is installed.
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, "-m", "inverse_design.cli", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--target", "naca24x12"], "NACA"),
        (["--target", "missing.dat"], "missing.dat"),
        (["--chord", "-1"], "chord"),
        (["--n-span", "2"], "n_span"),
    ],
)
def test_bad_input_exits_2_with_one_line(tmp_path, args, message):
    done = _run(*args, "--out", str(tmp_path / "out"), cwd=tmp_path)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("optimise-pressure: error:") and message in lines[0]
    assert "Traceback" not in done.stderr
    assert not (tmp_path / "out" / "summary.json").exists()


def test_evaluate_writes_the_summary(tmp_path):
    done = _run("--evaluate", "--n-span", "5", "--n-contour", "32", "--pressure", "2e4", "--json",
                "--out", str(tmp_path / "out"), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    written = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert written["result"] == "converged" and written["grid"] == [5, 32]
    assert summary["mid_bay_max_error_chord"] >= summary["mid_bay_rms_error_chord"] > 0


def test_a_failed_solve_exits_1_with_the_reason(tmp_path):
    # 60 steps cannot reach equilibrium: the command reports the failure code, no traceback.
    done = _run("--evaluate", "--n-span", "5", "--n-contour", "32", "--max-steps", "60",
                "--out", str(tmp_path / "out"), cwd=tmp_path)
    assert done.returncode == 1
    assert "max_steps_reached" in done.stderr + done.stdout
    assert "Traceback" not in done.stderr
