"""``optimise-pressure``: the command line, a thin layer over the public API.

By default it runs `inverse_design.optimise_pressure` on the case described by
the options (with no options, the built-in default: NACA 2412 target and
ribs, chord 1 m, ribs 0.25 m apart, 2% prestrain, a 9 x 64 grid, choosing the
pressure and the rib thickness scale so the bay-average section matches the
target). ``--evaluate`` only solves the equilibrium at the given pressure and
reports its errors. It writes ``summary.json`` into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="optimise-pressure",
        description="Inflatable wing bay: choose the internal pressure (and prestrain or rib "
        "thickness) so the pressurised skin matches a target profile. With no arguments it runs "
        "the built-in default case (NACA 2412, chord 1 m, ribs 0.25 m apart, 2%% prestrain, "
        "pressure and rib thickness optimised on a 9x64 grid).",
    )
    parser.add_argument("--target", default="naca2412",
                        help="target profile: nacaXXXX / nacaXXXXX or a Selig/Lednicer .dat file "
                        "(default naca2412); the ribs take this shape")
    parser.add_argument("--chord", type=float, default=1.0, help="chord, m (default 1.0)")
    parser.add_argument("--rib-spacing", type=float, default=0.25, help="rib spacing, m (default 0.25)")
    parser.add_argument("--pressure", type=float, default=1e4,
                        help="internal overpressure, Pa: the start of the optimisation, or the "
                        "value evaluated with --evaluate (default 1e4)")
    parser.add_argument("--pressure-bounds", type=float, nargs=2, default=(1e3, 1e5),
                        metavar=("LOW", "HIGH"), help="pressure bounds, Pa (default 1e3 1e5)")
    parser.add_argument("--prestrain-span", type=float, default=0.02,
                        help="span prestrain, fraction (default 0.02)")
    parser.add_argument("--prestrain-chord", type=float, default=0.02,
                        help="chord prestrain, fraction (default 0.02)")
    parser.add_argument("--rib-thickness-scale", type=float, default=1.0,
                        help="rib thickness over the target's (start or fixed value, default 1)")
    parser.add_argument("--variables", default="pressure,rib_thickness_scale",
                        help="comma-separated design variables among pressure, prestrain_span, "
                        "prestrain_chord, rib_thickness_scale, rib_chord_scale "
                        "(default pressure,rib_thickness_scale)")
    parser.add_argument("--objective", default="average", choices=("mid_bay", "average", "worst"),
                        help="which sections must match the target (default average)")
    parser.add_argument("--method", default="least_squares", choices=("least_squares", "root", "optax"),
                        help="optimiser (default least_squares)")
    parser.add_argument("--evaluate", action="store_true",
                        help="only solve the equilibrium at the given values and report the errors")
    parser.add_argument("--max-steps", type=int, default=200_000,
                        help="step cap of the equilibrium solve with --evaluate (default 200000)")
    parser.add_argument("--stiffness-span", type=float, default=2e5, help="E11, N/m (default 2e5)")
    parser.add_argument("--stiffness-chord", type=float, default=2e5, help="E22, N/m (default 2e5)")
    parser.add_argument("--poisson", type=float, default=0.25, help="Poisson coupling (default 0.25)")
    parser.add_argument("--n-span", type=int, default=9, help="nodes along the span (default 9)")
    parser.add_argument("--n-contour", type=int, default=64, help="nodes around the contour (default 64)")
    parser.add_argument("--out", default="optimise-pressure-out", help="output folder")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return parser


def _target(spec: str):
    from targets import load_airfoil, naca

    if Path(spec).suffix.lower() == ".dat" or Path(spec).exists():
        return load_airfoil(spec)
    return naca(spec)


def run(args: argparse.Namespace) -> dict:
    """Run the case described by ``args`` and write the output folder; return the summary."""
    from forward_solver import Bay, Fabric, Scene, solve_equilibrium

    from .objectives import section_errors
    from .optimise import optimise_pressure

    target = _target(args.target)
    bay = Bay.from_airfoil(target, chord=args.chord, rib_spacing=args.rib_spacing,
                           n_span=args.n_span, n_contour=args.n_contour)
    fabric = Fabric(stiffness_span=args.stiffness_span, stiffness_chord=args.stiffness_chord,
                    poisson=args.poisson)
    scene = Scene(bay, fabric)
    start = time.perf_counter()
    summary = {
        "target": target.name,
        "chord_m": args.chord,
        "rib_spacing_m": args.rib_spacing,
        "grid": [args.n_span, args.n_contour],
        "fabric": {"stiffness_span_n_per_m": args.stiffness_span,
                   "stiffness_chord_n_per_m": args.stiffness_chord, "poisson": args.poisson},
    }
    if args.evaluate:
        sol = solve_equilibrium(scene, args.pressure, (args.prestrain_span, args.prestrain_chord),
                                rib_thickness_scale=args.rib_thickness_scale,
                                max_steps=args.max_steps, throw=False)
        errors = section_errors(sol, target, args.chord)
        summary.update(mode="evaluate", pressure_pa=args.pressure,
                       prestrain=[args.prestrain_span, args.prestrain_chord],
                       rib_thickness_scale=args.rib_thickness_scale, result=sol.result.name,
                       steps=sol.steps, relative_residual=sol.residual,
                       mid_bay_rms_error_chord=errors.rms, mid_bay_max_error_chord=errors.max,
                       wrinkled_fraction=sol.wrinkled_fraction, success=sol.converged,
                       message=sol.message)
    else:
        variables = tuple(v.strip() for v in args.variables.split(",") if v.strip())
        initial = {"pressure": args.pressure, "prestrain_span": args.prestrain_span,
                   "prestrain_chord": args.prestrain_chord,
                   "rib_thickness_scale": args.rib_thickness_scale}
        res = optimise_pressure(scene, target, variables=variables, initial=initial,
                                bounds={"pressure": tuple(args.pressure_bounds)},
                                objective=args.objective, method=args.method)
        summary.update(mode="optimise", variables=list(variables), objective=args.objective,
                       method=args.method, success=res.success, message=res.message,
                       pressure_pa=res.pressure, prestrain=list(res.prestrain),
                       rib_thickness_scale=res.rib_thickness_scale,
                       rms_error_chord_before=res.initial_rms_error,
                       max_error_chord_before=res.initial_max_error,
                       rms_error_chord=res.rms_error, max_error_chord=res.max_error,
                       active_constraints=list(res.active_constraints),
                       iterations=len(res.history), forward_solves=res.solves,
                       wrinkled_fraction=res.solution.wrinkled_fraction)
    summary["wall_time_s"] = time.perf_counter() - start
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tmp = out / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=2))
    tmp.replace(out / "summary.json")
    summary["out"] = str(out.resolve())
    return summary


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``optimise-pressure`` console script; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    from forward_solver import ConvergenceError

    try:
        summary = run(args)
    except (ValueError, OSError) as exc:  # bad input: one line, no traceback
        print(f"optimise-pressure: error: {exc}", file=sys.stderr)
        return 2
    except ConvergenceError as exc:  # a forward solve failed: the reason, exit 1
        print(f"optimise-pressure: failed: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(summary, indent=2))
    elif not args.quiet:
        if summary["mode"] == "evaluate":
            print(f"{summary['target']}: {summary['result']} in {summary['steps']} steps, "
                  f"mid-bay error rms {summary['mid_bay_rms_error_chord']:.3e} chord, "
                  f"max {summary['mid_bay_max_error_chord']:.3e} chord")
            if not summary["success"]:
                print(f"equilibrium not reached: {summary['message']}", file=sys.stderr)
        else:
            print(f"{summary['target']}: pressure {summary['pressure_pa']:.1f} Pa, rib thickness "
                  f"scale {summary['rib_thickness_scale']:.4f}, prestrain "
                  f"{summary['prestrain'][0]:.4g}/{summary['prestrain'][1]:.4g}")
            print(f"{summary['objective']} error rms {summary['rms_error_chord_before']:.3e} -> "
                  f"{summary['rms_error_chord']:.3e} chord, max {summary['max_error_chord_before']:.3e}"
                  f" -> {summary['max_error_chord']:.3e} chord; active constraints: "
                  f"{', '.join(summary['active_constraints']) or 'none'}")
            if not summary["success"]:
                print(f"optimisation did not converge: {summary['message']}", file=sys.stderr)
        print(f"wrote {summary['out']}/summary.json")
    return 0 if summary["success"] else 1


if __name__ == "__main__":
    sys.exit(main())
