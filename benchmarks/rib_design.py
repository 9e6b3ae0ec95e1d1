"""Rib shape against pressure and thickness scale: how far the errors fall.

The default case (NACA 2412 ribs and target, chord 1 m, ribs 0.25 m apart,
fabric 2e5 N/m, 2% prestrain, wrinkle-free skin, bay-average objective,
SLSQP) designed four ways on one grid:

1. pressure and rib thickness scale (the ``optimise-pressure`` default);
2. pressure and rib shape (K = 4 Bernstein terms per surface, 8 coefficients);
3. pressure and rib shape with K = 8 (16 coefficients);
4. pressure, both prestrains and rib shape (K = 4);
5. pressure, both prestrains and rib thickness scale (4's reference: what
   the rib shape adds once the cut is free too).

Rib shapes keep the default manufacturability limits (`RibLimits`: local
thickness >= 0.8 of the starting rib's, radius of curvature >= half the
starting nose radius). Each design is then re-solved on finer grids
(2 n_span - 1 span nodes, 2 n_contour contour nodes) at the same
parameters, so the table says whether the gain survives refinement.

Run:  PYTHONPATH=. python benchmarks/rib_design.py [--n-span 17 --n-contour 64]

Writes benchmarks/results/rib_design.json (``rib_design_<cases>.json`` for a subset of the cases;
``benchmarks/performance_doc.py`` puts it in docs/performance.md) and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.results import save_result  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-span", type=int, default=17)
    parser.add_argument("--n-contour", type=int, default=64)
    parser.add_argument("--max-iterations", type=int, default=60)
    parser.add_argument("--cases", default="1,2,3,4,5")
    args = parser.parse_args()

    from forward_solver import Bay, Fabric, Parameters, Scene, solve_equilibrium
    from inverse_design import SolverSettings, optimise_pressure
    from inverse_design.objectives import design_errors, section_errors
    from targets import naca

    target = naca("2412")
    fabric = Fabric()

    def scene(n_span, n_contour):
        return Scene(Bay.from_airfoil(target, chord=1.0, rib_spacing=0.25, n_span=n_span,
                                      n_contour=n_contour), fabric)

    start = Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.02)
    cases = {
        "1": ("pressure + thickness scale", ("pressure", "rib_thickness_scale"),
              {"rib_thickness_scale": (0.7, 1.0)}, start),
        "2": ("pressure + rib shape, K = 4", ("pressure", "rib_shape"), {}, start),
        "3": ("pressure + rib shape, K = 8", ("pressure", "rib_shape"), {},
              start.replace(rib_shape=np.zeros(16))),
        "4": ("pressure + prestrains + rib shape, K = 4",
              ("pressure", "prestrain_span", "prestrain_chord", "rib_shape"), {}, start),
        "5": ("pressure + prestrains + thickness scale",
              ("pressure", "prestrain_span", "prestrain_chord", "rib_thickness_scale"),
              {"rib_thickness_scale": (0.7, 1.0)}, start),
    }
    base = scene(args.n_span, args.n_contour)
    finer = [(2 * args.n_span - 1, args.n_contour), (args.n_span, 2 * args.n_contour)]
    rows = []
    for key in args.cases.split(","):
        label, variables, bounds, initial = cases[key]
        bounds = {"pressure": (1e3, 1e5), **bounds}
        t = time.perf_counter()
        result = optimise_pressure(base, target, variables=variables, initial=initial, bounds=bounds,
                                   objective="average", solver=SolverSettings(max_iterations=args.max_iterations))
        wall = time.perf_counter() - t
        mid = section_errors(result.solution, target, 1.0)
        row = {"case": label, "variables": list(variables), "success": result.success,
               "message": result.message, "pressure_pa": float(result.parameters.pressure),
               "prestrain": [float(v) for v in result.parameters.prestrain],
               "rib_thickness_scale": float(result.parameters.rib_thickness_scale),
               "rib_shape": (None if result.parameters.rib_shape is None
                             else np.asarray(result.parameters.rib_shape).tolist()),
               "grid": [args.n_span, args.n_contour],
               "start_average_rms": result.initial_rms_error,
               "average_rms": result.rms_error, "average_max": result.max_error,
               "mid_bay_rms": mid.rms, "mid_bay_max": mid.max,
               "active": result.limits.active, "constraint_values": result.limits.values,
               "solves": result.solves, "wall_s": wall, "finer": []}
        for n_span, n_contour in finer:
            fine = scene(n_span, n_contour)
            sol = solve_equilibrium(fine, result.parameters.replace(stiffness_span=None, stiffness_chord=None),
                                    rtol=1e-10, method="relax+newton")
            rms, largest = design_errors(sol.nodes, target, 1.0, "average")
            fine_mid = section_errors(sol, target, 1.0)
            row["finer"].append({"grid": [n_span, n_contour], "average_rms": rms, "average_max": largest,
                                 "mid_bay_rms": fine_mid.rms, "mid_bay_max": fine_mid.max,
                                 "min_tension": float(min(np.min(sol.tension_span), np.min(sol.tension_chord))),
                                 "wrinkled_fraction": sol.wrinkled_fraction})
        rows.append(row)
        print(json.dumps(row, default=float), flush=True)

    full = args.cases == "1,2,3,4,5" and (args.n_span, args.n_contour) == (17, 64)
    command = "python benchmarks/rib_design.py" + ("" if full else f" --cases {args.cases} --n-span {args.n_span} "
                                                   f"--n-contour {args.n_contour}")
    command += "" if args.max_iterations == 60 else f" --max-iterations {args.max_iterations}"
    finer_names = [f"{a}x{b}" for a, b in finer]
    save_result("rib_design" if full else f"rib_design_{args.cases.replace(',', '')}_{args.n_span}x{args.n_contour}",
                title="Rib-shape designs of the default bay", command=command,
                columns=["design", "success", "pressure, kPa", "bay-average rms, chord", "bay-average max, chord",
                         "mid-bay rms, chord", "mid-bay max, chord",
                         f"bay-average rms on {' / '.join(finer_names)}", "forward solves", "wall time, s"],
                rows=[[r["case"], "yes" if r["success"] else "no", round(r["pressure_pa"] / 1e3, 3),
                       f"{r['average_rms']:.3e}", f"{r['average_max']:.3e}", f"{r['mid_bay_rms']:.3e}",
                       f"{r['mid_bay_max']:.3e}", " / ".join(f"{f['average_rms']:.3e}" for f in r["finer"]),
                       r["solves"], round(r["wall_s"], 1)] for r in rows],
                notes=[f"The default case (NACA 2412 ribs and target, chord 1 m, ribs 0.25 m apart, prestrain "
                       f"start 2%, pressure 1-100 kPa, wrinkle-free, bay-average objective) on "
                       f"{args.n_span}x{args.n_contour}, each design re-solved at its parameters on the finer "
                       "grids; wall time includes compilation.",
                       "Rib shape: K Bernstein terms per surface of the rib's outward offset "
                       "(docs/design_problem.md)."])
    print("\n| design | pressure | bay-average rms | bay-average max | mid-bay rms | mid-bay max | "
          "rms on finer grids | solves | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        fine = ", ".join(f"{f['average_rms']:.2e} ({f['grid'][0]}x{f['grid'][1]})" for f in r["finer"])
        print(f"| {r['case']} | {r['pressure_pa'] / 1e3:.2f} kPa | {r['average_rms']:.2e} | {r['average_max']:.2e} | "
              f"{r['mid_bay_rms']:.2e} | {r['mid_bay_max']:.2e} | {fine} | {r['solves']} | {r['wall_s']:.0f} |")


if __name__ == "__main__":
    main()
