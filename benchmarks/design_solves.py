"""Wing solves and time of a design: SLSQP against Gauss-Newton SQP, in one run.

Cases (every one at 17x64 per bay, the wrinkle floor on):

* ``bay``: the default case (what ``optimise-pressure`` runs: NACA 2412, chord
  1 m, ribs 0.25 m apart, pressure 1-100 kPa and rib thickness scale 0.7-1.0,
  prestrain 2%, bay-average objective);
* ``wing3``: the built-in 3-bay wing (``inverse_design/cases/wing_taper.toml``)
  with the pressure and a rib shape per rib (4 ribs x 8 coefficients: 33
  variables), as the command runs it with ``--variables pressure,rib_shape``
  (rib limits on; SLSQP with ``max_iterations=200``, as its README row);
* ``wing40``: the 40-cell case (``inverse_design/cases/wing_40_cells.toml``:
  pressure and both prestrains) through the command, end to end, with the
  report's time separately (Gauss-Newton only unless ``--wing40-slsqp``).

For each: wing solves, wall time, success, wing rms; then the ratios
SLSQP / Gauss-Newton, of SLSQP's run and the second Gauss-Newton run (both
on compiled functions; the first Gauss-Newton run includes the compilation). Quote the machine and its load with the numbers.
Writes ``benchmarks/results/design_solves.json`` (``benchmarks/performance_doc.py`` puts it in
``docs/performance.md``).

Run:  PYTHONPATH=. python benchmarks/design_solves.py [--cases bay,wing3,wing40] [--wing40-slsqp]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.results import save_result  # noqa: E402

CASES = {
    "bay": "the default bay (pressure, rib thickness scale; 17x64)",
    "wing3": "the built-in 3-bay wing, pressure and a rib shape per rib (33 variables)",
    "wing40": "the 40-cell wing through the command (pressure, both prestrains)",
}


def bay_case(method):
    from forward_solver import Bay, Fabric, Parameters, Scene
    from inverse_design import optimise_pressure
    from targets import naca

    target = naca("2412")
    scene = Scene(Bay.from_airfoil(target, chord=1.0, rib_spacing=0.25, n_span=17, n_contour=64), Fabric())
    return optimise_pressure(scene, target, ("pressure", "rib_thickness_scale"),
                             initial=Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.02),
                             bounds={"pressure": (1e3, 1e5), "rib_thickness_scale": (0.7, 1.0)},
                             objective="average", method=method)


def wing3_case(method):
    from forward_solver import Fabric
    from forward_solver import Wing
    from inverse_design import Constraints, DesignRequest, Layout, Limits, SolverSettings, optimise_wing
    from targets import naca

    af = naca("2412")
    wing = Wing(airfoils=(af, af, af, af), chords=(1.0, 0.85, 0.7, 0.6), stations=(0.0, 0.25, 0.5, 0.75))
    return optimise_wing(wing, Fabric(), None, DesignRequest(
        ("pressure", "rib_shape"), {"pressure": 1e4, "prestrain_span": 0.02, "prestrain_chord": 0.02},
        {"pressure": (1e3, 1e5)}, objective="average", method=method, limits=Limits(tension=Constraints()),
        solver=SolverSettings(max_iterations=200 if method == "slsqp" else 50), layout=Layout(n_span=17, n_contour=64)))


def _children_cpu() -> float:
    """CPU seconds (user + system) of the finished child processes so far: on a shared machine the
    command's own work, where its wall time also counts the other jobs' turns."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def wing40_case(method):
    """The command on the 40-cell case file in a fresh process: its own timings (optimisation, report)."""
    with tempfile.TemporaryDirectory() as tmp:
        command = [sys.executable, "-m", "inverse_design.app.cli", "--config",
                   str(ROOT / "inverse_design" / "cases" / "wing_40_cells.toml"), "--out", str(Path(tmp) / "out"),
                   "--json", "--method", method]
        start, cpu = time.perf_counter(), _children_cpu()
        done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
        wall, cpu = time.perf_counter() - start, _children_cpu() - cpu
        summary = json.loads(done.stdout)
    results = summary["results"]
    return {"solves": results["forward_solves"], "wall": wall, "cpu": cpu, "success": results["success"],
            "rms": summary["errors"]["after"]["rms"], "timings": summary["timings_s"]}


def row(name, method, run):
    start = time.perf_counter()
    res = run(method)
    if isinstance(res, dict):
        out = {"case": name, "method": method, **res}
    else:
        out = {"case": name, "method": method, "solves": res.solves, "wall": time.perf_counter() - start,
               "success": res.success, "rms": res.rms_error, "message": res.message[:160]}
    print(json.dumps(out), flush=True)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="bay,wing3,wing40")
    parser.add_argument("--wing40-slsqp", action="store_true")
    args = parser.parse_args(argv)
    print(f"# {platform.machine()} {platform.processor() or ''}, {os.cpu_count()} cores, load "
          f"{os.getloadavg()}", flush=True)
    runs = {"bay": bay_case, "wing3": wing3_case, "wing40": wing40_case}
    rows = []
    for name in args.cases.split(","):
        # gauss_newton, then slsqp, then gauss_newton again: the second gauss_newton and slsqp run on
        # compiled functions alike (the first pays the compilation of what both share).
        methods = (["gauss_newton", "slsqp", "gauss_newton"] if name != "wing40" or args.wing40_slsqp
                   else ["gauss_newton"])
        done = [row(name, m, runs[name]) for m in methods]
        rows += done
        if len(done) == 3:
            sq, gn = done[1:]
            print(f"# {name}: slsqp / gauss_newton: solves {sq['solves'] / gn['solves']:.2f}, time "
                  f"{sq['wall'] / gn['wall']:.2f}, rms {sq['rms'] / gn['rms']:.4f}", flush=True)
    print(f"# load at the end {os.getloadavg()}")
    table = []
    for r in rows:
        timings = r.get("timings", {})
        table.append([CASES[r["case"]], r["method"], "yes" if r["success"] else "no", r["solves"],
                      round(r["wall"], 1), round(r["cpu"], 1) if "cpu" in r else None,
                      round(timings["optimisation"], 1) if "optimisation" in timings else None,
                      round(timings["report"], 1) if "report" in timings else None, f"{r['rms']:.4e}"])
    command = "python benchmarks/design_solves.py --cases " + args.cases + (" --wing40-slsqp" if args.wing40_slsqp else "")
    save_result("design_solves", title="Solves and time of a design: SLSQP against Gauss-Newton",
                command=command,
                columns=["case", "method", "success", "wing solves", "wall time, s", "CPU time of the command, s",
                         "command's design, s",
                         "command's report, s", "rms error after, chord"],
                rows=table,
                notes=["Every case at 17x64 per bay with the wrinkle floor on. Each library case runs "
                       "gauss_newton (compiling), slsqp, then gauss_newton again (compiled): compare slsqp "
                       "with the second gauss_newton row.",
                       "The 40-cell row is the command (`--config inverse_design/cases/wing_40_cells.toml`) "
                       "in a fresh process, imports, compilation and the report included, with the "
                       "compilation cache of the user running it."])
    return rows


if __name__ == "__main__":
    main()
