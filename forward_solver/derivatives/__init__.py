"""Derivatives of the equilibrium shape, the adjoints as values (``solve_equilibrium(adjoint=...)``).

* `custom_jvp`: the custom JVP around the host solve (`differentiable_solution`),
  `GRADIENT_RTOL`, `nodes_only`;
* `implicit`: `ImplicitAdjoint`, the implicit function theorem, with its
  linear solvers as values: `SparseLU` (host) here and `krylov.BiCGStab`
  (matrix-free); `forward_only` for forward-mode callers;
* `rhs`: the implicit rule's right-hand side and operator, built there only;
* `krylov`: the matrix-free operator, block-Jacobi preconditioner and `BiCGStab`;
* `unrolled`: `UnrolledAdjoint`, plain AD through the unrolled relaxation
  (the check of the implicit rule).

The modules import the solvers and the solvers import them, so this file
imports nothing: import from the modules.
"""
