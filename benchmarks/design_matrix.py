"""Robustness of `optimise_pressure` over a matrix of cases.

Every combination of

* grid (n_span x n_contour): 7x64, 9x64, 17x128;
* objective: mid_bay, average, worst;
* design variables: the pressure; the pressure and both prestrains; the
  pressure and both rib scales (thickness and chord);
* target: NACA 2412, 0012, 4415, 23012 (the ribs are the target);

108 designs, each with the ``optimise-pressure`` command's defaults (the
namespace of `inverse_design.app.case.parse_arguments`, the scene built as
`inverse_design.app.command.run` builds it): fabric 2e5 N/m both ways, Poisson
0.25, prestrain 2% both ways, chord 1 m, rib spacing 0.25 m, pressure start
1e4 Pa, bounds pressure 1e3-1e5 Pa, prestrain 0-0.05, rib thickness 0.7-1.0,
rib chord 0.5-1.5, min_tension 0 (wrinkle-free), no max tension, SLSQP with
max_iterations 50.

One process; the runs are grouped by grid, so each grid's functions compile
once (the bay geometry is traced: a new target on the same grid reuses them).

For every run it records success, message, forward solves, iterations
(iterates in the history: one per forward solve, SLSQP's line-search trials
included), the final parameters, rms and max error (fractions of chord)
before and after, the active and violated constraints and the wall time; it
writes them as JSON (after every run, so an interrupted run keeps what it
finished) and prints a table and a summary: counts by outcome (converged;
failed: ``success`` False with a message; error: an exception escaped
`optimise_pressure`), the largest number of solves, the runs that hit the
iteration cap (SLSQP's "Iteration limit reached") or the evaluation cap
(`SLSQP_EVALUATIONS_PER_ITERATION` * max_iterations forward solves), and the
failures.

Run:
    PYTHONPATH=. python benchmarks/design_matrix.py            # all 108 (about 6 min on 2 busy cores)
    PYTHONPATH=. python benchmarks/design_matrix.py --quick    # 9 runs on 7x64, NACA 2412
    PYTHONPATH=. python benchmarks/design_matrix.py --out FILE # JSON elsewhere

Absolute times depend on the machine: the JSON and the printout name it.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import platform
import sys
import time
import traceback
from pathlib import Path

import jax
import numpy as np

from forward_solver import Bay, Fabric, Parameters, Scene
from inverse_design import Constraints, optimise_pressure
from inverse_design.app.case import parse_arguments
from inverse_design.methods import SLSQP_EVALUATIONS_PER_ITERATION
from targets import naca

GRIDS = ((7, 64), (9, 64), (17, 128))
OBJECTIVES = ("mid_bay", "average", "worst")
VARIABLE_SETS = {
    "pressure": ("pressure",),
    "pressure+prestrains": ("pressure", "prestrain_span", "prestrain_chord"),
    "pressure+rib scales": ("pressure", "rib_thickness_scale", "rib_chord_scale"),
}
TARGETS = ("2412", "0012", "4415", "23012")
QUICK = dict(grids=((7, 64),), targets=("2412",))

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "design_matrix.json"


def command_defaults():
    """The ``optimise-pressure`` defaults (its own namespace: they cannot drift from the command)."""
    args, _ = parse_arguments([])
    return args


def make_scene(args, target, n_span: int, n_contour: int) -> Scene:
    """The scene of `inverse_design.app.command.run`: ribs equal to the target."""
    bay = Bay.from_airfoil(target, chord=args.chord, rib_spacing=args.rib_spacing, n_span=n_span,
                           n_contour=n_contour)
    return Scene(bay, Fabric(stiffness_span=args.stiffness_span, stiffness_chord=args.stiffness_chord,
                             poisson=args.poisson))


def design_options(args, variables):
    """The start, bounds, constraints and optimiser options of `inverse_design.app.command.run`."""
    initial = Parameters(pressure=args.pressure, prestrain_span=args.prestrain_span,
                         prestrain_chord=args.prestrain_chord,
                         rib_thickness_scale=args.rib_thickness_scale, rib_chord_scale=args.rib_chord_scale)
    all_bounds = {"pressure": args.pressure_bounds, "prestrain_span": args.prestrain_bounds,
                  "prestrain_chord": args.prestrain_bounds, "rib_thickness_scale": args.rib_thickness_bounds,
                  "rib_chord_scale": args.rib_chord_bounds}
    constraints = (None if args.no_tension_constraints else
                   Constraints(min_tension=args.min_tension, max_tension=args.max_tension))
    return dict(initial=initial, bounds={n: tuple(all_bounds[n]) for n in variables},
                constraints=constraints, method=args.method, max_iterations=args.max_iterations,
                tolerance=args.tolerance)


def outcome(record: dict) -> str:
    """One word: converged, failed (a reported failure) or error (an exception)."""
    if "exception" in record:
        return "error"
    return "converged" if record["success"] else "failed"


def run_case(scene, target, args, objective, variables) -> dict:
    """One design, as a JSON-ready record."""
    options = design_options(args, variables)
    start = time.perf_counter()
    try:
        res = optimise_pressure(scene, target, variables, objective=objective, **options)
    except Exception as exc:  # recorded, not raised: the matrix goes on (the record says what)
        return {"exception": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc(),
                "wall_time": time.perf_counter() - start}
    cap = SLSQP_EVALUATIONS_PER_ITERATION * args.max_iterations
    return {
        "success": bool(res.success),
        "message": res.message,
        "solves": res.solves,
        "iterations": len(res.history),
        "parameters": {name: float(getattr(res.parameters, name)) for name in variables},
        "initial_rms_error": float(res.initial_rms_error),
        "initial_max_error": float(res.initial_max_error),
        "rms_error": float(res.rms_error),
        "max_error": float(res.max_error),
        "active_constraints": list(res.active_constraints),
        "violated_constraints": {k: float(v) for k, v in res.violated_constraints.items()},
        "constraint_values": {k: float(v) for k, v in res.constraint_values.items()},
        "iteration_cap": "Iteration limit reached" in res.message,
        "evaluation_cap": f"stopped after {cap} evaluations" in res.message,
        "wall_time": time.perf_counter() - start,
    }


def fmt(x, spec=".3g"):
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def table_line(r: dict) -> str:
    head = f"{r['grid']:>7} {r['objective']:<8} {r['variable_set']:<20} {r['target']:<6}"
    if "exception" in r:
        return f"{head} ERROR {r['exception'][:90]}"
    values = " ".join(f"{k.replace('prestrain_', 'e_').replace('rib_', '').replace('_scale', '')}="
                      f"{fmt(v, '.4g')}" for k, v in r["parameters"].items())
    flags = ("I" if r["iteration_cap"] else "") + ("E" if r["evaluation_cap"] else "")
    return (f"{head} {outcome(r):<9} {r['solves']:>5} {r['iterations']:>5} "
            f"{fmt(r['initial_rms_error'], '.2e')}->{fmt(r['rms_error'], '.2e')} {fmt(r['max_error'], '.2e')} "
            f"{r['wall_time']:7.1f} {flags:<2} {','.join(r['active_constraints']) or '-':<38} {values}")


def summarise(records: list[dict], max_iterations: int) -> list[str]:
    lines = []
    counts = {}
    for r in records:
        counts[outcome(r)] = counts.get(outcome(r), 0) + 1
    lines.append(f"runs: {len(records)}; " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    done = [r for r in records if "exception" not in r]
    if done:
        worst = max(done, key=lambda r: r["solves"])
        lines.append(f"max solves: {worst['solves']} ({case_name(worst)}); cap "
                     f"{SLSQP_EVALUATIONS_PER_ITERATION * max_iterations}; max iterations "
                     f"{max(r['iterations'] for r in done)}")
        times = np.array([r["wall_time"] for r in records])
        lines.append(f"wall time per run: median {np.median(times):.1f} s, max {times.max():.1f} s, "
                     f"total {times.sum() / 60:.1f} min")
        for grid in dict.fromkeys(r["grid"] for r in records):
            t = [r["wall_time"] for r in records if r["grid"] == grid]
            lines.append(f"  {grid}: {len(t)} runs, median {np.median(t):.1f} s, total {sum(t) / 60:.1f} min")
    capped = [r for r in done if r["iteration_cap"] or r["evaluation_cap"]]
    lines.append(f"hit a cap: {len(capped)} (iteration cap {sum(r['iteration_cap'] for r in done)}, "
                 f"evaluation cap {sum(r['evaluation_cap'] for r in done)})")
    lines += [f"  {case_name(r)}: {r['message']}" for r in capped]
    # The history holds one iterate per forward solve, line-search trials included: more
    # iterates than max_iterations is not the iteration cap, but shows a slow design.
    long = [r for r in done if r["iterations"] >= max_iterations and r not in capped]
    lines.append(f"{max_iterations} iterates or more without a cap: {len(long)}")
    lines += [f"  {case_name(r)}: {r['iterations']} iterates, {r['solves']} solves" for r in long]
    failed = [r for r in records if outcome(r) != "converged"]
    lines.append(f"not converged: {len(failed)}")
    for r in failed:
        text = r.get("exception") or r["message"]
        extra = f" violated {r['violated_constraints']}" if r.get("violated_constraints") else ""
        lines.append(f"  {case_name(r)}: {text}{extra}")
    return lines


def case_name(r: dict) -> str:
    return f"{r['grid']} {r['objective']} {r['variable_set']} naca{r['target']}"


def machine() -> str:
    return (f"{platform.node()} {platform.machine()} {platform.processor() or ''}, {os.cpu_count()} cpus, "
            f"JAX {jax.__version__} on {jax.devices()[0].device_kind}, Python {platform.python_version()}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="7x64 and NACA 2412 only (9 runs)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"JSON file (default {DEFAULT_OUT})")
    options = parser.parse_args(argv)
    grids, targets = (QUICK["grids"], QUICK["targets"]) if options.quick else (GRIDS, TARGETS)
    args = command_defaults()
    header = {"machine": machine(), "defaults": {k: v for k, v in vars(args).items()
                                                 if isinstance(v, (int, float, str, tuple, type(None)))}}
    options.out.parent.mkdir(parents=True, exist_ok=True)
    print(header["machine"])
    print(f"{'grid':>7} {'objective':<8} {'variables':<20} {'target':<6} {'outcome':<9} {'solves':>5} "
          f"{'iters':>5} {'rms before->after':<19} {'max':<8} {'time s':>7} cap {'active':<38} values")
    records = []
    started = time.perf_counter()
    for (n_span, n_contour), code in itertools.product(grids, targets):
        target = naca(code)
        scene = make_scene(args, target, n_span, n_contour)
        for objective, (set_name, variables) in itertools.product(OBJECTIVES, VARIABLE_SETS.items()):
            record = {"grid": f"{n_span}x{n_contour}", "objective": objective, "variable_set": set_name,
                      "target": code, **run_case(scene, target, args, objective, variables)}
            records.append(record)
            print(table_line(record), flush=True)
            options.out.write_text(json.dumps({**header, "runs": records}, indent=1))
    print(f"\nwhole matrix: {(time.perf_counter() - started) / 60:.1f} min on {header['machine']}")
    for line in summarise(records, args.max_iterations):
        print(line)
    print(f"wrote {options.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
