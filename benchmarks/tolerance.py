"""Time of the tolerance analysis (docs/tolerances.md) on the default case, against the design's.

The default case (what ``optimise-pressure`` designs: NACA 2412 bay, chord 1 m,
ribs 0.25 m apart, 17x64, pressure and rib thickness scale, bay-average
objective) is designed twice in one process (the second on compiled
functions), then its first-order tolerance analysis with every source at its
default runs twice (the second on compiled functions: the first compiles the
rib-shape programs that the rib tolerances add); the ratio is of the second
runs. Then ``--samples`` wings of the default bay are solved warm from the
nominal equilibrium (the Monte Carlo check), timed apart. Quote the machine
and its load with the numbers.

Writes ``benchmarks/results/tolerance.json`` (``benchmarks/performance_doc.py`` puts it in
``docs/performance.md``).

Run:  PYTHONPATH=. python benchmarks/tolerance.py [--samples 256]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.results import save_result  # noqa: E402


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
    options = parser.parse_args()
    from inverse_design.tolerance import tolerance_analysis

    times = {}
    for run in ("first", "second"):
        start = time.perf_counter()
        result = design()
        times[f"design {run}"] = time.perf_counter() - start
    for run in ("first", "second"):
        analysis = tolerance_analysis(result, ["defaults"], spec=3.0)
        times[f"tolerance {run}"] = analysis.timings["tolerance"]
    analysis = tolerance_analysis(result, ["defaults"], spec=3.0, samples=options.samples, seed=0)
    samples = analysis.timings["samples"]
    ratio = times["tolerance second"] / times["design second"]
    rows = [
        ["the design (default case, compiled)", round(times["design second"], 3), "", ""],
        ["the design (first run, compiling)", round(times["design first"], 3), "", ""],
        ["first-order analysis, 9 parameters (compiled)", round(times["tolerance second"], 3), round(ratio, 3),
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
    for row in rows:
        print(row)
    print(path)


if __name__ == "__main__":
    main()
