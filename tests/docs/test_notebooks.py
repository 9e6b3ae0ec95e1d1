"""The study notebooks run top to bottom in their small mode and show what they claim.

Each notebook is read into memory (the committed file, with its full-study
outputs, is never written) and run with ``WING_FULL_STUDY=0``, and a cell
appended at the end prints the notebook's ``summary`` dict as JSON. The four
run in one kernel, its namespace emptied (``%reset -f``), its figures closed
and matplotlib's settings restored before each: a name a notebook forgets to
define or import still fails it, while the kernel's start and the imports are
paid once (the file alone, in one process with a fresh compilation cache:
39.6 s with a kernel each, 35.0 s so).
The checks below are on those small-mode results: each could fail if the
physics or the solvers changed.

Deselect with ``-m "not notebooks"`` (the four take one to one and a half minutes on two
cores, a few minutes when other jobs share them).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from support.command import environment

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

pytestmark = pytest.mark.notebooks

ROOT = Path(__file__).resolve().parents[2]
NOTEBOOKS = ROOT / "notebooks"
MARK = "NOTEBOOK_SUMMARY="
PACKAGE = "NOTEBOOK_PACKAGE="
REPORT = f"""
import json as _json
import numpy as _np

def _plain(value):
    if isinstance(value, _np.generic):
        return value.item()
    if isinstance(value, _np.ndarray):
        return value.tolist()
    return str(value)

print({MARK!r} + _json.dumps(summary, default=_plain))
print({PACKAGE!r} + __import__("forward_solver").__file__)
"""


#: Run first in the shared kernel before each notebook: an empty namespace, no figures, matplotlib's defaults.
FRESH = """
get_ipython().run_line_magic("reset", "-f")
import matplotlib as _matplotlib
import matplotlib.pyplot as _plt
_plt.close("all")
_matplotlib.rcdefaults()
del _matplotlib, _plt
"""


@pytest.fixture(scope="module")
def kernel():
    """One small-mode kernel (``WING_FULL_STUDY=0``, started in notebooks/) for the module's notebooks, with
    the repository first on its path: the notebooks import the code under test, however the package is
    installed (`support.command.environment`, as the README's blocks do)."""
    from jupyter_client.manager import KernelManager

    manager = KernelManager(kernel_name="python3")
    manager.start_kernel(cwd=str(NOTEBOOKS), env=environment(WING_FULL_STUDY="0"))
    try:
        yield manager
    finally:
        manager.shutdown_kernel(now=True)


def run_small(name: str, kernel) -> dict:
    """Execute ``notebooks/<name>`` in small mode in the module's kernel (emptied first); return its
    ``summary`` dict."""
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    nb.cells.insert(0, nbformat.v4.new_code_cell(FRESH))
    nb.cells.append(nbformat.v4.new_code_cell(REPORT))
    client = nbclient.NotebookClient(nb, km=kernel, timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(NOTEBOOKS)}})
    try:
        client.execute()  # raises CellExecutionError if any cell fails
    finally:
        if client.kc is not None:
            client.kc.stop_channels()
    text = "".join(out.get("text", "") for out in nb.cells[-1].outputs if out.output_type == "stream")
    line = next(line for line in text.splitlines() if line.startswith(MARK))
    summary = json.loads(line[len(MARK):])
    package = next(line for line in text.splitlines() if line.startswith(PACKAGE))[len(PACKAGE):]
    assert Path(package).resolve().is_relative_to(ROOT), f"the notebook imported {package}, not the code under test"
    assert summary["full_study"] is False, "the test must run the small mode"
    return summary


