"""Time of the tolerance analysis (docs/tolerances.md) on the default case, against the design's.

The default case (what ``optimise-pressure`` designs: NACA 2412 bay, chord 1 m,
ribs 0.25 m apart, 17x64, pressure and rib thickness scale, bay-average
objective) is designed once and its first-order tolerance analysis with every
source at its default run once (both compiling: the first runs), then both
again ``--repeats`` times, alternating, on compiled functions; the ratio is of
the medians of those runs (a compiled design takes a few tenths of a second,
so one run is at the mercy of the machine's other work). BLAS runs on one
thread, as in the command (`inverse_design.app.cli`). Then ``--samples`` wings of the default bay are solved warm from the
nominal equilibrium (the Monte Carlo check), timed apart. Quote the machine
and its load with the numbers.

Writes ``benchmarks/results/tolerance.json`` (``benchmarks/performance_doc.py`` puts it in
``docs/performance.md``).

Run:  PYTHONPATH=. python benchmarks/tolerance.py [--samples 256]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.results import blas_as_in_the_command, print_result, save_result  # noqa: E402


LOAD_NOTE = ("the machine's load average is in its description: on a shared machine the wall times stretch "
             "with the other jobs (several times a quiet machine's at load 15 on 2 cores); compare the ratio, "
             "which is of one run, and re-measure the sample time on a quiet machine against its 30 s goal")


def design():
    from forward_solver import Bay, Fabric, Parameters, Scene
    from inverse_design import optimise_pressure
    from targets import naca

    target = naca("2412")
    scene = Scene(Bay.from_airfoil(target, chord=1.0, rib_spacing=0.25, n_span=17, n_contour=64), Fabric())
    return optimise_pressure(scene, target, ("pressure", "rib_thickness_scale"),
                             initial=Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.02),
                             bounds={"pressure": (1e3, 1e5), "rib_thickness_scale": (0.7, 1.0)},
                             objective="average")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=7)
    options = parser.parse_args()
    with blas_as_in_the_command():
        measure(options)


def measure(options) -> None:
    from inverse_design.tolerance import Sampling, tolerance_analysis

    times = {}
    start = time.perf_counter()
    result = design()
    times["design first"] = time.perf_counter() - start
    times["tolerance first"] = tolerance_analysis(result, ["defaults"], spec=3.0).timings["tolerance"]
    designs, analyses = [], []
    for _ in range(options.repeats):
        start = time.perf_counter()
        result = design()
        designs.append(time.perf_counter() - start)
        analyses.append(tolerance_analysis(result, ["defaults"], spec=3.0).timings["tolerance"])
    times["design second"], times["tolerance second"] = statistics.median(designs), statistics.median(analyses)
    analysis = tolerance_analysis(result, ["defaults"], spec=3.0, sampling=Sampling(samples=options.samples, seed=0))
    samples = analysis.timings["samples"]
    ratio = times["tolerance second"] / times["design second"]
    rows = [
        [f"the design (default case, compiled; median of {options.repeats})", round(times["design second"], 3), "", ""],
        ["the design (first run, compiling)", round(times["design first"], 3), "", ""],
        [f"first-order analysis, 9 parameters (compiled; median of {options.repeats})", round(times["tolerance second"], 3),
         round(ratio, 3),
         "<= 0.25 of the design"],
        ["first-order analysis (first run, compiling)", round(times["tolerance first"], 3),
         round(times["tolerance first"] / times["design first"], 3), ""],
        [f"{options.samples} Monte Carlo samples, warm", round(samples, 3), round(samples / options.samples, 4),
         "<= 30 s (2 cores)"],
    ]
    notes = [f"design: {result.solves} forward solves, rms {result.rms_error:.4g} chord; the analysis: "
             f"linear rms p95 {analysis.linear['rms']['p95']:.4g} mm, sampled {analysis.sampled['rms']['p95']:.4g} mm; "
             f"{analysis.sampled['failed']} of {options.samples} samples failed",
             "the ratio column: the analysis over the design (same run); for the samples, seconds per sample",
             LOAD_NOTE]
    path = save_result("tolerance", title="Tolerance analysis against the design, default case (17x64)",
                       command=f"PYTHONPATH=. python benchmarks/tolerance.py --samples {options.samples}",
                       columns=["step", "wall time (s)", "ratio or s per sample", "goal"], rows=rows, notes=notes)
    print_result(path, rows)


if __name__ == "__main__":
    main()
