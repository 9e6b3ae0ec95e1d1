"""The cut as a designed field against the uniform cut and the rib shape.

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

With ``--wing``, the built-in wing instead (`inverse_design/cases/wing_taper.toml`:
three bays of NACA 2412, chords 1.0/0.85/0.7/0.6 m, ribs 0.25 m apart; the
method "auto", i.e. Gauss-Newton), cases:

U. pressure, both uniform prestrains (0-5%) and rib thickness scale (0.7-1);
V. as U with both prestrains within -2% .. 5%;
S. pressure, thickness scale and one cut pattern for every bay (K = 6,
   -2% .. 5%);
P. as S with a cut pattern per bay (3 x 12 coefficients);
R. pressure and a rib shape per rib (K = 4; prestrains fixed at 2%).

Each wing design is re-solved at the same parameters on 33x64 and 17x128
and measured there by the design's own objective (`DesignProblem.measure`).

Run:  PYTHONPATH=. python benchmarks/cut_field.py [--n-span 17 --n-contour 64 --cases a,b,c,d,e]
      PYTHONPATH=. python benchmarks/cut_field.py --wing [--cases U,V,S,P,R]

Writes benchmarks/results/cut_field_<cases>_<grid>.json (``cut_field_wing_...`` with ``--wing``;
``benchmarks/performance_doc.py`` puts them in docs/performance.md) and prints a Markdown table.
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
    parser.add_argument("--cases", default="a,b,c,d,e")
    parser.add_argument("--no-finer", action="store_true", help="skip the re-solves on finer grids")
    parser.add_argument("--wing", action="store_true", help="the built-in 3-bay wing (cases U, V, S, P, R)")
    args = parser.parse_args()
    if args.wing:
        return wing_main(args)

    from forward_solver import Bay, Fabric, Parameters, Scene, solve_equilibrium
    from forward_solver.model.cut_field import field_values
    from inverse_design import SolverSettings, optimise_pressure
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
                                   objective="average", solver=SolverSettings(max_iterations=args.max_iterations))
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
               "min_tension": result.limits.values.get("min_tension"),
               "max_tension": result.limits.values.get("max_tension"),
               "active": result.limits.active, "solves": result.solves, "wall_s": wall, "finer": []}
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

    save_result(f"cut_field_{args.cases.replace(',', '')}_{args.n_span}x{args.n_contour}",
                title=f"Cut-pattern designs of the default bay, cases {args.cases}", command=_command(args),
                columns=["design", "success", "bay-average rms, chord", "bay-average max, chord", "mid-bay rms, chord",
                         "mid-bay max, chord", "LE recession, mm", "bay-average rms on finer grids",
                         "least / largest tension, N/m", "forward solves", "wall time, s"],
                rows=[[r["case"], "yes" if r["success"] else "no", f"{r['average_rms']:.3e}", f"{r['average_max']:.3e}",
                       f"{r['mid_bay_rms']:.3e}", f"{r['mid_bay_max']:.3e}", round(r["le_recession_mm"], 1),
                       " / ".join(f"{f['average_rms']:.3e}" for f in r["finer"]),
                       f"{r['min_tension']:.0f} / {r['max_tension']:.0f}", r["solves"], round(r["wall_s"], 1)]
                      for r in rows],
                notes=[f"The default case (NACA 2412, chord 1 m, ribs 0.25 m apart, prestrain start 2%, pressure "
                       f"1-100 kPa, rib thickness scale 0.7-1, wrinkle-free, bay-average objective) on "
                       f"{args.n_span}x{args.n_contour}, each design re-solved at its parameters on the finer grids; "
                       "the LE recession is the chordwise shift of the mid-bay section's nose behind the "
                       "target's; wall time includes compilation. The cases: the module docstring."])
    print("\n| design | success | bay-average rms | bay-average max | mid-bay rms | mid-bay max | LE recession mm | "
          "bay-average rms on finer grids | min/max tension N/m | solves | s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        fine = " / ".join(f"{f['average_rms']:.2e}" for f in r["finer"])
        print(f"| {r['case']} | {r['success']} | {r['average_rms']:.2e} | {r['average_max']:.2e} | "
              f"{r['mid_bay_rms']:.2e} | {r['mid_bay_max']:.2e} | {r['le_recession_mm']:.1f} | {fine} | "
              f"{r['min_tension']:.0f} / {r['max_tension']:.0f} | {r['solves']} | {r['wall_s']:.0f} |")


def _command(args) -> str:
    """The command line that reproduces this run."""
    words = ["python benchmarks/cut_field.py"] + (["--wing"] if args.wing else [])
    if args.cases != "a,b,c,d,e":
        words.append(f"--cases {args.cases}")
    if (args.n_span, args.n_contour) != (17, 64):
        words.append(f"--n-span {args.n_span} --n-contour {args.n_contour}")
    if args.max_iterations != 60:
        words.append(f"--max-iterations {args.max_iterations}")
    if args.no_finer:
        words.append("--no-finer")
    return " ".join(words)


def wing_main(args) -> None:
    """The built-in wing's designs (module docstring, ``--wing``)."""
    import jax

    from forward_solver import Fabric
    from forward_solver import Wing
    from inverse_design import Constraints, DesignRequest, Layout, SolverSettings, optimise_wing
    from inverse_design.objectives import WingTargets, section_errors
    from inverse_design.problem import DesignProblem
    from inverse_design.variables import DesignVariables
    from targets import naca

    target = naca("2412")
    fabric = Fabric()
    wing = Wing(airfoils=(target,) * 4, chords=(1.0, 0.85, 0.7, 0.6), stations=(0.0, 0.25, 0.5, 0.75))
    start = {"pressure": 1e4, "prestrain_span": 0.02, "prestrain_chord": 0.02}
    thickness = {"rib_thickness_scale": (0.7, 1.0)}
    wide = {"prestrain_span": (-0.02, 0.05), "prestrain_chord": (-0.02, 0.05)}
    uniform = ("pressure", "prestrain_span", "prestrain_chord", "rib_thickness_scale")
    field = ("pressure", "rib_thickness_scale", "cut_pattern")
    cases = {
        "U": ("pressure + both prestrains (0-5%) + thickness scale (uniform cut)", uniform, thickness, {}),
        "V": ("pressure + both prestrains (-2% .. 5%) + thickness scale (uniform cut)", uniform,
              {**thickness, **wide}, {}),
        "S": ("pressure + thickness scale + one cut pattern for every bay, K = 6", field,
              {**thickness, "cut_pattern": (-0.02, 0.05)}, {"cut_pattern": "shared"}),
        "P": ("pressure + thickness scale + a cut pattern per bay, K = 6", field,
              {**thickness, "cut_pattern": (-0.02, 0.05)}, {"cut_pattern": "per_bay"}),
        "R": ("pressure + a rib shape per rib, K = 4", ("pressure", "rib_shape"), {}, {}),
    }
    keys = "U,V,S,P,R" if args.cases == "a,b,c,d,e" else args.cases
    finer = [] if args.no_finer else [(2 * args.n_span - 1, args.n_contour), (args.n_span, 2 * args.n_contour)]

    def mid_bay(result, solutions, chords):
        """Per bay: mid-bay rms and max (fraction of the local chord) and LE recession (mm) against the
        mounted mid-bay section's nose."""
        out = []
        for k, sol in enumerate(solutions):
            chord = 0.5 * (chords[k] + chords[k + 1])
            errors = section_errors(sol, target, chord)
            row = sol.nodes.shape[0] // 2
            mounted = np.asarray(result.wing_solution.mounted[k])[row] if result is not None else None
            nose = float(np.min(np.asarray(sol.nodes)[row, :, 0]))
            out.append((errors.rms, errors.max, None if mounted is None else 1e3 * (nose - float(np.min(mounted[:, 0])))))
        return out

    rows = []
    for key in keys.split(","):
        label, variables, bounds, layout = cases[key]
        initial = {**start, **({"cut_pattern": np.zeros(12)} if "cut_pattern" in variables else {})}
        t = time.perf_counter()
        result = optimise_wing(wing, fabric, None, DesignRequest(
            variables, initial, {"pressure": (1e3, 1e5), **bounds}, objective="average",
            solver=SolverSettings(max_iterations=args.max_iterations),
            layout=Layout(n_span=args.n_span, n_contour=args.n_contour, **layout)))
        wall = time.perf_counter() - t
        sol, bays = result.wing_solution, result.per_bay
        solutions = [sol.bay_solution(k) for k in range(3)]
        mids = mid_bay(result, solutions, wing.chords)
        p = result.parameters
        row = {"case": label, "key": key, "variables": list(variables), "method": result.method,
               "success": result.success, "message": result.message, "pressure_pa": float(p.pressure),
               "prestrain": [float(v) for v in p.prestrain], "rib_thickness_scale": float(p.rib_thickness_scale),
               "cut_pattern": None if p.cut_pattern is None else np.asarray(p.cut_pattern).tolist(),
               "cut_patterns": None if bays.cut_patterns is None else bays.cut_patterns.tolist(),
               "rib_shapes": None if bays.rib_shapes is None else bays.rib_shapes.tolist(),
               "grid": [args.n_span, args.n_contour], "start_wing_rms": result.initial_rms_error,
               "wing_rms": result.rms_error, "bay_rms": bays.rms_error.tolist(),
               "bay_max": bays.max_error.tolist(), "mid_bay_rms": [m[0] for m in mids],
               "mid_bay_max": [m[1] for m in mids], "le_recession_mm": [m[2] for m in mids],
               "min_tension": result.limits.values.get("min_tension"),
               "max_tension": result.limits.values.get("max_tension"),
               "active": result.limits.active, "solves": result.solves, "wall_s": wall, "finer": []}
        given = {n: (bays.rib_shapes if n == "rib_shape" and bays.rib_shapes is not None else
                     bays.cut_patterns if n == "cut_pattern" and bays.cut_patterns is not None else
                     getattr(p, n)) for n in variables}
        for n_span, n_contour in finer:
            with jax.enable_x64(True):
                design = DesignVariables.build(variables, {**start, **given}, {"pressure": (1e3, 1e5), **bounds},
                                               n_ribs=4, rib_shape="per_rib", **layout)
                scenes = wing.scenes(fabric, n_span, n_contour)
                problem = DesignProblem(scenes, WingTargets([s.bay for s in scenes], [target] * 4, "average"), design,
                                        tension=Constraints(), solver=SolverSettings(rtol=1e-10))
                u = design.start_vector()
                fine = problem.solve(u)
                measured = problem.measure(fine, u)
            fine_mids = mid_bay(None, [fine.bay_solution(k) for k in range(3)], wing.chords)
            row["finer"].append({"grid": [n_span, n_contour], "wing_rms": measured["wing_rms"],
                                 "bay_rms": measured["rms"].tolist(), "bay_max": measured["max"].tolist(),
                                 "mid_bay_rms": [m[0] for m in fine_mids],
                                 "min_tension": float(np.min(measured["min_tension"])),
                                 "max_tension": float(np.max(measured["max_tension"]))})
        rows.append(row)
        print(json.dumps(row, default=float), flush=True)
    save_result(f"cut_field_wing_{keys.replace(',', '')}_{args.n_span}x{args.n_contour}",
                title=f"Cut-pattern designs of the built-in 3-bay wing, cases {keys}", command=_command(args),
                columns=["design", "result", "wing rms", "bay-average rms, root to tip", "mid-bay rms", "bay max",
                         "LE recession, mm", "wing rms on finer grids", "least / largest tension, N/m",
                         "wing solves", "wall time, s"],
                rows=[[r["case"], "success" if r["success"] else "failure", f"{r['wing_rms']:.3e}",
                       ", ".join(f"{v:.2e}" for v in r["bay_rms"]), ", ".join(f"{v:.2e}" for v in r["mid_bay_rms"]),
                       ", ".join(f"{v:.2e}" for v in r["bay_max"]),
                       ", ".join(f"{v:.1f}" for v in r["le_recession_mm"]),
                       " / ".join(f"{f['wing_rms']:.3e}" for f in r["finer"]),
                       f"{r['min_tension']:.1f} / {r['max_tension']:.0f}", r["solves"], round(r["wall_s"], 1)]
                      for r in rows],
                notes=[f"The built-in wing (inverse_design/cases/wing_taper.toml: three bays of NACA 2412, chords "
                       f"1.0/0.85/0.7/0.6 m, ribs 0.25 m apart) on {args.n_span}x{args.n_contour} per bay, start "
                       "10 kPa and 2% prestrains, average objective, the default method; errors are fractions of "
                       "the local chord, bays root to tip; wall time includes compilation."])
    print("\n| design | result | wing rms | bay-average rms, root to tip | mid-bay rms | bay max | LE recession "
          "mm | wing rms on 33x64 / 17x128 | least / largest tension N/m | wing solves | s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        def listed(values, form):
            return ", ".join(form.format(v) for v in values)
        fine = " / ".join(f"{f['wing_rms']:.3e}" for f in r["finer"])
        print(f"| {r['case']} | {'success' if r['success'] else 'failure'} | {r['wing_rms']:.3e} | "
              f"{listed(r['bay_rms'], '{:.2e}')} | {listed(r['mid_bay_rms'], '{:.2e}')} | "
              f"{listed(r['bay_max'], '{:.2e}')} | {listed(r['le_recession_mm'], '{:.1f}')} | {fine} | "
              f"{r['min_tension']:.1f} / {r['max_tension']:.0f} | {r['solves']} | {r['wall_s']:.0f} |")


if __name__ == "__main__":
    main()
