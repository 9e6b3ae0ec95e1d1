"""The tolerance analysis of the built-in 40-cell wing: its time against the design's, and the memory of
its Monte Carlo samples as they stream.

The wing of ``inverse_design/cases/wing_40_cells.toml`` (17x64 per bay) is designed as its case file
says (pressure and both uniform prestrains, Gauss-Newton) twice in one process (the second on compiled
functions), then its first-order analysis with every source at its default runs twice (the second on
compiled functions); the ratio is of the second runs. Then ``--samples`` wings are drawn and solved
warm from the nominal equilibrium, each row streamed to a CSV file as the command does, and the
process's resident memory (``/proc/self/statm``) is read after every tenth sample: a Monte Carlo
whose memory grows with N would show it there. BLAS runs on one thread, as in the command. Quote the
machine and its load with the numbers.

Writes ``benchmarks/results/tolerance_wing.json`` (``tolerance_wing_N.json`` for the first N bays,
``--cells N``; ``benchmarks/performance_doc.py`` puts it in ``docs/performance.md``).

Run:  PYTHONPATH=. python benchmarks/tolerance_wing.py [--samples 100] [--cells 40]
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.results import blas_as_in_the_command, print_result, save_result  # noqa: E402

CASE = ROOT / "inverse_design" / "cases" / "wing_40_cells.toml"


def resident_mb() -> float:
    """This process's resident memory now, MB (Linux)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def design(cells: int):
    """The command's design of the first ``cells`` bays of the 40-cell case (`inverse_design.app.design.optimise`)."""
    from inverse_design.app import design as command_design
    from inverse_design.app.case import Case

    case = Case.from_arguments(["--config", str(CASE)])
    return command_design.optimise(dataclasses.replace(case, ribs=case.ribs[:cells + 1]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=100)
    parser.add_argument("--cells", type=int, default=40)
    options = parser.parse_args()
    with blas_as_in_the_command():
        measure(options)


def measure(options) -> None:
    from inverse_design.tolerance import Sampling, tolerance_analysis

    load_start = os.getloadavg()[0]
    times = {}
    for run in ("first", "second"):
        start = time.perf_counter()
        result = design(options.cells)
        times[f"design {run}"] = time.perf_counter() - start
    for run in ("first", "second"):
        times[f"tolerance {run}"] = tolerance_analysis(result, ["defaults"], spec=3.0).timings["tolerance"]
    memory = []
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "tolerance_samples.csv"
        with open(path, "w", newline="") as handle:
            writer = None

            def on_sample(row: dict) -> None:
                nonlocal writer
                if writer is None:
                    writer = csv.DictWriter(handle, fieldnames=list(row))
                    writer.writeheader()
                writer.writerow(row)
                handle.flush()
                if (row["sample"] + 1) % 10 == 0:
                    memory.append((row["sample"] + 1, round(resident_mb())))

            before = resident_mb()
            analysis = tolerance_analysis(result, ["defaults"], spec=3.0,
                                          sampling=Sampling(samples=options.samples, seed=0, on_sample=on_sample))
        csv_kb = path.stat().st_size / 1024
    samples = analysis.timings["samples"]
    ratio = times["tolerance second"] / times["design second"]
    columns = len(analysis.columns)
    rows = [
        [f"the design, {options.cells} bays (compiled)", round(times["design second"], 2), "", ""],
        [f"the design, {options.cells} bays (first run, compiling)", round(times["design first"], 2), "", ""],
        [f"first-order analysis, {columns} parameters (compiled)", round(times["tolerance second"], 2), round(ratio, 3),
         "<= 0.25 of the design"],
        ["first-order analysis (first run, compiling)", round(times["tolerance first"], 2),
         round(times["tolerance first"] / times["design first"], 3), ""],
        [f"{options.samples} Monte Carlo samples, warm", round(samples, 1), round(samples / options.samples, 3), ""],
    ]
    growth = memory[-1][1] - memory[0][1] if len(memory) > 1 else None
    notes = [f"design: {result.solves} wing solves, rms {result.rms_error:.4g} chord, success {result.success}; "
             f"the analysis: linear rms p95 {analysis.linear['rms']['p95']:.4g} mm, sampled "
             f"{analysis.sampled['rms']['p95']:.4g} mm; {analysis.sampled['failed']} of {options.samples} samples failed",
             f"resident memory (MB) after every tenth sample, streamed to a {csv_kb:.0f} kB CSV: "
             + ", ".join(f"{n}: {mb}" for n, mb in memory)
             + f" (before the analysis {before:.0f} MB; growth from the 10th to the last sample "
             f"{growth} MB)",
             "the ratio column: the analysis over the design (same run); for the samples, seconds per sample",
             f"load average {load_start:.1f} at the start, {os.getloadavg()[0]:.1f} at the end (2-core machine shared "
             "with other work: compare the ratio, which is of one run)"]
    name = "tolerance_wing" if options.cells == 40 else f"tolerance_wing_{options.cells}"
    path = save_result(name, title=f"Tolerance analysis of the {options.cells}-cell wing (17x64 per bay)",
                       command=f"PYTHONPATH=. python benchmarks/tolerance_wing.py --samples {options.samples} "
                               f"--cells {options.cells}",
                       columns=["step", "wall time (s)", "ratio or s per sample", "goal"], rows=rows, notes=notes)
    print_result(path, rows, notes)


if __name__ == "__main__":
    main()