def test_pressurisation_dynamics(kernel):
    s = run_small("01_pressurisation_dynamics.ipynb", kernel)
    energy = s["kinetic_energy_at_0.1s"]
    # Viscosity (eq. 10) and aerodynamic damping (eq. 11) each take energy out of the oscillation.
    assert energy["eta = 5 N s/m"] < 0.1 * energy["no damping"]
    assert energy["nu_n = 0.05 s/m"] < 0.1 * energy["no damping"]
    # The curved, inflated skin rings above the flat-membrane estimate, and a sudden load
    # overshoots towards twice the static bulge.
    assert s["membrane_estimate_hz"] < s["dominant_frequency_hz"] < 2 * s["membrane_estimate_hz"]
    assert 1.5 < s["sudden_overshoot"] < 2.5
    overshoot = {float(k): v for k, v in s["overshoot_by_ramp_periods"].items()}
    assert overshoot[max(overshoot)] < overshoot[0.0]
    # The damped run comes to rest at the equilibrium solver's shape (rest test rtol 1e-6).
    assert s["rest_shape_error_m"] < 1e-6
    bulges = [s["max_bulge_mm_by_kpa"][k] for k in sorted(s["max_bulge_mm_by_kpa"], key=float)]
    assert all(b2 > b1 > 0 for b1, b2 in zip(bulges, bulges[1:]))


def test_runtime_vs_error(kernel):
    s = run_small("02_runtime_vs_error.ipynb", kernel)
    assert s["all_finite"] and s["runs"] >= 5
    # Nested grids converge at second order in the grid spacing.
    assert 1.5 < s["observed_order"] < 2.5
    errors = s["errors"]
    assert errors["relax 9x64 1e-08"] < 0.5 * errors["relax 5x32 1e-08"]
    # Newton and relaxation reach the same shape at the same tolerance.
    assert math.isclose(errors["relax+newton 9x64 1e-08"], errors["relax 9x64 1e-08"], rel_tol=1e-2)
    # The paper's physical-mass scheme is slower than relaxation on the same grid.
    assert all(ratio > 1 for _, _, ratio, _ in s["paper_over_relax"])


def test_stability_map(kernel):
    s = run_small("03_stability_map.ipynb", kernel)
    counts = s["map_counts"]
    assert counts["converged"] >= 1
    assert counts["diverged"] + counts["nonfinite"] >= 1
    # The measured Courant limit matches the analysis of eq. (14) to the trial spacing.
    for predicted, stable, unstable in s["limits"].values():
        assert stable is not None and unstable is not None
        assert stable < predicted + 0.01 and unstable > predicted - 0.05
    # Without damping the tension-only fabric blows up at alpha_k = 0.9; with compression allowed
    # it stays bounded.
    assert s["undamped"]["tension_only 0.9"][0] in ("diverged", "nonfinite")
    assert s["undamped"]["compression 0.9"][0] == "max_steps_reached"


def test_inverse_design_study(kernel):
    s = run_small("04_inverse_design_study.ipynb", kernel)
    ref, bounds = s["reference"], s["bounds"]
    assert ref["success"]
    assert bounds["pressure"][0] <= ref["pressure"] <= bounds["pressure"][1]
    for k, name in enumerate(("prestrain_span", "prestrain_chord")):
        assert bounds[name][0] <= ref["prestrain"][k] <= bounds[name][1]
    assert ref["rms_error"] < 0.5 * ref["initial_rms_error"]
    # SLSQP with adjoint gradients converges in 6 to 13 forward solves on these bays (full study
    # too); the penalty method it replaced crept along the constraint up to its 50-iteration cap.
    assert ref["solves"] < 30
    sweeps = s["sweeps"]
    for key, sweep in sweeps.items():
        assert sweep["success"], key
        assert sweep["solves"] < 30, key
        # The optimum spanwise prestrain follows the membrane estimate (sag = rib gap): within 12 %
        # in small mode, within 8 % for bays up to 0.3 m in the full study, constrained runs
        # included; 20 % leaves room for the coarse grid without admitting a wrong power of b or E.
        assert math.isclose(sweep["prestrain"][0], sweep["rule_prestrain"], rel_tol=0.2), key
        if key.endswith("wrinkle-free"):
            # A real constraint: no fibre compression beyond the optimiser's feasibility tolerance
            # (VIOLATION_TOLERANCE, about 0.5 N/m at 1 kPa on the 1 m chord; twice that here).
            assert sweep["min_tension"] > -1e-3 * sweep["pressure"], key
            # The constraint can only cost accuracy (0.1 %: SLSQP's stopping tolerance).
            free = sweeps[key.replace("wrinkle-free", "shape only")]
            assert sweep["rms_error"] > free["rms_error"] * (1 - 1e-3), key
