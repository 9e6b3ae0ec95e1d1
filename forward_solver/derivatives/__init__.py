"""Derivatives of the equilibrium shape, the adjoints as values (``solve_equilibrium(adjoint=...)``): the implicit
rule (`implicit`, its right-hand side `rhs`, the matrix-free `krylov`), the custom JVP of `solve_equilibrium`
(`custom_jvp`), forward-mode Jacobians (`forward`) and the unrolled check (`unrolled`). The modules import the
solvers and the solvers import them, so this file imports nothing: import from the modules.
"""
