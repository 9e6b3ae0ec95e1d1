"""Which optimiser converges: every documented variable set on four cases, by method.

The matrix of `optimise_pressure` / `optimise_wing` runs that decides what
``method="auto"`` chooses (`inverse_design.optimise`):

* cases: the default bay (the ``optimise-pressure`` defaults: NACA 2412
  target and ribs, chord 1 m, ribs 0.25 m apart); the built-in wing
  (``inverse_design/cases/wing_taper.toml``: three tapered NACA 2412 bays);
  a NACA 0012 bay; a bay of a real section (``tests/data/uiuc/e387.dat``);
* variable sets (`VARIABLE_SETS`): the pressure; the pressure and both
  prestrains; the pressure and the rib thickness scale (the command's
  default); the pressure and a rib shape (one per rib on the wing); the
  pressure, the rib thickness scale and a cut pattern (shared; and one per
  bay on the wing); and two combinations: pressure, prestrains and rib
  thickness scale; pressure, prestrains and rib shape;
* methods: slsqp and gauss_newton, and least_squares where both fail.

Every run is built from the command's own namespace
(`inverse_design.app.case.parse_arguments` on ``--variables ... --method
...``, plus ``--config`` or ``--target`` for the case; `case.design_inputs`
for the start, bounds and limits), so it takes the command's defaults for
everything else (fabric 2e5 N/m both ways, Poisson 0.25, prestrain start 2%,
pressure start 1e4 Pa in 1e3-1e5, objective "average", min_tension 0,
max_iterations 50).

It records success, message, forward solves, rms and max error (fractions of
chord) and wall time (compilation included: the first run of a variable set
compiles its functions) and writes the JSON of ``benchmarks/results/`` after
every run, so an interrupted matrix keeps what it finished.

Run:
    PYTHONPATH=. python benchmarks/design_matrix.py                      # 17x64, every case
    PYTHONPATH=. python benchmarks/design_matrix.py --grid 7 32 --out F  # a smaller grid
    PYTHONPATH=. python benchmarks/design_matrix.py --cases default --methods auto

Absolute times depend on the machine (and its load): the JSON names it.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "benchmarks" / "results" / "design_matrix.json"

#: Case name -> the command-line arguments that make it.
CASES = {
    "default bay (NACA 2412)": [],
    "NACA 0012 bay": ["--target", "naca0012"],
    "E387 bay (.dat)": ["--target", str(ROOT / "tests" / "data" / "uiuc" / "e387.dat")],
    "wing_taper.toml (3 bays)": ["--config", str(ROOT / "inverse_design" / "cases" / "wing_taper.toml")],
}
#: Short names of `CASES` for ``--cases``.
SHORT = {"default": "default bay (NACA 2412)", "naca0012": "NACA 0012 bay", "e387": "E387 bay (.dat)",
         "wing": "wing_taper.toml (3 bays)"}
#: Variable-set name -> (``--variables``, extra arguments, wing only).
VARIABLE_SETS = {
    "pressure": ("pressure", [], False),
    "pressure+prestrains": ("pressure,prestrain_span,prestrain_chord", [], False),
    "pressure+rib_thickness_scale": ("pressure,rib_thickness_scale", [], False),
    "pressure+rib_shape": ("pressure,rib_shape", [], False),
    "pressure+rib_thickness_scale+cut_pattern": ("pressure,rib_thickness_scale,cut_pattern", [], False),
    "pressure+rib_thickness_scale+cut_pattern per bay": (
        "pressure,rib_thickness_scale,cut_pattern", ["--cut-pattern-layout", "per_bay"], True),
    "pressure+prestrains+rib_thickness_scale": (
        "pressure,prestrain_span,prestrain_chord,rib_thickness_scale", [], False),
    "pressure+prestrains+rib_shape": ("pressure,prestrain_span,prestrain_chord,rib_shape", [], False),
}
METHODS = ("slsqp", "gauss_newton")
#: Tried where every method of `METHODS` failed.
FALLBACK = "least_squares"
COLUMNS = ["case", "variables", "method", "success", "solves", "rms", "max", "seconds"]


def case_arguments(case: str, set_name: str, method: str, grid=None) -> list[str]:
    """The command line of one run."""
    variables, extra, _ = VARIABLE_SETS[set_name]
    argv = [*CASES[case], "--variables", variables, *extra, "--method", method]
    if grid is not None:
        argv += ["--n-span", str(grid[0]), "--n-contour", str(grid[1])]
    return argv


def design(argv: list[str]):
    """The design the command runs for ``argv`` (as `inverse_design.app.command.run`, no report)."""
    from forward_solver import Bay, Fabric, Scene, Wing
    from inverse_design import DesignRequest, Layout, Limits, SolverSettings, methods, optimise_pressure, optimise_wing
    from inverse_design.app.case import design_inputs, load_section, parse_arguments

    args, _ = parse_arguments(argv)
    fabric = Fabric(stiffness_span=args.stiffness_span, stiffness_chord=args.stiffness_chord, poisson=args.poisson)
    initial, variables, rib_limits, bounds, constraints = design_inputs(args)
    options = dict(initial=initial, bounds=bounds, objective=args.objective,
                   method=methods.named(args.method, objective=args.objective, tolerance=args.tolerance),
                   limits=Limits(tension=constraints, ribs=rib_limits),
                   solver=SolverSettings(max_iterations=args.max_iterations,
                                         equilibrium_method=args.equilibrium_method, max_steps=args.max_steps))
    ribs = getattr(args, "wing", None)
    if ribs is not None:
        sections = [load_section(r["section"], "section") for r in ribs]
        targets = [load_section(r["target"], "target") if "target" in r else sections[k]
                   for k, r in enumerate(ribs)]
        wing = Wing(airfoils=tuple(sections), chords=tuple(r["chord"] for r in ribs),
                    stations=tuple(r["station"] for r in ribs), trailing_edge=args.trailing_edge)
        layout = Layout(n_span=args.n_span, n_contour=args.n_contour, cut_pattern=args.cut_pattern_layout)
        return optimise_wing(wing, fabric, targets, DesignRequest(variables, layout=layout, **options))
    target = load_section(args.target, "--target")
    rib = target if args.rib is None else load_section(args.rib, "--rib")
    bay = Bay.from_airfoil(rib, chord=args.chord, rib_spacing=args.rib_spacing, n_span=args.n_span,
                           n_contour=args.n_contour)
    return optimise_pressure(Scene(bay, fabric), target, variables, **options)


def run_one(case: str, set_name: str, method: str, grid=None) -> dict:
    """One design as a record: success, message, solves, errors, seconds (or the exception)."""
    start = time.perf_counter()
    try:
        result = design(case_arguments(case, set_name, method, grid))
    except Exception as exc:  # recorded, not raised: the matrix goes on
        return {"case": case, "variables": set_name, "method": method, "success": False,
                "message": f"{type(exc).__name__}: {exc}", "solves": None, "rms": None, "max": None,
                "seconds": round(time.perf_counter() - start, 1)}
    return {"case": case, "variables": set_name, "method": method if method != "auto" else f"auto ({result.method})",
            "success": bool(result.success), "message": result.message, "solves": int(result.solves),
            "rms": float(f"{result.rms_error:.4g}"), "max": float(f"{result.max_error:.4g}"),
            "seconds": round(time.perf_counter() - start, 1)}


def machine() -> str:
    import jax

    try:
        load = "load average %.1f at the start" % os.getloadavg()[0]
    except OSError:
        load = "load unknown"
    return (f"{platform.machine()} {platform.processor() or ''}, {os.cpu_count()} cpus ({load}), "
            f"JAX {jax.__version__} on {jax.devices()[0].device_kind}, Python {platform.python_version()}")


def write(out: Path, records: list[dict], command: str, grid_text: str, machine_text: str, done: bool) -> None:
    failures = [f"{r['case']} / {r['variables']} / {r['method']}: {r['message']}" for r in records
                if not r["success"]]
    notes = [f"grid {grid_text} (n_span x n_contour per bay); the command's defaults otherwise (objective "
             "average, min_tension 0, max_iterations 50, start 1e4 Pa and 2% prestrain)",
             "rms, max: normal distance from the target, fractions of the (local) chord, over every row of "
             "every bay; solves: forward solves (each solves every bay once); seconds: wall time, "
             "compilation included (the first run of a variable set compiles its functions), one process",
             f"least_squares only where {' and '.join(METHODS)} both failed",
             *(["unfinished: the run was interrupted; these rows are what finished"] if not done else []),
             *[f"failed: {line}" for line in failures]]
    payload = {"title": f"Design matrix: every documented variable set on four cases, by method ({grid_text})",
               "command": command, "machine": machine_text, "date": datetime.date.today().isoformat(),
               "columns": COLUMNS, "rows": [[r[c] for c in COLUMNS] for r in records], "notes": notes}
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(payload, indent=1) + "\n")
    tmp.replace(out)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grid", type=int, nargs=2, default=None, metavar=("N_SPAN", "N_CONTOUR"),
                        help="grid of every case (default: the command's, 17 64)")
    parser.add_argument("--cases", default=",".join(SHORT), help=f"comma-separated among {','.join(SHORT)}")
    parser.add_argument("--methods", default=",".join(METHODS),
                        help=f"comma-separated (default {','.join(METHODS)}; auto also works)")
    parser.add_argument("--no-fallback", action="store_true", help=f"never run {FALLBACK}")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"JSON file (default {DEFAULT_OUT})")
    options = parser.parse_args(argv)
    cases = [SHORT[c.strip()] for c in options.cases.split(",") if c.strip()]
    methods = [m.strip() for m in options.methods.split(",") if m.strip()]
    grid = tuple(options.grid) if options.grid else None
    grid_text = "x".join(map(str, grid)) if grid else "17x64"
    given = sys.argv[1:] if argv is None else argv
    shown = [a for a, b in zip(given, [None, *given]) if a != "--out" and b != "--out"]  # (not the JSON's place)
    command = " ".join(["PYTHONPATH=. python benchmarks/design_matrix.py", *shown])
    machine_text = machine()
    print(machine_text, flush=True)
    records = []
    for case in cases:
        for set_name, (_, _, wing_only) in VARIABLE_SETS.items():
            if wing_only and "--config" not in CASES[case]:
                continue
            tried = []
            for method in methods:
                tried.append(run_one(case, set_name, method, grid))
            if not options.no_fallback and not any(r["success"] for r in tried) and set(METHODS) <= set(methods):
                tried.append(run_one(case, set_name, FALLBACK, grid))
            for r in tried:
                records.append(r)
                print(f"{r['case']:<26} {r['variables']:<48} {r['method']:<22} {str(r['success']):<5} "
                      f"{r['solves']!s:>4} {r['rms']!s:>10} {r['max']!s:>10} {r['seconds']:>7} "
                      f"{'' if r['success'] else r['message'][:160]}", flush=True)
            write(options.out, records, command, grid_text, machine_text, done=False)
    write(options.out, records, command, grid_text, machine_text, done=True)
    print(f"wrote {options.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
