"""The solvers: every way to reach rest, each plugged into one loop or one Newton iteration.

* `methods` (`Relax`, `Newton`, `RelaxNewton`, `Explicit`) and `chain`
  (`Auto`): the equilibrium methods as values, what
  ``solve_equilibrium(method=...)`` takes;
* `loop`: the one chunked loop every explicit solver plugs into;
* `relax`: dynamic relaxation with its jit form (`relax.traced_solution`);
  `sequencing`: its grid sequencing;
* `explicit`: the paper's scheme (`simulate`);
* `newton`: Newton's method on the sparse Jacobian of `jacobian`;
* `bays`: N bays sharing one `Parameters` (`solve_bays`, `solve_wing`; the
  `Loop` and `Batch` strategies).

The modules import one another and `forward_solver.solve`, so this file
imports nothing: import from the modules (or from `forward_solver`).
"""
