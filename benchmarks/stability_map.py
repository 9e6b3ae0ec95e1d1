"""Stability map of the paper's explicit scheme: Courant coefficient against damping.

For each Courant coefficient ``alpha_k`` (eq. 16) and fabric viscosity ``eta``
(eq. 10), with a fixed aerodynamic damping ``nu_n`` (eq. 11), it pressurises
a bay with `forward_solver.simulate` (physical mass, pressure ramp) until rest
or the step cap, and records the result code and the steps taken. The time
step already shortens itself for the damping terms (see
`forward_solver.solvers.explicit.stable_time_step`), so the map shows where the
Courant coefficient alone breaks the scheme and how damping changes the
number of steps to rest.

Writes ``benchmarks/results/stability_map.png``, prints the table and saves it as
``benchmarks/results/stability_map_<bay>.json`` (``benchmarks/performance_doc.py`` puts it in
docs/performance.md).

Usage: python benchmarks/stability_map.py [--bay panel|wing] [--aero 0.05] [--max-steps 60000]
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.results import save_result  # noqa: E402
from forward_solver import Bay, Fabric, PressureRamp, Result, Scene, simulate  # noqa: E402
from targets import naca  # noqa: E402

COURANT = (0.2, 0.4, 0.6, 0.8, 0.9, 1.0, 1.2, 1.5)
VISCOSITY = (0.0, 1.0, 5.0, 20.0, 50.0)  # N*s/m
COLOURS = {Result.converged: "#2ca02c", Result.max_steps_reached: "#ffbf00",
           Result.diverged: "#d62728", Result.nonfinite: "#7f0000"}


def make_bay(kind: str) -> Bay:
    if kind == "wing":
        return Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=9, n_contour=32)
    return Bay.flat_panel(width=0.25, length=1.0, n_span=9, n_contour=33)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bay", choices=("panel", "wing"), default="panel")
    parser.add_argument("--aero", type=float, default=0.05, help="aerodynamic damping nu_n, s/m")
    parser.add_argument("--pressure", type=float, default=2e4, help="Pa")
    parser.add_argument("--max-steps", type=int, default=60_000)
    parser.add_argument("--rtol", type=float, default=1e-6)
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results")
    args = parser.parse_args()
    bay = make_bay(args.bay)
    print(f"machine: {platform.machine()}, bay: {args.bay} {bay.n_span}x{bay.n_contour}, "
          f"{args.pressure:g} Pa, nu_n {args.aero} s/m, rtol {args.rtol:g}, cap {args.max_steps} steps")
    print(f"{'courant':>8} {'eta':>6} {'result':>18} {'steps':>8} {'dt s':>10} {'wall s':>7}")
    codes = np.zeros((len(VISCOSITY), len(COURANT)), dtype=int)
    steps = np.zeros_like(codes)
    table = []
    for a, viscosity in enumerate(VISCOSITY):
        scene = Scene(bay, Fabric(viscosity=viscosity), aerodynamic_damping=args.aero)
        for b, courant in enumerate(COURANT):
            start = time.perf_counter()
            sol = simulate(scene, PressureRamp(args.pressure, 0.002), 0.005, courant=courant,
                           rtol=args.rtol, max_steps=args.max_steps, throw=False)
            codes[a, b], steps[a, b] = int(sol.result), sol.steps
            table.append([courant, viscosity, sol.result.name, sol.steps, f"{sol.extra['dt']:.2e}",
                          round(time.perf_counter() - start, 2)])
            print(f"{courant:>8.2f} {viscosity:>6.1f} {sol.result.name:>18} {sol.steps:>8} "
                  f"{sol.extra['dt']:>10.2e} {time.perf_counter() - start:>7.2f}", flush=True)

    fig, ax = plt.subplots(figsize=(8, 4.2))
    for a in range(len(VISCOSITY)):
        for b in range(len(COURANT)):
            code = Result(codes[a, b])
            ax.add_patch(plt.Rectangle((b - 0.5, a - 0.5), 1, 1, color=COLOURS[code]))
            label = f"{steps[a, b] / 1000:.0f}k" if code != Result.nonfinite else "NaN"
            ax.text(b, a, label, ha="center", va="center", fontsize=8,
                    color="white" if code in (Result.diverged, Result.nonfinite) else "black")
    ax.set_xlim(-0.5, len(COURANT) - 0.5)
    ax.set_ylim(-0.5, len(VISCOSITY) - 0.5)
    ax.set_xticks(range(len(COURANT)), [f"{c:g}" for c in COURANT])
    ax.set_yticks(range(len(VISCOSITY)), [f"{v:g}" for v in VISCOSITY])
    ax.set_xlabel("Courant coefficient alpha_k (eq. 16)")
    ax.set_ylabel("fabric viscosity eta (N s/m)")
    ax.set_title(f"Paper's scheme on the {args.bay} bay ({bay.n_span}x{bay.n_contour}), "
                 f"{args.pressure / 1e3:g} kPa, nu_n = {args.aero} s/m: steps to rest")
    handles = [plt.Rectangle((0, 0), 1, 1, color=c) for c in COLOURS.values()]
    ax.legend(handles, [r.name for r in COLOURS], loc="upper center", bbox_to_anchor=(0.5, -0.16),
              ncol=4, frameon=False, fontsize=8)
    fig.tight_layout()
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "stability_map.png"
    fig.savefig(path, dpi=130)
    print(f"wrote {path}")
    command = f"python benchmarks/stability_map.py --bay {args.bay}"
    for flag, value, default in (("--aero", args.aero, 0.05), ("--pressure", args.pressure, 2e4),
                                 ("--max-steps", args.max_steps, 60_000), ("--rtol", args.rtol, 1e-6)):
        command += "" if value == default else f" {flag} {value:g}"
    save_result(f"stability_map_{args.bay}", title=f"Stability of the paper's explicit scheme, {args.bay} bay",
                command=command,
                columns=["Courant coefficient", "viscosity, N s/m", "result", "steps", "time step, s", "wall time, s"],
                rows=table,
                notes=[f"{args.bay} bay {bay.n_span}x{bay.n_contour}, {args.pressure:g} Pa ramped over 2 ms, "
                       f"prestrain 0.5%, aerodynamic damping nu_n = {args.aero:g} s/m (eq. 11), run to rest at "
                       f"rtol {args.rtol:g} or {args.max_steps} steps with simulate (eq. 14-17)."])


if __name__ == "__main__":
    main()
