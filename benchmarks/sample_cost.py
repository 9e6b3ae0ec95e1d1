"""Time of a Monte Carlo sample against the grid: the fit behind the command's samples guard.

A Monte Carlo sample (`inverse_design.tolerance.monte_carlo`) solves every bay of a drawn wing warm from
the nominal equilibrium (chord Newton with its kept factor) and measures it. This times the samples of
`tolerance_analysis` (its ``timings["samples"]``: draws, solves, measures, rows) on one bay of NACA 2412,
chord 1 m, ribs 0.25 m apart, at one equilibrium (`evaluate_design`, 10 kPa, prestrains 2%), for the
default tolerances and for ``pressure=2%`` alone, on grids from 5x32 to 65x256, after a first run of 2
samples that compiles; then a 3-bay wing at 17x64 (the cost per bay should not change with the bays).
The seconds per sample and bay are fitted as ``b * nodes**p`` (least squares in the logs), which
`inverse_design.app.resources.SAMPLE_TIME_FIT` holds. BLAS on one thread, as in the command.

Writes ``benchmarks/results/sample_cost.json``.

Run:  PYTHONPATH=. python benchmarks/sample_cost.py [--seconds 12]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.results import blas_as_in_the_command, print_result, save_result  # noqa: E402

GRIDS = ((5, 32), (9, 64), (17, 64), (17, 128), (33, 128), (33, 256), (65, 256))


def equilibrium(n_span: int, n_contour: int, n_bays: int = 1):
    from forward_solver import Fabric, Wing
    from inverse_design import SolverSettings, evaluate_design
    from targets import naca

    af = naca("2412")
    wing = Wing(airfoils=(af,) * (n_bays + 1), chords=tuple(np.linspace(1.0, 0.8, n_bays + 1)),
                stations=tuple(0.25 * k for k in range(n_bays + 1)))
    return evaluate_design(wing.scenes(Fabric(), n_span, n_contour), [af] * (n_bays + 1),
                           {"pressure": 1e4, "prestrain_span": 0.02, "prestrain_chord": 0.02}, objective="average",
                           wing=wing, solver=SolverSettings(rtol=1e-11))


def per_sample(result, tolerances, seconds: float) -> tuple[float, int, int]:
    """``(seconds per sample, samples timed, failed)``: 2 samples first (compiling), 4 to time one, then
    enough for about ``seconds``."""
    from inverse_design.tolerance import Sampling, tolerance_analysis

    tolerance_analysis(result, tolerances, sampling=Sampling(samples=2, seed=1))  # (compiles)
    guess = tolerance_analysis(result, tolerances, sampling=Sampling(samples=4, seed=2)).timings["samples"] / 4
    count = int(min(max(seconds / max(guess, 1e-3), 8), 400))
    analysis = tolerance_analysis(result, tolerances, sampling=Sampling(samples=count, seed=0))
    return analysis.timings["samples"] / count, count, analysis.sampled["failed"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=12.0, help="about how long each row samples")
    options = parser.parse_args()
    rows, fit = [], []
    with blas_as_in_the_command():
        cases = [(g, 1, name, tol) for g in GRIDS for name, tol in (("defaults", ["defaults"]),
                                                                    ("pressure=2%", {"pressure": "2%"}))]
        cases.append(((17, 64), 3, "defaults", ["defaults"]))
        results = {}
        for (n_span, n_contour), bays, name, tolerances in cases:
            key = (n_span, n_contour, bays)
            if key not in results:
                results = {key: equilibrium(n_span, n_contour, bays)}
            seconds, count, failed = per_sample(results[key], tolerances, options.seconds)
            nodes = n_span * n_contour
            if bays == 1 and name == "defaults":
                fit.append((nodes, seconds))
            rows.append([f"{n_span} x {n_contour}", nodes, bays, name, count, failed, round(seconds, 4),
                         round(seconds / bays, 4)])
            print(rows[-1], flush=True)
    nodes, seconds = np.array(fit).T
    p, log_b = np.polyfit(np.log(nodes), np.log(seconds), 1)
    b = float(np.exp(log_b))
    worst = float(np.max(np.abs(b * nodes**p / seconds - 1)))
    notes = [f"fit of the defaults' seconds per sample and bay: {b:.3g} s * nodes**{p:.3f}, within {100 * worst:.0f}% "
             "of every one-bay row (inverse_design/app/resources.py SAMPLE_TIME_FIT)",
             "one bay of NACA 2412, chord 1 m (the wing: chords 1 to 0.8 m), ribs 0.25 m apart, at 10 kPa and 2% "
             "prestrains (evaluate_design, rtol 1e-11); samples solved to rtol 1e-8 warm from the nominal; the "
             "first 2 samples (compiling) not counted",
             "2-core machine shared with other work: the load is in the machine's description"]
    path = save_result("sample_cost", title="Seconds per Monte Carlo sample against the grid",
                       command="PYTHONPATH=. python benchmarks/sample_cost.py",
                       columns=["grid", "nodes", "bays", "tolerances", "samples", "failed", "s per sample",
                                "s per sample and bay"], rows=rows, notes=notes)
    print_result(path, [], notes)


if __name__ == "__main__":
    main()
