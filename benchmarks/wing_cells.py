"""Designs of a 40-cell wing cut cell by cell: time, wing solves, errors and peak memory.

Three 40-cell cases (``inverse_design/cases/``): the built-in elliptic wing
(``wing_40_cells.toml``, NACA 4415), a rectangular one of one section
(``wing_40_cells_constant.toml``) and one blended from NACA 4418 at the root
to NACA 2412 at the tip with a linear taper (``wing_40_cells_blended.toml``).
Four designs each (`DESIGNS`), the command's own designs of the cases
(`inverse_design.app.case.Case`, `inverse_design.app.design.optimise`): the
pressure and the uniform prestrains; the pressure and one shared cut field;
the pressure and a cut field per bay; the pressure, a cut field per bay and a
shape per rib (about 800 variables on 40 cells). Gauss-Newton with the block
Jacobian (`inverse_design.methods.blocks`) and the sparse step QP
(`inverse_design.methods.step_qp`).

Each design runs in a subprocess of its own, which reports its peak resident
memory (``resource.getrusage(RUSAGE_SELF).ru_maxrss``: JAX's buffers are not
Python objects, so tracemalloc misses them) and its wall time with the load
average at its start and end (the machine is shared). ``--refine`` re-solves
each design on 33x64 (`optimise.refine_design`) and records how far it
moves. ``--cells 10,20,40`` runs the first 10, 20 and 40 bays of a case (the
peak memory's growth; `inverse_design.memory` is calibrated on it).

Run:
    PYTHONPATH=. python benchmarks/wing_cells.py                       # every case and design, 17x64
    PYTHONPATH=. python benchmarks/wing_cells.py --cases elliptic --designs per_bay_ribs --refine
    PYTHONPATH=. python benchmarks/wing_cells.py --cases elliptic --designs per_bay_ribs --cells 10,20,40 --out F
    PYTHONPATH=. python benchmarks/wing_cells.py --designs per_bay_ribs --base /tmp/base --base-label cf33329

``--base DIR`` runs each design from that checkout too (an earlier commit: ``git worktree add /tmp/base
cf33329``), in turns with this tree's, and writes ``wing_cells_<label>.json``: a row per run, the ratio of
the two times per design in its notes.

The LE recession (the mid-bay nose behind its target's, `app.measures.le_recessions`) is the largest over the
bays.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.results import RESULTS, machine_description, save_result  # noqa: E402

CASES = {"elliptic": "wing_40_cells.toml", "constant": "wing_40_cells_constant.toml",
         "blended": "wing_40_cells_blended.toml"}
#: Design name -> (``--variables``, further arguments).
DESIGNS = {
    "prestrains": ("pressure,prestrain_span,prestrain_chord", []),
    "shared_field": ("pressure,cut_pattern", []),
    "per_bay": ("pressure,cut_pattern", ["--cut-pattern-layout", "per_bay"]),
    "per_bay_ribs": ("pressure,cut_pattern,rib_shape", ["--cut-pattern-layout", "per_bay"]),
}
COLUMNS = ["case", "bays", "design", "variables", "success", "wing solves", "rms", "max", "worst bay",
           "worst bay rms", "LE recession, largest (mm)", "QP rows kept (max)", "seconds", "peak MB", "load start/end",
           "33x64 rms", "33x64 move", "33x64 seconds", "peak MB with 33x64"]
#: The notes of every results file of this benchmark.
NOTES = ["grid 17x64 per bay unless the row says otherwise; the command's defaults (objective "
         "average, min_tension 0, max_iterations 50, start 1e4 Pa and 2% prestrain)",
         "designs: prestrains = pressure + uniform prestrains; shared_field = pressure + one "
         "cut field (12 coefficients); per_bay = pressure + a cut field per bay; per_bay_ribs = "
         "that + a shape per rib (8 coefficients each)",
         "rms, max: normal distance from the target, fractions of the local chord; worst bay: "
         "the bay of the largest rms; QP rows kept: the most tension and rib rows any step QP's "
         "working set held (step_qp.solve_working_set), of 2,048 tension rows per bay at 17x64 (the "
         "span and chord tensions of 1,024 cells against the floor) and about 500 rows per rib",
         "seconds: wall time of the design in its own process, compilation included; peak MB: "
         "ru_maxrss of that process; load: the 1-minute load average at its start and end "
         "(2-core machine shared with other work)",
         "33x64: the design re-solved on 33x64 (refine_design): its rms and how far the "
         "variables moved (pressure relative, others absolute, largest component)",
         "LE recession, largest: the largest over the bays of how far the mid-bay section's nose "
         "lies behind its target's (summary.json bays[K].le_recession), mm; rows without it were "
         "measured before it was recorded"]


def _load() -> float:
    return round(os.getloadavg()[0], 1) if hasattr(os, "getloadavg") else float("nan")


def run_design(case: str, design: str, cells: int | None, refine: bool, grid, max_iterations=None) -> dict:
    """One design in this process (the subprocess's work): its record."""
    import resource

    import numpy as np

    from inverse_design.app import design as command_design
    from inverse_design.app.case import Case
    from inverse_design.app.measures import le_recessions
    from inverse_design.optimise import refine_design
    from inverse_design.settings import Layout

    load_start = _load()
    variables, extra = DESIGNS[design]
    argv = ["--config", str(ROOT / "inverse_design" / "cases" / CASES[case]), "--variables", variables,
            "--method", "gauss_newton", *extra]
    if grid is not None:
        argv += ["--n-span", str(grid[0]), "--n-contour", str(grid[1])]
    if max_iterations is not None:
        argv += ["--max-iterations", str(max_iterations)]
    wing_case = Case.from_arguments(argv)
    if cells is not None:
        wing_case = dataclasses.replace(wing_case, ribs=wing_case.ribs[:cells + 1])
    start = time.perf_counter()
    result = command_design.optimise(wing_case)
    seconds = time.perf_counter() - start
    worst = int(np.argmax(result.per_bay.rms_error))
    size = sum(np.size(v) for v in result.history[-1]["values"].values()) if result.history else None
    record = {"case": case, "bays": wing_case.n_bays, "design": design, "variables": size,
              "success": bool(result.success), "message": result.message, "wing solves": int(result.solves),
              "rms": float(f"{result.rms_error:.4g}"), "max": float(f"{result.max_error:.4g}"),
              "worst bay": worst, "worst bay rms": float(f"{result.per_bay.rms_error[worst]:.4g}"),
              "QP rows kept (max)": max([h.get("qp_rows", 0) for h in result.history], default=0),
              "seconds": round(seconds, 1),
              "load start/end": f"{load_start}/{_load()}"}
    record["peak MB"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
    mid_chords = [0.5 * (b.chord_root + b.chord_tip) for b in result.wing_solution.bays]
    record["LE recession, largest (mm)"] = round(float(np.max(1e3 * le_recessions(result) * mid_chords)), 2)
    if refine:
        fine = refine_design(result, Layout(n_span=33, n_contour=64))
        change = fine.grid_change["change"]
        record["33x64 rms"] = float(f"{fine.rms_error:.4g}")
        record["33x64 move"] = "; ".join(f"{k} {v:.3g}" for k, v in change.items())
        record["33x64 seconds"] = round(time.perf_counter() - start - seconds, 1)
        record["peak MB with 33x64"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
    return record


def run_subprocess(case: str, design: str, cells, refine: bool, grid, max_iterations=None, root: Path = ROOT) -> dict:
    """`run_design` in a fresh Python (its own peak memory), from the checkout ``root`` (its own copy of
    this script and its package), or the failure as a record."""
    spec = json.dumps({"case": case, "design": design, "cells": cells, "refine": refine, "grid": grid,
                       "max_iterations": max_iterations})
    env = {**os.environ, "PYTHONPATH": str(root)}
    proc = subprocess.run([sys.executable, str(root / "benchmarks" / "wing_cells.py"), "--one", spec],
                          capture_output=True, text=True, env=env)
    for line in reversed(proc.stdout.splitlines()):
        if line.startswith("{"):
            return json.loads(line)
    tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
    return {"case": case, "bays": cells, "design": design, "success": False, "message": tail[0]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", default=",".join(CASES), help=f"comma-separated among {','.join(CASES)}")
    parser.add_argument("--designs", default=",".join(DESIGNS), help=f"comma-separated among {','.join(DESIGNS)}")
    parser.add_argument("--cells", default=None, help="comma-separated bay counts (the first N bays of each case)")
    parser.add_argument("--grid", type=int, nargs=2, default=None, metavar=("N_SPAN", "N_CONTOUR"))
    parser.add_argument("--refine", action="store_true", help="re-solve each design on 33x64")
    parser.add_argument("--max-iterations", type=int, default=None,
                        help="cap on wing solves (peak-memory runs: the peak comes with the first Jacobians)")
    parser.add_argument("--base", type=Path, default=None,
                        help="a checkout of an earlier commit: each design runs from it too, alternating")
    parser.add_argument("--base-label", default="base", help="its name in the results (e.g. a commit)")
    parser.add_argument("--out", type=Path, default=None,
                        help="results JSON (default: benchmarks/results/wing_cells.json, with --base "
                             "wing_cells_<label>.json)")
    parser.add_argument("--one", default=None, help=argparse.SUPPRESS)
    options = parser.parse_args(argv)
    if options.one is not None:
        spec = json.loads(options.one)
        print(json.dumps(run_design(spec["case"], spec["design"], spec["cells"], spec["refine"], spec["grid"],
                                    spec.get("max_iterations"))))
        return 0
    cells = [None] if options.cells is None else [int(c) for c in options.cells.split(",")]
    if options.base is not None:
        return compare(options, cells, argv)
    options.out = options.out or RESULTS / "wing_cells.json"
    records = []
    if options.out.exists():  # runs of other cases and designs are kept, the same ones replaced
        old = json.loads(options.out.read_text())
        records = [dict(zip(old["columns"], row)) for row in old["rows"]]
        records = [{**r, "message": ""} for r in records]
    for case in options.cases.split(","):
        for design in options.designs.split(","):
            for n in cells:
                record = run_subprocess(case, design, n, options.refine, options.grid, options.max_iterations)
                if options.max_iterations is not None:
                    record["design"] += f" (cap {options.max_iterations} solves)"
                print(json.dumps(record), flush=True)
                records = [r for r in records if (r.get("case"), r.get("design"), r.get("bays")) !=
                           (record["case"], record["design"], record.get("bays"))] + [record]
                rows = [[r.get(c) for c in COLUMNS] for r in records]
                failed = [f"{r['case']} {r['design']} ({r.get('bays')} bays): {r['message']}" for r in records
                          if r.get("message") and not r.get("success")]
                save_result(
                    options.out.stem, title="Designs of 40-cell wings cut cell by cell (Gauss-Newton, block "
                                            "Jacobian, sparse QP)" + (", re-solved on 33x64" if options.refine else ""),
                    command="PYTHONPATH=. python benchmarks/wing_cells.py " + " ".join(argv if argv is not None
                                                                                      else sys.argv[1:]),
                    columns=COLUMNS, rows=rows, notes=[*NOTES, *[f"failed: {line}" for line in failed]],
                    machine=machine_description(), folder=options.out.parent)
    return 0


def compare(options, cells, argv) -> int:
    """Each design from this checkout and from ``--base``, alternating, in fresh processes: one row per
    run, the ratio of their times in the notes."""
    trees = [("this tree", ROOT), (options.base_label, options.base.resolve())]
    out = options.out or RESULTS / f"wing_cells_{options.base_label}.json"
    records, ratios = [], []
    for case in options.cases.split(","):
        for design in options.designs.split(","):
            for n in cells:
                pair = {}
                for label, root in trees:
                    record = {"tree": label, **run_subprocess(case, design, n, options.refine, options.grid,
                                                              options.max_iterations, root)}
                    print(json.dumps(record), flush=True)
                    records.append(record)
                    pair[label] = record
                new, old = (pair[label].get("seconds") for label, _ in trees)
                if new and old:
                    ratios.append(f"{case} {design} ({pair['this tree'].get('bays')} bays): this tree "
                                  f"{new} s in {pair['this tree'].get('wing solves')} wing solves, "
                                  f"{options.base_label} {old} s in {pair[options.base_label].get('wing solves')}: "
                                  f"ratio {new / old:.2f}")
                save_result(
                    out.stem, title=f"Designs of 40-cell wings cut cell by cell, this tree against "
                                    f"{options.base_label}, alternating runs",
                    command="PYTHONPATH=. python benchmarks/wing_cells.py " + " ".join(
                        a for a in (argv if argv is not None else sys.argv[1:])),
                    columns=["tree", *COLUMNS], rows=[[r.get(c) for c in ["tree", *COLUMNS]] for r in records],
                    notes=[*ratios, *NOTES], machine=machine_description(), folder=out.parent)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
