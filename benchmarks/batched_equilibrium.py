"""Equilibria per second against batch size: one compiled `jax.vmap` call against a loop of eager solves.

Default bay (as benchmarks/refinement.py): NACA 2412 ribs, chord 1 m, ribs
0.25 m apart, stiffness 2e5 N/m both ways, Poisson 0.25, prestrain 0.5% both
ways. A batch of ``B`` pressures spread evenly over 5-50 kPa is solved to a
relative residual of 1e-8 two ways:

* **vmap**: ``jax.jit(jax.vmap(solve))`` of `solve_equilibrium` with
  ``throw=False`` (the pure-JAX relaxation of `forward_solver.solvers.relax.traced_solution`:
  mounted start, no grid sequencing); timed on a second call with pressures
  1% higher (the first call compiles; compile time is printed apart);
* **loop**: a Python loop of eager `solve_equilibrium` calls (grid
  sequencing, half bay), after one warm-up solve.

Equilibria per second is ``B`` over the wall time (`time.perf_counter`,
results blocked on). A vmapped batch runs until its slowest member stops, so
"max steps" is printed beside it. When JAX sees more than one device the
batch is sharded over a 1-D mesh (``NamedSharding``) where ``B`` divides
evenly; on a CPU try it with
``XLA_FLAGS=--xla_force_host_platform_device_count=2``.

``--krylov`` also prints the BiCGStab matrix-vector products (two per
iteration) that the implicit derivative's matrix-free solve (`krylov`) needs
to reach 1e-10 relative on 9x32, 17x64 and 17x128, for the pressure tangent's
right-hand side and a random one, with block Jacobi and with the scalar
Gershgorin (`forces.node_stiffness`) preconditioner.

A relaxation step is already vectorised over the nodes, so on a CPU
batching adds little; the compiled batch is for accelerators and for
composing with ``jax.grad``. Writes ``benchmarks/results/batched_equilibrium.json``
(``batched_equilibrium_quick.json`` with ``--quick``; ``--krylov``:
``krylov_products.json``) for ``benchmarks/performance_doc.py``.

Usage: python benchmarks/batched_equilibrium.py [--quick] [--krylov]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.sparse.linalg import bicgstab
from jax.sharding import Mesh, NamedSharding, PartitionSpec

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.results import save_result  # noqa: E402
from forward_solver import Bay, Fabric, Parameters, Scene, forces, solve_equilibrium
from forward_solver.derivatives.implicit import ImplicitAdjoint
from forward_solver.derivatives.krylov import KRYLOV_RTOL, jacobian_operator
from targets import naca

RTOL = 1e-8
THETA = Parameters(pressure=2e4, prestrain_span=0.005, prestrain_chord=0.005)


def default_scene(n_span: int, n_contour: int) -> Scene:
    bay = Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=n_span,
                           n_contour=n_contour)
    return Scene(bay, Fabric())


def batched(scene: Scene, sizes, repeat_eager: bool = True):
    """Rows of (B, vmap s, compile s, max steps, loop s) for each batch size."""
    devices = jax.devices()
    mesh = Mesh(np.array(devices), ("batch",)) if len(devices) > 1 else None

    def one(pressure):
        return solve_equilibrium(scene, THETA.replace(pressure=pressure), rtol=RTOL, throw=False)

    solve_batch = jax.jit(jax.vmap(one))
    solve_equilibrium(scene, THETA, rtol=RTOL)  # warm-up: the eager path compiles
    rows = []
    for size in sizes:
        pressures = np.linspace(5e3, 5e4, size)
        sharded = mesh is not None and size % len(devices) == 0

        def put(values):
            values = jnp.asarray(values)
            return jax.device_put(values, NamedSharding(mesh, PartitionSpec("batch"))) if sharded else values

        start = time.perf_counter()
        jax.block_until_ready(solve_batch(put(pressures)))
        first = time.perf_counter() - start
        start = time.perf_counter()
        sols = jax.block_until_ready(solve_batch(put(1.01 * pressures)))
        warm = time.perf_counter() - start
        sols.raise_if_failed()
        start = time.perf_counter()
        for p in 1.01 * pressures:
            solve_equilibrium(scene, THETA.replace(pressure=float(p)), rtol=RTOL)
        loop = time.perf_counter() - start
        rows.append((size, warm, first - warm, int(np.max(np.asarray(sols.steps))), loop, sharded))
        print(f"  {size:>3} {size / warm:>10.2f} {size / loop:>10.2f} {loop / warm:>7.2f} "
              f"{int(np.max(np.asarray(sols.steps))):>9} {first - warm:>9.1f}"
              f"{'  sharded' if sharded else ''}", flush=True)
    return rows


def krylov_products(n_span: int, n_contour: int) -> dict:
    """Matrix-vector products BiCGStab needs to reach `KRYLOV_RTOL` at the default bay's equilibrium."""
    scene = default_scene(n_span, n_contour)
    sol = solve_equilibrium(scene, THETA, rtol=1e-12, method="relax+newton")
    with jax.enable_x64(True):
        params = scene.params(THETA.resolved(scene.fabric))
        geometry = jax.tree_util.tree_map(jnp.asarray, scene.bay.geometry())
        physics = forces.static_physics(scene.physics(dynamic=False))
        x = jnp.asarray(sol.nodes)
        matvec, block_jacobi, _ = jacobian_operator(x, geometry, params, physics)
        ref = forces.prepare(geometry, params, physics)
        stiffness = forces.node_stiffness(x, ref, params, physics)[..., None]
        free = ref.free

        def scalar_jacobi(v):
            return free * (-v / stiffness) + (1.0 - free) * v

        dpressure = jax.tree_util.tree_map(jnp.zeros_like, params)._replace(pressure=jnp.float64(1.0))
        # b = J dx for the pressure tangent dx: the right-hand side the derivative solves.
        rhs = matvec(ImplicitAdjoint("iterative").at(x, geometry, params, physics).tangent(dpressure) * free)
        random = jnp.asarray(np.random.default_rng(0).normal(size=x.shape)) * free
        counts = {}
        for name, b in (("pressure", rhs), ("random", random)):
            for label, precondition in (("block", block_jacobi), ("scalar", scalar_jacobi)):
                calls = [0]

                def counted(v, calls=calls):
                    jax.debug.callback(lambda: calls.__setitem__(0, calls[0] + 1))
                    return matvec(v)

                out, _ = bicgstab(counted, b, tol=KRYLOV_RTOL, atol=0.0, maxiter=20_000,
                                  M=precondition)
                achieved = float(jnp.linalg.norm(matvec(out) - b) / jnp.linalg.norm(b))
                counts[(name, label)] = (calls[0], achieved)
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="9x32 only, batches 1-8")
    parser.add_argument("--krylov", action="store_true", help="also count the Krylov products")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)  # the solver computes in float64 (this script only)
    grids = [(9, 32)] if args.quick else [(17, 64), (9, 32)]
    sizes = (1, 2, 4, 8) if args.quick else (1, 2, 4, 8, 16, 32)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; "
          f"JAX {jax.__version__}, devices {jax.devices()}")
    print(f"default bay, pressures 5-50 kPa, rtol {RTOL:g}; eq/s = batch size / wall time")
    table = []
    for n_span, n_contour in grids:
        print(f"\n{n_span}x{n_contour}:\n  {'B':>3} {'vmap eq/s':>10} {'loop eq/s':>10} {'ratio':>7} "
              f"{'max steps':>9} {'compile s':>9}")
        for size, warm, compile_s, steps, loop, sharded in batched(default_scene(n_span, n_contour), sizes):
            table.append([f"{n_span}x{n_contour}", size, round(size / warm, 2), round(size / loop, 2),
                          round(loop / warm, 2), steps, round(compile_s, 1), "yes" if sharded else "no"])
    save_result("batched_equilibrium_quick" if args.quick else "batched_equilibrium",
                title="Equilibria per second: one jit(vmap) batch against a loop of solves",
                command="python benchmarks/batched_equilibrium.py" + (" --quick" if args.quick else ""),
                columns=["grid", "batch size", "vmap, equilibria/s", "loop, equilibria/s", "loop time / vmap time",
                         "max steps in the batch", "vmap compile, s", "sharded"],
                rows=table,
                notes=[f"Default bay, a batch of pressures spread over 5-50 kPa, rtol {RTOL:g}; vmap timed on a "
                       "second call at 1% higher pressures, the loop after a warm-up solve; devices "
                       f"{', '.join(str(d) for d in jax.devices())}."])
    if args.krylov:
        print(f"\nBiCGStab matrix-vector products to {KRYLOV_RTOL:g} relative (achieved residual):")
        krylov = []
        for n_span, n_contour in [(9, 32), (17, 64), (17, 128)]:
            counts = krylov_products(n_span, n_contour)
            cells = "  ".join(f"{rhs}/{pre} {n} ({r:.1e})" for (rhs, pre), (n, r) in counts.items())
            print(f"  {n_span}x{n_contour}: {cells}", flush=True)
            krylov += [[f"{n_span}x{n_contour}", rhs, pre, n, f"{r:.1e}"] for (rhs, pre), (n, r) in counts.items()]
        save_result("krylov_products", title="Matrix-vector products of the matrix-free implicit derivative",
                    command="python benchmarks/batched_equilibrium.py --quick --krylov",
                    columns=["grid", "right-hand side", "preconditioner", "products", "achieved residual"],
                    rows=krylov,
                    notes=[f"BiCGStab (two products per iteration) to {KRYLOV_RTOL:g} relative on the default bay."])


if __name__ == "__main__":
    main()
