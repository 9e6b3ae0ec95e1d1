"""A whole wing: `solve_wing`'s one ``jit(vmap)`` call against loops over its bays, and a 3-bay design.

Wings of N = 2, 4, 8 tapered bays (NACA 2412 ribs, chords linearly from
1.0 m at the root to 0.5 m at the tip, ribs 0.25 m apart; fabric 2e5 N/m
both ways, Poisson 0.25; 10 kPa, prestrain 2% both ways) on 9x32 and 17x64
grids, every bay solved to a relative residual of 1e-10 three ways:

* **batch**: `forward_solver.solve_wing`: every bay in one compiled
  ``jax.jit(jax.vmap(relaxation))`` call (the batch runs until its slowest
  bay stops);
* **jit loop**: a Python loop calling the same compiled relaxation once per
  bay (``wing.batched_equilibrium`` on a batch of one): the fair comparison
  for the batching itself (same code, same start, same stopping test);
* **eager loop**: a Python loop of `forward_solver.solve_equilibrium` per
  bay (the public single-bay API: grid sequencing; tapered bays are not
  symmetric, so no half bay).

Each is timed (``time.perf_counter``, results blocked on) as the median of
``--repeats`` calls after a warm-up call that compiles (compile time is
reported apart for the batch); the ratios are taken in the same run.

``--design`` also runs `inverse_design.optimise_wing` on the built-in
3-bay case (`inverse_design/cases/wing_taper.toml`: chords 1.0, 0.85, 0.7,
0.6 m, ribs 0.25 m apart, 17x64 per bay, pressure from 10 kPa in 1-100 kPa,
wrinkle-free skin) and reports solves, wall time (compilation included),
pressure and errors.

Writes ``benchmarks/results/wing_batch.json`` (``wing_batch_quick.json`` with ``--quick``) and,
with ``--design``, ``wing_batch_design.json``, and prints a table; ``benchmarks/performance_doc.py``
puts them in docs/performance.md.

``--strategies`` times `forward_solver.solve_bays`'s two strategies on
tapered wings of 3 and 8 bays at 17x64 (same wings and tolerance): "loop"
(per-bay `solve_equilibrium`: grid sequencing, the default on a CPU) and
"batch" (the one ``jit(vmap)`` relaxation, the default on an accelerator),
cold (first call in the run, compilation included) and warm (median of
``--repeats``); writes ``benchmarks/results/wing_strategies.json``. On a CPU the loop is
faster warm, which is why "auto" picks it there.

``--rib-shapes`` (with ``--design``) designs the same wing again with a
rib shape per rib (``variables=("pressure", "rib_shape")``, 4 Bernstein
terms per surface, the default rib limits).

Usage: python benchmarks/wing_batch.py [--quick] [--repeats 3] [--design [--rib-shapes]] [--no-batch] [--strategies]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from forward_solver import Fabric, Parameters, Scene, forces, solve_equilibrium
from forward_solver.precision import float64_scope
from forward_solver.solvers.bays import stack_trees, batched_equilibrium, solve_bays, solve_wing
from forward_solver.solvers.relax import RELAX_CHUNK
from forward_solver import Wing
from targets import naca

RTOL = 1e-10
MAX_STEPS = 200_000
PARAMETERS = Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.02)
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.results import save_result  # noqa: E402


def tapered_wing(n_bays: int) -> Wing:
    af = naca("2412")
    return Wing(airfoils=(af,) * (n_bays + 1), chords=tuple(np.linspace(1.0, 0.5, n_bays + 1)),
                stations=tuple(0.25 * np.arange(n_bays + 1)))


def _median_time(run, repeats: int) -> tuple[float, float]:
    """``(first call s, median of the next ``repeats`` s)``."""
    t = time.perf_counter()
    run()
    first = time.perf_counter() - t
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        run()
        times.append(time.perf_counter() - t)
    return first, statistics.median(times)


def batch(wing, fabric, grid):
    sol = solve_wing(wing, fabric, PARAMETERS, rtol=RTOL, max_steps=MAX_STEPS, strategy="batch", **grid)
    jax.block_until_ready(sol.nodes)
    assert sol.converged, sol.result
    return sol


def jit_loop(wing, fabric, grid):
    """The compiled relaxation of `solve_wing`, called on one bay at a time."""
    bays = wing.bays(**grid)
    scene = Scene(bays[0], fabric)
    physics = forces.static_physics(scene.physics(dynamic=False))
    steps = []
    with float64_scope():
        params = scene.params(PARAMETERS.resolved(fabric))
        for bay in bays:
            geometry = stack_trees([bay.geometry()])
            bound = jnp.asarray([bay.divergence_bound], jnp.float64)
            zeros = jnp.zeros((1, *bay.shape, 3), jnp.float64)
            nodes, result, _, s, _ = batched_equilibrium(geometry, bound, zeros, None, None, None, params,
                                                       jnp.asarray(RTOL, jnp.float64), physics,
                                                       -(-MAX_STEPS // RELAX_CHUNK))
            jax.block_until_ready(nodes)
            assert int(result[0]) == 0
            steps.append(int(s[0]))
    return steps


def eager_loop(wing, fabric, grid):
    steps = []
    for bay in wing.bays(**grid):
        sol = solve_equilibrium(Scene(bay, fabric), PARAMETERS, rtol=RTOL, max_steps=MAX_STEPS)
        steps.append(int(sol.steps))
    return steps


def strategies(fabric, repeats: int, counts=(3, 8), grid=(17, 64)) -> list:
    """`solve_bays` "loop" against "batch" on tapered wings: first call (cold) and median warm call."""
    rows = []
    for n in counts:
        scenes = tapered_wing(n).scenes(fabric, *grid)
        row = {"grid": list(grid), "bays": n}
        for strategy in ("loop", "batch"):
            def run():
                sol = solve_bays(scenes, PARAMETERS, rtol=RTOL, max_steps=MAX_STEPS, strategy=strategy)
                jax.block_until_ready(sol.nodes)
                assert sol.converged, sol.result
                row[f"{strategy}_steps"] = np.asarray(sol.steps).tolist()
            row[f"{strategy}_cold_s"], row[f"{strategy}_warm_s"] = _median_time(run, repeats)
        row["batch_over_loop_cold"] = row["batch_cold_s"] / row["loop_cold_s"]
        row["batch_over_loop_warm"] = row["batch_warm_s"] / row["loop_warm_s"]
        print(f"solve_bays {grid[0]}x{grid[1]} {n} bays: loop cold {row['loop_cold_s']:.2f} s, warm "
              f"{row['loop_warm_s']:.2f} s; batch cold {row['batch_cold_s']:.2f} s, warm {row['batch_warm_s']:.2f} s; "
              f"batch/loop {row['batch_over_loop_cold']:.2f} cold, {row['batch_over_loop_warm']:.2f} warm",
              file=sys.stderr)
        rows.append(row)
    return rows


def design_case(fabric, variables=("pressure",)) -> dict:
    from inverse_design.constraints import Constraints
    from inverse_design import DesignRequest, Layout, Limits, optimise_wing
    from inverse_design.app.case import Case
    from inverse_design.app.case_file import EXAMPLE_CASE

    case = Case.from_arguments(["--config", str(EXAMPLE_CASE)])
    values = vars(case.options)
    af = naca("2412")
    wing = Wing(airfoils=(af,) * len(case.ribs), chords=tuple(r.chord for r in case.ribs),
                stations=tuple(r.station for r in case.ribs))
    t = time.perf_counter()
    res = optimise_wing(wing, fabric, None, DesignRequest(
        variables, {"pressure": values["pressure"], "prestrain_span": values["prestrain_span"],
                    "prestrain_chord": values["prestrain_chord"]},
        {"pressure": tuple(values["pressure_bounds"])}, objective=values["objective"],
        method="slsqp", limits=Limits(tension=Constraints()),  # design_solves.py compares the methods
        layout=Layout(n_span=values["n_span"], n_contour=values["n_contour"])))
    wall = time.perf_counter() - t
    bays = res.per_bay
    return {"case": str(EXAMPLE_CASE.name), "variables": list(variables),
            "grid": [values["n_span"], values["n_contour"]],
            "chords_m": list(wing.chords), "stations_m": list(wing.stations),
            "method": res.method, "success": res.success, "message": res.message, "pressure_pa": float(res.pressure),
            "solves": res.solves, "iterations": len(res.history), "wall_time_s": wall,
            "rms_before": res.initial_rms_error, "rms_after": res.rms_error,
            "bay_rms_before": bays.initial_rms_error.tolist(), "bay_rms_after": bays.rms_error.tolist(),
            "bay_max_after": bays.max_error.tolist(), "bay_results": list(res.bay_results),
            "bay_min_tension": bays.min_tension.tolist(), "active": res.limits.active,
            "rib_shapes": None if bays.rib_shapes is None else bays.rib_shapes.tolist(), "rib_limits": bays.rib_limits}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="9x32 only, 2 and 4 bays, one repeat")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--design", action="store_true", help="also time the 3-bay design at 17x64")
    parser.add_argument("--rib-shapes", action="store_true",
                        help="with --design, also design the same wing with a rib shape per rib (4 terms per surface)")
    parser.add_argument("--no-batch", action="store_true", help="skip the batch timings")
    parser.add_argument("--strategies", action="store_true",
                        help="only solve_bays' loop against batch strategies, 3 and 8 bays at 17x64")
    args = parser.parse_args(argv)
    if args.strategies:
        rows = strategies(Fabric(), args.repeats)
        save_result("wing_strategies", title="solve_bays: the loop of bays against the jit(vmap) batch",
                    command=f"python benchmarks/wing_batch.py --strategies --repeats {args.repeats}",
                    columns=["grid", "bays", "loop cold, s", "loop warm, s", "batch cold, s", "batch warm, s",
                             "batch / loop warm"],
                    rows=[["{}x{}".format(*r["grid"]), r["bays"], round(r["loop_cold_s"], 3), round(r["loop_warm_s"], 3),
                           round(r["batch_cold_s"], 3), round(r["batch_warm_s"], 3),
                           round(r["batch_over_loop_warm"], 2)] for r in rows],
                    notes=[f"Tapered wings, every bay to a relative residual of {RTOL:g}; cold: the first call in "
                           f"the run, compilation included; warm: median of {args.repeats}; devices "
                           f"{', '.join(str(d) for d in jax.devices())}."])
        return 0
    grids = [(9, 32)] if args.quick else [(9, 32), (17, 64)]
    counts = [2, 4] if args.quick else [2, 4, 8]
    repeats = 1 if args.quick else args.repeats
    fabric = Fabric()
    rows = []
    for n_span, n_contour in ([] if args.no_batch else grids):
        grid = dict(n_span=n_span, n_contour=n_contour)
        for n in counts:
            wing = tapered_wing(n)
            holder = {}
            compile_and_run, t_batch = _median_time(lambda: holder.update(sol=batch(wing, fabric, grid)), repeats)
            _, t_jit = _median_time(lambda: holder.update(jit=jit_loop(wing, fabric, grid)), repeats)
            _, t_eager = _median_time(lambda: holder.update(eager=eager_loop(wing, fabric, grid)), repeats)
            row = {"grid": [n_span, n_contour], "bays": n, "batch_s": t_batch, "jit_loop_s": t_jit,
                   "eager_loop_s": t_eager, "batch_first_call_s": compile_and_run,
                   "batch_steps": np.asarray(holder["sol"].steps).tolist(), "jit_loop_steps": holder["jit"],
                   "eager_loop_steps": holder["eager"],
                   "jit_loop_over_batch": t_jit / t_batch, "eager_loop_over_batch": t_eager / t_batch}
            rows.append(row)
            print(f"{n_span}x{n_contour} {n} bays: batch {t_batch:.3f} s, jit loop {t_jit:.3f} s "
                  f"({row['jit_loop_over_batch']:.2f}x), eager loop {t_eager:.3f} s "
                  f"({row['eager_loop_over_batch']:.2f}x)", file=sys.stderr)
    designs = []
    if args.design:
        designs.append(design_case(fabric))
        if args.rib_shapes:
            designs.append(design_case(fabric, ("pressure", "rib_shape")))
    if rows:
        save_result("wing_batch_quick" if args.quick else "wing_batch",
                    title="N bays: one jit(vmap) batch against a loop of bays" + (" (quick run)" if args.quick else ""),
                    command="python benchmarks/wing_batch.py" + (" --quick" if args.quick else f" --repeats {repeats}"),
                    columns=["grid", "bays", "batch, s", "jit loop, s", "eager loop, s", "jit loop / batch",
                             "eager loop / batch", "steps: batch (slowest bay), jit loop (sum), eager loop (sum)"],
                    rows=[["{}x{}".format(*r["grid"]), r["bays"], round(r["batch_s"], 3), round(r["jit_loop_s"], 3),
                           round(r["eager_loop_s"], 3), round(r["jit_loop_over_batch"], 2),
                           round(r["eager_loop_over_batch"], 2),
                           f"{max(r['batch_steps'])}, {sum(r['jit_loop_steps'])}, {sum(r['eager_loop_steps'])}"]
                          for r in rows],
                    notes=[f"Tapered NACA 2412 wings, every bay to a relative residual of {RTOL:g}; median of "
                           f"{repeats} calls after a compiling call; ratios above 1: the batch is faster. "
                           "\"jit loop\" calls the same compiled relaxation once per bay, \"eager loop\" calls "
                           f"solve_equilibrium per bay; devices {', '.join(str(d) for d in jax.devices())}."])
    if designs:
        save_result("wing_batch_design", title="The built-in 3-bay wing designed with SLSQP",
                    command="python benchmarks/wing_batch.py --no-batch --design"
                            + (" --rib-shapes" if args.rib_shapes else ""),
                    columns=["variables", "result", "pressure, Pa", "wing solves", "wall time, s",
                             "wing rms before -> after", "bay rms after, root to tip", "bay min tension, N/m"],
                    rows=[[", ".join(d["variables"]), "success" if d["success"] else d["message"][:80],
                           round(d["pressure_pa"]), d["solves"], round(d["wall_time_s"], 1),
                           f"{d['rms_before']:.3e} -> {d['rms_after']:.3e}",
                           ", ".join(f"{v:.2e}" for v in d["bay_rms_after"]),
                           ", ".join(f"{v:.3g}" for v in d["bay_min_tension"])] for d in designs],
                    notes=["inverse_design/cases/wing_taper.toml (chords 1.0/0.85/0.7/0.6 m, ribs 0.25 m apart, "
                           "17x64 per bay, start 10 kPa, bounds 1-100 kPa, prestrain 2% fixed, wrinkle-free, "
                           "average objective), method slsqp; wall time includes compilation; errors in fractions "
                           "of the local chord."])
    print(f"{'grid':>6} {'bays':>4} {'batch s':>8} {'jit loop s':>10} {'eager loop s':>12} "
          f"{'jit/batch':>9} {'eager/batch':>11}  steps (batch max, jit loop sum, eager sum)")
    for r in rows:
        print(f"{r['grid'][0]:>3}x{r['grid'][1]:<3} {r['bays']:>4} {r['batch_s']:>8.3f} {r['jit_loop_s']:>10.3f} "
              f"{r['eager_loop_s']:>12.3f} {r['jit_loop_over_batch']:>9.2f} {r['eager_loop_over_batch']:>11.2f}  "
              f"{max(r['batch_steps'])}, {sum(r['jit_loop_steps'])}, {sum(r['eager_loop_steps'])}")
    for design in designs:
        print(f"design {design['variables']} {design['case']} ({design['grid'][0]}x{design['grid'][1]}, 3 bays): "
              f"{'success' if design['success'] else 'FAILED'}, {design['pressure_pa']:.6g} Pa, "
              f"{design['solves']} wing solves, {design['wall_time_s']:.1f} s; rms {design['rms_before']:.3e} -> "
              f"{design['rms_after']:.3e}; bays {design['bay_results']}; active {design['active']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
