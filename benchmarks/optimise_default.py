"""The default inverse-design case: fresh-process time, forward solves, and the grid's effect.

The default case (what ``optimise-pressure`` runs with no arguments): NACA 2412
ribs and target, chord 1 m, ribs 0.25 m apart, the default fabric (E = 2e5
N/m, nu = 0.25), prestrain 2% both ways, a 17 x 64 grid. Optimised: the
pressure (1-100 kPa) and the rib thickness scale (0.7-1.0) on the bay-average
objective, with a wrinkle-free skin (SLSQP).

Its optimum is the corner (1 kPa, 1.0): with ribs equal to the target the
bulge between them only adds error, and on a grid that resolves the skin
next to the ribs no cell wrinkles there. On 9 span nodes the contour strain
beside the ribs zig-zags from row to row and the second cell row from each
rib shows a spurious compression at the leading edge (-1337 N/m at 1 kPa,
against +111 N/m on 17 x 128 and +174 N/m on 33 x 256); the wrinkle
constraint then held the old 9 x 64 default at an interior 6.25 kPa and rib
scale 0.946. The span count decides it, not the contour count.

Run:  PYTHONPATH=. python benchmarks/optimise_default.py [--skip-grids] [--skip-command] [--grids 9x64,17x64]

1. The command in fresh processes (``python -m inverse_design.app.cli``): once
   with an empty compilation cache (everything compiles), twice with the cache
   it left (the second run of a grid on a machine), and once with the cache
   off. Wall time of the process, and the run's own timings.
2. The default case in one process on 9x64, 17x64, 17x128 and 33x256: the
   optimum, its forward solves, and its agreement with 33x256; and, for the
   ratio, the penalty method (least_squares) on 17x64.

Absolute times depend on the machine: quote it with them. Writes
``benchmarks/results/optimise_default_command.json`` and
``optimise_default_grids.json`` (``benchmarks/performance_doc.py`` puts them
in ``docs/performance.md``).
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

GRIDS = [(9, 64), (17, 64), (17, 128), (33, 256)]


def default_case(n_span: int = 17, n_contour: int = 64, method: str = "slsqp"):
    """The default scene, target and optimiser arguments (as the command builds them)."""
    from forward_solver import Bay, Fabric, Parameters, Scene
    from targets import naca

    target = naca("2412")
    bay = Bay.from_airfoil(target, chord=1.0, rib_spacing=0.25, n_span=n_span, n_contour=n_contour)
    kwargs = dict(
        variables=("pressure", "rib_thickness_scale"),
        initial=Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.02),
        bounds={"pressure": (1e3, 1e5), "rib_thickness_scale": (0.7, 1.0)},
        objective="average",
        method=method,
    )
    return Scene(bay, Fabric()), target, kwargs


def _children_cpu() -> float:
    """CPU seconds (user + system) of the finished child processes so far: on a shared machine the
    command's own work, where its wall time also counts the other jobs' turns."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def command_runs() -> list[dict]:
    """Wall time of fresh ``optimise-pressure`` processes: cold cache, cached twice, cached without figures,
    no cache."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, INFLATABLE_WING_CACHE=str(Path(tmp) / "cache"),
                   PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
        for label, extra in [("cold cache", []), ("cached", []), ("cached again", []),
                             ("cached, --no-figures", ["--no-figures"]), ("no cache", ["--no-compilation-cache"])]:
            out = Path(tmp) / f"out-{len(rows)}"
            start, cpu = time.perf_counter(), _children_cpu()
            done = subprocess.run([sys.executable, "-m", "inverse_design.app.cli", "--quiet", "--out", str(out),
                                   *extra], env=env, capture_output=True, text=True)
            wall, cpu = time.perf_counter() - start, _children_cpu() - cpu
            if done.returncode != 0:
                raise RuntimeError(f"optimise-pressure failed ({done.returncode}): {done.stderr}")
            summary = json.loads((out / "summary.json").read_text())
            rows.append({"run": label, "wall_s": wall, "cpu_s": cpu, **{f"{k}_s": v for k, v in summary["timings_s"].items()},
                         "forward_solves": summary["results"]["forward_solves"]})
    return rows


def grid_runs(grids=GRIDS) -> list[dict]:
    """The default case on each of ``grids`` (SLSQP) and the penalty method on 17x64."""
    from inverse_design import optimise_pressure

    rows = []
    for (n_span, n_contour), method in [*((g, "slsqp") for g in grids), ((17, 64), "least_squares")]:
        scene, target, kwargs = default_case(n_span, n_contour, method)
        result = optimise_pressure(scene, target, **kwargs)
        rows.append({"grid": f"{n_span}x{n_contour}", "method": method, "success": result.success,
                     "pressure_pa": result.pressure, "rib_thickness_scale": result.rib_thickness_scale,
                     "rms_error": result.rms_error, "max_error": result.max_error,
                     "min_tension": result.limits.values["min_tension"],
                     "active": result.limits.active, "forward_solves": result.solves,
                     "optimiser_s": result.wall_time})
    return rows


def _grid(text: str) -> tuple[int, int]:
    n_span, n_contour = text.lower().split("x")
    return int(n_span), int(n_contour)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--skip-command", action="store_true", help="skip the fresh-process timings")
    parser.add_argument("--skip-grids", action="store_true", help="skip the grid comparison")
    parser.add_argument("--grids", default=",".join(f"{a}x{b}" for a, b in GRIDS),
                        help="grids of the comparison, N_SPANxN_CONTOUR, comma-separated; the last is the "
                             "reference (default: %(default)s)")
    args = parser.parse_args(argv)
    grids = [_grid(g) for g in args.grids.split(",")]
    command = "python benchmarks/optimise_default.py"
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
          f"load {os.getloadavg()[0]:.1f}")
    if not args.skip_command:
        print("\noptimise-pressure (default case) in fresh processes:")
        print(f"{'run':<22}{'wall s':>8}{'CPU s':>8}{'setup':>8}{'optimise':>10}{'report':>8}{'solves':>8}")
        runs = command_runs()
        for r in runs:
            print(f"{r['run']:<22}{r['wall_s']:>8.2f}{r['cpu_s']:>8.2f}{r['setup_s']:>8.2f}{r['optimisation_s']:>10.2f}"
                  f"{r['report_s']:>8.2f}{r['forward_solves']:>8d}")
        save_result("optimise_default_command", title="The default case, optimise-pressure in fresh processes",
                    command=f"{command} --skip-grids",
                    columns=["run", "wall time of the process, s", "CPU time of the process, s", "setup, s",
                             "design, s", "report, s", "forward solves"],
                    rows=[[r["run"], round(r["wall_s"], 2), round(r["cpu_s"], 2), round(r["setup_s"], 2), round(r["optimisation_s"], 2),
                           round(r["report_s"], 2), r["forward_solves"]] for r in runs],
                    notes=["The default case (NACA 2412 bay, chord 1 m, ribs 0.25 m apart, 17x64 grid), "
                           "`python -m inverse_design.app.cli --quiet` in a fresh process each: with an empty "
                           "compilation cache, twice with the cache it left, once more so without the figures "
                           "(`--no-figures`), and with the cache off.",
                           "Imports, compilation, the design and the report are all in the wall time; the CPU "
                           "time (user + system) is the process's own, which on a shared machine says more than "
                           "its wall time."])
    if not args.skip_grids:
        rows = grid_runs(grids)
        reference = next(r for r in rows if r["grid"] == "{}x{}".format(*grids[-1]) and r["method"] == "slsqp")
        print(f"\nthe default case on each grid (agreement with {reference['grid']}):")
        print(f"{'grid':<8}{'method':<15}{'pressure Pa':>12}{'rib scale':>11}{'dp/p':>9}{'d rib':>9}"
              f"{'rms':>11}{'min T N/m':>11}{'solves':>7}{'s':>7}  active")
        table = []
        for r in rows:
            dp = r["pressure_pa"] / reference["pressure_pa"] - 1.0
            dr = r["rib_thickness_scale"] - reference["rib_thickness_scale"]
            print(f"{r['grid']:<8}{r['method']:<15}{r['pressure_pa']:>12.1f}{r['rib_thickness_scale']:>11.5f}"
                  f"{dp:>9.2%}{dr:>9.4f}{r['rms_error']:>11.3e}{r['min_tension']:>11.1f}"
                  f"{r['forward_solves']:>7d}{r['optimiser_s']:>7.1f}  {', '.join(r['active']) or 'none'}")
            table.append([r["grid"], r["method"], "yes" if r["success"] else "no", round(r["pressure_pa"], 1),
                          round(r["rib_thickness_scale"], 5), f"{r['rms_error']:.4e}", f"{r['max_error']:.3e}",
                          round(r["min_tension"], 1), r["forward_solves"], round(r["optimiser_s"], 1),
                          ", ".join(r["active"]) or "none"])
        save_result("optimise_default_grids", title="The default case on several grids",
                    command=f"{command} --skip-command --grids {args.grids}",
                    columns=["grid", "method", "success", "pressure, Pa", "rib thickness scale",
                             "bay-average rms, chord", "max error, chord", "least fibre tension, N/m",
                             "forward solves", "design, s", "active limits and bounds"],
                    rows=table,
                    notes=["The default design (pressure 1-100 kPa and rib thickness scale 0.7-1.0 from 10 kPa "
                           "and 1.0, prestrain 2% both ways, bay-average objective, wrinkle-free skin) on each "
                           "grid with SLSQP, and with the penalty method (least_squares) on 17x64 for the "
                           "ratio of forward solves; design time includes compilation.",
                           f"Agreement: the last SLSQP grid ({reference['grid']}) is the reference."])


if __name__ == "__main__":
    main()
