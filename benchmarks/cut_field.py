"""The cut as a designed field against the uniform cut and the rib shape (issue 21, item 2).

The default case (NACA 2412 ribs and target, chord 1 m, ribs 0.25 m apart,
fabric 2e5 N/m, prestrain start 2% both ways, pressure 1-100 kPa,
wrinkle-free skin, bay-average objective, SLSQP) designed several ways on
one grid:

a. pressure, both uniform prestrains (0-5%) and rib thickness scale (0.7-1):
   the best uniform cut;
b. pressure and rib shape (K = 4 Bernstein terms per surface);
c. pressure, both prestrains and rib shape (K = 4);
d. pressure, rib thickness scale and the cut pattern (K = 6 B-splines per
   fibre direction, local prestrain within -2% .. 5%; the uniform
   prestrains stay at their 2% start, the field's constant part replaces
   them);
e. as d with K = 12;
f. as a with both uniform prestrains within d's local bounds (-2% .. 5%):
   what the wider bounds alone give, without a field;
g. as f with the prestrains up to 10%;
h. as d with the local prestrain up to 10%;
i. the cut pattern (K = 6, -2% .. 5%) started from f's design (its uniform
   prestrains, a zero field): what the field adds to the best uniform cut
   (needs f earlier in the same run).

Each design is re-solved on finer grids (2 n_span - 1 span nodes, and 2
n_contour contour nodes) at the same parameters. The leading-edge recession
is the chordwise shift of the mid-bay section's nose: the least x of the
mid-bay section minus the target's (0), mm, positive when the nose lies
behind the target's.

Run:  PYTHONPATH=. python benchmarks/cut_field.py [--n-span 17 --n-contour 64 --cases a,b,c,d,e]

Writes benchmarks/results/cut_field_<cases>.json and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-span", type=int, default=17)
    parser.add_argument("--n-contour", type=int, default=64)
    parser.add_argument("--max-iterations", type=int, default=60)
    parser.add_argument("--cases", default="a,b,c,d,e")
    parser.add_argument("--no-finer", action="store_true", help="skip the re-solves on finer grids")
    args = parser.parse_args()

    import jax

    from forward_solver import Bay, Fabric, Parameters, Scene, solve_equilibrium
    from forward_solver.cut_field import field_values
    from inverse_design import optimise_pressure
    from inverse_design.objectives import design_errors, section_errors
    from targets import naca

    target = naca("2412")
    fabric = Fabric()
    nose_target = float(np.min(np.asarray(target.x)))

    def scene(n_span, n_contour):
        return Scene(Bay.from_airfoil(target, chord=1.0, rib_spacing=0.25, n_span=n_span,
                                      n_contour=n_contour), fabric)

    def recession_mm(solution):
        return 1e3 * (float(np.min(solution.section(0.5)[:, 0])) - nose_target)

    start = Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.02)
    thickness = {"rib_thickness_scale": (0.7, 1.0)}
    cases = {
        "a": ("pressure + both prestrains + thickness scale (uniform cut)",
              ("pressure", "prestrain_span", "prestrain_chord", "rib_thickness_scale"), thickness, start),
        "b": ("pressure + rib shape, K = 4", ("pressure", "rib_shape"), {}, start),
        "c": ("pressure + both prestrains + rib shape, K = 4",
              ("pressure", "prestrain_span", "prestrain_chord", "rib_shape"), {}, start),
        "d": ("pressure + thickness scale + cut pattern, K = 6",
              ("pressure", "rib_thickness_scale", "cut_pattern"), thickness, start.replace(cut_pattern=np.zeros(12))),
        "e": ("pressure + thickness scale + cut pattern, K = 12",
              ("pressure", "rib_thickness_scale", "cut_pattern"), thickness, start.replace(cut_pattern=np.zeros(24))),
        "f": ("pressure + both prestrains (-2% .. 5%) + thickness scale (uniform cut)",
              ("pressure", "prestrain_span", "prestrain_chord", "rib_thickness_scale"),
              {**thickness, "prestrain_span": (-0.02, 0.05), "prestrain_chord": (-0.02, 0.05)}, start),
        "g": ("pressure + both prestrains (-2% .. 10%) + thickness scale (uniform cut)",
              ("pressure", "prestrain_span", "prestrain_chord", "rib_thickness_scale"),
              {**thickness, "prestrain_span": (-0.02, 0.10), "prestrain_chord": (-0.02, 0.10)}, start),
        "h": ("pressure + thickness scale + cut pattern, K = 6, local prestrain -2% .. 10%",
              ("pressure", "rib_thickness_scale", "cut_pattern"), {**thickness, "cut_pattern": (-0.02, 0.10)},
              start.replace(cut_pattern=np.zeros(12))),
        "i": ("pressure + thickness scale + cut pattern, K = 6, from f's design",
              ("pressure", "rib_thickness_scale", "cut_pattern"), {**thickness, "cut_pattern": (-0.02, 0.05)}, None),
    }
    base = scene(args.n_span, args.n_contour)
    finer = [] if args.no_finer else [(2 * args.n_span - 1, args.n_contour), (args.n_span, 2 * args.n_contour)]
    rows, designs = [], {}
    for key in args.cases.split(","):
        label, variables, bounds, initial = cases[key]
        if key == "i":
            if "f" not in designs:
                raise SystemExit("case i starts from case f's design: run --cases f,i")
            initial = designs["f"].parameters.replace(cut_pattern=np.zeros(12), stiffness_span=None,
                                                      stiffness_chord=None)
        bounds = {"pressure": (1e3, 1e5), **bounds}
        t = time.perf_counter()
        result = optimise_pressure(base, target, variables=variables, initial=initial, bounds=bounds,
                                   objective="average", max_iterations=args.max_iterations)
        wall = time.perf_counter() - t
        designs[key] = result
        p = result.parameters
        mid = section_errors(result.solution, target, 1.0)
        s = np.linspace(0.0, 1.0, 201)
        span_field, chord_field = field_values(s, p.prestrain_span, p.prestrain_chord, p.cut_pattern)
        row = {"case": label, "key": key, "variables": list(variables), "success": result.success,
               "message": result.message, "pressure_pa": float(p.pressure),
               "prestrain": [float(v) for v in p.prestrain],
               "rib_thickness_scale": float(p.rib_thickness_scale),
               "rib_shape": None if p.rib_shape is None else np.asarray(p.rib_shape).tolist(),
               "cut_pattern": None if p.cut_pattern is None else np.asarray(p.cut_pattern).tolist(),
               "span_prestrain_field": [float(span_field.min()), float(span_field.max())],
               "chord_prestrain_field": [float(chord_field.min()), float(chord_field.max())],
               "grid": [args.n_span, args.n_contour],
               "start_average_rms": result.initial_rms_error,
               "average_rms": result.rms_error, "average_max": result.max_error,
               "mid_bay_rms": mid.rms, "mid_bay_max": mid.max, "le_recession_mm": recession_mm(result.solution),
               "min_tension": result.constraint_values.get("min_tension"),
               "max_tension": result.constraint_values.get("max_tension"),
               "active": result.active_constraints, "solves": result.solves, "wall_s": wall, "finer": []}
        for n_span, n_contour in finer:
            sol = solve_equilibrium(scene(n_span, n_contour), p.replace(stiffness_span=None, stiffness_chord=None),
                                    rtol=1e-10, method="relax+newton")
            rms, largest = design_errors(sol.nodes, target, 1.0, "average")
            fine_mid = section_errors(sol, target, 1.0)
            row["finer"].append({"grid": [n_span, n_contour], "average_rms": rms, "average_max": largest,
                                 "mid_bay_rms": fine_mid.rms, "mid_bay_max": fine_mid.max,
                                 "le_recession_mm": recession_mm(sol),
                                 "min_tension": float(min(np.min(sol.tension_span), np.min(sol.tension_chord))),
                                 "max_tension": float(max(np.max(sol.tension_span), np.max(sol.tension_chord))),
                                 "wrinkled_fraction": sol.wrinkled_fraction})
        rows.append(row)
        print(json.dumps(row, default=float), flush=True)

    record = {"date": time.strftime("%Y-%m-%d"), "machine": platform.platform(),
              "processor": platform.processor(), "cpus": os.cpu_count(), "load": os.getloadavg(),
              "jax": jax.__version__, "rows": rows}
    out = ROOT / "benchmarks" / "results"
    out.mkdir(parents=True, exist_ok=True)
    name = f"cut_field_{args.cases.replace(',', '')}_{args.n_span}x{args.n_contour}.json"
    (out / name).write_text(json.dumps(record, indent=2, default=float) + "\n")
    print("\n| design | success | bay-average rms | bay-average max | mid-bay rms | mid-bay max | LE recession mm | "
          "bay-average rms on finer grids | min/max tension N/m | solves | s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        fine = " / ".join(f"{f['average_rms']:.2e}" for f in r["finer"])
        print(f"| {r['case']} | {r['success']} | {r['average_rms']:.2e} | {r['average_max']:.2e} | "
              f"{r['mid_bay_rms']:.2e} | {r['mid_bay_max']:.2e} | {r['le_recession_mm']:.1f} | {fine} | "
              f"{r['min_tension']:.0f} / {r['max_tension']:.0f} | {r['solves']} | {r['wall_s']:.0f} |")


if __name__ == "__main__":
    main()
