"""The bays of one grid in one program, or one program per bay: a Newton iteration's arithmetic on the CPU.

At the equilibrium of the built-in 40-cell wing (``inverse_design/cases/wing_40_cells.toml``: 40 bays
of 17x64, 10 kPa, 2% prestrain both ways, relax+newton to 1e-8), the work of one Newton iteration of
every bay, timed two ways in one run:

* **per bay**: one compiled call per bay (``jax.jit``), as the loop strategy runs them
  (`forward_solver.solvers.bays.Loop`);
* **one program**: the same function ``jax.jit(jax.vmap(...))`` over the 40 stacked bays.

The pieces: the static residual (`forward_solver.forces.residual`), and the residual with the
Jacobian's structural non-zeros from one ``vmap`` of ``jvp`` over the colour seeds of the
sparsity pattern (`forward_solver.solvers.jacobian`'s colouring: the same code both ways, written
here). Then what stays on the host either way, since SciPy has no batched sparse LU: SuperLU
(`scipy.sparse.linalg.splu`, the solver's column ordering) of every bay's Jacobian and 29
back-solves with each (the compressed tangents of a design with a cut field per bay and a shape
per rib). Each piece: the median of ``--repeats`` timings of the 40 bays after a warm-up call (so
compilation is excluded), results blocked on; the two ways agree to rounding (checked).

Run:
    PYTHONPATH=. python benchmarks/bays_one_program.py [--repeats 7]

Writes ``benchmarks/results/bays_one_program.json``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.results import print_result, save_result  # noqa: E402

CASE = ROOT / "inverse_design" / "cases" / "wing_40_cells.toml"
TANGENTS = 29


def _median_ms(function, repeats: int) -> float:
    import jax

    jax.block_until_ready(function())
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(function())
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)

    import jax
    import jax.numpy as jnp
    import numpy as np
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from forward_solver import forces as fk
    from forward_solver import solve_wing
    from forward_solver.programs import prepare_compiled
    from forward_solver.solvers.jacobian import PERMC_SPEC, sparsity_pattern
    from inverse_design.app.case import Case

    case = Case.from_arguments(["--config", str(CASE)])
    n_span, n_contour = case.layout.n_span, case.layout.n_contour
    wing = solve_wing(case.wing, case.fabric, 1e4, (0.02, 0.02), n_span=n_span, n_contour=n_contour,
                      method="relax+newton", throw=True)
    with jax.enable_x64(True):
        physics = fk.static_physics(wing.scenes[0].physics(dynamic=False))
        params = [scene.params(wing.parameters) for scene in wing.scenes]
        refs = [prepare_compiled(scene.bay.geometry(), p, physics) for scene, p in zip(wing.scenes, params)]
        nodes = [jnp.asarray(x, jnp.float64) for x in wing.nodes]
        pattern = sparsity_pattern(refs[0], physics.periodic)
        colours, gather_colour, gather_row = (jnp.asarray(pattern.colours), jnp.asarray(pattern.gather_colour),
                                              jnp.asarray(pattern.gather_row))

        def residual(x, ref, p):
            return fk.residual(x, ref, p, physics)

        def jacobian_values(x, ref, p):
            free = jnp.broadcast_to(ref.free, x.shape).reshape(-1)
            seeds = (colours[None, :] == jnp.arange(pattern.n_colours)[:, None]).astype(x.dtype) * free

            def column_group(seed):
                return jax.jvp(lambda flat: residual(flat.reshape(x.shape), ref, p).reshape(-1),
                               (x.reshape(-1),), (seed,))

            r, compressed = jax.vmap(column_group, out_axes=(None, 0))(seeds)
            return r, compressed[gather_colour, gather_row]

        def stack(trees):
            return jax.tree_util.tree_map(lambda *leaves: jnp.stack(leaves), *trees)

        stacked = (jnp.stack(nodes), stack(refs), stack(params))
        rows, notes = [], []
        for name, function in (("static residual", residual), ("residual and Jacobian values", jacobian_values)):
            one = jax.jit(function)
            every = jax.jit(jax.vmap(function))
            per_bay = _median_ms(lambda: [one(x, r, p) for x, r, p in zip(nodes, refs, params)], args.repeats)
            together = _median_ms(lambda: every(*stacked), args.repeats)
            apart = [one(x, r, p) for x, r, p in zip(nodes, refs, params)]
            joint = every(*stacked)
            gap = max(float(jnp.max(jnp.abs(jnp.asarray(jax.tree_util.tree_leaves(a)[-1])
                                            - jax.tree_util.tree_leaves(joint)[-1][k])))
                      for k, a in enumerate(apart))
            rows.append([name, len(nodes), round(per_bay, 1), round(together, 1), round(together / per_bay, 2)])
            notes.append(f"{name}: largest difference between the two ways {gap:.2e} (N, N/m)")
        n_free = pattern.free_dofs.size
        matrices = []
        for x, r, p in zip(nodes, refs, params):
            _, data = jax.jit(jacobian_values)(x, r, p)
            matrices.append(sp.csc_matrix((np.asarray(data), pattern.indices.copy(), pattern.indptr.copy()),
                                          shape=(n_free, n_free)))
    factors = []

    def factorise():
        factors[:] = [spla.splu(m, permc_spec=PERMC_SPEC) for m in matrices]
        return factors

    rows.append(["SuperLU factorisations (host)", len(matrices), round(_median_ms(factorise, args.repeats), 1),
                 None, None])
    rhs = np.random.default_rng(0).standard_normal((n_free, TANGENTS))
    rows.append([f"{TANGENTS} back-solves with each factor (host)", len(matrices),
                 round(_median_ms(lambda: [f.solve(rhs) for f in factors], args.repeats), 1), None, None])
    notes += [f"{len(nodes)} bays of {n_span}x{n_contour} ({n_free} free unknowns each, {pattern.n_colours} colours, "
              f"{matrices[0].nnz} Jacobian non-zeros); medians of {args.repeats} timings after a warm-up call",
              "ratio: one program's time over the per-bay calls' (below 1: the one program is faster); the host "
              "rows have no one-program form (SciPy has no batched sparse LU)"]
    path = save_result("bays_one_program",
                       title="A Newton iteration's arithmetic on the 40-cell wing: one program per bay against "
                             "one vmapped program for every bay",
                       command="PYTHONPATH=. python benchmarks/bays_one_program.py"
                               + (f" --repeats {args.repeats}" if args.repeats != 7 else ""),
                       columns=["piece", "bays", "per bay, ms (all bays)", "one program, ms", "ratio"],
                       rows=rows, notes=notes)
    print_result(path, rows, notes)


if __name__ == "__main__":
    main()
