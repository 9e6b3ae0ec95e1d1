"""A light program against LLVM's level 2: the relaxation's first solve (compiling) and later solves, by grid.

`forward_solver.compilation.stored_jit` compiles a ``light`` program's
top-level calls at LLVM's optimisation level 0 (`LIGHT_OPTIONS`): less time
compiling, more running. The relaxation is light on grids of at most
`forward_solver.solvers.relax.LIGHT_RELAX_NODES` nodes. Each row is a fresh
process (no persistent compilation cache) that solves a NACA 2412 bay by
relaxation (`solve_equilibrium(..., method="relax")`, its grid-sequencing
levels included) at 2e4 Pa and 2% prestrain: the first solve, which
compiles, then two later solves at other pressures (a cold start each, no
compilation); ``light`` sets the threshold so that every level of the grid
is light, or none. The XLA fast-compilation flags are on, as in the command.

Run:  PYTHONPATH=. python benchmarks/light_programs.py [--grids 17x64,33x128,65x256]

Writes benchmarks/results/light_programs.json (docs/compilation.md quotes it).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.results import fresh_process_json, print_result, save_result  # noqa: E402

#: Run in a fresh process: one grid, light or not (JSON on stdout).
PROBE = """
import json, sys, time
sys.path.insert(0, {root!r})
from forward_solver.compilation import enable_fast_compilation
enable_fast_compilation()
from forward_solver import Bay, Fabric, Scene, solve_equilibrium
from forward_solver.solvers import relax
from targets import naca
relax.LIGHT_RELAX_NODES = 10**9 if {light!r} else 0
scene = Scene(Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span={ns}, n_contour={nc}), Fabric())
times = []
for k in range(3):
    start = time.perf_counter()
    solution = solve_equilibrium(scene, pressure=2e4 + 100.0 * k, prestrain=(0.02, 0.02), method="relax")
    times.append(time.perf_counter() - start)
    assert solution.converged
print(json.dumps({{"times": times, "height": float(solution.nodes[{ns} // 2, 10, 2])}}))
"""


def run(ns: int, nc: int, light: bool) -> dict:
    return fresh_process_json(PROBE.format(root=str(ROOT), ns=ns, nc=nc, light=light), ROOT)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grids", default="17x64,33x128,65x256")
    args = parser.parse_args()
    rows = []
    for grid in args.grids.split(","):
        ns, nc = (int(n) for n in grid.split("x"))
        full, light = run(ns, nc, False), run(ns, nc, True)
        rows.append([grid, round(full["times"][0], 2), round(light["times"][0], 2),
                     round(min(full["times"][1:]), 3), round(min(light["times"][1:]), 3),
                     f"{abs(full['height'] - light['height']):.1e}"])
    notes = ["fresh process each, no persistent compilation cache; a later solve is the faster of two, a cold "
             "start at another pressure; the last column: the two modes' mid-bay heights apart (m)"]
    path = save_result("light_programs", title="The relaxation compiled light (LLVM level 0) or at level 2, by grid",
                       command=f"PYTHONPATH=. python benchmarks/light_programs.py --grids {args.grids}",
                       columns=["grid", "first_s_level2", "first_s_light", "later_s_level2", "later_s_light",
                                "heights_apart_m"], rows=rows, notes=notes)
    print_result(path, rows, notes)


if __name__ == "__main__":
    main()
