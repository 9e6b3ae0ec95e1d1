"""Grid refinement of the default wing bay: mid-bay bulge and thickness against grid.

Default bay: NACA 2412 ribs, chord 1 m, ribs 0.25 m apart, stiffness
2e5 N/m both ways, Poisson 0.25, prestrain 0.5% both ways, 20 kPa. For each
nested grid it solves to a relative residual of 1e-10 (relaxation with grid
sequencing and half-bay symmetry) and prints the mid-bay maximum outward
displacement (along the mounted surface's normal) and the mid-bay maximum
thickness, with steps, first-call time (compilation included) and the time of
a second, warm solve. The observed order comes from successive differences.
Writes ``benchmarks/results/refinement.json`` (``refinement_<finest>.json`` for another
``--finest``; ``benchmarks/performance_doc.py`` puts it in docs/performance.md).

Usage: python benchmarks/refinement.py [--finest N_SPAN]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.results import save_result  # noqa: E402
from forward_solver import Bay, Fabric, Scene, forces, solve_equilibrium  # noqa: E402
from targets import naca  # noqa: E402


def outward_displacement(bay, nodes, row):
    with jax.enable_x64(True):
        x0 = bay.nominal_nodes()
        area = np.asarray(forces.node_area_vectors(x0, bay.periodic))
    normal = area / np.linalg.norm(area, axis=-1, keepdims=True)
    return np.sum((nodes[row] - x0[row]) * normal[row], axis=-1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--finest", type=int, default=65, help="finest n_span (n_contour = 8 (n_span - 1))")
    args = parser.parse_args()
    af = naca("2412")
    grids = []
    n = 9
    while n <= args.finest:
        grids.append((n, 8 * (n - 1)))
        n = 2 * n - 1
    print(f"machine: {platform.processor() or platform.machine()}, {jax.devices()[0].platform}, "
          f"{os.cpu_count()} cores")
    print(f"{'grid':>9} {'steps':>6} {'first s':>8} {'warm s':>7} {'residual':>9} "
          f"{'bulge m':>12} {'thickness m':>12}")
    rows, table = [], []
    for n_span, n_contour in grids:
        bay = Bay.from_airfoil(af, chord=1.0, rib_spacing=0.25, n_span=n_span, n_contour=n_contour)
        scene = Scene(bay, Fabric())
        t = time.perf_counter()
        solve_equilibrium(scene, 2e4, (0.005, 0.005), rtol=1e-10)
        first = time.perf_counter() - t
        sol = solve_equilibrium(scene, 2e4, (0.005, 0.005), rtol=1e-10)
        mid = n_span // 2
        bulge = outward_displacement(bay, sol.nodes, mid).max()
        thickness = np.ptp(sol.section(0.5)[:, 1])
        rows.append((bulge, thickness))
        table.append([f"{n_span}x{n_contour}", sol.steps, round(first, 2), round(sol.wall_time, 3),
                      f"{sol.residual:.1e}", f"{bulge:.7f}", f"{thickness:.7f}"])
        print(f"{n_span:>3}x{n_contour:<5} {sol.steps:>6} {first:>8.2f} {sol.wall_time:>7.3f} "
              f"{sol.residual:>9.1e} {bulge:>12.7f} {thickness:>12.7f}")
    rows = np.array(rows)
    notes = ["Default bay (NACA 2412 ribs, chord 1 m, ribs 0.25 m apart, 2e5 N/m both ways, prestrain 0.5% both "
             "ways, 20 kPa), each grid solved to a relative residual of 1e-10; bulge: the largest outward "
             "displacement at mid-bay along the mounted surface's normal; first-call time includes compilation."]
    for name, column in zip(("bulge", "thickness"), rows.T):
        diffs = np.abs(np.diff(column))
        orders = np.log2(diffs[:-1] / diffs[1:])
        print(f"{name}: successive differences {np.array2string(diffs, precision=2)}, "
              f"observed orders {np.array2string(orders, precision=2)}")
        notes.append(f"{name}: successive differences {', '.join(f'{d:.2e}' for d in diffs)} m, observed orders "
                     f"{', '.join(f'{o:.2f}' for o in orders)}.")
    save_result("refinement" if args.finest == 65 else f"refinement_{args.finest}",
                title="Grid refinement of the default bay",
                command="python benchmarks/refinement.py" + ("" if args.finest == 65 else f" --finest {args.finest}"),
                columns=["grid", "steps", "first call, s", "warm solve, s", "residual", "mid-bay bulge, m",
                         "mid-bay thickness, m"],
                rows=table, notes=notes)


if __name__ == "__main__":
    main()
