"""``optimise-pressure``: the command line, a thin layer over the public API.

Until the optimiser lands this command solves the equilibrium of the given
case at the given pressure and prestrain and reports how far its mid-bay
section lies from the target; it writes ``summary.json`` into ``--out``.
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
        description="Inflatable wing bay: equilibrium of the pressurised skin against a target "
        "profile. With no arguments it runs the built-in default case (NACA 2412 ribs, "
        "chord 1 m, ribs 0.25 m apart, 20 kPa, 0.5%% prestrain).",
    )
    parser.add_argument("--target", default="naca2412",
                        help="target profile: nacaXXXX / nacaXXXXX or a Selig/Lednicer .dat file "
                        "(default naca2412); the ribs take this shape")
    parser.add_argument("--chord", type=float, default=1.0, help="chord, m (default 1.0)")
    parser.add_argument("--rib-spacing", type=float, default=0.25, help="rib spacing, m (default 0.25)")
    parser.add_argument("--pressure", type=float, default=2e4, help="internal overpressure, Pa (default 2e4)")
    parser.add_argument("--prestrain-span", type=float, default=0.005,
                        help="span prestrain, fraction (default 0.005)")
    parser.add_argument("--prestrain-chord", type=float, default=0.005,
                        help="chord prestrain, fraction (default 0.005)")
    parser.add_argument("--stiffness-span", type=float, default=2e5, help="E11, N/m (default 2e5)")
    parser.add_argument("--stiffness-chord", type=float, default=2e5, help="E22, N/m (default 2e5)")
    parser.add_argument("--poisson", type=float, default=0.25, help="Poisson coupling (default 0.25)")
    parser.add_argument("--n-span", type=int, default=17, help="nodes along the span (default 17)")
    parser.add_argument("--n-contour", type=int, default=128, help="nodes around the contour (default 128)")
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
    """Solve the case described by ``args`` and write the output folder; return the summary."""
    from forward_solver import Bay, Fabric, Scene, solve_equilibrium

    from .objectives import section_errors

    target = _target(args.target)
    bay = Bay.from_airfoil(target, chord=args.chord, rib_spacing=args.rib_spacing,
                           n_span=args.n_span, n_contour=args.n_contour)
    fabric = Fabric(stiffness_span=args.stiffness_span, stiffness_chord=args.stiffness_chord,
                    poisson=args.poisson)
    start = time.perf_counter()
    sol = solve_equilibrium(Scene(bay, fabric), args.pressure,
                            (args.prestrain_span, args.prestrain_chord), throw=False)
    errors = section_errors(sol, target, args.chord)
    summary = {
        "target": target.name,
        "chord_m": args.chord,
        "rib_spacing_m": args.rib_spacing,
        "grid": [args.n_span, args.n_contour],
        "pressure_pa": args.pressure,
        "prestrain": [args.prestrain_span, args.prestrain_chord],
        "result": sol.result.name,
        "steps": sol.steps,
        "relative_residual": sol.residual,
        "mid_bay_rms_error_chord": errors.rms,
        "mid_bay_max_error_chord": errors.max,
        "wrinkled_fraction": sol.wrinkled_fraction,
        "wall_time_s": time.perf_counter() - start,
    }
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
    try:
        summary = run(args)
    except (ValueError, OSError) as exc:  # bad input: one line, no traceback
        print(f"optimise-pressure: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(summary, indent=2))
    elif not args.quiet:
        print(f"{summary['target']}: {summary['result']} in {summary['steps']} steps, "
              f"mid-bay error rms {summary['mid_bay_rms_error_chord']:.3e} chord, "
              f"max {summary['mid_bay_max_error_chord']:.3e} chord")
        print(f"wrote {summary['out']}/summary.json")
    return 0 if summary["result"] == "converged" else 1


if __name__ == "__main__":
    sys.exit(main())
